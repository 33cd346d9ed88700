"""Handles at any frame: the minimum-norm projection onto off-grid
point constraints (``bezmotion.diffusion.projection``), ``Handles.from_frames`` at any
frame, the sampler hitting them, one compilation for any mix, and training and
evaluation drawing them.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import assert_trees_close, assert_trees_identical, lapack_calls
from bmm.common import J, K, RESIDUAL, TINY

from bezmotion.bezier import BezierLayout, basis, evaluate
from bezmotion.bmm.denoiser import init_denoiser
from bezmotion.evaluation.curves import CurveMetricsConfig, curve_metrics, make_eval_set, reference_curves
from bezmotion.bmm.features import (
    draw_handle_frames,
    draw_intermediate_frames,
    draw_intermediate_slots,
    from_tokens,
    handle_positions,
    inbetween_conditions,
    normalize_conditions,
    predict_x0,
    split_features,
    to_tokens,
)
from bezmotion.bmm.sampling import BezierMotionModel, Handles, sample_curves
from bezmotion.bmm.train import BMMTrainConfig, CurveArrays, init_bmm_train_state, make_bmm_train_step
from bezmotion.data.characteristic import HIPS
from bezmotion.diffusion.ddim import ddim_sample
from bezmotion.diffusion.projection import on_control_frame, project_off_grid, project_onto_handles
from bezmotion.diffusion.schedule import cosine_schedule
from flax import nnx

LAYOUT = BezierLayout.from_controls(K, 6)


def curve_at(ctrl_pos, ctrl_tangent, joint, frame):
    """The curve of ``joint`` at ``frame`` through ``bezmotion.bezier.evaluate`` (controls, joints, 3 layout)."""
    dense = evaluate(LAYOUT, jnp.moveaxis(ctrl_pos, -2, -3), jnp.moveaxis(ctrl_tangent, -2, -3))  # (..., J, frames, 3)
    return np.asarray(dense[..., int(joint), int(frame), :])


def random_curves(rng, scale=30.0):
    pos = jnp.asarray(rng.normal(size=(K, J, 3)) * scale + 100.0, jnp.float32)
    tangent = jnp.asarray(rng.normal(size=(K, J, 3)) * 5.0, jnp.float32)
    return pos, tangent


def test_on_control_frame():
    grid, control = on_control_frame(LAYOUT, jnp.asarray([0, 1, 6, 13, 29, 30, 24]))
    np.testing.assert_array_equal(grid, [True, False, True, False, False, True, True])
    np.testing.assert_array_equal(np.asarray(control)[np.asarray(grid)], [0, 1, 5, 4])


def test_projection_hits_off_grid_handles_composed_on_one_joint_and_every_joint(rng):
    pos, tangent = random_curves(rng)
    # Several frames of one joint (two in one segment, one beside a grid handle in the
    # same segment) and a handle on every joint, one identical duplicate, one padding slot.
    joint = jnp.asarray([2, 2, 2, 2, 0, 1, 3, 4, 5, 5, 1], jnp.int32)
    frame = jnp.asarray([13, 14, 12, 29, 1, 7, 22, 17, 5, 5, 8], jnp.int32)
    valid = jnp.asarray([True] * 10 + [False])
    target = jnp.asarray(rng.normal(size=(11, 3)) * 40.0 + 100.0, jnp.float32)
    target = target.at[9].set(target[8])  # the identical duplicate
    new_pos, new_tangent = jax.jit(functools.partial(project_onto_handles, LAYOUT))(pos, tangent, Handles(joint, frame, target, valid))
    for h in range(10):
        np.testing.assert_allclose(curve_at(new_pos, new_tangent, joint[h], frame[h]), target[h], atol=1e-4 * 150)
    # The grid handle is an overwrite, bit for bit; the padding slot is not hit.
    np.testing.assert_array_equal(new_pos[2, 2], target[2])
    assert np.linalg.norm(curve_at(new_pos, new_tangent, 1, 8) - np.asarray(target[10])) > 1.0
    # Minimum norm: nothing moves that no handle depends on (joint 0 only near frame 1).
    np.testing.assert_array_equal(new_pos[2:, 0], pos[2:, 0])
    np.testing.assert_array_equal(new_tangent[2:, 0], tangent[2:, 0])


def test_projection_is_the_minimum_norm_correction(rng):
    pos, tangent = random_curves(rng)
    fixed = jnp.zeros((K, J), bool).at[0].set(True).at[-1].set(True)
    joint, frame = jnp.asarray([3, 3], jnp.int32), jnp.asarray([9, 16], jnp.int32)
    target = jnp.asarray(rng.normal(size=(2, 3)) * 20.0 + 100.0, jnp.float32)
    mean, std = jnp.asarray(rng.normal(size=(J, 3)), jnp.float32), jnp.asarray(rng.uniform(1, 30, (J, 3)), jnp.float32)
    t_mean, t_std = jnp.asarray(rng.normal(size=(J, 3)), jnp.float32), jnp.asarray(rng.uniform(1, 5, (J, 3)), jnp.float32)
    p, t = project_off_grid(
        LAYOUT, pos, tangent, fixed, Handles(joint, frame, target, jnp.ones(2, bool)),
        pos_mean=mean, pos_std=std, tangent_mean=t_mean, tangent_std=t_std,
    )  # fmt: skip
    world = lambda p, t: (mean + std * p, t_mean + t_std * t)  # noqa: E731
    for h in range(2):
        np.testing.assert_allclose(curve_at(*world(p, t), joint[h], frame[h]), target[h], atol=2e-2)
    # Against a float64 NumPy minimum-norm solve per coordinate.
    w_pos, w_tan = (np.asarray(w, np.float64) for w in basis(LAYOUT, np.array([9.0, 16.0])))
    for d in range(3):
        a = np.concatenate([w_pos * float(std[3, d]), w_tan * float(t_std[3, d])], axis=1)
        a[:, [0, K - 1]] = 0.0  # the fixed start and end positions
        z = np.concatenate([np.asarray(pos[:, 3, d], np.float64), np.asarray(tangent[:, 3, d], np.float64)])
        current = w_pos @ (float(mean[3, d]) + float(std[3, d]) * z[:K]) + w_tan @ (float(t_mean[3, d]) + float(t_std[3, d]) * z[K:])
        expected = z + np.linalg.pinv(a) @ (np.asarray(target[:, d], np.float64) - current)
        np.testing.assert_allclose(np.concatenate([p[:, 3, d], t[:, 3, d]]), expected, atol=2e-4)


def test_the_curve_metric_makes_the_smallest_change_of_the_curve(rng):
    """``metric="curve"`` meets the same handles by the correction whose dense curve moves
    least (Σ over frames of the squared change): never more than the variables' minimum-norm
    one, and far less next to a fixed key tangent, where that one moves the next control
    point. Fixed variables stay bit for bit; no handle, no change; no LAPACK call."""
    pos, tangent = random_curves(rng)
    fixed = jnp.zeros((K, J), bool).at[0].set(True).at[-1].set(True)
    fixed_tangent = fixed
    joint = jnp.asarray([2, 2, 4, 5, 1], jnp.int32)
    frame = jnp.asarray([1, 16, 29, 9, 3], jnp.int32)  # next to the keys, and between
    target = jnp.asarray(rng.normal(size=(5, 3)) * 20.0 + 100.0, jnp.float32)
    valid = jnp.asarray([True, True, True, True, False])
    std, t_std = jnp.asarray(rng.uniform(10, 30, (J, 3)), jnp.float32), jnp.asarray(rng.uniform(1, 3, (J, 3)), jnp.float32)
    run = lambda metric: project_off_grid(  # noqa: E731
        LAYOUT, pos, tangent, fixed, Handles(joint, frame, target, valid), pos_std=std, tangent_std=t_std, fixed_tangent=fixed_tangent, metric=metric
    )
    world = lambda p, t: evaluate(LAYOUT, jnp.moveaxis(std * p, -2, -3), jnp.moveaxis(t_std * t, -2, -3))  # noqa: E731
    before = np.asarray(world(pos, tangent))
    change = {}
    for metric in ("variables", "curve"):
        p, t = run(metric)
        dense = np.asarray(world(p, t))  # (J, frames, 3)
        for h in range(4):
            np.testing.assert_allclose(dense[int(joint[h]), int(frame[h])], target[h], atol=2e-2)
        np.testing.assert_array_equal(np.asarray(p)[[0, -1]], np.asarray(pos)[[0, -1]])
        np.testing.assert_array_equal(np.asarray(t)[[0, -1]], np.asarray(tangent)[[0, -1]])
        change[metric] = ((dense - before) ** 2).sum(axis=(1, 2))  # per joint
    assert np.all(change["curve"] <= change["variables"] * (1 + 1e-4) + 1e-3), change
    assert change["curve"][2] < 0.5 * change["variables"][2], change  # frame 1 beside the held key tangent
    nothing = project_off_grid(LAYOUT, pos, tangent, fixed, Handles(joint, frame, target, jnp.zeros(5, bool)), pos_std=std, tangent_std=t_std, metric="curve")
    assert_trees_identical(nothing, (pos, tangent))
    assert lapack_calls(lambda: run("curve")) == set()
    with pytest.raises(ValueError, match="metric must be 'variables' or 'curve'"):
        run("dense")


def test_a_chain_with_its_shared_tangents_held_falls_apart_into_its_windows(rng):
    """Why a chain without a handle next to a shared key projects window by window (the
    sampler's ``lax.cond``): joined over two windows with the shared key's position and tangent
    held, the minimum-norm correction is each window's own, to float rounding."""
    (pos_a, tan_a), (pos_b, tan_b) = random_curves(rng), random_curves(rng)
    pos_b, tan_b = pos_b.at[0].set(pos_a[-1]), tan_b.at[0].set(tan_a[-1])  # one shared key
    keys = jnp.zeros((K, J), bool).at[0].set(True).at[-1].set(True)
    joint, frame = jnp.asarray([2, 4, 0], jnp.int32), jnp.asarray([9, 16, 23], jnp.int32)  # none within a stride of a key
    valid = jnp.ones(3, bool)
    target_a, target_b = (jnp.asarray(rng.normal(size=(3, 3)) * 20.0, jnp.float32) for _ in range(2))
    std, t_std = jnp.asarray(rng.uniform(10, 30, (J, 3)), jnp.float32), jnp.asarray(rng.uniform(1, 3, (J, 3)), jnp.float32)
    scales = dict(pos_std=std, tangent_std=t_std)
    alone_a = project_off_grid(LAYOUT, pos_a, tan_a, keys, Handles(joint, frame, target_a, valid), fixed_tangent=keys, **scales)
    alone_b = project_off_grid(LAYOUT, pos_b, tan_b, keys, Handles(joint, frame, target_b, valid), fixed_tangent=keys, **scales)
    whole = BezierLayout.from_controls(2 * K - 1, LAYOUT.stride)
    held = jnp.zeros((2 * K - 1, J), bool).at[jnp.asarray([0, K - 1, 2 * K - 2])].set(True)
    joined = project_off_grid(
        whole, jnp.concatenate([pos_a, pos_b[1:]]), jnp.concatenate([tan_a, tan_b[1:]]), held,
        Handles(
            jnp.concatenate([joint, joint]), jnp.concatenate([frame, frame + LAYOUT.num_frames - 1]),
            jnp.concatenate([target_a, target_b]), jnp.ones(6, bool),
        ),
        fixed_tangent=held, **scales,
    )  # fmt: skip
    apart = tuple(jnp.concatenate([a, b[1:]]) for a, b in zip(alone_a, alone_b))
    assert np.abs(np.asarray(alone_a[0]) - np.asarray(pos_a)).max() > 1.0  # the handles moved the curves
    assert_trees_close(joined, apart, tol=1e-4)


def test_grid_only_and_padding_change_nothing_bit_for_bit(rng):
    pos, tangent = random_curves(rng)
    fixed = jnp.asarray(rng.random((K, J)) < 0.3)
    # Grid handles (already overwritten by the caller) and padding holding garbage.
    joint = jnp.asarray([1, 4, 99, 2], jnp.int32)
    frame = jnp.asarray([12, 30, 13, -5], jnp.int32)
    target = jnp.asarray([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [np.nan] * 3, [1e9] * 3], jnp.float32)
    valid = jnp.asarray([True, True, False, False])
    std = jnp.asarray(rng.uniform(1, 30, (J, 3)), jnp.float32)
    out = project_off_grid(LAYOUT, pos, tangent, fixed, Handles(joint, frame, target, valid), pos_std=std, tangent_std=std)
    assert_trees_identical(out, (pos, tangent))
    # An off-grid handle with and without padding beside it: the same correction.
    one = project_onto_handles(LAYOUT, pos, tangent, Handles(joint[:1], jnp.asarray([13]), target[:1], valid[:1]))
    padded = project_onto_handles(LAYOUT, pos, tangent, Handles(jnp.asarray([1, 99, 3]), jnp.asarray([13, 7, 40]), target[jnp.asarray([0, 2, 3])], jnp.asarray([True, False, False])))
    assert_trees_close(padded, one, tol=1e-4)


@pytest.fixture(scope="module")
def model(stats):
    graphdef, params = init_denoiser(RESIDUAL, key=jax.random.key(12))
    # A trained decoder is not zero: give it weights so the network's own term shows.
    params["decoder"]["kernel"][...] = 0.05 * jnp.asarray(np.random.default_rng(1).normal(size=params["decoder"]["kernel"].shape), jnp.float32)
    return BezierMotionModel(params, stats, graphdef, RESIDUAL)


@pytest.fixture(scope="module")
def motion(demo_dataset):
    offset = np.array([150.0, 3.0, -230.0], np.float32)
    pos = demo_dataset.ctrl_pos[[0, 7]] + offset
    return jnp.asarray(pos[:, 0]), jnp.asarray(pos[:, -1]), pos


def test_sampler_hits_off_grid_handles_through_bezier_evaluate(model, motion):
    start, end, pos = motion
    handles = Handles(
        joint=jnp.asarray([[2, 2, 0, 5], [1, 5, 3, 3]], jnp.int32),
        frame=jnp.asarray([[13, 12, 1, 29], [7, 18, 23, 3]], jnp.int32),
        position=jnp.asarray(pos[:, 2, :4] + 9.0, jnp.float32),
        valid=jnp.asarray([[True, True, True, True], [True, True, True, False]]),
    )
    for foot_lock in (False, True):
        curves = sample_curves(model, start, end, handles, key=jax.random.key(3), steps=4, foot_lock=foot_lock)
        assert all(np.all(np.isfinite(a)) for a in curves)
        for b in range(2):
            for s in range(4):
                if bool(handles.valid[b, s]):
                    got = curve_at(curves.ctrl_pos[b], curves.ctrl_tangent[b], handles.joint[b, s], handles.frame[b, s])
                    np.testing.assert_allclose(got, handles.position[b, s], atol=1e-4, rtol=1e-6)
        np.testing.assert_array_equal(curves.ctrl_pos[0, 2, 2], handles.position[0, 1])  # grid: exact
        np.testing.assert_array_equal(curves.ctrl_pos[:, 0], start)
        np.testing.assert_array_equal(curves.ctrl_pos[:, -1], end)


def _old_sampler(model, start, end, control, joint, position, valid, key, steps):
    """A sampler without off-grid handles: overwrite of control positions only."""
    cfg, stats = model.config, model.stats
    translation = start[HIPS] * jnp.asarray([1.0, 0.0, 1.0], start.dtype)
    world = inbetween_conditions(cfg.num_frames, start, end, Handles(joint, control * cfg.stride, position, valid))
    normalized = normalize_conditions(stats, world, translation)
    mask, target = normalized.to_grid(cfg.num_controls, cfg.num_joints, cfg.stride)
    _, world_target = world.to_grid(cfg.num_controls, cfg.num_joints, cfg.stride)
    denoise = functools.partial(predict_x0, nnx.merge(model.graphdef, model.params), stats, conditions=normalized)

    def fix(x0):
        feats = from_tokens(x0)
        return to_tokens(feats.at[..., :3].set(jnp.where(mask[..., None], target, feats[..., :3])))

    x_T = jax.random.normal(key, (cfg.num_controls, cfg.frame_features))
    x0, _ = ddim_sample(lambda x, t: denoise(x, t), cosine_schedule(cfg.num_timesteps), x_T, steps=steps, overwrite=fix, has_aux=True)
    pos, tangent, _ = split_features(stats.denormalize(from_tokens(x0)))
    return jnp.where(mask[..., None], world_target, pos + translation), tangent


def test_sampler_has_no_lapack_calls(model, motion):
    """The projection at every DDIM step stays in plain XLA ops (``bezmotion._src.linalg``):
    jaxlib's batched LAPACK kernels can deadlock each other on a 2-core CPU."""
    start, end, pos = motion
    handles = Handles(
        joint=jnp.asarray([[2, 0]], jnp.int32).repeat(2, 0),
        frame=jnp.asarray([[13, 12]], jnp.int32).repeat(2, 0),
        position=jnp.asarray(pos[:, 2, :2], jnp.float32),
        valid=jnp.ones((2, 2), bool),
    )
    sample = lambda s, e, h: sample_curves(model, s, e, h, key=jax.random.key(0), steps=2)
    assert lapack_calls(sample, start, end, handles) == set()


def test_grid_handles_sample_as_before(model, motion):
    start, end, pos = motion
    control, joint = jnp.asarray([1, 2, 4], jnp.int32), jnp.asarray([2, 4, 0], jnp.int32)
    position, valid = jnp.asarray(pos[0, [1, 2, 4], [2, 4, 0]] + 5.0), jnp.asarray([True, True, False])
    key = jax.random.key(8)
    old_pos, old_tangent = jax.jit(functools.partial(_old_sampler, model, steps=5))(start[0], end[0], control, joint, position, valid, key)
    new = sample_curves(model, start[0], end[0], Handles(joint, control * 6, position, valid), key=key, steps=5)
    np.testing.assert_allclose(new.ctrl_pos, old_pos, rtol=0, atol=1e-4)
    np.testing.assert_allclose(new.ctrl_tangent, old_tangent, rtol=0, atol=1e-4)
    np.testing.assert_array_equal(new.ctrl_pos[[1, 2], [2, 4]], position[:2])


def test_padding_changes_nothing_in_the_sampler(model, motion):
    start, end, pos = motion
    real = Handles(jnp.asarray([2, 3], jnp.int32), jnp.asarray([13, 24], jnp.int32), jnp.asarray(pos[0, 2, :2] + 4.0), jnp.asarray([True, True]))
    pad = lambda joint, frame, position: jax.tree.map(  # noqa: E731
        lambda a, b: jnp.concatenate([a, b]), real, Handles(jnp.asarray(joint, jnp.int32), jnp.asarray(frame, jnp.int32), jnp.asarray(position, jnp.float32), jnp.zeros(2, bool))
    )
    a = sample_curves(model, start[0], end[0], pad([2, 0], [13, 5], [[1.0, 2.0, 3.0]] * 2), key=jax.random.key(4), steps=3)
    b = sample_curves(model, start[0], end[0], pad([99, -3], [-7, 17], [[np.nan] * 3, [1e8] * 3]), key=jax.random.key(4), steps=3)
    assert_trees_identical(a, b)
    c = sample_curves(model, start[0], end[0], real, key=jax.random.key(4), steps=3)
    assert_trees_close(a, c, tol=1e-3)


def test_a_batch_mixing_grid_and_off_grid_handles_compiles_once(model, motion):
    start, end, pos = motion
    traces = []

    @jax.jit
    def run(handles):
        traces.append(1)  # Python side effect: runs once per trace
        return sample_curves(model, start, end, handles, key=jax.random.key(0), steps=2)

    position, valid = jnp.asarray(pos[:, 3, :3] + 1.0), jnp.ones((2, 3), bool)
    joint = jnp.asarray([[0, 1, 2], [3, 4, 5]], jnp.int32)
    for frames in ([[6, 12, 18], [24, 6, 12]], [[13, 1, 29], [7, 8, 9]], [[6, 13, 24], [5, 12, 17]]):
        curves = run(Handles(joint, jnp.asarray(frames, jnp.int32), position, valid))
        for b in range(2):
            for s in range(3):
                got = curve_at(curves.ctrl_pos[b], curves.ctrl_tangent[b], joint[b, s], frames[b][s])
                np.testing.assert_allclose(got, position[b, s], atol=1e-4, rtol=1e-6)
    assert len(traces) == 1


def test_handles_from_frames_any_frame_and_bad_frames():
    pos = np.arange(12.0).reshape(4, 3)
    h = Handles.from_frames(["head", "head", "hips", 5], [1, 13, 29, np.int64(12)], pos, config=TINY)
    np.testing.assert_array_equal(h.frame, [1, 13, 29, 12])
    assert h.frame.dtype == jnp.int32
    assert Handles.from_frames(["head"], [13.0], pos[:1], config=TINY).frame.tolist() == [13]
    for bad in (0, 30, 31, -1, -6, 12.5, "12", True, float("nan")):
        with pytest.raises(ValueError, match=rf"strictly between 0 and 30.*got {bad!r}"):
            Handles.from_frames(["head"], [bad], pos[:1], config=TINY)


def test_handles_from_frames_conflicting_duplicates_raise():
    same = Handles.from_frames(["head", "head"], [13, 13], np.ones((2, 3)), config=TINY)
    assert same.frame.tolist() == [13, 13]
    Handles.from_frames(["head", "hips"], [13, 13], np.arange(6.0).reshape(2, 3), config=TINY)  # other joint: fine
    with pytest.raises(ValueError, match=r"two handles on head at frame 13 with different positions: \[0.0, 1.0, 2.0\] and \[3.0, 4.0, 5.0\]"):
        Handles.from_frames(["head", "head"], [13, 13], np.arange(6.0).reshape(2, 3), config=TINY)
    with pytest.raises(ValueError, match="two handles on hips at frame 12"):
        Handles.from_frames([0, "hips"], [12, 12.0], np.arange(6.0).reshape(2, 3), config=TINY)


def test_draw_handle_frames():
    control = jnp.tile(jnp.arange(1, K - 1, dtype=jnp.int32), 500)
    assert_trees_identical(draw_handle_frames(jax.random.key(0), control, LAYOUT, 0.0), control * 6)
    anywhere = np.asarray(draw_handle_frames(jax.random.key(0), control, LAYOUT, 1.0))
    assert anywhere.min() == 1 and anywhere.max() == 29 and len(set(anywhere.tolist())) == 29
    half = np.asarray(draw_handle_frames(jax.random.key(1), control, LAYOUT, 0.5))
    moved = half != np.asarray(control) * 6
    assert 0.35 < moved.mean() < 0.55  # some moves land on their own control frame


def test_draw_intermediate_frames():
    keys = jax.random.split(jax.random.key(2), 300)
    grid = jax.vmap(lambda k: draw_intermediate_frames(k, LAYOUT, J, 4, 1))(keys)
    slots = jax.vmap(lambda k: draw_intermediate_slots(k, K, J, 4, 1))(keys)
    assert_trees_identical(grid, (slots[0] * 6, slots[1], slots[2]))  # the paper's draw, in frames
    for frames, allowed in (("off_grid", set(range(1, 30)) - {6, 12, 18, 24}), ("any", set(range(1, 30)))):
        frame, joint, valid = map(np.asarray, jax.vmap(lambda k: draw_intermediate_frames(k, LAYOUT, J, 4, 1, frames=frames))(keys))
        assert set(frame.ravel().tolist()) == allowed
        np.testing.assert_array_equal(valid, grid[2])  # the same handle counts
        assert all(len(set(zip(f, j))) == 4 for f, j in zip(frame, joint))  # distinct (frame, joint) slots
    with pytest.raises(ValueError, match="handle frames must be one of"):
        draw_intermediate_frames(keys[0], LAYOUT, J, 4, frames="odd")


def test_training_with_off_grid_handles(demo_dataset, stats):
    config = BMMTrainConfig(batch_size=4, learning_rate=1e-3, off_grid_handles=0.5)
    graphdef, state = init_bmm_train_state(TINY, config, key=jax.random.key(0))
    step = jax.jit(make_bmm_train_step(graphdef, TINY, config, stats))
    state, metrics = step(state, CurveArrays.from_dataset(demo_dataset))
    assert all(np.isfinite(float(v)) for v in jax.tree.leaves(metrics))
    with pytest.raises(ValueError, match="off_grid_handles"):
        BMMTrainConfig(off_grid_handles=1.5)
    assert BMMTrainConfig().off_grid_handles == 0.0  # the paper's handles by default


def test_handle_positions_and_eval_set_off_grid(demo_dataset):
    ds = demo_dataset
    pos, tangent = jnp.asarray(ds.ctrl_pos[3]), jnp.asarray(ds.ctrl_tangent[3])
    got = handle_positions(LAYOUT, pos, tangent, jnp.asarray([2, 4]), jnp.asarray([13, 12]))
    np.testing.assert_allclose(got[0], curve_at(pos, tangent, 2, 13), atol=1e-4)
    np.testing.assert_array_equal(got[1], pos[2, 4])

    grid = make_eval_set(ds, key=jax.random.key(5))
    off = make_eval_set(ds, key=jax.random.key(5), handle_frames="off_grid")
    assert_trees_identical((off.handles.valid, off.rows), (grid.handles.valid, grid.rows))
    assert np.all(np.asarray(off.handles.frame) % 6 != 0)
    for b in range(len(off.rows)):
        for s in range(4):
            f, jj = int(off.handles.frame[b, s]), int(off.handles.joint[b, s])
            np.testing.assert_allclose(off.handles.position[b, s], curve_at(off.ctrl_pos[b], off.ctrl_tangent[b], jj, f), atol=1e-4)
    ref = reference_curves(off, off.handles, LAYOUT)
    config = CurveMetricsConfig(LAYOUT, ds.fps, floor_height=0.0)
    assert curve_metrics(config, ref, off, off.handles)["handles_error_cm"] < 1e-4
    assert curve_metrics(config, ref, off, off.handles_ood)["handles_error_cm"] > 1.0
    with pytest.raises(ValueError, match="handle_frames"):
        make_eval_set(ds, key=jax.random.key(5), handle_frames="sometimes")
