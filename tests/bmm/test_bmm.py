"""The Bézier Motion Model stack: diffusion schedule and DDIM, the denoiser, its data
plumbing and losses, training (resume, Ctrl-C, several seeds), sampling, and the
curve-level evaluation.

Runs without ../shared: the real data is the bundled ``DEMO_CLIP`` (40 Bandai-Namco
frames → 10 windows of 31 frames at offset 1). Models are tiny (width 32, one layer) and
every expensive object — the curve dataset, the compiled training step, the compiled
sampler — lives in a module-scoped fixture shared by several tests. Schedules, DDIM and
the losses are checked against closed forms written here in NumPy, not against the
library's own formulas.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from helpers import SHARED_DATA, assert_trees_close, assert_trees_identical, requires_shared, trees_differ

from bezmotion.assets import DEMO_CLIP
from bezmotion.bezier import BezierLayout, evaluate
from bezmotion.bmm.evaluation import (
    CurveMetricsConfig,
    curve_metrics,
    make_eval_set,
    reference_curves,
    sample_in_chunks,
)
from bezmotion.training.checkpoint import CheckpointStore
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, FEET, HIPS
from bezmotion.data.curves import MotionClips, build_curve_dataset
from bezmotion.diffusion.ddim import ddim_sample
from bezmotion.diffusion.schedule import DiffusionSchedule, cosine_schedule, respaced_timesteps
from bezmotion.bmm.losses import LossWeights, bmm_loss_terms, dense_velocity, min_snr_weight
from bezmotion.metrics import contact_accuracy, foot_skating_ratio, handles_error, mean_position_error
from bezmotion.baselines import handle_interpolation
from bezmotion.xla_options import inference_compiler_options
from flax import nnx

from bezmotion.bmm.denoiser import (
    BMMConfig,
    BMMDenoiser,
    Conditions,
    apply_denoiser,
    count_parameters,
    init_denoiser,
    sinusoidal_encoding,
)
from bezmotion.bmm.features import (
    FeatureStats,
    control_features,
    draw_intermediate_slots,
    from_tokens,
    inbetween_conditions,
    interpolation_prior,
    normalize_conditions,
    predict_x0,
    split_features,
    to_tokens,
)
from bezmotion.bmm.sampling import BezierMotionModel, Handles, SampledCurves, load_model, sample_curves, save_model
from bezmotion.bmm.train import CurveArrays, BMMTrainConfig, init_bmm_train_state, init_bmm_train_states, make_bmm_train_step
from bezmotion.training import compile_train_step, data_mesh, run_training
from bezmotion.training.optim import adamw_amsgrad_torch
from helpers import REPO_ROOT

K, J = 6, 6  # control points per 31-frame window at stride 6; characteristic joints
F = J * 12  # frame-token features
TINY = BMMConfig.cpu(width=32, ff_width=64, num_heads=2, num_layers=1, dropout=0.0)

# ------------------------------------------------------------------------------ helpers


def np_cosine_alpha_bar(T: int, s: float = 0.008, max_beta: float = 0.999) -> np.ndarray:
    """Nichol & Dhariwal (2021) cosine schedule, written out from the paper in float64."""
    f = lambda u: np.cos((u + s) / (1.0 + s) * np.pi / 2.0) ** 2  # noqa: E731
    betas = np.array([min(1.0 - f((t + 1) / T) / f(t / T), max_beta) for t in range(T)])
    return np.cumprod(1.0 - betas)


def without_key_bias(tree):
    """``tree`` with the key part of every attention input bias zeroed. That bias adds the
    same ``q·b_k`` to all of a query's logits, which softmax ignores: its true gradient is
    0, so Adam turns pure rounding noise into ±lr updates whose signs depend on how the
    computation was batched."""

    def strip(path, x):
        names = [str(getattr(p, "key", getattr(p, "name", ""))) for p in path]
        if "in_proj" in names and "bias" in names and x.shape[-1] % 3 == 0:
            w = x.shape[-1] // 3
            return x.at[..., w : 2 * w].set(0)
        return x

    return jax.tree_util.tree_map_with_path(strip, tree)


def recording(fn):
    """Wrap ``denoise(x, t)`` so every (t, x_t) DDIM feeds it is recorded (by ``jax.debug.callback``)."""
    seen: dict[int, np.ndarray] = {}

    def store(x, t):
        seen[int(t)] = np.asarray(x, np.float64)

    def denoise(x, t):
        jax.debug.callback(store, x, t)
        return fn(x, t)

    return denoise, seen


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def demo_dataset():
    """The real fixture: DEMO_CLIP cut into the 10 windows of 31 frames at offset 1."""
    clips = MotionClips.from_bvh([read_bvh(DEMO_CLIP)])
    return build_curve_dataset(clips, "bandai_namco", window=31, offset=1, progress=False)


@pytest.fixture(scope="module")
def stats(demo_dataset) -> FeatureStats:
    """Per-(joint, feature) mean and floored std computed here in NumPy (float64)."""
    feats = np.concatenate([demo_dataset.ctrl_pos, demo_dataset.ctrl_tangent, demo_dataset.ctrl_rot6d], axis=-1)
    flat = feats.astype(np.float64).reshape(-1, J, 12)
    return FeatureStats(jnp.asarray(flat.mean(0), jnp.float32), jnp.asarray(np.maximum(flat.std(0), 1e-3), jnp.float32))


@pytest.fixture(scope="module")
def tiny_model() -> SimpleNamespace:
    """Untrained tiny denoiser with one jitted single-motion apply, shared by the tests."""
    graphdef, params = init_denoiser(TINY, key=jax.random.key(1))
    apply = jax.jit(lambda p, x, t, c: apply_denoiser(graphdef, p, x, t, c))
    return SimpleNamespace(graphdef=graphdef, params=params, apply=apply)


def some_conditions(rng: np.random.Generator, handles: int = 4, valid_handles: int = 2) -> Conditions:
    """Start/end of all joints plus ``handles`` slots of which the first ``valid_handles`` are valid."""
    return inbetween_conditions(
        K,
        jnp.asarray(rng.normal(size=(J, 3)), jnp.float32),
        jnp.asarray(rng.normal(size=(J, 3)), jnp.float32),
        jnp.asarray(rng.integers(1, K - 1, handles), jnp.int32),
        jnp.asarray(rng.integers(0, J, handles), jnp.int32),
        jnp.asarray(rng.normal(size=(handles, 3)), jnp.float32),
        jnp.arange(handles) < valid_handles,
    )


# ======================================================================== schedule & DDIM


@pytest.mark.parametrize("T", [1000, 20])
def test_cosine_schedule_matches_the_closed_form(T):
    schedule = cosine_schedule(T)
    assert isinstance(schedule, DiffusionSchedule) and schedule.num_timesteps == T
    assert schedule.alpha_bar.dtype == jnp.float32
    alpha_bar = np.asarray(schedule.alpha_bar, np.float64)
    np.testing.assert_allclose(alpha_bar, np_cosine_alpha_bar(T), rtol=2e-6, atol=1e-12)
    assert np.all(np.diff(alpha_bar) < 0.0), "ᾱ must be strictly decreasing"
    assert 0.0 < alpha_bar[-1] and alpha_bar[0] < 1.0
    if T == 1000:  # the last β is clipped at 0.999, so ᾱ drops by exactly that factor
        np.testing.assert_allclose(alpha_bar[-1] / alpha_bar[-2], 0.001, rtol=1e-4)


def test_cosine_schedule_rejects_no_timesteps():
    with pytest.raises(ValueError, match="num_timesteps"):
        cosine_schedule(0)


def test_snr_and_add_noise_formulas(rng):
    schedule = cosine_schedule(1000)
    ref = np_cosine_alpha_bar(1000)
    t = jnp.asarray([0, 1, 250, 500, 999], jnp.int32)
    a = np.asarray(schedule.alpha_bar)[np.asarray(t)]  # float32: 1 − ᾱ near t = 0 loses digits
    np.testing.assert_allclose(schedule.snr(t), a / (np.float32(1.0) - a), rtol=1e-6)
    np.testing.assert_allclose(schedule.snr(t), ref[t] / (1.0 - ref[t]), rtol=1e-3)
    assert float(schedule.snr(jnp.int32(0))) > 1e3 and float(schedule.snr(jnp.int32(999))) < 1e-6
    x0 = jnp.asarray(rng.normal(size=(4, 5)), jnp.float32)
    noise = jnp.asarray(rng.normal(size=(4, 5)), jnp.float32)
    for step in (0, 400, 999):
        expected = np.sqrt(ref[step]) * np.asarray(x0) + np.sqrt(1.0 - ref[step]) * np.asarray(noise)
        np.testing.assert_allclose(schedule.add_noise(x0, jnp.int32(step), noise), expected, rtol=1e-5, atol=1e-6)


def test_respaced_timesteps_follow_guided_diffusion():
    np.testing.assert_array_equal(respaced_timesteps(1000, 10), np.arange(0, 1000, 100))
    np.testing.assert_array_equal(respaced_timesteps(1000, 3), [0, 334, 668])
    np.testing.assert_array_equal(respaced_timesteps(1000, 7), np.arange(0, 1000, 143))  # smallest stride giving 7
    np.testing.assert_array_equal(respaced_timesteps(1000, 1000), np.arange(1000))
    np.testing.assert_array_equal(respaced_timesteps(1000, 1), [0])
    for bad in (0, 1001, -3):
        with pytest.raises(ValueError, match="steps must be between 1 and 1000"):
            respaced_timesteps(1000, bad)
    with pytest.raises(ValueError, match="no even stride"):
        respaced_timesteps(1000, 999)  # ⌈1000/stride⌉ is never 999


def test_ddim_with_an_exact_oracle_walks_the_deterministic_path(rng):
    """1000 steps, x̂₀ always the truth: the sample is x₀ and every visited x_t lies on
    √ᾱ_t·x₀ + √(1−ᾱ_t)·ε̂ with the single ε̂ implied by x_T (η = 0)."""
    schedule = cosine_schedule(1000)
    ref = np.asarray(schedule.alpha_bar, np.float64)
    x0 = jnp.asarray(rng.normal(size=(3, 4)), jnp.float32)
    x_T = jnp.asarray(rng.normal(size=(3, 4)), jnp.float32)
    denoise, seen = recording(lambda x, t: x0)
    sample = ddim_sample(denoise, schedule, x_T, steps=1000)
    np.testing.assert_allclose(sample, x0, rtol=0, atol=1e-6)
    assert sorted(seen) == list(range(1000))
    eps = (np.asarray(x_T, np.float64) - np.sqrt(ref[999]) * np.asarray(x0)) / np.sqrt(1.0 - ref[999])
    for t in (999, 998, 900, 500, 100, 10, 1, 0):
        expected = np.sqrt(ref[t]) * np.asarray(x0, np.float64) + np.sqrt(1.0 - ref[t]) * eps
        np.testing.assert_allclose(seen[t], expected, atol=2e-4, err_msg=f"x_t off the DDIM path at t={t}")


def test_ddim_matches_a_numpy_reimplementation(rng):
    """10 respaced steps with a time-dependent (non-oracle) denoiser, written out in NumPy:
    the model sees the original timesteps 900, 800, …, 0 and ᾱ_prev = 1 after the last."""
    schedule = cosine_schedule(1000)
    ab = np.asarray(schedule.alpha_bar, np.float64)
    x_T = jnp.asarray(rng.normal(size=(2, 5)), jnp.float32)
    model = lambda x, t: 0.5 * x + 1e-3 * t  # noqa: E731
    denoise, seen = recording(model)
    sample = ddim_sample(denoise, schedule, x_T, steps=10)
    assert sorted(seen) == list(range(0, 1000, 100))
    x = np.asarray(x_T, np.float64)
    for t in range(900, -1, -100):
        np.testing.assert_allclose(seen[t], x, rtol=1e-4, atol=1e-5)
        a, a_prev = ab[t], (ab[t - 100] if t else 1.0)
        x0 = model(x, t)
        eps = (x - np.sqrt(a) * x0) / np.sqrt(1.0 - a)
        x = np.sqrt(a_prev) * x0 + np.sqrt(1.0 - a_prev) * eps
    np.testing.assert_allclose(sample, x, rtol=1e-4, atol=1e-5)
    # Deterministic: the same start gives the same sample, bit for bit.
    np.testing.assert_array_equal(ddim_sample(model, schedule, x_T, steps=10), sample)
    with pytest.raises(ValueError, match="steps"):
        ddim_sample(model, schedule, x_T, steps=0)


def test_ddim_overwrite_applies_to_every_prediction_and_the_final_sample(rng):
    schedule = cosine_schedule(1000)
    ab = np.asarray(schedule.alpha_bar, np.float64)
    known = jnp.asarray(rng.normal(size=(4, 3)), jnp.float32)
    x_T = jnp.asarray(rng.normal(size=(4, 3)), jnp.float32)
    garbage = lambda x, t: 50.0 * jnp.sin(3.0 * x) + t / 100.0  # noqa: E731

    # Overwrite everything: garbage never reaches the update, so DDIM walks the oracle's path.
    denoise, seen = recording(garbage)
    sample = ddim_sample(denoise, schedule, x_T, steps=10, overwrite=lambda x0: jnp.broadcast_to(known, x0.shape))
    np.testing.assert_array_equal(sample, known)
    eps = (np.asarray(x_T, np.float64) - np.sqrt(ab[900]) * np.asarray(known)) / np.sqrt(1.0 - ab[900])
    for t in range(800, -1, -100):
        np.testing.assert_allclose(seen[t], np.sqrt(ab[t]) * np.asarray(known) + np.sqrt(1.0 - ab[t]) * eps, atol=1e-4)

    # Overwrite a mask: exactly the known values there, the model's prediction elsewhere.
    mask = jnp.asarray(rng.random((4, 3)) < 0.5).at[0, 0].set(True).at[0, 1].set(False)
    fix = lambda x0: jnp.where(mask, known, x0)  # noqa: E731
    partial = ddim_sample(garbage, schedule, x_T, steps=10, overwrite=fix)
    np.testing.assert_array_equal(np.asarray(partial)[np.asarray(mask)], np.asarray(known)[np.asarray(mask)])
    assert np.all(np.asarray(partial)[~np.asarray(mask)] != np.asarray(known)[~np.asarray(mask)])

    # Without overwrite nothing is enforced: the sample is the garbage model's last prediction.
    free = ddim_sample(garbage, schedule, x_T, steps=10)
    assert np.max(np.abs(np.asarray(free) - np.asarray(known))) > 1.0


def test_ddim_has_aux_returns_the_last_steps_aux(rng):
    schedule = cosine_schedule(1000)
    x_T = jnp.asarray(rng.normal(size=(2, 3)), jnp.float32)
    model = lambda x, t: 0.9 * x  # noqa: E731
    with_aux = lambda x, t: (model(x, t), {"t": t, "first": x[0, 0]})  # noqa: E731
    sample, aux = ddim_sample(with_aux, schedule, x_T, steps=5, has_aux=True)
    np.testing.assert_array_equal(sample, ddim_sample(model, schedule, x_T, steps=5))
    assert int(aux["t"]) == 0  # the final step is t = 0
    assert aux["first"].shape == () and float(aux["first"]) != float(x_T[0, 0])


# ============================================================================ conditions


def test_conditions_grid_round_trip(rng):
    mask = jnp.asarray(rng.random((K, J)) < 0.4)
    position = jnp.asarray(rng.normal(size=(K, J, 3)), jnp.float32)
    cond = Conditions.from_grid(mask, position)
    assert cond.position.shape == (K * J, 3) and cond.valid.shape == (K * J,)
    # Slot k·J + j is (control k, joint j).
    np.testing.assert_array_equal(cond.control, np.repeat(np.arange(K), J))
    np.testing.assert_array_equal(cond.joint, np.tile(np.arange(J), K))
    back_mask, back_pos = cond.to_grid(K, J)
    np.testing.assert_array_equal(back_mask, mask)
    np.testing.assert_array_equal(np.asarray(back_pos)[np.asarray(mask)], np.asarray(position)[np.asarray(mask)])
    np.testing.assert_array_equal(np.asarray(back_pos)[~np.asarray(mask)], 0.0)
    # Batched from_grid keeps the batch axes.
    batched = Conditions.from_grid(jnp.stack([mask, ~mask]), jnp.stack([position, -position]))
    assert batched.position.shape == (2, K * J, 3) and batched.joint.shape == (2, K * J)
    np.testing.assert_array_equal(batched.valid[1], ~mask.reshape(-1))


def test_conditions_to_grid_invalid_slots_never_overwrite_valid_ones():
    cond = Conditions(
        position=jnp.asarray([[1.0, 2.0, 3.0], [9.0, 9.0, 9.0], [4.0, 5.0, 6.0], [7.0, 7.0, 7.0]]),
        joint=jnp.asarray([2, 2, 3, 3], jnp.int32),
        control=jnp.asarray([1, 1, 4, 4], jnp.int32),
        valid=jnp.asarray([True, False, True, True]),
    )
    mask, pos = cond.to_grid(K, J)
    assert int(mask.sum()) == 2 and bool(mask[1, 2]) and bool(mask[4, 3])
    np.testing.assert_array_equal(pos[1, 2], [1.0, 2.0, 3.0])  # the later invalid slot is dropped
    np.testing.assert_array_equal(pos[4, 3], [7.0, 7.0, 7.0])  # of two valid slots, the later wins


# ============================================================================== denoiser


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
    for bad in ({"width": 30, "num_heads": 4}, {"num_controls": 1}, {"dropout": 1.0}, {"num_layers": 0}, {"stride": True}):
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
        control=jnp.where(pad, jnp.asarray(rng.integers(0, K, pad.shape), jnp.int32), cond.control),
    )
    assert trees_differ(moved, cond)
    assert_trees_identical(tiny_model.apply(tiny_model.params, x, t, moved), base)

    # Garbage in padding (NaN positions, out-of-range joints and controls) cannot poison it.
    garbage = cond._replace(
        position=jnp.where(pad[:, None], jnp.nan, cond.position),
        joint=jnp.where(pad, 99, cond.joint),
        control=jnp.where(pad, -7, cond.control),
    )
    assert_trees_identical(tiny_model.apply(tiny_model.params, x, t, garbage), base)

    # More padding slots (a different number of slots): the same output.
    extra = Conditions(
        jnp.asarray(rng.normal(size=(5, 3)), jnp.float32), jnp.arange(5, dtype=jnp.int32) % J,
        jnp.arange(5, dtype=jnp.int32) % K, jnp.zeros(5, bool),
    )  # fmt: skip
    longer = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), cond, extra)
    assert_trees_close(tiny_model.apply(tiny_model.params, x, t, longer), base, tol=1e-6)

    # A valid condition does change it (position, and which joint it constrains).
    assert trees_differ(tiny_model.apply(tiny_model.params, x, t, cond._replace(valid=cond.valid.at[-1].set(True))), base)
    assert trees_differ(tiny_model.apply(tiny_model.params, x, t, cond._replace(position=cond.position.at[0, 0].add(1.0))), base)
    assert trees_differ(tiny_model.apply(tiny_model.params, x, t, cond._replace(joint=cond.joint.at[12].set((cond.joint[12] + 1) % J))), base)
    assert trees_differ(tiny_model.apply(tiny_model.params, x, t, cond._replace(control=cond.control.at[12].set(cond.control[12] % 4 + 1))), base)
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


# ====================================================================== data plumbing


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
    h_control = jnp.asarray([2, 3, 1], jnp.int32)
    h_joint = jnp.asarray([5, 0, 1], jnp.int32)
    h_pos = jnp.asarray(rng.normal(size=(3, 3)), jnp.float32).at[2].set(jnp.nan)  # a NaN in the padding
    h_valid = jnp.asarray([True, True, False])
    cond = inbetween_conditions(K, start, end, h_control, h_joint, h_pos, h_valid)
    assert cond.position.shape == (2 * J + 3, 3)
    np.testing.assert_array_equal(cond.position[:J], start)
    np.testing.assert_array_equal(cond.position[J : 2 * J], end)
    np.testing.assert_array_equal(cond.position[2 * J :2 * J + 2], h_pos[:2])
    np.testing.assert_array_equal(cond.joint, [*range(J), *range(J), 5, 0, 1])
    np.testing.assert_array_equal(cond.control, [0] * J + [K - 1] * J + [2, 3, 1])
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


# ================================================================================ losses


def perfect_prediction(rng) -> dict:
    """Targets whose feet stand still exactly where they are in contact, and a prediction
    equal to them (contact logits ±1000, so the probabilities are exactly 0 or 1)."""
    layout = BezierLayout.from_controls(K, 6)
    pos = rng.normal(scale=30.0, size=(K, J, 3))
    tan = rng.normal(scale=5.0, size=(K, J, 3))
    left, right = FEET
    # Left foot planted over segments 0 and 1 (controls 0, 1), then moving.
    pos[:3, left] = pos[0, left]
    tan[:3, left] = 0.0
    # Right foot moving, then planted over segments 3 and 4 (controls 3, 4, and 5 which looks back).
    pos[3:, right] = pos[3, right]
    tan[3:, right] = 0.0
    contacts = np.zeros((K, 2), bool)
    contacts[:2, 0] = True
    contacts[3:, 1] = True
    rot = rng.normal(size=(K, J, 6))
    pos, tan, rot = (jnp.asarray(a, jnp.float32) for a in (pos, tan, rot))
    dense = jnp.moveaxis(evaluate(layout, jnp.moveaxis(pos, 1, 0), jnp.moveaxis(tan, 1, 0)), 0, 1)
    mask = jnp.zeros((K, J), bool).at[0].set(True).at[-1].set(True).at[2, 1].set(True).at[3, 4].set(True)
    contacts = jnp.asarray(contacts)
    return {
        "layout": layout, "pred_pos": pos, "pred_tangent": tan, "pred_rot6d": rot,
        "contact_logits": jnp.where(contacts, 1000.0, -1000.0), "target_pos": pos, "target_tangent": tan,
        "target_rot6d": rot, "target_contacts": contacts, "dense_target": dense, "condition_mask": mask,
    }  # fmt: skip


def terms_of(case: dict) -> dict[str, float]:
    return {k: float(v) for k, v in bmm_loss_terms(**case).items()}


def test_loss_terms_vanish_for_a_perfect_prediction(rng):
    case = perfect_prediction(rng)
    terms = terms_of(case)
    assert set(terms) == {"position", "tangent", "orientation", "velocity", "dense_position", "condition", "contact", "skate"}
    for name, value in terms.items():
        assert value < 1e-12, f"{name} = {value} for a perfect prediction"


def test_each_loss_term_responds_to_its_own_perturbation(rng):
    case = perfect_prediction(rng)
    num_cond = int(case["condition_mask"].sum())
    zero = lambda terms, names: all(terms[n] < 1e-12 for n in names)  # noqa: E731

    # Position of an unconditioned control point (hips, control 2): 10 cm = 0.1 m.
    t = terms_of({**case, "pred_pos": case["pred_pos"].at[2, HIPS, 0].add(10.0)})
    assert t["position"] == pytest.approx(0.01 / (K * J * 3), rel=1e-4)
    assert t["dense_position"] > 0 and t["velocity"] > 0
    assert zero(t, ["tangent", "orientation", "condition", "contact", "skate"])

    # Position of a conditioned one (joint 1 at control 2).
    t = terms_of({**case, "pred_pos": case["pred_pos"].at[2, 1, 0].add(10.0)})
    assert t["condition"] == pytest.approx(0.01 / (3 * num_cond), rel=1e-4)
    assert t["position"] == pytest.approx(0.01 / (K * J * 3), rel=1e-4)

    # Tangent.
    t = terms_of({**case, "pred_tangent": case["pred_tangent"].at[1, 2, 2].add(10.0)})
    assert t["tangent"] == pytest.approx(0.01 / (K * J * 3), rel=1e-4)
    assert t["dense_position"] > 0 and t["velocity"] > 0
    assert zero(t, ["position", "orientation", "condition", "contact"])

    # Orientation (unitless).
    t = terms_of({**case, "pred_rot6d": case["pred_rot6d"].at[4, 3, 5].add(0.5)})
    assert t["orientation"] == pytest.approx(0.25 / (K * J * 6), rel=1e-4)
    assert zero(t, ["position", "tangent", "velocity", "dense_position", "condition", "contact", "skate"])

    # Dense target: a jump at one frame.
    t = terms_of({**case, "dense_target": case["dense_target"].at[14, 0, 1].add(10.0)})
    assert t["dense_position"] == pytest.approx(0.01 / (31 * J * 3), rel=1e-4)
    assert t["velocity"] == pytest.approx(2 * 0.01 / (30 * J * 3), rel=1e-4)  # two velocities change
    assert zero(t, ["position", "tangent", "orientation", "condition", "contact", "skate"])

    # Contact where the foot is planted but predicted off: contact only, no skating.
    t = terms_of({**case, "contact_logits": case["contact_logits"].at[0, 0].set(-1000.0)})
    assert t["contact"] == pytest.approx(1.0 / (K * 2))
    assert zero(t, ["skate", "position", "velocity"])

    # Contact predicted where the left foot moves (control 3, frame 18 → 19): skating.
    t = terms_of({**case, "contact_logits": case["contact_logits"].at[3, 0].set(1000.0)})
    assert t["contact"] == pytest.approx(1.0 / (K * 2))
    p3, p4 = np.asarray(case["pred_pos"][3:5, FEET[0]], np.float64)
    t3, t4 = np.asarray(case["pred_tangent"][3:5, FEET[0]], np.float64)
    u = 1.0 / 6.0
    bez = (1 - u) ** 3 * p3 + 3 * (1 - u) ** 2 * u * (p3 + t3) + 3 * (1 - u) * u**2 * (p4 - t4) + u**3 * p4
    v = (bez - p3) / 100.0
    assert t["skate"] == pytest.approx(np.sum(v**2) / (K * 2 * 3), rel=1e-3)
    assert t["skate"] > 1e-6


def test_loss_weights_are_the_papers_table_5():
    w = LossWeights()
    assert dataclasses.asdict(w) == {
        "position": 1.0, "tangent": 5.0, "orientation": 1.0, "velocity": 10.0,
        "dense_position": 1.0, "condition": 5.0, "contact": 0.01, "skate": 10.0,
    }  # fmt: skip
    terms = {name: jnp.float32(i + 1) for i, name in enumerate(dataclasses.asdict(w))}
    expected = sum(getattr(w, name) * (i + 1) for i, name in enumerate(dataclasses.asdict(w)))
    assert float(w.total(terms)) == pytest.approx(expected)


def test_min_snr_weight_and_dense_velocity(rng):
    snr = jnp.asarray([0.01, 1.0, 5.0, 7.0, 1e6])
    np.testing.assert_allclose(min_snr_weight(snr, 5.0), [0.01, 1.0, 5.0, 5.0, 5.0])
    np.testing.assert_array_equal(min_snr_weight(snr, None), np.ones(5))
    schedule = cosine_schedule(1000)
    assert float(min_snr_weight(schedule.snr(jnp.int32(0)), 5.0)) == 5.0
    assert float(min_snr_weight(schedule.snr(jnp.int32(999)), 5.0)) < 1e-6
    pos = jnp.asarray(rng.normal(size=(2, 7, J, 3)), jnp.float32)
    vel = dense_velocity(pos)
    assert vel.shape == (2, 6, J, 3)
    np.testing.assert_allclose(vel[1, 3], pos[1, 4] - pos[1, 3], rtol=1e-6)


# ============================================================================== training

TRAIN = BMMTrainConfig(batch_size=8, learning_rate=1e-3, ema_decay=0.9)


def committed(step):
    """Run a compiled step on device-committed states. States restored by orbax are
    committed; without this, the first step on one would compile the step a second time."""
    device = jax.devices()[0]
    return lambda state, data: step(jax.device_put(state, device), data)


@pytest.fixture(scope="module")
def kit(demo_dataset, stats) -> SimpleNamespace:
    """The tiny model's compiled training step on the DEMO_CLIP curves (compiled once)."""
    assert len(demo_dataset) == 10
    graphdef, state0 = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(0))
    step_fn = make_bmm_train_step(graphdef, TINY, TRAIN, stats)
    step = committed(compile_train_step(step_fn, num_seeds=None))
    data = CurveArrays.from_dataset(demo_dataset)
    return SimpleNamespace(graphdef=graphdef, state0=state0, step_fn=step_fn, step=step, data=data)


