"""The full in-betweening pipeline: poses and handles in, a full-body motion out.

    start pose, end pose, handles ──▶ BMM curves of the six characteristic joints
        ──▶ dense trajectories (Bézier positions, slerped orientations)
        ──▶ ik_fn per frame ──▶ full-body poses of the target character ──▶ BVH

:func:`inbetween` is one jit-compiled function of arrays; the IK module is an argument
(``ik_fn(params, targets) -> pose``, :mod:`bezmotion.ik.protocol`), so any learned,
analytic or user-written IK drives any character.

**Character transfer** (BMM §5.2): a BMM trained on one skeleton drives another through
a :class:`Transfer` — positions scaled by the ratio of standing hip heights about the
start hips' floor point, and the generated global orientations composed with fixed per-joint offsets.
The offsets come from each character's mean characteristic-joint orientation relative
to its facing (:class:`CharacterProfile`), the data-driven stand-in for the paper's
"align both skeletons to the same pose".
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion._xla import call_with_inference_options
from bezmotion.bezier import BezierLayout, reconstruct_dense
from bezmotion.data.bvh import BvhMotion
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
from bezmotion.geometry.rotations import (
    matrix_from_quat,
    quat_conjugate,
    quat_from_matrix,
    quat_from_rot6d,
    quat_mul,
    rot6d_from_quat,
)
from bezmotion.ik.protocol import Character, IKFn, IKTargets, Pose, pose_fk, pose_local, targets_from_pose
from bezmotion.metrics import handles_error, mean_position_error
from bezmotion.sampling import BezierMotionModel, Handles, SampledCurves, sample_curves

LEFT = tuple(CHARACTERISTIC_JOINTS.index(j) for j in ("left_hand", "left_foot"))
RIGHT = tuple(CHARACTERISTIC_JOINTS.index(j) for j in ("right_hand", "right_foot"))
_UP = np.asarray([0.0, 1.0, 0.0])


# ----------------------------------------------------------------------------- transfer


def facing_yaw(positions: Float[Array, "*batch 6 3"]) -> Float[Array, "*batch 4"]:
    """The character's facing as a rotation about +Y taking +Z to its forward direction.

    Forward is horizontal and perpendicular to the left-minus-right vector of the hands
    and feet, so it is defined by positions alone, whatever a skeleton's joint axes are.
    """
    left = positions[..., LEFT, :].mean(-2) - positions[..., RIGHT, :].mean(-2)
    forward = jnp.cross(left, jnp.asarray(_UP, positions.dtype))
    angle = jnp.arctan2(forward[..., 0], forward[..., 2])
    half = 0.5 * angle
    zero = jnp.zeros_like(half)
    return jnp.stack([jnp.cos(half), zero, jnp.sin(half), zero], axis=-1)


def mean_rotation(quat: Float[Array, "samples 4"]) -> Float[Array, "4"]:
    """Chordal mean of rotations: the rotation nearest (Frobenius) to the mean matrix."""
    u, _, vt = jnp.linalg.svd(matrix_from_quat(quat).mean(0))
    d = jnp.sign(jnp.linalg.det(u @ vt))
    return quat_from_matrix(u @ jnp.diag(jnp.asarray([1.0, 1.0, 1.0], quat.dtype).at[2].set(d)) @ vt)


@dataclasses.dataclass(frozen=True)
class CharacterProfile:
    """What a transfer needs to know about one character.

    Attributes:
      height: the hips' median height above the floor (cm), the floor being the 5th
        percentile of the ankle heights: a standing-height measure taken from motion, so
        it does not depend on how a skeleton's rest pose or joints are laid out.
      mean_orientation: ``(6, 4)`` chordal mean over many poses of each characteristic
        joint's global orientation relative to the character's facing (:func:`facing_yaw`).
    """

    height: float
    mean_orientation: np.ndarray

    @classmethod
    def from_poses(cls, character: Character, poses: Pose) -> CharacterProfile:
        """Profile from a batch of poses ``(samples, …)`` of the character (e.g. its corpus)."""
        targets = targets_from_pose(character, poses)
        yaw = facing_yaw(targets.position)
        relative = quat_mul(quat_conjugate(yaw)[..., None, :], quat_from_rot6d(targets.rot6d))
        mean = jax.vmap(mean_rotation, in_axes=1)(relative)
        pos = np.asarray(targets.position)
        floor = np.percentile(pos[:, 4:6, 1], 5.0)
        return cls(float(np.median(pos[:, HIPS, 1]) - floor), np.asarray(mean, np.float64))

    def to_json(self) -> dict:
        return {"height": self.height, "mean_orientation": np.asarray(self.mean_orientation).tolist()}

    @classmethod
    def load(cls, path: str | os.PathLike) -> CharacterProfile:
        """Read a profile written by ``experiments/character_profiles.py`` (e.g. ``PROFILES_DIR / "lafan1.json"``)."""
        path = Path(path)
        try:
            return cls.from_json(json.loads(path.read_text()))
        except (KeyError, ValueError, TypeError) as e:
            raise ValueError(f"{path}: not a character profile ({e})") from None

    @classmethod
    def from_json(cls, data: dict) -> CharacterProfile:
        mean = np.asarray(data["mean_orientation"], np.float64)
        if mean.shape != (len(CHARACTERISTIC_JOINTS), 4) or not np.isfinite(mean).all():
            raise ValueError(f"mean_orientation must be a finite (6, 4) array, got {mean.shape}")
        norms = np.linalg.norm(mean, axis=-1)
        if np.any(np.abs(norms - 1.0) > 1e-3):
            raise ValueError(f"mean_orientation must hold unit quaternions, got norms {norms.round(4).tolist()}")
        if not float(data["height"]) > 0:
            raise ValueError(f"height must be positive, got {data['height']}")
        return cls(float(data["height"]), mean)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Transfer:
    """Maps curves from a BMM's training character to a target character.

    Attributes:
      scale: target height ÷ source height (scalar array).
      rot_offset: ``(6, 4)`` per-joint offsets: ``q_target = q_source ⊗ rot_offset``.
    """

    scale: Float[Array, ""]
    rot_offset: Float[Array, "6 4"]

    @classmethod
    def identity(cls) -> Transfer:
        """No transfer: the BMM was trained on the target character."""
        rot = jnp.zeros((len(CHARACTERISTIC_JOINTS), 4), jnp.float32).at[:, 0].set(1.0)
        return cls(jnp.asarray(1.0, jnp.float32), rot)

    @classmethod
    def between(cls, source: CharacterProfile, target: CharacterProfile) -> Transfer:
        """The transfer aligning ``source``'s mean orientations and height to ``target``'s."""
        src, tgt = jnp.asarray(source.mean_orientation), jnp.asarray(target.mean_orientation)
        offset = quat_mul(quat_conjugate(src), tgt)
        return cls(jnp.asarray(target.height / source.height, jnp.float32), offset.astype(jnp.float32))


def _anchor(start_hips: Float[Array, "3"]) -> Float[Array, "3"]:
    """The point positions are scaled about: the start hips projected to the floor (y = 0)."""
    return start_hips * jnp.asarray([1.0, 0.0, 1.0], start_hips.dtype)


def to_source_space(transfer: Transfer, anchor: Float[Array, "3"], position: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """Target-character positions → the BMM's training-character positions."""
    return anchor + (position - anchor) / transfer.scale


