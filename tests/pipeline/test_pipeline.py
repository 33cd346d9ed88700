"""The in-betweening pipeline: the IK protocol's pose conversions, ``inbetween`` (BMM curves →
dense trajectories → ``ik_fn`` per frame), character transfer, BVH export and the
after-IK metrics.

Real data: the bundled Bandai-Namco clip (:data:`bezmotion.assets.DEMO_CLIP`, 40 frames,
22 joints under a static ``joint_Root``). The BMM is tiny and untrained (width 32, one
layer): these tests check plumbing, not motion quality. The IK modules are written here
(the hips where the targets put them, every other joint fixed; a table look-up that is
exact on known poses), never the rig or the learned IK. Compiling dominates the time, so
one compiled in-betweening serves most tests (module-scoped fixtures); the reference
values are plain NumPy (``helpers``).
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import (
    assert_same_rotation,
    assert_trees_close,
    np_forward_kinematics,
    np_matrix_from_quat,
    np_quat_from_axis_angle,
    np_quat_mul,
    np_quat_rotate,
    random_quat_np,
)

from bezmotion.assets import DEMO_CLIP
from bezmotion.bmm.evaluation import floor_height_from, make_eval_set
from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
from bezmotion.data.curves import MotionClips, build_curve_dataset
from bezmotion.geometry.rotations import quat_from_rot6d
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.protocol import (
    Character,
    IKTargets,
    Pose,
    pose_fk,
    pose_from_global,
    pose_from_motion,
    targets_from_pose,
)
from bezmotion.bmm.denoiser import BMMConfig, init_denoiser
from bezmotion.bmm.features import FeatureStats
from bezmotion.pipeline import (
    CharacterProfile,
    Transfer,
    curves_to_target,
    default_channels,
    facing_yaw,
    full_body_handles_error,
    inbetween,
    mean_rotation,
    mpjpe,
    pose_to_bvh,
    to_source_space,
)
from bezmotion.pipeline.evaluation import (
    PipelineMetricsConfig,
    evaluate_pipeline,
    ground_truth_pose_metrics,
    pose_metrics,
    run_pipeline,
    window_poses,
)
from bezmotion.bmm.sampling import BezierMotionModel, Handles, SampledCurves

TINY = BMMConfig.cpu(width=32, ff_width=64, num_heads=2, num_layers=1, dropout=0.0)
FRAMES, STRIDE, K = TINY.num_frames, TINY.stride, TINY.num_controls  # 31, 6, 6
STEPS = 2  # DDIM steps: plumbing, not quality
LEFT_HAND = CHARACTERISTIC_JOINTS.index("left_hand")
SCALED = 1.37  # a transfer scale whose round trip is not exact in float32


# ------------------------------------------------------------------------------ helpers

# Eager JAX compiles every primitive anew for each new shape; one jit per shape is far cheaper.
fk = jax.jit(pose_fk)
targets_of = jax.jit(targets_from_pose)
handles_error = jax.jit(full_body_handles_error, static_argnums=3)
mpjpe_of = jax.jit(mpjpe)
motion_to_pose = jax.jit(pose_from_motion)
global_to_pose = jax.jit(pose_from_global)
source_space = jax.jit(to_source_space)
to_target = jax.jit(curves_to_target)
yaw_of = jax.jit(facing_yaw)
mean_of = jax.jit(mean_rotation)


def np_rot6d(quat: np.ndarray) -> np.ndarray:
    """ortho6D from its definition: the rotation matrix's first two columns."""
    m = np_matrix_from_quat(quat)
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def hips_only_ik(character: Character):
    """The cheapest IK: the hips where and how the targets say, every other joint at
    ``params`` (local rotations). It records each trace in ``.traces`` (Python runs only
    while JAX traces), so tests can count compilations."""

    def ik(params: jax.Array, targets: IKTargets) -> Pose:
        ik.traces.append(1)
        hips_rot = quat_from_rot6d(targets.rot6d[HIPS])  # ancestors are identity: local == global
        return Pose(targets.position[HIPS], params.at[character.hips].set(hips_rot))

    ik.traces = []
    return ik


