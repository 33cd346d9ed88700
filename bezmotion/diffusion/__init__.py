"""Gaussian diffusion: noise schedules, DDIM sampling with overwrite (inpainting), and the
minimum-norm projection of Bézier curves onto handles at any frame."""

from bezmotion.diffusion.ddim import ddim_sample
from bezmotion.diffusion.projection import on_control_frame, project_off_grid, project_onto_handles
from bezmotion.diffusion.schedule import DiffusionSchedule, cosine_schedule, respaced_timesteps

__all__ = [
    "DiffusionSchedule",
    "cosine_schedule",
    "ddim_sample",
    "on_control_frame",
    "project_off_grid",
    "project_onto_handles",
    "respaced_timesteps",
]
