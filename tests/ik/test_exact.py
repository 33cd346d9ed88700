"""The exact IK stage (bezmotion.ik.exact): reaches reachable targets on both skeletons,
stays finite and reports the residual for unreachable ones, composes with the rig and
the learned IK, finite gradients; joint limits from motion and JSON; bad input.

Real data: the bundled Bandai-Namco ``DEMO_CLIP``; the LaFAN1-layout skeleton is the
synthetic one of ``conftest.synthetic_clip`` (made-up offsets and motion).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import synthetic_clip
from helpers import lapack_calls

from bezmotion.assets import BUNDLED_IK, DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.geometry.rotations import quat_angle, quat_from_axis_angle, quat_from_rot6d, quat_mul
import bezmotion.ik.exact as exact_module
from bezmotion.ik.exact import ExactIKFn, _errors, exact_ik
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protocol import Character, IKTargets, Pose, pose_from_motion, solve_frames, targets_from_pose
from bezmotion.ik.protores import load_ik_model, protores_ik_fn
from bezmotion.ik.rig import make_rig, rig_ik
from bezmotion.ik.temporal import FLIP_TURN, KEY_TURN

REACH_TOL_CM = 1e-3
HEAD, FEET = 1, [4, 5]  # characteristic joints
FRAMES = 8


# One compiled window solve per inner IK, frame count and key blend, shared by the tests below:
# their keys and targets are arguments here, where a closure over them compiled it again per test.
_solve_window = jax.jit(ExactIKFn.solve_window_with_residual, static_argnums=(0, 4))


_solve_frames = jax.jit(lambda fn, params, targets: jax.vmap(fn.with_residual, in_axes=(None, 0))(params, targets), static_argnums=0)


def _no_handles(targets: IKTargets) -> IKTargets:
    """``targets`` without handles, as an all-false ``pinned`` rather than ``None`` (another
    pytree): the solves compiled for targets with handles serve these too."""
    return targets._replace(pinned=jnp.zeros(targets.position.shape[:-1], bool))


def _with_residual(fn: ExactIKFn):
    """Every frame solved alone, with its residual (compiled once per inner IK and shape)."""
    return functools.partial(_solve_frames, fn)


@dataclasses.dataclass
class Case:
    character: Character
    truth: Pose  # (FRAMES, …) corpus poses, randomly bent
    fn: ExactIKFn
    params: object
    solve: object  # jitted, vmapped with_residual


def _bent(character: Character, quat: np.ndarray, pos: np.ndarray, seed: int) -> Pose:
    """Corpus poses with every joint turned by up to ~17° about a random axis: new but reachable targets."""
    rng = np.random.default_rng(seed)
    pose = pose_from_motion(character, jnp.asarray(quat, jnp.float32), jnp.asarray(pos, jnp.float32))
    axis = rng.normal(size=pose.quat_local.shape[:-1] + (3,))
    turn = quat_from_axis_angle(jnp.asarray(axis, jnp.float32), jnp.asarray(rng.uniform(0, 0.3, axis.shape[:-1]), jnp.float32))
    above = list(character.ancestors_of_hips())
    quat_local = quat_mul(pose.quat_local, turn)
    if above:
        quat_local = quat_local.at[:, above].set(pose.quat_local[:, above])
    return Pose(pose.root_pos, quat_local)


def _case(character: Character, preset: str, quat: np.ndarray, pos: np.ndarray, seed: int) -> Case:
    truth = _bent(character, quat, pos, seed)
    rig = make_rig(character, preset)
    # From the rig: far from the targets, where short steps (0.2 rad) also meet the orientations,
    # and a light prior (the default, 50, holds a learned IK's near pose: from the rig's it
    # leaves ~1 cm after 10 steps).
    fn, params = exact_ik(rig_ik, rig, character, iterations=10, max_turn=0.2, prior_weight=1.0)
    return Case(character, truth, fn, params, _with_residual(fn))


@pytest.fixture(scope="module")
def bandai() -> Case:
    motion = read_bvh(DEMO_CLIP)
    character = Character.from_bvh(motion, "bandai_namco")
    frames = np.linspace(0, motion.num_frames - 1, FRAMES).astype(int)
    return _case(character, "bandai_namco", motion.quat_local[frames], motion.pos_local[frames], 0)


@pytest.fixture(scope="module")
def lafan1_like() -> Case:
    skeleton, quat, root = synthetic_clip(60, seed=3)
    # Bone-like offsets (the synthetic ones are random vectors; a rig needs limbs of real proportion).
    character = Character.from_skeleton(skeleton, "lafan1")
    pos = np.broadcast_to(np.asarray(skeleton.offsets), quat.shape[:2] + (3,)).copy()
    pos[:, 0] = root
    frames = np.linspace(0, 59, FRAMES).astype(int)
    return _case(character, "lafan1", quat[frames], pos[frames], 1)


@pytest.mark.parametrize("name", ["bandai", "lafan1_like"])
def test_reaches_reachable_targets(request, name):
    case: Case = request.getfixturevalue(name)
    targets = targets_from_pose(case.character, case.truth)
    result = case.solve(case.params, targets)
    assert np.all(np.isfinite(result.pose.quat_local)) and np.all(np.isfinite(result.pose.root_pos))
    assert float(jnp.max(result.position_error)) < REACH_TOL_CM
    # The orientations are weighted, not hard, but reachable ones are met closely.
    assert float(jnp.max(result.rotation_error)) < np.radians(1.0)
    # The rig alone does not reach them all (the spine's bend is its own guess).
    rig_errors = jax.jit(lambda rig, t: _errors(case.character, jax.vmap(rig_ik, in_axes=(None, 0))(rig, t), t)[0])
    assert float(jnp.max(rig_errors(case.params.inner, targets))) > 10 * REACH_TOL_CM


def test_unreachable_targets_finite_with_residual(bandai):
    targets = targets_from_pose(bandai.character, bandai.truth)
    # The right hand 2 m above the head and the left foot 1 m below the floor.
    position = targets.position.at[:, 3].add(jnp.asarray([0.0, 200.0, 0.0])).at[:, 4].add(jnp.asarray([0.0, -100.0, 0.0]))
    result = bandai.solve(bandai.params, targets._replace(position=position))
    assert np.all(np.isfinite(result.pose.quat_local)) and np.all(np.isfinite(result.pose.root_pos))
    error = np.asarray(result.position_error)
    assert np.all(np.isfinite(error))
    assert np.all(error[:, 3] > 50.0) and np.all(error[:, 4] > 20.0)  # reported, not hidden
    # Stretched as far as the limbs allow: well beyond where the rig leaves them.
    assert np.all(error[:, 3] < 200.0)


def test_a_windows_frames_solved_together_are_each_solved_as_alone(bandai):
    """The frames' Levenberg–Marquardt steps run in lock step, one trust-region branch for the
    window (the second candidate evaluated where any frame needs it): each frame's pose is still
    its own solve, here with every other frame's hand out of reach (long, clipped steps there)."""
    targets = targets_from_pose(bandai.character, bandai.truth)
    targets = targets._replace(position=targets.position.at[::2, 3].add(jnp.asarray([0.0, 200.0, 0.0])))
    alone = bandai.solve(bandai.params, targets).pose  # each frame its own solve (a batch of one, mapped)

    @jax.jit
    def together(params, targets):
        start = jax.vmap(rig_ik, in_axes=(None, 0))(params.inner, targets)
        problems = jax.vmap(lambda s, t: exact_module._problem(params, s, t))(start, targets)
        return exact_module._solve(params, problems, params.iterations)

    pose = together(bandai.params, targets)
    np.testing.assert_allclose(np.asarray(pose.root_pos), np.asarray(alone.root_pos), atol=1e-3)
    assert float(jnp.max(quat_angle(pose.quat_local, alone.quat_local))) < 1e-4