def lookup_ik(params: tuple[jax.Array, Pose], targets: IKTargets) -> Pose:
    """A "perfect" IK on known poses: the pose whose six target positions are nearest."""
    table, poses = params
    i = jnp.argmin(jnp.sum((table - targets.position) ** 2, axis=(-2, -1)))
    return jax.tree.map(lambda x: x[i], poses)


def identity_quats(joints: int) -> jax.Array:
    return jnp.zeros((joints, 4), jnp.float32).at[:, 0].set(1.0)


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


def yawed(pose: Pose, angle: float) -> tuple[Pose, np.ndarray]:
    """``pose`` (hips-rooted: ancestors at identity, at the origin) turned by ``angle`` about +Y."""
    q = np_quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.asarray(angle))
    quat = np.asarray(pose.quat_local, np.float64).copy()
    quat[..., 1, :] = np_quat_mul(q, quat[..., 1, :])  # joint 1 is Bandai-Namco's Hips
    root = np_quat_rotate(q, np.asarray(pose.root_pos, np.float64))
    return Pose(jnp.asarray(root, jnp.float32), jnp.asarray(quat, jnp.float32)), q


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def clip() -> SimpleNamespace:
    """The demo clip, its character, its 40 frames as poses and its NumPy FK (float64)."""
    motion = read_bvh(DEMO_CLIP)
    character = Character.from_bvh(motion, "bandai_namco")
    pose = motion_to_pose(character, jnp.asarray(motion.quat_local, jnp.float32), jnp.asarray(motion.pos_local, jnp.float32))
    quat_global, pos_global = np_forward_kinematics(motion.skeleton.parents, motion.quat_local, motion.pos_local)
    return SimpleNamespace(motion=motion, character=character, pose=pose, quat_global=quat_global, pos_global=pos_global)


@pytest.fixture(scope="module")
def curves(clip) -> SimpleNamespace:
    """The clip as a curve dataset: 31-frame windows at offset 5 (2 windows)."""
    clips = MotionClips.from_bvh([clip.motion])
    dataset = build_curve_dataset(clips, "bandai_namco", window=FRAMES, stride=STRIDE, offset=5, progress=False)
    return SimpleNamespace(clips=clips, dataset=dataset)


@pytest.fixture(scope="module")
def bmm(curves) -> BezierMotionModel:
    """Untrained tiny BMM; feature statistics computed here in NumPy from the clip's curves."""
    ds = curves.dataset
    feats = np.concatenate([ds.ctrl_pos, ds.ctrl_tangent, ds.ctrl_rot6d], axis=-1).astype(np.float64).reshape(-1, 6, 12)
    stats = FeatureStats(jnp.asarray(feats.mean(0), jnp.float32), jnp.asarray(np.maximum(feats.std(0), 1e-3), jnp.float32))
    graphdef, params = init_denoiser(TINY, key=jax.random.key(3))
    return BezierMotionModel(params, stats, graphdef, TINY)


@pytest.fixture(scope="module")
def run(clip, bmm) -> SimpleNamespace:
    """One in-betweening of frames 0–30 with the hips-only IK (all other joints at identity):
    a hips handle 11 cm off the mocap at frame 12, a left-hand handle at frame 18, and a
    padding slot sitting on the hips handle's place with a NaN position."""
    character = clip.character
    ik = hips_only_ik(character)
    rest = identity_quats(character.num_joints)
    start, end = frame(clip.pose, 0), frame(clip.pose, FRAMES - 1)
    _, pos = fk(character, clip.pose)
    idx = np.asarray(character.characteristic)
    hips_target = np.asarray(pos[12, idx[HIPS]]) + np.array([6.0, 5.0, -8.0])
    hand_target = np.asarray(pos[18, idx[LEFT_HAND]]) + np.array([0.0, 20.0, 0.0])
    handles = Handles(
        joint=jnp.asarray([HIPS, LEFT_HAND, HIPS], jnp.int32),
        control=jnp.asarray([2, 3, 2], jnp.int32),
        position=jnp.asarray(np.stack([hips_target, hand_target, np.full(3, np.nan)]), jnp.float32),
        valid=jnp.asarray([True, True, False]),
    )
    key = jax.random.key(7)
    result = inbetween(bmm, ik, rest, character, start, end, handles, key=key, steps=STEPS)
    return SimpleNamespace(
        character=character, ik=ik, rest=rest, start=start, end=end, handles=handles, result=result, key=key
    )


