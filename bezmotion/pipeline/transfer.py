"""**Character transfer** (BMM §5.2): a BMM trained on one skeleton drives another through
a :class:`Transfer` — positions scaled by the ratio of standing hip heights about the
start hips' floor point, and the generated global orientations composed with fixed per-joint offsets.

The offsets stand in for the paper's "align both skeletons to the same pose". Two ways to
measure them (:class:`CharacterProfile`, ``Transfer.between(…, orientation=…)``):

- ``"anatomical"`` (default): each joint's frame against a frame its bones make —
  the hips' against the spine and the hip line, the head's against the neck and the
  shoulder line, a hand's (foot's) against its forearm (shin) and elbow's (knee's) hinge
  (:func:`anatomical_frames`). That relation is fixed by how a file lays out its joint axes,
  up to the wrist's, ankle's or neck's own turn, so its mean over a few poses is the
  skeleton's convention whatever the poses are: a user's clip of someone standing still
  gives the same offsets as one of someone waving.
- ``"facing"``: each joint's mean orientation relative to the character's facing. That mean
  is of the poses as much as of the skeleton: measured on a user's own clip (the only
  poses of an unknown skeleton there are), it maps the clip's poses onto the training
  corpus's mean pose (a still clip with hanging arms reads as the corpus's mean hand,
  raised in a third of Bandai-Namco's contents).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion.bmm.sampling import SampledCurves
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
from bezmotion.data.curves import CurveDataset
from bezmotion.geometry.rotations import quat_conjugate, quat_from_matrix, quat_from_rot6d, quat_mul, quat_rotate, rot6d_from_quat
from bezmotion.ik.protocol import Character, Pose, pose_fk, targets_from_pose
from bezmotion.ik.rig import derive_rig_spec
from bezmotion._src.linalg import top_eigenvector
from bezmotion._src.messages import one_line
from bezmotion._src.structured_files import read_structured_file

ORIENTATION_CHOICES = ("anatomical", "facing")
"""How :meth:`Transfer.between` aligns two skeletons' joint orientations (see the module docstring)."""

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
    without LAPACK: :mod:`bezmotion._src.linalg`). Returned with ``w ≥ 0``.
    """
    mean = top_eigenvector(jnp.einsum("si,sj->ij", quat, quat) / quat.shape[0])
    return jnp.where(mean[:1] < 0, -mean, mean)


def _frame(primary: Float[Array, "*batch 3"], secondary: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """The rotation whose columns are ``primary`` (normalised), ``secondary``'s part across it
    (normalised), and their cross product."""
    x = primary / jnp.linalg.norm(primary, axis=-1, keepdims=True)
    y = secondary - jnp.sum(secondary * x, axis=-1, keepdims=True) * x
    y = y / jnp.linalg.norm(y, axis=-1, keepdims=True)
    return jnp.stack([x, y, jnp.cross(x, y)], axis=-1)


# A hinge (thigh × shin, upper arm × forearm, unit bones) is |sin bend| long; the body's forward
# direction, this long, takes over where the limb is straight and the hinge says nothing.
_STRAIGHT_LIMB_FALLBACK = 0.05


def anatomical_frames(character: Character, poses: Pose) -> Float[Array, "*batch 6 3 3"]:
    """The frames the six joints' bones make (world from frame), pose by pose, for the
    ``"anatomical"`` orientation offsets (see the module docstring):

    - hips: along the first spine bone, then the hip line (right upper leg to left);
    - head: along the neck (its parent to it), then the shoulder line (right upper arm to left);
    - hands and feet: along the forearm and shin, then the elbow's or knee's hinge (upper bone ×
      lower bone), or the body's forward direction where the limb is straight.

    The limbs are the rig's chains (:func:`~bezmotion.ik.rig.derive_rig_spec`: twist joints
    skipped).
    """
    spec = derive_rig_spec(character)
    index = {name: j for j, name in enumerate(character.skeleton.names)}
    spine = [index[n] for n in spec.spine]
    arms = [[index[n] for n in chain] for chain in (spec.left_arm, spec.right_arm)]
    legs = [[index[n] for n in chain] for chain in (spec.left_leg, spec.right_leg)]
    _, pos = pose_fk(character, poses)
    hips = _frame(pos[..., spine[1], :] - pos[..., spine[0], :], pos[..., legs[0][0], :] - pos[..., legs[1][0], :])
    head = _frame(pos[..., spine[-1], :] - pos[..., spine[-2], :], pos[..., arms[0][0], :] - pos[..., arms[1][0], :])
    forward = hips[..., 2]  # spine × hip line: the pelvis' forward
    limbs = []
    for upper, middle, end in (*arms, *legs):
        a = pos[..., middle, :] - pos[..., upper, :]
        b = pos[..., end, :] - pos[..., middle, :]
        hinge = jnp.cross(a / jnp.linalg.norm(a, axis=-1, keepdims=True), b / jnp.linalg.norm(b, axis=-1, keepdims=True))
        limbs.append(_frame(b, hinge + _STRAIGHT_LIMB_FALLBACK * forward))
    return jnp.stack([hips, head, *limbs], axis=-3)


@dataclasses.dataclass(frozen=True)
class CharacterProfile:
    """What a transfer needs to know about one character.

    Attributes:
      height: the hips' median height above the floor (cm), the floor being the 5th
        percentile of the ankle heights: a standing-height measure taken from motion, so
        it does not depend on how a skeleton's rest pose or joints are laid out.
      mean_orientation: ``(6, 4)`` chordal mean over many poses of each characteristic
        joint's global orientation relative to the character's facing (:func:`facing_yaw`).
      anatomical_offset: ``(6, 4)`` chordal mean over the same poses of each joint's frame
        as seen from its own (:func:`anatomical_frames`: ``Rᵀ A``); None for a profile
        written without it.
      facing: the poses' mean facing (degrees about +Y from +Z: :func:`facing_yaw`'s angle,
        their circular mean); for a training corpus, the way a BMM trained on it expects a
        motion to start (:func:`placement`). None for a profile written without it.
    """

    height: float
    mean_orientation: Float[np.ndarray, "6 4"]
    anatomical_offset: Float[np.ndarray, "6 4"] | None = None
    facing: float | None = None

    @classmethod
    def from_poses(cls, character: Character, poses: Pose) -> CharacterProfile:
        """Profile from a batch of poses ``(samples, …)`` of the character (e.g. its corpus)."""
        targets = targets_from_pose(character, poses)
        quat = quat_from_rot6d(targets.rot6d)
        yaw = facing_yaw(targets.position)
        relative = quat_mul(quat_conjugate(yaw)[..., None, :], quat)
        mean = jax.vmap(mean_rotation, in_axes=1)(relative)
        anatomical = quat_mul(quat_conjugate(quat), quat_from_matrix(anatomical_frames(character, poses)))
        offset = jax.vmap(mean_rotation, in_axes=1)(anatomical)
        pos = np.asarray(targets.position)
        floor = np.percentile(pos[:, 4:6, 1], 5.0)
        yaw = np.asarray(yaw, np.float64)
        angle = 2.0 * np.arctan2(yaw[:, 2], yaw[:, 0])  # about +Y from +Z
        facing = float(np.degrees(np.arctan2(np.sin(angle).mean(), np.cos(angle).mean())))
        return cls(float(np.median(pos[:, HIPS, 1]) - floor), np.asarray(mean, np.float64), np.asarray(offset, np.float64), facing)

    def to_json(self) -> dict:
        data = {"height": self.height, "mean_orientation": np.asarray(self.mean_orientation).tolist()}
        if self.anatomical_offset is not None:
            data["anatomical_offset"] = np.asarray(self.anatomical_offset).tolist()
        if self.facing is not None:
            data["facing_deg"] = self.facing
        return data

    @classmethod
    def load(cls, path: str | os.PathLike) -> CharacterProfile:
        """Read a profile written by ``experiments/character_profiles.py`` (e.g. ``PROFILES_DIR / "lafan1.json"``)."""
        path = Path(path)
        try:
            return cls.from_json(read_structured_file(path))
        except (KeyError, ValueError, TypeError, IndexError, AttributeError) as e:
            raise ValueError(f"{path}: not a character profile ({one_line(e, 160)})") from None

    @classmethod
    def from_json(cls, data: dict) -> CharacterProfile:
        def rotations(name: str) -> np.ndarray:
            quat = np.asarray(data[name], np.float64)
            if quat.shape != (len(CHARACTERISTIC_JOINTS), 4) or not np.isfinite(quat).all():
                raise ValueError(f"{name} must be a finite (6, 4) array, got {quat.shape}")
            norms = np.linalg.norm(quat, axis=-1)
            if np.any(np.abs(norms - 1.0) > 1e-3):
                raise ValueError(f"{name} must hold unit quaternions, got norms {norms.round(4).tolist()}")
            return quat

        if not float(data["height"]) > 0:
            raise ValueError(f"height must be positive, got {data['height']}")
        offset = rotations("anatomical_offset") if "anatomical_offset" in data else None
        facing = None if "facing_deg" not in data else float(data["facing_deg"])
        if facing is not None and not np.isfinite(facing):
            raise ValueError(f"facing_deg must be a finite angle, got {data['facing_deg']}")
        return cls(float(data["height"]), rotations("mean_orientation"), offset, facing)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Transfer:
    """Maps curves from a BMM's training character to a target character.

    Attributes:
      scale: target height ÷ source height (scalar array).
      rot_offset: ``(6, 4)`` per-joint offsets: ``q_target = q_source ⊗ rot_offset``.
      facing: ``(4,)`` the turn about +Y taking +Z to the way the BMM's training motions
        face (:attr:`CharacterProfile.facing`), or None. A BMM trained without yaw
        augmentation on a corpus whose actors mostly face one way knows motion facing that
        way; with a facing, each in-between is turned about the start hips to start facing
        it in the BMM's space, and back (:func:`placement`). None: the keys as they face
        (the paper's). docs/skeletons.md measures both.
    """

    scale: Float[Array, ""]
    rot_offset: Float[Array, "6 4"]
    facing: Float[Array, "4"] | None = None

    @classmethod
    def identity(cls, facing: float | None = None) -> Transfer:
        """No transfer: the BMM was trained on the target character; ``facing`` (degrees, its
        training corpus's :attr:`CharacterProfile.facing`) as in :meth:`between`."""
        rot = jnp.zeros((len(CHARACTERISTIC_JOINTS), 4), jnp.float32).at[:, 0].set(1.0)
        return cls(jnp.asarray(1.0, jnp.float32), rot, _yaw_quat(facing))

    @classmethod
    def between(
        cls, source: CharacterProfile, target: CharacterProfile, *, orientation: str = "anatomical", facing: bool = True
    ) -> Transfer:
        """The transfer from ``source`` to ``target``: their heights' ratio, and orientation
        offsets that align (see the module docstring)

        - ``"anatomical"``: each joint's frame against its bones' (``q_s a_s = q_t a_t``, so
          ``offset = a_s a_t⁻¹``); where a profile has no ``anatomical_offset``, ``"facing"``;
        - ``"facing"``: each joint's mean orientation relative to the facing (``offset = m_s⁻¹ m_t``).

        ``facing``: turn each in-between to start facing the way ``source``'s motions do
        (its :attr:`CharacterProfile.facing`, where it has one; see :attr:`Transfer.facing`).

        Raises:
          ValueError: another ``orientation``.
        """
        if orientation not in ORIENTATION_CHOICES:
            raise ValueError(f"orientation must be one of {', '.join(ORIENTATION_CHOICES)}, got {orientation!r}")
        if orientation == "anatomical" and source.anatomical_offset is not None and target.anatomical_offset is not None:
            offset = quat_mul(jnp.asarray(source.anatomical_offset), quat_conjugate(jnp.asarray(target.anatomical_offset)))
        else:
            offset = quat_mul(quat_conjugate(jnp.asarray(source.mean_orientation)), jnp.asarray(target.mean_orientation))
        return cls(
            jnp.asarray(target.height / source.height, jnp.float32), offset.astype(jnp.float32), _yaw_quat(source.facing if facing else None)
        )


def _yaw_quat(degrees: float | None) -> Float[Array, "4"] | None:
    """The turn by ``degrees`` about +Y (w, x, y, z), float32; None for None."""
    if degrees is None:
        return None
    half = 0.5 * np.radians(degrees)
    return jnp.asarray([np.cos(half), 0.0, np.sin(half), 0.0], jnp.float32)


class Placement(NamedTuple):
    """Where one in-between sits in the BMM's space: ``p_bmm = origin + turn (p − origin) / scale``.

    Attributes:
      origin: ``(3,)`` the start hips on the floor (:func:`floor_anchor`), which positions
        are scaled and turned about.
      turn: ``(4,)`` a turn about +Y (identity: none).
    """

    origin: Float[Array, "3"]
    turn: Float[Array, "4"]


def placement(transfer: Transfer, start: Float[Array, "6 3"]) -> Placement:
    """The placement of an in-between whose first key's six joints are at ``start`` (cm):
    about its hips on the floor, turned (when ``transfer.facing`` is set) so that the key
    faces (:func:`facing_yaw`) the way the BMM's training motions do."""
    origin = floor_anchor(start[HIPS])
    if transfer.facing is None:
        return Placement(origin, jnp.asarray([1.0, 0.0, 0.0, 0.0], start.dtype))
    turn = quat_mul(transfer.facing.astype(start.dtype), quat_conjugate(facing_yaw(start)))
    return Placement(origin, turn)


def _origin_turn(anchor: Float[Array, "3"] | Placement) -> tuple[Array, Array | None]:
    return (anchor.origin, anchor.turn) if isinstance(anchor, Placement) else (anchor, None)


def floor_anchor(start_hips: Float[Array, "3"]) -> Float[Array, "3"]:
    """The point positions are scaled about: the start hips projected to the floor (y = 0)."""
    return start_hips * jnp.asarray([1.0, 0.0, 1.0], start_hips.dtype)


def to_source_space(
    transfer: Transfer, anchor: Float[Array, "3"] | Placement, position: Float[Array, "*batch 3"]
) -> Float[Array, "*batch 3"]:
    """Target-character positions → the BMM's training-character positions, scaled about
    ``anchor`` (a point, or a :class:`Placement` that also turns them)."""
    origin, turn = _origin_turn(anchor)
    moved = (position - origin) / transfer.scale
    return origin + (moved if turn is None else quat_rotate(turn.astype(position.dtype), moved))


def orientations_to_source_space(
    transfer: Transfer, rot6d: Float[Array, "*batch 6 6"], turn: Float[Array, "4"] | None = None
) -> Float[Array, "*batch 6 6"]:
    """Target-character global orientations of the six joints → the training character's
    (the inverse of :func:`curves_to_target`'s ``turn⁻¹ ⊗ q_source ⊗ rot_offset``)."""
    offset = quat_conjugate(transfer.rot_offset.astype(rot6d.dtype))
    quat = quat_mul(quat_from_rot6d(rot6d), offset)
    return rot6d_from_quat(quat if turn is None else quat_mul(turn.astype(rot6d.dtype), quat))


def curves_to_target(transfer: Transfer, anchor: Float[Array, "3"] | Placement, curves: SampledCurves) -> SampledCurves:
    """Sampled curves of the source character → the target character (positions, tangents,
    orientations), the inverse of :func:`to_source_space` and :func:`orientations_to_source_space`."""
    origin, turn = _origin_turn(anchor)
    dtype = curves.ctrl_rot6d.dtype
    back = None if turn is None else quat_conjugate(turn.astype(dtype))
    unturn = (lambda v: v) if back is None else (lambda v: quat_rotate(back, v))  # noqa: E731
    quat = quat_mul(quat_from_rot6d(curves.ctrl_rot6d), transfer.rot_offset.astype(dtype))
    return SampledCurves(
        origin + unturn(curves.ctrl_pos - origin) * transfer.scale,
        unturn(curves.ctrl_tangent) * transfer.scale,
        rot6d_from_quat(quat if back is None else quat_mul(back, quat)),
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