@pytest.fixture(scope="module")
def trajectory(kit) -> list:
    """``states[k]``: the state after k steps from ``kit.state0``, by calling the step by hand."""
    states = [kit.state0]
    for _ in range(6):
        states.append(kit.step(states[-1], kit.data)[0])
    return states


def test_train_config_validation():
    for bad in ({"batch_size": 0}, {"learning_rate": 0.0}, {"weight_decay": -1.0}, {"condition_dropout": 1.0}, {"ema_decay": 1.0}):
        with pytest.raises(ValueError):
            BMMTrainConfig(**bad)
    assert BMMTrainConfig().learning_rate == 1e-4 and BMMTrainConfig().batch_size == 64 and BMMTrainConfig().min_snr_gamma == 5.0


def test_optimizer_is_adamw_with_amsgrad_and_decoupled_decay():
    config = BMMTrainConfig(learning_rate=0.1, weight_decay=0.5)
    opt = adamw_amsgrad_torch(config.learning_rate, config.weight_decay)
    params = {"w": jnp.asarray([1.0, -2.0, 3.0])}
    grads = {"w": jnp.asarray([0.5, -0.1, 0.0])}
    updates, _ = opt.update(grads, opt.init(params), params)
    # First Adam step: m̂/√v̂ = sign(g); the decay is added unscaled, then everything × −lr.
    np.testing.assert_allclose(updates["w"], -0.1 * (np.sign([0.5, -0.1, 0.0]) + 0.5 * np.array([1.0, -2.0, 3.0])), rtol=1e-5)
    # Many steps against a NumPy transcription of torch.optim.AdamW(amsgrad=True): decay
    # p ← p(1 − lr·wd), then the step with the max of the *raw* second moment, corrected after.
    lr, wd = 0.1, 0.5
    rng = np.random.default_rng(3)
    p = np.array([1.0, -2.0, 3.0])
    m, v, v_max = np.zeros(3), np.zeros(3), np.zeros(3)
    params, state = {"w": jnp.asarray(p, jnp.float32)}, opt.init(params)
    for t in range(1, 41):
        g = rng.normal(size=3) * (30.0 if t == 1 else 1.0)  # one large early gradient
        updates, state = opt.update({"w": jnp.asarray(g, jnp.float32)}, state, params)
        params = optax.apply_updates(params, updates)
        p = p * (1.0 - lr * wd)
        m, v = 0.9 * m + 0.1 * g, 0.999 * v + 0.001 * g * g
        v_max = np.maximum(v_max, v)
        p = p - lr * (m / (1 - 0.9**t)) / (np.sqrt(v_max / (1 - 0.999**t)) + 1e-8)
    np.testing.assert_allclose(np.asarray(params["w"]), p, rtol=1e-5, atol=1e-6)


