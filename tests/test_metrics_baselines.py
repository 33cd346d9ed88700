"""L2Q, L2P, NPSS on hand-computed cases, and the two baselines."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.geometry import quat_from_axis_angle, quat_mul
from bezmotion.evaluation.metrics import align_to_context, l2p, l2q, npss
from bezmotion.evaluation.baselines import interpolation, transition_weights, zero_velocity


def test_l2q_by_hand():
    true = jnp.zeros((2, 3, 22, 4)).at[..., 0].set(1.0)
    pred = true.at[0, 0, 5, 0].set(-1.0)  # one sign flip: |(-1) - 1| = 2 on one of 6 frames
    assert float(l2q(pred, true)) == pytest.approx(2.0 / 6.0)
    # All joints' components go into one norm per frame: 22 unit differences → sqrt(22).
    shifted = true.at[..., 1].set(1.0)
    assert float(l2q(shifted, true)) == pytest.approx(np.sqrt(22.0))


def test_l2p_by_hand():
    true = jnp.zeros((1, 2, 2, 3))
    pred = true.at[0, 0, 1, 2].set(3.0).at[0, 1, 0, 0].set(4.0)
    std = jnp.asarray([1.0, 1.0, 1.0, 1.0, 1.0, 0.5])  # (2 joints × 3,)
    # frame 0: |3 / 0.5| = 6; frame 1: |4 / 1| = 4 → mean 5.
    assert float(l2p(pred, true, std)) == pytest.approx(5.0)


def _npss_numpy(pred, true):
    """NPSS written out with explicit loops (definition in REFERENCE.md §1)."""
    emds, weights = [], []
    for b in range(true.shape[0]):
        for f in range(true.shape[2]):
            pt = np.real(np.fft.fft(true[b, :, f])) ** 2
            pp = np.real(np.fft.fft(pred[b, :, f])) ** 2
            emds.append(np.sum(np.abs(np.cumsum(pp / pp.sum()) - np.cumsum(pt / pt.sum()))))
            weights.append(pt.sum())
    return np.sum(np.array(emds) * weights) / np.sum(weights)


def test_npss_against_loops_and_properties():
    rng = np.random.default_rng(0)
    true = rng.normal(size=(3, 8, 5))
    pred = true + 0.3 * rng.normal(size=true.shape)
    with jax.enable_x64(True):
        value = float(npss(jnp.asarray(pred), jnp.asarray(true)))
        same = float(npss(jnp.asarray(true), jnp.asarray(true)))
        scaled = float(npss(jnp.asarray(2.0 * pred), jnp.asarray(true)))
    assert value == pytest.approx(_npss_numpy(pred, true), rel=1e-12)
    assert same == 0.0
    assert scaled == pytest.approx(value, rel=1e-12)  # power spectra are normalised


def test_align_to_context_flips_to_the_last_past_frame():
    q = quat_from_axis_angle(jnp.asarray([0.0, 1.0, 0.0]), jnp.asarray([0.1, 0.2, 0.3]))  # (3, 4)
    seq = jnp.stack([-q[0], -q[1], q[2]])[None, :, None, :]  # (1, 3 frames, 1 joint, 4)
    last = q[None, None, 0]
    aligned = align_to_context(seq, jnp.asarray(last))
    np.testing.assert_allclose(aligned[0, :, 0], q, atol=1e-7)


def test_transition_weights():
    np.testing.assert_allclose(transition_weights(3), [0.25, 0.5, 0.75])
    for bad in (0, -2):
        with pytest.raises(ValueError, match=f"positive integer, got {bad}"):
            transition_weights(bad)
    with pytest.raises((TypeError, ValueError)):  # TypeError from the runtime type check
        transition_weights(2.5)


def test_zero_velocity_copies_last_frame():
    q = jnp.asarray(np.random.default_rng(1).normal(size=(2, 22, 4)))
    r = jnp.asarray([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    tq, tr = zero_velocity(q, r, 5)
    assert tq.shape == (2, 5, 22, 4) and tr.shape == (2, 5, 3)
    np.testing.assert_array_equal(tq[:, 3], q)
    np.testing.assert_array_equal(tr[:, 4], r)


def test_interpolation_lerps_root_and_slerps_rotations():
    axis = jnp.asarray([0.0, 0.0, 1.0])
    start = quat_from_axis_angle(axis, 0.0)[None].repeat(22, 0)
    end = quat_from_axis_angle(axis, 1.2)[None].repeat(22, 0)
    tq, tr = interpolation(start, jnp.zeros(3), -end, jnp.asarray([4.0, 0.0, 8.0]), 3)  # -end: same rotation
    np.testing.assert_allclose(tr, [[1.0, 0.0, 2.0], [2.0, 0.0, 4.0], [3.0, 0.0, 6.0]], atol=1e-6)
    for k, w in enumerate([0.25, 0.5, 0.75]):
        expected = quat_from_axis_angle(axis, 1.2 * w)
        np.testing.assert_allclose(tq[k, 7], expected, atol=1e-6)  # shortest path despite -end
    # Composition check: the middle frame applied twice gives the end rotation.
    mid = tq[1, 0]
    np.testing.assert_allclose(quat_mul(mid, mid), end[0], atol=1e-6)