def test_finite_gradients(bandai):
    targets = targets_from_pose(bandai.character, bandai.truth)
    one = jax.tree.map(lambda x: x[:2], targets)

    def loss(position):
        pose = jax.vmap(bandai.fn, in_axes=(None, 0))(bandai.params, one._replace(position=position))
        return jnp.sum(pose.quat_local**2 * jnp.arange(4.0)) + jnp.sum(pose.root_pos)

    grad = jax.jit(jax.grad(loss))(one.position)
    assert np.all(np.isfinite(grad)) and float(jnp.max(jnp.abs(grad))) > 0.0


def test_analytic_limit_jacobian_is_the_derivative_of_the_excess(bandai):
    """The joint limits' Jacobian (closed form: J_r⁻¹(ρ) J_r(δ) on the axes out of range)
    against forward-mode differentiation of the excess, at turns from 0 to ~2.5 rad."""
    limits = JointLimits.load(BUNDLED_IK / "joint_limits.json", bandai.character)
    _, params = exact_ik(rig_ik, None, bandai.character, limits=limits)
    start = bandai.truth.quat_local[0]
    free = len(exact_module._free_joints(bandai.character))
    rng = np.random.default_rng(5)
    for scale in (0.0, 1e-6, 0.3, 1.5):
        delta = jnp.asarray(rng.normal(size=(free, 3)) * scale, jnp.float32)
        excess, rel = exact_module._limit_excess(params, start, delta)
        jacobian = exact_module._limit_jacobian(params, rel, delta)
        full = jax.jacfwd(lambda d: exact_module._limit_excess(params, start, d)[0])(delta)  # (free, 3, free, 3)
        blocks = full[jnp.arange(free), :, jnp.arange(free), :]
        if scale > 0.3:
            assert float(jnp.sum(jnp.abs(excess) > 0)) > 5  # some axes out of range: the check is not vacuous
        np.testing.assert_allclose(jacobian, blocks, atol=2e-4, err_msg=f"turns of scale {scale}")


