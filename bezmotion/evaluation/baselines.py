"""Non-learned in-betweeners: every baseline the learned models are compared with, and
the residual bases the Δ-interpolator predicts over.

- **Transition baselines** of the LaFAN1 benchmark: :func:`zero_velocity` and
  :func:`interpolation` take the last past key frame and the target key frame (local
  rotations and root position) and return the ``n`` transition frames between them;
  leading axes batch. :func:`zero_velocity_inbetweener` and
  :func:`interpolation_inbetweener` wrap them in the benchmark's in-betweener signature
  ``(past_quat (B, past, J, 4), past_root (B, past, 3), target_quat (B, J, 4),
  target_root (B, 3), n) -> (quat (B, n, J, 4), root (B, n, 3))`` (see
  :mod:`bezmotion.evaluation.lafan1`).
- **Key-frame baselines** for any layout of known frames (one example; ``jax.vmap`` over
  a batch): :func:`keyframe_interpolation` (lerp the root, slerp local rotations),
  :func:`keyframe_position_interpolation` and :func:`keyframe_position_zero_velocity`
  (global point positions). The known frames (:class:`KeyFrames`,
  :class:`KeyPositions`, also the Δ-interpolator's input) carry their frame indices and
  a validity mask, so padded fixed-size layouts work. With 10 past frames and one target,
  :func:`keyframe_interpolation` is the benchmark's :func:`interpolation`.
  :func:`zero_velocity_position_inbetweener` and :func:`interpolation_position_inbetweener`
  wrap the position ones in the Anidance benchmark's in-betweener signature (see
  :mod:`bezmotion.evaluation.anidance`).
- :func:`handle_interpolation`, BMM's reference, and the key-frame interpolations are the
  models' own (:mod:`bezmotion.interpolation`), re-exported here beside the baselines.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from bezmotion.geometry.rotations import slerp
from bezmotion.interpolation import (
    OFF_GRID_REFERENCES,
    KeyFrames,
    KeyPositions,
    _bracketing_keys,
    handle_interpolation,
    interpolation_through_points,
    keyframe_interpolation,
    keyframe_position_interpolation,
)

# ------------------------------------------------------------------ transition baselines


def transition_weights(n: int, dtype=jnp.float32) -> Float[Array, "n"]:
    """Interpolation weights ``k / (n + 1)`` for the transition frames ``k = 1 … n``."""
    if not (isinstance(n, int) and n >= 1):
        raise ValueError(f"the transition length must be a positive integer, got {n!r}")
    return jnp.arange(1, n + 1, dtype=dtype) / (n + 1)


def zero_velocity(
    quat_last: Float[Array, "*batch joints 4"], root_last: Float[Array, "*batch 3"], n: int
) -> tuple[Float[Array, "*batch n joints 4"], Float[Array, "*batch n 3"]]:
    """Every transition frame copies the last past frame (local rotations and root)."""
    transition_weights(n)  # validates n
    quat = jnp.broadcast_to(quat_last[..., None, :, :], (*quat_last.shape[:-2], n, *quat_last.shape[-2:]))
    root = jnp.broadcast_to(root_last[..., None, :], (*root_last.shape[:-1], n, 3))
    return quat, root


def interpolation(
    quat_last: Float[Array, "*batch joints 4"],
    root_last: Float[Array, "*batch 3"],
    quat_target: Float[Array, "*batch joints 4"],
    root_target: Float[Array, "*batch 3"],
    n: int,
) -> tuple[Float[Array, "*batch n joints 4"], Float[Array, "*batch n 3"]]:
    """Root position lerped, every local rotation slerped (shortest path), weights k/(n+1)."""
    w = transition_weights(n, quat_last.dtype)
    root = root_last[..., None, :] + w[:, None] * (root_target - root_last)[..., None, :]
    quat = slerp(quat_last[..., None, :, :], quat_target[..., None, :, :], w[:, None])
    return quat, root


def zero_velocity_inbetweener(past_quat, past_root, target_quat, target_root, n: int):
    """:func:`zero_velocity` as a transition in-betweener (copies the last past frame)."""
    return zero_velocity(past_quat[:, -1], past_root[:, -1], n)


def interpolation_inbetweener(past_quat, past_root, target_quat, target_root, n: int):
    """:func:`interpolation` as a transition in-betweener (lerp root, slerp local rotations
    from the last past frame to the target)."""
    return interpolation(past_quat[:, -1], past_root[:, -1], target_quat, target_root, n)


# ------------------------------------------------------------------- key-frame baselines


def keyframe_position_zero_velocity(keys: KeyPositions, missing_frame: Int[Array, "missing"]) -> Float[Array, "missing points 3"]:
    """Every missing frame copies the nearest valid key frame before it (the zero-velocity
    baseline; with one past frame and one target, the past frame). One example."""
    prev, _, _ = _bracketing_keys(keys.frame, keys.valid, missing_frame, keys.pos.dtype)
    return keys.pos[prev]


PositionInBetweener = Callable[[Array, tuple[int, ...], tuple[int, ...]], Array]
"""``inbetween(key_pos (B, K, P, 3), key_frame (K ints), missing_frame (M ints)) -> (B, M, P, 3)``."""


def _position_inbetweener(baseline) -> PositionInBetweener:
    """A one-example key-frame position baseline as a batched in-betweener of static layout."""

    def inbetween(
        key_pos: Float[Array, "batch keys points 3"], key_frame: tuple[int, ...], missing_frame: tuple[int, ...]
    ) -> Float[Array, "batch missing points 3"]:
        frame = jnp.asarray(key_frame, jnp.int32)
        valid = jnp.ones(frame.shape, bool)
        missing = jnp.asarray(missing_frame, jnp.int32)
        return jax.vmap(lambda pos: baseline(KeyPositions(pos, frame, valid), missing))(key_pos)

    return inbetween


#: Each missing frame copies the nearest key frame before it (:func:`keyframe_position_zero_velocity`).
zero_velocity_position_inbetweener = _position_inbetweener(keyframe_position_zero_velocity)
#: Each missing frame is lerped between the key frames around it (:func:`keyframe_position_interpolation`).
interpolation_position_inbetweener = _position_inbetweener(keyframe_position_interpolation)


__all__ = [
    "OFF_GRID_REFERENCES",
    "KeyFrames",
    "KeyPositions",
    "PositionInBetweener",
    "handle_interpolation",
    "interpolation",
    "interpolation_through_points",
    "interpolation_inbetweener",
    "interpolation_position_inbetweener",
    "keyframe_interpolation",
    "keyframe_position_interpolation",
    "keyframe_position_zero_velocity",
    "transition_weights",
    "zero_velocity",
    "zero_velocity_inbetweener",
    "zero_velocity_position_inbetweener",
]
