"""The learning-rate schedules (``bezmotion.training.optim.warmup_then_decay``) against the
closed forms of the two schedules the trainers use, written out here in float64: the
Δ-interpolator's linear warm-up + step decay and the learned IK's linear warm-up + cosine
decay. (AMSGrad is checked in ``test_amsgrad.py``.)
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import optax
import pytest

from bezmotion.delta.train import DeltaTrainConfig, learning_rate_schedule as delta_schedule
from bezmotion.ik.training import IKTrainConfig, learning_rate_schedule as ik_schedule
from bezmotion.training.optim import warmup_then_decay


def step_decay_reference(t: int, *, initial: float, peak: float, warmup: int, every: int, factor: float) -> float:
    """Linear from ``initial`` to ``peak`` over ``warmup`` steps, then ×``factor`` every ``every`` steps."""
    if t < warmup:
        return initial + (peak - initial) * t / warmup
    return peak * factor ** ((t - warmup) // every)


def cosine_reference(t: int, *, initial: float, peak: float, warmup: int, total: int, end: float) -> float:
    """Linear from ``initial`` to ``peak`` over ``warmup`` steps, then a half cosine down to
    ``end`` at step ``total``, constant after."""
    if t < warmup:
        return initial + (peak - initial) * t / warmup
    progress = min(t - warmup, total - warmup) / (total - warmup)
    return end + (peak - end) * 0.5 * (1.0 + math.cos(math.pi * progress))


def values(schedule, steps) -> np.ndarray:
    return np.asarray([float(schedule(jnp.int32(t))) for t in steps])


STEPS = [0, 1, 7, 49, 50, 51, 99, 100, 101, 149, 150, 151, 250, 1000]


def test_step_decay_matches_its_closed_form():
    kw = dict(initial=1e-6, peak=2e-4, warmup=50, every=50, factor=0.1)
    decay = optax.exponential_decay(kw["peak"], kw["every"], kw["factor"], staircase=True)
    schedule = warmup_then_decay(decay, init_value=kw["initial"], peak_value=kw["peak"], warmup_steps=kw["warmup"])
    expected = [step_decay_reference(t, **kw) for t in STEPS]
    np.testing.assert_allclose(values(schedule, STEPS), expected, rtol=1e-5, atol=1e-12)
    assert float(schedule(jnp.int32(99))) == pytest.approx(2e-4, rel=1e-6)  # the first drop is at 100
    assert float(schedule(jnp.int32(100))) == pytest.approx(2e-5, rel=1e-5)


def test_the_delta_trainer_schedule_is_warmup_then_step_decay():
    config = DeltaTrainConfig(learning_rate=2e-4, initial_learning_rate=1e-6, warmup_steps=50, decay_every=50, decay_factor=0.1)
    expected = [step_decay_reference(t, initial=1e-6, peak=2e-4, warmup=50, every=50, factor=0.1) for t in STEPS]
    np.testing.assert_allclose(values(delta_schedule(config), STEPS), expected, rtol=1e-5, atol=1e-12)


def test_cosine_decay_matches_its_closed_form_and_optax_warmup_cosine():
    peak, end, warmup, total = 1e-3, 1e-5, 20, 120
    cosine = optax.cosine_decay_schedule(peak, total - warmup, alpha=end / peak)
    schedule = warmup_then_decay(cosine, init_value=peak * 0.01, peak_value=peak, warmup_steps=warmup)
    steps = [0, 1, 10, 19, 20, 21, 70, 119, 120, 500]
    expected = [cosine_reference(t, initial=peak * 0.01, peak=peak, warmup=warmup, total=total, end=end) for t in steps]
    np.testing.assert_allclose(values(schedule, steps), expected, rtol=1e-5)
    # The docstring's claim: exactly optax's own warm-up + cosine, bit for bit.
    same = optax.warmup_cosine_decay_schedule(peak * 0.01, peak, warmup, total, end)
    np.testing.assert_array_equal(values(schedule, range(150)), values(same, range(150)))


@pytest.mark.parametrize(
    "kw, warmup, total",
    [
        (dict(num_steps=120, warmup_steps=5, learning_rate=3e-3, final_learning_rate=1e-5), 5, 120),
        # Warm-up longer than the run: clipped so at least one step decays.
        (dict(num_steps=10, warmup_steps=200, learning_rate=1e-3, final_learning_rate=1e-5), 9, 11),
        # No warm-up asked for: one step all the same.
        (dict(num_steps=50, warmup_steps=0, learning_rate=1e-3, final_learning_rate=1e-4), 1, 50),
    ],
)
def test_the_ik_trainer_schedule_is_warmup_then_cosine(kw, warmup, total):
    config = IKTrainConfig(**kw)
    lr, end = config.learning_rate, config.final_learning_rate
    steps = sorted({0, 1, warmup - 1, warmup, warmup + 1, (warmup + total) // 2, total - 1, total, total + 10})
    expected = [cosine_reference(t, initial=lr * 0.01, peak=lr, warmup=warmup, total=total, end=end) for t in steps]
    np.testing.assert_allclose(values(ik_schedule(config), steps), expected, rtol=1e-5)
