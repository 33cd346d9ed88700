"""The BMM's curve-level evaluation (``bezmotion.evaluation.curves``) and the reference and
metrics it reports (``bezmotion.evaluation.baselines``, ``bezmotion.evaluation.metrics``), worked out by hand;
the LaFAN1 experiment end to end.
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import SHARED_DATA, assert_trees_identical, load_experiment, requires_shared
from bmm.common import J, K

from bezmotion.evaluation.baselines import handle_interpolation, interpolation_through_points
from bezmotion.bezier import BezierLayout
from bezmotion.bmm.features import inbetween_conditions
from bezmotion.evaluation.curves import (
    CurveMetricsConfig,
    curve_metrics,
    dense_positions,
    make_eval_set,
    reference_curves,
    sample_in_chunks,
)
from bezmotion.bmm.sampling import SampledCurves
from bezmotion.data.characteristic import FEET
from bezmotion.evaluation.metrics import contact_accuracy, foot_skating_ratio, handles_error, mean_position_error
from bezmotion.handles import Handles


LAYOUT = BezierLayout.from_controls(K, 6)


def test_handle_interpolation_by_hand():
    target = jnp.asarray(np.random.default_rng(3).normal(size=(K, 2, 3)), jnp.float32)
    mask = jnp.zeros((K, 2), bool).at[0].set(True).at[-1].set(True).at[3, 0].set(True)
    pos, tangent = handle_interpolation(mask, target)
    p, tg = np.asarray(pos, np.float64), np.asarray(target, np.float64)
    for k, j in zip(*np.nonzero(np.asarray(mask)), strict=True):
        np.testing.assert_array_equal(pos[k, j], target[k, j])  # exact through the known points
    # Joint 0: known at 0, 3, 5 → linear in control index on each side.
    np.testing.assert_allclose(p[1, 0], tg[0, 0] + (tg[3, 0] - tg[0, 0]) / 3, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(p[2, 0], tg[0, 0] + 2 * (tg[3, 0] - tg[0, 0]) / 3, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(p[4, 0], (tg[3, 0] + tg[5, 0]) / 2, rtol=1e-5, atol=1e-6)
    # Joint 1: known only at the ends.
    for k in range(1, 5):
        np.testing.assert_allclose(p[k, 1], tg[0, 1] + k * (tg[5, 1] - tg[0, 1]) / 5, rtol=1e-5, atol=1e-6)
    # Catmull-Rom tangents, one-sided at the ends.
    t_ref = np.concatenate([(p[1:2] - p[:1]) / 3, (p[2:] - p[:-2]) / 6, (p[-1:] - p[-2:-1]) / 3])
    np.testing.assert_allclose(tangent, t_ref, rtol=1e-5, atol=1e-5)
    # Batched.
    bpos, _ = handle_interpolation(jnp.stack([mask, mask]), jnp.stack([target, target + 1.0]))
    np.testing.assert_allclose(bpos[1], pos + 1.0, rtol=1e-5, atol=1e-5)


def _slots(frames, joints, positions):
    """Condition slots of two joints (:func:`inbetween_conditions`): both keys, then the
    handles at ``frames``; ``positions``: the start's two, the end's two, the handles'."""
    p = jnp.asarray(positions, jnp.float32)
    return inbetween_conditions(31, p[:2], p[2:4], Handles(jnp.asarray(joints, jnp.int32), jnp.asarray(frames, jnp.int32), p[4:], jnp.ones(len(frames), bool)))