def test_no_lapack_calls(bandai):
    """The solve stays in plain XLA ops (``bezmotion._src.linalg``): jaxlib's batched LAPACK
    kernels can deadlock each other on a 2-core CPU."""
    targets = targets_from_pose(bandai.character, bandai.truth)
    assert lapack_calls(lambda t: bandai.solve(bandai.params, t), targets) == set()


def test_composes_with_learned_ik_and_window_solve(bandai):
    """On top of the learned IK (the bundled model), through the window solve the pipeline uses."""
    model = load_ik_model(BUNDLED_IK)
    limits = JointLimits.load(BUNDLED_IK / "joint_limits.json", bandai.character)
    # Bent poses (every joint up to 17° off the corpus pose) are far from what a learned IK
    # gives: 20 steps meet them to 10 µm (14 steps: 45 µm; the pipeline's 6 stop at ~2 mm).
    fn, params = exact_ik(protores_ik_fn, model, bandai.character, limits=limits, iterations=20)
    targets = _no_handles(targets_from_pose(bandai.character, bandai.truth))  # the window solve compiled here serves the next tests too
    result = _solve_window(fn, params, targets, None, 0)
    assert float(jnp.max(result.position_error)) < REACH_TOL_CM
    pose = jax.jit(lambda p, t: solve_frames(fn, p, t))(params, targets)  # the pipeline's entry point
    np.testing.assert_allclose(np.asarray(pose.quat_local), np.asarray(result.pose.quat_local), atol=1e-6)


def test_bad_settings(bandai):
    with pytest.raises(ValueError, match="position_wieght"):
        exact_ik(rig_ik, bandai.params.inner, bandai.character, position_wieght=1.0)
    with pytest.raises(ValueError, match="joint limits for 3 joints"):
        exact_ik(rig_ik, bandai.params.inner, bandai.character, limits=JointLimits.unlimited(3))
    # Out of range, NaN, or a fractional step count: named with the value.
    for setting, message in (
        ({"smoothing": 0.7}, r"smoothing=0.7: must lie in \[0.0, 0.5\]"),
        ({"handle_spread": 1.5}, r"handle_spread=1.5: must lie in \[0.0, 1.0\]"),
        ({"plant_weight": -1.0}, r"plant_weight=-1.0: must lie in \[0.0, ∞\)"),
        ({"robust_cm": float("nan")}, r"robust_cm=nan"),
        ({"max_turn": 0.0}, r"max_turn=0.0: must lie in \(0.0, ∞\)"),
        ({"window_passes": 0}, r"window_passes=0"),
        ({"iterations": 2.5}, r"iterations=2.5: must be an integer"),
    ):
        with pytest.raises(ValueError, match=message):
            exact_ik(rig_ik, bandai.params.inner, bandai.character, **setting)
    exact_ik(rig_ik, bandai.params.inner, bandai.character, smoothing=0.5, key_hold_decay=1.0, rotation_weight=0.0, iterations=0)


def test_pinned_targets_weigh_handle_weight_more(bandai):
    """A pinned target's (a handle's) position residual counts ``handle_weight`` times as much
    as the others': the cost of a pose missing the right hand by 3 cm and the head by 2 cm."""
    truth = jax.tree.map(lambda x: x[0], bandai.truth)
    targets = targets_from_pose(bandai.character, truth)
    position = targets.position.at[3].add(jnp.asarray([3.0, 0.0, 0.0])).at[1].add(jnp.asarray([0.0, 2.0, 0.0]))
    free = len(exact_module._free_joints(bandai.character))
    params = dataclasses.replace(bandai.params, handle_weight=7.0)

    def cost(pinned) -> float:
        scale = exact_module._position_scale(params, pinned, jnp.zeros(6, bool), jnp.float32)
        problem = exact_module._Problem(truth, position, exact_module.quat_from_rot6d(targets.rot6d), scale, jnp.asarray(0.0))
        return float(exact_module._evaluate(params, problem, jnp.zeros((free, 3)), jnp.zeros(3))[-1])

    w = params.position_weight**2
    assert cost(jnp.zeros(6, bool)) == pytest.approx(w * (9.0 + 4.0), rel=1e-4)
    assert cost(jnp.zeros(6, bool).at[3].set(True)) == pytest.approx(w * (49.0 * 9.0 + 4.0), rel=1e-4)


def test_pinned_target_moves_the_hips_when_the_limbs_cannot_reach(bandai):
    """The head's target 12 cm above it, pinned, on 8 corpus frames: the spine cannot stretch,
    so only translating the hips (and the legs' targets yielding) reaches it. The least-squares
    split at handle_weight 10 leaves the head under 1 cm off with the hips ~11 cm up. (With one
    trust-region factor for the whole step, the hips stayed within 0.3 cm and the head 11.8 cm
    off: the linearised step asked a twist axis for tens of radians and froze everything.)"""
    targets = targets_from_pose(bandai.character, bandai.truth)
    head = 1
    raised = targets._replace(
        position=targets.position.at[:, head, 1].add(12.0), pinned=jnp.zeros((FRAMES, 6), bool).at[:, head].set(True)
    )
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character)  # the pipeline's settings
    result = _with_residual(fn)(params, raised)
    assert float(jnp.max(result.position_error[:, head])) < 1.0
    hips_rise = result.pose.root_pos[:, 1] - jax.vmap(protores_ik_fn, in_axes=(None, 0))(params.inner, raised).root_pos[:, 1]
    assert float(jnp.min(hips_rise)) > 8.0


