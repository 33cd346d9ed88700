"""Character transfer (``bezmotion.pipeline.transfer``): profiles, the transfer between them,
and the in-betweening with a transfer.
"""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import (
    assert_same_rotation,
    assert_trees_close,
    np_quat_from_axis_angle,
    np_quat_mul,
    np_quat_rotate,
    random_quat_np,
)
from ik.demo_poses import fk, np_rot6d, targets_of
from pipeline.common import K, LEFT_HAND, STEPS

from bezmotion.bmm.sampling import SampledCurves
from bezmotion.data.characteristic import HIPS
from bezmotion.ik.protocol import Pose
from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.evaluation import skeleton_zoo as zoo
from bezmotion.pipeline import (
    CharacterProfile,
    InbetweenOptions,
    Transfer,
    curves_to_target,
    facing_yaw,
    inbetween,
    mean_rotation,
    orientations_to_source_space,
    placement,
    to_source_space,
)
from bezmotion.pipeline.authoring import load_profile, motion_poses, recognise_character

SCALED = 1.37  # a transfer scale whose round trip is not exact in float32
source_space = jax.jit(to_source_space)
to_target = jax.jit(curves_to_target)
yaw_of = jax.jit(facing_yaw)
mean_of = jax.jit(mean_rotation)


def yawed(pose: Pose, angle: float) -> tuple[Pose, np.ndarray]:
    """``pose`` (hips-rooted: ancestors at identity, at the origin) turned by ``angle`` about +Y."""
    q = np_quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.asarray(angle))
    quat = np.asarray(pose.quat_local, np.float64).copy()
    quat[..., 1, :] = np_quat_mul(q, quat[..., 1, :])  # joint 1 is Bandai-Namco's Hips
    root = np_quat_rotate(q, np.asarray(pose.root_pos, np.float64))
    return Pose(jnp.asarray(root, jnp.float32), jnp.asarray(quat, jnp.float32)), q


def again(bmm, run, **kwargs):
    """``run``'s in-betweening with some arguments replaced (same shapes and settings as the
    conftest's, ``key_blend_frames=0`` included: no recompilation, comparable frames)."""
    args = dict(handles=run.handles, transfer=None, key=run.key)
    args.update(kwargs)
    model = dataclasses.replace(run.model, bmm=bmm, transfer=args["transfer"])
    return inbetween(model, run.keys, args["handles"], key=args["key"], options=InbetweenOptions(steps=STEPS, key_blend_frames=0))


@pytest.fixture(scope="module")
def profile(clip) -> CharacterProfile:
    return CharacterProfile.from_poses(clip.character, clip.pose)


def test_transfer_between_a_profile_and_itself_is_no_transfer(bmm, run, profile):
    t = Transfer.between(profile, profile, facing=False)  # with the facing, a turn alone (test_a_placement_…)
    assert float(t.scale) == 1.0 and t.scale.dtype == jnp.float32 and t.rot_offset.dtype == jnp.float32
    np.testing.assert_allclose(t.rot_offset, Transfer.identity().rot_offset, atol=1e-6)
    same = again(bmm, run, transfer=t)
    assert_trees_close(same.curves, run.result.curves, tol=1e-4)
    assert_trees_close(same.pose, run.result.pose, tol=1e-4)


