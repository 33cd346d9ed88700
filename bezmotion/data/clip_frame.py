"""A clip's units and up axis, told from the clip, and its motion converted into ours and back.

bezmotion works in centimetres with Y up (the LaFAN1 and Bandai-Namco files' convention, and
what every threshold of the pipeline is measured in: a planted foot moves slower than
7.5 cm/s, a handle is missed beyond 1 cm, the exact IK's weights are per cm). BVH files from
other tools come in metres or millimetres (Blender's exporter writes its scene unit, the
metre), some with Z up. :class:`ClipFrame` converts such a clip into ours before anything
reads it, and the result back into the clip's own convention when it is written, so the
in-between opens in the user's tool where the clip does.

:func:`detect_clip_frame` tells both from the clip:

- **up**: the direction (+Y or +Z) along which the head stands above the feet in many of the
  clip's frames and below them in (nearly) none (a frame counts where the head-over-feet
  direction is within ~37° of an axis; lying frames count for both sides of a horizontal
  axis as the body turns);
- **units**: the skeleton's size — the bone lengths from the head down to the hips and on to
  a foot, as the offsets give them (the same in every pose) — is a person's 70–300 cm (a
  child's to a giant's) in centimetres, in metres or in millimetres, and only one of them.
  A skeleton that is a person's size in none of them (raw CMU files, in a unit of about
  5.6 cm; inches, a person ~55–65 in) is taken to be a typical adult's size,
  :data:`TYPICAL_PERSON_CM`, and its unit is that many centimetres over its size: any unit
  works, to within a person's build, and the caller says so.

A unit is a name of :data:`CM_PER_UNIT` or a number of centimetres per file unit, written
as text (``"5.6"``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data.bvh import BvhMotion
from bezmotion.geometry.rotations import quat_mul, quat_rotate
from bezmotion.geometry.skeleton import ancestors, forward_kinematics

CM_PER_UNIT = {"cm": 1.0, "m": 100.0, "mm": 0.1, "in": 2.54}
"""Centimetres per unit of each unit a clip may be in."""
UP_AXES = ("y", "z")
DETECTED_UNITS = ("cm", "m", "mm")  # told apart by size alone; inches are not (see the module docstring)
PERSON_CM = (70.0, 300.0)  # a skeleton's head-to-hips-to-foot length (cm) that counts as a person's, a child's to a giant's
TYPICAL_PERSON_CM = 150.0  # an adult's head-to-hips-to-foot length (cm): LaFAN1's actors 166, Bandai-Namco's 134
_DETECT_FRAMES = 256  # frames of a clip the up axis is told from (evenly spread)
_UPRIGHT = 0.8  # a frame votes for an axis when its head-over-feet direction is within ~37° of it
_OPPOSITE = 0.05  # up's opposite may get this fraction of up's votes (a handstand, a cartwheel)

# Z up into Y up: −90° about X, (x, y, z) → (x, z, −y), as a quaternion (w, x, y, z).
_Z_TO_Y_QUAT = np.array([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0])


@dataclasses.dataclass(frozen=True)
class ClipFrame:
    """The units and up axis a clip is written in.

    Attributes:
      units: one of :data:`CM_PER_UNIT` (``"cm"``, ``"m"``, ``"mm"``, ``"in"``).
      up: ``"y"`` or ``"z"``.
    """

    units: str = "cm"
    up: str = "y"

    def __post_init__(self) -> None:
        cm_per_unit(self.units)  # a name or a positive number
        if self.up not in UP_AXES:
            raise ValueError(f"up must be one of {', '.join(UP_AXES)}, got {self.up!r}")

    @property
    def cm_per_unit(self) -> float:
        """Centimetres per unit of the file."""
        return cm_per_unit(self.units)

    @property
    def is_ours(self) -> bool:
        """Centimetres with Y up: nothing to convert."""
        return self.cm_per_unit == 1.0 and self.up == "y"

    def to_ours(self, motion: BvhMotion) -> BvhMotion:
        """``motion`` in centimetres with Y up: offsets, translations and End Sites scaled to
        cm; with Z up, the whole motion turned about X (the root's rotation and position:
        every other joint is in its parent's frame)."""
        return _convert(motion, self.cm_per_unit, _Z_TO_Y_QUAT if self.up == "z" else None)

    def from_ours(self, motion: BvhMotion) -> BvhMotion:
        """The inverse of :meth:`to_ours`: a motion of ours in this frame's units and up axis."""
        inverse = _Z_TO_Y_QUAT * np.array([1.0, -1.0, -1.0, -1.0])
        return _convert(motion, 1.0 / self.cm_per_unit, inverse if self.up == "z" else None)


def cm_per_unit(units: str) -> float:
    """Centimetres per unit of ``units``: a name of :data:`CM_PER_UNIT` or a positive number as text.

    Raises:
      ValueError: neither (the message gives the value).
    """
    if units in CM_PER_UNIT:
        return CM_PER_UNIT[units]
    try:
        value = float(units)
    except (TypeError, ValueError):
        value = float("nan")
    if not (np.isfinite(value) and 1e-6 <= value <= 1e6):
        raise ValueError(f"units must be one of {', '.join(CM_PER_UNIT)} or centimetres per unit (a number), got {units!r}")
    return value


def _convert(motion: BvhMotion, scale: float, turn: np.ndarray | None) -> BvhMotion:
    """``motion`` scaled by ``scale``, then turned by the quaternion ``turn`` (about the world origin)."""
    if scale == 1.0 and turn is None:
        return motion
    offsets = np.asarray(motion.skeleton.offsets, np.float64) * scale
    pos_local = np.asarray(motion.pos_local, np.float64) * scale
    quat_local = np.asarray(motion.quat_local, np.float64)
    if turn is not None:
        with jax.enable_x64(True):
            root = np.asarray(quat_mul(jnp.asarray(turn), jnp.asarray(quat_local[:, 0])))
            root_pos = np.asarray(quat_rotate(jnp.asarray(turn), jnp.asarray(pos_local[:, 0])))
        pos_local = pos_local.copy()
        pos_local[:, 0] = root_pos
        quat_local = quat_local.copy()
        quat_local[:, 0] = root
    end_sites = tuple((parent, tuple(float(x) * scale for x in offset)) for parent, offset in motion.end_sites)
    skeleton = dataclasses.replace(motion.skeleton, offsets=offsets)
    return dataclasses.replace(motion, skeleton=skeleton, quat_local=quat_local, pos_local=pos_local, end_sites=end_sites)


def chain_length(parents, offsets: np.ndarray, a: int, b: int) -> float:
    """Length of the bones between joints ``a`` and ``b`` along the hierarchy (through their
    lowest common ancestor), in the offsets' units."""
    up_a, up_b = ancestors(parents, a), ancestors(parents, b)
    common = next(j for j in up_a if j in set(up_b))
    bones = up_a[: up_a.index(common)] + up_b[: up_b.index(common)]  # each joint's offset is its bone to its parent
    return float(sum(np.linalg.norm(offsets[j]) for j in bones))


def detect_units(motion: BvhMotion, hips: int, head: int, feet: tuple[int, int]) -> str:
    """The length unit of ``motion`` from its skeleton's size: the bones from ``head`` down to
    ``hips`` and on to the longer of the ``feet``' legs. ``"cm"``, ``"m"`` or ``"mm"`` where
    the size is a person's in exactly one of them; else the centimetres per unit that make it
    :data:`TYPICAL_PERSON_CM` (as text, e.g. ``"5.617"``: see the module docstring).

    Raises:
      ValueError: the skeleton has no size (its bones are all of zero length).
    """
    size = skeleton_size(motion, hips, head, feet)
    fits = [u for u in DETECTED_UNITS if PERSON_CM[0] <= size * CM_PER_UNIT[u] <= PERSON_CM[1]]
    if len(fits) == 1:
        return fits[0]
    if not (np.isfinite(size) and size > 0):
        raise ValueError(f"cannot tell the clip's units: its head-to-hips-to-foot bones are {size:.4g} units long")
    return f"{TYPICAL_PERSON_CM / size:.6g}"


def skeleton_size(motion: BvhMotion, hips: int, head: int, feet: tuple[int, int]) -> float:
    """The length of the bones from ``head`` down to ``hips`` and on to the longer of the
    ``feet``' legs, in the file's units (the same in every pose)."""
    parents = motion.skeleton.parents
    offsets = np.asarray(motion.skeleton.offsets, np.float64)
    return chain_length(parents, offsets, head, hips) + max(chain_length(parents, offsets, hips, f) for f in feet)


def detect_up(motions: BvhMotion | Sequence[BvhMotion], head: int, feet: tuple[int, int]) -> str:
    """The up axis (``"y"`` or ``"z"``) of a clip, or of clips of one skeleton told together:
    where the ``head`` stands above the ``feet`` (left, right) in many frames and below them
    in (nearly) none.

    Raises:
      ValueError: that direction is neither +Y nor +Z, or no direction is; the message
        gives each direction's count of frames.
    """
    above = []  # (frames, 3) head over the feet, of every clip
    for motion in [motions] if isinstance(motions, BvhMotion) else motions:
        frames = np.unique(np.linspace(0, motion.num_frames - 1, min(_DETECT_FRAMES, motion.num_frames)).round().astype(int))
        with jax.enable_x64(True):
            _, pos = forward_kinematics(motion.skeleton.parents, jnp.asarray(motion.quat_local[frames]), jnp.asarray(motion.pos_local[frames]))
        pos = np.asarray(pos)
        above.append(pos[:, head] - 0.5 * (pos[:, feet[0]] + pos[:, feet[1]]))
    above = np.concatenate(above)
    # Each frame where the body lies clearly along one axis votes for that direction (±X, ±Y,
    # ±Z). A person's head is (nearly) never below the feet, so up is a direction voted for
    # whose opposite (nearly) never is; lying frames (falls, ground work) vote for both sides
    # of the horizontal axes as the body turns. Of such directions, the most voted is up.
    along = np.abs(above) > _UPRIGHT * np.linalg.norm(above, axis=-1, keepdims=True)
    votes = np.array([[np.sum(along[:, a] & (above[:, a] * sign > 0)) for sign in (1, -1)] for a in range(3)])  # (axis, ±)
    one_sided = (votes > 0) & (votes[:, ::-1] <= _OPPOSITE * votes)
    axis, negative = np.unravel_index(np.argmax(np.where(one_sided, votes, -1)), votes.shape)
    if not one_sided[axis, negative] or negative or axis == 0:
        shown = ", ".join(f"{d}{x} in {votes[a, k]}" for a, x in enumerate("XYZ") for k, d in enumerate("+−"))
        raise ValueError(
            f"cannot tell the clip's up axis: of {len(above)} frames, the head stands above the feet along {shown}; "
            "give it (y or z)"
        )
    return "y" if axis == 1 else "z"


def detect_clip_frame(motion: BvhMotion, hips: int, head: int, feet: tuple[int, int]) -> ClipFrame:
    """The units and up axis of ``motion`` (see the module docstring), from its joints'
    indices ``hips``, ``head`` and ``feet`` (left, right): :func:`detect_units`, :func:`detect_up`."""
    return ClipFrame(detect_units(motion, hips, head, feet), detect_up(motion, head, feet))


__all__ = ["CM_PER_UNIT", "TYPICAL_PERSON_CM", "UP_AXES", "ClipFrame", "chain_length", "cm_per_unit", "detect_clip_frame", "detect_units", "detect_up", "skeleton_size"]