def test_data_mesh_is_none_on_one_device():
    n = len(jax.local_devices())
    mesh = data_mesh()
    if n == 1:
        assert mesh is None
    else:  # e.g. under XLA_FLAGS=--xla_force_host_platform_device_count=2
        assert mesh.axis_names == ("data",) and mesh.devices.size == n


def test_train_step_updates_everything_consistently(kit, trajectory):
    s0, s1 = trajectory[0], trajectory[1]
    assert int(s1.step) == 1 and int(s0.step) == 0
    assert trees_differ(s1.params, s0.params) and trees_differ([s1.key], [s0.key])
    assert_trees_close(s1.ema, jax.tree.map(lambda e, p: 0.9 * e + 0.1 * p, s0.ema, s1.params), tol=1e-6)
    _, metrics = kit.step(s0, kit.data)
    names = {"loss", "grad_norm", "position", "tangent", "orientation", "velocity", "dense_position", "condition", "contact", "skate"}
    assert set(metrics) == names
    assert all(np.isfinite(float(v)) for v in metrics.values())
    # Pure: the same state gives the same next state, bit for bit.
    assert_trees_identical(kit.step(s0, kit.data)[0], s1)


def test_training_lowers_the_loss(kit):
    """60 steps of the tiny model on the real curves: the loss on fixed batches/noise drops."""
    eval_keys = [jax.random.key(100 + i) for i in range(4)]

    def eval_loss(state):
        return np.mean([float(kit.step(dataclasses.replace(state, key=k), kit.data)[1]["loss"]) for k in eval_keys])

    before = eval_loss(kit.state0)
    state, history = run_training(kit.step, kit.state0, kit.data, num_steps=60, progress=False, log_every=10)
    after = eval_loss(state)
    assert int(state.step) == 60
    assert [h["step"] for h in history] == [10, 20, 30, 40, 50, 60]
    assert all(np.isfinite(v) for h in history for v in h.values())
    assert after < 0.5 * before, f"loss {before:.4f} → {after:.4f}"


