"""The six characteristic joints BMM models (hips, head, hands, feet) and their features.

BMM (§4.1) reduces any humanoid skeleton to ``J_sub`` — hips, head, both hands, both
feet — whose global positions (as Bézier curves) and global orientations (ortho6D) are
what the motion model generates; a skeleton-specific IK module turns them back into a
full pose. This module names those joints on each supported skeleton, extracts their
trajectories by forward kinematics, aligns windows the way the paper does, and labels
foot contacts.

Positions are centimetres, +Y up; rotations are global (world-from-joint).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bezmotion._src.messages import listed
from bezmotion.data import lafan1
from bezmotion.data.windows import foot_contacts
from bezmotion.geometry.rotations import rot6d_from_quat
from bezmotion.geometry.skeleton import forward_kinematics

CHARACTERISTIC_JOINTS: tuple[str, ...] = ("hips", "head", "left_hand", "right_hand", "left_foot", "right_foot")
"""The roles of ``J_sub``, in the order used by every array with a ``joints`` axis of 6."""

HIPS = CHARACTERISTIC_JOINTS.index("hips")
FEET: tuple[int, int] = (CHARACTERISTIC_JOINTS.index("left_foot"), CHARACTERISTIC_JOINTS.index("right_foot"))

SKELETON_MAPS: Mapping[str, Mapping[str, str]] = {
    "lafan1": {
        "hips": "Hips", "head": "Head", "left_hand": "LeftHand", "right_hand": "RightHand",
        "left_foot": "LeftFoot", "right_foot": "RightFoot",
    },
    "bandai_namco": {
        "hips": "Hips", "head": "Head", "left_hand": "Hand_L", "right_hand": "Hand_R",
        "left_foot": "Foot_L", "right_foot": "Foot_R",
    },
}  # fmt: skip
"""Role → joint name for the bundled skeletons. Feet are the ankles (the BVH ``*Foot``
joints); pass your own dict to :func:`characteristic_indices` for other skeletons."""

_BANDAI_NAMCO_NAMES = (
    "joint_Root", "Hips", "Spine", "Chest", "Neck", "Head", "Shoulder_L", "UpperArm_L", "LowerArm_L", "Hand_L",
    "Shoulder_R", "UpperArm_R", "LowerArm_R", "Hand_R", "UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L",
    "UpperLeg_R", "LowerLeg_R", "Foot_R", "Toes_R",
)  # fmt: skip
_BANDAI_NAMCO_PARENTS = (-1, 0, 1, 2, 3, 4, 3, 6, 7, 8, 3, 10, 11, 12, 1, 14, 15, 16, 1, 18, 19, 20)


def _hierarchy(names: Sequence[str], parents: Sequence[int]) -> dict[str, str | None]:
    return {name: (names[p] if p >= 0 else None) for name, p in zip(names, parents)}


PRESET_HIERARCHIES: Mapping[str, Mapping[str, str | None]] = {
    "lafan1": _hierarchy(lafan1.JOINT_NAMES, lafan1.PARENTS),
    "bandai_namco": _hierarchy(_BANDAI_NAMCO_NAMES, _BANDAI_NAMCO_PARENTS),
}
"""Each bundled skeleton's whole hierarchy, joint → parent (None for the root). A file is
taken for a preset only when its hierarchy is exactly this (:func:`preset_of`): six joint
names in common (a CMU or MotionBuilder file's ``Hips``, ``LeftHand`` …) say nothing about
the joints between them that the preset's models pose."""


def preset_of(joint_names: Sequence[str], parents: Sequence[int]) -> str | None:
    """The preset of :data:`PRESET_HIERARCHIES` whose whole hierarchy a skeleton has (the
    same joints, each under the same parent, in any order), else None."""
    hierarchy = _hierarchy(joint_names, parents)
    return next((preset for preset, theirs in PRESET_HIERARCHIES.items() if hierarchy == dict(theirs)), None)


CONTACT_SPEED = 0.002**0.5 * 100.0 * 20.0
"""Foot-contact speed threshold in cm/s (≈ 89.4): HumanML3D's rule (BMM cites Zhang et
al. 2023b), a squared per-frame displacement below 0.002 m² at 20 fps, restated as a
speed so it holds at any frame rate."""


def characteristic_indices(joint_names: Sequence[str], mapping: str | Mapping[str, str]) -> tuple[int, ...]:
    """Indices of the six characteristic joints in a skeleton, in :data:`CHARACTERISTIC_JOINTS` order.

    Args:
      joint_names: the skeleton's joint names.
      mapping: a key of :data:`SKELETON_MAPS` (``"lafan1"``, ``"bandai_namco"``) or a dict
        from every role in :data:`CHARACTERISTIC_JOINTS` to a joint name, e.g.
        ``{"hips": "pelvis", "head": "head", "left_hand": "l_wrist", …}``.
    Raises:
      ValueError: unknown preset, missing or unknown role, or a joint name the skeleton lacks.
    """
    if isinstance(mapping, str):
        if mapping not in SKELETON_MAPS:
            raise ValueError(f"unknown skeleton map {mapping!r}; known: {sorted(SKELETON_MAPS)}, or pass a dict")
        mapping = SKELETON_MAPS[mapping]
    missing = [role for role in CHARACTERISTIC_JOINTS if role not in mapping]
    unknown = [role for role in mapping if role not in CHARACTERISTIC_JOINTS]
    if missing or unknown:
        raise ValueError(
            f"a characteristic-joint map needs exactly the roles {list(CHARACTERISTIC_JOINTS)}; "
            f"missing {missing}, unknown {unknown}"
        )
    names = list(joint_names)
    absent = {role: mapping[role] for role in CHARACTERISTIC_JOINTS if mapping[role] not in names}
    if absent:
        raise ValueError(f"joints {absent} are not in the skeleton; its {len(names)} joints are {listed(names)}")
    indices = tuple(names.index(mapping[role]) for role in CHARACTERISTIC_JOINTS)
    if len(set(indices)) != len(indices):
        raise ValueError(f"characteristic joints must be distinct, got {dict(mapping)}")
    return indices


def characteristic_trajectories(
    parents: Sequence[int],
    indices: Sequence[int],
    quat_local: Float[Array, "*batch frames joints 4"],
    pos_local: Float[Array, "*batch frames joints 3"],
) -> tuple[Float[Array, "*batch frames 6 3"], Float[Array, "*batch frames 6 6"]]:
    """Global positions and 6D orientations of the characteristic joints, by FK.

    Args:
      parents: the skeleton's parent indices.
      indices: the six joints (:func:`characteristic_indices`).
      quat_local: local rotations (w, x, y, z).
      pos_local: local translations — offsets, with the animated root (and any other
        translated joint) filled in (cm).
    Returns:
      ``(positions (cm), rot6d)`` of the six joints.
    """
    quat_global, pos_global = forward_kinematics(tuple(parents), quat_local, pos_local)
    idx = np.asarray(indices)
    return pos_global[..., idx, :], rot6d_from_quat(quat_global[..., idx, :])


def align_to_start(
    positions: Float[Array, "*batch frames 6 3"],
) -> tuple[Float[Array, "*batch frames 6 3"], Float[Array, "*batch 3"]]:
    """Translate a window so the hips start at the origin in X and Z (BMM §4.1).

    Height is left alone and nothing is rotated: the paper works in a global frame and
    does not face-normalise, since the facing is unknown at test time.

    Returns:
      ``(aligned positions, translation)``; add ``translation`` back to undo.
    """
    start = positions[..., 0, HIPS, :]
    translation = start * jnp.asarray([1.0, 0.0, 1.0], positions.dtype)
    return positions - translation[..., None, None, :], translation


def contact_labels(
    positions: Float[Array, "*batch frames 6 3"],
    fps: float,
    speed_threshold: float = CONTACT_SPEED,
) -> Bool[Array, "*batch frames 2"]:
    """Left and right foot contacts: the ankle moves slower than ``speed_threshold`` (cm/s).

    The last frame repeats the label before it.
    """
    if not (fps > 0 and speed_threshold > 0):  # also rejects NaN
        raise ValueError(f"fps and speed_threshold must be positive, got fps={fps}, speed_threshold={speed_threshold}")
    return foot_contacts(positions, FEET, threshold=(speed_threshold / fps) ** 2)
