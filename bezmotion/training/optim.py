"""Optimisers shared by the trainers.

The papers trained with PyTorch; :func:`scale_by_amsgrad_torch` reproduces PyTorch's
AMSGrad exactly, which optax's differs from.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jaxtyping import Array, Int


class AmsgradState(NamedTuple):
    count: Int[Array, ""]
    mu: Any
    nu: Any
    nu_max: Any


def scale_by_amsgrad_torch(b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8) -> optax.GradientTransformation:
    """Adam with AMSGrad exactly as PyTorch computes it (the paper trained with PyTorch).

    PyTorch keeps the running maximum of the *raw* second moment and bias-corrects it
    afterwards: ``m̂ / (√(max_s ν_s / (1 − β₂ᵗ)) + ε)``. ``optax.scale_by_amsgrad`` takes the
    maximum of the already corrected moment instead, so one large early gradient — when
    the correction multiplies ν by up to 1/(1 − β₂) — damps that parameter for good.
    """

    def init(params):
        zeros = lambda: jax.tree.map(jnp.zeros_like, params)  # noqa: E731
        return AmsgradState(jnp.zeros((), jnp.int32), zeros(), zeros(), zeros())

    def update(grads, state, params=None):
        del params
        count = state.count + 1
        mu = jax.tree.map(lambda m, g: b1 * m + (1.0 - b1) * g, state.mu, grads)
        nu = jax.tree.map(lambda v, g: b2 * v + (1.0 - b2) * g * g, state.nu, grads)
        nu_max = jax.tree.map(jnp.maximum, state.nu_max, nu)
        c1 = 1.0 - b1 ** count.astype(jnp.float32)
        c2 = 1.0 - b2 ** count.astype(jnp.float32)
        updates = jax.tree.map(lambda m, v: (m / c1) / (jnp.sqrt(v / c2) + eps), mu, nu_max)
        return updates, AmsgradState(count, mu, nu, nu_max)

    return optax.GradientTransformation(init, update)


def adamw_amsgrad_torch(learning_rate: float | optax.Schedule, weight_decay: float) -> optax.GradientTransformation:
    """AdamW with AMSGrad as PyTorch's ``AdamW(amsgrad=True)``: decoupled weight decay
    ``lr·wd·θ`` added to the AMSGrad direction, then scaled by the learning rate
    (a constant or an optax schedule)."""
    return optax.chain(
        scale_by_amsgrad_torch(),
        optax.add_decayed_weights(weight_decay),
        optax.scale_by_learning_rate(learning_rate),
    )


__all__ = ["AmsgradState", "adamw_amsgrad_torch", "scale_by_amsgrad_torch"]
