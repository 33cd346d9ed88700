"""BVH export of in-betweened poses (any channel layout)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data.bvh import BvhMotion
from bezmotion.ik.protocol import Character, Pose, pose_local


def default_channels(character: Character) -> tuple[tuple[str, ...], ...]:
    """BVH channels: 6 (position, ZYX rotation) on the hips and the joints above it, ZYX rotations elsewhere."""
    moving = {character.hips, *character.ancestors_of_hips()}
    rotation = ("Zrotation", "Yrotation", "Xrotation")
    position = ("Xposition", "Yposition", "Zposition")
    return tuple((position + rotation) if j in moving else rotation for j in range(character.num_joints))


def pose_to_bvh(
    character: Character,
    poses: Pose,
    *,
    fps: float = 30.0,
    channels: tuple[tuple[str, ...], ...] | None = None,
) -> BvhMotion:
    """A :class:`~bezmotion.data.bvh.BvhMotion` of ``poses`` ``(frames, …)`` for
    :func:`~bezmotion.data.bvh.write_bvh` (float64; channels default :func:`default_channels`)."""
    if poses.quat_local.ndim != 3 or poses.quat_local.shape[1:] != (character.num_joints, 4):
        raise ValueError(f"poses must be (frames, {character.num_joints}, 4) for {character.name}, got {poses.quat_local.shape}")
    if poses.root_pos.shape != (poses.quat_local.shape[0], 3):
        raise ValueError(f"poses.root_pos must be ({poses.quat_local.shape[0]}, 3), got {poses.root_pos.shape}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    channels = default_channels(character) if channels is None else tuple(tuple(c) for c in channels)
    if len(channels) != character.num_joints:
        raise ValueError(f"need channels for {character.num_joints} joints, got {len(channels)}")
    with jax.enable_x64(True):
        quat, pos = pose_local(character, Pose(jnp.asarray(poses.root_pos, jnp.float64), jnp.asarray(poses.quat_local, jnp.float64)))
        quat, pos = np.asarray(quat), np.asarray(pos)
    return BvhMotion(character.skeleton, quat, pos, channels, 1.0 / fps, character.end_sites)