def test_checkpoint_resume_is_bit_identical(kit, trajectory, tmp_path):
    # Half the run (a periodic checkpoint at 2, the final one at 3) ...
    config = {"model": dataclasses.asdict(TINY), "note": "resume"}
    store = CheckpointStore(tmp_path / "resume")
    half, history = run_training(
        kit.step, kit.state0, kit.data, num_steps=3, store=store, checkpoint_every=2, config=config, progress=False, log_every=1
    )
    assert_trees_identical(half, trajectory[3])
    assert [h["step"] for h in history] == [1, 2, 3]
    assert store.latest_step() == 3 and store.config() == config
    fresh = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(99))[1]  # another seed: restore must replace it all
    assert_trees_identical(store.restore(fresh, step=2), trajectory[2])
    restored = store.restore(fresh)
    assert_trees_identical(restored, trajectory[3])
    assert jnp.issubdtype(restored.key.dtype, jax.dtypes.prng_key)
    # ... then, as a new process would, from a fresh state and the same folder, to the end.
    resumed, _ = run_training(kit.step, fresh, kit.data, num_steps=6, store=store, progress=False)
    assert_trees_identical(resumed, trajectory[6])
    assert store.latest_step() == 6
    # Already done: nothing more runs, the stored state comes back.
    again, history = run_training(kit.step, fresh, kit.data, num_steps=6, store=store, progress=False)
    assert_trees_identical(again, trajectory[6]) and history == []
    store.close()
    empty = CheckpointStore(tmp_path / "empty")
    assert empty.latest_step() is None and empty.config() is None
    with pytest.raises(FileNotFoundError):
        empty.restore(fresh)
    empty.close()


