"""Window-level preprocessing shared by the corpora: sliding windows, XZ-centering,
facing normalisation at a key frame, and foot contacts.

All functions are pure and batch-polymorphic over leading ``*batch`` axes; positions
are in centimetres with +Y up.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Shaped

from bezmotion.geometry.rotations import quat_conjugate, quat_mul, quat_rotate


def sliding_window_starts(num_frames: int, window: int, offset: int) -> np.ndarray:
    """Start frames of the LaFAN1 sliding windows over a clip of ``num_frames`` frames.

    Windows start at 0, ``offset``, ``2·offset``, … while ``start + window < num_frames``
    — strictly: a window that would end exactly on the last frame is dropped, as the
    official LaFAN1 extractor does.
    """
    if window <= 0 or offset <= 0:
        raise ValueError(f"window and offset must be positive, got window={window}, offset={offset}")
    last = num_frames - window  # exclusive upper bound for the start
    return np.arange(0, max(last, 0), offset, dtype=np.int64)


def center_xz(root_pos: Float[Array, "*batch frames 3"]) -> Float[Array, "*batch frames 3"]:
    """Subtract the window-mean root X and Z (height untouched)."""
    mean = jnp.mean(root_pos, axis=-2, keepdims=True)
    return root_pos - mean * jnp.asarray([1.0, 0.0, 1.0], root_pos.dtype)


def facing_rotation(
    root_quat: Float[Array, "*batch 4"], forward_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
) -> Float[Array, "*batch 4"]:
    """The rotation about +Y that takes +X onto the root's horizontal facing direction.

    The facing direction is the root's local ``forward_axis`` (LaFAN1: +Y of the hips)
    rotated into the world, with its height component removed. The yaw is built
    directly from its angle θ = atan2(−f_z, f_x), which equals the shortest-arc rotation
    from +X onto the facing direction (w = cos θ/2 ≥ 0) and stays a pure yaw even when
    the facing direction is (nearly) −X, where a generic "rotation between two vectors"
    has to pick an arbitrary axis.
    """
    axis = jnp.asarray(forward_axis, root_quat.dtype)
    forward = quat_rotate(root_quat, jnp.broadcast_to(axis, root_quat.shape[:-1] + (3,)))
    fx, fz = forward[..., 0], forward[..., 2]
    # Double where: a facing direction straight up or down has no yaw; use 0, not NaN gradients.
    flat = (fx * fx + fz * fz) < 1e-24
    theta = jnp.where(flat, 0.0, jnp.arctan2(-jnp.where(flat, 0.0, fz), jnp.where(flat, 1.0, fx)))
    half = 0.5 * theta
    zero = jnp.zeros_like(half)
    return jnp.stack([jnp.cos(half), zero, jnp.sin(half), zero], axis=-1)


def face_forward_at_frame(
    quat_local: Float[Array, "*batch frames joints 4"],
    root_pos: Float[Array, "*batch frames 3"],
    frame: int,
    forward_axis: tuple[float, float, float] = (0.0, 1.0, 0.0),
) -> tuple[Float[Array, "*batch frames joints 4"], Float[Array, "*batch frames 3"]]:
    """Rotate a window about +Y so the root faces +X at ``frame`` (LaFAN1: frame 9).

    The LaFAN1 protocol applies ``yrot⁻¹`` to every global rotation and position and
    converts back to local. Left-multiplying all global rotations by one rotation leaves
    every non-root local rotation unchanged (``conj(y·g_p)·(y·g_c) = conj(g_p)·g_c``),
    so only the root's rotation and position change; computing it this way is exact
    and skips a full FK/IK round trip.
    """
    yrot_inv = quat_conjugate(facing_rotation(quat_local[..., frame, 0, :], forward_axis))
    root_quat = quat_mul(yrot_inv[..., None, :], quat_local[..., :, 0, :])
    quat_local = quat_local.at[..., :, 0, :].set(root_quat)
    root_pos = quat_rotate(yrot_inv[..., None, :], root_pos)
    return quat_local, root_pos


def foot_contacts(
    pos_global: Float[Array, "*batch frames joints 3"],
    joints: tuple[int, ...],
    threshold: float | Float[Array, ""] = 0.02,
) -> Bool[Array, "*batch frames contact_joints"]:
    """Contact labels: a joint is in contact when its squared per-frame displacement is
    below ``threshold`` (cm²). The last frame repeats the one before it (LaFAN1 rule).
    """
    idx = np.asarray(joints)
    p = pos_global[..., idx, :]
    step_sq = jnp.sum((p[..., 1:, :, :] - p[..., :-1, :, :]) ** 2, axis=-1)
    contact = step_sq < threshold
    return jnp.concatenate([contact, contact[..., -1:, :]], axis=-2)


def join_windows(x: Shaped[Array, "windows window_frames ..."]) -> Shaped[Array, "frames ..."]:
    """Per-window frames of a chain → the chain's frames, each shared key once (window
    ``i``'s last frame is window ``i + 1``'s first; the earlier window's is kept)."""
    return jnp.concatenate([x[:, :-1].reshape(-1, *x.shape[2:]), x[-1, -1:]])


def join_unequal_windows(parts: Sequence[Shaped[Array, "_ ..."]]) -> Shaped[Array, "frames ..."]:
    """:func:`join_windows` of windows of different lengths, given one by one: each shared
    key once (the earlier window's)."""
    return jnp.concatenate([parts[0], *(part[1:] for part in parts[1:])])


def split_windows(x: Float[Array, "frames ..."], windows: int) -> Float[Array, "windows window_frames ..."]:
    """A chain's frames → its windows' frames, the inverse of :func:`join_windows`: each
    shared key twice (window ``i``'s last frame and window ``i + 1``'s first).

    Args:
      x: ``(frames, …)`` with ``frames = windows·(window_frames − 1) + 1``.
      windows: how many windows the chain has (``≥ 1``).
    Raises:
      ValueError: ``windows < 1``, or ``frames`` not a chain of that many equal windows.
    """
    frames = x.shape[0]
    if windows < 1 or (frames - 1) % windows or frames < 2:
        raise ValueError(f"{frames} frames are not a chain of {windows} windows ((window frames − 1)·windows + 1)")
    length = (frames - 1) // windows + 1
    return x[np.arange(windows)[:, None] * (length - 1) + np.arange(length)]