def curves_to_target(transfer: Transfer, anchor: Float[Array, "3"], curves: SampledCurves) -> SampledCurves:
    """Sampled curves of the source character → the target character (positions, tangents, orientations)."""
    quat = quat_mul(quat_from_rot6d(curves.ctrl_rot6d), transfer.rot_offset.astype(curves.ctrl_rot6d.dtype))
    return SampledCurves(
        anchor + (curves.ctrl_pos - anchor) * transfer.scale,
        curves.ctrl_tangent * transfer.scale,
        rot6d_from_quat(quat),
        curves.contacts,
    )


# ----------------------------------------------------------------------------- pipeline


class InbetweenResult(NamedTuple):
    """One in-betweened window of the target character (world frame, cm).

    Attributes:
      pose: :class:`~bezmotion.ik.protocol.Pose` per frame, ``(frames, …)``.
      curves: the BMM curves in the target character's space.
      positions: ``(frames, 6, 3)`` dense characteristic-joint trajectories given to IK.
      rot6d: ``(frames, 6, 6)`` dense characteristic-joint orientations given to IK.
    """

    pose: Pose
    curves: SampledCurves
    positions: Float[Array, "frames 6 3"]
    rot6d: Float[Array, "frames 6 6"]


def _inbetween(
    bmm: BezierMotionModel,
    ik_params: Any,
    character: Character,
    start: Pose,
    end: Pose,
    handles: Handles,
    transfer: Transfer,
    key: Array,
    *,
    ik_fn: IKFn,
    steps: int,
    guidance: float,
    foot_lock: bool,
    keep_keyframes: bool,
) -> InbetweenResult:
    cfg = bmm.config
    first, last = targets_from_pose(character, start), targets_from_pose(character, end)
    anchor = _anchor(first.position[HIPS])
    source = functools.partial(to_source_space, transfer, anchor)
    curves = sample_curves(
        bmm, source(first.position), source(last.position), handles._replace(position=source(handles.position)),
        key=key, steps=steps, guidance=guidance, foot_lock=foot_lock,
    )  # fmt: skip
    curves = curves_to_target(transfer, anchor, curves)
    # The end control points are the given poses themselves: their positions exactly
    # (undoing the scale round trip's rounding) and their orientations, which BMM does
    # not take as conditions.
    ends = jnp.asarray([0, cfg.num_controls - 1])
    curves = curves._replace(
        ctrl_pos=curves.ctrl_pos.at[ends].set(jnp.stack([first.position, last.position])),
        ctrl_rot6d=curves.ctrl_rot6d.at[ends].set(jnp.stack([first.rot6d, last.rot6d])),
    )
    # Padding slots are sent out of range and dropped, so that one sharing a handle's place
    # cannot write over it.
    control = jnp.where(handles.valid, handles.control, cfg.num_controls)
    curves = curves._replace(ctrl_pos=curves.ctrl_pos.at[control, handles.joint].set(handles.position, mode="drop"))
    layout = BezierLayout.from_controls(cfg.num_controls, cfg.stride)
    positions, rot6d = reconstruct_dense(layout, curves.ctrl_pos, curves.ctrl_tangent, curves.ctrl_rot6d)
    pose = jax.vmap(ik_fn, in_axes=(None, 0))(ik_params, IKTargets(positions, rot6d))
    if keep_keyframes:
        pose = jax.tree.map(lambda p, a, b: p.at[0].set(a).at[-1].set(b), pose, start, end)
    return InbetweenResult(pose, curves, positions, rot6d)