def test_ctrl_c_saves_the_held_state_and_resume_completes_identically(kit, trajectory, tmp_path):
    def interrupted_at(k):
        def step(state, data):
            if int(state.step) == k:
                raise KeyboardInterrupt
            return kit.step(state, data)

        return step

    store = CheckpointStore(tmp_path / "run")
    with pytest.raises(KeyboardInterrupt):
        run_training(interrupted_at(4), kit.state0, kit.data, num_steps=6, store=store, checkpoint_every=1000, progress=False)
    assert store.latest_step() == 4
    fresh = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(98))[1]
    assert_trees_identical(store.restore(fresh), trajectory[4])
    resumed, _ = run_training(kit.step, fresh, kit.data, num_steps=6, store=store, progress=False)
    assert_trees_identical(resumed, trajectory[6])
    store.close()


def test_sigterm_checkpoints_at_a_step_boundary_like_ctrl_c(kit, trajectory, tmp_path):
    def terminated_after(k):
        def step(state, data):
            new = kit.step(state, data)
            if int(new[0].step) == k:  # as `kill` from another shell would, mid-run
                os.kill(os.getpid(), signal.SIGTERM)
            return new

        return step

    before = signal.getsignal(signal.SIGTERM)
    store = CheckpointStore(tmp_path / "run")
    with pytest.raises(KeyboardInterrupt, match="signal"):
        run_training(terminated_after(3), kit.state0, kit.data, num_steps=6, store=store, checkpoint_every=1000, progress=False)
    assert signal.getsignal(signal.SIGTERM) == before  # the handler is gone again
    assert store.latest_step() == 3
    fresh = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(98))[1]
    resumed, _ = run_training(kit.step, fresh, kit.data, num_steps=6, store=store, progress=False)
    assert_trees_identical(resumed, trajectory[6])
    store.close()


def test_vmapped_seeds_match_single_seed_runs(kit, tmp_path):
    seeds = (5, 6)
    graphdef, stacked = init_bmm_train_states(TINY, TRAIN, list(seeds))
    assert graphdef == kit.graphdef
    vstep = committed(compile_train_step(kit.step_fn, num_seeds=len(seeds)))
    store = CheckpointStore(tmp_path / "seeds")
    multi, history = run_training(vstep, stacked, kit.data, num_steps=1, store=store, progress=False, log_every=1)
    np.testing.assert_array_equal(multi.step, [1, 1])
    _, multi_metrics = vstep(multi, kit.data)
    assert len(history) == 1 and np.isfinite(history[0]["loss"])
    singles = []
    for i, seed in enumerate(seeds):
        _, single = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(seed))
        assert_trees_identical(jax.tree.map(lambda a, i=i: a[i], stacked), single)
        single, metrics = kit.step(single, kit.data)
        # One step matches to float rounding. (Not more steps: Adam's m̂/(√v̂ + ε) turns
        # rounding-level differences of gradients near ε into visible parameter differences.)
        assert_trees_close(without_key_bias(jax.tree.map(lambda a, i=i: a[i], multi)), without_key_bias(single), tol=1e-6)
        assert history[0]["loss"] != pytest.approx(float(metrics["loss"]))  # the history averages the seeds
        _, metrics = kit.step(single, kit.data)
        np.testing.assert_allclose(multi_metrics["loss"][i], metrics["loss"], rtol=1e-5)
        singles.append(single)
    assert trees_differ(singles[0].params, singles[1].params)
    np.testing.assert_allclose(history[0]["loss"], np.mean([float(s) for s in vstep(stacked, kit.data)[1]["loss"]]), rtol=1e-6)
    # The stacked state (keys included) survives a checkpoint round trip.
    assert_trees_identical(store.restore(stacked), multi)
    store.close()
    with pytest.raises(ValueError, match="seed"):
        init_bmm_train_states(TINY, TRAIN, [])


# ============================================================================== sampling


@pytest.fixture(scope="module")
def model(stats) -> BezierMotionModel:
    graphdef, params = init_denoiser(TINY, key=jax.random.key(11))
    return BezierMotionModel(params, stats, graphdef, TINY)


@pytest.fixture(scope="module")
def motions(demo_dataset) -> SimpleNamespace:
    """Two motions from the demo windows, moved away from the origin in XZ, with handles
    (the second motion has one padding slot)."""
    offset = np.array([150.0, 3.0, -230.0], np.float32)
    rows = [0, 7]
    pos = demo_dataset.ctrl_pos[rows] + offset
    handles = Handles(
        joint=jnp.asarray([[2, 4, 0], [1, 5, 3]], jnp.int32),
        control=jnp.asarray([[1, 2, 4], [3, 2, 1]], jnp.int32),
        position=jnp.asarray(np.stack([pos[0, [1, 2, 4], [2, 4, 0]] + 5.0, pos[1, [3, 2, 1], [1, 5, 3]] - 7.0]), jnp.float32),
        valid=jnp.asarray([[True, True, True], [True, True, False]]),
    )
    return SimpleNamespace(start=jnp.asarray(pos[:, 0]), end=jnp.asarray(pos[:, -1]), handles=handles)


def grid_errors(curves: SampledCurves, m: SimpleNamespace) -> np.ndarray:
    """All constraint residuals (start, end, valid handles) as one array."""
    pos = np.asarray(curves.ctrl_pos)
    res = [pos[:, 0] - np.asarray(m.start), pos[:, -1] - np.asarray(m.end)]
    h = m.handles
    for b in range(pos.shape[0]):
        for s in range(h.valid.shape[1]):
            if bool(h.valid[b, s]):
                res.append(pos[b, int(h.control[b, s]), int(h.joint[b, s])] - np.asarray(h.position[b, s]))
    return np.concatenate([np.ravel(r) for r in res])