def test_zero_rotation_weight_solves_positions_only(bandai):
    """``rotation_weight=0`` drops the orientation rows (a 1/0 on the dual system's diagonal
    would make every step NaN, so the solve would silently return the inner IK's pose)."""
    targets = _no_handles(targets_from_pose(bandai.character, bandai.truth))  # at the default steps: the test above's compiled solve
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character, rotation_weight=0.0)
    result = _with_residual(fn)(params, targets)
    start = jax.vmap(protores_ik_fn, in_axes=(None, 0))(params.inner, targets)
    assert np.all(np.isfinite(result.pose.quat_local))
    # Met to within 0.05 cm in the default 6 steps; the inner IK's pose, which NaN steps would
    # return, misses by over 1 cm.
    assert float(jnp.max(result.position_error)) < 0.05
    assert float(jnp.max(exact_module._errors(bandai.character, start, targets)[0])) > 1.0


def test_window_solve_joins_the_keys_and_holds_their_neighbours(bandai):
    """With keys, the window solve puts them at the ends exactly, and the key hold trades a
    frame next to a key reaching its target for staying near the key: the right hand's
    target 20 cm up at frame 1 of 31 consecutive mocap frames is reached without the hold
    by turning the arm; the harder the hold, the less frame 1 turns away from the key, and the
    finish's ``key_turn`` caps even the free solve's turn there."""
    motion = read_bvh(DEMO_CLIP)
    window = slice(9, 40)  # 31 frames, as the pipeline's (the compiled solve of the tests below)
    truth = pose_from_motion(bandai.character, jnp.asarray(motion.quat_local[window]), jnp.asarray(motion.pos_local[window]))
    targets = targets_from_pose(bandai.character, truth)
    targets = _no_handles(targets._replace(position=targets.position.at[1, 3].add(jnp.asarray([0.0, 20.0, 0.0]))))
    keys = tuple(jax.tree.map(lambda x, i=i: x[i], truth) for i in (0, -1))
    # (finish_turn and key_turn off: they would ramp the free solve's snap to the jump, which is no handle.)
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character, finish_turn=0.0, key_turn=0.0)
    solve = lambda p, t: _solve_window(fn, p, t, keys, 6)  # noqa: E731

    def turn_next_to_start_deg(result) -> float:
        return float(jnp.max(quat_angle(result.pose.quat_local[0], result.pose.quat_local[1])) * 180 / np.pi)

    free, default, hard = (solve(dataclasses.replace(params, key_hold_weight=w), targets) for w in (0.0, params.key_hold_weight, 1e5))
    for result in (free, default, hard):
        np.testing.assert_array_equal(np.asarray(result.pose.quat_local[0]), np.asarray(keys[0].quat_local))
        np.testing.assert_array_equal(np.asarray(result.pose.root_pos[-1]), np.asarray(keys[1].root_pos))
    assert float(free.position_error[1, 3]) < 0.05  # without the hold, frame 1 reaches the jump (0.016 cm in 6 steps)
    turns = [turn_next_to_start_deg(r) for r in (free, default, hard)]
    # (With key_smoothing's 0.5 next to the keys the default hold already keeps frame 1 as
    # close as the hard one does, to within 0.01°.)
    assert turns[0] > turns[1] > turns[2] - 0.01 and turns[2] < 0.5 * turns[0], turns
    # The finish (its defaults) ramps even the free solve's turn out of the key down to key_turn.
    capped = solve(dataclasses.replace(params, key_hold_weight=0.0, finish_turn=FLIP_TURN, key_turn=KEY_TURN), targets)
    np.testing.assert_array_equal(np.asarray(capped.pose.quat_local[0]), np.asarray(keys[0].quat_local))
    assert turn_next_to_start_deg(capped) <= np.degrees(KEY_TURN) + 0.01 < turns[0], (turn_next_to_start_deg(capped), turns)
    assert float(hard.position_error[1, 3]) > 5.0  # held hard, it stays near the key

    # key_hold_decay: the hold d frames from the key is key_hold_weight · decay^(d − 1). The
    # same jump two frames after the key: no decay holds only frame 1, so frame 2 reaches
    # it; a slow one holds frame 2 nearly as hard as frame 1 (a traced weight: no recompile).
    later = targets._replace(position=targets.position.at[1, 3].add(jnp.asarray([0.0, -20.0, 0.0])).at[2, 3].add(jnp.asarray([0.0, 20.0, 0.0])))
    errors = [float(solve(dataclasses.replace(params, key_hold_weight=1e5, key_hold_decay=d), later).position_error[2, 3]) for d in (0.0, 0.9)]
    assert errors[0] < 0.01 < 5.0 < errors[1], errors