def test_interpolation_through_points_on_the_grid_and_between():
    """On control frames both ways are handle_interpolation; between them both meet the
    condition, and "linear" interpolates through it in frame: on a motion that turns at
    frame 13 (a tent), its curve stays near the motion, where the projection's bump does not."""
    rng = np.random.default_rng(4)
    keys = rng.normal(size=(4, 3)) * 20.0
    grid = _slots([12], [0], [*keys, [5.0, 60.0, -3.0]])
    mask = jnp.zeros((K, 2), bool).at[0].set(True).at[-1].set(True).at[2, 0].set(True)
    target = jnp.zeros((K, 2, 3)).at[0].set(keys[[0, 1]]).at[-1].set(keys[[2, 3]]).at[2, 0].set(jnp.asarray([5.0, 60.0, -3.0]))
    expected = handle_interpolation(mask, target)
    for way in ("projection", "linear"):
        pos, tangent, on_grid = interpolation_through_points(LAYOUT, grid, 2, off_grid=way)
        np.testing.assert_array_equal(on_grid, mask)
        np.testing.assert_allclose(pos, expected[0], atol=1e-5)
        np.testing.assert_allclose(tangent, expected[1], atol=1e-5)
    # The tent: joint 0 rises 60 cm linearly to frame 13 and falls back by frame 30; joint 1 rests.
    frames = np.arange(31)
    tent = 60.0 * np.minimum(frames / 13, (30 - frames) / 17)
    motion = np.zeros((31, 2, 3))
    motion[:, 0, 1] = tent
    between = _slots([13], [0], [motion[0, 0], motion[0, 1], motion[30, 0], motion[30, 1], motion[13, 0]])
    error = {}
    for way in ("projection", "linear"):
        pos, tangent, _ = interpolation_through_points(LAYOUT, between, 2, off_grid=way)
        dense = np.asarray(dense_positions(LAYOUT, pos, tangent))
        np.testing.assert_allclose(dense[13, 0], motion[13, 0], atol=1e-4)  # the condition, met
        np.testing.assert_allclose(dense[:, 1], 0.0, atol=1e-6)  # the other joint untouched
        error[way] = float(np.mean(np.abs(dense[:, 0, 1] - tent)))
    assert error["linear"] < 0.25 * error["projection"], error  # 0.96 against 17.3 cm (mean over the frames)
    with pytest.raises(ValueError, match="'bump'"):
        interpolation_through_points(LAYOUT, between, 2, off_grid="bump")


def test_handles_error_by_hand():
    ctrl = jnp.zeros((K, J, 3)).at[4, 2].set(jnp.asarray([1.0, 1.0, 1.0]))
    control = jnp.asarray([2, 4, 1], jnp.int32)
    joint = jnp.asarray([1, 2, 0], jnp.int32)
    position = jnp.asarray([[3.0, 4.0, 0.0], [1.0, 1.0, 1.0], [100.0, 0.0, 0.0]])
    slots = lambda valid: Handles(joint, control, position, jnp.asarray(valid))  # noqa: E731
    assert float(handles_error(ctrl, slots([True, True, False]))) == pytest.approx(2.5)
    assert float(handles_error(ctrl, slots([True, True, True]))) == pytest.approx(35.0)
    assert float(handles_error(ctrl, slots([False] * 3))) == 0.0


def test_foot_skating_ratio_by_hand():
    frames, fps = 11, 30.0
    x = np.arange(frames) * 1.0  # 1 cm per frame = 30 cm/s > 7.5 cm/s

    def feet(left_y=1.0, right_y=1.0, speed=1.0, axis=0):
        f = np.zeros((frames, 2, 3))
        f[:, :, axis] = (x * speed)[:, None]
        f[:, 0, 1] += left_y
        f[:, 1, 1] += right_y
        return jnp.asarray(f, jnp.float32)

    assert float(foot_skating_ratio(feet(), fps)) == 1.0  # both low and fast
    assert float(foot_skating_ratio(feet(left_y=20.0), fps)) == 0.0  # one foot lifted
    assert float(foot_skating_ratio(feet(speed=0.1), fps)) == 0.0  # 3 cm/s: slow
    assert float(foot_skating_ratio(feet(axis=2), fps)) == 1.0  # Z is horizontal too
    assert float(foot_skating_ratio(feet(speed=0.1), 300.0)) == 1.0  # 30 cm/s at 300 fps
    assert float(foot_skating_ratio(feet(left_y=21.0, right_y=21.0), fps, floor_height=20.0)) == 1.0
    half = np.array(feet())
    half[6:, :, 0] = half[5, :, 0]  # stops after frame 5: 5 of 10 steps skate
    assert float(foot_skating_ratio(jnp.asarray(half), fps)) == pytest.approx(0.5)
    # Only one foot sliding is not skating.
    one = np.array(feet())
    one[:, 1, 0] = 0.0
    assert float(foot_skating_ratio(jnp.asarray(one), fps)) == 0.0


def test_foot_skating_ratio_heights_from_other_feet():
    """``heights_from``: another motion's feet decide which frames are on the floor, the
    speeds stay the feet's own; a foot sliding 20 cm up counts where the other's is down."""
    frames, fps = 11, 30.0
    sliding = np.zeros((frames, 2, 3), np.float32)
    sliding[:, :, 0] = np.arange(frames)[:, None]  # 30 cm/s
    lifted = sliding.copy()
    lifted[:, 0, 1] = 20.0  # the left foot 20 cm up
    on_floor = np.zeros_like(sliding)  # still, on the floor
    assert float(foot_skating_ratio(jnp.asarray(lifted), fps)) == 0.0
    assert float(foot_skating_ratio(jnp.asarray(lifted), fps, heights_from=jnp.asarray(on_floor))) == 1.0
    assert float(foot_skating_ratio(jnp.asarray(sliding), fps, heights_from=jnp.asarray(lifted))) == 0.0
    assert float(foot_skating_ratio(jnp.asarray(on_floor), fps, heights_from=jnp.asarray(sliding))) == 0.0  # still feet never skate
    # Mismatched frames: jaxtyping's check where it is on (the tests), else the function's own.
    with pytest.raises((TypeError, ValueError), match="heights_from"):
        foot_skating_ratio(jnp.asarray(sliding), fps, heights_from=jnp.asarray(sliding[1:]))


