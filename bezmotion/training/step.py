"""One gradient update of a :class:`~bezmotion.training.state.TrainState`, shared by every trainer.

A model's step draws its batch and per-example keys from ``state.key``, builds a loss
``loss_fn(params, *args) -> (loss, terms)`` and hands both to :func:`apply_gradients`,
which differentiates, updates the optimiser, the parameters and (if the run keeps one)
their moving average, and advances the step counter.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
import optax
from jaxtyping import Array

from bezmotion.training.state import TrainState


def apply_gradients(
    state: TrainState,
    optimizer: optax.GradientTransformation,
    loss_fn: Callable[..., tuple[Array, dict[str, Array]]],
    *loss_args: Any,
    next_key: Array,
    ema_decay: float | None = None,
) -> tuple[TrainState, dict[str, Array]]:
    """Differentiate ``loss_fn(state.params, *loss_args)`` and take one optimiser step.

    Args:
      state: the current state (one seed).
      optimizer: the run's optax transformation (its state is ``state.opt_state``).
      loss_fn: returns the scalar loss and a dict of scalar terms to log.
      loss_args: everything else the loss takes (batch, per-example keys).
      next_key: the state's key for the next step (the caller split it from ``state.key``).
      ema_decay: decay of the parameters' moving average; ``None`` for runs without one.

    Returns:
      The next state and the metrics ``{"loss", "grad_norm", **terms}``.
    """
    (loss, terms), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params, *loss_args)
    updates, opt_state = optimizer.update(grads, state.opt_state, state.params)
    params = optax.apply_updates(state.params, updates)
    ema = state.ema
    if ema_decay is not None:
        ema = jax.tree.map(lambda e, p: ema_decay * e + (1.0 - ema_decay) * p, state.ema, params)
    metrics = {"loss": loss, "grad_norm": optax.tree_utils.tree_norm(grads), **terms}
    return TrainState(params, opt_state, ema, state.step + 1, next_key), metrics


def count_parameters(params: Any) -> int:
    """Number of scalars in a parameter pytree (any model)."""
    return int(sum(np.prod(x.shape) for x in jax.tree.leaves(params)))


__all__ = ["apply_gradients", "count_parameters"]