def test_key_smoothing_filters_only_the_frames_next_to_the_keys(bandai):
    """``key_smoothing`` weighs the between-pass filter on the frames within the key blend's
    frames of a key (here 6 of 31, the pipeline's); frames further in are solved from the same
    starts, so they come out bit for bit the same, while the frames next to the keys change (a
    traced weight: no recompile; the demo window's compiled solve of the tests below)."""
    motion = read_bvh(DEMO_CLIP)
    truth = pose_from_motion(bandai.character, jnp.asarray(motion.quat_local[:31]), jnp.asarray(motion.pos_local[:31]))
    targets = targets_from_pose(bandai.character, truth)
    targets = _no_handles(targets._replace(position=targets.position.at[:, 3].add(jnp.asarray([0.0, 15.0, 0.0]))))
    keys = tuple(jax.tree.map(lambda x, i=i: x[i], truth) for i in (0, -1))
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character)
    solve = lambda p, t: _solve_window(fn, p, t, keys, 6).pose  # noqa: E731
    assert params.key_smoothing == 0.5 != params.smoothing
    as_elsewhere, stronger = (solve(dataclasses.replace(params, key_smoothing=w), targets).quat_local for w in (params.smoothing, 0.5))
    # Frames 0–5 and 25–30 lie within 6 of a key; a frame's second-pass start reads its
    # neighbours' first-pass poses, so frames 7–23 start alike.
    np.testing.assert_array_equal(np.asarray(as_elsewhere[7:24]), np.asarray(stronger[7:24]))
    assert float(jnp.max(quat_angle(as_elsewhere[1:6], stronger[1:6]))) > 1e-3
    with pytest.raises(ValueError, match="key_smoothing=0.6"):
        exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character, key_smoothing=0.6)


def _head_raised(bandai: Case):
    """``(targets, raised, fn, params)``: 8 consecutive frames of the demo clip, and the same with
    the head's target 12 cm up and pinned: reaching it lifts the hips, and the feet give way.
    Every foot planted; 20 steps as in test_composes_with_learned_ik_and_window_solve (the
    same compiled solve)."""
    motion = read_bvh(DEMO_CLIP)
    truth = pose_from_motion(bandai.character, jnp.asarray(motion.quat_local[10:18]), jnp.asarray(motion.pos_local[10:18]))
    targets = targets_from_pose(bandai.character, truth)
    raised = targets._replace(
        position=targets.position.at[:, HEAD, 1].add(12.0), pinned=jnp.zeros((FRAMES, 6), bool).at[:, HEAD].set(True)
    )
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character, plant_step=100.0, handle_weight=10.0, iterations=20)
    return targets, raised, fn, params


def test_planted_feet_hold_their_targets_against_a_handle(bandai):
    """The head raised: planted feet (``plant_weight``) keep their targets closer, and the head
    gives up some of its reach instead. (The height weighing as the rest: the default lets a
    planted foot rise, test_planted_feet_rise_rather_than_slide.)"""
    _, raised, fn, params = _head_raised(bandai)
    loose, planted = (
        _solve_window(fn, dataclasses.replace(params, plant_weight=w, plant_height_scale=1.0), raised, None, 0) for w in (1.0, 10.0)
    )
    feet_loose, feet_planted = (float(jnp.mean(r.position_error[:, FEET])) for r in (loose, planted))
    assert feet_loose > 2.0 and feet_planted < 0.5 * feet_loose, (feet_loose, feet_planted)
    assert float(jnp.mean(planted.position_error[:, HEAD])) > float(jnp.mean(loose.position_error[:, HEAD]))


def test_planted_feet_rise_rather_than_slide(bandai):
    """The head raised: where the planted feet must give way, a light height
    (``plant_height_scale``) lets them rise, a heel lifting, and keeps them where they stand
    horizontally; at 1 they slide as much as they rise."""
    targets, raised, fn, params = _head_raised(bandai)

    def feet_miss(scale: float) -> tuple[float, float]:
        """The feet's mean horizontal miss and mean rise (cm) with ``plant_height_scale=scale``."""
        pose = _solve_window(fn, dataclasses.replace(params, plant_weight=10.0, plant_height_scale=scale), raised, None, 0).pose
        miss = targets_from_pose(bandai.character, pose).position[:, FEET] - targets.position[:, FEET]
        return float(jnp.mean(jnp.linalg.norm(miss[..., ::2], axis=-1))), float(jnp.mean(miss[..., 1]))

    (slide_even, rise_even), (slide_light, rise_light) = feet_miss(1.0), feet_miss(0.1)
    assert slide_light < 0.5 * slide_even, (slide_light, slide_even)
    assert rise_light > 2.0 * max(rise_even, 0.1), (rise_light, rise_even)


