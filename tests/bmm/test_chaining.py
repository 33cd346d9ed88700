"""Chained windows (``bezmotion.bmm.sampling.sample_chained_curves``):
continuity at the chained keys (tangents, orientations, contacts shared; positions the
keys), handles hit next to a shared key, independent windows for comparison, one
compilation, the input errors, and the boundary velocity jump metric.
"""

from __future__ import annotations

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import assert_trees_identical, lapack_calls
from bmm.common import J, K, TINY

from bezmotion.bezier import BezierLayout, evaluate
from bezmotion.bmm.sampling import Handles, sample_chained_curves, sample_curves, share_boundaries, shared_key_mask
from bezmotion.evaluation.metrics import boundary_velocity_jump, chain_velocity_jumps, distribution_summary

LAYOUT = BezierLayout.from_controls(K, TINY.stride)
KEYS = 4  # three windows
STEPS = 3
LAST = TINY.num_frames - 1  # 30: a window's last frame


@pytest.fixture(scope="module")
def chain(demo_dataset) -> SimpleNamespace:
    """Four keys from the demo windows walking +X (100 cm a window), each window with
    handles: one on the frame next to a shared key (window 0 at 29, window 1 at 1, window 2
    at 1), one on a control frame, one between, and a padding slot in window 2."""
    pos = np.asarray(demo_dataset.ctrl_pos, np.float32)
    rot = np.asarray(demo_dataset.ctrl_rot6d, np.float32)
    rows, controls = [0, 0, 5, 9], [0, -1, -1, -1]
    step = np.array([100.0, 0.0, 0.0], np.float32)
    key_pos = np.stack([pos[r, c] + k * step for k, (r, c) in enumerate(zip(rows, controls))])
    key_rot6d = np.stack([rot[r, c] for r, c in zip(rows, controls)])
    frame = np.array([[29, 12, 17], [1, 6, 22], [1, 24, 9]], np.int32)
    joint = np.array([[4, 0, 2], [4, 1, 5], [0, 3, 3]], np.int32)
    # Where the straight line between the window's keys is at that frame, moved 8 cm up.
    t = frame[..., None] / LAST
    lerp = (1 - t) * key_pos[:-1][np.arange(3)[:, None], joint] + t * key_pos[1:][np.arange(3)[:, None], joint]
    position = (lerp + np.array([0.0, 8.0, 0.0], np.float32)).astype(np.float32)
    position[2, 2] = np.nan  # padding holds anything
    valid = jnp.asarray([[True] * 3, [True] * 3, [True, True, False]])
    handles = Handles(jnp.asarray(joint), jnp.asarray(frame), jnp.asarray(position), valid)
    return SimpleNamespace(key_pos=jnp.asarray(key_pos), key_rot6d=jnp.asarray(key_rot6d), handles=handles)


@pytest.fixture(scope="module")
def coupled(model, chain):
    return sample_chained_curves(model, chain.key_pos, chain.handles, key=jax.random.key(5), steps=STEPS)


@pytest.fixture(scope="module")
def independent(model, chain):
    return sample_chained_curves(model, chain.key_pos, chain.handles, key=jax.random.key(5), steps=STEPS, coupled=False)


def velocity(curves, window: int, frame: float) -> np.ndarray:
    """``(joints, 3)`` the analytic velocity (cm/frame) of a window's curves at ``frame``."""
    pos = jnp.moveaxis(curves.ctrl_pos[window], -2, -3)
    tangent = jnp.moveaxis(curves.ctrl_tangent[window], -2, -3)
    at = lambda f: evaluate(LAYOUT, pos, tangent, f[None])[:, 0]  # noqa: E731
    return np.asarray(jax.jacfwd(at)(jnp.asarray(frame, jnp.float32)))


def handle_residuals(curves, handles) -> list[float]:
    dense = np.asarray(evaluate(LAYOUT, jnp.moveaxis(curves.ctrl_pos, -2, -3), jnp.moveaxis(curves.ctrl_tangent, -2, -3)))
    out = []
    for w, s in zip(*np.nonzero(np.asarray(handles.valid))):
        got = dense[w, int(handles.joint[w, s]), int(handles.frame[w, s])]
        out.append(float(np.abs(got - np.asarray(handles.position[w, s])).max()))
    return out