@pytest.fixture(scope="module")
def sampled(model, motions) -> SampledCurves:
    return sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5)


def test_sampling_hits_start_end_and_handles_exactly(model, motions, sampled):
    assert sampled.ctrl_pos.shape == (2, K, J, 3) and sampled.ctrl_tangent.shape == (2, K, J, 3)
    assert sampled.ctrl_rot6d.shape == (2, K, J, 6) and sampled.contacts.shape == (2, K, 2)
    assert all(np.all(np.isfinite(a)) for a in sampled)
    assert np.all((np.asarray(sampled.contacts) >= 0) & (np.asarray(sampled.contacts) <= 1))
    assert np.all(grid_errors(sampled, motions) == 0.0)
    h = motions.handles
    assert float(handles_error(sampled.ctrl_pos, h.control, h.joint, h.position, h.valid)) == 0.0
    # The padding slot is not a constraint: the curve does not go through it.
    assert np.linalg.norm(np.asarray(sampled.ctrl_pos[1, 1, 3]) - np.asarray(h.position[1, 2])) > 1e-3
    # Unconstrained points sit near the motion (the start's XZ offset is undone), not at the origin.
    hips_mid = np.asarray(sampled.ctrl_pos[:, 2, HIPS])
    assert np.all(np.abs(hips_mid[:, [0, 2]] - np.asarray(motions.start[:, HIPS])[:, [0, 2]]) < 100.0)
    # Same key, same curves; another key, other curves.
    again = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5)
    assert_trees_identical(again, sampled)
    other = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(22), steps=5)
    assert trees_differ(other.ctrl_tangent, sampled.ctrl_tangent)


def test_sampling_without_overwrite_does_not_enforce_the_constraints(model, motions, sampled):
    free = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, overwrite=False)
    errors = np.abs(grid_errors(free, motions))
    assert np.all(np.isfinite(errors)) and errors.max() > 1.0 and np.mean(errors == 0.0) < 0.5


def test_batched_sampling_equals_per_motion_calls(model, motions, sampled):
    keys = jax.random.split(jax.random.key(21), 2)
    for i in range(2):
        one = sample_curves(
            model, motions.start[i], motions.end[i], jax.tree.map(lambda a, i=i: a[i], motions.handles), key=keys[i], steps=5
        )
        assert one.ctrl_pos.shape == (K, J, 3)
        assert_trees_close(one, jax.tree.map(lambda a, i=i: a[i], sampled), tol=1e-5)


def test_guided_sampling_runs_and_still_hits_the_constraints(model, motions, sampled):
    guided = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, guidance=2.5)
    assert all(np.all(np.isfinite(a)) for a in guided)
    assert np.all(grid_errors(guided, motions) == 0.0)
    # The unconditional pass pulls the sample away from the conditional one (by centimetres,
    # not by the rounding of a differently batched computation).
    assert np.max(np.abs(np.asarray(guided.ctrl_tangent) - np.asarray(sampled.ctrl_tangent))) > 0.5


def test_sample_curves_input_errors(model, motions):
    with pytest.raises((ValueError, TypeError)):  # TypeError: the jaxtyping hook of the test session
        sample_curves(model, motions.start[:, :5], motions.end[:, :5], motions.handles, key=jax.random.key(0))
    with pytest.raises(ValueError, match="batched like start"):
        sample_curves(model, motions.start, motions.end, jax.tree.map(lambda a: a[0], motions.handles), key=jax.random.key(0))


def test_handles_from_frames():
    h = Handles.from_frames(["left_hand", 5, "hips"], [6, 12, 24], np.arange(9.0).reshape(3, 3), config=TINY)
    np.testing.assert_array_equal(h.joint, [CHARACTERISTIC_JOINTS.index("left_hand"), 5, HIPS])
    np.testing.assert_array_equal(h.control, [1, 2, 4])
    np.testing.assert_array_equal(h.position, np.arange(9.0).reshape(3, 3))
    assert h.position.dtype == jnp.float32 and bool(h.valid.all())
    empty = Handles.empty((2,))
    assert empty.position.shape == (2, 1, 3) and not bool(empty.valid.any())

    pos = np.zeros((1, 3))
    with pytest.raises(ValueError, match="control frames"):
        Handles.from_frames(["head"], [7], pos, config=TINY)
    with pytest.raises(ValueError, match="control frames"):
        Handles.from_frames(["head"], [36], pos, config=TINY)  # a multiple of 6 past the window
    for frame in (-6, 0, 30):  # the first and last frames are the start and end poses
        with pytest.raises(ValueError, match=rf"intermediate control frames.*got {frame}"):
            Handles.from_frames(["head"], [frame], pos, config=TINY)
    with pytest.raises(ValueError, match="unknown joint 'LeftHand'"):
        Handles.from_frames(["LeftHand"], [6], pos, config=TINY)
    with pytest.raises(ValueError, match="out of range"):
        Handles.from_frames([6], [6], pos, config=TINY)
    with pytest.raises(ValueError, match="one frame and one"):
        Handles.from_frames(["head", "hips"], [6, 12], pos, config=TINY)
    with pytest.raises(ValueError, match="one frame and one"):
        Handles.from_frames(["head"], [6, 12], pos, config=TINY)
    with pytest.raises((ValueError, TypeError)):  # TypeError: the jaxtyping hook of the test session
        Handles.from_frames(["head"], [6], np.zeros((1, 2)), config=TINY)
    with pytest.raises(ValueError, match="finite"):
        Handles.from_frames(["head"], [6], np.array([[0.0, np.nan, 1.0]]), config=TINY)


def test_save_and_load_model_round_trip(model, tmp_path, rng):
    save_model(tmp_path / "bmm", model)
    loaded = load_model(tmp_path / "bmm")
    assert loaded.config == model.config
    assert_trees_identical(loaded.params, model.params)
    assert_trees_identical(loaded.stats, model.stats)
    x = jnp.asarray(rng.normal(size=(K, F)), jnp.float32)
    cond = some_conditions(rng)
    assert_trees_identical(
        apply_denoiser(loaded.graphdef, loaded.params, x, jnp.int32(3), cond),
        apply_denoiser(model.graphdef, model.params, x, jnp.int32(3), cond),
    )
    with pytest.raises(FileNotFoundError, match="not a saved BMM"):
        load_model(tmp_path / "nothing")


# ============================================================== reference and metrics