def test_a_still_runs_last_frame_is_held_like_the_rest(bandai):
    """A foot target still on frames 0–4 and moving from 4 to 5 on: frame 4, the still run's
    last (still against frame 3), is planted like the frames before it, so with the head pulled
    up its foot keeps its target as they do instead of jumping off it for one frame."""
    targets, raised, fn, params = _head_raised(bandai)
    right_foot = FEET[1]
    still = raised.position[0, right_foot]
    path = jnp.where(jnp.arange(FRAMES)[:, None] <= 4, still, still + jnp.asarray([0.0, 0.0, 3.0]) * (jnp.arange(FRAMES)[:, None] - 4))
    raised = raised._replace(position=raised.position.at[:, right_foot].set(path))
    pose = _solve_window(fn, dataclasses.replace(params, plant_step=0.25), raised, None, 0).pose
    miss = targets_from_pose(bandai.character, pose).position[:, right_foot] - path
    horizontal = np.asarray(jnp.linalg.norm(miss[:, ::2], axis=-1))
    assert horizontal[4] < 1.5 * horizontal[:4].max() + 0.05, horizontal
    assert horizontal[4] < 0.5 * horizontal[5], horizontal  # the first moving frame gives way


def test_planted_foot_height_is_light_only_upwards(bandai):
    """A planted foot 1 cm above its target costs ``plant_height_scale²`` of what 1 cm below
    it does (and of 1 cm to the side): the foot may rise, a heel lifting, but not sink into the floor."""
    character, right_foot = bandai.character, 5
    params = dataclasses.replace(bandai.params, plant_weight=10.0, plant_height_scale=0.1)
    start = jax.tree.map(lambda a: a[0], bandai.truth)
    here = targets_from_pose(character, start)
    planted = jnp.zeros(6, bool).at[right_foot].set(True)
    scale = exact_module._position_scale(params, jnp.zeros(6, bool), planted, jnp.float32)

    def cost(offset: list[float]) -> float:
        """The solve's cost at the start pose, the right foot's target moved by ``offset`` (cm)."""
        target = here.position.at[right_foot].add(jnp.asarray(offset))
        problem = exact_module._Problem(start, target, quat_from_rot6d(here.rot6d), scale, jnp.zeros(()))
        return float(exact_module._evaluate(params, problem, jnp.zeros((len(exact_module._free_joints(character)), 3)), jnp.zeros(3))[-1])

    weight = params.position_weight * params.plant_weight
    np.testing.assert_allclose(cost([0.0, -1.0, 0.0]), (0.1 * weight) ** 2, rtol=1e-3)  # the foot above its target
    np.testing.assert_allclose(cost([0.0, 1.0, 0.0]), weight**2, rtol=1e-3)  # below it
    np.testing.assert_allclose(cost([1.0, 0.0, 0.0]), weight**2, rtol=1e-3)  # beside it


@dataclasses.dataclass(frozen=True)
class _FlippingIK:
    """The learned IK, with joint ``arm`` twisted 149° on the frames whose hips target lies in
    ``(low, high)`` along z (the demo clip walks along z): a lasting flip."""

    arm: int
    low: float
    high: float

    def __call__(self, params, targets):
        pose = protores_ik_fn(params, targets)
        arm = self.arm
        flip = quat_from_axis_angle(jnp.asarray([1.0, 0.0, 0.0]), jnp.asarray(2.6))
        inside = (targets.position[0, 2] > self.low) & (targets.position[0, 2] < self.high)
        return pose._replace(quat_local=pose.quat_local.at[arm].set(jnp.where(inside, quat_mul(pose.quat_local[arm], flip), pose.quat_local[arm])))


def test_window_solve_ramps_a_lasting_flip_of_the_inner_ik(bandai):
    """The window solve limits the inner poses' turns (``limit_turns``) before solving: a learned
    IK that twists an arm 149° for five frames near the end key gives an exact IK turning it at
    most ~43° a frame (40° here), where without the limit (``spike_turn=0``) the smoothing
    only spreads the step over a few frames (62°)."""
    from bezmotion.evaluation.metrics import rotation_change_deg

    motion = read_bvh(DEMO_CLIP)
    truth = pose_from_motion(bandai.character, jnp.asarray(motion.quat_local[10:26]), jnp.asarray(motion.pos_local[10:26]))
    targets = targets_from_pose(bandai.character, truth)  # hips z: −539 … −519 cm; frames 9–13 flipped
    keys = tuple(jax.tree.map(lambda x, i=i: x[i], truth) for i in (0, -1))
    arm = bandai.character.skeleton.names.index("UpperArm_R")
    fn, params = exact_ik(_FlippingIK(arm, -527.5, -522.0), load_ik_model(BUNDLED_IK), bandai.character, finish_turn=0.0)  # the first ramp alone
    solve = lambda p, t: _solve_window(fn, p, t, keys, 6)  # noqa: E731
    limited, unlimited = solve(params, targets), solve(dataclasses.replace(params, spike_turn=0.0), targets)
    arm_turn = lambda r: float(jnp.max(rotation_change_deg(r.pose.quat_local)[:, arm]))  # noqa: E731
    assert arm_turn(unlimited) > 55.0 and arm_turn(limited) < 45.0, (arm_turn(unlimited), arm_turn(limited))
    # The targets are met as closely (within 0.5 cm: every frame of 16 lies near a key, held).
    mean, worst = (float(jnp.mean(limited.position_error)), float(jnp.max(limited.position_error)))
    assert mean <= float(jnp.mean(unlimited.position_error)) + 0.01 and worst <= float(jnp.max(unlimited.position_error)) + 0.05