def test_coupled_chain_is_c1_at_the_shared_keys(coupled, chain):
    assert coupled.ctrl_pos.shape == (KEYS - 1, K, J, 3) and all(np.isfinite(np.asarray(a)).all() for a in coupled)
    pos, tangent = np.asarray(coupled.ctrl_pos), np.asarray(coupled.ctrl_tangent)
    # Positions: every window starts and ends on its keys, bit for bit.
    np.testing.assert_array_equal(pos[:, 0], chain.key_pos[:-1])
    np.testing.assert_array_equal(pos[:, -1], chain.key_pos[1:])
    # Tangents, orientations and contacts at a shared key: one value for both windows.
    for leaf in (tangent, coupled.ctrl_rot6d, coupled.contacts):
        np.testing.assert_array_equal(np.asarray(leaf)[:-1, -1], np.asarray(leaf)[1:, 0])
    # Hence the same velocity on both sides of every shared key (C¹), 3·T/stride cm/frame.
    for w in range(KEYS - 2):
        before, after = velocity(coupled, w, float(LAST)), velocity(coupled, w + 1, 0.0)
        np.testing.assert_allclose(before, after, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(after, 3.0 * tangent[w + 1, 0] / TINY.stride, rtol=1e-5, atol=1e-4)
    assert np.abs(tangent[:-1, -1]).max() > 1.0  # a real tangent, not a zero one made equal


def test_coupled_chain_hits_every_handle_even_next_to_a_shared_key(coupled, chain):
    # Frames 29 and 1 depend on the shared tangent, which the projection holds fixed.
    assert max(handle_residuals(coupled, chain.handles)) < 1e-4
    # The padding slot (NaN) is no constraint.
    assert np.isfinite(np.asarray(coupled.ctrl_pos)).all()


def test_a_chain_with_no_handle_next_to_a_shared_key_is_joined_too(model, chain):
    """The projection's other branch: every window meets its handles alone, its shared
    tangents held (nothing to meet over the chain); still C¹ and through every handle."""
    away = chain.handles._replace(frame=jnp.asarray([[15, 12, 17], [9, 6, 22], [14, 24, 9]], jnp.int32))
    curves = sample_chained_curves(model, chain.key_pos, away, key=jax.random.key(5), steps=STEPS)
    tangent = np.asarray(curves.ctrl_tangent)
    np.testing.assert_array_equal(tangent[:-1, -1], tangent[1:, 0])
    np.testing.assert_array_equal(np.asarray(curves.ctrl_pos)[:, 0], chain.key_pos[:-1])
    assert max(handle_residuals(curves, away)) < 1e-4


def test_independent_windows_are_sample_curves_and_break_at_the_keys(model, coupled, independent, chain):
    # coupled=False is D.1: each window sampled alone, from the same noise.
    alone = sample_curves(model, chain.key_pos[:-1], chain.key_pos[1:], chain.handles, key=jax.random.key(5), steps=STEPS)
    assert_trees_identical(independent, alone)
    assert max(handle_residuals(independent, chain.handles)) < 1e-4
    np.testing.assert_array_equal(np.asarray(independent.ctrl_pos)[:-1, -1], np.asarray(independent.ctrl_pos)[1:, 0])
    # ... but the velocity jumps at the keys, by far more than the coupled chain's.
    jumps = [np.abs(velocity(independent, w, float(LAST)) - velocity(independent, w + 1, 0.0)).max() for w in range(KEYS - 2)]
    assert min(jumps) > 1.0, jumps
    # Coupling changes the windows' interiors too (the shared tangent enters every x̂₀).
    assert np.abs(np.asarray(coupled.ctrl_pos)[:, 1:-1] - np.asarray(independent.ctrl_pos)[:, 1:-1]).max() > 1e-3


def test_key_orientations_and_foot_lock_keep_the_chain_joined(model, chain):
    curves = sample_chained_curves(
        model, chain.key_pos, chain.handles, key=jax.random.key(6), steps=STEPS, key_rot6d=chain.key_rot6d, foot_lock=True
    )
    rot = np.asarray(curves.ctrl_rot6d)
    np.testing.assert_array_equal(rot[:, 0], chain.key_rot6d[:-1])
    np.testing.assert_array_equal(rot[:, -1], chain.key_rot6d[1:])
    tangent = np.asarray(curves.ctrl_tangent)
    np.testing.assert_array_equal(tangent[:-1, -1], tangent[1:, 0])
    np.testing.assert_array_equal(np.asarray(curves.ctrl_pos)[:, 0], chain.key_pos[:-1])
    assert max(handle_residuals(curves, chain.handles)) < 1e-4


def test_key_tangents_are_kept_through_the_coupled_chain(model, chain, demo_dataset):
    tangent = np.asarray(demo_dataset.ctrl_tangent, np.float32)
    key_tangent = jnp.asarray(np.stack([2.0 * tangent[r, c] for r, c in zip([0, 0, 5, 9], [0, -1, -1, -1])]))
    curves = sample_chained_curves(model, chain.key_pos, chain.handles, key=jax.random.key(6), steps=STEPS, key_tangent=key_tangent)
    got = np.asarray(curves.ctrl_tangent)
    np.testing.assert_array_equal(got[:, 0], key_tangent[:-1])
    np.testing.assert_array_equal(got[:, -1], key_tangent[1:])
    assert max(handle_residuals(curves, chain.handles)) < 1e-4  # also the handles next to the keys (frames 1, 29)
    with pytest.raises((ValueError, TypeError), match=r"key_tangent"):
        sample_chained_curves(model, chain.key_pos, chain.handles, key=jax.random.key(0), steps=1, key_tangent=key_tangent[:3])


def test_batched_chains_compile_once_and_match_single_chains(model, chain):
    traces = []

    @jax.jit
    def run(key_pos, handles, key):
        traces.append(1)  # runs once per trace
        return sample_chained_curves(model, key_pos, handles, key=key, steps=2)

    batch = jax.tree.map(lambda a: jnp.stack([a, a]), (chain.key_pos, chain.handles))
    two = run(batch[0].at[1].add(jnp.asarray([0.0, 0.0, 50.0])), batch[1], jax.random.key(1))
    again = run(batch[0], batch[1], jax.random.key(2))
    assert len(traces) == 1 and two.ctrl_pos.shape == (2, KEYS - 1, K, J, 3)
    np.testing.assert_array_equal(np.asarray(two.ctrl_tangent)[:, :-1, -1], np.asarray(two.ctrl_tangent)[:, 1:, 0])
    assert not np.array_equal(np.asarray(again.ctrl_tangent[0]), np.asarray(again.ctrl_tangent[1]))  # own keys per chain
    first = sample_chained_curves(model, chain.key_pos, chain.handles, key=jax.random.split(jax.random.key(2), 2)[0], steps=2)
    np.testing.assert_allclose(np.asarray(first.ctrl_pos), np.asarray(again.ctrl_pos[0]), atol=1e-3)


def test_the_coupled_chain_has_no_lapack_calls(model, chain):
    """Its handles are met over the whole chain (plain XLA solves, :mod:`bezmotion._src.linalg`)."""
    sample = lambda k, h: sample_chained_curves(model, k, h, key=jax.random.key(0), steps=1, foot_lock=True)  # noqa: E731
    assert lapack_calls(sample, chain.key_pos, chain.handles) == set()


def test_two_keys_are_one_window(model, chain):
    """A chain of two keys is the window between them, bit for bit, with the same key."""
    one = jax.tree.map(lambda a: a[:1], chain.handles)
    chained = sample_chained_curves(model, chain.key_pos[:2], one, key=jax.random.key(3), steps=2)
    alone = sample_curves(model, chain.key_pos[0], chain.key_pos[1], jax.tree.map(lambda a: a[0], one), key=jax.random.key(3), steps=2)
    assert_trees_identical(jax.tree.map(lambda a: a[0], chained), alone)


def test_chain_input_errors(model, chain):
    run = lambda *a, **k: sample_chained_curves(model, *a, key=jax.random.key(0), steps=1, **k)  # noqa: E731
    with pytest.raises(ValueError, match=r"keys ≥ 2.*\(1, 6, 3\)"):
        run(chain.key_pos[:1], jax.tree.map(lambda a: a[:0], chain.handles))
    with pytest.raises(ValueError, match=r"handles must be batched.*\(3,\).*\(2,\)"):
        run(chain.key_pos, jax.tree.map(lambda a: a[:2], chain.handles))
    # The type checks of the test session may catch this one first (as for sample_curves).
    with pytest.raises((ValueError, TypeError), match=r"key_rot6d"):
        run(chain.key_pos, chain.handles, key_rot6d=chain.key_rot6d[:3])
    with pytest.raises(ValueError, match="overwrite=True"):
        run(chain.key_pos, chain.handles, overwrite=False)


def test_share_boundaries_and_shared_key_mask():
    x = jnp.arange(3 * 4, dtype=jnp.float32).reshape(3, 4)  # 3 windows, 4 controls
    np.testing.assert_array_equal(share_boundaries(x), [[0, 1, 2, 3.5], [3.5, 5, 6, 7.5], [7.5, 9, 10, 11]])
    mask = np.asarray(shared_key_mask(3, 4, 2))
    np.testing.assert_array_equal(mask[..., 0], [[0, 0, 0, 1], [1, 0, 0, 1], [1, 0, 0, 0]])
    assert (mask[..., 0] == mask[..., 1]).all()


def test_boundary_velocity_jump():
    frames = np.arange(7, dtype=np.float32)
    # Joint 0 moves at 1 cm/frame then 3 cm/frame from frame 3 on; joint 1 accelerates (p = f²).
    p0 = np.where(frames <= 3, frames, 3 + 3 * (frames - 3))
    pos = np.zeros((2, 7, 2, 3), np.float32)
    pos[:, :, 0, 0], pos[:, :, 1, 2] = p0, frames**2
    pos[1] *= 2.0
    jump = np.asarray(boundary_velocity_jump(jnp.asarray(pos), [3, 5]))
    assert jump.shape == (2, 2, 2)
    np.testing.assert_allclose(jump[0], [[2.0, 2.0], [0.0, 2.0]])  # (boundary, joint)
    np.testing.assert_allclose(jump[1], 2.0 * jump[0])
    for bad in ([0], [6], [3, 7]):
        with pytest.raises(ValueError, match=r"boundary frames must be integers in 1 … 5 \(7 frames\), got"):
            boundary_velocity_jump(jnp.asarray(pos), np.asarray(bad))
    with pytest.raises((ValueError, TypeError), match="boundary"):  # the session's type checks may come first
        boundary_velocity_jump(jnp.asarray(pos), np.asarray([2.5]))


def test_chain_velocity_jumps_split_the_inner_frames_at_the_shared_keys():
    pos = jnp.asarray(np.random.default_rng(0).normal(size=(2, 13, 3, 3)), jnp.float32)  # 3 windows of 5 frames
    jumps = chain_velocity_jumps(pos, 3)
    np.testing.assert_array_equal(jumps.all_frames, boundary_velocity_jump(pos, np.arange(1, 12)))
    np.testing.assert_array_equal(jumps.at_shared_keys, boundary_velocity_jump(pos, [4, 8]))
    np.testing.assert_array_equal(jumps.other_frames, boundary_velocity_jump(pos, [1, 2, 3, 5, 6, 7, 9, 10, 11]))
    assert chain_velocity_jumps(pos, 1).at_shared_keys.shape == (2, 0, 3)
    for windows in (0, 5):
        with pytest.raises(ValueError, match=rf"13 frames are not a chain of {windows} windows"):
            chain_velocity_jumps(pos, windows)


def test_distribution_summary():
    assert distribution_summary(np.arange(101.0).reshape(1, 101)) == {"mean": 50.0, "p95": 95.0, "max": 100.0, "count": 101}
    with pytest.raises(ValueError, match="no values to summarise"):
        distribution_summary(np.zeros((2, 0, 6)))
