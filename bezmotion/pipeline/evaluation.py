"""Metrics of the full pipeline, after IK, on a corpus's validation windows (BMM Table 1).

The evaluation windows are those of :func:`bezmotion.bmm.evaluation.make_eval_set` (same
handles, same OOD noise); here each window also carries the ground-truth full-body poses
of the target character, so the start and end poses are real and MPJPE can be measured.
Everything is in the windows' aligned frame (hips start at the origin in XZ).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.bmm.evaluation import EvalSet, map_in_chunks
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import CurveDataset
from bezmotion.ik.protocol import Character, IKFn, Pose, pose_fk, pose_from_motion, targets_from_pose
from bezmotion.metrics import foot_skating_ratio, key_pop_deg, mean_position_error, rotation_change_deg
from bezmotion.pipeline.inbetweening import KEY_BLEND_FRAMES, inbetween_traced
from bezmotion.pipeline.transfer import Transfer
from bezmotion.metrics import handles_error
from jaxtyping import Array, Float
from bezmotion.bmm.sampling import BezierMotionModel, Handles


def full_body_handles_error(
    character: Character, pose: Pose, handles: Handles, stride: int
) -> Float[Array, ""]:
    """Mean distance (cm) between each valid handle and the IK'd skeleton's joint at its
    frame (BMM Table 1, measured after IK). ``pose`` is ``(*batch, frames, …)``, handles
    ``(*batch, handles)`` at any frame (``stride`` is no longer needed; kept for callers)."""
    _, pos = pose_fk(character, pose)
    characteristic = pos[..., np.asarray(character.characteristic), :]  # (*batch, frames, 6, 3)
    return handles_error(characteristic, handles.frame, handles.joint, handles.position, handles.valid)


def mpjpe(character: Character, pose: Pose, true: Pose) -> Float[Array, ""]:
    """Mean per-joint position error (cm) over every joint and frame."""
    return mean_position_error(pose_fk(character, pose)[1], pose_fk(character, true)[1])


def window_poses(character: Character, clips: MotionClips, dataset: CurveDataset, rows: np.ndarray) -> Pose:
    """Ground-truth poses ``(windows, frames, …)`` of dataset windows ``rows``, aligned like
    the dataset (the start hips at the origin in XZ).

    Args:
      clips: the clips ``dataset`` was built from (e.g. :func:`~bezmotion.data.corpus.motion_clips`).
    """
    frames = dataset.layout.num_frames
    first = clips.starts[dataset.clip_index[rows]] + dataset.start_frame[rows]
    index = first[:, None] + np.arange(frames)
    pose = pose_from_motion(
        character, jnp.asarray(clips.quat_local[index], jnp.float32), jnp.asarray(clips.pos_local[index], jnp.float32)
    )
    shift = pose.root_pos[:, :1] * jnp.asarray([1.0, 0.0, 1.0], jnp.float32)
    return pose._replace(root_pos=pose.root_pos - shift)


@dataclasses.dataclass(frozen=True)
class PipelineMetricsConfig:
    """Settings of the after-IK metrics: the curves' stride, frame rate and the character's
    ankle height with the foot flat (cm; :func:`~bezmotion.bmm.evaluation.floor_height_from`)."""

    stride: int
    fps: float
    floor_height: float


def pose_metrics(
    config: PipelineMetricsConfig, character: Character, pose: Pose, truth: Pose, handles: Handles
) -> dict[str, float]:
    """Handles error (full skeleton), foot-skating ratio, MPJPE and key pop (largest per-frame
    joint rotation change at the first and last frame pair, degrees) of ``pose`` ``(windows, frames, …)``."""
    _, pos = pose_fk(character, pose)
    _, true_pos = pose_fk(character, truth)
    feet = np.asarray(character.characteristic[4:6])
    return {
        "handles_error_cm": float(full_body_handles_error(character, pose, handles, config.stride)),
        "foot_skating_ratio": float(foot_skating_ratio(pos[..., feet, :], config.fps, floor_height=config.floor_height)),
        "mpjpe_cm": float(mean_position_error(pos, true_pos)),
        "key_pop_deg": float(key_pop_deg(pose.quat_local)),
    }


def ground_truth_pose_metrics(
    config: PipelineMetricsConfig, character: Character, truth: Pose, ik_fn: IKFn | None = None, ik_params: Any = None
) -> dict[str, float]:
    """The mocap's own foot skating; with an IK, also the IK's floor: MPJPE of IK applied to
    the true six-joint trajectories (positions and orientations) of every frame."""
    _, pos = pose_fk(character, truth)
    feet = np.asarray(character.characteristic[4:6])
    out = {
        "foot_skating_ratio": float(foot_skating_ratio(pos[..., feet, :], config.fps, floor_height=config.floor_height)),
        "key_pop_deg": float(key_pop_deg(truth.quat_local)),
        "max_rotation_change_deg": float(jnp.max(rotation_change_deg(truth.quat_local))),
    }
    if ik_fn is not None:
        ik = jax.jit(jax.vmap(jax.vmap(ik_fn, in_axes=(None, 0)), in_axes=(None, 0)))
        recon = map_in_chunks(lambda t, _: ik(ik_params, t), targets_from_pose(character, truth), key=jax.random.key(0))
        _, rpos = pose_fk(character, recon)
        out["ik_of_mocap_mpjpe_cm"] = float(mean_position_error(rpos, pos))
        out["ik_of_mocap_foot_skating_ratio"] = float(
            foot_skating_ratio(rpos[..., feet, :], config.fps, floor_height=config.floor_height)
        )
    return out


@functools.partial(jax.jit, static_argnames=("ik_fn", "steps", "foot_lock", "key_blend_frames", "key_orientations"))
def _run_chunk(bmm, ik_params, character, transfer, inputs, key, *, ik_fn, steps, foot_lock, key_blend_frames, key_orientations) -> Pose:
    """:func:`~bezmotion.pipeline.inbetweening.inbetween` of a chunk of windows; one compilation per IK,
    settings and shapes, shared by every call (evaluate_pipeline's in-distribution and OOD runs)."""
    one = functools.partial(
        inbetween_traced, ik_fn=ik_fn, steps=steps, guidance=1.0, foot_lock=foot_lock, keep_keyframes=True,
        key_blend_frames=key_blend_frames, key_orientations=key_orientations,
    )  # fmt: skip
    start, end, handles = inputs
    keys = jax.random.split(key, start.root_pos.shape[0])
    run = lambda s, e, h, k: one(bmm, ik_params, character, s, e, h, transfer, k).pose  # noqa: E731
    return jax.vmap(run)(start, end, handles, keys)


def run_pipeline(
    bmm: BezierMotionModel,
    ik_fn: IKFn,
    ik_params: Any,
    character: Character,
    truth: Pose,
    handles: Handles,
    *,
    key: jax.Array,
    transfer: Transfer | None = None,
    steps: int = 10,
    foot_lock: bool = False,
    chunk: int = 128,
    key_blend_frames: int = KEY_BLEND_FRAMES,
    key_orientations: bool = True,
) -> Pose:
    """In-between every window (start and end from ``truth``) through ``handles``; poses ``(windows, frames, …)``."""
    transfer = Transfer.identity() if transfer is None else transfer
    batch = functools.partial(
        _run_chunk, bmm, ik_params, character, transfer, ik_fn=ik_fn, steps=steps, foot_lock=foot_lock,
        key_blend_frames=key_blend_frames, key_orientations=key_orientations,
    )  # fmt: skip
    first = jax.tree.map(lambda x: x[:, 0], truth)
    last = jax.tree.map(lambda x: x[:, -1], truth)
    return map_in_chunks(batch, (first, last, handles), key=key, chunk=chunk)


def evaluate_pipeline(
    config: PipelineMetricsConfig,
    bmm: BezierMotionModel,
    ik_fn: IKFn,
    ik_params: Any,
    character: Character,
    truth: Pose,
    eval_set: EvalSet,
    *,
    key: jax.Array,
    transfer: Transfer | None = None,
    foot_lock: bool = False,
    key_blend_frames: int = KEY_BLEND_FRAMES,
    key_orientations: bool = True,
    chunk: int = 128,
) -> dict[str, dict[str, float]]:
    """After-IK metrics in distribution and OOD (handles with ±16 cm noise), 10 DDIM steps."""
    out = {}
    for name, handles in (("id", eval_set.handles), ("ood", eval_set.handles_ood)):
        pose = run_pipeline(
            bmm, ik_fn, ik_params, character, truth, handles, key=key, transfer=transfer, foot_lock=foot_lock,
            key_blend_frames=key_blend_frames, key_orientations=key_orientations, chunk=chunk,
        )  # fmt: skip
        out[name] = pose_metrics(config, character, pose, truth, handles)
    return out
