"""The data-free rig IK (bezmotion.ik.rig): real poses round trip, limits, JAX contracts, bad specs.

Real data: the bundled Bandai-Namco ``DEMO_CLIP`` always, and a few LaFAN1 subject-5 frames
when ``../shared/data/lafan1/lafan1-subset.zip`` is present.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SHARED_DATA
from jaxtyping import Array

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.geometry.rotations import quat_conjugate, quat_from_axis_angle, quat_from_rot6d, quat_identity, quat_mul, quat_rotate
from bezmotion.ik.exact import exact_ik
from bezmotion.ik.protocol import Character, IKTargets, Pose, pose_fk, pose_from_motion, targets_from_pose
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.rig import RIG_PRESETS, Rig, RigSpec, _rest_lateral, elbows_from_keys, make_rig, refine_limbs, rig_ik, with_rest_pose

LAFAN1_ZIP = SHARED_DATA / "lafan1" / "lafan1-subset.zip"
requires_lafan1 = pytest.mark.skipif(not LAFAN1_ZIP.exists(), reason=f"LaFAN1 subset not found at {LAFAN1_ZIP}")

# The head is reached by a law-of-cosines bend of the spine: exact up to float32 rounding
# of ~100 cm coordinates through ~20 rotation products (measured: ≤ 7e-5 cm on 1520
# LaFAN1 subject-5 frames, ≤ 2e-4 cm on the demo clip). Hands and feet: one two-bone step.
HEAD_TOL_CM = 5e-3
END_TOL_CM = 1e-3
ANGLE_TOL_RAD = 1e-3

# One compiled solver and FK per skeleton: every test below feeds batches of the same shape
# (XLA compile time dominates this module's run time).
solve = jax.jit(jax.vmap(rig_ik, in_axes=(None, 0)))
fk = jax.jit(pose_fk)


@dataclasses.dataclass
class Case:
    character: Character
    rig: Rig
    targets: IKTargets
    truth: Pose
    pose: Pose  # rig_ik's answer (jit + vmap)


def _case(character: Character, preset: str, quat_local: np.ndarray, pos_local: np.ndarray) -> Case:
    truth = pose_from_motion(character, jnp.asarray(quat_local, jnp.float32), jnp.asarray(pos_local, jnp.float32))
    targets = targets_from_pose(character, truth)
    rig = make_rig(character, preset)
    return Case(character, rig, targets, truth, solve(rig, targets))


@pytest.fixture(scope="module")
def bandai() -> Case:
    motion = read_bvh(DEMO_CLIP)
    return _case(Character.from_bvh(motion, "bandai_namco"), "bandai_namco", motion.quat_local, motion.pos_local)


@pytest.fixture(scope="module")
def lafan1_case() -> Case:
    if not LAFAN1_ZIP.exists():
        pytest.skip(f"LaFAN1 subset not found at {LAFAN1_ZIP}")
    from bezmotion.data.lafan1 import load_lafan1

    corpus = load_lafan1(LAFAN1_ZIP)
    quats, positions = [], []
    for f in corpus.files_of([5]):
        quat, root = corpus.clip(f)
        pos = np.broadcast_to(corpus.offsets[f], quat.shape[:2] + (3,)).copy()
        pos[:, 0] = root
        quats.append(quat[::97])  # a spread of obstacles, ground work and falls
        positions.append(pos[::97])
    skeleton = corpus.clip_skeleton(corpus.files_of([5])[0])
    character = Character.from_skeleton(skeleton, "lafan1")
    return _case(character, "lafan1", np.concatenate(quats), np.concatenate(positions))


def _angle(q: Array | np.ndarray, r: Array | np.ndarray) -> np.ndarray:
    """Rotation angle (rad) between quaternions, from the chord (accurate near zero, unlike acos)."""
    q, r = np.asarray(q, np.float64), np.asarray(r, np.float64)
    chord = np.minimum(np.linalg.norm(q - r, axis=-1), np.linalg.norm(q + r, axis=-1))
    return 4.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0))


def _lengths(rig: Rig, limb: int) -> tuple[float, float]:
    offsets = np.asarray(rig.skeleton.offsets)
    _, mid, end = rig.limbs[limb]
    return float(np.linalg.norm(offsets[mid])), float(np.linalg.norm(offsets[end]))


def _check_round_trip(case: Case) -> None:
    rig, targets, character = case.rig, case.targets, case.character
    assert np.all(np.isfinite(case.pose.quat_local)) and np.all(np.isfinite(case.pose.root_pos))
    quat, pos = (np.asarray(x) for x in fk(character, case.pose))
    idx = list(character.characteristic)
    want_pos, want_quat = np.asarray(targets.position), np.asarray(quat_from_rot6d(targets.rot6d))

    np.testing.assert_allclose(pos[:, idx[0]], want_pos[:, 0], atol=END_TOL_CM)
    assert np.max(_angle(quat[:, idx], want_quat)) < ANGLE_TOL_RAD  # all six orientations
    assert np.max(np.linalg.norm(pos[:, idx[1]] - want_pos[:, 1], axis=-1)) < HEAD_TOL_CM

    # Hands and feet: exactly on target when the limb reaches it from where the rig put its
    # root, else at full reach along the root-to-target direction.
    reached = 0
    for limb, (root, _, end) in enumerate(rig.limbs):
        upper, lower = _lengths(rig, limb)
        to_target = want_pos[:, limb + 2] - pos[:, root]
        dist = np.linalg.norm(to_target, axis=-1, keepdims=True)
        expected = pos[:, root] + np.clip(dist, abs(upper - lower), upper + lower) * to_target / dist
        np.testing.assert_allclose(pos[:, end], expected, atol=END_TOL_CM)
        inside = (dist[:, 0] < upper + lower - 1e-3) & (dist[:, 0] > abs(upper - lower) + 1e-3)
        np.testing.assert_allclose(pos[inside, end], want_pos[inside, limb + 2], atol=END_TOL_CM)
        reached += int(inside.sum())
    assert reached > len(want_pos)  # most real targets are within reach

    # Joints the rig does not solve keep their rest (identity) rotation.
    solved = set(rig.spine) | {j for limb in rig.limbs for j in limb}
    rest = [j for j in range(rig.num_joints) if j not in solved]
    np.testing.assert_allclose(np.abs(np.asarray(case.pose.quat_local)[:, rest, 0]), 1.0, atol=1e-6)


def test_bandai_namco_round_trip(bandai):
    _check_round_trip(bandai)
    # Knees bend the right way: on this walk they land within millimetres of the truth.
    _, pos = fk(bandai.character, bandai.pose)
    _, true = fk(bandai.character, bandai.truth)
    err = np.linalg.norm(np.asarray(pos) - np.asarray(true), axis=-1).mean(0)
    knees = [bandai.rig.limbs[2][1], bandai.rig.limbs[3][1]]
    assert np.all(err[knees] < 1.0), err[knees]  # measured 0.58 cm both
    assert err.mean() < 3.0  # measured 2.47 cm (clavicles held at zero rotation)


@requires_lafan1
def test_lafan1_round_trip(lafan1_case):
    _check_round_trip(lafan1_case)


def test_presets_name_real_joints(bandai):
    from bezmotion.data.lafan1 import JOINT_NAMES  # the names every LaFAN1 BVH file is checked against

    for names, preset in ((bandai.character.skeleton.names, "bandai_namco"), (JOINT_NAMES, "lafan1")):
        spec = RigSpec.preset(preset)
        assert spec is RIG_PRESETS[preset]
        for field in ("spine", "left_arm", "right_arm", "left_leg", "right_leg"):
            assert all(n in names for n in getattr(spec, field)), (preset, field)


def test_frames_are_independent_under_vmap(bandai):
    # Reordering the batch reorders the answers and nothing else.
    order = np.random.default_rng(0).permutation(len(bandai.targets.position))
    shuffled = solve(bandai.rig, jax.tree.map(lambda x: x[order], bandai.targets))
    np.testing.assert_array_equal(np.asarray(shuffled.quat_local), np.asarray(bandai.pose.quat_local)[order])
    np.testing.assert_array_equal(np.asarray(shuffled.root_pos), np.asarray(bandai.pose.root_pos)[order])


# Frames of the demo clip whose targets are edited into degenerate cases.
EXTENDED_ETC, CURLED, HEAD_ON_HIPS = 0, 1, 2


@pytest.fixture(scope="module")
def degenerate(bandai) -> tuple[IKTargets, Pose]:
    """The demo clip's targets with frames edited into hard cases, and rig_ik's answers.

    Frame 0: the left hand exactly at full reach, the left foot on the hip joint (zero
    distance), the right hand far out of reach. Frame 1: a head target 12 cm from the
    first spine joint, closer than the shared-rotation first guess can fold (FABRIK has to
    reshape the spine). Frame 2: the head target on the hips (no "up" direction).
    Limb roots depend on the hips and head targets only, so frame 0's come from the
    unedited solve.
    """
    rig = bandai.rig
    _, pos = fk(bandai.character, bandai.pose)
    pos = np.asarray(pos)
    position = np.array(bandai.targets.position)
    upper, lower = _lengths(rig, 0)
    position[EXTENDED_ETC, 2] = pos[EXTENDED_ETC, rig.limbs[0][0]] + (upper + lower) * np.asarray([0.6, -0.48, 0.64])
    position[EXTENDED_ETC, 3] = pos[EXTENDED_ETC, rig.limbs[1][0]] + np.asarray([300.0, 50.0, 0.0])
    position[EXTENDED_ETC, 4] = pos[EXTENDED_ETC, rig.limbs[2][0]]
    hips = np.asarray(quat_from_rot6d(bandai.targets.rot6d[CURLED, 0]))
    forward = np.asarray(quat_rotate(jnp.asarray(hips), jnp.asarray([0.0, 0.0, 1.0])))
    position[CURLED, 1] = pos[CURLED, rig.spine[1]] + 12.0 * forward
    position[HEAD_ON_HIPS, 1] = position[HEAD_ON_HIPS, 0]
    targets = bandai.targets._replace(position=jnp.asarray(position))
    return targets, solve(rig, targets)


def test_unreachable_and_degenerate_targets_are_clamped_and_finite(bandai, degenerate):
    targets, pose = degenerate
    rig = bandai.rig
    assert np.all(np.isfinite(pose.quat_local)) and np.all(np.isfinite(pose.root_pos))
    _, pos = fk(bandai.character, pose)
    pos, want = np.asarray(pos), np.asarray(targets.position)
    for limb, (root, mid, end) in enumerate(rig.limbs):  # bone lengths are kept whatever the target
        upper, lower = _lengths(rig, limb)
        np.testing.assert_allclose(np.linalg.norm(pos[:, mid] - pos[:, root], axis=-1), upper, atol=1e-3)
        np.testing.assert_allclose(np.linalg.norm(pos[:, end] - pos[:, mid], axis=-1), lower, atol=1e-3)
    frame = pos[EXTENDED_ETC]
    # Full reach: reached, the arm straight.
    np.testing.assert_allclose(frame[rig.limbs[0][2]], want[EXTENDED_ETC, 2], atol=END_TOL_CM)
    # Out of reach: straight, pointing at the target.
    root, _, end = rig.limbs[1]
    reach, aim = frame[end] - frame[root], want[EXTENDED_ETC, 3] - frame[root]
    assert abs(np.linalg.norm(reach) - sum(_lengths(rig, 1))) < 1e-3
    assert np.dot(reach, aim) / (np.linalg.norm(reach) * np.linalg.norm(aim)) > 1.0 - 1e-6
    # Zero distance: folded as far as the bones allow, |thigh - shin| from the hip.
    root, _, end = rig.limbs[2]
    upper, lower = _lengths(rig, 2)
    assert abs(np.linalg.norm(frame[end] - frame[root]) - abs(upper - lower)) < 1e-3
    # A curled spine is reached (without FABRIK, spine_iterations=0, it misses by 6.9 cm).
    assert np.linalg.norm(pos[CURLED, rig.spine[-1]] - want[CURLED, 1]) < 1e-2


def test_gradients_are_finite_at_degenerate_targets(bandai, degenerate):
    targets, _ = degenerate
    character, rig = bandai.character, bandai.rig
    weights = jax.random.normal(jax.random.key(0), (2, character.num_joints, 4))

    def loss(position, rot6d, offsets):
        skeleton = dataclasses.replace(rig.skeleton, offsets=offsets)
        pose = rig_ik(dataclasses.replace(rig, skeleton=skeleton), IKTargets(position, rot6d))
        quat, pos = pose_fk(dataclasses.replace(character, skeleton=skeleton), pose)
        return jnp.sum(weights[0, :, :3] * pos) + jnp.sum(weights[1] * quat)

    frames = np.asarray([EXTENDED_ETC, CURLED, HEAD_ON_HIPS, 5])
    grads = jax.jit(jax.vmap(jax.grad(loss, argnums=(0, 1, 2)), in_axes=(0, 0, None)))(
        targets.position[frames], targets.rot6d[frames], jnp.asarray(rig.skeleton.offsets, jnp.float32)
    )
    for name, grad in zip(("position", "rot6d", "offsets"), grads):
        assert np.all(np.isfinite(grad)), name
        assert np.any(grad != 0.0), name


def test_rest_rotations_are_kept(bandai):
    # A bind pose for the joints the rig does not solve (here: the clip's first frame).
    rest = np.asarray(bandai.truth.quat_local[0])
    rig = make_rig(bandai.character, "bandai_namco", rest_quat_local=rest)
    pose = solve(rig, bandai.targets)  # same structure: no recompilation
    solved = set(rig.spine) | {j for limb in rig.limbs for j in limb}
    kept = [j for j in range(rig.num_joints) if j not in solved]
    assert _angle(np.asarray(pose.quat_local)[:, kept], rest[kept]).max() < 1e-5
    _, pos = fk(bandai.character, pose)
    np.testing.assert_allclose(pos[:, rig.limbs[3][2]], bandai.targets.position[:, 5], atol=END_TOL_CM)
    # The clavicles now point sideways as in the clip: the arms land much closer.
    _, true = fk(bandai.character, bandai.truth)
    err = np.linalg.norm(np.asarray(pos) - np.asarray(true), axis=-1).mean()
    assert err < 2.0  # measured 1.73 cm (2.47 cm with identity clavicles)


def test_knees_do_not_depend_on_the_rest_pose_leg_direction(bandai):
    # The same motion on a skeleton whose left leg points down at zero rotation instead of
    # up: its joint frames turned half a turn about the rest forward axis (z here), which
    # flips their lateral axis. Positions, and so the rig's answer, must not change.
    flip = np.asarray([0.0, 0.0, 0.0, 1.0])  # π about z
    skeleton = bandai.character.skeleton
    turned = {skeleton.index(n) for n in ("UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L")}
    change = np.asarray([flip if j in turned else [1.0, 0.0, 0.0, 0.0] for j in range(skeleton.num_joints)])
    parent_change = change[[max(p, 0) for p in skeleton.parents]]
    parent_change[0] = [1.0, 0.0, 0.0, 0.0]
    offsets = quat_rotate(quat_conjugate(jnp.asarray(parent_change)), jnp.asarray(skeleton.offsets, jnp.float32))
    quat_local = quat_mul(quat_mul(quat_conjugate(jnp.asarray(parent_change)), bandai.truth.quat_local), jnp.asarray(change))
    character = dataclasses.replace(bandai.character, skeleton=dataclasses.replace(skeleton, offsets=offsets))
    truth = Pose(bandai.truth.root_pos, quat_local.astype(jnp.float32))
    np.testing.assert_allclose(fk(character, truth)[1], fk(bandai.character, bandai.truth)[1], atol=1e-3)

    pose = solve(make_rig(character, "bandai_namco"), targets_from_pose(character, truth))  # no recompilation
    np.testing.assert_allclose(fk(character, pose)[1], fk(bandai.character, bandai.pose)[1], atol=1e-3)


# ---------------------------------------------------------------------------- bad input


@pytest.fixture(scope="module")
def bandai_character() -> Character:
    return Character.from_bvh(read_bvh(DEMO_CLIP), "bandai_namco")


def _spec(**changes) -> dict:
    spec = dataclasses.asdict(RIG_PRESETS["bandai_namco"])
    spec.update(changes)
    return spec


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (_spec(left_arm=("UpperArm_L", "Forearm_L", "Hand_L")), r"unknown joint 'Forearm_L' in RigSpec.left_arm"),
        (_spec(spine=("Hips", "Spine", "Torso", "Neck", "Head")), r"unknown joint 'Torso' in RigSpec.spine"),
        (_spec(left_leg=("UpperLeg_L", "Foot_L", "LowerLeg_L")), r"joint 'LowerLeg_L' \(a child of 'UpperLeg_L'\) does not descend from 'Foot_L'"),
        (_spec(spine=("Hips", "Spine", "Chest", "Neck")), r"RigSpec.spine ends at 'Neck' but the character's head is 'Head'"),
        (_spec(spine=("Spine", "Chest", "Neck", "Head")), r"RigSpec.spine starts at 'Spine' but the character's hips is 'Hips'"),
        (_spec(right_arm=("Shoulder_R", "UpperArm_R", "LowerArm_R")), r"right_arm ends at 'LowerArm_R'"),
        (_spec(left_arm=("UpperLeg_L", "LowerLeg_L", "Foot_L")), r"'UpperLeg_L' is in both RigSpec.left_arm and RigSpec.left_leg"),
        (_spec(spine=("Hips", "Head")), r"RigSpec.spine needs the hips, at least one spine joint and the head"),
        (_spec(left_leg=("UpperLeg_L", "LowerLeg_L")), r"RigSpec.left_leg needs exactly 3 joints"),
        ({k: v for k, v in _spec().items() if k != "right_leg"}, r"missing \['right_leg'\]"),
        (_spec(tail=("Hips",)), r"unknown \['tail'\]"),
        ("mixamo", r"unknown rig preset 'mixamo'"),
    ],
)
def test_bad_spec_raises(bandai_character, spec, message):
    with pytest.raises(ValueError, match=message):
        make_rig(bandai_character, spec)


def test_spec_from_a_dict_of_lists(bandai_character):
    as_lists = {field: list(names) for field, names in dataclasses.asdict(RIG_PRESETS["bandai_namco"]).items()}
    from_dict, preset = make_rig(bandai_character, as_lists), make_rig(bandai_character, "bandai_namco")
    assert jax.tree.structure(from_dict) == jax.tree.structure(preset)  # same static topology
    assert from_dict.limbs == preset.limbs and from_dict.spine == (1, 2, 3, 4, 5)
    assert from_dict.limb_bases[0] == (2, (6, 7))  # the left arm hangs off the chest through Shoulder_L


def test_wrong_skeleton_preset_and_bad_rest_raise(bandai_character):
    with pytest.raises(ValueError, match=r"unknown joint 'Spine1' in RigSpec.spine"):
        make_rig(bandai_character, "lafan1")
    with pytest.raises(ValueError, match=r"rest_quat_local must have shape \(22, 4\)"):
        make_rig(bandai_character, "bandai_namco", rest_quat_local=np.zeros((21, 4)))
    rest = np.array(quat_identity((22,)))
    rest[0] = [0.0, 1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"identity above the hips; joints \['joint_Root'\]"):
        make_rig(bandai_character, "bandai_namco", rest_quat_local=rest)
    rest = np.array(quat_identity((22,)))
    rest[7] *= 2.0
    with pytest.raises(ValueError, match=r"unit quaternions; joints \['UpperArm_L'\]"):
        make_rig(bandai_character, "bandai_namco", rest_quat_local=rest)
    with pytest.raises(ValueError, match="spine_iterations must be a non-negative int"):
        make_rig(bandai_character, "bandai_namco", spine_iterations=-1)


def test_refine_limbs_puts_hands_and_feet_on_their_targets_and_keeps_the_rest(bandai):
    """``refine_limbs`` after another IK (here: the truth with every limb joint bent off):
    hands and feet land on moved targets exactly, only the 12 limb joints change."""
    c = bandai
    limbs = np.asarray(c.rig.limbs).reshape(-1)
    # A perturbed starting pose: each limb joint turned by ~17° about a fixed axis.
    turn = jnp.asarray([np.cos(0.15), np.sin(0.15), 0.0, 0.0], jnp.float32)
    start = c.truth._replace(quat_local=c.truth.quat_local.at[:, limbs].set(quat_mul(c.truth.quat_local[:, limbs], turn)))
    targets = c.targets._replace(position=c.targets.position.at[:, 2:].add(jnp.asarray([2.0, 3.0, -1.0], jnp.float32)))
    refined = jax.jit(jax.vmap(refine_limbs, in_axes=(None, 0, 0)))(c.rig, start, targets)
    _, pos = fk(c.character, refined)
    ends = np.asarray(c.character.characteristic[2:])
    reach = np.linalg.norm(np.asarray(pos[:, ends] - targets.position[:, 2:]), axis=-1)
    assert reach.max() < END_TOL_CM * 10, reach.max()
    others = np.setdiff1d(np.arange(c.character.num_joints), limbs)
    np.testing.assert_array_equal(np.asarray(refined.quat_local[:, others]), np.asarray(start.quat_local[:, others]))
    np.testing.assert_array_equal(np.asarray(refined.root_pos), np.asarray(start.root_pos))
    quat_global, _ = fk(c.character, refined)
    assert _angle(quat_global[:, ends], quat_from_rot6d(targets.rot6d[:, 2:])).max() < ANGLE_TOL_RAD


def test_the_rest_pose_sets_the_spine_and_the_limbs_twist(bandai):
    """With a bind pose, the rig starts its spine from the bind pose's and takes each limb's
    twist (the elbow's and wrist's rotations about their bones) from it: on the bind pose's
    own targets the spine comes back as it was, and over the clip every solved joint lies
    far nearer the truth than from the zero rotation (from which the spine's first joint
    came out ~1.2 rad from the truth on the bind pose's own targets)."""
    c = bandai
    rest = np.asarray(c.truth.quat_local[0])
    rig = make_rig(c.character, "bandai_namco", rest_quat_local=rest)
    pose = solve(rig, c.targets)
    spine = list(rig.spine[1:-1])
    assert _angle(pose.quat_local[0, spine], rest[spine]).max() < 1e-3
    solved = sorted(set(rig.spine[1:]) | {j for limb in rig.limbs for j in limb})
    with_rest = _angle(pose.quat_local[:, solved], c.truth.quat_local[:, solved]).mean(0)
    without = _angle(c.pose.quat_local[:, solved], c.truth.quat_local[:, solved]).mean(0)
    assert with_rest.mean() < 0.5 * without.mean(), (with_rest, without)


def test_refine_limbs_keeps_the_poses_own_twist(bandai):
    """``refine_limbs`` of a pose onto its own targets changes nothing: each limb keeps the
    pose's elbow side and the share of twist its elbow and wrist carry."""
    c = bandai
    refined = jax.jit(jax.vmap(refine_limbs, in_axes=(None, 0, 0)))(c.rig, c.truth, c.targets)
    limbs = np.asarray(c.rig.limbs).reshape(-1)
    assert _angle(refined.quat_local[:, limbs], c.truth.quat_local[:, limbs]).max() < 2e-3


def test_a_traced_rest_pose_per_frame_matches_rigs_made_with_it(bandai):
    """``with_rest_pose`` gives every :class:`Rig` in a params pytree (the rig's own, the exact
    IK's) a rest pose that may be traced: vmapped over frames, each frame's pose is the one a
    rig made with that frame's rest gives (what the pipeline evaluation does per window)."""
    c = bandai
    rests = c.truth.quat_local  # each frame rests in its own pose
    traced = jax.jit(jax.vmap(lambda r, t: rig_ik(with_rest_pose(c.rig, r), t)))(rests, c.targets)
    for i in (0, 20, 39):
        made = make_rig(c.character, "bandai_namco", rest_quat_local=np.asarray(rests[i]))
        alone = solve(made, c.targets)  # the module's compiled solve: a rig's rest is a leaf
        assert _angle(traced.quat_local[i], alone.quat_local[i]).max() < 1e-4
    assert _angle(traced.quat_local, c.pose.quat_local).max() > 0.1  # the fixture's rig rests elsewhere
    _, params = exact_ik(rig_ik, c.rig, c.character)
    np.testing.assert_array_equal(with_rest_pose(params, rests[1]).inner.rest_quat_local, rests[1])


def test_a_bent_bind_pose_keeps_the_knees_side_when_the_toes_point_along_the_leg(bandai):
    """Feet turned 115° about their lateral axis (pointed, the toes along or behind the shin, as
    when lying or falling) mislead the rough knee hint (toes and pelvis forward): from the zero
    rotation the rig bends knees backwards in a third of the demo clip's frames (45 cm off). A
    bind pose with a bent knee tells which way knees bend about the foot's lateral axis, at any
    bend: every knee stays on its side."""
    c, rig = bandai, bandai.rig
    lateral = _rest_lateral(rig, jnp.asarray(c.character.skeleton.offsets), rig.rest_quat_local)  # per foot, in its frame
    quat = c.truth.quat_local
    frames = quat.shape[0]
    for (_, _, foot), foot_lateral in zip(rig.limbs[2:], lateral):
        point = quat_from_axis_angle(jnp.broadcast_to(foot_lateral, (frames, 3)), jnp.full(frames, -2.0))
        quat = quat.at[:, foot].set(quat_mul(quat[:, foot], point))
    pointed = c.truth._replace(quat_local=quat)
    knees = [mid for _, mid, _ in rig.limbs[2:]]
    want = np.asarray(fk(c.character, pointed)[1])[:, knees]

    def knee_error(bind: Rig) -> np.ndarray:
        pose = solve(bind, targets_from_pose(c.character, pointed))
        return np.linalg.norm(np.asarray(fk(c.character, pose)[1])[:, knees] - want, axis=-1)

    _, leg_pos = fk(c.character, c.truth)
    root, knee, ankle = rig.limbs[2]
    thigh, shin = np.asarray(leg_pos[:, root] - leg_pos[:, knee]), np.asarray(leg_pos[:, ankle] - leg_pos[:, knee])
    bent = int(np.argmax(np.linalg.norm(np.cross(thigh, shin), axis=-1) / np.linalg.norm(thigh, axis=-1) / np.linalg.norm(shin, axis=-1)))
    assert (knee_error(rig) > 10.0).sum() >= 8  # measured 16 of 40 frames, 45 cm at worst
    with_bind = knee_error(make_rig(c.character, "bandai_namco", rest_quat_local=np.asarray(c.truth.quat_local[bent])))
    assert with_bind.max() < 4.5, with_bind.max()  # measured 3.8 cm (2.0 with the zero rotation's lateral axis, which other bone axes break)


def test_elbows_turn_with_the_hand_all_around_the_shoulder(bandai):
    """The elbow's side is the least rotation of a reference arm (forward and down, elbow
    back, down and out) onto the hand's direction, so it moves continuously wherever the hand
    goes except straight behind the head. The left hand sweeps a circle about its shoulder
    through an arm raised forward and up and one pushing back and down, where the part of a
    fixed pole hint across the arm vanishes (the old hint, behind the chest and a little down
    and out, turned the elbow half a turn about the arm there)."""
    c, rig = bandai, bandai.rig
    frames = c.targets.position.shape[0]  # the module's batch: no recompilation
    _, pos = fk(c.character, jax.tree.map(lambda x: x[0], c.pose))
    pos = np.asarray(pos, np.float64)
    (shoulder, elbow, _), (right_shoulder, _, _) = rig.limbs[:2]
    up = pos[rig.spine[-1]] - pos[rig.spine[0]]
    left = pos[shoulder] - pos[right_shoulder]
    forward = np.cross(left, up)
    forward, left = forward / np.linalg.norm(forward), left / np.linalg.norm(left)
    up = np.cross(forward, left)
    body = np.stack([forward, up, left])  # rows: the body's forward, up and the left arm's outward
    old_hint, behind_the_head = np.asarray([-1.0, -0.5, 0.5]) @ body, np.asarray([-1.0, 1.0, 0.0]) @ body
    old_hint /= np.linalg.norm(old_hint)
    across = np.cross(old_hint, behind_the_head)  # the circle through ±old_hint, 73° from behind the head
    across /= np.linalg.norm(across)
    angle = np.linspace(0.0, 2.0 * np.pi, frames, endpoint=False)[:, None]
    reach = 0.8 * sum(_lengths(rig, 0))
    hand = pos[shoulder] + reach * (np.cos(angle) * old_hint + np.sin(angle) * across)
    first = jax.tree.map(lambda x: jnp.broadcast_to(x[:1], x.shape), c.targets)
    swept = first._replace(position=first.position.at[:, 2].set(jnp.asarray(hand, jnp.float32)))
    _, got = fk(c.character, solve(rig, swept))
    got = np.asarray(got)
    np.testing.assert_allclose(got[:, shoulder], np.broadcast_to(pos[shoulder], (frames, 3)), atol=1e-3)
    np.testing.assert_allclose(got[:, rig.limbs[0][2]], hand, atol=END_TOL_CM)
    # The elbow's bend direction across the arm turns by about the sweep's 9° a step.
    arm = got[:, rig.limbs[0][2]] - got[:, shoulder]
    arm /= np.linalg.norm(arm, axis=-1, keepdims=True)
    bend = got[:, elbow] - got[:, shoulder]
    bend -= np.sum(bend * arm, axis=-1, keepdims=True) * arm
    bend /= np.linalg.norm(bend, axis=-1, keepdims=True)
    turns = np.degrees(np.arccos(np.clip(np.sum(bend * np.roll(bend, -1, axis=0), axis=-1), -1.0, 1.0)))
    assert turns.max() < 30.0, turns.max()  # measured 22.5° (the old hint: 50.6°)


def _with_twist_joints(case: Case) -> tuple[Character, np.ndarray, dict[str, str]]:
    """The case's skeleton with a twist joint halfway along every upper arm, forearm and thigh
    (as Daz Genesis has them: ``UpperArm_L → UpperArmTwist_L → LowerArm_L``); returns the
    character, each new joint's source joint (-1 for a twist joint) and the twist → limb
    joint names."""
    skeleton = case.character.skeleton
    offsets = np.asarray(skeleton.offsets, np.float64)
    split = {"LowerArm_L": "UpperArmTwist_L", "LowerArm_R": "UpperArmTwist_R", "Hand_L": "LowerArmTwist_L", "Hand_R": "LowerArmTwist_R"}
    split |= {"LowerLeg_L": "UpperLegTwist_L", "LowerLeg_R": "UpperLegTwist_R"}
    names, parents, new_offsets, source, index = [], [], [], [], {}
    for j, name in enumerate(skeleton.names):
        parent = index.get(skeleton.parents[j], -1)
        if name in split:  # the twist joint halfway along the bone, then the joint itself
            names.append(split[name]), parents.append(parent), new_offsets.append(offsets[j] / 2), source.append(-1)
            parent, offset = len(names) - 1, offsets[j] / 2
        else:
            offset = offsets[j]
        index[j] = len(names)
        names.append(name), parents.append(parent), new_offsets.append(offset), source.append(j)
    twisted = Skeleton(tuple(parents), tuple(names), np.asarray(new_offsets, np.float32))
    return Character.from_skeleton(twisted, "bandai_namco"), np.asarray(source), split


def test_twist_joints_inside_a_limb_are_held_at_rest_and_change_nothing(bandai):
    """A limb whose joints descend through twist joints (``RigSpec`` names the same three):
    the rig and ``refine_limbs`` hold the twist joints at rest and pose every other joint as on
    the skeleton without them; ``derive_rig_spec`` skips them by name."""
    from bezmotion.pipeline.authoring import derive_rig_spec

    character, source, split = _with_twist_joints(bandai)
    kept = np.flatnonzero(source >= 0)
    twists = np.flatnonzero(source < 0)
    rig = make_rig(character, "bandai_namco")
    assert all(len(a) == 1 and len(b) == 1 for a, b in rig.limb_between[:2]) and [len(b) for b in rig.limb_between[2]] == [1, 0]
    assert derive_rig_spec(character) == RIG_PRESETS["bandai_namco"]
    posed = solve(rig, bandai.targets)
    np.testing.assert_allclose(np.abs(np.asarray(posed.quat_local)[:, twists, 0]), 1.0, atol=1e-6)  # at rest
    _, pos = fk(character, posed)
    _, plain = fk(bandai.character, bandai.pose)
    np.testing.assert_allclose(np.asarray(pos)[:, kept], np.asarray(plain), atol=2e-3)
    # refine_limbs from a pose whose twist joints are turned 34° about their bones: it keeps
    # them and still lands.
    offsets = np.asarray(character.skeleton.offsets)
    child = [character.skeleton.parents.index(t) for t in twists]
    axis = offsets[child] / np.linalg.norm(offsets[child], axis=-1, keepdims=True)
    turn = jnp.asarray(np.concatenate([np.full((len(twists), 1), np.cos(0.3)), np.sin(0.3) * axis], axis=-1), jnp.float32)
    quat = jnp.asarray(np.asarray(bandai.truth.quat_local)[:, np.maximum(source, 0)]).at[:, twists].set(turn)
    start = Pose(bandai.truth.root_pos, quat)
    refined = jax.jit(jax.vmap(refine_limbs, in_axes=(None, 0, 0)))(rig, start, bandai.targets)
    np.testing.assert_array_equal(np.asarray(refined.quat_local[:, twists]), np.asarray(start.quat_local[:, twists]))
    _, pos = fk(character, refined)
    ends = np.asarray(character.characteristic[2:])
    assert np.linalg.norm(np.asarray(pos[:, ends] - bandai.targets.position[:, 2:]), axis=-1).max() < 10 * END_TOL_CM
    with pytest.raises(ValueError, match=r"joint 'UpperArmTwist_L' \(a child of 'UpperArm_L'\) does not descend from 'LowerArm_L'"):
        make_rig(character, _spec(left_arm=("UpperArm_L", "LowerArm_L", "UpperArmTwist_L")))


def test_elbows_bend_as_the_keys_around_the_frame_do(bandai):
    """``elbows_from_keys``: on the frames of the keys the rig's arms bend their elbows to the
    keys' side of the shoulder-to-hand line (the rig's fixed reference arm chooses its own);
    hands stay on their targets and the legs are untouched."""
    c = bandai
    frames = 31
    truth = jax.tree.map(lambda a: a[:frames], c.truth)
    targets = jax.tree.map(lambda a: a[:frames], c.targets)
    keys = jax.tree.map(lambda a: a[jnp.asarray([0, frames - 1])], truth)
    posed = jax.tree.map(lambda a: a[:frames], c.pose)
    turned = jax.jit(elbows_from_keys)(c.rig, posed, targets, keys)
    limbs = np.asarray(c.rig.limbs)

    def side(pose):  # (frames, arm, 3) the elbows' offsets across the shoulder-to-hand line (cm)
        _, pos = fk(c.character, pose)
        pos = np.asarray(pos, np.float64)
        reach = pos[:, limbs[:2, 2]] - pos[:, limbs[:2, 0]]
        reach /= np.linalg.norm(reach, axis=-1, keepdims=True)
        off = pos[:, limbs[:2, 1]] - pos[:, limbs[:2, 0]]
        return off - (off * reach).sum(-1, keepdims=True) * reach

    def angle(a, b):
        unit = lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True)  # noqa: E731
        return np.degrees(np.arccos(np.clip((unit(a) * unit(b)).sum(-1), -1.0, 1.0)))

    want, got, rig_own = side(truth), side(turned), side(posed)
    # On this walk the rig bends the right elbow 44–57° round the line from the mocap's; the
    # keys' side brings it within 5° on every frame (the keys' elbows are 3–7 cm off the line).
    assert angle(rig_own, want)[:, 1].min() > 40.0
    assert angle(got, want)[:, 1].max() < 6.0, angle(got, want)[:, 1].max()
    # The hands where the rig put them (on their targets where the arm reaches).
    hands = lambda pose: np.asarray(fk(c.character, pose)[1])[:, limbs[:2, 2]]  # noqa: E731
    np.testing.assert_allclose(hands(turned), hands(posed), atol=10 * END_TOL_CM)
    legs = limbs[2:].reshape(-1)
    np.testing.assert_allclose(np.asarray(turned.quat_local)[:, legs], np.asarray(posed.quat_local)[:, legs], atol=1e-5)
