"""One gradient update (``bezmotion.training.step.apply_gradients``) on a quadratic loss,
against the update written out by hand: ∇ ½‖w − c‖² = w − c, SGD with momentum, the
parameters' moving average and the step counter; and ``count_parameters``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from bezmotion.training import TrainState, apply_gradients, count_parameters

LR, MOMENTUM = 0.1, 0.5
W0 = np.array([1.0, -2.0, 0.5], np.float32)
TARGET = np.array([0.0, 1.0, 2.0], np.float32)


def quadratic_loss(params, target, scale):
    """``scale · ½‖w − target‖²`` and one extra term to log."""
    diff = params["w"] - target
    return scale * 0.5 * jnp.sum(diff**2), {"max_error": jnp.max(jnp.abs(diff))}


def fresh(optimizer, *, ema: bool) -> TrainState:
    params = {"w": jnp.asarray(W0)}
    return TrainState(params, optimizer.init(params), params if ema else None, jnp.zeros((), jnp.int32), jax.random.key(0))


@pytest.mark.parametrize("ema_decay", [None, 0.9])
def test_two_updates_match_the_hand_computation(ema_decay):
    optimizer = optax.sgd(LR, momentum=MOMENTUM)
    state = fresh(optimizer, ema=ema_decay is not None)
    keys = jax.random.split(jax.random.key(1), 2)
    step = jax.jit(lambda s, k: apply_gradients(s, optimizer, quadratic_loss, jnp.asarray(TARGET), 2.0, next_key=k, ema_decay=ema_decay))

    w, velocity, ema = W0.astype(np.float64), np.zeros(3), W0.astype(np.float64)
    for k in keys:
        grad = 2.0 * (w - TARGET)
        loss = 2.0 * 0.5 * np.sum((w - TARGET) ** 2)
        max_error = np.max(np.abs(w - TARGET))
        velocity = grad + MOMENTUM * velocity  # optax's (and PyTorch's) heavy-ball trace
        w = w - LR * velocity
        ema = ema_decay * ema + (1 - ema_decay) * w if ema_decay is not None else ema
        state, metrics = step(state, k)

        np.testing.assert_allclose(state.params["w"], w, rtol=1e-6)
        np.testing.assert_allclose(float(metrics["loss"]), loss, rtol=1e-6)
        np.testing.assert_allclose(float(metrics["grad_norm"]), np.linalg.norm(grad), rtol=1e-6)
        np.testing.assert_allclose(float(metrics["max_error"]), max_error, rtol=1e-6)
        assert set(metrics) == {"loss", "grad_norm", "max_error"}
        assert np.array_equal(jax.random.key_data(state.key), jax.random.key_data(k))  # the caller's next key
        if ema_decay is None:
            assert state.ema is None
        else:
            np.testing.assert_allclose(state.ema["w"], ema, rtol=1e-6)
    assert int(state.step) == 2


def test_the_state_is_not_mutated_and_the_update_is_pure():
    optimizer = optax.adam(1e-2)
    state = fresh(optimizer, ema=True)
    args = (jnp.asarray(TARGET), 1.0)
    a, _ = apply_gradients(state, optimizer, quadratic_loss, *args, next_key=state.key, ema_decay=0.99)
    b, _ = apply_gradients(state, optimizer, quadratic_loss, *args, next_key=state.key, ema_decay=0.99)
    np.testing.assert_array_equal(state.params["w"], W0)
    np.testing.assert_array_equal(state.ema["w"], W0)
    for x, y in zip(jax.tree.leaves(a.params) + jax.tree.leaves(a.opt_state), jax.tree.leaves(b.params) + jax.tree.leaves(b.opt_state)):
        np.testing.assert_array_equal(x, y)


def test_count_parameters_counts_every_scalar():
    params = {"a": jnp.zeros((3, 4)), "b": [jnp.zeros(5), jnp.zeros(())], "c": {"d": jnp.zeros((2, 2, 2))}}
    assert count_parameters(params) == 12 + 5 + 1 + 8
    assert count_parameters({}) == 0