def again(bmm, run, **kwargs):
    """``run``'s in-betweening with some arguments replaced (same shapes: no recompilation)."""
    args = dict(handles=run.handles, transfer=None, key=run.key)
    args.update(kwargs)
    return inbetween(
        bmm, run.ik, run.rest, run.character, run.start, run.end, args["handles"], key=args["key"],
        transfer=args["transfer"], steps=STEPS,
    )  # fmt: skip


@pytest.fixture(scope="module")
def profile(clip) -> CharacterProfile:
    return CharacterProfile.from_poses(clip.character, clip.pose)


# ============================================================================== protocol


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


# ============================================================================== inbetween


def test_inbetween_curves_pass_through_the_handles_and_the_keyframes(run):
    r, h = run.result, run.handles
    assert r.positions.shape == (FRAMES, 6, 3) and r.rot6d.shape == (FRAMES, 6, 6)
    assert r.pose.root_pos.shape == (FRAMES, 3) and r.pose.quat_local.shape == (FRAMES, 22, 4)
    assert r.curves.ctrl_pos.shape == (K, 6, 3) and all(np.isfinite(np.asarray(a)).all() for a in (*r.curves, *r.pose))
    ctrl = np.asarray(r.curves.ctrl_pos)
    # Bit for bit at the handles' control points; the padding slot (NaN) is no constraint.
    np.testing.assert_array_equal(ctrl[2, HIPS], np.asarray(h.position[0]))
    np.testing.assert_array_equal(ctrl[3, LEFT_HAND], np.asarray(h.position[1]))
    # The end control points are the given poses' six joints, positions and orientations.
    for pose, k in ((run.start, 0), (run.end, K - 1)):
        t = targets_of(run.character, pose)
        np.testing.assert_allclose(ctrl[k], t.position, atol=1e-3)
        np.testing.assert_allclose(r.curves.ctrl_rot6d[k], t.rot6d, atol=1e-5)
    # The dense trajectories IK receives go through all of them.
    np.testing.assert_allclose(r.positions[12, HIPS], h.position[0], atol=1e-3)
    np.testing.assert_allclose(r.positions[18, LEFT_HAND], h.position[1], atol=1e-3)
    np.testing.assert_allclose(np.asarray(r.positions)[[0, -1]], ctrl[[0, -1]], atol=1e-3)


def test_keep_keyframes_returns_the_given_start_and_end_poses(run):
    pose = run.result.pose
    for i, given in ((0, run.start), (-1, run.end)):
        np.testing.assert_array_equal(pose.root_pos[i], given.root_pos)
        np.testing.assert_array_equal(pose.quat_local[i], given.quat_local)
    # Every other frame is the IK's own: body at identity (what hips-only IK gives).
    body = np.delete(np.asarray(pose.quat_local[1:-1]), run.character.hips, axis=1)
    np.testing.assert_array_equal(body, np.tile([1.0, 0.0, 0.0, 0.0], (FRAMES - 2, 21, 1)))
    assert not np.allclose(np.asarray(run.start.quat_local), [1.0, 0.0, 0.0, 0.0])


def test_hips_only_ik_has_no_full_body_error_on_a_hips_handle(run):
    r, h, c = run.result, run.handles, run.character
    # The IK puts the hips on the trajectory, oriented as the curves say.
    np.testing.assert_array_equal(r.pose.root_pos[1:-1], r.positions[1:-1, HIPS])
    quat, _ = fk(c, r.pose)
    np.testing.assert_allclose(np_rot6d(np.asarray(quat[1:-1, c.hips])), r.rot6d[1:-1, HIPS], atol=1e-5)
    hips_only = h._replace(valid=jnp.asarray([True, False, False]))
    assert float(handles_error(c, r.pose, hips_only, STRIDE)) < 1e-4
    # The hand handle is out of this IK's reach: the metric sees it.
    hand_only = h._replace(valid=jnp.asarray([False, True, False]))
    assert float(handles_error(c, r.pose, hand_only, STRIDE)) > 5.0


