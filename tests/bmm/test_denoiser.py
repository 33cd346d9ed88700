"""The BMM denoiser (``bezmotion.bmm.denoiser``): its conditions, shapes and parameter
count, padding, dropout, jit/vmap, and the residual prediction and last-layer fast path.
Models are tiny (width 32, one layer).
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from helpers import assert_trees_close, assert_trees_identical, trees_differ
from bmm.common import F, J, K, RESIDUAL, TINY, some_conditions

from bezmotion.bmm.denoiser import (
    BMMConfig,
    BMMDenoiser,
    apply_denoiser,
    count_parameters,
    init_denoiser,
    sinusoidal_encoding,
)
from bezmotion.bmm.features import interpolation_prior, normalize_conditions, predict_x0
from bezmotion.bmm.sampling import BezierMotionModel, with_off_grid_prior
from bezmotion.handles import Handles
from bezmotion.bezier import BezierLayout


@pytest.fixture(scope="module")
def tiny_model() -> SimpleNamespace:
    """Untrained tiny denoiser with one jitted single-motion apply, shared by the tests."""
    graphdef, params = init_denoiser(TINY, key=jax.random.key(1))
    apply = jax.jit(lambda p, x, t, c: apply_denoiser(graphdef, p, x, t, c))
    return SimpleNamespace(graphdef=graphdef, params=params, apply=apply)


def test_conditions_grid_round_trip(rng):
    mask = jnp.asarray(rng.random((K, J)) < 0.4)
    position = jnp.asarray(rng.normal(size=(K, J, 3)), jnp.float32)
    cond = Handles.from_grid(mask, position, 6)
    assert cond.position.shape == (K * J, 3) and cond.valid.shape == (K * J,)
    # Slot k·J + j is (control k, i.e. frame 6k, joint j).
    np.testing.assert_array_equal(cond.frame, np.repeat(np.arange(K) * 6, J))
    np.testing.assert_array_equal(cond.joint, np.tile(np.arange(J), K))
    back_mask, back_pos = cond.to_grid(K, J, 6)
    np.testing.assert_array_equal(back_mask, mask)
    np.testing.assert_array_equal(np.asarray(back_pos)[np.asarray(mask)], np.asarray(position)[np.asarray(mask)])
    np.testing.assert_array_equal(np.asarray(back_pos)[~np.asarray(mask)], 0.0)
    # Batched from_grid keeps the batch axes.
    batched = Handles.from_grid(jnp.stack([mask, ~mask]), jnp.stack([position, -position]), 6)
    assert batched.position.shape == (2, K * J, 3) and batched.joint.shape == (2, K * J)
    np.testing.assert_array_equal(batched.valid[1], ~mask.reshape(-1))


def test_conditions_to_grid_invalid_slots_never_overwrite_valid_ones():
    cond = Handles(
        position=jnp.asarray([[1.0, 2.0, 3.0], [9.0, 9.0, 9.0], [4.0, 5.0, 6.0], [7.0, 7.0, 7.0]]),
        joint=jnp.asarray([2, 2, 3, 3], jnp.int32),
        frame=jnp.asarray([6, 6, 24, 24], jnp.int32),
        valid=jnp.asarray([True, False, True, True]),
    )
    mask, pos = cond.to_grid(K, J, 6)
    assert int(mask.sum()) == 2 and bool(mask[1, 2]) and bool(mask[4, 3])
    np.testing.assert_array_equal(pos[1, 2], [1.0, 2.0, 3.0])  # the later invalid slot is dropped
    np.testing.assert_array_equal(pos[4, 3], [7.0, 7.0, 7.0])  # of two valid slots, the later wins


def analytic_parameter_count(c: BMMConfig) -> int:
    w, ff, f = c.width, c.ff_width, c.frame_features
    linear = lambda n_in, n_out: n_in * n_out + n_out  # noqa: E731
    layer = 4 * linear(w, w) + 2 * 2 * w + linear(w, ff) + linear(ff, w)
    return linear(f, w) + linear(3, w) + c.num_joints * w + 2 * linear(w, w) + c.num_layers * layer + linear(w, f + 2)


def test_parameter_count_of_the_paper_size():
    params = jax.eval_shape(lambda key: init_denoiser(BMMConfig.paper(), key=key)[1], jax.random.key(0))
    n = count_parameters(params)
    assert 17.0e6 < n < 17.6e6
    assert n == analytic_parameter_count(BMMConfig.paper())


def test_bmm_config_validation():
    assert BMMConfig().num_frames == 31 and BMMConfig().max_conditions == 36 and BMMConfig().frame_features == 72
    assert BMMConfig().off_grid_prior == "linear"  # also what a saved config from before the field loads as
    for bad in ({"width": 30, "num_heads": 4}, {"num_controls": 1}, {"dropout": 1.0}, {"num_layers": 0}, {"stride": True}, {"off_grid_prior": "bump"}):
        with pytest.raises(ValueError, match="BMMConfig"):
            BMMConfig(**bad)


def test_sinusoidal_encoding():
    enc = sinusoidal_encoding(jnp.asarray([0.0, 3.0]), 8)
    assert enc.shape == (2, 8)
    np.testing.assert_allclose(enc[0], [0, 0, 0, 0, 1, 1, 1, 1], atol=1e-7)
    freqs = np.exp(-np.log(10000.0) * np.arange(4) / 4)
    np.testing.assert_allclose(enc[1], np.concatenate([np.sin(3 * freqs), np.cos(3 * freqs)]), atol=1e-6)


def test_denoiser_shapes_and_parameter_count(tiny_model, rng):
    x = jnp.asarray(rng.normal(size=(K, F)), jnp.float32)
    x0, logits = tiny_model.apply(tiny_model.params, x, jnp.int32(500), some_conditions(rng))
    assert x0.shape == (K, F) and logits.shape == (K, 2)
    assert np.all(np.isfinite(x0)) and np.all(np.isfinite(logits))
    assert count_parameters(tiny_model.params) == analytic_parameter_count(TINY)


def test_padding_condition_slots_change_nothing(tiny_model, rng):
    x = jnp.asarray(rng.normal(size=(K, F)), jnp.float32)
    t = jnp.int32(321)
    cond = some_conditions(rng, handles=4, valid_handles=2)
    base = tiny_model.apply(tiny_model.params, x, t, cond)

    # Different positions, joints and controls in the two padding slots: identical output.
    pad = np.asarray(~cond.valid)
    moved = cond._replace(
        position=jnp.where(pad[:, None], 1e3 * jnp.asarray(rng.normal(size=cond.position.shape), jnp.float32), cond.position),
        joint=jnp.where(pad, jnp.asarray(rng.integers(0, J, pad.shape), jnp.int32), cond.joint),
        frame=jnp.where(pad, jnp.asarray(rng.integers(0, 31, pad.shape), jnp.int32), cond.frame),
    )
    assert trees_differ(moved, cond)
    assert_trees_identical(tiny_model.apply(tiny_model.params, x, t, moved), base)

    # Garbage in padding (NaN positions, out-of-range joints and controls) cannot poison it.
    garbage = cond._replace(
        position=jnp.where(pad[:, None], jnp.nan, cond.position),
        joint=jnp.where(pad, 99, cond.joint),
        frame=jnp.where(pad, -7, cond.frame),
    )
    assert_trees_identical(tiny_model.apply(tiny_model.params, x, t, garbage), base)

    # More padding slots (a different number of slots): the same output.
    extra = Handles(
        position=jnp.asarray(rng.normal(size=(5, 3)), jnp.float32), joint=jnp.arange(5, dtype=jnp.int32) % J,
        frame=jnp.arange(5, dtype=jnp.int32) * 7, valid=jnp.zeros(5, bool),
    )  # fmt: skip
    longer = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), cond, extra)
    assert_trees_close(tiny_model.apply(tiny_model.params, x, t, longer), base, tol=1e-6)

    # A valid condition does change it (position, and which joint it constrains).
    assert trees_differ(tiny_model.apply(tiny_model.params, x, t, cond._replace(valid=cond.valid.at[-1].set(True))), base)
    assert trees_differ(tiny_model.apply(tiny_model.params, x, t, cond._replace(position=cond.position.at[0, 0].add(1.0))), base)
    assert trees_differ(tiny_model.apply(tiny_model.params, x, t, cond._replace(joint=cond.joint.at[12].set((cond.joint[12] + 1) % J))), base)
    assert trees_differ(tiny_model.apply(tiny_model.params, x, t, cond._replace(frame=cond.frame.at[12].add(1))), base)
    # And so do the timestep and the input.
    assert trees_differ(tiny_model.apply(tiny_model.params, x, jnp.int32(322), cond), base)


def test_denoiser_dropout_only_with_a_key(rng):
    config = dataclasses.replace(TINY, dropout=0.5)
    graphdef, params = init_denoiser(config, key=jax.random.key(2))
    graphdef0, params0 = init_denoiser(TINY, key=jax.random.key(2))  # the same weights, dropout 0
    x = jnp.asarray(rng.normal(size=(K, F)), jnp.float32)
    cond = some_conditions(rng)

    @jax.jit
    def outputs(k3, k4):
        run = lambda key=None: apply_denoiser(graphdef, params, x, jnp.int32(10), cond, key=key)  # noqa: E731
        run0 = lambda key=None: apply_denoiser(graphdef0, params0, x, jnp.int32(10), cond, key=key)  # noqa: E731
        return run(), run(k3), run(k3), run(k4), run0(), run0(k3)

    plain, drop3, drop3_again, drop4, plain0, drop0 = outputs(jax.random.key(3), jax.random.key(4))
    assert_trees_identical(drop3, drop3_again)
    assert trees_differ(drop3, plain) and trees_differ(drop3, drop4)
    assert_trees_close(plain0, plain)  # without a key, dropout is off
    assert_trees_close(drop0, plain0)  # with dropout 0 the key makes no difference


def test_denoiser_jit_matches_eager_and_vmap_matches_loop(tiny_model, rng):
    xs = jnp.asarray(rng.normal(size=(3, K, F)), jnp.float32)
    ts = jnp.asarray([0, 500, 999], jnp.int32)
    conds = [some_conditions(rng, valid_handles=v) for v in (0, 2, 4)]
    stacked = jax.tree.map(lambda *a: jnp.stack(a), *conds)
    batched = jax.jit(jax.vmap(lambda x, t, c: apply_denoiser(tiny_model.graphdef, tiny_model.params, x, t, c)))(xs, ts, stacked)
    eager = apply_denoiser(tiny_model.graphdef, tiny_model.params, xs[1], ts[1], conds[1])
    assert_trees_close(tiny_model.apply(tiny_model.params, xs[1], ts[1], conds[1]), eager, tol=2e-5)
    for i in range(3):
        jitted = tiny_model.apply(tiny_model.params, xs[i], ts[i], conds[i])
        assert_trees_close(jax.tree.map(lambda a, i=i: a[i], batched), jitted, tol=2e-5)


def test_prediction_kind_is_validated():
    with pytest.raises(ValueError, match="prediction"):
        BMMConfig.cpu(prediction="eps")


def test_last_layer_computing_only_frame_tokens_is_exact(rng):
    """The denoiser's last layer updates only the frame tokens; every token is still a key,
    so those rows equal the full layer's."""
    module = BMMDenoiser(BMMConfig.cpu(width=64, ff_width=96, num_heads=4, num_layers=2), rngs=nnx.Rngs(params=jax.random.key(3)))
    layer = module.layers[-1]
    tokens = jnp.asarray(rng.normal(size=(21, 64)), jnp.float32)
    valid = jnp.asarray(np.arange(21) < 18)
    frames = slice(1, 1 + K)
    full = jax.jit(lambda x: layer(x, valid, None))(tokens)
    only = jax.jit(lambda x: layer(x, valid, None, frames))(tokens)
    assert only.shape == (K, 64)
    np.testing.assert_allclose(only, full[frames], rtol=1e-5, atol=1e-5)
    # ... and the frames still listen to the other tokens.
    moved = jax.jit(lambda x: layer(x, valid, None, frames))(tokens.at[12].add(1.0))
    assert trees_differ(moved, only)