@functools.cache
def _compiled(options: tuple[tuple[str, str], ...]):
    return jax.jit(
        _inbetween, static_argnames=("ik_fn", "steps", "guidance", "foot_lock", "keep_keyframes"),
        compiler_options=dict(options) or None,
    )  # fmt: skip


def inbetween(
    bmm: BezierMotionModel,
    ik_fn: IKFn,
    ik_params: Any,
    character: Character,
    start: Pose,
    end: Pose,
    handles: Handles,
    *,
    key: Array,
    transfer: Transfer | None = None,
    steps: int = 10,
    guidance: float = 1.0,
    foot_lock: bool = False,
    keep_keyframes: bool = True,
) -> InbetweenResult:
    """In-between a window of ``character`` from ``start`` to ``end`` through ``handles``.

    Args:
      bmm: a trained BMM (:func:`bezmotion.sampling.load_model`); its window is
        ``bmm.config.num_frames`` frames (31), the start pose at frame 0, the end at the last.
      ik_fn, ik_params: the character's IK module (one frame; vmapped over the window).
      character: the target skeleton and its characteristic joints.
      start, end: unbatched :class:`~bezmotion.ik.protocol.Pose` of the first and last frame.
      handles: intermediate handles in the target character's world frame
        (:meth:`Handles.from_frames`: joint name, control frame, position in cm).
      key: PRNG key of the diffusion sampler.
      transfer: when the BMM was trained on another skeleton (:meth:`Transfer.between`);
        default none.
      steps, guidance, foot_lock: passed to :func:`~bezmotion.sampling.sample_curves`.
      keep_keyframes: output the given start and end poses at the first and last frame
        (rather than their IK reconstruction), so the window joins its neighbours exactly.
    Returns:
      :class:`InbetweenResult`; its curves pass through every handle exactly, so the
      full-body handle error is the IK module's alone.

    Raises:
      ValueError: poses not of this character, or handles not of one motion.
    """
    if start.quat_local.shape != (character.num_joints, 4) or end.quat_local.shape != start.quat_local.shape:
        raise ValueError(
            f"start and end must be single poses of {character.name} ({character.num_joints} joints): quat_local "
            f"{start.quat_local.shape}, {end.quat_local.shape}"
        )
    if handles.position.ndim != 2:
        raise ValueError(f"handles must describe one motion ((handles, 3) positions), got {handles.position.shape}")
    for name, pose in (("start", start), ("end", end)):
        if any(isinstance(x, jax.core.Tracer) for x in pose):
            continue  # inside a caller's jit: values are unknown until run time
        if not (np.isfinite(np.asarray(pose.root_pos)).all() and np.isfinite(np.asarray(pose.quat_local)).all()):
            raise ValueError(f"the {name} pose contains non-finite values")
    transfer = Transfer.identity() if transfer is None else transfer
    return call_with_inference_options(
        _compiled, bmm, ik_params, character, start, end, handles, transfer, key,
        ik_fn=ik_fn, steps=steps, guidance=guidance, foot_lock=foot_lock, keep_keyframes=keep_keyframes,
    )  # fmt: skip


