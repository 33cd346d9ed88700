"""The reference motions the models predict over: interpolation through what is known.

- :func:`keyframe_interpolation` (lerp the root, slerp local rotations) and
  :func:`keyframe_position_interpolation` (global point positions) between the key frames
  around each missing frame, for any layout of known frames (:class:`KeyFrames`,
  :class:`KeyPositions`: frame indices and a validity mask, so padded layouts work): the
  Δ-interpolator's residual bases and the benchmarks' interpolation baselines.
- :func:`handle_interpolation`: the BMM's reference, Bézier curves through the start, end
  and handle control points; :func:`interpolation_through_points` the same through point
  conditions at any frames (handles between control frames too).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from bezmotion.bezier import BezierLayout
from bezmotion.diffusion.projection import project_off_grid
from bezmotion.handles import Handles, grid_conditions, on_control_frame
from bezmotion.geometry.rotations import slerp

# ------------------------------------------------------------------------ key frames


class KeyFrames(NamedTuple):
    """The known frames of one example (add leading axes to batch).

    Attributes:
      quat_local: ``(keys, J, 4)`` local rotations (root: global).
      root_pos: ``(keys, 3)`` root positions (cm).
      frame: ``(keys,)`` frame index of each key in the window (increasing over valid keys).
      valid: ``(keys,)`` which slots hold a key frame; the others are padding, never
        read (the Δ-interpolator's first ``n_past`` slots, the past context, must be valid).
    """

    quat_local: Float[Array, "*batch keys joints 4"]
    root_pos: Float[Array, "*batch keys 3"]
    frame: Int[Array, "*batch keys"]
    valid: Bool[Array, "*batch keys"]


class KeyPositions(NamedTuple):
    """The known frames of one example in the positions representation (add leading axes
    to batch).

    Attributes:
      pos: ``(keys, P, 3)`` global point positions (cm); point 0 is the root.
      frame: ``(keys,)`` frame index of each key (increasing over valid keys).
      valid: ``(keys,)`` which slots hold a key frame; the others are padding, never
        read (the Δ-interpolator's first ``n_past`` slots, the past context, must be valid).
    """

    pos: Float[Array, "*batch keys points 3"]
    frame: Int[Array, "*batch keys"]
    valid: Bool[Array, "*batch keys"]



def _bracketing_keys(
    frame: Int[Array, "keys"], valid: Bool[Array, "keys"], missing_frame: Int[Array, "missing"], dtype
) -> tuple[Int[Array, "missing"], Int[Array, "missing"], Array]:
    """For each missing frame: the slots of the nearest valid keys before and after it and
    its lerp weight between them (0 at ``prev``). A frame with a key on one side only gets
    that key on both sides (weight 0)."""
    t = missing_frame[:, None]
    before = valid[None, :] & (frame[None, :] < t)
    after = valid[None, :] & (frame[None, :] > t)
    prev = jnp.argmax(jnp.where(before, frame[None, :], jnp.iinfo(frame.dtype).min), axis=-1)
    nxt = jnp.argmin(jnp.where(after, frame[None, :], jnp.iinfo(frame.dtype).max), axis=-1)
    prev = jnp.where(before.any(-1), prev, nxt)
    nxt = jnp.where(after.any(-1), nxt, prev)
    span = frame[nxt] - frame[prev]
    w = jnp.where(span > 0, (missing_frame - frame[prev]).astype(dtype) / jnp.maximum(span, 1).astype(dtype), 0.0)
    return prev, nxt, w


def keyframe_interpolation(
    keys: KeyFrames, missing_frame: Int[Array, "missing"]
) -> tuple[Float[Array, "missing joints 4"], Float[Array, "missing 3"]]:
    """Lerp the root and slerp every local rotation between the valid key frames just
    before and just after each missing frame (weights by frame index).

    With 10 past frames and one target this is the benchmark's :func:`interpolation`,
    weights ``k/(n+1)``. A frame with a key on one side only copies that key. One
    example; ``jax.vmap`` over a batch. Returns ``(quat (missing, J, 4), root (missing, 3))``.
    """
    prev, nxt, w = _bracketing_keys(keys.frame, keys.valid, missing_frame, keys.root_pos.dtype)
    quat = slerp(keys.quat_local[prev], keys.quat_local[nxt], w[:, None])
    root = keys.root_pos[prev] + w[:, None] * (keys.root_pos[nxt] - keys.root_pos[prev])
    return quat, root


def keyframe_position_interpolation(keys: KeyPositions, missing_frame: Int[Array, "missing"]) -> Float[Array, "missing points 3"]:
    """Lerp every point between the valid key frames just before and just after each
    missing frame, weights by frame index (the Anidance benchmark's LERP baseline; with key
    frames every 6 frames, piecewise linear through them). A frame with a key on one side
    only copies that key. One example; ``jax.vmap`` over a batch."""
    prev, nxt, w = _bracketing_keys(keys.frame, keys.valid, missing_frame, keys.pos.dtype)
    return keys.pos[prev] + w[:, None, None] * (keys.pos[nxt] - keys.pos[prev])



# ---------------------------------------------------------------------- curves (BMM)


def handle_interpolation(
    mask: Bool[Array, "*batch controls joints"], target: Float[Array, "*batch controls joints 3"]
) -> tuple[Float[Array, "*batch controls joints 3"], Float[Array, "*batch controls joints 3"]]:
    """The non-learned reference for BMM: curves through the known control points only.

    Each joint's unknown control positions are linearly interpolated (in control index)
    between its nearest known ones — the first and last control points are always known
    in in-betweening — and tangents are Catmull-Rom's, ``T_k = (P_{k+1} − P_{k−1})/6``
    (velocity = central difference), one-sided ``(P_1 − P_0)/3`` at the ends.

    Args:
      mask: which (control, joint) positions are known; the first and last rows must be.
      target: the known positions (cm); ignored where ``mask`` is false.
    Returns:
      ``(ctrl_pos, ctrl_tangent)``.
    """
    k = mask.shape[-2]
    index = jnp.arange(k)[:, None]
    prev = jax.lax.cummax(jnp.where(mask, index, 0), axis=mask.ndim - 2)
    nxt = jax.lax.cummin(jnp.where(mask, index, k - 1), axis=mask.ndim - 2, reverse=True)
    span = jnp.maximum(nxt - prev, 1)
    w = ((index - prev) / span).astype(target.dtype)[..., None]
    take = lambda i: jnp.take_along_axis(target, i[..., None], axis=-3)  # noqa: E731
    pos = (1.0 - w) * take(prev) + w * take(nxt)
    pos = jnp.where(mask[..., None], target, pos)
    return pos, _catmull_rom_tangents(pos)


# How the reference reaches conditions between control frames (interpolation_through_points).
OFF_GRID_REFERENCES = ("projection", "linear")


def interpolation_through_points(
    layout: BezierLayout,
    conditions: Handles,
    num_joints: int,
    *,
    off_grid: str = "linear",
) -> tuple[Float[Array, "controls joints 3"], Float[Array, "controls joints 3"], Bool[Array, "controls joints"]]:
    """The reference curves through point conditions at any frames (one motion; ``jax.vmap``
    over a batch): every valid condition met exactly.

    On control frames only (the paper's handles), this is :func:`handle_interpolation` of
    the conditioned control points. A condition between control frames (``frame`` 13,
    say) is reached one of two ways:

    - ``"projection"``: :func:`handle_interpolation` through the conditions on control
      frames alone, then the minimum-norm correction onto the others
      (:func:`~bezmotion.diffusion.projection.project_off_grid`). The correction moves only
      the two control points around the condition, so the curve bends there alone: a bump
      that rises and falls within about six frames, so the joint strays from the motion
      around the handle more than around a handle on a control frame.
    - ``"linear"`` (default): each joint's control positions linear in *frame* between its
      nearest conditions before and after them, wherever those sit (on control frames this
      is :func:`handle_interpolation`'s interpolation in control index), Catmull-Rom
      tangents, then the same correction, now a small one: the condition shapes the curve
      between its neighbouring conditions as a condition on a control frame does.

    Args:
      layout: the curves' layout.
      conditions: ``(slots,)`` each condition's joint, frame (0 … last), position (cm) and
        whether it is real; every joint needs a valid condition at the first and at the
        last frame (in-betweening's keys), or its curve is meaningless (finite, though).
      num_joints: joints of the curves.
      off_grid: ``"linear"`` or ``"projection"`` (above).
    Returns:
      ``(ctrl_pos, ctrl_tangent, on_grid)``: the curves ``(controls, joints, 3)`` and which
      control positions a condition on a control frame set ``(controls, joints)``.
    Raises:
      ValueError: ``off_grid`` not one of :data:`OFF_GRID_REFERENCES`.
    """
    if off_grid not in OFF_GRID_REFERENCES:
        raise ValueError(f"off_grid must be one of {OFF_GRID_REFERENCES}, got {off_grid!r}")
    on_grid, _ = on_control_frame(layout, conditions.frame)
    # The two ways differ only in which conditions the interpolation reads ("projection": those
    # on control frames, i.e. handle_interpolation); the correction meets the rest either way.
    read = conditions.valid if off_grid == "linear" else conditions.valid & on_grid
    ctrl_pos = _linear_in_frame(layout, conditions._replace(valid=read), num_joints)
    mask, _ = grid_conditions(layout, conditions, num_joints)
    ctrl_pos, ctrl_tangent = project_off_grid(layout, ctrl_pos, _catmull_rom_tangents(ctrl_pos, layout.last_control), mask, conditions)
    return ctrl_pos, ctrl_tangent, mask


def _linear_in_frame(layout: BezierLayout, conditions: Handles, num_joints: int) -> Float[Array, "controls joints 3"]:
    """``(controls, joints, 3)``: each joint's position at every control frame, linear in
    frame between its nearest valid conditions at or before and at or after that frame (a
    condition on the control frame itself: its position exactly, the weight being 0)."""
    joint, frame, position, valid = conditions
    controls = jnp.asarray(layout.control_frames, jnp.int32)[:, None, None]  # (K, 1, 1)
    own = (valid[None, :] & (joint[None, :] == jnp.arange(num_joints)[:, None]))[None]  # (1, J, S)
    slot_frame = frame.astype(jnp.int32)[None, None, :]
    before = jnp.argmax(jnp.where(own & (slot_frame <= controls), slot_frame, -1), axis=-1)  # (K, J)
    after = jnp.argmin(jnp.where(own & (slot_frame >= controls), slot_frame, layout.num_frames), axis=-1)
    f0, f1 = frame[before], frame[after]
    # In control index on control frames, as handle_interpolation: (k − prev) / span.
    w = ((controls[..., 0] - f0) / jnp.maximum(f1 - f0, 1)).astype(position.dtype)[..., None]
    return (1.0 - w) * position[before] + w * position[after]


def _catmull_rom_tangents(pos: Float[Array, "*batch controls joints 3"], last: int | Int[Array, ""] | None = None) -> Float[Array, "*batch controls joints 3"]:
    """``T_k = (P_{k+1} − P_{k−1})/6``, one-sided ``(P_1 − P_0)/3`` at the ends.

    ``last``: the last control point when the ones after it are padding (a
    :class:`~bezmotion.bezier.PaddedLayout`'s traced one): the padding is replaced by the
    reflection ``2·P_last − P_{last−1}``, whose central difference at ``last`` is the
    one-sided one, so the window's own tangents are those of its unpadded curve.
    """
    if last is not None and not isinstance(last, int):
        k = jnp.arange(pos.shape[-3])[:, None, None]
        end, before = jnp.take(pos, last, axis=-3)[..., None, :, :], jnp.take(pos, last - 1, axis=-3)[..., None, :, :]
        pos = jnp.where(k > last, 2.0 * end - before, pos)
    inner = (pos[..., 2:, :, :] - pos[..., :-2, :, :]) / 6.0
    first = (pos[..., 1:2, :, :] - pos[..., :1, :, :]) / 3.0
    last = (pos[..., -1:, :, :] - pos[..., -2:-1, :, :]) / 3.0
    return jnp.concatenate([first, inner, last], axis=-3)


__all__ = [
    "OFF_GRID_REFERENCES",
    "KeyFrames",
    "KeyPositions",
    "handle_interpolation",
    "interpolation_through_points",
    "keyframe_interpolation",
    "keyframe_position_interpolation",
]
