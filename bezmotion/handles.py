"""Handles: where joints must be, at which frames. The one struct every stage takes."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple, Protocol, runtime_checkable

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from bezmotion.bezier import BezierLayout
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS


@runtime_checkable
class WindowShape(Protocol):
    """What :meth:`Handles.from_frames` reads of a model's configuration."""

    num_frames: int
    num_joints: int


class Handles(NamedTuple):
    """Sparse position conditions: joint ``joint`` is at ``position`` at frame ``frame``.

    The one struct of the method's conditions: a user's handles, the BMM's condition tokens
    (the keys' joints, then the handles), the projection's and the baselines' constraints.

    Attributes:
      joint: ``(*batch, handles)`` characteristic-joint indices (0…5, see
        :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS`).
      frame: ``(*batch, handles)`` integer frames strictly inside the window (1 … 29 for
        31 frames): control frames (multiples of the stride) or any frame between them.
      position: ``(*batch, handles, 3)`` world positions (cm).
      valid: ``(*batch, handles)`` which entries are real (padding lets motions in a
        batch have different numbers of handles).
    """

    joint: Int[Array, "*batch handles"]
    frame: Int[Array, "*batch handles"]
    position: Float[Array, "*batch handles 3"]
    valid: Bool[Array, "*batch handles"]

    @classmethod
    def from_frames(
        cls,
        joints: list[str | int],
        frames: Sequence[Any],
        positions: Float[Array | np.ndarray, "handles 3"],
        *,
        config: WindowShape,
    ) -> Handles:
        """Handles from joint names (or indices), frame numbers and positions (one motion).

        ``frames`` are checked here rather than by type (ints, NumPy integers or whole
        floats; anything else raises naming it). Any integer frame strictly between the start and end frames is allowed; the same
        joint may have handles on several frames. Two handles on one joint and frame must
        agree (an identical repeat is harmless).

        Raises:
          ValueError: unknown joint, a frame that is not an integer in 1 … num_frames − 2
          (the start and end poses are given separately), two different positions for one
          joint and frame, or a positions array of the wrong shape.
        """
        positions = np.asarray(positions, np.float32)
        if positions.shape != (len(joints), 3) or len(frames) != len(joints):
            raise ValueError(
                f"need one frame and one (3,) position per joint: {len(joints)} joints, {len(frames)} frames, "
                f"positions {positions.shape}"
            )
        if not np.isfinite(positions).all():
            raise ValueError(f"handle positions must be finite, got {positions.tolist()}")
        joint_ids = []
        for j in joints:
            if isinstance(j, str):
                if j not in CHARACTERISTIC_JOINTS:
                    raise ValueError(f"unknown joint {j!r}; handles can be placed on {list(CHARACTERISTIC_JOINTS)}")
                j = CHARACTERISTIC_JOINTS.index(j)
            if not 0 <= int(j) < config.num_joints:
                raise ValueError(f"joint index {j} out of range 0…{config.num_joints - 1}")
            joint_ids.append(int(j))
        last = config.num_frames - 1
        frame_ids = []
        for f in frames:
            whole = _integer_frame(f)
            if whole is None or not 0 < whole < last:
                raise ValueError(
                    f"handles sit on integer frames strictly between 0 and {last} (the start and end poses are given "
                    f"separately), got {f!r}"
                )
            frame_ids.append(whole)
        seen: dict[tuple[int, int], int] = {}
        for i, slot in enumerate(zip(joint_ids, frame_ids)):
            if slot in seen and not np.array_equal(positions[seen[slot]], positions[i]):
                raise ValueError(
                    f"two handles on {CHARACTERISTIC_JOINTS[slot[0]]} at frame {slot[1]} with different positions: "
                    f"{positions[seen[slot]].tolist()} and {positions[i].tolist()}"
                )
            seen.setdefault(slot, i)
        return cls(
            jnp.asarray(joint_ids, jnp.int32),
            jnp.asarray(frame_ids, jnp.int32),
            jnp.asarray(positions),
            jnp.ones(len(joint_ids), bool),
        )

    @classmethod
    def from_controls(
        cls, joint: Int[ArrayLike, "*batch handles"], control: Int[ArrayLike, "*batch handles"], position, valid, *, stride: int
    ) -> Handles:
        """Handles on control points (the paper's): frame = ``control · stride``."""
        return cls(jnp.asarray(joint, jnp.int32), jnp.asarray(control, jnp.int32) * stride, jnp.asarray(position), jnp.asarray(valid, bool))

    @classmethod
    def empty(cls, batch_shape: tuple[int, ...] = ()) -> Handles:
        """No handles (one padding slot, so the shapes stay non-empty)."""
        return cls(
            jnp.zeros((*batch_shape, 1), jnp.int32),
            jnp.zeros((*batch_shape, 1), jnp.int32),
            jnp.zeros((*batch_shape, 1, 3), jnp.float32),
            jnp.zeros((*batch_shape, 1), bool),
        )

    @classmethod
    def from_grid(
        cls, mask: Bool[Array, "*batch controls joints"], position: Float[Array, "*batch controls joints 3"], stride: int
    ) -> Handles:
        """All ``controls × joints`` slots, valid where ``mask`` (the training layout)."""
        *batch, k, j = mask.shape
        control, joint = np.meshgrid(np.arange(k), np.arange(j), indexing="ij")
        shape = (*batch, k * j)
        return cls(
            position=position.reshape(*batch, k * j, 3),
            joint=jnp.broadcast_to(jnp.asarray(joint.reshape(-1), jnp.int32), shape),
            frame=jnp.broadcast_to(jnp.asarray(control.reshape(-1) * stride, jnp.int32), shape),
            valid=mask.reshape(shape),
        )

    def to_grid(
        self, num_controls: int, num_joints: int, stride: int
    ) -> tuple[Bool[Array, "controls joints"], Float[Array, "controls joints 3"]]:
        """``(mask, position)`` of the handles on control frames, on the control × joint
        grid (one motion; later slots win). Handles between control frames are left out."""
        return grid_conditions(BezierLayout.from_controls(num_controls, stride), self, num_joints)