def test_contact_accuracy_and_mean_position_error():
    prob = jnp.asarray([[0.7, 0.2], [0.4, 0.9]])
    true = jnp.asarray([[True, False], [True, False]])
    assert float(contact_accuracy(prob, true)) == pytest.approx(0.5)
    pred = jnp.zeros((2, 3, 1, 3)).at[0, 0, 0].set(jnp.asarray([3.0, 4.0, 0.0]))
    assert float(mean_position_error(pred, jnp.zeros((2, 3, 1, 3)))) == pytest.approx(5.0 / 6.0)


def test_ground_truth_metrics_report_the_mocap_and_its_fitted_curves(demo_dataset, eval_set):
    from bezmotion.evaluation.curves import ground_truth_metrics

    config = CurveMetricsConfig(BezierLayout.from_controls(K, 6), demo_dataset.fps, 0.0)
    gt = ground_truth_metrics(config, eval_set)
    fitted = SampledCurves(eval_set.ctrl_pos, eval_set.ctrl_tangent, jnp.zeros((*eval_set.ctrl_pos.shape[:-1], 6)), eval_set.ctrl_contacts.astype(jnp.float32))
    as_model = curve_metrics(config, fitted, eval_set, eval_set.handles)
    assert gt["fitted_curves"]["dense_error_cm"] == pytest.approx(as_model["dense_error_cm"], rel=1e-6)
    assert gt["fitted_curves"]["foot_skating_ratio"] == pytest.approx(as_model["foot_skating_ratio"], rel=1e-6)
    # Fitted with pinned positions: the curves pass through the mocap's control frames,
    # and in between they stay within the fit's sub-centimetre error.
    assert 0.0 < gt["fitted_curves"]["dense_error_cm"] < 0.5 and as_model["handles_error_cm"] < 1e-4
    dense_feet = eval_set.dense_pos[..., list(FEET), :]
    assert gt["foot_skating_ratio"] == pytest.approx(float(foot_skating_ratio(dense_feet, demo_dataset.fps, floor_height=0.0)))


@pytest.fixture(scope="module")
def eval_set(demo_dataset):
    return make_eval_set(demo_dataset, key=jax.random.key(5))


