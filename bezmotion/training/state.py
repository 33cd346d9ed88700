"""The state a training run threads through its jitted step, for any model.

A run is a pure function of its seed: ``step(state, data) -> (state, metrics)`` draws
everything random from ``state.key``, so a checkpointed state resumes bit-identically.
Several seeds train together as one state stacked on a leading axis (see
:func:`stack_seeds`) under ``jax.vmap``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import nnx
from jaxtyping import Array, Int


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class TrainState:
    """Everything that changes during training (one seed; stacked on axis 0 for several).

    Attributes:
      params, ema: model parameters and their exponential moving average.
      opt_state: optimiser state.
      step: number of steps taken.
      key: PRNG key for the next step.
    """

    params: Any
    opt_state: Any
    ema: Any
    step: Int[Array, "*seeds"]
    key: Array


def fresh_train_state(
    init_model: Callable[[Array], tuple[nnx.GraphDef, nnx.State]],
    optimizer: optax.GradientTransformation,
    *,
    key: Array,
    ema: bool,
) -> tuple[nnx.GraphDef, TrainState]:
    """Fresh parameters (``init_model(key)``), optimiser state and step 0 for one seed;
    ``ema`` starts as a copy of the parameters, or is ``None`` for models that keep none."""
    init_key, state_key = jax.random.split(key)
    graphdef, params = init_model(init_key)
    return graphdef, TrainState(params, optimizer.init(params), params if ema else None, jnp.zeros((), jnp.int32), state_key)


def stack_seeds(
    init_one: Callable[[Array], tuple[nnx.GraphDef, TrainState]], seeds: list[int] | tuple[int, ...]
) -> tuple[nnx.GraphDef, TrainState]:
    """``init_one(key)`` for every seed, states stacked on a leading axis (any model)."""
    if not seeds:
        raise ValueError("need at least one seed")
    states = [init_one(jax.random.key(s)) for s in seeds]
    return states[0][0], jax.tree.map(lambda *xs: jnp.stack(xs), *(s for _, s in states))


__all__ = ["TrainState", "fresh_train_state", "stack_seeds"]
