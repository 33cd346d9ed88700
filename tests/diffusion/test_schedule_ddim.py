"""The diffusion schedule and DDIM (``bezmotion.diffusion``), checked against closed forms
written here in NumPy, not against the library's own formulas.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.diffusion.ddim import ddim_sample
from bezmotion.diffusion.schedule import DiffusionSchedule, cosine_schedule, respaced_timesteps


def np_cosine_alpha_bar(T: int, s: float = 0.008, max_beta: float = 0.999) -> np.ndarray:
    """Nichol & Dhariwal (2021) cosine schedule, written out from the paper in float64."""
    f = lambda u: np.cos((u + s) / (1.0 + s) * np.pi / 2.0) ** 2  # noqa: E731
    betas = np.array([min(1.0 - f((t + 1) / T) / f(t / T), max_beta) for t in range(T)])
    return np.cumprod(1.0 - betas)


def recording(fn):
    """Wrap ``denoise(x, t)`` so every (t, x_t) DDIM feeds it is recorded (by ``jax.debug.callback``)."""
    seen: dict[int, np.ndarray] = {}

    def store(x, t):
        seen[int(t)] = np.asarray(x, np.float64)

    def denoise(x, t):
        jax.debug.callback(store, x, t)
        return fn(x, t)

    return denoise, seen


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