def test_any_plain_function_is_an_ik_and_compiles_once(clip, bmm, run):
    traces = []

    def translated_rest(params: dict, targets: IKTargets) -> Pose:  # ignores orientations
        traces.append(1)
        return Pose(targets.position[HIPS] + params["shift"], params["rest"])

    params = {"shift": jnp.asarray([0.0, 2.0, 0.0]), "rest": clip.pose.quat_local[20]}
    args = (bmm, translated_rest, params, run.character, run.start, run.end, run.handles)
    first = inbetween(*args, key=jax.random.key(0), steps=STEPS, keep_keyframes=False)
    second = inbetween(*args, key=jax.random.key(1), steps=STEPS, keep_keyframes=False)
    assert len(traces) == 1, "a second call with the same shapes must not retrace"
    for r in (first, second):
        np.testing.assert_allclose(r.pose.root_pos, r.positions[:, HIPS] + np.array([0.0, 2.0, 0.0]), atol=1e-4)
        # Without keep_keyframes the first and last frames are the IK's too.
        np.testing.assert_array_equal(r.pose.quat_local, np.broadcast_to(params["rest"], (FRAMES, 22, 4)))
    assert not np.allclose(first.curves.ctrl_tangent, second.curves.ctrl_tangent)


def test_inbetween_rejects_bad_inputs(bmm, run):
    def call(start=run.start, end=run.end, handles=run.handles):
        return inbetween(bmm, run.ik, run.rest, run.character, start, end, handles, key=run.key, steps=STEPS)

    batched = jax.tree.map(lambda x: x[None], run.start)
    with pytest.raises(ValueError, match=r"single poses of bandai_namco \(22 joints\).*\(1, 22, 4\), \(22, 4\)"):
        call(start=batched)
    with pytest.raises(ValueError, match=r"\(22, 4\), \(21, 4\)"):
        call(end=run.end._replace(quat_local=run.end.quat_local[:21]))
    with pytest.raises(ValueError, match="the start pose contains non-finite values"):
        call(start=run.start._replace(root_pos=run.start.root_pos.at[1].set(jnp.nan)))
    with pytest.raises(ValueError, match="the end pose contains non-finite values"):
        call(end=run.end._replace(quat_local=run.end.quat_local.at[3, 0].set(jnp.inf)))
    with pytest.raises(ValueError, match=r"one motion.*got \(1, 3, 3\)"):
        call(handles=jax.tree.map(lambda x: x[None], run.handles))


# =============================================================================== transfer


def test_transfer_between_a_profile_and_itself_is_no_transfer(bmm, run, profile):
    t = Transfer.between(profile, profile)
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
    ctrl = np.asarray(r.curves.ctrl_pos)
    np.testing.assert_array_equal(ctrl[2, HIPS], np.asarray(run.handles.position[0]))
    np.testing.assert_array_equal(ctrl[3, LEFT_HAND], np.asarray(run.handles.position[1]))
    np.testing.assert_array_equal(ctrl[[0, -1]], np.asarray(run.result.curves.ctrl_pos)[[0, -1]])
    free = np.ones(K, bool)
    free[[0, -1]] = False
    assert np.abs(ctrl[free] - np.asarray(run.result.curves.ctrl_pos)[free]).max() > 1.0  # the scale does act


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


# ================================================================================= export


@pytest.mark.parametrize("which", ["default", "clip"])
def test_bvh_export_round_trip_matches_pipeline_fk(clip, run, tmp_path, which):
    c, pose = run.character, run.result.pose
    channels = default_channels(c) if which == "default" else clip.motion.channels
    if which == "default":
        assert [len(ch) for ch in channels] == [6, 6] + [3] * 20
        assert channels[1] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    else:
        assert all(ch[3:] == ("Zrotation", "Xrotation", "Yrotation") and len(ch) == 6 for ch in channels)
    motion = pose_to_bvh(c, pose, fps=clip.motion.fps, channels=None if which == "default" else channels)
    assert motion.quat_local.dtype == np.float64 and motion.channels == tuple(channels)
    path = tmp_path / f"{which}.bvh"
    write_bvh(path, motion)
    back = read_bvh(path)
    assert back.skeleton.names == c.skeleton.names and back.channels == tuple(channels)
    assert back.num_frames == FRAMES and back.frame_time == pytest.approx(clip.motion.frame_time)
    assert back.end_sites == clip.motion.end_sites
    _, pos = np_forward_kinematics(back.skeleton.parents, back.quat_local, back.pos_local)
    np.testing.assert_allclose(pos, fk(c, pose)[1], atol=1e-3)
    np.testing.assert_allclose(pos, np_pose_positions(c, pose), atol=1e-3)


