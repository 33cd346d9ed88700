"""DDIM sampling (Song et al. 2021, η = 0) for x₀-predicting denoisers, with overwrite.

The denoiser predicts x₀. DDIM respaced to ``steps`` visits the timesteps of
:func:`~bezmotion.diffusion.schedule.respaced_timesteps` from the largest down; the
model is always fed the *original* timestep, and the update uses the kept ᾱ only:

    ε̂ = (x_t − √ᾱ_t·x̂₀) / √(1 − ᾱ_t),      x_prev = √ᾱ_prev·x̂₀ + √(1 − ᾱ_prev)·ε̂,

with ``ᾱ_prev = 1`` after the last step, so the sample is the last x̂₀. Inpainting by
overwrite (BMM, CondMDI) replaces the known entries of x̂₀ before every update; BMM also
overwrites the final sample, which makes the known entries exact.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from bezmotion.diffusion.schedule import DiffusionSchedule, respaced_timesteps

Denoiser = Callable[[Array, Int[Array, ""]], Array]
"""``denoise(x_t, t) -> x̂₀`` for one timestep ``t`` (an int32 scalar, original numbering)."""


def ddim_sample(
    denoise: Denoiser,
    schedule: DiffusionSchedule,
    x_T: Float[Array, "*shape"],
    *,
    steps: int,
    overwrite: Callable[[Array], Array] | None = None,
    has_aux: bool = False,
) -> Float[Array, "*shape"] | tuple[Float[Array, "*shape"], Any]:
    """Run deterministic DDIM from ``x_T`` (pure noise) to a sample.

    Args:
      denoise: the x₀-predicting model, closed over its parameters and conditions.
      schedule: the training noise schedule.
      x_T: the starting noise, any shape (batch axes included).
      steps: number of denoising steps (static; e.g. 10 → t = 900, 800, …, 0).
      overwrite: ``x̂₀ -> x̂₀`` with the known entries replaced (``None``: no inpainting);
        applied to every x̂₀ and to the final sample.
      has_aux: ``denoise`` returns ``(x̂₀, aux)`` (e.g. contact logits); the last step's
        ``aux`` is returned too.
    Returns:
      the sample, shaped like ``x_T`` (and the final ``aux`` with ``has_aux``).
    """
    kept = respaced_timesteps(schedule.num_timesteps, steps)
    alpha_bar = schedule.alpha_bar[kept]
    alpha_bar_prev = jnp.concatenate([jnp.ones((1,), alpha_bar.dtype), alpha_bar[:-1]])
    fix = (lambda x: x) if overwrite is None else overwrite
    model = denoise if has_aux else (lambda x, t: (denoise(x, t), ()))

    def step(carry, inputs):
        x, _ = carry
        t, a, a_prev = inputs
        x0, aux = model(x, t)
        x0 = fix(x0)
        eps = (x - jnp.sqrt(a) * x0) / jnp.sqrt(1.0 - a)
        return ((jnp.sqrt(a_prev) * x0 + jnp.sqrt(1.0 - a_prev) * eps).astype(x.dtype), aux), None

    timesteps = jnp.asarray(kept, jnp.int32)
    aux_shape = jax.eval_shape(model, x_T, timesteps[0])[1]
    aux0 = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), aux_shape)
    (x, aux), _ = jax.lax.scan(step, (x_T, aux0), (timesteps[::-1], alpha_bar[::-1], alpha_bar_prev[::-1]))
    return (fix(x), aux) if has_aux else fix(x)
