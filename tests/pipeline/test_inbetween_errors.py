"""``inbetween`` rejects non-finite start and end poses, eagerly and inside a caller's jit.

Concrete poses are checked before compiling (``ValueError``); traced ones by
``eqx.error_if`` when the computation runs (the same message).
The BMM is tiny and untrained and the IK puts only the hips in place: plumbing, not motion.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.bmm.denoiser import BMMConfig, init_denoiser
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, Handles
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import HIPS
from bezmotion.geometry.rotations import quat_from_rot6d
from bezmotion.bezier import BezierLayout, tangent_from_velocity
from bezmotion.ik.protocol import Character, IKTargets, Pose, pose_from_motion, targets_from_pose
from bezmotion.pipeline import InbetweenOptions, Inbetweener
from bezmotion.pipeline.inbetweening import inbetween, key_velocities

TINY = BMMConfig.cpu(width=32, ff_width=64, num_heads=2, num_layers=1, dropout=0.0)
STEPS = 1  # DDIM steps: the checks run before sampling


def hips_only_ik(params: jax.Array, targets: IKTargets) -> Pose:
    """The hips where the targets put them, every other joint at ``params`` (local rotations)."""
    return Pose(targets.position[HIPS], params.at[1].set(quat_from_rot6d(targets.rot6d[HIPS])))  # Bandai-Namco hips: joint 1


@pytest.fixture(scope="module")
def case():
    """The bundled clip's frames 0 and 30 as start and end, a tiny BMM, no handles."""
    motion = read_bvh(DEMO_CLIP)
    character = Character.from_bvh(motion, "bandai_namco")
    frames = TINY.num_frames
    poses = pose_from_motion(character, motion.quat_local[:frames].astype(np.float32), motion.pos_local[:frames].astype(np.float32))
    start, end = jax.tree.map(lambda x: x[0], poses), jax.tree.map(lambda x: x[-1], poses)
    graphdef, params = init_denoiser(TINY, key=jax.random.key(0))
    stats = FeatureStats(jnp.zeros((6, 12), jnp.float32), jnp.full((6, 12), 50.0, jnp.float32))
    bmm = BezierMotionModel(params, stats, graphdef, TINY)
    rest = jnp.asarray(poses.quat_local[0])
    return bmm, character, rest, start, end


def nan_at(pose: Pose) -> Pose:
    return pose._replace(root_pos=pose.root_pos.at[1].set(jnp.nan))


def run(case, start, end, key_velocity=None):
    bmm, character, rest, _, _ = case
    keys = jax.tree.map(lambda a, b: jnp.stack([a, b]), start, end)
    model = Inbetweener(bmm, hips_only_ik, rest, character)
    return inbetween(model, keys, Handles.empty(), key=jax.random.key(1), options=InbetweenOptions(steps=STEPS), key_velocity=key_velocity)


@pytest.mark.parametrize("which", ["start", "end"])
def test_a_non_finite_pose_raises_a_value_error_naming_it(case, which):
    _, _, _, start, end = case
    start, end = (nan_at(start), end) if which == "start" else (start, nan_at(end))
    with pytest.raises(ValueError, match=f"key {0 if which == 'start' else 1} contains non-finite values"):
        run(case, start, end)


def test_inside_a_callers_jit_a_non_finite_start_pose_raises_when_it_runs(case):
    _, _, _, start, end = case
    jitted = jax.jit(lambda s, e: run(case, s, e).pose)
    finite = jitted(start, end)  # the check passes finite poses through unchanged
    assert np.isfinite(np.asarray(finite.quat_local)).all()
    # eqx.error_if raises equinox.EquinoxRuntimeError; plain jax.jit re-wraps it in a
    # runtime error whose type depends on JAX's dispatch path. The message survives.
    with pytest.raises((eqx.EquinoxRuntimeError, RuntimeError, ValueError), match="key 0 contains non-finite values"):
        jax.block_until_ready(jitted(nan_at(start), end))


def test_key_velocities_are_met_exactly_and_bad_ones_raise(case):
    """``key_velocity`` (e.g. :func:`key_velocities` of the frames around the keys) becomes
    the curves' tangents at the keys, exactly; a wrong shape or a NaN raises before compiling."""
    bmm, character, rest, start, end = case
    motion = read_bvh(DEMO_CLIP)
    around = pose_from_motion(character, motion.quat_local[[0, 1, 29, 30]].astype(np.float32), motion.pos_local[[0, 1, 29, 30]].astype(np.float32))
    velocity = key_velocities(character, around)
    position = targets_from_pose(character, around).position
    np.testing.assert_allclose(velocity, jnp.stack([position[1] - position[0], position[3] - position[2]]), atol=1e-5)
    result = run(case, start, end, velocity)
    layout = BezierLayout.from_controls(TINY.num_controls, TINY.stride)
    np.testing.assert_array_equal(result.joined_curves().ctrl_tangent[jnp.asarray([0, -1])], tangent_from_velocity(layout, velocity))
    run_with = lambda v: run(case, start, end, v)  # noqa: E731
    # The type checks of the test session may catch this one first (as for sample_curves).
    with pytest.raises((ValueError, TypeError), match="key_velocity"):
        run_with(velocity[0])
    with pytest.raises(ValueError, match="key_velocity contains infinite values"):
        run_with(velocity.at[1, 2, 0].set(jnp.inf))
    # NaN: a velocity not known (the end key's here): the start key's is kept, the model picks the end's.
    unknown = run_with(velocity.at[1].set(jnp.nan))
    tangent = unknown.joined_curves().ctrl_tangent
    assert np.isfinite(np.asarray(unknown.pose.quat_local)).all() and np.isfinite(np.asarray(tangent)).all()
    np.testing.assert_array_equal(tangent[0], tangent_from_velocity(layout, velocity)[0])
    assert not np.allclose(tangent[-1], tangent_from_velocity(layout, velocity)[1])


def test_checked_on_the_host_the_inbetweens_program_holds_no_host_callback(case):
    """XLA's persistent cache stores no program with a host callback; ``eqx.error_if`` is
    one. With concrete inputs ``inbetween`` checks them in a program of their own, so the
    in-between's compiles without them (and a caller's jit keeps them)."""
    from bezmotion.pipeline.inbetweening import _inbetween

    bmm, character, rest, start, end = case
    keys = jax.tree.map(lambda a, b: jnp.stack([a, b]), start, end)
    model = Inbetweener(bmm, hips_only_ik, rest, character)

    def text(checked: bool) -> str:
        program = functools.partial(_inbetween.__wrapped__, options=InbetweenOptions(steps=STEPS), key_velocity=None, checked=checked)
        return str(jax.make_jaxpr(program)(model, keys, Handles.empty(), jax.random.key(1)))

    assert "callback" in text(True)  # the in-program checks are what the cache cannot store
    assert "callback" not in text(False)
