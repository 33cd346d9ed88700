"""The IK protocol's pose conversions (``bezmotion.ik.protocol``): poses from motions and from
global joints, targets from poses, and the character's checks. The reference values are plain
NumPy (``helpers``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import assert_same_rotation, np_forward_kinematics, random_quat_np
from ik.demo_poses import clip, fk, frame, motion_to_pose, np_pose_positions, np_rot6d, targets_of  # noqa: F401  (clip: a fixture)

from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.protocol import Character, pose_from_global

global_to_pose = jax.jit(pose_from_global)


def test_pose_from_motion_keeps_every_global_joint_of_the_clip(clip):
    c = clip.character
    assert (c.hips, c.ancestors_of_hips(), c.num_joints) == (1, (0,), 22)
    np.testing.assert_array_equal(c.rest_hips_parent_position(), np.zeros(3))
    assert c.end_sites and c.name == "bandai_namco"
    pose = clip.pose
    assert pose.root_pos.shape == (40, 3) and pose.quat_local.shape == (40, 22, 4)
    np.testing.assert_array_equal(pose.quat_local[:, 0], np.tile([1.0, 0.0, 0.0, 0.0], (40, 1)))
    quat, pos = fk(c, pose)
    np.testing.assert_allclose(pos, clip.pos_global, atol=1e-3)
    np.testing.assert_allclose(np_pose_positions(c, pose), clip.pos_global, atol=1e-3)
    assert_same_rotation(quat[:, 1:], clip.quat_global[:, 1:], atol=1e-5)


def synthetic_character(rng: np.random.Generator) -> Character:
    """Nine joints: root → spine → hips, the hips carrying head, hands and feet; the hips
    have two ancestors with non-zero rest offsets."""
    parents = (-1, 0, 1, 2, 3, 2, 2, 2, 2)
    names = ("root", "spine", "hips", "neck", "head", "hand_l", "hand_r", "foot_l", "foot_r")
    skeleton = Skeleton.from_parents(parents, names, rng.normal(scale=20.0, size=(9, 3)))
    return Character(skeleton, (2, 4, 5, 6, 7, 8), "synthetic")


def test_pose_from_motion_with_rotated_and_translated_ancestors(rng):
    c = synthetic_character(rng)
    offsets = np.asarray(c.skeleton.offsets, np.float64)
    assert c.ancestors_of_hips() == (1, 0)
    np.testing.assert_allclose(c.rest_hips_parent_position(), offsets[0] + offsets[1], atol=1e-5)
    quat = random_quat_np(rng, (5, 9))
    pos_local = np.broadcast_to(offsets, (5, 9, 3)).copy()
    pos_local[:, 0] += rng.normal(scale=50.0, size=(5, 3))  # the root moves, and so does the hips
    pos_local[:, 2] += rng.normal(scale=5.0, size=(5, 3))
    quat_true, pos_true = np_forward_kinematics(c.skeleton.parents, quat, pos_local)
    pose = motion_to_pose(c, jnp.asarray(quat, jnp.float32), jnp.asarray(pos_local, jnp.float32))
    np.testing.assert_array_equal(pose.quat_local[:, :2], np.tile([1.0, 0.0, 0.0, 0.0], (5, 2, 1)))
    np.testing.assert_allclose(pose.root_pos, pos_true[:, 2], atol=1e-3)
    rot, pos = fk(c, pose)
    np.testing.assert_allclose(pos[:, 2:], pos_true[:, 2:], atol=1e-3)
    assert_same_rotation(rot[:, 2:], quat_true[:, 2:], atol=1e-5)
    # The ancestors stand at rest, above the hips.
    np.testing.assert_allclose(pos[:, 1], np.broadcast_to(offsets[0] + offsets[1], (5, 3)), atol=1e-4)
    # From globals: the same pose back.
    back = global_to_pose(c, jnp.asarray(quat_true, jnp.float32), jnp.asarray(pos_true, jnp.float32))
    np.testing.assert_allclose(back.root_pos, pose.root_pos, atol=1e-3)
    assert_same_rotation(back.quat_local, pose.quat_local, atol=1e-5)


def test_pose_from_global_round_trip_on_the_clip(clip):
    c = clip.character
    quat, pos = fk(c, clip.pose)
    back = global_to_pose(c, quat, pos)
    np.testing.assert_allclose(back.root_pos, clip.pose.root_pos, atol=1e-4)
    assert_same_rotation(back.quat_local, clip.pose.quat_local, atol=1e-5)
    np.testing.assert_allclose(fk(c, back)[1], clip.pos_global, atol=1e-3)


def test_targets_from_pose_are_the_six_joints_global_positions_and_orientations(clip):
    c = clip.character
    targets = targets_of(c, clip.pose)
    assert targets.position.shape == (40, 6, 3) and targets.rot6d.shape == (40, 6, 6)
    idx = list(c.characteristic)
    assert [c.skeleton.names[i] for i in idx] == ["Hips", "Head", "Hand_L", "Hand_R", "Foot_L", "Foot_R"]
    np.testing.assert_allclose(targets.position, clip.pos_global[:, idx], atol=1e-3)
    np.testing.assert_allclose(targets.rot6d, np_rot6d(clip.quat_global[:, idx]), atol=1e-5)
    # Unbatched poses work the same.
    one = targets_of(c, frame(clip.pose, 9))
    np.testing.assert_allclose(one.position, targets.position[9], atol=1e-4)


def test_character_rejects_bad_joints_and_mappings(clip):
    skeleton = clip.character.skeleton
    with pytest.raises(ValueError, match=r"need 6 characteristic joints, got \(1, 5, 9\)"):
        Character(skeleton, (1, 5, 9))
    with pytest.raises(ValueError, match=r"indices \[22, -1\] out of range for 22 joints"):
        Character(skeleton, (1, 5, 22, 9, -1, 3))
    with pytest.raises(ValueError, match="unknown skeleton map 'smpl'"):
        Character.from_skeleton(skeleton, "smpl")
    with pytest.raises(ValueError, match="unknown skeleton map 'lafan'"):
        Character.from_bvh(clip.motion, "lafan")
    with pytest.raises(ValueError, match="LeftHand"):  # the LaFAN1 names are not this skeleton's
        Character.from_skeleton(skeleton, "lafan1")
    custom = dict(hips="Hips", head="Head", left_hand="Hand_L", right_hand="Hand_R", left_foot="Foot_L", right_foot="Foot_R")
    assert Character.from_skeleton(skeleton, custom).characteristic == clip.character.characteristic
    with pytest.raises(ValueError, match="Pelvis"):
        Character.from_skeleton(skeleton, {**custom, "hips": "Pelvis"})
