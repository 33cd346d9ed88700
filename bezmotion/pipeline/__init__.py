"""In-betweening end to end: poses and handles in, a full-body motion of any character out.

    key poses, handles ──▶ BMM curves of the six characteristic joints
        ──▶ dense trajectories ──▶ ik_fn per frame ──▶ full-body poses ──▶ BVH

:mod:`~bezmotion.pipeline.model` (the model object, :class:`Inbetweener`),
:mod:`~bezmotion.pipeline.inbetweening` (the jit-compiled :func:`inbetween` through any
number of keys),
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
    InbetweenOptions,
    InbetweenResult,
    WindowCurves,
    chain_key_velocities,
    curves_traced,
    inbetween,
    inbetween_traced,
    join_chain_curves,
    key_velocities,
    pose_from_curves,
    window_handles,
)
from bezmotion.pipeline.model import Inbetweener, pretrained
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
    "CharacterProfile",
    "GlbContents",
    "InbetweenOptions",
    "InbetweenResult",
    "Inbetweener",
    "PipelineMetricsConfig",
    "Placement",
    "Transfer",
    "WindowCurves",
    "chain_key_velocities",
    "anatomical_frames",
    "curves_to_target",
    "curves_traced",
    "default_channels",
    "evaluate_pipeline",
    "facing_yaw",
    "floor_anchor",
    "full_body_handles_error",
    "ground_truth_pose_metrics",
    "inbetween",
    "inbetween_traced",
    "join_chain_curves",
    "join_windows",
    "key_velocities",
    "mean_rotation",
    "mpjpe",
    "orientations_to_source_space",
    "placement",
    "pose_from_curves",
    "pose_metrics",
    "pose_to_bvh",
    "pretrained",
    "read_glb",
    "run_pipeline",
    "split_windows",
    "to_source_space",
    "transfer_curve_dataset",
    "validate_glb",
    "window_handles",
    "window_poses",
    "write_glb",
    "write_preview",
]
