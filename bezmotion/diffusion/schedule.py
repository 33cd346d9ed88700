"""Noise schedules for Gaussian diffusion (the MDM / CondMDI conventions BMM builds on).

Timesteps are integers ``t = 0 … T−1``; ``alpha_bar[t]`` is the signal fraction
``ᾱ_t`` of ``x_t = √ᾱ_t·x₀ + √(1−ᾱ_t)·ε``. The cosine schedule follows Nichol & Dhariwal
(2021) exactly as guided-diffusion builds it: ``β_t = min(1 − f((t+1)/T)/f(t/T), 0.999)``
with ``f(u) = cos²((u + 0.008)/1.008 · π/2)``, and ``ᾱ_t = Π_{s≤t}(1 − β_s)``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

DEFAULT_NUM_TIMESTEPS = 1000


def cosine_alpha_bar_fn(u: np.ndarray, s: float = 0.008) -> np.ndarray:
    """``f(u) = cos²((u + s)/(1 + s) · π/2)`` for ``u = t/T ∈ [0, 1]`` (Nichol & Dhariwal Eq. 17)."""
    return np.cos((u + s) / (1.0 + s) * np.pi / 2.0) ** 2


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DiffusionSchedule:
    """A discrete noise schedule.

    Attributes:
      alpha_bar: ``(T,)`` cumulative signal fraction ``ᾱ_t`` (float32 leaf, decreasing).
    """

    alpha_bar: Float[Array, "T"]

    @property
    def num_timesteps(self) -> int:
        return self.alpha_bar.shape[0]

    def snr(self, t: Int[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        """Signal-to-noise ratio ``ᾱ_t / (1 − ᾱ_t)``."""
        a = self.alpha_bar[t]
        return a / (1.0 - a)

    def add_noise(
        self, x0: Float[Array, "*batch"], t: Int[ArrayLike, ""], noise: Float[Array, "*batch"]
    ) -> Float[Array, "*batch"]:
        """Forward process ``q(x_t | x₀)``: ``√ᾱ_t·x₀ + √(1−ᾱ_t)·noise`` (``t`` is one timestep)."""
        a = self.alpha_bar[t]
        return jnp.sqrt(a) * x0 + jnp.sqrt(1.0 - a) * noise


def cosine_schedule(
    num_timesteps: int = DEFAULT_NUM_TIMESTEPS, *, s: float = 0.008, max_beta: float = 0.999
) -> DiffusionSchedule:
    """The cosine schedule (Nichol & Dhariwal 2021), ``T = num_timesteps`` (MDM, BMM: 1000)."""
    if num_timesteps < 1:
        raise ValueError(f"num_timesteps must be ≥ 1, got {num_timesteps}")
    u = np.arange(num_timesteps + 1, dtype=np.float64) / num_timesteps
    f = cosine_alpha_bar_fn(u, s)
    betas = np.minimum(1.0 - f[1:] / f[:-1], max_beta)
    return DiffusionSchedule(jnp.asarray(np.cumprod(1.0 - betas), jnp.float32))


def respaced_timesteps(num_timesteps: int, steps: int) -> np.ndarray:
    """The ``steps`` timesteps DDIM visits, ascending: ``0, T/steps, 2T/steps, …``
    (guided-diffusion's ``space_timesteps(T, "ddimN")``; 10 of 1000 → 0, 100, …, 900)."""
    if not 1 <= steps <= num_timesteps:
        raise ValueError(f"steps must be between 1 and {num_timesteps}, got {steps}")
    for stride in range(1, num_timesteps + 1):
        kept = np.arange(0, num_timesteps, stride)
        if len(kept) == steps:
            return kept
    raise ValueError(f"no even stride gives exactly {steps} of {num_timesteps} timesteps")