# ----------------------------------------------------------------------------- metrics and export


def full_body_handles_error(
    character: Character, pose: Pose, handles: Handles, stride: int
) -> Float[Array, ""]:
    """Mean distance (cm) between each valid handle and the IK'd skeleton's joint at its
    frame (BMM Table 1, measured after IK). ``pose`` is ``(*batch, frames, …)``, handles
    ``(*batch, handles)``; handles sit on control frames, every ``stride`` frames."""
    _, pos = pose_fk(character, pose)
    at_controls = pos[..., ::stride, :, :][..., np.asarray(character.characteristic), :]  # (*batch, controls, 6, 3)
    return handles_error(at_controls, handles.control, handles.joint, handles.position, handles.valid)


def mpjpe(character: Character, pose: Pose, true: Pose) -> Float[Array, ""]:
    """Mean per-joint position error (cm) over every joint and frame."""
    return mean_position_error(pose_fk(character, pose)[1], pose_fk(character, true)[1])


def default_channels(character: Character) -> tuple[tuple[str, ...], ...]:
    """BVH channels: 6 (position, ZYX rotation) on the hips and the joints above it, ZYX rotations elsewhere."""
    moving = {character.hips, *character.ancestors_of_hips()}
    rotation = ("Zrotation", "Yrotation", "Xrotation")
    position = ("Xposition", "Yposition", "Zposition")
    return tuple((position + rotation) if j in moving else rotation for j in range(character.num_joints))


def pose_to_bvh(
    character: Character,
    poses: Pose,
    *,
    fps: float = 30.0,
    channels: tuple[tuple[str, ...], ...] | None = None,
) -> BvhMotion:
    """A :class:`~bezmotion.data.bvh.BvhMotion` of ``poses`` ``(frames, …)`` for
    :func:`~bezmotion.data.bvh.write_bvh` (float64; channels default :func:`default_channels`)."""
    if poses.quat_local.ndim != 3 or poses.quat_local.shape[1:] != (character.num_joints, 4):
        raise ValueError(f"poses must be (frames, {character.num_joints}, 4) for {character.name}, got {poses.quat_local.shape}")
    if poses.root_pos.shape != (poses.quat_local.shape[0], 3):
        raise ValueError(f"poses.root_pos must be ({poses.quat_local.shape[0]}, 3), got {poses.root_pos.shape}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    channels = default_channels(character) if channels is None else tuple(tuple(c) for c in channels)
    if len(channels) != character.num_joints:
        raise ValueError(f"need channels for {character.num_joints} joints, got {len(channels)}")
    with jax.enable_x64(True):
        quat, pos = pose_local(character, Pose(jnp.asarray(poses.root_pos, jnp.float64), jnp.asarray(poses.quat_local, jnp.float64)))
        quat, pos = np.asarray(quat), np.asarray(pos)
    return BvhMotion(character.skeleton, quat, pos, channels, 1.0 / fps, character.end_sites)
