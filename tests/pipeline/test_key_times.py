"""``inbetween_at``: keys at any frames (the demo clip's 0, 8, 25 and 39: gaps of 8, 17 and
14). The motion has every frame, holds every key, meets the handles on its curves and is
C¹ at the keys; evenly spaced keys are ``inbetween``'s chain; bad times and handles on keys
are refused naming them."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ik.demo_poses import fk
from pipeline.common import LEFT_HAND, STEPS, model_of

from bezmotion.bezier import BezierLayout, JoinedLayout, evaluate, locate
from bezmotion.bmm.sampling import Handles
from bezmotion.pipeline import InbetweenOptions, inbetween, inbetween_at

TIMES = (0, 8, 25, 39)


@pytest.fixture(scope="module")
def model(clip, bmm, run):
    return model_of(bmm, run.ik, run.rest, clip.character)


def keys_at(clip, times) -> jax.Array:
    return jax.tree.map(lambda a: a[jnp.asarray(times)], clip.pose)


def left_hand_handles(clip, frames, lift: float = 10.0) -> Handles:
    _, pos = fk(clip.character, clip.pose)
    idx = np.asarray(clip.character.characteristic)[LEFT_HAND]
    target = pos[np.asarray(frames), idx] + np.array([0.0, lift, 0.0], np.float32)
    n = len(frames)
    return Handles(jnp.full(n, LEFT_HAND, jnp.int32), jnp.asarray(frames, jnp.int32), jnp.asarray(target), jnp.ones(n, bool))


@pytest.fixture(scope="module")
def unequal(clip, model):
    handles = left_hand_handles(clip, [4, 30])
    result = inbetween_at(model, keys_at(clip, TIMES), TIMES, handles, key=jax.random.key(3), options=InbetweenOptions(steps=STEPS))
    return result, handles


def test_unequal_keys_hold_every_key_and_meet_the_handles(clip, unequal):
    result, handles = unequal
    keys = keys_at(clip, TIMES)
    assert result.pose.root_pos.shape[0] == 40 and result.positions.shape == (40, 6, 3) and len(result.windows) == 3
    assert result.layout == JoinedLayout.of((8, 17, 14)) and result.layout.key_frames.tolist() == list(TIMES)
    np.testing.assert_array_equal(np.asarray(result.pose.root_pos[jnp.asarray(TIMES)]), np.asarray(keys.root_pos))
    np.testing.assert_array_equal(np.asarray(result.pose.quat_local[jnp.asarray(TIMES)]), np.asarray(keys.quat_local))
    for i, f in enumerate(np.asarray(handles.frame)):
        assert np.abs(np.asarray(result.positions[f, LEFT_HAND]) - np.asarray(handles.position[i])).max() < 1e-3


def test_the_joined_curve_is_the_motion_and_c1_at_every_key(unequal):
    result, _ = unequal
    curves, layout = result.curves, result.layout
    assert curves.ctrl_pos.shape[0] == layout.num_controls
    dense = evaluate(layout, jnp.swapaxes(curves.ctrl_pos, 0, 1), jnp.swapaxes(curves.ctrl_tangent, 0, 1))  # (6, frames, 3)
    np.testing.assert_allclose(np.asarray(jnp.swapaxes(dense, 0, 1)), np.asarray(result.positions), atol=1e-3)
    # At each shared key both windows have one tangent: here the window after key 25 (a
    # handle 5 frames after it) chose it, the window before key 8 chose that one.
    for before, after in zip(result.windows, result.windows[1:]):
        np.testing.assert_allclose(np.asarray(after.curves.ctrl_tangent[0, 0]), np.asarray(before.curves.ctrl_tangent[0, -1]), atol=1e-5)
    # The one curve through every key (one tangent per control point: C¹ there) is the motion.


def test_independent_windows_of_unequal_keys_break_the_tangent(clip, model, unequal):
    apart = inbetween_at(
        model, keys_at(clip, TIMES), TIMES, unequal[1], key=jax.random.key(3), options=InbetweenOptions(steps=STEPS, coupled=False)
    )
    assert max(float(jnp.abs(a.curves.ctrl_tangent[0, 0] - b.curves.ctrl_tangent[0, -1]).max()) for b, a in zip(apart.windows, apart.windows[1:])) > 0.1


def test_evenly_spaced_times_are_the_chain(clip, model):
    times = (3, 21, 39)  # 18 apart: a multiple of the stride, one coupled chain
    keys = keys_at(clip, times)
    handles = left_hand_handles(clip, [10])
    chain = inbetween(model, keys, handles._replace(frame=handles.frame - 3), key=jax.random.key(5), options=InbetweenOptions(steps=STEPS), span=18)
    timed = inbetween_at(model, keys, times, handles, key=jax.random.key(5), options=InbetweenOptions(steps=STEPS))
    assert len(timed.windows) == 1 and timed.layout.control_frames.tolist() == BezierLayout(37).control_frames.tolist()
    np.testing.assert_array_equal(np.asarray(timed.pose.root_pos), np.asarray(chain.pose.root_pos))
    np.testing.assert_array_equal(np.asarray(timed.curves.ctrl_pos), np.asarray(chain.joined_curves().ctrl_pos))


def test_joined_layout_locates_every_frame_in_its_window():
    layout = JoinedLayout.of((8, 17, 14))
    assert layout.control_frames.tolist() == [0, 6, 8, 14, 20, 25, 31, 37, 39] and layout.key_controls.tolist() == [0, 2, 5, 8]
    segment, t = locate(layout, layout.frames())
    starts, lengths = layout.control_frames[:-1], layout.segment_lengths
    np.testing.assert_allclose(np.asarray(starts[np.asarray(segment)] + np.asarray(t) * lengths[np.asarray(segment)]), layout.frames(), atol=1e-5)
    assert ((np.asarray(t) >= 0) & (np.asarray(t) <= 1)).all()
    assert JoinedLayout.of((30, 30)).control_frames.tolist() == BezierLayout(61).control_frames.tolist()
    with pytest.raises(ValueError, match=r"spans must be one or more integers ≥ 1, got \(8, 0\)"):
        JoinedLayout.of((8, 0))


@pytest.mark.parametrize(
    ("times", "message"),
    [
        ((0, 8, 8, 39), r"times must increase by 2 … 900 frames from one key to the next, got \[0, 8, 8, 39\] \(keys 1 and 2 are 0 apart\)"),
        ((0, 8, 39), r"times must give one frame per key \(4\), got 3"),
        (np.asarray([0.0, 8.0, 25.0, 39.0]), "times must be the keys' frames, integers in a list"),
    ],
)
def test_bad_times_are_refused_naming_them(clip, model, times, message):
    with pytest.raises(ValueError, match=message):
        inbetween_at(model, keys_at(clip, TIMES), times, key=jax.random.key(3), options=InbetweenOptions(steps=STEPS))


@pytest.mark.parametrize("frame", [8, 0, 39, 41])
def test_a_handle_on_a_key_or_outside_is_refused_naming_it(clip, model, frame):
    handles = left_hand_handles(clip, [min(frame, 39)])._replace(frame=jnp.asarray([frame], jnp.int32))
    with pytest.raises(ValueError, match=f"handle 0: frame {frame} is outside the in-between or on a key"):
        inbetween_at(model, keys_at(clip, TIMES), TIMES, handles, key=jax.random.key(3), options=InbetweenOptions(steps=STEPS))
