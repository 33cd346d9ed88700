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

from bezmotion.geometry.rotations import quat_angle, quat_from_axis_angle, quat_identity
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.protocol import Character, IKTargets, Pose, pose_from_global, solve_frames
from bezmotion.ik.temporal import FLIP_TURN, KEY_TURN

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


def _twisting_ik(params, targets):
    """A toy per-frame IK: joint 1 of 3 twisted about X by the hips target's X (rad), the rest identity."""
    twist = quat_from_axis_angle(jnp.asarray([1.0, 0.0, 0.0]), targets.position[0, 0])
    return Pose(targets.position[0], quat_identity((3,)).at[1].set(twist))


def _joint1_turns(pose: Pose) -> np.ndarray:
    """Joint 1's turn (rad) from each frame to the next."""
    return np.asarray(quat_angle(pose.quat_local[1:, 1], pose.quat_local[:-1, 1]))


def test_solve_frames_takes_a_per_frame_iks_flips_out():
    """A per-frame IK that twists joint 1 by 149° for one frame (5) and for good from frame 12
    on: ``solve_frames`` replaces the one-frame flip by its neighbours and ramps into the
    lasting one at most :data:`FLIP_TURN` a frame, keeping the window's ends (the keys' frames)
    bit for bit; ``flip_turn=0`` returns the IK's poses as they are."""
    angle = np.linspace(0.0, 0.5, 20)
    angle[5] += 2.6
    angle[12:] += 2.6

    position = np.zeros((20, 6, 3), np.float32)
    position[:, 0, 0] = angle
    targets = IKTargets(jnp.asarray(position), jnp.zeros((20, 6, 6)))
    solve = jax.jit(solve_frames, static_argnums=0, static_argnames="flip_turn")
    raw, clean = solve(_twisting_ik, None, targets, flip_turn=0.0), solve(_twisting_ik, None, targets)

    assert _joint1_turns(raw).max() > 2.5
    assert _joint1_turns(clean).max() <= FLIP_TURN + 1e-5
    assert _joint1_turns(clean)[3:6].max() < 0.1  # frame 5 between its neighbours
    for kept in (0, 19):
        np.testing.assert_array_equal(np.asarray(clean.quat_local[kept]), np.asarray(raw.quat_local[kept]))
    np.testing.assert_array_equal(np.asarray(clean.root_pos), np.asarray(raw.root_pos))


def test_solve_frames_turns_slowly_out_of_the_keys():
    """A per-frame IK that poses joint 1 as the keys do on the keys' frames, twisted by 80° on the
    frames next to them and by 138° on all others (not a one-frame flip: the two frames after
    a key disagree): its flips taken out, it still turns :data:`FLIP_TURN` on the steps next
    to the keys with ``key_turn=0``; joined to the keys it turns no more than
    :data:`KEY_TURN` there (the mocap's largest there: 29° Bandai-Namco, 36° LaFAN1), easing to
    :data:`FLIP_TURN` over the key blend's frames, and the middle of the window is the same."""
    frames, blend = 31, 6

    position = np.full((frames, 6, 3), 2.4, np.float32)
    position[[1, -2]], position[[0, -1]] = 1.4, 0.0
    targets = IKTargets(jnp.asarray(position), jnp.zeros((frames, 6, 6)))
    key = Pose(jnp.zeros(3), quat_identity((3,)))  # the IK's own pose on the keys' frames
    solve = jax.jit(solve_frames, static_argnums=0, static_argnames=("key_blend_frames", "key_turn"))
    joined = solve(_twisting_ik, None, targets, keys=(key, key), key_blend_frames=blend)
    plain = solve(_twisting_ik, None, targets, keys=(key, key), key_blend_frames=blend, key_turn=0.0)

    np.testing.assert_allclose(_joint1_turns(plain)[[0, -1]], FLIP_TURN, atol=1e-5)
    assert _joint1_turns(joined)[[0, -1]].max() <= KEY_TURN + 1e-5
    assert _joint1_turns(joined).max() <= FLIP_TURN + 1e-5
    for kept in (0, frames - 1):
        np.testing.assert_array_equal(np.asarray(joined.quat_local[kept]), np.asarray(key.quat_local))
    np.testing.assert_array_equal(np.asarray(joined.quat_local[15]), np.asarray(plain.quat_local[15]))
