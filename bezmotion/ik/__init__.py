"""IK modules: six characteristic-joint targets → a full-body pose of one character.

See :mod:`bezmotion.ik.protocol` for the ``ik_fn(params, targets) -> pose`` protocol.
"""

from bezmotion.ik.exact import ExactIKFn, ExactIKParams, ExactIKResult, exact_ik
from bezmotion.ik.joint_limits import JointLimits, joint_limits_from_motion
from bezmotion.ik.protocol import (
    Character,
    IKFn,
    IKTargets,
    Pose,
    pose_fk,
    pose_from_global,
    pose_from_motion,
    pose_local,
    solve_frames,
    targets_from_pose,
)
from bezmotion.ik.protores import (
    Effectors,
    ProtoResConfig,
    ProtoResModel,
    load_ik_model,
    protores_ik_fn,
    protores_refined_ik_fn,
    save_ik_model,
    solve_effectors,
)
from bezmotion.ik.rig import RIG_PRESETS, Rig, RigSpec, make_rig, refine_limbs, rig_ik, with_rest_pose

__all__ = [
    "RIG_PRESETS",
    "Character",
    "Effectors",
    "ExactIKFn",
    "ExactIKParams",
    "ExactIKResult",
    "IKFn",
    "IKTargets",
    "JointLimits",
    "Pose",
    "ProtoResConfig",
    "ProtoResModel",
    "Rig",
    "RigSpec",
    "exact_ik",
    "joint_limits_from_motion",
    "load_ik_model",
    "make_rig",
    "pose_fk",
    "pose_from_global",
    "pose_from_motion",
    "pose_local",
    "protores_ik_fn",
    "protores_refined_ik_fn",
    "refine_limbs",
    "rig_ik",
    "save_ik_model",
    "solve_frames",
    "solve_effectors",
    "targets_from_pose",
    "with_rest_pose",
]
