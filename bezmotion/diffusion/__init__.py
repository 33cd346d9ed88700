"""Gaussian diffusion: noise schedules and DDIM sampling with overwrite (inpainting)."""

from bezmotion.diffusion.ddim import ddim_sample
from bezmotion.diffusion.schedule import DiffusionSchedule, cosine_schedule, respaced_timesteps

__all__ = ["DiffusionSchedule", "cosine_schedule", "ddim_sample", "respaced_timesteps"]
