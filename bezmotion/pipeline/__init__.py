"""In-betweening end to end: poses and handles in, a full-body motion of any character out.

    start pose, end pose, handles ──▶ BMM curves of the six characteristic joints
        ──▶ dense trajectories ──▶ ik_fn per frame ──▶ full-body poses ──▶ BVH

:mod:`~bezmotion.pipeline.inbetweening` (the jit-compiled :func:`inbetween`, and
:func:`inbetween_chain` through several keys),
:mod:`~bezmotion.pipeline.transfer` (driving one skeleton with another's BMM),
:mod:`~bezmotion.pipeline.export` (BVH), :mod:`~bezmotion.pipeline.gltf` (glTF: skeleton
and curves), :mod:`~bezmotion.pipeline.preview` (animated GIF), :mod:`~bezmotion.pipeline.evaluation` (the
pipeline over a corpus's validation windows) and :mod:`~bezmotion.pipeline.window_figures` (their
per-window figures after IK and of the curves).
"""

from bezmotion.pipeline.evaluation import (
    evaluate_pipeline,
    full_body_handles_error,
    ground_truth_pose_metrics,
    mpjpe,
    pose_metrics,
    run_pipeline,
    window_poses,
)
from bezmotion.pipeline.window_figures import PipelineMetricsConfig
from bezmotion.pipeline.export import default_channels, pose_to_bvh
from bezmotion.pipeline.gltf import GlbContents, read_glb, validate_glb, write_glb
from bezmotion.pipeline.preview import write_preview
from bezmotion.data.windows import join_windows, split_windows
from bezmotion.pipeline.inbetweening import (
    ChainResult,
    InbetweenResult,
    WindowCurves,
    chain_curves_traced,
    chain_key_velocities,
    inbetween,
    inbetween_chain,
    inbetween_chain_traced,
    inbetween_traced,
    join_chain_curves,
    key_velocities,
    pose_from_chain_curves,
    pose_from_curves,
    window_curves_traced,
)
from bezmotion.pipeline.transfer import (
    CharacterProfile,
    Placement,
    Transfer,
    anatomical_frames,
    curves_to_target,
    facing_yaw,
    floor_anchor,
    mean_rotation,
    orientations_to_source_space,
    placement,
    to_source_space,
    transfer_curve_dataset,
)

__all__ = [
    "ChainResult",
    "CharacterProfile",
    "GlbContents",
    "InbetweenResult",
    "PipelineMetricsConfig",
    "Placement",
    "Transfer",
    "WindowCurves",
    "chain_curves_traced",
    "chain_key_velocities",
    "anatomical_frames",
    "curves_to_target",
    "default_channels",
    "evaluate_pipeline",
    "facing_yaw",
    "floor_anchor",
    "full_body_handles_error",
    "ground_truth_pose_metrics",
    "inbetween",
    "inbetween_chain",
    "inbetween_chain_traced",
    "inbetween_traced",
    "join_chain_curves",
    "join_windows",
    "key_velocities",
    "mean_rotation",
    "mpjpe",
    "orientations_to_source_space",
    "placement",
    "pose_from_chain_curves",
    "pose_from_curves",
    "pose_metrics",
    "pose_to_bvh",
    "read_glb",
    "run_pipeline",
    "split_windows",
    "to_source_space",
    "transfer_curve_dataset",
    "validate_glb",
    "window_curves_traced",
    "window_poses",
    "write_glb",
    "write_preview",
]
