"""In-betweening end to end: poses and handles in, a full-body motion of any character out.

    key poses, handles ──▶ BMM curves of the six characteristic joints
        ──▶ dense trajectories ──▶ ik_fn per frame ──▶ full-body poses ──▶ BVH

:mod:`~bezmotion.pipeline.model` (the model object, :class:`Inbetweener`),
:mod:`~bezmotion.pipeline.inbetweening` (the jit-compiled :func:`inbetween` through any
number of keys), :mod:`~bezmotion.pipeline.key_times` (:func:`inbetween_at`: keys at any frames),
:mod:`~bezmotion.pipeline.transfer` (driving one skeleton with another's BMM),
:mod:`~bezmotion.pipeline.export` (BVH), :mod:`~bezmotion.pipeline.gltf` (glTF: skeleton
and curves), :mod:`~bezmotion.pipeline.preview` (animated GIF). Measuring the pipeline on a
corpus is research code: :mod:`bezmotion.evaluation.pipeline`.
"""

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
from bezmotion.pipeline.key_times import TimedInbetween, inbetween_at
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
    "Placement",
    "Transfer",
    "WindowCurves",
    "chain_key_velocities",
    "anatomical_frames",
    "curves_to_target",
    "curves_traced",
    "default_channels",
    "facing_yaw",
    "floor_anchor",
    "TimedInbetween",
    "inbetween",
    "inbetween_at",
    "inbetween_traced",
    "join_chain_curves",
    "join_windows",
    "key_velocities",
    "mean_rotation",
    "orientations_to_source_space",
    "placement",
    "pose_from_curves",
    "pose_to_bvh",
    "pretrained",
    "read_glb",
    "split_windows",
    "to_source_space",
    "transfer_curve_dataset",
    "validate_glb",
    "window_handles",
    "write_glb",
    "write_preview",
]