def _demo_window_pulled(character: Character, head_cm: float, hips_cm: float) -> tuple[IKTargets, tuple[Pose, Pose]]:
    """The demo clip's first 31 frames as targets and keys, the head moved ``head_cm`` and the
    hips ``hips_cm`` up along a bump peaking at frame 6 (a curve through the handles), both
    pinned there (the hips only when moved)."""
    motion = read_bvh(DEMO_CLIP)
    truth = pose_from_motion(character, jnp.asarray(motion.quat_local[:31]), jnp.asarray(motion.pos_local[:31]))
    targets = targets_from_pose(character, truth)
    bump = jnp.exp(-0.5 * ((jnp.arange(31) - 6) / 3.0) ** 2)
    position = targets.position.at[:, 1, 1].add(head_cm * bump)
    pinned = jnp.zeros((31, 6), bool).at[6, 1].set(True)
    if hips_cm:
        position, pinned = position.at[:, 0, 1].add(hips_cm * bump), pinned.at[6, 0].set(True)
    keys = tuple(jax.tree.map(lambda x, i=i: x[i], truth) for i in (0, -1))
    return targets._replace(position=position, pinned=pinned), keys


def test_second_pass_starts_from_ramps_into_a_handle_frame(bandai, monkeypatch):
    """Between its passes the window solve ramps the frames next to a handle frame towards it
    (``limit_turns`` keeping the handle frames): head pinned 20 cm lower and hips 8 cm higher at
    frame 6 of the demo window (the curves bend there over a few frames), the first pass bends
    the chest at the handle frame alone (its neighbours, held near the key, weigh less). With
    the ramp the chest turns ~50° a frame at most; keeping only the keys, ~74°; the handles
    are met as closely."""
    from bezmotion.evaluation.metrics import rotation_change_deg

    targets, keys = _demo_window_pulled(bandai.character, head_cm=-20.0, hips_cm=8.0)
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character, handle_spread=0.0, finish_turn=0.0)  # the ramp alone

    def solve(window_solve):
        result = window_solve(fn, params, targets, keys, 6)
        return float(jnp.max(rotation_change_deg(result.pose.quat_local))), float(jnp.max(result.position_error[6, :2]))

    ramped, ramped_miss = solve(_solve_window)
    keys_only = exact_module.limit_turns
    monkeypatch.setattr(exact_module, "limit_turns", lambda pose, turn, anchors=None: keys_only(pose, turn))
    # A new function, traced again (jit caches by function), so the patched limit_turns is the one used.
    unramped, unramped_miss = solve(jax.jit(lambda *args: ExactIKFn.solve_window_with_residual(*args), static_argnums=(0, 4)))
    assert unramped > 65.0 and ramped < 55.0, (unramped, ramped)
    assert ramped_miss <= unramped_miss + 0.02, (ramped_miss, unramped_miss)


def test_finish_ramps_every_turn_into_the_handle_frames(bandai):
    """``finish_turn``: after the last pass no joint turns more than it in one frame; the handle
    frames and the keys are kept, so the handles are met exactly as without it. Head pinned 30 cm
    lower and hips 12 cm higher at frame 6 of the demo window: a joint turns ~57° a frame into
    the handle frame without the finish, 43° with it."""
    from bezmotion.evaluation.metrics import rotation_change_deg

    targets, keys = _demo_window_pulled(bandai.character, head_cm=-30.0, hips_cm=12.0)
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character)
    solve = lambda p: _solve_window(fn, p, targets, keys, 6)  # noqa: E731
    finished, raw = solve(params), solve(dataclasses.replace(params, finish_turn=0.0))
    largest = lambda r: float(jnp.max(rotation_change_deg(r.pose.quat_local)))  # noqa: E731
    assert largest(raw) > 50.0 and largest(finished) <= np.degrees(params.finish_turn) + 1e-3, (largest(raw), largest(finished))
    for kept in (0, 6, 30):
        np.testing.assert_array_equal(np.asarray(finished.pose.quat_local[kept]), np.asarray(raw.pose.quat_local[kept]))
    np.testing.assert_array_equal(np.asarray(finished.position_error[6]), np.asarray(raw.position_error[6]))


