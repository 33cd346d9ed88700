"""A traditional IK rig that needs no data (BMM Appendix D.4): bent spine, two-bone limbs.

The rig turns :class:`~bezmotion.ik.protocol.IKTargets` into a full-body
:class:`~bezmotion.ik.protocol.Pose` with geometry alone, so it drives any humanoid
skeleton whose chains are named in a :class:`RigSpec`:

1. **Hips** take the target position and global orientation.
2. **Spine** (hips → head): from the rest pose's spine (the bind pose given to
   :func:`make_rig`; identity by default), the turn to the hips-to-head rotation the
   targets ask for is shared evenly by the spine joints (this sets the twist and a
   natural curve); the chain is
   then bent at its middle joint, as two rigid halves, by the law of cosines so the head
   joint reaches its target exactly. When the halves cannot reach it, a fixed number of
   FABRIK iterations reshapes the chain (they leave a chain that reaches unchanged) and
   a second bend finishes. Each spine joint takes the smallest swing from its first
   guess onto the bent chain, and the head takes its target orientation.
3. **Arms and legs**: analytic two-bone IK (law of cosines) reaches the hand / ankle
   exactly when it can and the nearest reachable point along the same direction when it
   cannot. The bend plane comes from a pole hint built from bone directions in world
   space (never from assumed joint axes, so it works for LaFAN1's zero-rotation rest pose
   and for Bandai-Namco's alike): knees in the plane across the foot's lateral axis, on
   the side of the toes and the pelvis' forward; elbows where the least rotation from an
   arm pointing forward and down (elbow back, down and out) to the hand's direction
   carries them. The hand / foot then takes its target orientation; the forearm / shin keeps the
   rest pose's wrist / ankle rotation against it, and the upper bone the rest pose's
   elbow / knee rotation, each then swung least onto its bone (no data fixes a bone's
   twist: the rest pose does; from identity, none at the elbow or the wrist).
4. Every other joint (clavicles, toes, joints above the hips) keeps its rest local
   rotation: identity, or a bind pose given to :func:`make_rig`.

Everything is one frame, fixed iteration counts and no data-dependent Python control
flow: ``jax.vmap(rig_ik, in_axes=(None, 0))`` solves a batch of frames, and divisions,
square roots and normalisations use the double-``where`` pattern so gradients are finite
at full extension, at zero target distance and at collinear pole hints.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion._src.messages import listed
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.data.joint_roles import name_words
from bezmotion.geometry.rotations import (
    matrix_from_quat,
    matrix_from_rot6d,
    normalize,
    quat_conjugate,
    quat_from_matrix,
    quat_identity,
    quat_mul,
    safe_norm,
    slerp,
)
from bezmotion.geometry.skeleton import Skeleton, ancestors, forward_kinematics
from bezmotion.ik.protocol import Character, IKTargets, Pose, pose_fk

_HEAD, _LEFT_HAND, _RIGHT_HAND, _LEFT_FOOT, _RIGHT_FOOT = (
    CHARACTERISTIC_JOINTS.index(role) for role in ("head", "left_hand", "right_hand", "left_foot", "right_foot")
)
_LIMBS: tuple[str, ...] = ("left_arm", "right_arm", "left_leg", "right_leg")
_LIMB_TARGET: tuple[int, ...] = (_LEFT_HAND, _RIGHT_HAND, _LEFT_FOOT, _RIGHT_FOOT)

# Pole hints. Knees bend about the shin's lateral axis, and the ankle hardly turns about
# the shin, so the knee's plane is the one across the foot's lateral axis (the rest pose's
# right-to-left hip direction carried by the foot's target rotation). Which way along it
# the knee goes comes from a rougher hint, towards the toes and the pelvis' forward
# (sums of unit vectors), which also stands in when the foot's lateral axis lies along
# the leg. The lateral axis is read off the rig's rest pose (the first key's, in the
# commands), not the zero rotation, so a file's bone axes and zero-rotation pose do not
# change it. A bind pose whose knees bend says which way they go
# instead (_bind_knee_bends): the rough hint fails where the toes point along the leg.
# Elbows: where the least rotation from a reference arm carries its elbow. The arm pointing
# forward and down bends its elbow back, down and out; the arm turned from there to any
# reach direction turns its elbow with it. Only one reach direction has no least rotation
# (the opposite one: behind the head, 45° up, where shoulders do not reach), so the
# elbow's side changes smoothly everywhere a hand goes; a fixed hint's part across the
# arm vanishes twice (arms raised forward, arms pushing back and down) and flips there.
_KNEE_FORWARD_WEIGHT = 1.0
_KNEE_PLANE_MIN = 0.2  # |lateral × leg axis| below this: the plane is ill-defined
# A bind pose whose knee bends this much about the foot's lateral axis (|thigh × shin| · lateral,
# ~6°) or more tells the knees' side instead (_bind_knee_bends).
_BIND_KNEE_MIN = 0.1
# In body axes (forward, up, outward); sums of unit vectors, not normalised here.
_ARM_REFERENCE_REACH = (1.0, -1.0, 0.0)
_ARM_REFERENCE_ELBOW = (-1.0, -1.0, 1.0)

# Below this (cm, or cm² for squared lengths) a length counts as zero.
_EPS = 1e-6
# A key's elbow this close (cm) to its shoulder-to-hand line tells no side (elbows_from_keys).
_STRAIGHT_CM = 1.0
# Which limbs take their side from the keys: the arms (a raised knee's side is the rig's own,
# from the foot's orientation; from the keys it changed nothing on the case that showed the arms').
_LIMBS_FROM_KEYS = np.asarray([True, True, False, False])


# --------------------------------------------------------------------------------- spec


@dataclasses.dataclass(frozen=True)
class RigSpec:
    """Which joints of a skeleton form the rig's chains (names, so one spec fits many files).

    Attributes:
      spine: the chain from the hips to the head, parent to child (at least one joint
        between them), e.g. ``("Hips", "Spine", "Spine1", "Spine2", "Neck", "Head")``.
      left_arm, right_arm: ``(upper arm, forearm, hand)``; the joints between the spine
        and the upper arm (shoulders / clavicles) stay at rest.
      left_leg, right_leg: ``(upper leg, lower leg, foot)`` — the foot is the ankle joint.

    Each limb joint descends from the one before, directly or through joints that the rig
    holds at their rest rotations (twist or roll joints inside the chain, e.g. Daz Genesis'
    ``lShldrBend → lShldrTwist → lForearmBend → lForearmTwist → lHand``).
    """

    # Plain ``tuple[str, ...]`` so that a wrong length reaches the ValueError below.
    spine: tuple[str, ...]
    left_arm: tuple[str, ...]
    right_arm: tuple[str, ...]
    left_leg: tuple[str, ...]
    right_leg: tuple[str, ...]

    def __post_init__(self) -> None:
        for field in ("spine", *_LIMBS):
            value = getattr(self, field)
            if isinstance(value, str) or not isinstance(value, Sequence):
                raise ValueError(f"RigSpec.{field} must be a sequence of joint names, got {value!r}")
            names = tuple(value)
            bad = [n for n in names if not isinstance(n, str) or not n]
            if bad:
                raise ValueError(f"RigSpec.{field} has invalid joint names {bad}")
            if field == "spine" and len(names) < 3:
                raise ValueError(f"RigSpec.spine needs the hips, at least one spine joint and the head, got {names}")
            if field != "spine" and len(names) != 3:
                raise ValueError(f"RigSpec.{field} needs exactly 3 joints (root, middle, end), got {names}")
            object.__setattr__(self, field, names)
        seen: dict[str, str] = {}
        for field in ("spine", *_LIMBS):
            for name in getattr(self, field):
                if name in seen:
                    raise ValueError(f"joint {name!r} is in both RigSpec.{seen[name]} and RigSpec.{field}")
                seen[name] = field

    @classmethod
    def preset(cls, name: str) -> RigSpec:
        """The spec of a bundled skeleton: ``"lafan1"`` or ``"bandai_namco"``."""
        if name not in RIG_PRESETS:
            raise ValueError(f"unknown rig preset {name!r}; known: {sorted(RIG_PRESETS)}, or pass a dict")
        return RIG_PRESETS[name]

    @classmethod
    def from_dict(cls, mapping: Mapping[str, Sequence[str]]) -> RigSpec:
        """A spec from a dict with the keys ``spine``, ``left_arm``, ``right_arm``, ``left_leg``, ``right_leg``."""
        fields = ("spine", *_LIMBS)
        missing = [f for f in fields if f not in mapping]
        unknown = [k for k in mapping if k not in fields]
        if missing or unknown:
            raise ValueError(f"a rig spec needs exactly the keys {list(fields)}; missing {missing}, unknown {unknown}")
        return cls(**{f: tuple(mapping[f]) for f in fields})


RIG_PRESETS: Mapping[str, RigSpec] = {
    "lafan1": RigSpec(
        spine=("Hips", "Spine", "Spine1", "Spine2", "Neck", "Head"),
        left_arm=("LeftArm", "LeftForeArm", "LeftHand"),
        right_arm=("RightArm", "RightForeArm", "RightHand"),
        left_leg=("LeftUpLeg", "LeftLeg", "LeftFoot"),
        right_leg=("RightUpLeg", "RightLeg", "RightFoot"),
    ),
    "bandai_namco": RigSpec(
        spine=("Hips", "Spine", "Chest", "Neck", "Head"),
        left_arm=("UpperArm_L", "LowerArm_L", "Hand_L"),
        right_arm=("UpperArm_R", "LowerArm_R", "Hand_R"),
        left_leg=("UpperLeg_L", "LowerLeg_L", "Foot_L"),
        right_leg=("UpperLeg_R", "LowerLeg_R", "Foot_R"),
    ),
}
"""Rig specs of the bundled skeletons (LaFAN1 BVH and Bandai-Namco BVH joint names)."""


# ---------------------------------------------------------------------------------- rig


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Rig:
    """Parameters of :func:`rig_ik`: a skeleton's rest offsets and its chains (a pytree).

    Build it with :func:`make_rig`. The arrays (``skeleton.offsets``, ``rest_quat_local``)
    are leaves and the joint indices static, so a rig passes straight into
    ``jit``/``vmap``/``grad``.

    Attributes:
      skeleton: the character's skeleton (rest offsets in cm).
      rest_quat_local: ``(joints, 4)`` local rotations of the joints the rig does not
        solve (clavicles, toes, …), and the reference of the solved ones (the spine's
        shape, each limb's twist); identity unless :func:`make_rig` was given others.
      spine: joint indices from the hips to the head.
      limbs: ``(root, middle, end)`` joint indices of the left arm, right arm, left leg,
        right leg.
      limb_between: per limb, ``(root → middle, middle → end)``: the joints strictly between
        them (parent → child; twist joints), which keep their ``rest_quat_local``; empty
        where the middle is the root's child and the end the middle's.
      limb_bases: per limb, ``(k, path)``: the limb hangs off ``spine[k]`` through the
        joints ``path`` (the clavicle, …, the limb root); all but the limb root keep
        their ``rest_quat_local``.
      toes: per leg, a child joint of the foot whose bone gives the toes' direction, or
        ``-1`` when the foot has none.
      spine_iterations: FABRIK iterations for spine targets the first guess cannot reach.
    """

    skeleton: Skeleton
    rest_quat_local: Float[Array, "joints 4"]
    spine: tuple[int, ...] = dataclasses.field(metadata=dict(static=True))
    limbs: tuple[tuple[int, int, int], ...] = dataclasses.field(metadata=dict(static=True))
    limb_bases: tuple[tuple[int, tuple[int, ...]], ...] = dataclasses.field(metadata=dict(static=True))
    toes: tuple[int, int] = dataclasses.field(metadata=dict(static=True))
    spine_iterations: int = dataclasses.field(default=8, metadata=dict(static=True))
    limb_between: tuple[tuple[tuple[int, ...], tuple[int, ...]], ...] = dataclasses.field(
        default=(((), ()),) * 4, metadata=dict(static=True)
    )

    @property
    def num_joints(self) -> int:
        return self.skeleton.num_joints


def _joint(skeleton: Skeleton, name: str, where: str) -> int:
    if name not in skeleton.names:
        raise ValueError(f"unknown joint {name!r} in RigSpec.{where}; this skeleton's {skeleton.num_joints} joints are {listed(skeleton.names)}")
    return skeleton.names.index(name)


def _check_chain(skeleton: Skeleton, chain: Sequence[int], where: str) -> None:
    for parent, child in itertools.pairwise(chain):
        if skeleton.parents[child] != parent:
            actual = skeleton.parents[child]
            actual_name = skeleton.names[actual] if actual >= 0 else None
            raise ValueError(
                f"RigSpec.{where}: joint {skeleton.names[child]!r} is a child of {actual_name!r}, "
                f"not of {skeleton.names[parent]!r}; a chain lists parent → child joints"
            )


def _descent(skeleton: Skeleton, chain: Sequence[int], where: str) -> tuple[tuple[int, ...], ...]:
    """Per consecutive pair of ``chain``, the joints strictly between them (parent → child):
    each joint must descend from the one before.

    Raises:
      ValueError: a joint that does not descend from the one before, naming both.
    """
    between = []
    for parent, child in itertools.pairwise(chain):
        above = ancestors(skeleton.parents, child)[1:]
        if parent not in above:
            actual = skeleton.parents[child]
            actual_name = skeleton.names[actual] if actual >= 0 else None
            raise ValueError(
                f"RigSpec.{where}: joint {skeleton.names[child]!r} (a child of {actual_name!r}) does not descend from "
                f"{skeleton.names[parent]!r}; a chain lists parent → child joints (a limb's may skip twist joints between)"
            )
        between.append(tuple(reversed(above[: above.index(parent)])))
    return tuple(between)


# Joints inside a limb that only turn it about its bone (Daz Genesis' lForearmTwist, Unreal's
# upperarm_twist_01_l when in the chain, "ForeArmRoll"): no elbow or knee.
_TWIST_WORDS = frozenset({"twist", "roll"})


def derive_rig_spec(character: Character) -> RigSpec:
    """The rig's chains read off the hierarchy: the spine is the path from the hips to the
    head, each limb the hand (ankle) and its two nearest ancestors that bend it — skipping
    twist and roll joints (by name) and joints at their parent's place (no bone), which the
    rig holds at rest (``lShldrBend → lShldrTwist → lForearmBend → lForearmTwist → lHand``
    is the arm ``(lShldrBend, lForearmBend, lHand)``).

    Raises:
      ValueError: the head does not descend from the hips, or a hand or foot has fewer than
        two such ancestors below the spine.
    """
    names, parents = character.skeleton.names, character.skeleton.parents
    role = dict(zip(CHARACTERISTIC_JOINTS, character.characteristic))
    spine, j = [role["head"]], parents[role["head"]]
    while j >= 0 and j != role["hips"]:
        spine.append(j)
        j = parents[j]
    if j != role["hips"]:
        raise ValueError(
            f"the head {names[role['head']]!r} does not descend from the hips {names[role['hips']]!r}; "
            "name the rig's chains in the mapping file ('rig')"
        )
    spine.append(j)

    offsets = np.asarray(character.skeleton.offsets, np.float64)
    on_spine = set(spine)

    def bends(j: int) -> bool:
        return not (_TWIST_WORDS & set(name_words(names[j]))) and float(np.linalg.norm(offsets[j])) > 1e-6

    def limb(end: int) -> tuple[str, ...]:
        chain, j = [end], parents[end]
        while len(chain) < 3 and j >= 0 and j not in on_spine:
            if bends(j):
                chain.append(j)
            j = parents[j]
        if len(chain) < 3:
            raise ValueError(
                f"{names[end]!r} needs two ancestors below the spine that bend it for a two-bone limb; "
                "name the chains in the mapping file ('rig')"
            )
        return tuple(names[i] for i in reversed(chain))

    return RigSpec(
        spine=tuple(names[i] for i in reversed(spine)),
        left_arm=limb(role["left_hand"]), right_arm=limb(role["right_hand"]),
        left_leg=limb(role["left_foot"]), right_leg=limb(role["right_foot"]),
    )  # fmt: skip


def make_rig(
    character: Character,
    spec: RigSpec | str | Mapping[str, Sequence[str]],
    *,
    rest_quat_local: Float[Array | np.ndarray, "joints 4"] | None = None,
    spine_iterations: int = 8,
) -> Rig:
    """The :class:`Rig` of a character, checking the spec against its skeleton.

    Args:
      character: the skeleton and its characteristic joints.
      spec: a :class:`RigSpec`, a preset name (``"lafan1"``, ``"bandai_namco"``) or a dict
        for :meth:`RigSpec.from_dict`.
      rest_quat_local: ``(joints, 4)`` local rotations (w, x, y, z) that the joints the rig
        does not solve keep — clavicles, toes, fingers. Default: identity, the skeleton's
        zero-rotation rest pose. A bind pose helps skeletons whose zero rotation is not a
        natural pose: LaFAN1's and Bandai-Namco's clavicles point up along the neck at
        zero rotation. The solved joints start from it too: the spine from its spine (the
        turn to the targets' hips-to-head rotation spread along it), each limb's elbow /
        knee and wrist / ankle with its rotations about their bones (twist), which no
        target fixes (from the zero rotation, the first spine joint comes out far from the
        mocap's), and a bent knee says which
        way the knees bend (without one, toes pointing along the leg can flip them).
        Joints above the hips must be identity (a :class:`~bezmotion.ik.protocol.Pose`
        holds them there).
      spine_iterations: FABRIK iterations for spine targets that the first guess cannot
        reach (each costs two passes over the spine).
    Raises:
      ValueError: an unknown joint name (the message names it), a chain that is not
        parent → child (a limb's joints: descendants), chain ends that are not the character's characteristic joints,
        a limb that does not hang off the spine, or a bad ``rest_quat_local``.
    """
    if isinstance(spec, str):
        spec = RigSpec.preset(spec)
    elif not isinstance(spec, RigSpec):
        spec = RigSpec.from_dict(spec)
    if not (isinstance(spine_iterations, int) and spine_iterations >= 0):
        raise ValueError(f"spine_iterations must be a non-negative int, got {spine_iterations!r}")
    skeleton = character.skeleton
    spine = tuple(_joint(skeleton, n, "spine") for n in spec.spine)
    _check_chain(skeleton, spine, "spine")
    limbs = tuple(tuple(_joint(skeleton, n, field) for n in getattr(spec, field)) for field in _LIMBS)
    limb_between = tuple(_descent(skeleton, limb, field) for field, limb in zip(_LIMBS, limbs))

    def expect(joint: int, role: str, where: str, end: str = "ends") -> None:
        wanted = character.characteristic[CHARACTERISTIC_JOINTS.index(role)]
        if joint != wanted:
            raise ValueError(
                f"RigSpec.{where} {end} at {skeleton.names[joint]!r} but the character's {role} is "
                f"{skeleton.names[wanted]!r}"
            )

    expect(spine[0], "hips", "spine", "starts")
    expect(spine[-1], "head", "spine")
    for field, limb, role in zip(_LIMBS, limbs, ("left_hand", "right_hand", "left_foot", "right_foot")):
        expect(limb[-1], role, field)

    limb_bases = []
    for field, limb in zip(_LIMBS, limbs):
        path, j = [limb[0]], skeleton.parents[limb[0]]
        while j >= 0 and j not in spine:
            path.append(j)
            j = skeleton.parents[j]
        if j < 0:
            raise ValueError(
                f"RigSpec.{field}: {skeleton.names[limb[0]]!r} does not hang off the spine chain {spec.spine}"
            )
        if spine.index(j) == len(spine) - 1:
            raise ValueError(
                f"RigSpec.{field}: {skeleton.names[limb[0]]!r} hangs off the head; "
                "limbs must hang off the hips or the spine"
            )
        limb_bases.append((spine.index(j), tuple(reversed(path))))
    toes = tuple(next(iter(skeleton.children(limb[-1])), -1) for limb in limbs[2:])

    offsets = jnp.asarray(skeleton.offsets)
    if rest_quat_local is None:
        rest = quat_identity((skeleton.num_joints,), offsets.dtype)
    else:
        rest = np.asarray(rest_quat_local, np.float64)
        if rest.shape != (skeleton.num_joints, 4):
            raise ValueError(f"rest_quat_local must have shape ({skeleton.num_joints}, 4), got {rest.shape}")
        norms = np.linalg.norm(rest, axis=-1)
        if not np.all(np.abs(norms - 1.0) < 1e-3):
            bad = [skeleton.names[j] for j in np.flatnonzero(~(np.abs(norms - 1.0) < 1e-3))]
            raise ValueError(f"rest_quat_local must hold unit quaternions; joints {bad} do not")
        above = [j for j in character.ancestors_of_hips() if abs(abs(rest[j, 0]) - 1.0) > 1e-6]
        if above:
            raise ValueError(
                f"rest_quat_local must be identity above the hips; joints {[skeleton.names[j] for j in above]} are not"
            )
        rest = jnp.asarray(rest / norms[:, None], offsets.dtype)
    return Rig(skeleton, rest, spine, limbs, tuple(limb_bases), toes, spine_iterations, limb_between)  # type: ignore[arg-type]


def with_rest_pose(params: Any, quat_local: Float[Array, "joints 4"]) -> Any:
    """``params`` (any pytree: a :class:`Rig`, an exact IK's params on one, …) with every
    :class:`Rig` in it taking ``quat_local`` as its ``rest_quat_local``.

    For a rest pose per window under ``vmap`` (e.g. each window's start key, as ``bezmotion
    inbetween`` gives the rig the take's start key). Unchecked, so it traces: pass a
    :class:`~bezmotion.ik.protocol.Pose`'s rotations (unit, identity above the hips), or check
    them once with :func:`make_rig`.
    """

    def replace(node: Any) -> Any:
        if not isinstance(node, Rig):
            return node
        return dataclasses.replace(node, rest_quat_local=jnp.asarray(quat_local, node.rest_quat_local.dtype))

    return jax.tree.map(replace, params, is_leaf=lambda node: isinstance(node, Rig))


# ------------------------------------------------------------------------------ solving


# Levi-Civita symbol: cross products and skew matrices as single contractions, which keeps
# the traced graph (and XLA's compile time, under grad too) small.
_LEVI_CIVITA = np.zeros((3, 3, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI_CIVITA[_i, _j, _k], _LEVI_CIVITA[_i, _k, _j] = 1.0, -1.0


def _cross(u: Float[Array, "*#batch 3"], v: Float[Array, "*#batch 3"]) -> Float[Array, "*batch 3"]:
    return jnp.einsum("ijk,...j,...k->...i", jnp.asarray(_LEVI_CIVITA, u.dtype), u, v)


def _apply(m: Float[Array, "*#batch 3 3"], v: Float[Array, "*#batch 3"]) -> Float[Array, "*batch 3"]:
    """``m @ v`` for rotation matrices ``m`` and vectors ``v``."""
    return jnp.einsum("...ij,...j->...i", m, v)


def _where_normalize(v: Float[Array, "*batch 3"], fallback: Float[Array, "*#batch 3"]) -> Float[Array, "*batch 3"]:
    """``v / |v|``, or ``fallback`` where ``v`` (almost) vanishes; finite gradients either way."""
    norm = safe_norm(v, keepdims=True)
    ok = norm > _EPS
    return jnp.where(ok, v / jnp.where(ok, norm, 1.0), fallback)


def _perpendicular(v: Float[Array, "*batch 3"], axis: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """The part of ``v`` perpendicular to the unit vector ``axis``."""
    return v - jnp.sum(v * axis, axis=-1, keepdims=True) * axis


def _any_perpendicular(axis: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """Some unit vector perpendicular to the unit vector ``axis`` (the last-resort direction)."""
    # x unless the axis is close to x (then y): the cross product is at least 0.43 long.
    near_x = jnp.abs(axis[..., :1]) > 0.9
    basis = jnp.where(near_x, jnp.asarray([0.0, 1.0, 0.0], axis.dtype), jnp.asarray([1.0, 0.0, 0.0], axis.dtype))
    return normalize(_cross(axis, basis))


def _swing(u: Float[Array, "*batch 3"], v: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """The least rotation (matrix) taking direction ``u`` to direction ``v``.

    Identity when either vanishes; a half turn about an axis perpendicular to ``u`` when
    they are opposite. Built from the half-way quaternion ``(1 + u·v, u × v)``, which
    stays accurate for nearly opposite directions.
    """
    u, v = normalize(u), normalize(v)
    half = jnp.concatenate([1.0 + jnp.sum(u * v, axis=-1, keepdims=True), _cross(u, v)], axis=-1)
    norm = safe_norm(half, keepdims=True)
    opposite = norm < 64.0 * float(jnp.finfo(u.dtype).eps)
    flip = jnp.concatenate([jnp.zeros_like(half[..., :1]), _any_perpendicular(u)], axis=-1)
    q = jnp.where(opposite, flip, half / jnp.where(opposite, 1.0, norm))
    w, xyz = q[..., :1, None], q[..., 1:]
    eye = jnp.eye(3, dtype=u.dtype)
    skew = jnp.einsum("ijk,...j->...ik", jnp.asarray(_LEVI_CIVITA, u.dtype), xyz)
    outer = xyz[..., :, None] * xyz[..., None, :]
    return (w * w - jnp.sum(xyz * xyz, axis=-1)[..., None, None]) * eye + 2.0 * outer + 2.0 * w * skew


def _bend(
    p_root: Float[Array, "*batch 3"],
    len_a: Float[Array, "*batch"],
    len_b: Float[Array, "*batch"],
    target: Float[Array, "*batch 3"],
    hint: Float[Array, "*batch 3"],
    fallback: Float[Array, "*batch 3"],
) -> tuple[Float[Array, "*batch 3"], Float[Array, "*batch 3"]]:
    """Where the middle and the end of two-bone chains go to reach ``target`` (law of cosines).

    Args:
      p_root: the chain's fixed root (cm).
      len_a, len_b: the two bones' lengths (cm).
      target: where the end should be (cm); its distance from the root is clamped to the
        reachable ``[|len_a - len_b|, len_a + len_b]``, keeping the direction.
      hint: world direction the middle joint bends towards (its part across the reach
        axis counts; a hint along the axis falls back to some perpendicular).
      fallback: the unit reach direction when ``target`` sits on the root.
    Returns:
      ``(p_mid, p_end)``: ``|p_mid - p_root| = len_a``, ``|p_end - p_mid| = len_b``.
    """
    len_a, len_b = len_a[..., None], len_b[..., None]
    to_target = target - p_root
    axis = _where_normalize(to_target, fallback)
    reach = jnp.clip(safe_norm(to_target, keepdims=True), jnp.abs(len_a - len_b), len_a + len_b)
    # cos of the angle at the root between the reach axis and the first bone.
    num = len_a * len_a + reach * reach - len_b * len_b
    den = 2.0 * len_a * reach
    ok = den > _EPS
    cos_root = jnp.clip(jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0), -1.0, 1.0)
    sin_sq = 1.0 - cos_root * cos_root
    bent = sin_sq > _EPS * _EPS
    sin_root = jnp.where(bent, jnp.sqrt(jnp.where(bent, sin_sq, 1.0)), 0.0)
    across = _where_normalize(_perpendicular(hint, axis), _any_perpendicular(axis))
    return p_root + len_a * (cos_root * axis + sin_root * across), p_root + reach * axis


def _close(points: Float[Array, "n 3"], target: Float[Array, "3"]) -> Float[Array, "n 3"]:
    """Bend a chain at its middle point, as two rigid halves, so its end reaches ``target``.

    The law of cosines gives the bend exactly; the halves are swung as little as possible
    (in the plane of the chain's current bend), so the chain keeps its shape.
    """
    mid = points.shape[0] // 2
    base = points[0]
    first, second = points[mid] - base, points[-1] - points[mid]
    p_mid, p_end = _bend(base, safe_norm(first), safe_norm(second), target, first, normalize(points[-1] - base))
    points = base + _apply(_swing(first, p_mid - base), points - base)
    tail = p_mid + _apply(_swing(points[-1] - p_mid, p_end - p_mid), points[mid:] - p_mid)
    return jnp.concatenate([points[:mid], tail], axis=0)


def _reach(
    points: Float[Array, "n 3"], lengths: Float[Array, "n-1"], target: Float[Array, "3"], iterations: int
) -> Float[Array, "n 3"]:
    """Bend a chain (first point pinned) so its end reaches ``target``, keeping its shape where it can.

    A two-half bend (:func:`_close`) reaches most targets exactly from a good first guess.
    When the halves are too short or too long for the target, FABRIK (Aristidou & Lasenby
    2011) reshapes the chain, and a second two-half bend removes what FABRIK's slow
    convergence near full reach leaves. FABRIK leaves a chain that already reaches its
    target unchanged, so a reached target stays reached.
    """
    count = points.shape[0]
    base = points[0]

    def fabrik(_, chain):
        # Backward from the target, then forward from the pinned base; each step keeps
        # one bone's length exactly.
        chain = list(chain)
        chain[-1] = target
        for k in range(count - 2, -1, -1):
            chain[k] = chain[k + 1] + lengths[k] * normalize(chain[k] - chain[k + 1])
        chain[0] = base
        for k in range(count - 1):
            chain[k + 1] = chain[k] + lengths[k] * normalize(chain[k + 1] - chain[k])
        return tuple(chain)

    def close_then_fabrik(points, first):
        # Traced once for both bends (XLA compile time grows with the graph): the FABRIK
        # iterations only count after the first bend.
        points = _close(points, target)
        reshaped = jnp.stack(jax.lax.fori_loop(0, iterations, fabrik, tuple(points)))
        return jnp.where(first, reshaped, points), None

    points, _ = jax.lax.scan(close_then_fabrik, points, jnp.asarray([True, False]))
    return points


def _two_bone(
    p_root: Float[Array, "*batch 3"],
    bone_upper: Float[Array, "*batch 3"],
    bone_lower: Float[Array, "*batch 3"],
    target: Float[Array, "*batch 3"],
    rot_end: Float[Array, "*batch 3 3"],
    hint: Float[Array, "*batch 3"],
    mid_local: Float[Array, "*batch 3 3"],
    end_local: Float[Array, "*batch 3 3"],
) -> tuple[Float[Array, "*batch 3 3"], Float[Array, "*batch 3 3"]]:
    """Global rotations (matrices) of the upper and lower bones of two-bone limbs.

    Args:
      p_root: world position of the limb root (shoulder / hip joint), cm.
      bone_upper: rest offset of the middle joint in the root's frame (cm).
      bone_lower: rest offset of the end joint in the middle joint's frame (cm).
      target: where the end joint should be (cm); clamped to the reachable shell.
      rot_end: the end joint's target global rotation (sets the limb's twist).
      hint: world direction towards which the middle joint should bend.
      mid_local, end_local: a reference pose's local rotations of the middle and end
        joints (elbow and wrist): how the limb shares its twist between its joints (identity:
        none at the elbow and the wrist).
    Returns:
      ``(rot_upper, rot_lower)`` global rotations of the root and middle joints.
    """
    # The limb's straight direction under the end rotation: the reach direction when the
    # target sits on the root (any direction would do; this one is continuous in rot_end).
    up = jnp.asarray([0.0, 1.0, 0.0], p_root.dtype)
    fallback = _where_normalize(_apply(rot_end, bone_upper + bone_lower), up)
    p_mid, p_end = _bend(p_root, safe_norm(bone_upper), safe_norm(bone_lower), target, hint, fallback)
    # Lower bone: the least swing from where the end rotation puts it with the reference's
    # wrist / ankle rotation; upper bone: the least swing from where the lower one puts it
    # with the reference's elbow / knee. Each keeps the reference's twist about its bone.
    guess_lower = rot_end @ jnp.swapaxes(end_local, -1, -2)
    rot_lower = _swing(_apply(guess_lower, bone_lower), p_end - p_mid) @ guess_lower
    guess_upper = rot_lower @ jnp.swapaxes(mid_local, -1, -2)
    rot_upper = _swing(_apply(guess_upper, bone_upper), p_mid - p_root) @ guess_upper
    return rot_upper, rot_lower


def _limb_bones(
    rig: Rig, offsets: Float[Array, "joints 3"], rot_local: Float[Array, "joints 3 3"]
) -> tuple[Float[Array, "limbs 2 3"], Float[Array, "limbs 2 3 3"]]:
    """Per limb, its two bones through the joints between (``Rig.limb_between``), posed by
    ``rot_local`` (local rotation matrices of every joint):

    - ``(limb, 2, 3)`` the middle joint's offset in the root's frame and the end's in the
      middle's (the offsets themselves where nothing is between);
    - ``(limb, 2, 3, 3)`` the rotation of the joints between, composed (identity where none):
      a joint's global rotation is its limb parent's, times that, times its own local one.
    """
    dtype = offsets.dtype
    bones, turns = [], []
    for (_, middle, end), between in zip(rig.limbs, rig.limb_between):
        for child, path in zip((middle, end), between):
            turn, bone = jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype)
            for j in path:
                bone = bone + turn @ offsets[j]
                turn = turn @ rot_local[j]
            bones.append(bone + turn @ offsets[child])
            turns.append(turn)
    n = len(rig.limbs)
    return jnp.stack(bones).reshape(n, 2, 3), jnp.stack(turns).reshape(n, 2, 3, 3)


def _rest_lateral(rig: Rig, offsets: Float[Array, "joints 3"], rest: Float[Array, "joints 4"]) -> Float[Array, "2 3"]:
    """Per leg, the axis its knee bends about, in that leg's foot frame, as the rig's rest
    pose (``rest``, its local rotations: in the commands, the first key's) holds it: the
    knee's own hinge (thigh × shin) where the pose bends it, else the legs' lateral axis
    (right hip to left hip), blended between the two as the bend grows to
    ``_BIND_KNEE_MIN``. Measured on that pose rather than at zero rotation, it does not
    depend on how a file lays out its zero-rotation pose or its bones' axes: turning a
    joint's frame by ``C`` turns this vector by ``Cᵀ`` and the target rotation by ``C``,
    and their product stays the same."""
    rot, pos = forward_kinematics(rig.skeleton.parents, rest, offsets)
    upper, knee, ankle = (np.asarray(j) for j in zip(*rig.limbs[2:]))
    across = normalize(pos[upper[0]] - pos[upper[1]])
    hinge = _cross(normalize(pos[knee] - pos[upper]), normalize(pos[ankle] - pos[knee]))  # (2, 3), |·| = sin(bend)
    hinge = jnp.where(jnp.sum(hinge * across, axis=-1, keepdims=True) < 0.0, -hinge, hinge)  # a knee bends forward of the hips' line
    weight = jnp.clip(safe_norm(hinge, keepdims=True) / _BIND_KNEE_MIN, 0.0, 1.0)
    axis = _where_normalize(weight * _where_normalize(hinge, across) + (1.0 - weight) * across, across)
    return _apply(jnp.swapaxes(matrix_from_quat(rot[ankle]), -1, -2), axis)


def _bind_knee_bends(
    rig: Rig, bones: Float[Array, "limbs 2 3"], turns: Float[Array, "limbs 2 3 3"], rest_rot: Float[Array, "joints 3 3"], lateral: Float[Array, "2 3"]
) -> tuple[Array, Array]:
    """``(sense (2, 1), bent (2, 1))`` per leg: which way the bind pose's knee bends about the
    foot's ``lateral`` axis (per leg, in its foot's frame: :func:`_rest_lateral`), the sign of ``(thigh × shin) ·
    lateral``, and whether that product is at least ``_BIND_KNEE_MIN`` (a straight leg, e.g.
    the zero rotation's, says nothing). Unlike where the knee lies, the sense does not change
    as the knee bends further or the ankle flexes."""
    _, knee, ankle = np.asarray(rig.limbs[2:]).T
    bones, turns = bones[2:], turns[2:]  # the legs' (_limb_bones at the rest pose)
    knee_turn = turns[:, 0] @ rest_rot[knee]
    thigh, shin = normalize(bones[:, 0]), normalize(_apply(knee_turn, bones[:, 1]))  # in the thigh's frame
    bend = jnp.sum(_cross(thigh, shin) * _apply(knee_turn @ turns[:, 1] @ rest_rot[ankle], lateral), axis=-1, keepdims=True)
    return jnp.where(bend < 0.0, -1.0, 1.0), jnp.abs(bend) > _BIND_KNEE_MIN


def rig_ik(rig: Rig, targets: IKTargets) -> Pose:
    """Solve one frame: six characteristic-joint targets → a full-body pose.

    Satisfies :class:`~bezmotion.ik.protocol.IKFn`; ``jax.vmap(rig_ik, in_axes=(None, 0))``
    solves many frames.

    Args:
      rig: from :func:`make_rig`.
      targets: ``position (6, 3)`` cm and ``rot6d (6, 6)`` global orientations, in
        :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS` order.
    Returns:
      The pose: hips at the target position; hips, head, hands and feet at their target
      orientations; hands, feet and head at their targets when the chains reach them,
      else as close as the chain reaches along the same direction.
    """
    dtype = targets.position.dtype
    offsets = jnp.asarray(rig.skeleton.offsets, dtype)
    rest = jnp.asarray(rig.rest_quat_local, dtype)
    rot_target = matrix_from_rot6d(targets.rot6d)
    pos_target = targets.position
    spine = rig.spine
    n = len(spine) - 1  # spine[n] is the head; spine[1:n] bend the chain
    rot_hips = rot_target[0]

    # First guess: the rest pose's spine, and every joint from spine[1] to the head takes the
    # same share of the turn between its hips-to-head rotation and the targets', so the
    # twist and the bend spread along the spine (from the zero rotation: all of it).
    rest_chain = [rest[spine[1]]]
    for j in spine[2:]:
        rest_chain.append(quat_mul(rest_chain[-1], rest[j]))  # spine[1] … spine[k] composed
    rest_chain = jnp.stack(rest_chain)
    hips_to_head = quat_from_matrix(rot_hips.T @ rot_target[_HEAD])
    turn = quat_mul(hips_to_head, quat_conjugate(rest_chain[-1]))
    turn = jnp.where(turn[:1] < 0.0, -turn, turn)  # the short way
    shares = jnp.arange(1, n, dtype=dtype) / n
    guess = rot_hips @ matrix_from_quat(quat_mul(slerp(quat_identity((), dtype), turn, shares), rest_chain[:-1]))  # spine[1:n]
    bones = _apply(guess, offsets[np.asarray(spine[2:])])  # spine[k] → spine[k + 1], k = 1..n-1
    start = pos_target[0] + rot_hips @ offsets[spine[1]]
    points = jnp.concatenate([start[None], start + jnp.cumsum(bones, axis=0)])
    points = _reach(points, safe_norm(bones), pos_target[_HEAD], rig.spine_iterations)
    # Each spine joint takes the least swing from its guess onto the bent chain.
    bent = _swing(bones, points[1:] - points[:-1]) @ guess
    rot_spine = jnp.concatenate([rot_hips[None], bent, rot_target[_HEAD][None]])
    pos_spine = jnp.concatenate([pos_target[:1], points])

    # Limb roots hang off the posed spine through joints held at their rest rotations.
    rest_rot = matrix_from_quat(rest)
    roots, root_parents = [], []
    for k, path in rig.limb_bases:
        pos, rot = pos_spine[k], rot_spine[k]
        for j in path[:-1]:
            pos = pos + rot @ offsets[j]
            rot = rot @ rest_rot[j]
        roots.append(pos + rot @ offsets[path[-1]])
        root_parents.append(rot)
    roots, root_parents = jnp.stack(roots), jnp.stack(root_parents)

    # Body axes from bone directions in world space (no assumed joint axes): up from the
    # hips to the head target, left from the right to the left limb root.
    up = _where_normalize(pos_target[_HEAD] - pos_target[0], rot_hips @ offsets[spine[1]])
    left = normalize(roots[np.asarray([0, 2])] - roots[np.asarray([1, 3])])  # chest, pelvis
    forward = normalize(_cross(left, up))
    outward = left[0] * jnp.asarray([[1.0], [-1.0]], dtype)
    arm_axes = jnp.stack(jnp.broadcast_arrays(forward[0], up, outward), axis=-2)  # (arm, forward / up / outward, 3)
    reference_reach = normalize(jnp.asarray(_ARM_REFERENCE_REACH, dtype) @ arm_axes)
    reach = _where_normalize(pos_target[np.asarray(_LIMB_TARGET[:2])] - roots[:2], reference_reach)
    elbows = _apply(_swing(reference_reach, reach), jnp.asarray(_ARM_REFERENCE_ELBOW, dtype) @ arm_axes)
    feet = np.asarray(_LIMB_TARGET[2:])
    toes = jnp.stack([rot_target[t] @ offsets[toe] if toe >= 0 else jnp.zeros(3, dtype) for t, toe in zip(feet, rig.toes)])
    toward = normalize(toes) + _KNEE_FORWARD_WEIGHT * forward[1]
    rest_lateral = _rest_lateral(rig, offsets, rest)
    lateral = _apply(rot_target[feet], rest_lateral)
    across = _cross(lateral, _where_normalize(pos_target[feet] - roots[2:], normalize(toward)))
    side = jnp.where(jnp.sum(across * toward, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    # A bent bind pose knows better which way the knees bend about the lateral axis: a knee on
    # +across bends with (thigh × shin) · lateral < 0 (that product is −|thigh × shin| there).
    # Toes and pelvis can point along the leg (lying, a pointed foot), where the rough hint's
    # side flips between frames and the leg turns half a turn.
    bones, turns = _limb_bones(rig, offsets, rest_rot)  # through any twist joints, at rest
    bind_sense, bind_bent = _bind_knee_bends(rig, bones, turns, rest_rot, rest_lateral)
    side = jnp.where(bind_bent, -bind_sense, side)
    knees = jnp.where(safe_norm(across, keepdims=True) > _KNEE_PLANE_MIN, side * across, toward)

    limbs = np.asarray(rig.limbs)
    ends = np.asarray(_LIMB_TARGET)
    rot_end = rot_target[ends]
    upper, lower = _two_bone(
        roots, bones[:, 0], bones[:, 1], pos_target[ends], rot_end, jnp.concatenate([elbows, knees]),
        turns[:, 0] @ rest_rot[limbs[:, 1]], turns[:, 1] @ rest_rot[limbs[:, 2]],
    )  # fmt: skip

    # Local rotations: parentᵀ · child, converted to quaternions in one batch (a twist joint
    # between two limb joints stays at rest: the child's parent frame is past it).
    spine_local = jnp.swapaxes(rot_spine[:-1], -1, -2) @ rot_spine[1:]
    limb_parents = jnp.stack([root_parents, upper @ turns[:, 0], lower @ turns[:, 1]], axis=1)  # (limb, joint in limb, 3, 3)
    limb_local = jnp.swapaxes(limb_parents, -1, -2) @ jnp.stack([upper, lower, rot_end], axis=1)
    solved = quat_from_matrix(jnp.concatenate([rot_hips[None], spine_local, limb_local.reshape(-1, 3, 3)]))
    solved_joints = [spine[0], *spine[1:], *limbs.reshape(-1).tolist()]
    source = np.arange(rig.num_joints)  # rest rotations by default ...
    source[solved_joints] = rig.num_joints + np.arange(len(solved_joints))  # ... solved ones after them
    quat_local = jnp.concatenate([rest, solved])[source]
    return Pose(pos_target[0], quat_local)


def _rig_character(rig: Rig) -> Character:
    """The character whose characteristic joints are the rig's chain ends (for FK of its poses)."""
    return Character(rig.skeleton, (rig.spine[0], rig.spine[-1], *(limb[2] for limb in rig.limbs)))


def elbows_from_keys(rig: Rig, pose: Pose, targets: IKTargets, keys: Pose) -> Pose:
    """``pose`` ``(K·(W − 1) + 1, …)`` (the rig's, a chain of ``K`` windows of ``W`` frames
    between ``keys`` batched ``(K + 1, …)``) with each arm re-solved (:func:`refine_limbs`)
    to bend its elbow the way the keys around the frame bend theirs: the elbow's offset
    across the shoulder-to-hand line, in the hips' frame, blended from the window's start
    key to its end key along the window, turned by the frame's own hips.

    The rig's fixed reference arm chooses an elbow side that may lie half a turn round that
    line from the key's (a dance's raised arms: 100–170°), and joining the key to it swings
    the hand through that arc, far off its curve (85 cm on LaFAN1's ``dance1_subject1``).
    The legs keep their knees."""
    limbs = np.asarray(rig.limbs)
    character = _rig_character(rig)
    frames, num_keys = pose.root_pos.shape[0], keys.root_pos.shape[0]
    span = (frames - 1) // (num_keys - 1)

    def across(p: Pose) -> Float[Array, "4 3"]:  # the elbows' and knees' offsets across the reach, in the hips' frame
        quat, pos = pose_fk(character, p)
        reach = _where_normalize(pos[limbs[:, 2]] - pos[limbs[:, 0]], jnp.asarray([0.0, 1.0, 0.0], pos.dtype))
        off = _perpendicular(pos[limbs[:, 1]] - pos[limbs[:, 0]], reach)
        return _apply(jnp.swapaxes(matrix_from_quat(quat[rig.spine[0]]), -1, -2), off)

    at_keys = jax.vmap(across)(keys)  # (K + 1, 4, 3)
    f = np.arange(frames)
    window = np.minimum(f // span, num_keys - 2)
    t = jnp.asarray((f - window * span) / span, pose.root_pos.dtype)[:, None, None]
    wanted = (1.0 - t) * at_keys[window] + t * at_keys[window + 1]  # (frames, 4, 3), hips' frame
    # Keys with straight arms say nothing, nor do they for the legs: zero, the rig's own side there.
    wanted = jnp.where((safe_norm(wanted, keepdims=True) > _STRAIGHT_CM) & _LIMBS_FROM_KEYS[:, None], wanted, 0.0)
    # The hips' global rotation is their local one (a Pose holds the joints above them at identity).
    hips = matrix_from_quat(pose.quat_local[:, rig.spine[0]])[:, None]
    return jax.vmap(functools.partial(refine_limbs, rig))(pose, targets, _apply(hips, wanted))


def refine_limbs(rig: Rig, pose: Pose, targets: IKTargets, hint: Float[Array, "limbs 3"] | None = None) -> Pose:
    """Re-solve the arms and legs of one frame's ``pose`` (e.g. a learned IK's) with the
    rig's two-bone IK, so hands and feet reach their targets exactly when they can and take
    their target orientations.

    The limb roots stay where ``pose`` puts them and each elbow and knee keeps the side
    ``pose`` bends it to and the twist its rotations give it about the limb's bones; the
    hips, spine, head and every other joint are unchanged. ``hint``: world directions
    ``(4, 3)`` (arms, then legs) to bend each elbow and knee towards instead of ``pose``'s
    (a zero row: ``pose``'s).
    Satisfies nothing by itself: compose it after an ``ik_fn``
    (:func:`bezmotion.ik.protores.protores_refined_ik_fn`).
    """
    dtype = targets.position.dtype
    limbs = np.asarray(rig.limbs)
    quat_global, pos_global = pose_fk(_rig_character(rig), pose)
    offsets = jnp.asarray(rig.skeleton.offsets, dtype)
    ends = np.asarray(_LIMB_TARGET)
    rot_end = matrix_from_rot6d(targets.rot6d[ends])
    roots = pos_global[limbs[:, 0]]
    own_local = matrix_from_quat(pose.quat_local)
    bones, turns = _limb_bones(rig, offsets, own_local)  # through the pose's own twist joints, which stay
    own = turns @ own_local[limbs[:, 1:]]  # (limb, mid / end, 3, 3): the pose's own twists
    own_side = pos_global[limbs[:, 1]] - roots
    hint = own_side if hint is None else jnp.where(jnp.any(hint != 0.0, axis=-1, keepdims=True), hint, own_side)
    upper, lower = _two_bone(roots, bones[:, 0], bones[:, 1], targets.position[ends], rot_end, hint, own[:, 0], own[:, 1])
    root_parents = matrix_from_quat(quat_global[np.asarray([rig.skeleton.parents[r] for r in limbs[:, 0]])])
    limb_parents = jnp.stack([root_parents, upper @ turns[:, 0], lower @ turns[:, 1]], axis=1)
    limb_local = jnp.swapaxes(limb_parents, -1, -2) @ jnp.stack([upper, lower, rot_end], axis=1)
    quat_local = pose.quat_local.at[limbs.reshape(-1)].set(quat_from_matrix(limb_local.reshape(-1, 3, 3)).astype(pose.quat_local.dtype))
    return Pose(pose.root_pos, quat_local)
