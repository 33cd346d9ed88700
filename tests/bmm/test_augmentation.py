"""Augmentation of curve windows (``bezmotion.bmm.augmentation``) and the training levers
of ``BMMTrainConfig`` (learning-rate schedule, yaw and mirror augmentation), on the
bundled Bandai-Namco clip's real windows."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bmm.common import TINY

from bezmotion.assets import DEMO_CLIP
from bezmotion.bmm.augmentation import augment, hold_still, mirror, rest_reflections, rotate_yaw
from bezmotion.bmm.train import BMMTrainConfig, CurveArrays, init_bmm_train_state, make_bmm_train_step
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import SKELETON_MAPS
from bezmotion.geometry.rotations import matrix_from_quat, matrix_from_rot6d
from bezmotion.geometry.skeleton import forward_kinematics
from bezmotion.training import compile_train_step


def example_of(dataset, i: int = 3):
    arrays = CurveArrays.from_dataset(dataset)
    return tuple(jnp.asarray(a[i]) for a in arrays)


BN_REFLECTIONS = ((1.0, -1.0, 1.0), (1.0, 1.0, -1.0), (-1.0, 1.0, 1.0), (-1.0, 1.0, 1.0), (-1.0, 1.0, 1.0), (-1.0, 1.0, 1.0))


def test_rest_reflections_of_the_bandai_namco_skeleton():
    """Its hips' legs differ in Y, its chest's shoulders in Z (the head's), hands and feet in X."""
    skeleton = read_bvh(DEMO_CLIP).skeleton
    names = dict(SKELETON_MAPS["bandai_namco"])
    assert rest_reflections(skeleton, names) == BN_REFLECTIONS
    with pytest.raises(ValueError, match="mirror images"):
        rest_reflections(skeleton, {**names, "left_foot": names["left_hand"]})
    with pytest.raises(ValueError, match="unknown joint"):
        rest_reflections(skeleton, {**names, "head": "nope"})


def test_yaw_turn_keeps_shapes_heights_distances_and_orientation_consistency(demo_dataset):
    ex = example_of(demo_dataset)
    turned = rotate_yaw(ex, jnp.float32(1.1))
    pos, tangent, rot6d, contacts, dense = turned
    np.testing.assert_allclose(pos[..., 1], ex[0][..., 1], atol=1e-4)  # heights
    np.testing.assert_allclose(np.linalg.norm(dense - dense[:, :1], axis=-1), np.linalg.norm(ex[4] - ex[4][:, :1], axis=-1), atol=1e-3)
    np.testing.assert_array_equal(contacts, ex[3])
    # Every joint's local axes turn with the body: R' R^T is the same yaw for all.
    rel = matrix_from_rot6d(rot6d) @ jnp.swapaxes(matrix_from_rot6d(ex[2]), -1, -2)
    np.testing.assert_allclose(rel, np.broadcast_to(rel[0, 0], rel.shape), atol=1e-5)
    back = rotate_yaw(turned, jnp.float32(-1.1))
    for a, b in zip(back, ex):
        np.testing.assert_allclose(a, b, atol=1e-4)


def test_mirror_twice_is_the_identity_and_swaps_sides(demo_dataset):
    ex = example_of(demo_dataset)
    once = mirror(ex, BN_REFLECTIONS)
    np.testing.assert_allclose(once[0][:, 2, 0], -ex[0][:, 3, 0], atol=1e-6)  # left hand ← mirrored right hand
    np.testing.assert_array_equal(once[3], ex[3][:, ::-1])
    for a, b in zip(mirror(once, BN_REFLECTIONS), ex):
        np.testing.assert_allclose(a, b, atol=1e-5)


def test_mirrored_orientations_carry_the_mirrored_bones():
    """On the real clip: a mirrored orientation, applied to the rest offset of a left bone,
    gives the world mirror image of the matching right bone — the right foot's orientation
    becomes the left foot's (toe bone), and the hips' own turns it onto the other leg."""
    motion = read_bvh(DEMO_CLIP)
    skeleton = motion.skeleton
    names = SKELETON_MAPS["bandai_namco"]
    quat, _ = forward_kinematics(skeleton.parents, jnp.asarray(motion.quat_local), jnp.asarray(motion.pos_local))
    n = quat.shape[0]
    world_mirror = jnp.asarray([-1.0, 1.0, 1.0])
    # (slot of the oriented joint in the six, joint whose orientation is mirrored, slot it lands in, right child, left child)
    cases = (
        (5, "Foot_R", 4, "Toes_R", "Toes_L"),  # right foot → left foot
        (0, "Hips", 0, "UpperLeg_R", "UpperLeg_L"),  # the hips onto themselves
    )
    for slot, joint, mirrored_slot, right_child, left_child in cases:
        matrix = matrix_from_quat(quat[:, skeleton.index(joint)])
        rot6d = jnp.zeros((n, 6, 6)).at[:, slot].set(jnp.concatenate([matrix[..., :, 0], matrix[..., :, 1]], -1))
        zeros = jnp.zeros((n, 6, 3))
        mirrored = mirror((zeros, zeros, rot6d, jnp.zeros((n, 2), bool), zeros), BN_REFLECTIONS)
        bone = matrix_from_rot6d(mirrored[2][:, mirrored_slot]) @ jnp.asarray(motion.pos_local[:, skeleton.index(left_child), :, None])
        expected = (matrix @ jnp.asarray(motion.pos_local[:, skeleton.index(right_child), :, None]))[..., 0] * world_mirror
        assert float(jnp.min(jnp.linalg.norm(expected, axis=-1))) > 1.0  # a real bone, not a zero offset
        np.testing.assert_allclose(bone[..., 0], expected, atol=1e-3)


def test_augment_off_is_the_identity_and_on_is_random(demo_dataset):
    ex = example_of(demo_dataset)
    same = augment(jax.random.key(0), ex, yaw=False, mirror_probability=0.0, reflections=BN_REFLECTIONS)
    for a, b in zip(same, ex):
        np.testing.assert_array_equal(a, b)
    outs = [augment(jax.random.key(k), ex, yaw=True, mirror_probability=0.5, reflections=BN_REFLECTIONS) for k in range(8)]
    assert len({round(float(o[0][-1, 0, 0]), 3) for o in outs}) == 8


def test_lever_validation_and_the_cosine_schedule():
    for bad in (
        {"mirror_augmentation": 1.5}, {"lr_schedule": "step"}, {"lr_schedule": "cosine"},
        {"lr_schedule": "cosine", "total_steps": 10, "warmup_steps": 10}, {"rest_reflections": ((1.0, 1.0, 1.0),) * 6}, {"mirror_augmentation": 0.5},
        {"final_lr_fraction": -0.1},
    ):  # fmt: skip
        with pytest.raises(ValueError):
            BMMTrainConfig(**bad)
    assert BMMTrainConfig().learning_rate_schedule() == 1e-4  # the paper's constant rate
    schedule = BMMTrainConfig(learning_rate=1e-3, lr_schedule="cosine", warmup_steps=10, total_steps=110).learning_rate_schedule()
    np.testing.assert_allclose([schedule(0), schedule(5), schedule(10), schedule(60), schedule(110)], [0.0, 5e-4, 1e-3, 5.5e-4, 1e-4], rtol=1e-5)


def test_levers_off_keep_the_paper_step_and_on_train(demo_dataset, stats):
    """The default config's step is unchanged by the levers' existence (same stream); with all
    levers on, the step still runs, stays finite and differs."""
    data = CurveArrays.from_dataset(demo_dataset)
    base = BMMTrainConfig(batch_size=4, learning_rate=1e-3)
    on = dataclasses.replace(
        base, lr_schedule="cosine", warmup_steps=2, total_steps=10, yaw_augmentation=True, mirror_augmentation=0.5,
        rest_reflections=BN_REFLECTIONS,
    )
    results = {}
    for name, cfg in (("base", base), ("on", on)):
        graphdef, state = init_bmm_train_state(TINY, cfg, key=jax.random.key(0))
        step = compile_train_step(make_bmm_train_step(graphdef, TINY, cfg, stats), num_seeds=None)
        for _ in range(3):
            state, metrics = step(state, data)
        assert all(np.isfinite(float(v)) for v in metrics.values())
        results[name] = float(metrics["loss"])
    assert results["base"] != results["on"]


def test_a_held_pose_is_still_aligned_and_planted(demo_dataset):
    ex = example_of(demo_dataset)
    pos, tangent, rot6d, contacts, dense = hold_still(ex, jnp.asarray(3))
    want = np.asarray(ex[0][3]) - np.asarray(ex[0][3, 0]) * np.array([1.0, 0.0, 1.0])  # the hips start at the origin in XZ
    np.testing.assert_allclose(pos, np.broadcast_to(want, pos.shape), atol=1e-5)
    np.testing.assert_allclose(dense, np.broadcast_to(want, dense.shape), atol=1e-5)
    np.testing.assert_array_equal(tangent, 0.0)
    np.testing.assert_allclose(rot6d, np.broadcast_to(np.asarray(ex[2][3]), rot6d.shape))
    assert np.asarray(contacts).all()
    held = augment(jax.random.key(1), ex, yaw=False, mirror_probability=0.0, reflections=None, still_probability=1.0)
    assert np.ptp(np.asarray(held[0]), axis=0).max() == 0.0  # every example held still
    kept = augment(jax.random.key(1), ex, yaw=False, mirror_probability=0.0, reflections=None, still_probability=0.0)
    for a, b in zip(kept, ex):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="still_augmentation must be a probability in"):
        BMMTrainConfig(still_augmentation=1.5)
