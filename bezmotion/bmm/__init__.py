"""The Bézier Motion Model (BMM, Studer et al. 2024): diffusion over Bézier curves of the
six characteristic joints, with handles hit exactly.

:mod:`~bezmotion.bmm.denoiser` (the transformer), :mod:`~bezmotion.bmm.features` (curves
↔ normalised tokens, conditions), :mod:`~bezmotion.bmm.losses`, :mod:`~bezmotion.bmm.train`
(its jitted step; the loop is :mod:`bezmotion.training`), :mod:`~bezmotion.bmm.sampling`
(DDIM with overwrite, save/load), :mod:`~bezmotion.bmm.foot_lock`. Its evaluation and
the paper's ablations are research code, in :mod:`bezmotion.evaluation`.
"""

from bezmotion.bmm.denoiser import BMMConfig, BMMDenoiser, init_denoiser
from bezmotion.bmm.sampling import BezierMotionModel, Handles, SampledCurves, load_model, sample_curves, save_model, with_off_grid_prior
from bezmotion.bmm.train import BMMTrainConfig, CurveArrays, init_bmm_train_states, make_bmm_train_step

__all__ = [
    "BMMConfig",
    "BMMDenoiser",
    "BMMTrainConfig",
    "BezierMotionModel",
    "CurveArrays",
    "Handles",
    "SampledCurves",
    "init_bmm_train_states",
    "init_denoiser",
    "load_model",
    "make_bmm_train_step",
    "sample_curves",
    "save_model",
    "with_off_grid_prior",
]
