"""The IK protocol: six characteristic-joint targets in, a full-body pose of one character out.

BMM (§4.3) factorises motion into skeleton-agnostic curves of the six characteristic
joints and a skeleton-specific IK module. Every IK module in bezmotion — learned
(:mod:`bezmotion.ik.protores`), analytic (:mod:`bezmotion.ik.rig`) or your own — is a
function ``ik_fn(params, targets) -> pose`` for one frame, written for unbatched inputs
and ``vmap``-ped by the caller. The pipeline never imports a particular IK.

Conventions: positions in centimetres, +Y up, world frame; rotations are global
(world-from-joint) for targets and local (parent-from-joint) for poses; quaternions
(w, x, y, z); orientations ortho6D (:func:`~bezmotion.geometry.rotations.rot6d_from_quat`).

A :class:`Pose` stores the *hips* global position and every joint's local rotation.
Joints above the hips (Bandai-Namco's static ``joint_Root``) are held at identity, so the
hips' local rotation is its global one; :func:`pose_from_motion` re-expresses any motion
in this form without changing a single global joint position.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, NamedTuple, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bezmotion.data.bvh import BvhMotion
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS, characteristic_indices
from bezmotion.geometry.rotations import quat_identity, rot6d_from_quat
from bezmotion.geometry.skeleton import Skeleton, forward_kinematics, inverse_kinematics
from bezmotion.ik.key_blend import blend_to_chain_keys, distances_to_keys
from bezmotion.ik.temporal import FLIP_TURN, KEY_TURN, remove_flips, turn_out_of_keys


class IKTargets(NamedTuple):
    """What an IK module is asked to reach, for the six characteristic joints.

    Attributes:
      position: ``(*batch, 6, 3)`` world positions (cm), :data:`CHARACTERISTIC_JOINTS` order.
      rot6d: ``(*batch, 6, 6)`` global orientations in the *target character's* joint
        convention (a BMM trained on another skeleton is mapped to it by
        :class:`bezmotion.pipeline.transfer.Transfer`'s per-joint ``rot_offset``).
      pinned: ``(*batch, 6)`` which positions are handles the user placed (``None``: none
        is). An IK that weighs its targets (:class:`~bezmotion.ik.exact.ExactIKFn`) hits
        those first where not all six can be met (generated curves are not always
        consistent with the skeleton's bone lengths); the others ignore it.
    """

    position: Float[Array, "*batch 6 3"]
    rot6d: Float[Array, "*batch 6 6"]
    pinned: Bool[Array, "*batch 6"] | None = None


class Pose(NamedTuple):
    """A full-body pose of one character.

    Attributes:
      root_pos: ``(*batch, 3)`` global position of the hips (cm).
      quat_local: ``(*batch, joints, 4)`` local rotations of every joint; joints above the
        hips are identity.
    """

    root_pos: Float[Array, "*batch 3"]
    quat_local: Float[Array, "*batch joints 4"]


@runtime_checkable  # so that annotations with it can be checked at run time (jaxtyping/beartype)
class IKFn(Protocol):
    """``ik_fn(params, targets) -> pose`` for one frame (unbatched; ``vmap`` it)."""

    def __call__(self, params: Any, targets: IKTargets) -> Pose: ...


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Character:
    """A skeleton plus where its six characteristic joints are.

    Attributes:
      skeleton: the joint hierarchy and rest offsets (cm).
      characteristic: indices of hips, head, hands, feet (:data:`CHARACTERISTIC_JOINTS` order).
      name: a label for files and reports.
      end_sites: ``(parent joint, (x, y, z) offset in cm)`` of the skeleton's End Sites,
        kept so that exported BVH files show the head, hand and toe lengths.
    """

    skeleton: Skeleton
    characteristic: tuple[int, ...] = dataclasses.field(metadata=dict(static=True))
    name: str = dataclasses.field(default="character", metadata=dict(static=True))
    end_sites: tuple[tuple[int, tuple[float, float, float]], ...] = dataclasses.field(default=(), metadata=dict(static=True))

    def __post_init__(self) -> None:
        object.__setattr__(self, "characteristic", tuple(int(i) for i in self.characteristic))
        if len(self.characteristic) != len(CHARACTERISTIC_JOINTS):
            raise ValueError(f"need {len(CHARACTERISTIC_JOINTS)} characteristic joints, got {self.characteristic}")
        bad = [i for i in self.characteristic if not 0 <= i < self.skeleton.num_joints]
        if bad:
            raise ValueError(f"characteristic joint indices {bad} out of range for {self.skeleton.num_joints} joints")

    @classmethod
    def from_skeleton(cls, skeleton: Skeleton, mapping: str | Mapping[str, str], name: str | None = None) -> Character:
        """A character from a skeleton and a role → joint-name map (or preset ``"lafan1"``, ``"bandai_namco"``)."""
        label = name if name is not None else (mapping if isinstance(mapping, str) else "character")
        return cls(skeleton, characteristic_indices(skeleton.names, mapping), label)

    @classmethod
    def from_bvh(cls, motion: BvhMotion, mapping: str | Mapping[str, str], name: str | None = None) -> Character:
        """A character from a BVH motion's skeleton (its End Sites kept for export)."""
        character = cls.from_skeleton(motion.skeleton, mapping, name)
        return dataclasses.replace(character, end_sites=tuple(motion.end_sites))

    @property
    def hips(self) -> int:
        """Index of the hips, the joint whose global position a :class:`Pose` stores."""
        return self.characteristic[HIPS]

    @property
    def num_joints(self) -> int:
        return self.skeleton.num_joints

    def ancestors_of_hips(self) -> tuple[int, ...]:
        """Joints strictly above the hips (held at identity in a :class:`Pose`)."""
        chain, j = [], self.skeleton.parents[self.hips]
        while j >= 0:
            chain.append(j)
            j = self.skeleton.parents[j]
        return tuple(chain)

    def rest_hips_parent_position(self) -> Float[Array, "3"]:
        """Global position (cm) of the hips' parent when everything above it is at rest (zero for a root hips)."""
        offsets = jnp.asarray(self.skeleton.offsets)
        above = list(self.ancestors_of_hips())
        return offsets[np.asarray(above)].sum(axis=0) if above else jnp.zeros(3, offsets.dtype)


def pose_local(character: Character, pose: Pose) -> tuple[Float[Array, "*batch joints 4"], Float[Array, "*batch joints 3"]]:
    """Local rotations and translations (every joint, as a BVH stores them) of ``pose``."""
    offsets = jnp.asarray(character.skeleton.offsets, pose.root_pos.dtype)
    batch = pose.root_pos.shape[:-1]
    pos_local = jnp.broadcast_to(offsets, (*batch, character.num_joints, 3))
    hips_local = pose.root_pos - jnp.asarray(character.rest_hips_parent_position(), pose.root_pos.dtype)
    return pose.quat_local, pos_local.at[..., character.hips, :].set(hips_local)


@jax.jit  # eagerly (handles checked against the keys, the editor's edits) one program per shape, not a scan traced each call
def pose_fk(character: Character, pose: Pose) -> tuple[Float[Array, "*batch joints 4"], Float[Array, "*batch joints 3"]]:
    """Global ``(quat, pos)`` of every joint of ``pose`` (cm)."""
    quat_local, pos_local = pose_local(character, pose)
    return forward_kinematics(character.skeleton.parents, quat_local, pos_local)


@jax.jit  # one compiled program per shape; eagerly, forward kinematics runs as hundreds of tiny ones
def pose_from_motion(
    character: Character,
    quat_local: Float[Array | np.ndarray, "*batch joints 4"],
    pos_local: Float[Array | np.ndarray, "*batch joints 3"],
) -> Pose:
    """Re-express motion frames (local rotations and per-joint translations) as :class:`Pose`.

    Global positions are unchanged as long as only the hips and its ancestors are
    translated away from their rest offsets (true of LaFAN1 and Bandai-Namco).
    """
    quat_local, pos_local = jnp.asarray(quat_local), jnp.asarray(pos_local)
    quat_global, pos_global = forward_kinematics(character.skeleton.parents, quat_local, pos_local)
    above = list(character.ancestors_of_hips())
    quat = quat_local.at[..., character.hips, :].set(quat_global[..., character.hips, :])
    if above:
        quat = quat.at[..., above, :].set(quat_identity((len(above),), quat.dtype))
    return Pose(pos_global[..., character.hips, :], quat)


def pose_from_global(character: Character, quat_global: Float[Array, "*batch joints 4"], pos_global: Float[Array, "*batch joints 3"]) -> Pose:
    """A :class:`Pose` from global joint rotations (the hips' position taken from ``pos_global``)."""
    quat_local, pos_local = inverse_kinematics(character.skeleton.parents, quat_global, pos_global)
    return pose_from_motion(character, quat_local, pos_local)


def solve_frames(
    ik_fn: IKFn,
    params: Any,
    targets: IKTargets,
    *,
    keys: tuple[Pose, Pose] | Pose | None = None,
    key_blend_frames: int = 0,
    flip_turn: float = FLIP_TURN,
    key_turn: float = KEY_TURN,
) -> Pose:
    """Poses of a window of frames: ``targets`` are ``(frames, 6, …)``.

    An IK whose ``ik_fn`` has a ``solve_window(params, targets, keys, key_blend_frames)``
    method solves the window itself (e.g. :class:`~bezmotion.ik.exact.ExactIKFn`, which
    smooths over time and joins the keys before its solve); otherwise ``ik_fn`` is
    vmapped over the frames, its flips are taken out (a joint turning more than
    ``flip_turn`` rad in one frame: :func:`~bezmotion.ik.temporal.remove_flips`, the keys'
    frames kept), the keys are blended in, and the joints turn out of the keys no faster
    than ``key_turn`` (:func:`~bezmotion.ik.temporal.turn_out_of_keys`).

    Args:
      keys: the ``(start, end)`` key poses (unbatched) to put at the first and last frame,
        joined to the in-between over ``key_blend_frames`` frames
        (:func:`~bezmotion.ik.key_blend.blend_to_keys`); or, for a chain of windows joined
        (``targets`` of ``K·(W − 1) + 1`` frames), its ``K + 1`` keys batched in one
        :class:`Pose`, each window joined to its own two
        (:func:`~bezmotion.ik.key_blend.blend_to_chain_keys`); ``None``: the IK's own poses there.
      flip_turn: rad, a per-frame IK's largest turn of a joint in one frame before it counts
        as a flip (:data:`~bezmotion.ik.temporal.FLIP_TURN`, 43°, the LaFAN1 mocap's largest;
        0: the IK's poses as they are, the paper's). Removing the flips costs next to no
        handle error.
      key_turn: rad, a per-frame IK's largest turn of a joint on the step next to a key,
        easing to ``flip_turn`` over the ``key_blend_frames`` frames from it
        (:data:`~bezmotion.ik.temporal.KEY_TURN`, 23°, under both corpora's mocap's largest
        there; 0, or ``key_blend_frames=0``: no such limit). Without it the IK's own turn away from the key's pose
        (where its pose on the key's frame is not the key's) pops at up to ``flip_turn``.
        With ``flip_turn=0`` and ``key_turn=0`` the IK's poses are joined to the keys as the
        paper's are.
    """
    window = getattr(ik_fn, "solve_window", None)
    if window is not None:
        return window(params, targets, keys=keys, key_blend_frames=key_blend_frames)
    pose = jax.vmap(ik_fn, in_axes=(None, 0))(params, targets)
    # The keys' frames are kept (chains: every key's); handle frames are not: kept, a flip there
    # would pop the keys, and ramped, they move next to nothing.
    if keys is None:
        return remove_flips(pose, flip_turn)
    distance = distances_to_keys(pose.root_pos.shape[0], keys)
    at_keys = jnp.asarray(distance == 0)
    pose = blend_to_chain_keys(remove_flips(pose, flip_turn, at_keys), keys, key_blend_frames)
    if key_turn <= 0.0 or key_blend_frames == 0:  # no join asked for: the keys replace their frames alone
        return pose
    return turn_out_of_keys(pose, distance, key_turn, flip_turn, key_blend_frames, at_keys)


def targets_from_pose(character: Character, pose: Pose) -> IKTargets:
    """The six characteristic joints' world positions and orientations in ``pose`` (what IK should reproduce)."""
    quat_global, pos_global = pose_fk(character, pose)
    idx = np.asarray(character.characteristic)
    return IKTargets(pos_global[..., idx, :], rot6d_from_quat(quat_global[..., idx, :]))