def test_make_eval_set(demo_dataset, eval_set):
    es = eval_set
    ds = demo_dataset
    assert_trees_identical(make_eval_set(ds, key=jax.random.key(5)), es)
    np.testing.assert_array_equal(es.start, ds.ctrl_pos[:, 0])
    np.testing.assert_array_equal(es.end, ds.ctrl_pos[:, -1])
    np.testing.assert_array_equal(es.ctrl_contacts, ds.ctrl_contacts)
    np.testing.assert_array_equal(es.dense_pos, ds.dense_pos)
    np.testing.assert_array_equal(es.ctrl_pos, ds.ctrl_pos)
    np.testing.assert_array_equal(es.ctrl_tangent, ds.ctrl_tangent)
    h = es.handles
    assert h.frame.shape == (10, 4)
    control, joint, valid = map(np.asarray, (h.frame // 6, h.joint, h.valid))
    np.testing.assert_array_equal(np.asarray(h.frame) % 6, 0)
    assert control.min() >= 1 and control.max() <= K - 2
    counts = valid.sum(1)
    assert counts.min() >= 1 and counts.max() <= 4
    rows = np.arange(10)[:, None]
    np.testing.assert_array_equal(h.position, ds.ctrl_pos[rows, control, joint])
    noise = np.asarray(es.handles_ood.position) - np.asarray(h.position)
    assert np.all(np.abs(noise) <= 16.0 + 1e-3) and np.abs(noise).max() > 4.0
    np.testing.assert_array_equal(es.handles_ood.frame, h.frame)
    np.testing.assert_array_equal(es.handles_ood.valid, h.valid)
    # A subset of windows, still deterministic.
    sub = make_eval_set(ds, key=jax.random.key(5), num_windows=4)
    assert sub.start.shape == (4, J, 3)
    starts = [int(np.flatnonzero(np.all(ds.ctrl_pos[:, 0] == s, axis=(1, 2)))[0]) for s in np.asarray(sub.start)]
    assert starts == sorted(set(starts))
    with pytest.raises(ValueError, match="max_handles"):
        make_eval_set(ds, key=jax.random.key(5), max_handles=0)


def test_reference_curves_and_curve_metrics(demo_dataset, eval_set):
    es = eval_set
    ref = reference_curves(es, es.handles, LAYOUT)
    assert ref.ctrl_pos.shape == (10, K, J, 3) and ref.contacts.shape == (10, K, 2)
    np.testing.assert_array_equal(ref.ctrl_pos[:, 0], es.start)
    np.testing.assert_array_equal(ref.ctrl_pos[:, -1], es.end)
    h = es.handles
    assert float(handles_error(ref.ctrl_pos, h._replace(frame=h.frame // 6))) == 0.0
    # OOD handles are hit exactly as well (the reference trusts them).
    ood = reference_curves(es, es.handles_ood, LAYOUT)
    o = es.handles_ood
    assert float(handles_error(ood.ctrl_pos, o._replace(frame=o.frame // 6))) == 0.0
    # An invalid slot is ignored: moving it changes nothing.
    moved = h._replace(position=jnp.where(h.valid[..., None], h.position, h.position + 50.0))
    np.testing.assert_array_equal(reference_curves(es, moved, LAYOUT).ctrl_pos, ref.ctrl_pos)

    config = CurveMetricsConfig(demo_dataset.layout, demo_dataset.fps, floor_height=0.0)
    metrics = curve_metrics(config, ref, es, es.handles)
    assert set(metrics) == {"handles_error_cm", "dense_error_cm", "foot_skating_ratio", "contact_accuracy"}
    assert metrics["handles_error_cm"] == 0.0
    assert 0.0 <= metrics["foot_skating_ratio"] <= 1.0
    # Contacts of 0.5 count as "no contact".
    assert metrics["contact_accuracy"] == pytest.approx(float(np.mean(~demo_dataset.ctrl_contacts)))
    # The fitted curves themselves: handles exact, dense error = the fit residual (small), contacts right.
    fitted = SampledCurves(
        jnp.asarray(demo_dataset.ctrl_pos), jnp.asarray(demo_dataset.ctrl_tangent),
        jnp.asarray(demo_dataset.ctrl_rot6d), jnp.asarray(demo_dataset.ctrl_contacts, jnp.float32),
    )  # fmt: skip
    own = curve_metrics(config, fitted, es, es.handles)
    assert own["handles_error_cm"] == 0.0 and own["contact_accuracy"] == 1.0
    assert own["dense_error_cm"] < 2.0 and own["dense_error_cm"] < metrics["dense_error_cm"]


def test_sample_in_chunks(eval_set):
    calls = []

    def sample(start, end, handles, key):
        calls.append(start.shape[0])
        tag = jax.random.uniform(key, ())
        c = start.shape[0]
        return SampledCurves(
            jnp.broadcast_to(start[:, None], (c, K, J, 3)), jnp.zeros((c, K, J, 3)),
            jnp.zeros((c, K, J, 6)), jnp.full((c, K, 2), tag),
        )  # fmt: skip

    key = jax.random.key(8)
    out = sample_in_chunks(sample, eval_set, eval_set.handles, key=key, chunk=4)
    assert calls == [4, 4, 4]  # the last chunk padded to the same shape
    assert out.ctrl_pos.shape == (10, K, J, 3)
    np.testing.assert_array_equal(out.ctrl_pos[:, 0], eval_set.start)
    for i, rows in enumerate((slice(0, 4), slice(4, 8), slice(8, 10))):
        np.testing.assert_array_equal(out.contacts[rows], float(jax.random.uniform(jax.random.fold_in(key, i), ())))
    calls.clear()
    sample_in_chunks(sample, eval_set, eval_set.handles, key=key, chunk=256)
    assert calls == [10]


@pytest.fixture(scope="module")
def experiment():
    return load_experiment("bmm_lafan1")


@requires_shared
def test_bmm_lafan1_experiment_smoke(tmp_path, experiment):
    """The experiment end to end on the real LaFAN1 subset: tiny model, a few steps, a few windows."""
    out = tmp_path / "bmm.json"
    args = ["--out", str(out), "--data", str(SHARED_DATA / "lafan1" / "lafan1-subset.zip"), "--config", "tiny",
            "--steps", "4", "--checkpoint-every", "2", "--eval-windows", "6", "--table6-steps", "5",
            "--run-dir", str(tmp_path / "run"), "--no-progress"]  # fmt: skip
    results = experiment.main(args)
    saved = json.loads(out.read_text())
    assert saved["eval"]["n_windows"] == 6 and saved["training"]["steps"] == 4
    bmm = saved["bmm"]["0"]
    assert bmm["overwrite"]["id"]["handles_error_cm"] == 0.0 and bmm["overwrite"]["ood"]["handles_error_cm"] == 0.0
    assert bmm["no_overwrite"]["id"]["handles_error_cm"] > 0.0
    assert saved["reference"]["id"]["handles_error_cm"] == 0.0 and list(bmm["steps"]) == ["5"]
    assert (tmp_path / "run" / "model" / "config.json").exists() and out.with_suffix(".md").exists()
    # Running it again resumes at step 4 (nothing more to train) and evaluates the saved
    # model with handles off the control grid beside the grid ones.
    out2 = tmp_path / "off_grid.json"
    off = experiment.main([*args[:1], str(out2), *args[2:], "--handle-frames", "off_grid"])
    assert off["training"]["history"] == [] and results["model"]["params"] == off["model"]["params"]
    section = off["handle_frames"]
    assert all(f % 6 for f in section["frames"])
    assert section["bmm"]["0"]["id"]["handles_error_cm"] < 1e-3 and section["bmm"]["0"]["ood"]["handles_error_cm"] < 1e-3
    assert section["reference"]["id"]["handles_error_cm"] < 1e-3
    assert "off the control grid" in out2.with_suffix(".md").read_text()
    # A larger --steps goes on training the same run (constant learning rate) from step 4;
    # --parameters raw evaluates and saves the raw parameters instead of their average.
    out3 = tmp_path / "longer.json"
    longer_args = [str(out3) if a == str(out) else "6" if a == "4" else a for a in args]
    longer = experiment.main([*longer_args, "--parameters", "raw"])
    assert [h["step"] for h in longer["training"]["history"]][-1] == 6 and longer["training"]["evaluated_parameters"] == "raw"
    assert (tmp_path / "run" / "model_raw" / "config.json").exists()


@requires_shared
def test_bmm_lafan1_levers_held_out_contents_and_learning_curve(tmp_path, experiment):
    """The training levers' protocol end to end on the real LaFAN1 subset: the push sequences held out,
    warm-up + cosine, yaw and mirror augmentation, a learning curve every 2 steps with the
    stopping rule; then the same command resumes with nothing to train and keeps the curve."""
    out = tmp_path / "levers.json"
    args = ["--out", str(out), "--data", str(SHARED_DATA / "lafan1" / "lafan1-subset.zip"), "--config", "tiny",
            "--steps", "4", "--checkpoint-every", "2", "--eval-windows", "6", "--table6-steps", "5",
            "--run-dir", str(tmp_path / "run"), "--no-progress", "--holdout-contents", "push*",
            "--lr-schedule", "cosine", "--warmup-steps", "1", "--augment-yaw", "--augment-mirror", "0.5",
            "--eval-every", "2", "--curve-windows", "4", "--patience", "3"]  # fmt: skip
    saved = experiment.main(args)
    training = saved["training"]
    assert [list(r) for r in training["rest_reflections"]] == [[1.0, 1.0, -1.0]] * 6  # LaFAN1's rest pose mirrors in Z
    curve = training["learning_curve"]
    assert [p["step"] for p in curve["points"]] == [2, 4] and curve["stopped_at"] is None
    assert set(curve["points"][0]) >= {"id", "held_out", "loss", "train_s"} and set(curve["points"][0]["id"]) == {"ema", "raw"}
    assert np.isfinite(curve["points"][-1]["held_out"]["ema"]["dense_error_cm"])
    held = saved["held_out"]
    assert held["contents"] == ["push*"] and held["n_windows"] == 6
    assert held["bmm"]["0"]["id"]["handles_error_cm"] == 0.0 and held["reference"]["id"]["dense_error_cm"] > 0.0
    assert out.with_suffix(".curve.png").stat().st_size > 1000 and "Held-out contents" in out.with_suffix(".md").read_text()
    again = experiment.main(args)
    assert again["training"]["history"] == [] and again["training"]["learning_curve"]["points"] == curve["points"]
    with pytest.raises(ValueError, match="no clip"):
        experiment.main([*args, "--holdout-contents", "nothing-like-this"])
    with pytest.raises(SystemExit):  # an options error: one line from the parser, exit status 2
        experiment.main([*args[:-6], "--patience", "2"])