def test_pose_to_bvh_rejects_bad_input(run):
    c, pose = run.character, run.result.pose
    with pytest.raises(ValueError, match=r"poses must be \(frames, 22, 4\) for bandai_namco, got \(22, 4\)"):
        pose_to_bvh(c, run.start)
    with pytest.raises(ValueError, match=r"got \(31, 21, 4\)"):
        pose_to_bvh(c, pose._replace(quat_local=pose.quat_local[:, :21]))
    with pytest.raises(ValueError, match=r"poses.root_pos must be \(31, 3\), got \(3,\)"):
        pose_to_bvh(c, pose._replace(root_pos=pose.root_pos[0]))
    for fps in (0.0, -30.0, float("nan")):
        with pytest.raises(ValueError, match=f"fps must be positive, got {fps}"):
            pose_to_bvh(c, pose, fps=fps)
    with pytest.raises(ValueError, match="need channels for 22 joints, got 21"):
        pose_to_bvh(c, pose, channels=default_channels(c)[:21])


# ================================================================================ metrics


def test_full_body_handles_error_against_numpy(clip, rng):
    c = clip.character
    pose = jax.tree.map(lambda x: jnp.stack([x[:FRAMES], x[5 : 5 + FRAMES]]), clip.pose)  # (2, 31, …)
    joint = rng.integers(0, 6, (2, 4))
    control = rng.integers(0, K, (2, 4))
    valid = np.array([[True, True, False, True], [False, True, False, False]])
    position = rng.normal(scale=30.0, size=(2, 4, 3)) + clip.pos_global[0, 1]
    position[~valid] = np.nan  # padding is ignored, whatever it holds
    handles = Handles(
        jnp.asarray(joint, jnp.int32), jnp.asarray(control, jnp.int32), jnp.asarray(position, jnp.float32), jnp.asarray(valid)
    )
    pos = np_pose_positions(c, pose)  # (2, 31, 22, 3)
    idx = np.asarray(c.characteristic)
    errors = [
        np.linalg.norm(pos[b, control[b, s] * STRIDE, idx[joint[b, s]]] - position[b, s])
        for b in range(2) for s in range(4) if valid[b, s]
    ]  # fmt: skip
    got = float(handles_error(c, pose, handles, STRIDE))
    assert np.isfinite(got) and got == pytest.approx(np.mean(errors), rel=1e-5)
    # One motion alone, and no valid handle at all.
    one = float(handles_error(c, frame(pose, 1), frame(handles, 1), STRIDE))
    assert one == pytest.approx(errors[-1], rel=1e-5)
    assert float(handles_error(c, pose, handles._replace(valid=jnp.zeros((2, 4), bool)), STRIDE)) == 0.0
    # MPJPE: zero against itself, the shift's length against a shifted copy.
    assert float(mpjpe_of(c, pose, pose)) == 0.0
    shifted = pose._replace(root_pos=pose.root_pos + jnp.asarray([3.0, 0.0, 4.0]))
    assert float(mpjpe_of(c, shifted, pose)) == pytest.approx(5.0 * 21 / 22, rel=1e-4)  # joint_Root stays put


