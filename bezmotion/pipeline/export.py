"""BVH export of in-betweened poses (any channel layout, on the user's own skeleton)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data.bvh import POSITION_CHANNELS, BvhMotion
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
    template: BvhMotion | None = None,
) -> BvhMotion:
    """A :class:`~bezmotion.data.bvh.BvhMotion` of ``poses`` ``(frames, …)`` for
    :func:`~bezmotion.data.bvh.write_bvh` (float64).

    Args:
      character: the character ``poses`` belong to (e.g. the IK model's).
      poses: ``(frames, …)`` poses.
      fps: frames per second; its frame time is written exactly.
      channels: per-joint channel names; default :func:`default_channels` (positions on the
        hips and the joints above it only). The hips need position channels: they carry
        the pose's root motion.
      template: a motion (e.g. the user's clip, from :func:`~bezmotion.data.bvh.read_bvh`)
        whose OFFSETs and End Sites the file carries instead of ``character``'s, so that it
        rigs like the clip; same joints in the same order. Rotations and the hips' global
        position are copied, so joints without position channels move with the template's
        bone lengths (equal to ``character``'s for a character read from the same corpus).
    """
    if poses.quat_local.ndim != 3 or poses.quat_local.shape[1:] != (character.num_joints, 4):
        raise ValueError(f"poses must be (frames, {character.num_joints}, 4) for {character.name}, got {poses.quat_local.shape}")
    if poses.root_pos.shape != (poses.quat_local.shape[0], 3):
        raise ValueError(f"poses.root_pos must be ({poses.quat_local.shape[0]}, 3), got {poses.root_pos.shape}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if template is not None:
        names, parents = template.skeleton.names, template.skeleton.parents
        if names != character.skeleton.names or parents != character.skeleton.parents:
            raise ValueError(
                f"template joints {list(names)} (parents {list(parents)}) differ from {character.name}'s "
                f"{list(character.skeleton.names)} (parents {list(character.skeleton.parents)})"
            )
        character = dataclasses.replace(character, skeleton=template.skeleton, end_sites=tuple(template.end_sites))
    channels = default_channels(character) if channels is None else tuple(tuple(c) for c in channels)
    if len(channels) != character.num_joints:
        raise ValueError(f"need channels for {character.num_joints} joints, got {len(channels)}")
    if not set(POSITION_CHANNELS) <= set(channels[character.hips]):
        hips = character.skeleton.names[character.hips]
        raise ValueError(f"the hips ({hips!r}) need position channels (they carry the root motion), got {list(channels[character.hips])}")
    with jax.enable_x64(True):
        quat, pos = pose_local(character, Pose(jnp.asarray(poses.root_pos, jnp.float64), jnp.asarray(poses.quat_local, jnp.float64)))
        quat, pos = np.asarray(quat), np.asarray(pos)
    return BvhMotion(character.skeleton, quat, pos, channels, 1.0 / fps, character.end_sites)