def test_to_source_space_and_curves_to_target_are_inverses(rng):
    offset = random_quat_np(rng, (6,))
    t = Transfer(jnp.asarray(SCALED, jnp.float32), jnp.asarray(offset, jnp.float32))
    anchor = jnp.asarray([30.0, 0.0, -40.0])
    pos = jnp.asarray(rng.normal(scale=50.0, size=(K, 6, 3)), jnp.float32)
    source = source_space(t, anchor, pos)
    np.testing.assert_allclose(source, anchor + (np.asarray(pos) - anchor) / SCALED, rtol=1e-6, atol=1e-4)
    tangent = jnp.asarray(rng.normal(size=(K, 6, 3)), jnp.float32)
    quat = random_quat_np(rng, (K, 6))
    curves = SampledCurves(source, tangent, jnp.asarray(np_rot6d(quat), jnp.float32), jnp.zeros((K, 2)))
    target = to_target(t, anchor, curves)
    np.testing.assert_allclose(target.ctrl_pos, pos, atol=1e-4)
    np.testing.assert_allclose(target.ctrl_tangent, SCALED * np.asarray(tangent), rtol=1e-6)
    np.testing.assert_allclose(target.ctrl_rot6d, np_rot6d(np_quat_mul(quat, offset)), atol=1e-5)
    # Identity: nothing moves.
    same = to_target(Transfer.identity(), anchor, curves)
    np.testing.assert_allclose(same.ctrl_pos, source, atol=1e-5)
    np.testing.assert_allclose(same.ctrl_rot6d, curves.ctrl_rot6d, atol=1e-6)


def test_transfer_between_profiles_aligns_heights_and_orientations(rng):
    src = CharacterProfile(80.0, random_quat_np(rng, (6,)))
    tgt = CharacterProfile(100.0, random_quat_np(rng, (6,)))
    t = Transfer.between(src, tgt)
    assert float(t.scale) == pytest.approx(1.25)
    assert_same_rotation(np_quat_mul(src.mean_orientation, np.asarray(t.rot_offset)), tgt.mean_orientation, atol=1e-5)


def test_a_scaled_transfer_keeps_handles_and_keyframes_exact(bmm, run):
    """Also when a padding slot sits on a handle's control point (the ``run`` handles' third slot)."""
    t = Transfer(jnp.asarray(SCALED, jnp.float32), Transfer.identity().rot_offset)
    r = again(bmm, run, transfer=t)
    ctrl = np.asarray(r.joined_curves().ctrl_pos)
    np.testing.assert_array_equal(ctrl[2, HIPS], np.asarray(run.handles.position[0]))
    np.testing.assert_array_equal(ctrl[3, LEFT_HAND], np.asarray(run.handles.position[1]))
    np.testing.assert_array_equal(ctrl[[0, -1]], np.asarray(run.result.joined_curves().ctrl_pos)[[0, -1]])
    free = np.ones(K, bool)
    free[[0, -1]] = False
    assert np.abs(ctrl[free] - np.asarray(run.result.joined_curves().ctrl_pos)[free]).max() > 1.0  # the scale does act


def test_character_profile_is_invariant_to_the_facing(clip, profile):
    assert profile.mean_orientation.shape == (6, 4) and profile.mean_orientation.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(profile.mean_orientation, axis=-1), 1.0, atol=1e-6)
    assert 60.0 < profile.height < 100.0  # hips above the ankles of a standing adult, cm
    turned, q = yawed(clip.pose, 2.1)
    np.testing.assert_allclose(fk(clip.character, turned)[1][..., 1], clip.pos_global[..., 1], atol=1e-3)
    other = CharacterProfile.from_poses(clip.character, turned)
    assert other.height == pytest.approx(profile.height, abs=1e-3)
    assert_same_rotation(other.mean_orientation, profile.mean_orientation, atol=1e-4)
    # The facing turns with the character.
    yaw = yaw_of(targets_of(clip.character, clip.pose).position)
    yaw_turned = yaw_of(targets_of(clip.character, turned).position)
    assert_same_rotation(yaw_turned, np_quat_mul(q, np.asarray(yaw)), atol=1e-5)


def test_facing_yaw_by_hand():
    pos = np.zeros((2, 6, 3), np.float32)
    pos[0, [2, 4], 0], pos[0, [3, 5], 0] = 10.0, -10.0  # left is +X: facing +Z, no turn
    pos[1, [2, 4], 2], pos[1, [3, 5], 2] = -10.0, 10.0  # left is -Z: facing +X, a quarter turn
    pos[:, :, 1] = np.arange(6.0)  # heights play no part
    s = np.sqrt(0.5)
    np.testing.assert_allclose(yaw_of(jnp.asarray(pos)), [[1.0, 0.0, 0.0, 0.0], [s, 0.0, s, 0.0]], atol=1e-6)


