"""Sampling the BMM (``bezmotion.bmm.sampling``): the constraints hit exactly, batching,
guidance, input errors, handles from frames, saving and loading, and composing inside a jit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import assert_trees_close, assert_trees_identical, trees_differ
from bmm.common import F, J, K, RESIDUAL, TINY, grid_errors, some_conditions

from bezmotion.evaluation.baselines import handle_interpolation
from bezmotion.bezier import BezierLayout, evaluate, tangent_from_velocity
from bezmotion.bmm.denoiser import apply_denoiser, init_denoiser
from bezmotion.bmm.sampling import BezierMotionModel, Handles, held_key_tangents, load_model, sample_curves, save_model
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
from bezmotion.evaluation.metrics import handles_error
from bezmotion._src.xla_options import inference_compiler_options


def test_sampling_hits_start_end_and_handles_exactly(model, motions, sampled):
    assert sampled.ctrl_pos.shape == (2, K, J, 3) and sampled.ctrl_tangent.shape == (2, K, J, 3)
    assert sampled.ctrl_rot6d.shape == (2, K, J, 6) and sampled.contacts.shape == (2, K, 2)
    assert all(np.all(np.isfinite(a)) for a in sampled)
    assert np.all((np.asarray(sampled.contacts) >= 0) & (np.asarray(sampled.contacts) <= 1))
    assert np.all(grid_errors(sampled, motions) == 0.0)
    h = motions.handles
    assert float(handles_error(sampled.ctrl_pos, h._replace(frame=h.frame // TINY.stride))) == 0.0
    # The padding slot is not a constraint: the curve does not go through it.
    assert np.linalg.norm(np.asarray(sampled.ctrl_pos[1, 1, 3]) - np.asarray(h.position[1, 2])) > 1e-3
    # Unconstrained points sit near the motion (the start's XZ offset is undone), not at the origin.
    hips_mid = np.asarray(sampled.ctrl_pos[:, 2, HIPS])
    assert np.all(np.abs(hips_mid[:, [0, 2]] - np.asarray(motions.start[:, HIPS])[:, [0, 2]]) < 100.0)
    # Same key, same curves; another key, other curves.
    again = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5)
    assert_trees_identical(again, sampled)
    other = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(22), steps=5)
    assert trees_differ(other.ctrl_tangent, sampled.ctrl_tangent)


def test_sampling_without_overwrite_does_not_enforce_the_constraints(model, motions, sampled):
    free = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, overwrite=False)
    errors = np.abs(grid_errors(free, motions))
    assert np.all(np.isfinite(errors)) and errors.max() > 1.0 and np.mean(errors == 0.0) < 0.5


def test_batched_sampling_equals_per_motion_calls(model, motions, sampled):
    keys = jax.random.split(jax.random.key(21), 2)
    for i in range(2):
        one = sample_curves(
            model, motions.start[i], motions.end[i], jax.tree.map(lambda a, i=i: a[i], motions.handles), key=keys[i], steps=5
        )
        assert one.ctrl_pos.shape == (K, J, 3)
        assert_trees_close(one, jax.tree.map(lambda a, i=i: a[i], sampled), tol=1e-5)


def test_guided_sampling_runs_and_still_hits_the_constraints(model, motions, sampled):
    guided = sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, guidance=2.5)
    assert all(np.all(np.isfinite(a)) for a in guided)
    assert np.all(grid_errors(guided, motions) == 0.0)
    # The unconditional pass pulls the sample away from the conditional one (by centimetres,
    # not by the rounding of a differently batched computation).
    assert np.max(np.abs(np.asarray(guided.ctrl_tangent) - np.asarray(sampled.ctrl_tangent))) > 0.5


def test_sample_curves_input_errors(model, motions):
    with pytest.raises((ValueError, TypeError)):  # TypeError: the jaxtyping hook of the test session
        sample_curves(model, motions.start[:, :5], motions.end[:, :5], motions.handles, key=jax.random.key(0))
    with pytest.raises(ValueError, match="batched like start"):
        sample_curves(model, motions.start, motions.end, jax.tree.map(lambda a: a[0], motions.handles), key=jax.random.key(0))


def test_handles_from_frames():
    h = Handles.from_frames(["left_hand", 5, "hips"], [6, 12, 24], np.arange(9.0).reshape(3, 3), config=TINY)
    np.testing.assert_array_equal(h.joint, [CHARACTERISTIC_JOINTS.index("left_hand"), 5, HIPS])
    np.testing.assert_array_equal(h.frame, [6, 12, 24])
    np.testing.assert_array_equal(h.position, np.arange(9.0).reshape(3, 3))
    assert h.position.dtype == jnp.float32 and bool(h.valid.all())
    empty = Handles.empty((2,))
    assert empty.position.shape == (2, 1, 3) and not bool(empty.valid.any())

    pos = np.zeros((1, 3))
    with pytest.raises(ValueError, match="unknown joint 'LeftHand'"):
        Handles.from_frames(["LeftHand"], [6], pos, config=TINY)
    with pytest.raises(ValueError, match="out of range"):
        Handles.from_frames([6], [6], pos, config=TINY)
    with pytest.raises(ValueError, match="one frame and one"):
        Handles.from_frames(["head", "hips"], [6, 12], pos, config=TINY)
    with pytest.raises(ValueError, match="one frame and one"):
        Handles.from_frames(["head"], [6, 12], pos, config=TINY)
    with pytest.raises((ValueError, TypeError)):  # TypeError: the jaxtyping hook of the test session
        Handles.from_frames(["head"], [6], np.zeros((1, 2)), config=TINY)
    with pytest.raises(ValueError, match="finite"):
        Handles.from_frames(["head"], [6], np.array([[0.0, np.nan, 1.0]]), config=TINY)


def test_save_and_load_model_round_trip(model, tmp_path, rng):
    save_model(tmp_path / "bmm", model)
    loaded = load_model(tmp_path / "bmm")
    assert loaded.config == model.config
    assert_trees_identical(loaded.params, model.params)
    assert_trees_identical(loaded.stats, model.stats)
    x = jnp.asarray(rng.normal(size=(K, F)), jnp.float32)
    cond = some_conditions(rng)
    assert_trees_identical(
        apply_denoiser(loaded.graphdef, loaded.params, x, jnp.int32(3), cond),
        apply_denoiser(model.graphdef, model.params, x, jnp.int32(3), cond),
    )
    with pytest.raises(FileNotFoundError, match="not a saved BMM"):
        load_model(tmp_path / "nothing")


def test_fresh_residual_model_samples_the_reference_curves(stats, motions):
    """A zero-initialised residual decoder starts training at the non-learned reference."""
    graphdef, params = init_denoiser(RESIDUAL, key=jax.random.key(5))
    fresh = BezierMotionModel(params, stats, graphdef, RESIDUAL)
    curves = sample_curves(fresh, motions.start, motions.end, motions.handles, key=jax.random.key(6), steps=5)
    h = motions.handles
    start_end = jnp.stack([motions.start, motions.end], axis=1)
    mask = np.zeros((2, K, J), bool)
    target = np.zeros((2, K, J, 3), np.float32)
    mask[:, [0, -1]] = True
    target[:, [0, -1]] = np.asarray(start_end)
    for b in range(2):
        for i in range(h.valid.shape[1]):
            if bool(h.valid[b, i]):
                mask[b, int(h.frame[b, i]) // 6, int(h.joint[b, i])] = True
                target[b, int(h.frame[b, i]) // 6, int(h.joint[b, i])] = np.asarray(h.position[b, i])
    ref_pos, ref_tangent = handle_interpolation(jnp.asarray(mask), jnp.asarray(target))
    np.testing.assert_allclose(curves.ctrl_pos, ref_pos, atol=1e-3)
    np.testing.assert_allclose(curves.ctrl_tangent, ref_tangent, atol=1e-3)
    assert np.all(np.asarray(curves.contacts) == 0.5)


def test_sample_curves_composes_inside_a_callers_jit(model, motions, sampled):
    options = inference_compiler_options()
    assert isinstance(options, tuple) and all(isinstance(k, str) for k, _ in options)
    outer = jax.jit(lambda s, e, h, k: sample_curves(model, s, e, h, key=k, steps=5))
    inside = outer(motions.start, motions.end, motions.handles, jax.random.key(21))
    # Different compiler options may order floating-point work differently: close, not identical.
    assert_trees_close(inside, sampled, tol=1e-4)
    assert np.all(grid_errors(inside, motions) == 0.0)
    # ... also when every input is a constant of the caller's computation.
    constants = jax.jit(lambda: sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5))()
    assert_trees_close(constants, sampled, tol=1e-4)


def test_key_tangents_are_conditions_hit_exactly_and_steer_the_sample(model, motions, sampled, demo_dataset):
    """``key_tangent`` puts the keys' velocities on the first and last control tangents
    exactly, and, written into x̂₀ at every step, changes what the model predicts between."""
    tangent = np.asarray(demo_dataset.ctrl_tangent[[0, 7]], np.float32)  # (2, controls, 6, 3)
    given = np.stack([-2.0 * tangent[:, 0], 3.0 * tangent[:, -1]], axis=1)  # not what the model would guess
    keyed = sample_curves(
        model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, key_tangent=jnp.asarray(given)
    )
    np.testing.assert_array_equal(np.asarray(keyed.ctrl_tangent)[:, [0, -1]], given)
    assert np.all(grid_errors(keyed, motions) == 0.0)  # positions still exact
    assert trees_differ(keyed.ctrl_pos[:, 1:-1], sampled.ctrl_pos[:, 1:-1])
    with pytest.raises((ValueError, TypeError), match="key_tangent|shape"):
        sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(0), key_tangent=jnp.asarray(given[:, :, :3]))


def test_a_handle_next_to_a_key_takes_precedence_over_that_keys_tangent(model, motions, demo_dataset):
    """A joint's handle within a stride of a key releases that key's tangent of that joint
    (:func:`held_key_tangents`): the model chooses it, so that the curve need not swing out
    at the next control point to reach the handle; every other key tangent stays exact."""
    frame = jnp.asarray([[1, 29, 0, 6, 24, 3], [5, 25, 30, 1, 2, 28]], jnp.int32)
    joint = jnp.asarray([[2, 3, 4, 5, 0, 1], [0, 1, 2, 3, 4, 5]], jnp.int32)
    valid = jnp.asarray([[True, True, True, True, True, False], [True] * 6])
    held = np.asarray(jax.vmap(lambda f, j, v: held_key_tangents(Handles(j, f, None, v), K, J, TINY.stride))(frame, joint, valid))
    expected = np.zeros((2, K, J), bool)
    expected[:, [0, -1]] = True
    expected[0, 0, 2] = expected[0, -1, 3] = False  # frames 1 and 29; 0, 6, 24 and the padding's 3 hold
    expected[1, 0, [0, 3, 4]] = expected[1, -1, [1, 5]] = False
    np.testing.assert_array_equal(held, expected)

    tangent = np.asarray(demo_dataset.ctrl_tangent[[0, 7]], np.float32)
    given = np.stack([-2.0 * tangent[:, 0], 3.0 * tangent[:, -1]], axis=1)  # (2, 2, J, 3)
    pos = np.asarray(motions.start)[0, 2] + np.asarray([0.0, 20.0, 0.0], np.float32)
    near = Handles(
        joint=jnp.asarray([[2]], jnp.int32), frame=jnp.asarray([[1]], jnp.int32), position=jnp.asarray([[pos]]), valid=jnp.asarray([[True]])
    )
    keyed = sample_curves(model, motions.start[:1], motions.end[:1], near, key=jax.random.key(3), steps=3, key_tangent=jnp.asarray(given[:1]))
    got = np.asarray(keyed.ctrl_tangent)[0][[0, -1]]
    released = np.zeros((2, J), bool)
    released[0, 2] = True
    np.testing.assert_array_equal(got[~released], given[0][~released])
    assert not np.allclose(got[released], given[0][released])
    layout = BezierLayout.from_controls(K, TINY.stride)
    dense = evaluate(layout, keyed.ctrl_pos[0].swapaxes(0, 1), keyed.ctrl_tangent[0].swapaxes(0, 1))  # (J, frames, 3)
    np.testing.assert_allclose(np.asarray(dense)[2, 1], pos, atol=1e-3)  # the handle, exactly


def test_tangent_from_velocity_moves_the_curve_at_that_velocity():
    layout = BezierLayout.from_controls(K, TINY.stride)
    velocity = jnp.asarray([1.5, -2.0, 0.25])  # cm/frame at control 0 and at the last control
    ctrl_tangent = jnp.zeros((K, 3)).at[0].set(tangent_from_velocity(layout, velocity)).at[-1].set(tangent_from_velocity(layout, velocity))
    eps, last = 1e-2, layout.num_frames - 1
    points = evaluate(layout, jnp.zeros((K, 3)), ctrl_tangent, jnp.asarray([0.0, eps, last - eps, last]))
    np.testing.assert_allclose(np.asarray(points[1] - points[0]) / eps, np.asarray(velocity), rtol=1e-2)
    np.testing.assert_allclose(np.asarray(points[3] - points[2]) / eps, np.asarray(velocity), rtol=1e-2)


def test_key_orientations_are_conditions_hit_exactly_and_steer_the_sample(model, motions, sampled, demo_dataset):
    """``key_rot6d`` puts the keys' orientations on the first and last control points exactly,
    and, written into x̂₀ at every step, changes what the model predicts between them."""
    rows = [0, 7]
    rot = np.asarray(demo_dataset.ctrl_rot6d[rows], np.float32)  # (2, controls, 6, 6)
    turned = np.stack([rot[:, -1], rot[:, 0]], axis=1)  # the end's orientation at the start and vice versa
    keyed = sample_curves(
        model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5, key_rot6d=jnp.asarray(turned)
    )
    np.testing.assert_array_equal(np.asarray(keyed.ctrl_rot6d)[:, [0, -1]], turned)
    assert np.all(grid_errors(keyed, motions) == 0.0)  # positions still exact
    assert trees_differ(keyed.ctrl_rot6d[:, 1:-1], sampled.ctrl_rot6d[:, 1:-1])
    with pytest.raises((ValueError, TypeError), match="key_rot6d|shape"):
        sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(0), key_rot6d=jnp.asarray(turned[:, 0]))
