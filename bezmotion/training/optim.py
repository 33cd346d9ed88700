"""Optimisers and learning-rate schedules shared by the trainers.

The papers trained with PyTorch; :func:`scale_by_amsgrad_torch` reproduces PyTorch's
AMSGrad exactly, which optax's differs from. :func:`warmup_then_decay` is the one
schedule shape the Δ-interpolator and the learned IK both train with (a linear warm-up,
then a decay of their choice); both use it with ``optax.adam``.
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


def warmup_then_decay(
    decay: optax.Schedule, *, init_value: float, peak_value: float, warmup_steps: int
) -> optax.Schedule:
    """A linear warm-up from ``init_value`` to ``peak_value``, then ``decay``.

    ``decay`` is any optax schedule that starts at ``peak_value``; it is counted from the
    end of the warm-up (it sees step ``t − warmup_steps``). The two in use:

    - step decay (Δ-interpolator, Harvey et al. 2020):
      ``optax.exponential_decay(peak, decay_every, decay_factor, staircase=True)``;
    - cosine decay to ``end`` at step ``total`` (learned IK):
      ``optax.cosine_decay_schedule(peak, total - warmup_steps, alpha=end / peak)``, which
      makes this exactly ``optax.warmup_cosine_decay_schedule(init, peak, warmup_steps,
      total, end)``.

    Args:
      decay: the schedule after the warm-up (a function of the step, returning the rate).
      init_value: the rate at step 0.
      peak_value: the rate reached at ``warmup_steps``.
      warmup_steps: length of the warm-up (steps); 0 starts with ``decay`` at once.

    Returns:
      An optax schedule: step count → learning rate.
    """
    warmup = optax.linear_schedule(init_value, peak_value, warmup_steps)
    return optax.join_schedules([warmup, decay], [warmup_steps])


__all__ = ["AmsgradState", "adamw_amsgrad_torch", "scale_by_amsgrad_torch", "warmup_then_decay"]