def _integer_frame(frame) -> int | None:
    """``frame`` as an int when it is a whole number (int, NumPy integer or integral
    float), else ``None`` (bools, fractions, strings, NaN)."""
    if isinstance(frame, (bool, np.bool_)):
        return None
    if isinstance(frame, (int, np.integer)):
        return int(frame)
    if isinstance(frame, (float, np.floating)) and np.isfinite(frame) and float(frame).is_integer():
        return int(frame)
    return None


def on_control_frame(layout: BezierLayout, frame: Int[ArrayLike, "*shape"]) -> tuple[Bool[Array, "*shape"], Int[Array, "*shape"]]:
    """``(on_grid, control)``: whether each frame is a control frame, and its control index
    there (clipped into range elsewhere, so it is always safe to index with)."""
    frame = jnp.asarray(frame)
    controls = jnp.asarray(layout.control_frames, frame.dtype)
    control = jnp.clip(jnp.searchsorted(controls, frame), 0, layout.num_controls - 1).astype(jnp.int32)
    return controls[control] == frame, control


def grid_conditions(
    layout: BezierLayout, handles: Handles, num_joints: int
) -> tuple[Bool[Array, "controls joints"], Float[Array, "controls joints 3"]]:
    """``(mask, target)``: the valid handles that sit on control frames, on the control ×
    joint grid (one motion; later slots win); the others are left out."""
    on_grid, control = on_control_frame(layout, handles.frame)
    # Other slots scatter out of range and are dropped, so they never overwrite a grid one.
    control = jnp.where(handles.valid & on_grid, control, layout.num_controls)
    joint = handles.joint
    mask = jnp.zeros((layout.num_controls, num_joints), bool).at[control, joint].set(True, mode="drop")
    target = jnp.zeros((layout.num_controls, num_joints, 3), handles.position.dtype).at[control, joint].set(handles.position, mode="drop")
    return mask, target


__all__ = ["Handles", "WindowShape", "grid_conditions", "on_control_frame"]
