"""Foot locking (``bezmotion.bmm.foot_lock``), alone and inside sampling.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import assert_trees_close, assert_trees_identical
from bmm.common import J, K, grid_errors

from bezmotion.bmm.sampling import sample_curves
from bezmotion.data.characteristic import FEET


def test_lock_feet_pins_each_contact_run_and_leaves_everything_else(rng):
    from bezmotion.bmm.foot_lock import lock_feet

    pos = jnp.asarray(rng.normal(scale=20.0, size=(K, J, 3)), jnp.float32)
    tangent = jnp.asarray(rng.normal(scale=5.0, size=(K, J, 3)), jnp.float32)
    left, right = FEET
    contacts = np.full((K, 2), 0.1, np.float32)
    contacts[1:4, 0] = 0.9  # left foot planted over controls 1, 2, 3
    contacts[4, 1] = 0.8  # right foot: a one-control run ...
    contacts[0:2, 1] = 0.7  # ... and a run through the (constrained) start
    constrained = np.zeros((K, J), bool)
    constrained[[0, -1]] = True
    new_pos, new_tangent = lock_feet(pos, tangent, jnp.asarray(contacts), jnp.asarray(constrained))
    p, t, p0, t0 = (np.asarray(a) for a in (new_pos, new_tangent, pos, tangent))
    # Left run 1–3: one horizontal position, the run's mean; heights kept; no horizontal velocity.
    np.testing.assert_allclose(p[1:4, left][:, [0, 2]], np.broadcast_to(p0[1:4, left][:, [0, 2]].mean(0), (3, 2)), rtol=1e-6)
    np.testing.assert_array_equal(p[1:4, left, 1], p0[1:4, left, 1])
    np.testing.assert_array_equal(t[1:4, left][:, [0, 2]], 0.0)
    np.testing.assert_array_equal(t[1:4, left, 1], t0[1:4, left, 1])
    # Right run 0–1 contains the start, which does not move: control 1 takes its XZ.
    np.testing.assert_array_equal(p[0, right], p0[0, right])
    np.testing.assert_allclose(p[1, right][[0, 2]], p0[0, right][[0, 2]], rtol=1e-6)
    # A one-control run keeps its position and only stops horizontally.
    np.testing.assert_array_equal(p[4, right], p0[4, right])
    np.testing.assert_array_equal(t[4, right][[0, 2]], 0.0)
    # Unplanted controls, other joints: untouched, bit for bit.
    untouched = np.ones((K, J), bool)
    untouched[1:4, left] = untouched[[0, 1, 4], right] = False
    np.testing.assert_array_equal(p[untouched], p0[untouched])
    np.testing.assert_array_equal(t[untouched], t0[untouched])
    # Batch axes: the same as one motion at a time.
    batched = lock_feet(jnp.stack([pos, pos + 1.0]), jnp.stack([tangent] * 2), jnp.asarray(np.stack([contacts] * 2)), jnp.asarray(np.stack([constrained] * 2)))
    assert_trees_close(jax.tree.map(lambda a: a[0], batched), (new_pos, new_tangent), tol=1e-6)
    with pytest.raises(ValueError, match="threshold"):
        lock_feet(pos, tangent, jnp.asarray(contacts), jnp.asarray(constrained), threshold=1.0)


def test_a_foot_handle_between_control_frames_plants_its_contact_run(rng):
    from bezmotion.bezier import BezierLayout
    from bezmotion.handles import Handles
    from bezmotion.bmm.foot_lock import lock_feet

    layout = BezierLayout.from_controls(K, 6)
    pos = jnp.asarray(rng.normal(scale=20.0, size=(K, J, 3)), jnp.float32)
    tangent = jnp.asarray(rng.normal(scale=5.0, size=(K, J, 3)), jnp.float32)
    left, right = FEET
    contacts = np.full((K, 2), 0.1, np.float32)
    contacts[1:4, 0] = 0.9  # left foot planted over controls 1–3 (frames 6–18), no constraint in it
    contacts[0:3, 1] = 0.9  # right foot planted over controls 0–2, through the constrained start
    constrained = np.zeros((K, J), bool)
    constrained[[0, -1]] = True
    target = np.asarray(rng.normal(scale=20.0, size=(5, 3)), np.float32)
    handles = Handles(
        position=jnp.asarray(target),
        joint=jnp.asarray([left, right, left, 0, left], jnp.int32),
        # left inside its run; right inside its run (which the start already anchors);
        # left from control 3 (planted) to 4 (not); the hips; padding inside the left run.
        frame=jnp.asarray([9, 7, 20, 9, 15], jnp.int32),
        valid=jnp.asarray([True, True, True, True, False]),
    )
    args = (pos, tangent, jnp.asarray(contacts), jnp.asarray(constrained))
    new_pos, new_tangent = (np.asarray(a) for a in lock_feet(*args, handles=handles, layout=layout))
    plain_pos, plain_tangent = (np.asarray(a) for a in lock_feet(*args))
    # The left run stands where its handle puts the foot, horizontally; heights kept.
    np.testing.assert_allclose(new_pos[1:4, left][:, [0, 2]], np.broadcast_to(target[0, [0, 2]], (3, 2)), rtol=1e-6)
    np.testing.assert_array_equal(new_pos[1:4, left, 1], np.asarray(pos)[1:4, left, 1])
    # The right run holds the start (control 0) and a handle at frame 7: control 1 (frame 6)
    # and control 2 (frame 12) are nearer the handle, so they stand where it puts the foot.
    np.testing.assert_allclose(new_pos[1:3, right][:, [0, 2]], np.broadcast_to(target[1, [0, 2]], (2, 2)), rtol=1e-6)
    # Everything else as without handles: the start, the other handles (leaving the run,
    # another joint, padding) change nothing, tangents alike.
    others = np.ones((K, J), bool)
    others[1:4, left] = others[1:3, right] = False
    np.testing.assert_array_equal(new_pos[others], plain_pos[others])
    np.testing.assert_array_equal(new_tangent, plain_tangent)
    # Held at the run's mean of conditions (the earlier rule), the start alone anchors the right run.
    mean_pos = np.asarray(lock_feet(*args, handles=handles, layout=layout, anchor="mean")[0])
    np.testing.assert_array_equal(mean_pos[:, right], plain_pos[:, right])
    # Padding holds anything, NaN too (0 × NaN would poison its run).
    nan_padding = handles._replace(position=handles.position.at[4].set(jnp.nan))
    assert_trees_identical(lock_feet(*args, handles=nan_padding, layout=layout), lock_feet(*args, handles=handles, layout=layout))
    with pytest.raises(ValueError, match="layout"):
        lock_feet(*args, handles=handles)


def test_a_run_between_two_conditions_steps_once_between_them(rng):
    """A foot planted over the whole window whose start and end put it in two places: each
    control point stands where the nearer condition puts the foot (one step, between controls
    2 and 3), where holding the run at their mean (``anchor="mean"``) stops the foot at every
    control point on the way — and at the keys, where a chain's windows meet."""
    from bezmotion.bmm.foot_lock import lock_feet

    pos = jnp.asarray(rng.normal(scale=20.0, size=(K, J, 3)), jnp.float32)
    tangent = jnp.asarray(rng.normal(scale=5.0, size=(K, J, 3)), jnp.float32)
    left, _ = FEET
    contacts = np.full((K, 2), 0.1, np.float32)
    contacts[:, 0] = 0.9
    constrained = np.zeros((K, J), bool)
    constrained[[0, -1]] = True
    args = (pos, tangent, jnp.asarray(contacts), jnp.asarray(constrained))
    p0 = np.asarray(pos)[:, left][:, [0, 2]]
    nearest, mean = (np.asarray(lock_feet(*args, anchor=a)[0])[:, left][:, [0, 2]] for a in ("nearest", "mean"))
    np.testing.assert_allclose(nearest, p0[[0, 0, 0, -1, -1, -1]], rtol=1e-6)
    np.testing.assert_allclose(mean[1:-1], np.broadcast_to((p0[0] + p0[-1]) / 2, (K - 2, 2)), rtol=1e-6)
    # Seven control points: the middle one is as near to both and stands between them.
    seven = lambda a: jnp.concatenate([a, a[-1:]])  # noqa: E731  (the last row twice: planted, constrained)
    pos7 = jnp.asarray(rng.normal(scale=20.0, size=(K + 1, J, 3)), jnp.float32)
    locked = np.asarray(lock_feet(pos7, seven(tangent), seven(jnp.asarray(contacts)), jnp.asarray(constrained[[0, 1, 2, 3, 4, 4, 5]]))[0])
    ends = np.asarray(pos7)[[0, -1], left][:, [0, 2]]
    np.testing.assert_allclose(locked[3, left][[0, 2]], ends.mean(0), rtol=1e-6)
    with pytest.raises(ValueError, match="anchor must be one of"):
        lock_feet(*args, anchor="median")


