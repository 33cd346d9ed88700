"""The Δ-interpolator (Oreshkin et al. 2023): a deterministic transformer in-betweener
that predicts residuals over SLERP and linear interpolation.

:mod:`~bezmotion.delta.model` (the network and in-betweeners for any skeleton: the
config holds its parents), :mod:`~bezmotion.delta.train` (its data as plain arrays,
losses and jitted step; the loop is :mod:`bezmotion.training`). The non-learned
baselines it predicts residuals over are :mod:`bezmotion.interpolation`.
"""

from bezmotion.delta.model import DeltaConfig, DeltaInterpolator, delta_inbetweener, delta_position_inbetweener, init_delta
from bezmotion.delta.train import (
    DeltaArrays,
    DeltaPositionArrays,
    DeltaTrainConfig,
    init_delta_train_states,
    make_delta_train_step,
    run_delta_training,
)

__all__ = [
    "DeltaArrays",
    "DeltaConfig",
    "DeltaInterpolator",
    "DeltaPositionArrays",
    "DeltaTrainConfig",
    "delta_inbetweener",
    "delta_position_inbetweener",
    "init_delta",
    "init_delta_train_states",
    "make_delta_train_step",
    "run_delta_training",
]
