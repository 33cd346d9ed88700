"""The Δ-interpolator (Oreshkin et al. 2023): a deterministic transformer in-betweener
that predicts residuals over SLERP and linear interpolation.

:mod:`~bezmotion.delta.model` (the network and in-betweeners for any skeleton),
:mod:`~bezmotion.delta.train` (its data, losses and jitted step; the loop is
:mod:`bezmotion.training`).
"""

from bezmotion.delta.model import DeltaConfig, DeltaInterpolator, delta_inbetweener, delta_position_inbetweener, init_delta
from bezmotion.delta.train import DeltaTrainConfig, init_delta_train_states, make_delta_train_step

__all__ = [
    "DeltaConfig",
    "DeltaInterpolator",
    "DeltaTrainConfig",
    "delta_inbetweener",
    "delta_position_inbetweener",
    "init_delta",
    "init_delta_train_states",
    "make_delta_train_step",
]
