"""Training any bezmotion model: explicit state, one jitted step, checkpoints, resume.

Knows no model: the BMM (:mod:`bezmotion.bmm.train`), the Δ-interpolator
(:mod:`bezmotion.delta.train`) and the learned IK (:mod:`bezmotion.ik.training`) each
build a ``step(state, data) -> (state, metrics)`` and hand it to :func:`run_training`
(or :func:`train_with_learning_curve`, which evaluates every N steps and stops early).
"""

from bezmotion.training.checkpoint import CONFIG_FILE, CheckpointStore, save_model_folder
from bezmotion.training.learning_curve import StoppingRule, load_curve, train_with_learning_curve
from bezmotion.training.loop import compile_train_step, data_mesh, run_training, shard_batch
from bezmotion.training.optim import adamw_amsgrad_torch, scale_by_amsgrad_torch, warmup_then_decay
from bezmotion.training.step import apply_gradients, count_parameters
from bezmotion.training.state import TrainState, fresh_train_state, stack_seeds

__all__ = [
    "CONFIG_FILE",
    "CheckpointStore",
    "StoppingRule",
    "TrainState",
    "adamw_amsgrad_torch",
    "apply_gradients",
    "compile_train_step",
    "count_parameters",
    "data_mesh",
    "fresh_train_state",
    "load_curve",
    "run_training",
    "save_model_folder",
    "scale_by_amsgrad_torch",
    "shard_batch",
    "stack_seeds",
    "train_with_learning_curve",
    "warmup_then_decay",
]
