"""**Character transfer** (BMM §5.2): a BMM trained on one skeleton drives another through
a :class:`Transfer` — positions scaled by the ratio of standing hip heights about the
start hips' floor point, and the generated global orientations composed with fixed per-joint offsets.
The offsets come from each character's mean characteristic-joint orientation relative
to its facing (:class:`CharacterProfile`), the data-driven stand-in for the paper's
"align both skeletons to the same pose".
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion.bmm.sampling import SampledCurves
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
from bezmotion.data.curves import CurveDataset
from bezmotion.geometry.rotations import quat_conjugate, quat_from_rot6d, quat_mul, rot6d_from_quat
from bezmotion.ik.protocol import Character, Pose, targets_from_pose
from bezmotion.linalg import top_eigenvector

LEFT = tuple(CHARACTERISTIC_JOINTS.index(j) for j in ("left_hand", "left_foot"))
RIGHT = tuple(CHARACTERISTIC_JOINTS.index(j) for j in ("right_hand", "right_foot"))
_UP = np.asarray([0.0, 1.0, 0.0])


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
    """Chordal mean of rotations: the rotation nearest (Frobenius) to the mean matrix.

    ``tr(R(q)ᵀ R(qᵢ)) = 4 (q·qᵢ)² − 1``, so that rotation is the top eigenvector of the mean
    quaternion outer product (Markley's average; the same as an SVD of the mean matrix,
    without LAPACK: :mod:`bezmotion.linalg`). Returned with ``w ≥ 0``.
    """
    mean = top_eigenvector(jnp.einsum("si,sj->ij", quat, quat) / quat.shape[0])
    return jnp.where(mean[:1] < 0, -mean, mean)


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
    mean_orientation: Float[np.ndarray, "6 4"]

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


def floor_anchor(start_hips: Float[Array, "3"]) -> Float[Array, "3"]:
    """The point positions are scaled about: the start hips projected to the floor (y = 0)."""
    return start_hips * jnp.asarray([1.0, 0.0, 1.0], start_hips.dtype)


def to_source_space(transfer: Transfer, anchor: Float[Array, "3"], position: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """Target-character positions → the BMM's training-character positions."""
    return anchor + (position - anchor) / transfer.scale


def orientations_to_source_space(transfer: Transfer, rot6d: Float[Array, "*batch 6 6"]) -> Float[Array, "*batch 6 6"]:
    """Target-character global orientations of the six joints → the training character's
    (the inverse of :func:`curves_to_target`'s ``q_source ⊗ rot_offset``)."""
    offset = quat_conjugate(transfer.rot_offset.astype(rot6d.dtype))
    return rot6d_from_quat(quat_mul(quat_from_rot6d(rot6d), offset))


def curves_to_target(transfer: Transfer, anchor: Float[Array, "3"], curves: SampledCurves) -> SampledCurves:
    """Sampled curves of the source character → the target character (positions, tangents, orientations)."""
    quat = quat_mul(quat_from_rot6d(curves.ctrl_rot6d), transfer.rot_offset.astype(curves.ctrl_rot6d.dtype))
    return SampledCurves(
        anchor + (curves.ctrl_pos - anchor) * transfer.scale,
        curves.ctrl_tangent * transfer.scale,
        rot6d_from_quat(quat),
        curves.contacts,
    )


def transfer_curve_dataset(dataset: CurveDataset, transfer: Transfer) -> CurveDataset:
    """A curve dataset of one character moved into another's space (training on several corpora).

    The character-agnostic training of BMM §8's future work: a corpus's windows become
    windows of the target character, so one model trains on both — positions, tangents
    and dense trajectories scaled by ``transfer.scale`` about the floor below the start hips
    (the windows are aligned so that this is the origin), global orientations composed with
    the per-joint offsets (``q ⊗ rot_offset``, as :func:`curves_to_target` does). Contacts,
    fit errors and provenance (``clip_index``, ``start_frame``) are kept.

    Args:
      dataset: the source character's curves (aligned: hips start at the origin in XZ).
      transfer: source → target, e.g. ``Transfer.between(lafan1_profile, bandai_namco_profile)``.
    Returns:
      The same windows in the target character's space (float32).
    """
    curves = SampledCurves(
        jnp.asarray(dataset.ctrl_pos), jnp.asarray(dataset.ctrl_tangent), jnp.asarray(dataset.ctrl_rot6d), jnp.asarray(dataset.ctrl_contacts)
    )
    moved = curves_to_target(transfer, jnp.zeros(3, jnp.float32), curves)
    as_numpy = lambda x: np.asarray(x, np.float32)  # noqa: E731
    return dataclasses.replace(
        dataset,
        ctrl_pos=as_numpy(moved.ctrl_pos),
        ctrl_tangent=as_numpy(moved.ctrl_tangent),
        ctrl_rot6d=as_numpy(moved.ctrl_rot6d),
        dense_pos=as_numpy(np.asarray(dataset.dense_pos) * float(transfer.scale)),
    )
