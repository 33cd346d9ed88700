"""Soft per-joint rotation limits, measured from a corpus, for the exact IK (:mod:`bezmotion.ik.exact`).

A joint's limits are a range per axis of the rotation vector of its local rotation relative
to the corpus' mean rotation of that joint (``log(center⁻¹ ⊗ q_local)``, radians). The exact
IK's solve pays a hinge beyond the range, so a limb keeps to rotations people make.
:func:`joint_limits_from_motion` measures them (``experiments/joint_limits.py`` over a
corpus' training clips); :meth:`JointLimits.save` / :meth:`JointLimits.load` keep them as
JSON beside an IK model (``joint_limits.json``).
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion.geometry.rotations import quat_conjugate, quat_log, quat_mul
from bezmotion._src.checksums import add_checked_file
from bezmotion._src.structured_files import read_structured_file
from bezmotion.ik.protocol import Character

# A joint without limits: a range wider than any rotation's logarithm (|log| ≤ π).
_UNLIMITED = 1e3


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class JointLimits:
    """Soft per-joint rotation limits: a range per axis of ``log(center⁻¹ ⊗ q_local)``.

    Attributes:
      center: ``(joints, 4)`` the corpus' mean local rotation of each joint.
      lower, upper: ``(joints, 3)`` the range (rad) of the rotation vector of each joint's
        local rotation relative to ``center``, in the center's frame; ±1e3 = unlimited.
    """

    center: Float[Array, "joints 4"]
    lower: Float[Array, "joints 3"]
    upper: Float[Array, "joints 3"]

    @classmethod
    def unlimited(cls, num_joints: int, dtype=jnp.float32) -> JointLimits:
        """No limits (the default when none were measured)."""
        center = jnp.zeros((num_joints, 4), dtype).at[:, 0].set(1.0)
        return cls(center, jnp.full((num_joints, 3), -_UNLIMITED, dtype), jnp.full((num_joints, 3), _UNLIMITED, dtype))

    def to_json(self, character: Character) -> dict[str, Any]:
        """``{"joints": {name: {"center": [w, x, y, z], "lower": [...], "upper": [...]}}}`` (radians)."""
        center, lower, upper = (np.asarray(x, np.float64) for x in (self.center, self.lower, self.upper))
        return {
            "units": "radians; rotation vector of center⁻¹ ⊗ local rotation",
            "joints": {
                name: {"center": center[j].round(6).tolist(), "lower": lower[j].round(5).tolist(), "upper": upper[j].round(5).tolist()}
                for j, name in enumerate(character.skeleton.names)
            },
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any], character: Character) -> JointLimits:
        """Limits from :meth:`to_json`'s dict; joints it does not name are unlimited.

        Raises:
          ValueError: a joint name the character does not have, or a malformed entry.
        """
        joints = data.get("joints") if isinstance(data, Mapping) else None
        if not isinstance(joints, Mapping):
            raise ValueError(f"joint limits need a 'joints' mapping, got {type(joints).__name__}")
        names = character.skeleton.names
        unknown = [n for n in joints if n not in names]
        if unknown:
            raise ValueError(f"joint limits name joints {unknown} that {character.name} does not have")
        limits = cls.unlimited(character.num_joints)
        center, lower, upper = (np.array(x, np.float64) for x in (limits.center, limits.lower, limits.upper))
        for name, entry in joints.items():
            j = names.index(name)
            try:
                c, lo, hi = (np.asarray(entry[k], np.float64) for k in ("center", "lower", "upper"))
            except (KeyError, TypeError) as err:
                raise ValueError(f"joint limits of {name!r}: need 'center', 'lower' and 'upper' ({err})") from None
            if c.shape != (4,) or lo.shape != (3,) or hi.shape != (3,) or not (np.all(lo <= hi) and np.linalg.norm(c) > 0.5):
                raise ValueError(f"joint limits of {name!r}: bad center {c.tolist()} or range {lo.tolist()}…{hi.tolist()}")
            center[j], lower[j], upper[j] = c / np.linalg.norm(c), lo, hi
        return cls(jnp.asarray(center, jnp.float32), jnp.asarray(lower, jnp.float32), jnp.asarray(upper, jnp.float32))

    def save(self, path: str | os.PathLike, character: Character) -> None:
        """Write :meth:`to_json` to ``path`` (atomically). In a saved model's folder (one with
        checksums) the file joins its checksums, after the folder is checked
        (:func:`~bezmotion._src.checksums.add_checked_file`; a damaged folder raises)."""
        path = Path(path)
        add_checked_file(path.parent, path.name, json.dumps(self.to_json(character), indent=1) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike, character: Character) -> JointLimits:
        """Read limits written by :meth:`save`.

        Raises:
          ValueError: not such a file (naming it), or not one of ``character``'s joints.
        """
        try:
            data = read_structured_file(path)
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None
        return cls.from_json(data, character)


def joint_limits_from_motion(
    character: Character,
    quat_local: Float[Array | np.ndarray, "frames joints 4"],
    *,
    percentile: float = 0.5,
    margin: float = 0.1,
) -> JointLimits:
    """Measure per-joint rotation limits on motion frames (e.g. a corpus' training clips).

    Args:
      character: the skeleton (the hips and the joints above it stay unlimited: the hips'
        rotation is global, the others are held at identity).
      quat_local: ``(frames, joints, 4)`` local rotations.
      percentile: the range runs from this percentile to ``100 - percentile`` on each axis.
      margin: radians added on both sides (the corpus is a sample of what bodies do).
    """
    q = np.asarray(quat_local, np.float64).reshape(-1, character.num_joints, 4)
    if q.shape[0] == 0:
        raise ValueError("joint limits need at least one frame")
    # The mean of hemisphere-aligned quaternions (aligned to a first estimate): fine for
    # the concentrated distributions of joint rotations.
    first = q[0]
    q = np.where(np.sum(q * first, axis=-1, keepdims=True) < 0.0, -q, q)
    center = q.mean(axis=0)
    center /= np.maximum(np.linalg.norm(center, axis=-1, keepdims=True), 1e-12)
    with jax.default_device(jax.devices("cpu")[0]):
        rel = np.asarray(quat_log(quat_mul(quat_conjugate(jnp.asarray(center)[None]), jnp.asarray(q))))
    lower = np.percentile(rel, percentile, axis=0) - margin
    upper = np.percentile(rel, 100.0 - percentile, axis=0) + margin
    free = [character.hips, *character.ancestors_of_hips()]
    lower[free], upper[free] = -_UNLIMITED, _UNLIMITED
    return JointLimits(jnp.asarray(center, jnp.float32), jnp.asarray(lower, jnp.float32), jnp.asarray(upper, jnp.float32))
