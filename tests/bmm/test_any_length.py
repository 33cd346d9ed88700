"""Windows of any length (keys 2 … 900 frames apart): the control grid extended, a control
point every stride frames and the last segment shorter; keys and handles met exactly at
every length. The model is tiny and untrained: the plumbing, not the motion."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bmm.common import J

from bezmotion.bezier import BezierLayout, evaluate
from bezmotion.bmm.sampling import MAX_WINDOW_FRAMES, Handles, handles_next_to_keys, sample_chained_curves, sample_curves

LENGTHS = (9, 16, 31, 46, 91)  # keys 8, 15, 30, 45 and 90 frames apart: the issue's buckets' ends and the default


def handles_for(frames: int, start: np.ndarray, end: np.ndarray) -> Handles:
    """Three handles, off the control grid where the length allows, near the straight line."""
    picks = sorted({1, frames // 3 + 1, frames - 2})
    joint = np.array([3, 0, 4][: len(picks)], np.int32)
    t = np.array(picks, np.float32)[:, None] / (frames - 1)
    position = (1 - t) * start[joint] + t * end[joint] + np.array([0.0, 12.0, 5.0], np.float32)
    return Handles(jnp.asarray(joint), jnp.asarray(picks, jnp.int32), jnp.asarray(position), jnp.ones(len(picks), bool))


@pytest.mark.parametrize("frames", LENGTHS)
def test_a_window_of_any_length_meets_its_keys_and_handles_exactly(model, motions, frames):
    start, end = np.asarray(motions.start[0]), np.asarray(motions.end[0])
    handles = handles_for(frames, start, end)
    curves = sample_curves(model, jnp.asarray(start), jnp.asarray(end), handles, key=jax.random.key(3), steps=2, num_frames=frames)
    layout = BezierLayout(frames, model.config.stride)
    assert curves.ctrl_pos.shape == (layout.num_controls, J, 3) and np.isfinite(np.asarray(curves.ctrl_pos)).all()
    dense = np.asarray(evaluate(layout, curves.ctrl_pos.swapaxes(0, 1), curves.ctrl_tangent.swapaxes(0, 1)))  # (J, frames, 3)
    np.testing.assert_array_equal(dense[:, 0], start)
    np.testing.assert_allclose(dense[:, -1], end, atol=1e-4)  # the last control point is the key; its frame's basis is exact
    met = dense[np.asarray(handles.joint), np.asarray(handles.frame)]
    assert np.abs(met - np.asarray(handles.position)).max() < 1e-3  # cm


def test_the_default_length_is_the_models_window(model, motions):
    start, end = motions.start[0], motions.end[0]
    h = jax.tree.map(lambda a: a[0], motions.handles)
    default = sample_curves(model, start, end, h, key=jax.random.key(3), steps=2)
    explicit = sample_curves(model, start, end, h, key=jax.random.key(3), steps=2, num_frames=model.config.num_frames)
    jax.tree.map(np.testing.assert_array_equal, default, explicit)


@pytest.mark.parametrize("frames", [2, 0, MAX_WINDOW_FRAMES + 1, True])
def test_a_length_out_of_range_is_refused_naming_it(model, motions, frames):
    with pytest.raises(ValueError, match="num_frames is an integer in 3"):
        sample_curves(model, motions.start[0], motions.end[0], Handles.empty(), key=jax.random.key(3), steps=1, num_frames=frames)


def test_a_handle_past_a_short_windows_end_is_refused(model, motions):
    start, end = motions.start[0], motions.end[0]
    late = Handles(jnp.asarray([3], jnp.int32), jnp.asarray([20], jnp.int32), (start[3] + end[3])[None] / 2, jnp.ones(1, bool))
    with pytest.raises(ValueError, match="handle 0: frame outside 1 … 14"):
        sample_curves(model, start, end, late, key=jax.random.key(3), steps=1, num_frames=16)


def test_a_coupled_chain_needs_spans_of_whole_strides(model, motions):
    keys = jnp.stack([motions.start[0], motions.end[0], motions.start[0] + 40.0])
    two = Handles(*(jnp.stack([a, a]) for a in Handles.empty()))
    with pytest.raises(ValueError, match="multiple of the stride"):
        sample_chained_curves(model, keys, two, key=jax.random.key(3), steps=1, num_frames=46)
    chained = sample_chained_curves(model, keys, two, key=jax.random.key(3), steps=1, num_frames=37)  # 36 = 6 strides
    assert chained.ctrl_pos.shape == (2, 7, J, 3)
    np.testing.assert_array_equal(np.asarray(chained.ctrl_pos[0, -1]), np.asarray(chained.ctrl_pos[1, 0]))


def test_handles_next_to_the_last_key_of_a_short_last_segment():
    # 46 frames: control frames 0, 6, …, 42, 45; frames 43 and 44 lie between the last two.
    h = Handles(jnp.asarray([0, 1, 2], jnp.int32), jnp.asarray([43, 41, 3], jnp.int32), None, jnp.ones(3, bool))
    near = np.asarray(handles_next_to_keys(h, 9, J, 6, num_frames=46))
    assert near[1].tolist() == [True, False, False, False, False, False]
    assert near[0].tolist() == [False, False, True, False, False, False]