def test_residual_prediction_adds_the_prior_to_the_network_output(stats, rng):
    graphdef, params = init_denoiser(RESIDUAL, key=jax.random.key(4))
    # A trained decoder is not zero: give it weights so the network's own term shows.
    params["decoder"]["kernel"][...] = jnp.asarray(rng.normal(size=params["decoder"]["kernel"].shape), jnp.float32)
    module = nnx.merge(graphdef, params)
    cond = normalize_conditions(stats, some_conditions(rng))
    x = jnp.asarray(rng.normal(size=(K, F)), jnp.float32)
    raw, raw_logits = module(x, jnp.int32(300), cond)
    x0, logits = predict_x0(module, stats, x, jnp.int32(300), cond)
    np.testing.assert_allclose(x0 - raw, interpolation_prior(stats, cond, BezierLayout.from_controls(K, 6)), atol=1e-5)
    assert_trees_identical(logits, raw_logits)
    # Handles between control frames: the prior is the config's (linear by default), the
    # network's term the same either way; with_off_grid_prior switches a model's.
    off = cond._replace(frame=cond.frame.at[2 * J :].add(1))
    raw_off, _ = module(x, jnp.int32(300), off)
    model = BezierMotionModel(params, stats, graphdef, RESIDUAL)
    x0s = {}
    for way in ("linear", "projection"):
        switched = with_off_grid_prior(model, way)
        assert switched.config.off_grid_prior == way and switched.params is params
        x0s[way], _ = predict_x0(nnx.merge(switched.graphdef, params), stats, x, jnp.int32(300), off)
        prior = interpolation_prior(stats, off, BezierLayout.from_controls(K, 6), off_grid=way)
        np.testing.assert_allclose(x0s[way] - raw_off, prior, atol=1e-5)
    assert float(jnp.max(jnp.abs(x0s["linear"] - x0s["projection"]))) > 1e-2
    with pytest.raises(ValueError, match="'bump'"):
        with_off_grid_prior(model, "bump")
    # The paper's x₀ prediction returns the network output as it is.
    plain = nnx.merge(*init_denoiser(TINY, key=jax.random.key(4)))
    assert_trees_identical(predict_x0(plain, stats, x, jnp.int32(300), cond), plain(x, jnp.int32(300), cond))