def test_a_held_foot_stays_within_reach_of_the_hips(rng):
    """The hips walk 150 cm through a window whose left foot is "planted" throughout, its
    curve keeping 90 cm below them: the lock holds the foot at the nearer key only where that
    stays within 1.1 × the curves' own reach (controls 1 and 4, 95 cm from the hips); controls
    2 and 3 (108 cm away when held) keep their own position and tangent."""
    from bezmotion.bmm.foot_lock import MAX_STRETCH, lock_feet

    left, right = FEET
    hips = np.zeros((K, 3))
    hips[:, 0] = 30.0 * np.arange(K)  # 30 cm a control point
    pos = np.asarray(rng.normal(scale=5.0, size=(K, J, 3)))
    pos[:, 0] = hips  # HIPS is joint 0
    pos[:, left] = hips + [0.0, -90.0, 0.0]
    tangent = np.asarray(rng.normal(scale=5.0, size=(K, J, 3)))
    contacts = np.full((K, 2), 0.1, np.float32)
    contacts[:, 0] = 0.9
    constrained = np.zeros((K, J), bool)
    constrained[[0, -1]] = True
    args = (jnp.asarray(pos, jnp.float32), jnp.asarray(tangent, jnp.float32), jnp.asarray(contacts), jnp.asarray(constrained))
    p, t = (np.asarray(a) for a in lock_feet(*args))
    np.testing.assert_allclose(p[[1, 4], left][:, [0, 2]], pos[[0, -1], left][:, [0, 2]], atol=1e-5)  # held at the nearer key
    np.testing.assert_array_equal(t[[1, 4], left][:, [0, 2]], 0.0)
    np.testing.assert_allclose(p[[2, 3], left], pos[[2, 3], left], atol=1e-5)  # out of reach held: their own
    np.testing.assert_allclose(t[[2, 3], left], tangent[[2, 3], left], atol=1e-6)
    assert np.linalg.norm(p[:, left] - hips, axis=-1).max() <= MAX_STRETCH * 90.0 + 1e-3
    # Without the limit (max_stretch=None), every point is held at the nearer key.
    unlimited = np.asarray(lock_feet(*args, max_stretch=None)[0])
    np.testing.assert_allclose(unlimited[1:5, left][:, [0, 2]], pos[[0, 0, -1, -1], left][:, [0, 2]], atol=1e-5)
    with pytest.raises(ValueError, match="max_stretch must be a factor of at least 1"):
        lock_feet(*args, max_stretch=0.5)


def test_foot_locked_sampling_keeps_the_constraints_exact(model, motions, sampled):
    locked = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, foot_lock=True)
    assert np.all(grid_errors(locked, motions) == 0.0)
    assert_trees_identical(locked.contacts, sampled.contacts)
    planted = np.asarray(locked.contacts) > 0.5
    assert planted.any(), "the fixture model should plant some foot somewhere"
    feet_tangent = np.asarray(locked.ctrl_tangent)[:, :, list(FEET)]
    np.testing.assert_array_equal(feet_tangent[planted][:, [0, 2]], 0.0)
    others = [j for j in range(J) if j not in FEET]
    assert_trees_identical(locked.ctrl_pos[:, :, others], sampled.ctrl_pos[:, :, others])
    # By name: True is "nearest"; "mean", the earlier rule, differs only in the feet's positions.
    named, mean = (sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, foot_lock=a) for a in ("nearest", "mean"))
    assert_trees_identical(named, locked)
    assert_trees_identical(mean.ctrl_tangent, locked.ctrl_tangent)
    assert_trees_identical(mean.ctrl_pos[:, :, others], locked.ctrl_pos[:, :, others])
    with pytest.raises(ValueError, match="foot_lock must be"):
        sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, foot_lock="median")
