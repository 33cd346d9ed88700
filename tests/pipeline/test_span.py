"""``inbetween`` with keys any distance apart (``span``): the demo clip's frames 0 and 39
in-betweened over 39 frames, not squeezed into 30; the keys held and the handles met by the
curves at every span; chains of equal spans; spans out of range refused."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ik.demo_poses import fk
from pipeline.common import LEFT_HAND, STEPS, model_of

from bezmotion.bmm.sampling import Handles
from bezmotion.pipeline import InbetweenOptions, inbetween


@pytest.fixture(scope="module")
def model(clip, bmm, run):
    return model_of(bmm, run.ik, run.rest, clip.character)


def left_hand_handle(clip, frame: int, lift: float = 10.0) -> Handles:
    _, pos = fk(clip.character, clip.pose)
    target = pos[frame, np.asarray(clip.character.characteristic)[LEFT_HAND]] + np.array([0.0, lift, 0.0], np.float32)
    return Handles(jnp.asarray([LEFT_HAND], jnp.int32), jnp.asarray([frame], jnp.int32), jnp.asarray(target[None]), jnp.ones(1, bool))


@pytest.mark.parametrize("span", [8, 17, 39])
def test_keys_any_distance_apart_are_held_and_the_handle_met(clip, model, span):
    keys = jax.tree.map(lambda a: a[jnp.asarray([0, span])], clip.pose)
    handle = left_hand_handle(clip, span // 2 + 1)
    result = inbetween(model, keys, handle, key=jax.random.key(3), options=InbetweenOptions(steps=STEPS), span=span)
    assert result.pose.root_pos.shape[0] == span + 1 and result.positions.shape[0] == span + 1
    np.testing.assert_allclose(np.asarray(result.pose.root_pos[jnp.asarray([0, -1])]), np.asarray(keys.root_pos), atol=1e-4)
    met = np.asarray(result.positions[int(handle.frame[0]), LEFT_HAND])
    assert np.abs(met - np.asarray(handle.position[0])).max() < 1e-3  # cm, the curves


def test_a_chain_of_equal_spans(clip, model):
    keys = jax.tree.map(lambda a: a[jnp.asarray([0, 18, 36])], clip.pose)
    handle = left_hand_handle(clip, 25)
    result = inbetween(model, keys, handle, key=jax.random.key(3), options=InbetweenOptions(steps=STEPS), span=18)
    assert result.pose.root_pos.shape[0] == 37
    np.testing.assert_allclose(np.asarray(result.pose.root_pos[jnp.asarray([0, 18, 36])]), np.asarray(keys.root_pos), atol=1e-4)
    assert np.abs(np.asarray(result.positions[25, LEFT_HAND]) - np.asarray(handle.position[0])).max() < 1e-3


@pytest.mark.parametrize("span", [1, 0, 900 + 1, True])
def test_a_span_out_of_range_is_refused_naming_it(clip, model, span):
    keys = jax.tree.map(lambda a: a[jnp.asarray([0, 30])], clip.pose)
    with pytest.raises(ValueError, match="span, the frames from one key to the next, is an integer in 2 … 900"):
        inbetween(model, keys, None, key=jax.random.key(3), options=InbetweenOptions(steps=STEPS), span=span)


def test_a_handle_outside_the_spans_window_is_refused(clip, model):
    keys = jax.tree.map(lambda a: a[jnp.asarray([0, 20])], clip.pose)
    with pytest.raises(ValueError, match="handles go on frames 1 … 19"):
        inbetween(model, keys, left_hand_handle(clip, 25), key=jax.random.key(3), options=InbetweenOptions(steps=STEPS), span=20)