def test_mean_rotation_of_symmetric_rotations_is_their_centre(rng):
    centre = random_quat_np(rng)
    axes = rng.normal(size=(3, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    spread = np_quat_from_axis_angle(np.concatenate([axes, axes]), np.array([0.4, 0.7, 0.2, -0.4, -0.7, -0.2]))
    samples = np_quat_mul(centre, spread) * np.array([1, -1, 1, 1, -1, 1])[:, None]  # signs do not matter
    assert_same_rotation(mean_of(jnp.asarray(samples, jnp.float32)), centre, atol=1e-5)


def test_character_profile_load_round_trip_and_malformed_files(tmp_path, profile):
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"corpus": "bandai_namco", **profile.to_json()}))
    loaded = CharacterProfile.load(good)
    assert loaded.height == profile.height
    np.testing.assert_array_equal(loaded.mean_orientation, profile.mean_orientation)
    cases = {
        "truncated": good.read_text()[:-7],
        "no_height": json.dumps({"mean_orientation": profile.to_json()["mean_orientation"]}),
        "a_list": json.dumps([1, 2, 3]),
        "wrong_shape": json.dumps({**profile.to_json(), "mean_orientation": [[1.0, 0.0, 0.0, 0.0]] * 5}),
        "ragged": json.dumps({**profile.to_json(), "mean_orientation": [[1.0, 0.0], [1.0]]}),
        "zero_height": json.dumps({**profile.to_json(), "height": 0.0}),
        "text_height": json.dumps({**profile.to_json(), "height": "tall"}),
    }
    for name, text in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(text)
        with pytest.raises(ValueError, match=rf"{name}\.json: not a character profile"):
            CharacterProfile.load(path)


