"""The bundled demo clip as IK-protocol poses (the ``clip`` fixture), the protocol's
functions jitted once, and NumPy references for poses; shared by ``tests/ik/test_protocol.py``
and the pipeline tests (``from ik.demo_poses import …``).

Real data: the bundled Bandai-Namco clip (:data:`bezmotion.assets.DEMO_CLIP`, 40 frames,
22 joints under a static ``joint_Root``).
"""

from __future__ import annotations

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import np_forward_kinematics, np_matrix_from_quat

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.ik.protocol import Character, Pose, pose_fk, pose_from_motion, targets_from_pose


# Eager JAX compiles every primitive anew for each new shape; one jit per shape is far cheaper.
fk = jax.jit(pose_fk)
targets_of = jax.jit(targets_from_pose)
motion_to_pose = jax.jit(pose_from_motion)


def np_rot6d(quat: np.ndarray) -> np.ndarray:
    """ortho6D from its definition: the rotation matrix's first two columns."""
    m = np_matrix_from_quat(quat)
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def frame(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


def ancestors(parents: tuple[int, ...], joint: int) -> list[int]:
    out, j = [], parents[joint]
    while j >= 0:
        out.append(j)
        j = parents[j]
    return out


def np_pose_positions(character: Character, pose: Pose) -> np.ndarray:
    """Global joint positions of a :class:`Pose` by a NumPy FK loop, from its definition:
    the hips at ``root_pos``, the joints above it at rest (identity), offsets elsewhere."""
    parents, hips = character.skeleton.parents, character.hips
    offsets = np.asarray(character.skeleton.offsets, np.float64)
    quat = np.asarray(pose.quat_local, np.float64)
    pos_local = np.broadcast_to(offsets, (*quat.shape[:-1], 3)).copy()
    above = ancestors(parents, hips)
    pos_local[..., hips, :] = np.asarray(pose.root_pos, np.float64) - offsets[above].sum(0)
    return np_forward_kinematics(parents, quat, pos_local)[1]


@pytest.fixture(scope="session")
def clip() -> SimpleNamespace:
    """The demo clip, its character, its 40 frames as poses and its NumPy FK (float64)."""
    motion = read_bvh(DEMO_CLIP)
    character = Character.from_bvh(motion, "bandai_namco")
    pose = motion_to_pose(character, jnp.asarray(motion.quat_local, jnp.float32), jnp.asarray(motion.pos_local, jnp.float32))
    quat_global, pos_global = np_forward_kinematics(motion.skeleton.parents, motion.quat_local, motion.pos_local)
    return SimpleNamespace(motion=motion, character=character, pose=pose, quat_global=quat_global, pos_global=pos_global)
