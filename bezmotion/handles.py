"""Handles: where joints must be, at which frames. The one struct every stage takes."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple, Protocol, runtime_checkable

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from bezmotion._src.problems import Problem, raised_in_program
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




HANDLE_FARTHEST_CM = 10_000.0
"""How far (cm) a handle may lie from the straight line between the keys around it: no
motion within one window goes farther, so a handle beyond it is a slip of units or digits."""


def straight_line(start: Float[Array, "*batch joints 3"], end: Float[Array, "*batch joints 3"], handles: Handles, num_frames: int) -> Float[Array, "*batch slots 3"]:
    """Where each handle's joint is on the straight line from its ``start`` to its ``end``
    position at the handle's frame (one window of ``num_frames`` frames, batched alike)."""
    joint = jnp.clip(handles.joint, 0, start.shape[-2] - 1)[..., None]
    at = lambda pos: jnp.take_along_axis(pos, joint, axis=-2)  # noqa: E731  (*batch, slots, 3)
    t = (handles.frame / (num_frames - 1)).astype(start.dtype)[..., None]
    return (1.0 - t) * at(start) + t * at(end)


def line_between_keys(key_positions: np.ndarray, joint: int, frame: int, key_frames: Sequence[int] | np.ndarray) -> np.ndarray:
    """``(3,)`` where ``joint`` is at ``frame`` on the straight line between its positions at
    the keys around that frame (``key_positions`` ``(K, joints, 3)``, the keys at
    ``key_frames`` ``(K,)``, increasing): the reference a relative handle is an offset from."""
    key_frames = np.asarray(key_frames)
    window = int(np.clip(np.searchsorted(key_frames, frame, side="right") - 1, 0, len(key_positions) - 2))
    t = (frame - key_frames[window]) / (key_frames[window + 1] - key_frames[window])
    return (1.0 - t) * key_positions[window, joint] + t * key_positions[window + 1, joint]


def handle_problems(
    handles: Handles, *, num_frames: int, num_joints: int, span: int | None = None, line: Float[Array, "*batch slots 3"] | None = None
) -> list[Problem]:
    """What is wrong with ``handles``' valid slots: a :class:`~bezmotion._src.problems.Problem`
    per rule, flagging each slot that breaks it (over any batch), its message naming the slot.

    Args:
      num_frames: frames of the motion the handles' frames count in (a window's 31, or a
        chain's); a handle sits strictly inside, and off every ``span``-th frame (the keys).
      num_joints: joints a handle's index may name.
      line: ``(*batch, slots, 3)`` the straight line between the keys at each handle
        (:func:`straight_line`); a handle farther than :data:`HANDLE_FARTHEST_CM` from it is refused.
    Raises:
      ValueError: at once, frames or joints that are not integers.
    """
    for name in ("frame", "joint"):
        if not jnp.issubdtype(jnp.asarray(getattr(handles, name)).dtype, jnp.integer):
            raise ValueError(f"handles.{name} must be integers, got {jnp.asarray(getattr(handles, name)).dtype}")
    last = num_frames - 1
    span = last if span is None else span
    joint, frame, position, valid = handles.joint, handles.frame, handles.position, handles.valid.astype(bool)
    same = (joint[..., :, None] == joint[..., None, :]) & (frame[..., :, None] == frame[..., None, :]) & valid[..., :, None] & valid[..., None, :]
    differ = jnp.any(position[..., :, None, :] != position[..., None, :, :], axis=-1)
    rules = [
        (valid & ((joint < 0) | (joint >= num_joints)), f"joint index outside 0 … {num_joints - 1}"),
        (valid & ((frame <= 0) | (frame >= last) | (frame % span == 0)), f"frame outside 1 … {last - 1} or on a key (every {span}th frame)"),
        (valid & ~jnp.isfinite(position).all(axis=-1), "position not finite"),
        (jnp.any(same & differ, axis=-1), "another handle puts the same joint at the same frame elsewhere"),
    ]
    if line is not None:
        far = valid & (jnp.linalg.norm(position - line, axis=-1) > HANDLE_FARTHEST_CM)
        rules.append((far, f"farther than {HANDLE_FARTHEST_CM / 100:.0f} m from the straight line between its keys (positions are in cm)"))
    slots = handles.valid.shape[-1]
    return [Problem(bad.reshape(-1, slots).any(axis=0), tuple(f"handle {i}: {what}" for i in range(slots))) for bad, what in rules]


def checked_handles(
    handles: Handles, *, num_frames: int, num_joints: int, span: int | None = None, line: Float[Array, "*batch slots 3"] | None = None
) -> Handles:
    """``handles`` with run-time checks of their valid slots (``eqx.error_if``, inside a
    computation as outside: one path), each naming the first slot that fails it; the rules
    and arguments are :func:`handle_problems`'."""
    return raised_in_program(handles, handle_problems(handles, num_frames=num_frames, num_joints=num_joints, span=span, line=line))


__all__ = ["HANDLE_FARTHEST_CM", "Handles", "WindowShape", "checked_handles", "handle_problems", "grid_conditions", "line_between_keys", "on_control_frame", "straight_line"]
