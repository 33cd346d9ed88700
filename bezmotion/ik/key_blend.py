"""Joining an in-between to its key poses without a pop.

The pipeline outputs the given start and end poses at the window's first and last frames
(``keep_keyframes``), but the IK's pose one frame later is its own solution of nearly the
same targets, which may differ from the key's by tens of degrees at a joint (a learned
IK's elbow swivel, the rig's straight spine): the joint turns that far in one frame.
:func:`blend_to_keys` fades the key's correction out over the first (and in over the
last) ``frames`` frames instead: each joint's local rotation is pre-multiplied by a
slerped fraction of ``key ⊗ ik⁻¹`` at the key, and the hips' position is shifted by the
same fraction of the difference. The fraction falls from 1 at the key to 0 after
``frames`` frames along a half cosine, so the correction starts and ends with zero speed.
With ``frames`` ≤ the control stride (6), frames holding handles (multiples of the
stride) are untouched.

:func:`bezmotion.ik.protocol.solve_frames` applies it: after a per-frame IK, or, for an
IK that solves whole windows (:class:`~bezmotion.ik.exact.ExactIKFn`), to the poses it
starts from, so that its solve hits the targets (handles on any frame included) from
poses already joined to the keys.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion.data.windows import join_windows, split_windows
from bezmotion.geometry.rotations import quat_conjugate, quat_identity, quat_mul, slerp

if TYPE_CHECKING:  # protocol.solve_frames blends keys: no import cycle at run time
    from bezmotion.ik.protocol import Pose


def key_blend_weights(num_frames: int, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """``(from_start, from_end)``: each frame's share ``(num_frames,)`` of the start and end keys' corrections."""
    t = np.arange(num_frames, dtype=np.float64)
    fade = lambda d: np.where(d < frames, 0.5 * (1.0 + np.cos(np.pi * np.minimum(d, frames) / max(frames, 1))), 0.0)  # noqa: E731
    return fade(t), fade(num_frames - 1 - t)


def blend_to_keys(pose: Pose, start: Pose, end: Pose, frames: int) -> Pose:
    """``pose`` ``(frames, …)`` with the start and end keys at its ends, joined over ``frames`` frames.

    Args:
      pose: the IK's poses of the whole window, keys included.
      start, end: the key poses (unbatched) that replace the first and last frame.
      frames: how many frames the key's correction takes to fade out (0: the keys replace
        the first and last frame alone).
    Returns:
      The blended poses: exactly ``start`` and ``end`` at the first and last frame.
    """
    num = pose.root_pos.shape[0]
    if frames < 0 or not isinstance(frames, int):
        raise ValueError(f"key blend frames must be a non-negative int, got {frames!r}")
    if frames > 0:
        w_start, w_end = (jnp.asarray(w, pose.root_pos.dtype) for w in key_blend_weights(num, frames))
        identity = quat_identity(pose.quat_local.shape[1:-1], pose.quat_local.dtype)

        def fraction(key: Float[Array, "joints 4"], at: Float[Array, "joints 4"], w: Array) -> Array:
            correction = quat_mul(key, quat_conjugate(at))
            return slerp(identity[None], correction[None], w[:, None])  # (frames, joints, 4)

        quat = quat_mul(fraction(start.quat_local, pose.quat_local[0], w_start), pose.quat_local)
        quat = quat_mul(fraction(end.quat_local, pose.quat_local[-1], w_end), quat)
        root = (
            pose.root_pos
            + w_start[:, None] * (start.root_pos - pose.root_pos[0])
            + w_end[:, None] * (end.root_pos - pose.root_pos[-1])
        )
        pose = pose._replace(root_pos=root, quat_local=quat)
    return pose._replace(
        root_pos=pose.root_pos.at[0].set(start.root_pos).at[-1].set(end.root_pos),
        quat_local=pose.quat_local.at[0].set(start.quat_local).at[-1].set(end.quat_local),
    )


def key_chain(keys: tuple[Pose, Pose] | Pose) -> Pose:
    """Keys as one :class:`Pose` batched ``(keys, …)``: a ``(start, end)`` pair stacked, a
    chain's batched keys as they are."""
    if isinstance(keys, tuple) and not hasattr(keys, "_fields"):
        return jax.tree.map(lambda *k: jnp.stack(k), *keys)
    return keys


def key_distances(num_frames: int, num_windows: int) -> np.ndarray:
    """``(num_frames,)``: how many frames each frame lies from the nearest key of a chain of
    ``num_windows`` equal windows (0 at the keys).

    Raises:
      ValueError: ``num_frames`` is not a chain of ``num_windows`` equal windows.
    """
    window_frames = split_windows(jnp.zeros(num_frames), num_windows).shape[1]  # raises for a non-chain
    into = np.arange(num_frames) % (window_frames - 1)
    return np.minimum(into, window_frames - 1 - into)


def distances_to_keys(num_frames: int, keys: tuple[Pose, Pose] | Pose) -> np.ndarray:
    """:func:`key_distances` for the windows between ``keys`` (a ``(start, end)`` pair, or a
    chain's keys batched ``(K + 1, …)``)."""
    return key_distances(num_frames, key_chain(keys).root_pos.shape[0] - 1)


def blend_to_chain_keys(pose: Pose, keys: tuple[Pose, Pose] | Pose, frames: int) -> Pose:
    """:func:`blend_to_keys` for a chain: ``pose`` ``(K·(W − 1) + 1, …)``, every window of
    ``W`` frames joined to its two keys of ``keys`` (batched ``(K + 1, …)``, or a
    ``(start, end)`` pair for one window).

    Raises:
      ValueError: the frames are not ``len(keys) − 1`` equal windows.
    """
    chain = key_chain(keys)
    num_windows = chain.root_pos.shape[0] - 1
    windows = jax.tree.map(lambda a: split_windows(a, num_windows), pose)
    starts, ends = (jax.tree.map(lambda a, s=s: a[s], chain) for s in (slice(None, -1), slice(1, None)))
    blended = jax.vmap(lambda p, s, e: blend_to_keys(p, s, e, frames))(windows, starts, ends)
    return jax.tree.map(join_windows, blended)