def test_handle_spread_weighs_a_handles_neighbours_more(bandai):
    """``handle_spread``: a joint ``d`` frames from its handle weighs ``handle_weight^(spread^d)``
    (2.2× next to it at 0.25, 1.2× two frames away, 1 where the exponent falls under 0.05),
    the handle itself ``handle_weight``, other joints and 0 unchanged; the neighbours of an OOD
    head handle then lie nearer their curve."""
    pinned = jnp.zeros((12, 6), bool).at[6, 1].set(True)
    near = np.asarray(exact_module._near_handles(pinned, 0.25, jnp.float32))
    np.testing.assert_allclose(near[[4, 5, 6, 7, 8], 1], [0.0625, 0.25, 0.0, 0.25, 0.0625])
    assert not near[[0, 1, 2, 3, 9, 10, 11], 1].any() and not near[:, [0, 2, 3, 4, 5]].any()
    assert not np.asarray(exact_module._near_handles(pinned, 0.0, jnp.float32)).any()
    everywhere = np.asarray(exact_module._near_handles(pinned, 1.0, jnp.float32))  # 1: every frame of the handle's joint
    assert everywhere[np.arange(12) != 6, 1].all() and not everywhere[:, [0, 2, 3, 4, 5]].any()
    _, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character)
    scale = exact_module._position_scale(params, pinned[5], jnp.zeros(6, bool), jnp.float32, jnp.asarray(near[5]))
    np.testing.assert_allclose(np.asarray(scale[:, 0]), [1.0, 25.0**0.25, 1.0, 1.0, 1.0, 1.0], rtol=1e-6)

    targets, keys = _demo_window_pulled(bandai.character, head_cm=-20.0, hips_cm=0.0)
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character)
    solve = lambda p: _solve_window(fn, p, targets, keys, 6)  # noqa: E731
    off, spread = solve(dataclasses.replace(params, handle_spread=0.0)), solve(params)  # the default: 0.25
    neighbours = lambda r: float(jnp.mean(r.position_error[jnp.asarray([4, 5, 7, 8]), 1]))  # noqa: E731
    assert neighbours(spread) < neighbours(off) - 0.05, (neighbours(off), neighbours(spread))
    assert float(spread.position_error[6, 1]) < 0.05


def test_robust_loss_lets_a_far_unpinned_target_go_and_keeps_near_ones(bandai):
    """``robust_cm``: beyond it an unpinned position costs Huber's loss, so a left-hand target
    80 cm out of reach no longer drags the rest of the body off its targets; reachable
    targets, and a pinned far one, are solved as in least squares. (Planted feet stay least
    squares too: ``test_planted_feet_hold_their_targets_against_a_handle`` runs at the default.)"""
    targets = targets_from_pose(bandai.character, bandai.truth)
    left_hand, others = 2, [0, 1, 3, 4, 5]
    far = _no_handles(targets._replace(position=targets.position.at[:, left_hand, 0].add(80.0)))
    fn, params = exact_ik(protores_ik_fn, load_ik_model(BUNDLED_IK), bandai.character, robust_cm=0.0)  # least squares
    robust = dataclasses.replace(params, robust_cm=5.0)
    solve = _with_residual(fn)
    plain_far, robust_far = solve(params, far), solve(robust, far)
    dragged, kept = (float(jnp.mean(r.position_error[:, others])) for r in (plain_far, robust_far))
    assert kept < 0.5 * dragged and dragged > 0.5, (dragged, kept)
    assert float(jnp.mean(robust_far.position_error[:, left_hand])) > float(jnp.mean(plain_far.position_error[:, left_hand]))
    # Reachable targets: the same poses (the learned IK starts a few cm off, so the first steps
    # differ slightly) and the targets met as closely.
    near = _no_handles(targets)
    plain_near, robust_near = solve(params, near), solve(robust, near)
    np.testing.assert_allclose(robust_near.pose.quat_local, plain_near.pose.quat_local, atol=2e-3)
    assert float(jnp.max(robust_near.position_error)) < 2 * float(jnp.max(plain_near.position_error)) + 1e-3
    # Pinned, the far target stays least squares: reached at least as closely (the unpinned
    # joints it drags far off give way more easily).
    pinned = far._replace(pinned=far.pinned.at[:, left_hand].set(True))
    reach = [float(jnp.mean(solve(p, pinned).position_error[:, left_hand])) for p in (params, robust)]
    assert reach[1] <= reach[0] + 1e-3, reach
    # The cost beyond the threshold is Huber's: 2·5·20 − 5² per cm² for a 20 cm miss.
    truth = jax.tree.map(lambda x: x[0], bandai.truth)
    one = targets_from_pose(bandai.character, truth)
    scale = exact_module._position_scale(robust, jnp.zeros(6, bool), jnp.zeros(6, bool), jnp.float32)
    problem = exact_module._Problem(
        truth, one.position.at[left_hand, 1].add(20.0), exact_module.quat_from_rot6d(one.rot6d), scale, jnp.asarray(0.0), jnp.full((6, 1), 5.0)
    )
    free = len(exact_module._free_joints(bandai.character))
    cost = float(exact_module._evaluate(robust, problem, jnp.zeros((free, 3)), jnp.zeros(3))[-1])
    assert cost == pytest.approx(robust.position_weight**2 * (2 * 5.0 * 20.0 - 25.0), rel=1e-4)
