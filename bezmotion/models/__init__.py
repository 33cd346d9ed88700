"""In-betweening models: baselines (zero-velocity, interpolation); later the BMM denoiser,
the Δ-interpolator and IK modules."""

from bezmotion.models.baselines import interpolation, transition_weights, zero_velocity

__all__ = ["interpolation", "transition_weights", "zero_velocity"]
