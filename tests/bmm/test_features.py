"""The BMM's data plumbing (``bezmotion.bmm.features``): feature statistics, tokens,
condition slots and their normalisation, and the interpolation prior.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from bmm.common import F, J, K

from bezmotion.bezier import BezierLayout

from bezmotion.evaluation.baselines import handle_interpolation
from bezmotion.handles import Handles
from bezmotion.bmm.features import (
    FeatureStats,
    control_features,
    draw_intermediate_slots,
    from_tokens,
    inbetween_conditions,
    interpolation_prior,
    normalize_conditions,
    split_features,
    to_tokens,
)


LAYOUT = BezierLayout.from_controls(K, 6)


def test_feature_stats_from_dataset(demo_dataset, stats):
    computed = FeatureStats.from_dataset(demo_dataset)
    np.testing.assert_allclose(computed.mean, stats.mean, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(computed.std, stats.std, rtol=1e-5, atol=1e-6)
    # A constant feature gets the floor, not a zero std.
    flat = dataclasses.replace(demo_dataset, ctrl_tangent=np.full_like(demo_dataset.ctrl_tangent, 7.0))
    floored = FeatureStats.from_dataset(flat)
    np.testing.assert_allclose(floored.std[:, 3:6], 1e-3)
    np.testing.assert_allclose(floored.mean[:, 3:6], 7.0)


def test_feature_plumbing_round_trips(stats, rng):
    pos, tan, rot = (jnp.asarray(rng.normal(size=(2, K, J, n)), jnp.float32) for n in (3, 3, 6))
    feats = control_features(pos, tan, rot)
    assert feats.shape == (2, K, J, 12)
    for a, b in zip(split_features(feats), (pos, tan, rot), strict=True):
        np.testing.assert_array_equal(a, b)
    tokens = to_tokens(feats)
    assert tokens.shape == (2, K, F)
    np.testing.assert_array_equal(tokens[1, 3, 4 * 12 + 7], feats[1, 3, 4, 7])  # joint-major within a token
    np.testing.assert_array_equal(from_tokens(tokens), feats)
    np.testing.assert_allclose(stats.denormalize(stats.normalize(feats)), feats, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(stats.normalize(feats), (feats - stats.mean) / stats.std, rtol=1e-6)
    joint = jnp.asarray([0, 5, 2], jnp.int32)
    p = jnp.asarray(rng.normal(size=(3, 3)), jnp.float32)
    np.testing.assert_allclose(
        stats.normalize_positions(p, joint), (p - stats.mean[joint, :3]) / stats.std[joint, :3], rtol=1e-6
    )


def test_draw_intermediate_slots_distribution():
    keys = jax.random.split(jax.random.key(7), 3000)
    everything = (K - 2) * J

    @jax.jit
    def draws(keys):
        return (
            jax.vmap(lambda k: draw_intermediate_slots(k, K, J, 4))(keys),
            jax.vmap(lambda k: draw_intermediate_slots(k, K, J, 4, min_handles=1))(keys[:500]),
            draw_intermediate_slots(keys[0], K, J, everything, min_handles=everything),
        )

    (control, joint, valid), (_, _, valid1), (c, j, v) = draws(keys)
    control, joint, valid = map(np.asarray, (control, joint, valid))
    assert control.shape == joint.shape == valid.shape == (3000, 4)
    assert control.min() >= 1 and control.max() <= K - 2, "handles must be intermediate (1…K−2)"
    assert joint.min() >= 0 and joint.max() <= J - 1
    slots = (control - 1) * J + joint  # 0 … (K−2)·J − 1
    assert all(len(set(row)) == 4 for row in slots), "slots must be distinct"
    counts = valid.sum(1)
    assert np.all(valid == (np.arange(4) < counts[:, None])), "the valid ones come first"
    assert set(counts) == {0, 1, 2, 3, 4}
    assert np.all(np.abs(np.bincount(counts) / 3000 - 0.2) < 0.04)
    # Every one of the (K−2)·J slots is used, roughly uniformly.
    hist = np.bincount(slots[valid], minlength=(K - 2) * J)
    assert hist.size == (K - 2) * J and np.all(np.abs(hist / hist.mean() - 1.0) < 0.3)
    # min_handles.
    assert set(np.asarray(valid1).sum(1)) == {1, 2, 3, 4}
    # All slots at once.
    assert bool(v.all()) and sorted(np.asarray((c - 1) * J + j)) == list(range(everything))


def test_inbetween_conditions_layout_and_normalisation(stats, rng):
    start = jnp.asarray(rng.normal(size=(J, 3)), jnp.float32)
    end = jnp.asarray(rng.normal(size=(J, 3)), jnp.float32)
    h_frame = jnp.asarray([12, 19, 6], jnp.int32)
    h_joint = jnp.asarray([5, 0, 1], jnp.int32)
    h_pos = jnp.asarray(rng.normal(size=(3, 3)), jnp.float32).at[2].set(jnp.nan)  # a NaN in the padding
    h_valid = jnp.asarray([True, True, False])
    cond = inbetween_conditions(31, start, end, Handles(h_joint, h_frame, h_pos, h_valid))
    assert cond.position.shape == (2 * J + 3, 3)
    np.testing.assert_array_equal(cond.position[:J], start)
    np.testing.assert_array_equal(cond.position[J : 2 * J], end)
    np.testing.assert_array_equal(cond.position[2 * J :2 * J + 2], h_pos[:2])
    np.testing.assert_array_equal(cond.joint, [*range(J), *range(J), 5, 0, 1])
    np.testing.assert_array_equal(cond.frame, [0] * J + [30] * J + [12, 19, 6])
    np.testing.assert_array_equal(cond.valid, [True] * (2 * J) + [True, True, False])

    translation = jnp.asarray([10.0, 0.0, -20.0])
    norm = normalize_conditions(stats, cond, translation)
    expected = (np.asarray(cond.position[:-1]) - np.asarray(translation)) / np.asarray(stats.std)[np.asarray(cond.joint[:-1]), :3]
    expected -= (np.asarray(stats.mean) / np.asarray(stats.std))[np.asarray(cond.joint[:-1]), :3]
    np.testing.assert_allclose(norm.position[:-1], expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(norm.position[-1], [0.0, 0.0, 0.0])  # padding → zeros, NaN included
    np.testing.assert_array_equal(norm.joint, cond.joint)
    np.testing.assert_array_equal(norm.valid, cond.valid)
    no_shift = normalize_conditions(stats, cond)
    np.testing.assert_allclose(no_shift.position[:-1], stats.normalize_positions(cond.position[:-1], cond.joint[:-1]), rtol=1e-6)


def test_interpolation_prior_is_the_reference_curves_in_model_space(stats, demo_dataset):
    pos = jnp.asarray(demo_dataset.ctrl_pos[4])
    handle = Handles(frame=jnp.asarray([18], jnp.int32), joint=jnp.asarray([2], jnp.int32), position=pos[3, 2][None], valid=jnp.asarray([True]))
    world = inbetween_conditions(31, pos[0], pos[-1], handle)
    prior = interpolation_prior(stats, normalize_conditions(stats, world), LAYOUT)
    assert prior.shape == (K, F)
    mask = np.zeros((K, J), bool)
    mask[[0, -1]] = True
    mask[3, 2] = True
    ref_pos, ref_tangent = handle_interpolation(jnp.asarray(mask), pos)
    p, t, o = split_features(stats.denormalize(from_tokens(prior)))
    np.testing.assert_allclose(p, ref_pos, atol=1e-3)
    np.testing.assert_allclose(t, ref_tangent, atol=1e-3)
    np.testing.assert_allclose(o, jnp.broadcast_to(stats.mean[:, 6:], o.shape), atol=1e-6)
    # Without start and end (all conditions dropped for guidance) the prior is the mean: 0.
    dropped = normalize_conditions(stats, world._replace(valid=jnp.zeros_like(world.valid)))
    assert np.all(np.asarray(interpolation_prior(stats, dropped, LAYOUT)) == 0.0)
