"""Non-learned in-betweeners.

- The LaFAN1 benchmark's zero-velocity and interpolation baselines: both take the last
  past key frame and the target key frame (local rotations and root position) and
  return the ``n`` transition frames between them; leading axes batch.
- :func:`handle_interpolation`, BMM's reference: Bézier curves through the start, end
  and handle control points only.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from bezmotion.geometry.rotations import slerp


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
    inner = (pos[..., 2:, :, :] - pos[..., :-2, :, :]) / 6.0
    first = (pos[..., 1:2, :, :] - pos[..., :1, :, :]) / 3.0
    last = (pos[..., -1:, :, :] - pos[..., -2:-1, :, :]) / 3.0
    return pos, jnp.concatenate([first, inner, last], axis=-3)