def test_transfer_curve_dataset_moves_real_windows_into_the_target_space():
    """The bundled clip's windows as LaFAN1's character: scaled about the floor below the
    start hips, orientations offset per joint, the curves still through their own dense
    trajectories at the control frames; the identity transfer changes nothing."""
    from bezmotion.assets import DEMO_CLIP, PROFILES_DIR
    from bezmotion.bezier import BezierLayout, evaluate
    from bezmotion.data.bvh import read_bvh
    from bezmotion.data.corpus import MotionClips
    from bezmotion.data.curves import build_curve_dataset
    from bezmotion.geometry.rotations import quat_from_rot6d
    from bezmotion.pipeline import transfer_curve_dataset

    dataset = build_curve_dataset(MotionClips.from_bvh([read_bvh(DEMO_CLIP)]), "bandai_namco", window=31, offset=3, progress=False)
    same = transfer_curve_dataset(dataset, Transfer.identity())
    for name in ("ctrl_pos", "ctrl_tangent", "dense_pos"):
        np.testing.assert_allclose(getattr(same, name), getattr(dataset, name), atol=1e-5)
    np.testing.assert_allclose(np.abs(same.ctrl_rot6d), np.abs(dataset.ctrl_rot6d), atol=1e-5)
    source = CharacterProfile.load(PROFILES_DIR / "bandai_namco.json")
    target = CharacterProfile.load(PROFILES_DIR / "lafan1.json")
    transfer = Transfer.between(source, target)
    moved = transfer_curve_dataset(dataset, transfer)
    scale = target.height / source.height
    np.testing.assert_allclose(moved.ctrl_pos, dataset.ctrl_pos * scale, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(moved.dense_pos, dataset.dense_pos * scale, rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(moved.ctrl_contacts, dataset.ctrl_contacts)
    np.testing.assert_array_equal(moved.clip_index, dataset.clip_index)
    # Orientations: q ⊗ offset, per joint.
    expected = np_quat_mul(np.asarray(quat_from_rot6d(jnp.asarray(dataset.ctrl_rot6d))), np.asarray(transfer.rot_offset))
    assert_same_rotation(np.asarray(quat_from_rot6d(jnp.asarray(moved.ctrl_rot6d))), expected, atol=1e-4)
    # Still a consistent dataset: the moved curves fit the moved trajectories as well as before, scaled.
    layout = BezierLayout(31, 6)

    def fit_error(d):
        dense = evaluate(layout, jnp.swapaxes(jnp.asarray(d.ctrl_pos), 1, 2), jnp.swapaxes(jnp.asarray(d.ctrl_tangent), 1, 2))
        return np.abs(np.asarray(dense) - np.swapaxes(d.dense_pos, 1, 2)).max()

    np.testing.assert_allclose(fit_error(moved), scale * fit_error(dataset), rtol=1e-3, atol=1e-4)


def test_a_placement_turns_the_start_to_the_trained_facing_and_back(rng):
    """With a facing, the start key faces the BMM's training facing in its space; the curves come back exactly."""
    trained = 30.0
    t = Transfer(jnp.asarray(SCALED, jnp.float32), jnp.asarray(random_quat_np(rng, (6,)), jnp.float32), Transfer.identity(trained).facing)
    start = jnp.asarray(rng.normal(scale=30.0, size=(6, 3)), jnp.float32)
    where = placement(t, start)
    source = source_space(t, where, start)
    np.testing.assert_allclose(source[HIPS, [0, 2]], start[HIPS, [0, 2]], atol=1e-4)  # turned about the start hips
    assert_same_rotation(np.asarray(yaw_of(source)), np.asarray(t.facing), atol=1e-5)
    tangent = jnp.asarray(rng.normal(size=(K, 6, 3)), jnp.float32)
    quat = random_quat_np(rng, (K, 6))
    rot6d = jnp.asarray(np_rot6d(quat), jnp.float32)
    pos = jnp.asarray(rng.normal(scale=50.0, size=(K, 6, 3)), jnp.float32)
    curves = SampledCurves(source_space(t, where, pos), tangent, orientations_to_source_space(t, rot6d, where.turn), jnp.zeros((K, 2)))
    back = to_target(t, where, curves)
    np.testing.assert_allclose(back.ctrl_pos, pos, atol=1e-3)
    np.testing.assert_allclose(back.ctrl_rot6d, rot6d, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(back.ctrl_tangent, axis=-1), SCALED * np.linalg.norm(tangent, axis=-1), rtol=1e-5)
    # No facing: no turn (the paper's placement, the keys as they face).
    assert_same_rotation(np.asarray(placement(Transfer.identity(), start).turn), np.array([1.0, 0.0, 0.0, 0.0]), atol=0.0)


def test_anatomical_offsets_follow_a_files_bone_axes():
    """The same motion with every joint's axes turned by C_j: the anatomical offsets turn by C_j
    too (offset' = offset ⊗ C), so the transferred orientations are the file's own; the facing
    offsets (each joint's mean over the clip) do as well, but also carry the clip's poses."""
    motion = read_bvh(DEMO_CLIP)
    turn = zoo.random_axes(motion, 3)
    profiles = []
    for m in (motion, zoo.reorient(motion, turn)):
        recognised = recognise_character(m)
        profiles.append(CharacterProfile.from_poses(recognised.character, motion_poses(m, recognised.character, slice(None))))
    source = load_profile("bandai_namco")
    six = list(recognise_character(motion).character.characteristic)
    for orientation in ("anatomical", "facing"):
        before, after = (np.asarray(Transfer.between(source, p, orientation=orientation).rot_offset, np.float64) for p in profiles)
        assert_same_rotation(after, np_quat_mul(before, turn[six]), atol=2e-4)
    # The bundled profile's anatomical offsets describe the same skeleton as the demo clip's own.
    own = np.asarray(Transfer.between(source, profiles[0]).rot_offset, np.float64)
    angles = np.degrees(2 * np.arccos(np.clip(np.abs(own[:, 0]), 0.0, 1.0)))
    assert angles.max() < 25.0, angles  # the wrists' and ankles' own turns in 40 frames of a walk