def test_handle_interpolation_by_hand():
    target = jnp.asarray(np.random.default_rng(3).normal(size=(K, 2, 3)), jnp.float32)
    mask = jnp.zeros((K, 2), bool).at[0].set(True).at[-1].set(True).at[3, 0].set(True)
    pos, tangent = handle_interpolation(mask, target)
    p, tg = np.asarray(pos, np.float64), np.asarray(target, np.float64)
    for k, j in zip(*np.nonzero(np.asarray(mask)), strict=True):
        np.testing.assert_array_equal(pos[k, j], target[k, j])  # exact through the known points
    # Joint 0: known at 0, 3, 5 → linear in control index on each side.
    np.testing.assert_allclose(p[1, 0], tg[0, 0] + (tg[3, 0] - tg[0, 0]) / 3, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(p[2, 0], tg[0, 0] + 2 * (tg[3, 0] - tg[0, 0]) / 3, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(p[4, 0], (tg[3, 0] + tg[5, 0]) / 2, rtol=1e-5, atol=1e-6)
    # Joint 1: known only at the ends.
    for k in range(1, 5):
        np.testing.assert_allclose(p[k, 1], tg[0, 1] + k * (tg[5, 1] - tg[0, 1]) / 5, rtol=1e-5, atol=1e-6)
    # Catmull-Rom tangents, one-sided at the ends.
    t_ref = np.concatenate([(p[1:2] - p[:1]) / 3, (p[2:] - p[:-2]) / 6, (p[-1:] - p[-2:-1]) / 3])
    np.testing.assert_allclose(tangent, t_ref, rtol=1e-5, atol=1e-5)
    # Batched.
    bpos, _ = handle_interpolation(jnp.stack([mask, mask]), jnp.stack([target, target + 1.0]))
    np.testing.assert_allclose(bpos[1], pos + 1.0, rtol=1e-5, atol=1e-5)


def test_handles_error_by_hand():
    ctrl = jnp.zeros((K, J, 3)).at[4, 2].set(jnp.asarray([1.0, 1.0, 1.0]))
    control = jnp.asarray([2, 4, 1], jnp.int32)
    joint = jnp.asarray([1, 2, 0], jnp.int32)
    position = jnp.asarray([[3.0, 4.0, 0.0], [1.0, 1.0, 1.0], [100.0, 0.0, 0.0]])
    assert float(handles_error(ctrl, control, joint, position, jnp.asarray([True, True, False]))) == pytest.approx(2.5)
    assert float(handles_error(ctrl, control, joint, position, jnp.asarray([True, True, True]))) == pytest.approx(35.0)
    assert float(handles_error(ctrl, control, joint, position, jnp.zeros(3, bool))) == 0.0


def test_foot_skating_ratio_by_hand():
    frames, fps = 11, 30.0
    x = np.arange(frames) * 1.0  # 1 cm per frame = 30 cm/s > 7.5 cm/s

    def feet(left_y=1.0, right_y=1.0, speed=1.0, axis=0):
        f = np.zeros((frames, 2, 3))
        f[:, :, axis] = (x * speed)[:, None]
        f[:, 0, 1] += left_y
        f[:, 1, 1] += right_y
        return jnp.asarray(f, jnp.float32)

    assert float(foot_skating_ratio(feet(), fps)) == 1.0  # both low and fast
    assert float(foot_skating_ratio(feet(left_y=20.0), fps)) == 0.0  # one foot lifted
    assert float(foot_skating_ratio(feet(speed=0.1), fps)) == 0.0  # 3 cm/s: slow
    assert float(foot_skating_ratio(feet(axis=2), fps)) == 1.0  # Z is horizontal too
    assert float(foot_skating_ratio(feet(speed=0.1), 300.0)) == 1.0  # 30 cm/s at 300 fps
    assert float(foot_skating_ratio(feet(left_y=21.0, right_y=21.0), fps, floor_height=20.0)) == 1.0
    half = np.array(feet())
    half[6:, :, 0] = half[5, :, 0]  # stops after frame 5: 5 of 10 steps skate
    assert float(foot_skating_ratio(jnp.asarray(half), fps)) == pytest.approx(0.5)
    # Only one foot sliding is not skating.
    one = np.array(feet())
    one[:, 1, 0] = 0.0
    assert float(foot_skating_ratio(jnp.asarray(one), fps)) == 0.0


def test_contact_accuracy_and_mean_position_error():
    prob = jnp.asarray([[0.7, 0.2], [0.4, 0.9]])
    true = jnp.asarray([[True, False], [True, False]])
    assert float(contact_accuracy(prob, true)) == pytest.approx(0.5)
    pred = jnp.zeros((2, 3, 1, 3)).at[0, 0, 0].set(jnp.asarray([3.0, 4.0, 0.0]))
    assert float(mean_position_error(pred, jnp.zeros((2, 3, 1, 3)))) == pytest.approx(5.0 / 6.0)


def test_ground_truth_metrics_report_the_mocap_and_its_fitted_curves(demo_dataset, eval_set):
    from bezmotion.bmm.evaluation import ground_truth_metrics

    config = CurveMetricsConfig(BezierLayout.from_controls(K, 6), demo_dataset.fps, 0.0)
    gt = ground_truth_metrics(config, eval_set)
    fitted = SampledCurves(eval_set.ctrl_pos, eval_set.ctrl_tangent, jnp.zeros((*eval_set.ctrl_pos.shape[:-1], 6)), eval_set.ctrl_contacts.astype(jnp.float32))
    as_model = curve_metrics(config, fitted, eval_set, eval_set.handles)
    assert gt["fitted_curves"]["dense_error_cm"] == pytest.approx(as_model["dense_error_cm"], rel=1e-6)
    assert gt["fitted_curves"]["foot_skating_ratio"] == pytest.approx(as_model["foot_skating_ratio"], rel=1e-6)
    # Fitted with pinned positions: the curves pass through the mocap's control frames,
    # and in between they stay within the fit's sub-centimetre error.
    assert 0.0 < gt["fitted_curves"]["dense_error_cm"] < 0.5 and as_model["handles_error_cm"] < 1e-4
    dense_feet = eval_set.dense_pos[..., list(FEET), :]
    assert gt["foot_skating_ratio"] == pytest.approx(float(foot_skating_ratio(dense_feet, demo_dataset.fps, floor_height=0.0)))


@pytest.fixture(scope="module")
def eval_set(demo_dataset):
    return make_eval_set(demo_dataset, key=jax.random.key(5))


def test_make_eval_set(demo_dataset, eval_set):
    es = eval_set
    ds = demo_dataset
    assert_trees_identical(make_eval_set(ds, key=jax.random.key(5)), es)
    np.testing.assert_array_equal(es.start, ds.ctrl_pos[:, 0])
    np.testing.assert_array_equal(es.end, ds.ctrl_pos[:, -1])
    np.testing.assert_array_equal(es.ctrl_contacts, ds.ctrl_contacts)
    np.testing.assert_array_equal(es.dense_pos, ds.dense_pos)
    np.testing.assert_array_equal(es.ctrl_pos, ds.ctrl_pos)
    np.testing.assert_array_equal(es.ctrl_tangent, ds.ctrl_tangent)
    h = es.handles
    assert h.control.shape == (10, 4)
    control, joint, valid = map(np.asarray, (h.control, h.joint, h.valid))
    assert control.min() >= 1 and control.max() <= K - 2
    counts = valid.sum(1)
    assert counts.min() >= 1 and counts.max() <= 4
    rows = np.arange(10)[:, None]
    np.testing.assert_array_equal(h.position, ds.ctrl_pos[rows, control, joint])
    noise = np.asarray(es.handles_ood.position) - np.asarray(h.position)
    assert np.all(np.abs(noise) <= 16.0 + 1e-3) and np.abs(noise).max() > 4.0
    np.testing.assert_array_equal(es.handles_ood.control, h.control)
    np.testing.assert_array_equal(es.handles_ood.valid, h.valid)
    # A subset of windows, still deterministic.
    sub = make_eval_set(ds, key=jax.random.key(5), num_windows=4)
    assert sub.start.shape == (4, J, 3)
    starts = [int(np.flatnonzero(np.all(ds.ctrl_pos[:, 0] == s, axis=(1, 2)))[0]) for s in np.asarray(sub.start)]
    assert starts == sorted(set(starts))
    with pytest.raises(ValueError, match="max_handles"):
        make_eval_set(ds, key=jax.random.key(5), max_handles=0)


def test_reference_curves_and_curve_metrics(demo_dataset, eval_set):
    es = eval_set
    ref = reference_curves(es, es.handles, K)
    assert ref.ctrl_pos.shape == (10, K, J, 3) and ref.contacts.shape == (10, K, 2)
    np.testing.assert_array_equal(ref.ctrl_pos[:, 0], es.start)
    np.testing.assert_array_equal(ref.ctrl_pos[:, -1], es.end)
    h = es.handles
    assert float(handles_error(ref.ctrl_pos, h.control, h.joint, h.position, h.valid)) == 0.0
    # OOD handles are hit exactly as well (the reference trusts them).
    ood = reference_curves(es, es.handles_ood, K)
    o = es.handles_ood
    assert float(handles_error(ood.ctrl_pos, o.control, o.joint, o.position, o.valid)) == 0.0
    # An invalid slot is ignored: moving it changes nothing.
    moved = h._replace(position=jnp.where(h.valid[..., None], h.position, h.position + 50.0))
    np.testing.assert_array_equal(reference_curves(es, moved, K).ctrl_pos, ref.ctrl_pos)

    config = CurveMetricsConfig(demo_dataset.layout, demo_dataset.fps, floor_height=0.0)
    metrics = curve_metrics(config, ref, es, es.handles)
    assert set(metrics) == {"handles_error_cm", "dense_error_cm", "foot_skating_ratio", "contact_accuracy"}
    assert metrics["handles_error_cm"] == 0.0
    assert 0.0 <= metrics["foot_skating_ratio"] <= 1.0
    # Contacts of 0.5 count as "no contact".
    assert metrics["contact_accuracy"] == pytest.approx(float(np.mean(~demo_dataset.ctrl_contacts)))
    # The fitted curves themselves: handles exact, dense error = the fit residual (small), contacts right.
    fitted = SampledCurves(
        jnp.asarray(demo_dataset.ctrl_pos), jnp.asarray(demo_dataset.ctrl_tangent),
        jnp.asarray(demo_dataset.ctrl_rot6d), jnp.asarray(demo_dataset.ctrl_contacts, jnp.float32),
    )  # fmt: skip
    own = curve_metrics(config, fitted, es, es.handles)
    assert own["handles_error_cm"] == 0.0 and own["contact_accuracy"] == 1.0
    assert own["dense_error_cm"] < 2.0 and own["dense_error_cm"] < metrics["dense_error_cm"]


def test_sample_in_chunks(eval_set):
    calls = []

    def sample(start, end, handles, key):
        calls.append(start.shape[0])
        tag = jax.random.uniform(key, ())
        c = start.shape[0]
        return SampledCurves(
            jnp.broadcast_to(start[:, None], (c, K, J, 3)), jnp.zeros((c, K, J, 3)),
            jnp.zeros((c, K, J, 6)), jnp.full((c, K, 2), tag),
        )  # fmt: skip

    key = jax.random.key(8)
    out = sample_in_chunks(sample, eval_set, eval_set.handles, key=key, chunk=4)
    assert calls == [4, 4, 4]  # the last chunk padded to the same shape
    assert out.ctrl_pos.shape == (10, K, J, 3)
    np.testing.assert_array_equal(out.ctrl_pos[:, 0], eval_set.start)
    for i, rows in enumerate((slice(0, 4), slice(4, 8), slice(8, 10))):
        np.testing.assert_array_equal(out.contacts[rows], float(jax.random.uniform(jax.random.fold_in(key, i), ())))
    calls.clear()
    sample_in_chunks(sample, eval_set, eval_set.handles, key=key, chunk=256)
    assert calls == [10]


@requires_shared
def test_bmm_lafan1_experiment_smoke(tmp_path, monkeypatch):
    """The experiment end to end on the real LaFAN1 subset: tiny model, a few steps, a few windows."""
    import importlib.util

    monkeypatch.syspath_prepend(str(REPO_ROOT / "experiments"))
    spec = importlib.util.spec_from_file_location("bmm_lafan1", REPO_ROOT / "experiments" / "bmm_lafan1.py")
    experiment = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(experiment)
    out = tmp_path / "bmm.json"
    args = ["--out", str(out), "--data", str(SHARED_DATA / "lafan1" / "lafan1-subset.zip"), "--config", "tiny",
            "--steps", "4", "--checkpoint-every", "2", "--eval-windows", "8", "--table6-steps", "5",
            "--run-dir", str(tmp_path / "run"), "--no-progress"]  # fmt: skip
    results = experiment.main(args)
    saved = json.loads(out.read_text())
    assert saved["eval"]["n_windows"] == 8 and saved["training"]["steps"] == 4
    bmm = saved["bmm"]["0"]
    assert bmm["overwrite"]["id"]["handles_error_cm"] == 0.0 and bmm["overwrite"]["ood"]["handles_error_cm"] == 0.0
    assert bmm["no_overwrite"]["id"]["handles_error_cm"] > 0.0
    assert saved["reference"]["id"]["handles_error_cm"] == 0.0 and list(bmm["steps"]) == ["5"]
    assert (tmp_path / "run" / "model" / "config.json").exists() and out.with_suffix(".md").exists()
    # Running it again resumes at step 4: nothing more to train.
    again = experiment.main(args)
    assert again["training"]["history"] == [] and results["model"]["params"] == again["model"]["params"]


# ===================================================== residual prediction and fast paths

RESIDUAL = dataclasses.replace(TINY, prediction="residual")


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


def test_interpolation_prior_is_the_reference_curves_in_model_space(stats, demo_dataset):
    pos = jnp.asarray(demo_dataset.ctrl_pos[4])
    handle = (jnp.asarray([3], jnp.int32), jnp.asarray([2], jnp.int32), pos[3, 2][None], jnp.asarray([True]))
    world = inbetween_conditions(K, pos[0], pos[-1], *handle)
    prior = interpolation_prior(stats, normalize_conditions(stats, world), K)
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
    assert np.all(np.asarray(interpolation_prior(stats, dropped, K)) == 0.0)


def test_residual_prediction_adds_the_prior_to_the_network_output(stats, rng):
    graphdef, params = init_denoiser(RESIDUAL, key=jax.random.key(4))
    # A trained decoder is not zero: give it weights so the network's own term shows.
    params["decoder"]["kernel"][...] = jnp.asarray(rng.normal(size=params["decoder"]["kernel"].shape), jnp.float32)
    module = nnx.merge(graphdef, params)
    cond = normalize_conditions(stats, some_conditions(rng))
    x = jnp.asarray(rng.normal(size=(K, F)), jnp.float32)
    raw, raw_logits = module(x, jnp.int32(300), cond)
    x0, logits = predict_x0(module, stats, x, jnp.int32(300), cond)
    np.testing.assert_allclose(x0 - raw, interpolation_prior(stats, cond, K), atol=1e-5)
    assert_trees_identical(logits, raw_logits)
    # The paper's x₀ prediction returns the network output as it is.
    plain = nnx.merge(*init_denoiser(TINY, key=jax.random.key(4)))
    assert_trees_identical(predict_x0(plain, stats, x, jnp.int32(300), cond), plain(x, jnp.int32(300), cond))


def test_fresh_residual_model_samples_the_reference_curves(stats, motions):
    """A zero-initialised residual decoder starts training at the non-learned reference."""
    graphdef, params = init_denoiser(RESIDUAL, key=jax.random.key(5))
    fresh = BezierMotionModel(params, stats, graphdef, RESIDUAL)
    curves = sample_curves(fresh, motions.start, motions.end, motions.handles, key=jax.random.key(6), steps=5)
    h = motions.handles
    start_end = jnp.stack([motions.start, motions.end], axis=1)
    mask = np.zeros((2, K, J), bool)
    target = np.zeros((2, K, J, 3), np.float32)
    mask[:, [0, -1]] = True
    target[:, [0, -1]] = np.asarray(start_end)
    for b in range(2):
        for i in range(h.valid.shape[1]):
            if bool(h.valid[b, i]):
                mask[b, int(h.control[b, i]), int(h.joint[b, i])] = True
                target[b, int(h.control[b, i]), int(h.joint[b, i])] = np.asarray(h.position[b, i])
    ref_pos, ref_tangent = handle_interpolation(jnp.asarray(mask), jnp.asarray(target))
    np.testing.assert_allclose(curves.ctrl_pos, ref_pos, atol=1e-3)
    np.testing.assert_allclose(curves.ctrl_tangent, ref_tangent, atol=1e-3)
    assert np.all(np.asarray(curves.contacts) == 0.5)


def test_sample_curves_composes_inside_a_callers_jit(model, motions, sampled):
    options = inference_compiler_options()
    assert isinstance(options, tuple) and all(isinstance(k, str) for k, _ in options)
    outer = jax.jit(lambda s, e, h, k: sample_curves(model, s, e, h, key=k, steps=5))
    inside = outer(motions.start, motions.end, motions.handles, jax.random.key(21))
    # Different compiler options may order floating-point work differently: close, not identical.
    assert_trees_close(inside, sampled, tol=1e-4)
    assert np.all(grid_errors(inside, motions) == 0.0)
    # ... also when every input is a constant of the caller's computation.
    constants = jax.jit(lambda: sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5))()
    assert_trees_close(constants, sampled, tol=1e-4)


# ============================================================================ foot locking


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
