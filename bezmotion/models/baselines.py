"""Non-learned in-betweeners of the LaFAN1 benchmark: zero-velocity and interpolation.

Both take the last past key frame and the target key frame (local rotations and root
position) and return the ``n`` transition frames between them; leading axes batch.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

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