def test_window_poses_reproduce_the_curve_dataset(clip, curves):
    c, ds = clip.character, curves.dataset
    assert len(ds) == 2 and list(ds.start_frame) == [0, 5]
    truth = window_poses(c, curves.clips, ds, np.arange(2))
    assert truth.root_pos.shape == (2, FRAMES, 3) and truth.quat_local.shape == (2, FRAMES, 22, 4)
    np.testing.assert_array_equal(np.asarray(truth.root_pos)[:, 0, [0, 2]], np.zeros((2, 2)))
    np.testing.assert_array_equal(truth.quat_local[..., 0, :], np.broadcast_to([1.0, 0.0, 0.0, 0.0], (2, FRAMES, 4)))
    targets = targets_of(c, truth)
    np.testing.assert_allclose(targets.position, ds.dense_pos, atol=1e-3)
    np.testing.assert_allclose(targets.rot6d[:, ds.layout.control_frames], ds.ctrl_rot6d, atol=1e-5)
    # The windows are the clip's frames 0–30 and 5–35, moved in XZ only.
    for w, first in enumerate((0, 5)):
        moved = np.asarray(clip.pose.root_pos[first : first + FRAMES]) - np.asarray(truth.root_pos[w])
        np.testing.assert_allclose(moved - moved[0], 0.0, atol=1e-3)
        assert moved[0, 1] == 0.0
        np.testing.assert_array_equal(truth.quat_local[w], clip.pose.quat_local[first : first + FRAMES])
    # Rows pick windows, in the order given.
    swapped = window_poses(c, curves.clips, ds, np.array([1, 0]))
    np.testing.assert_array_equal(swapped.root_pos, np.asarray(truth.root_pos)[::-1])


@pytest.fixture(scope="module")
def evaluation(clip, curves) -> SimpleNamespace:
    ds = curves.dataset
    eval_set = make_eval_set(ds, key=jax.random.key(5))
    truth = window_poses(clip.character, curves.clips, ds, eval_set.rows)
    config = PipelineMetricsConfig(stride=STRIDE, fps=ds.fps, floor_height=floor_height_from(ds))
    return SimpleNamespace(eval_set=eval_set, truth=truth, config=config)


def test_evaluate_pipeline_returns_finite_metrics_and_compiles_once(clip, bmm, evaluation):
    c, ev = clip.character, evaluation
    ik, rest = hips_only_ik(c), identity_quats(c.num_joints)
    metrics = evaluate_pipeline(ev.config, bmm, ik, rest, c, ev.truth, ev.eval_set, key=jax.random.key(2))
    assert set(metrics) == {"id", "ood"}
    for m in metrics.values():
        assert set(m) == {"handles_error_cm", "foot_skating_ratio", "mpjpe_cm"}
        assert all(np.isfinite(v) for v in m.values())
        assert m["handles_error_cm"] >= 0.0 and 0.0 <= m["foot_skating_ratio"] <= 1.0 and m["mpjpe_cm"] > 1.0
    assert len(ik.traces) == 1, "the in-distribution and OOD runs must share one compilation"
    # The windows start and end on the true poses; same key and steps (10), same poses as evaluate_pipeline's.
    pose = run_pipeline(bmm, ik, rest, c, ev.truth, ev.eval_set.handles, key=jax.random.key(2), steps=10)
    assert len(ik.traces) == 1
    for i in (0, -1):
        np.testing.assert_array_equal(pose.root_pos[:, i], ev.truth.root_pos[:, i])
        np.testing.assert_array_equal(pose.quat_local[:, i], ev.truth.quat_local[:, i])
    again_metrics = pose_metrics(ev.config, c, pose, ev.truth, ev.eval_set.handles)
    assert again_metrics == pytest.approx(metrics["id"], rel=1e-6)


def test_metrics_of_the_truth_and_of_a_perfect_ik(clip, evaluation):
    c, ev = clip.character, evaluation
    truth_metrics = pose_metrics(ev.config, c, ev.truth, ev.truth, ev.eval_set.handles)
    assert truth_metrics["mpjpe_cm"] == 0.0
    assert truth_metrics["handles_error_cm"] < 1e-3  # the handles are the mocap's (pinned) control points
    flat = jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), ev.truth)
    table = jnp.asarray(np_pose_positions(c, flat)[:, list(c.characteristic)], jnp.float32)
    gt = ground_truth_pose_metrics(ev.config, c, ev.truth, lookup_ik, (table, flat))
    assert set(gt) == {"foot_skating_ratio", "ik_of_mocap_mpjpe_cm", "ik_of_mocap_foot_skating_ratio"}
    assert gt["foot_skating_ratio"] == truth_metrics["foot_skating_ratio"]
    assert gt["ik_of_mocap_mpjpe_cm"] < 1e-4
    assert gt["ik_of_mocap_foot_skating_ratio"] == pytest.approx(gt["foot_skating_ratio"], abs=1e-6)
    assert set(ground_truth_pose_metrics(ev.config, c, ev.truth)) == {"foot_skating_ratio"}
