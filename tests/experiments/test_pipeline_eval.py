"""experiments/pipeline_eval.py: one evaluation of the whole pipeline, every IK on the same curves.

Runs on a folder holding copies of the bundled Bandai-Namco clip (``--bvh-dir``) with the
bundled models, so it needs no shared data; chained segments (``--segments``) on copies of
that clip played forward then back (79 frames: room for chains of two windows).
"""

from __future__ import annotations

import dataclasses
import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.bezier import BezierLayout, fit_curves
from bezmotion.evaluation.curves import make_eval_set
from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.data.windows import split_windows
from bezmotion.evaluation.metrics import chain_velocity_jumps
from bezmotion.pipeline.authoring import load_profile
from bezmotion.pipeline.transfer import Transfer
from helpers import assert_trees_identical, load_experiment

METRICS = {
    "handles_error_cm", "handles_error_max_cm", "unreachable_fraction", "mpjpe_cm", "foot_skating_ratio", "key_pop_deg",
    "curve_error_cm", "curve_error_max_cm", "planted_foot_rise_cm", "planted_foot_sink_cm", "foot_sliding_ratio",
}  # fmt: skip


@pytest.fixture(scope="module")
def experiment():
    return load_experiment("pipeline_eval")


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """Three copies of the bundled 40-frame clip: two 31-frame windows each (offset 5)."""
    folder = tmp_path_factory.mktemp("my_clips")
    for i in range(3):
        shutil.copy(DEMO_CLIP, folder / f"walk_{i + 1}.bvh")
    return folder


@pytest.fixture(scope="module")
def long_clips(tmp_path_factory):
    """Two copies of the bundled clip played forward then back: 79 frames, four chains of two windows each."""
    folder = tmp_path_factory.mktemp("long_clips")
    motion = read_bvh(DEMO_CLIP)
    there_and_back = np.r_[np.arange(40), np.arange(38, -1, -1)]
    motion = dataclasses.replace(motion, quat_local=motion.quat_local[there_and_back], pos_local=motion.pos_local[there_and_back])
    for i in range(2):
        write_bvh(folder / f"walk_{i + 1}.bvh", motion)
    return folder


@pytest.fixture
def recorded(experiment, monkeypatch, tmp_path):
    """Runs of the script that record the curves it samples and the curves each IK is given."""
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    log = {"sampled": [], "solved": []}

    def sample(*args, **kwargs):
        curves = real_sample(*args, **kwargs)
        log["sampled"].append(curves)
        return curves

    def solve(fn, params, curves, *args, **kwargs):
        log["solved"].append((fn, curves))
        return real_solve(fn, params, curves, *args, **kwargs)

    real_sample, real_solve = experiment.sample_window_curves, experiment.solve_window_curves
    monkeypatch.setattr(experiment, "sample_window_curves", sample)
    monkeypatch.setattr(experiment, "solve_window_curves", solve)
    return log


def test_every_ik_on_the_same_curves_and_windows_independent_of_their_count(experiment, clips, recorded, tmp_path):
    # Chunks of 2: the 2-window run below (and the next test's) reuses this run's compiled programs.
    common = ["--bvh-dir", str(clips), "--steps", "2", "--chunk", "2"]
    out = tmp_path / "four.json"
    four = experiment.main(["--out", str(out), "--windows", "4", "--ik", "learned", "rig", *common])
    assert json.loads(out.read_text()) == four and out.with_suffix(".md").exists()
    assert four["windows"] == 4 and set(four) >= {"ik", "curves", "mocap", "labels", "settings"}
    assert "id" not in four  # several IKs: id / ood per IK
    for name in ("learned", "rig"):
        section = four["ik"][name]
        assert section["compile_s"] > 0.0
        for cond in ("id", "ood"):
            assert METRICS | {"ik_ms_per_window", "handles_missed_fraction"} <= set(section[cond])
            assert section[cond]["unreachable_fraction"] <= section[cond]["handles_missed_fraction"]
            assert section[cond]["handles_error_cm"] <= section[cond]["handles_error_max_cm"]
            assert 0.0 <= section[cond]["curve_error_cm"] <= section[cond]["curve_error_max_cm"]
    # The curves were sampled once per condition, and both IKs were given those very arrays.
    sampled, solved = recorded["sampled"], recorded["solved"]
    assert len(sampled) == 2 and len(solved) == 4
    assert solved[0][1] is sampled[0] and solved[1][1] is sampled[0]
    assert solved[2][1] is sampled[1] and solved[3][1] is sampled[1]
    # Curves before IK pass through every handle; the reference too; orientations for the BMM only.
    curves = four["curves"]
    for kind in ("bmm", "reference"):
        for cond in ("id", "ood"):
            assert curves[kind][cond]["handles_error_cm"] < 1e-3
            assert {"dense_error_cm", "foot_skating_ratio", "dense_error_per_joint_cm"} <= set(curves[kind][cond])
    assert 0.0 < curves["bmm"]["id"]["orientation_error_deg"] < 90.0
    assert set(curves["bmm"]["id"]["orientation_error_per_joint_deg"]) == {"hips", "head", "left_hand", "right_hand", "left_foot", "right_foot"}
    assert "orientation_error_deg" not in curves["reference"]["id"]
    assert {"foot_skating_ratio", "key_pop_deg", "max_rotation_change_deg"} <= set(four["mocap"])
    # Per label: the folder's files are all "walk".
    assert list(four["labels"]) == ["walk"] and four["labels"]["walk"]["windows"] == 4
    assert four["labels"]["walk"]["ik"]["rig"]["id"]["mpjpe_cm"] == pytest.approx(four["ik"]["rig"]["id"]["mpjpe_cm"])
    # Paired: rig minus learned window by window; its mean is the difference of the two means.
    assert list(four["paired"]) == ["rig minus learned"]
    for cond in ("id", "ood"):
        paired = four["paired"]["rig minus learned"][cond]
        for figure in ("mpjpe_cm", "foot_skating_ratio", "curve_error_cm"):
            expected = four["ik"]["rig"][cond][figure] - four["ik"]["learned"][cond][figure]
            assert paired[figure]["mean"] == pytest.approx(expected, abs=1e-5)
            assert paired[figure]["windows"] == 4 and paired[figure]["se"] >= 0.0 and 0.0 <= paired[figure]["better_fraction"] <= 1.0
    assert four["labels"]["walk"]["paired"] == four["paired"]
    # The per-window figures behind every summary, beside the JSON.
    with np.load(tmp_path / "four.windows.npz") as saved:
        assert saved["labels"].tolist() == ["walk"] * 4 and saved["rows"].tolist() == four["settings"]["rows"]
        assert float(saved["ik/rig/id/mpjpe"].mean()) == pytest.approx(four["ik"]["rig"]["id"]["mpjpe_cm"])
        per_joint = saved["ik/rig/id/mpjpe_per_joint"]  # where the MPJPE comes from, joint by joint
        assert per_joint.shape[0] == 4 and per_joint.shape[1] > 6
        np.testing.assert_allclose(per_joint.mean(axis=-1), saved["ik/rig/id/mpjpe"], rtol=1e-5)
        assert float(saved["curves/bmm/ood/dense"].mean()) == pytest.approx(four["curves"]["bmm"]["ood"]["dense_error_cm"])
        assert "mocap/skating" in saved

    # A smaller run: its windows are the first ones of the larger, with the same handles and curves.
    recorded["sampled"].clear()
    two = experiment.main(["--out", str(tmp_path / "two.json"), "--windows", "2", "--ik", "rig", *common])
    assert two["settings"]["rows"] == four["settings"]["rows"][:2]
    assert two["id"] == two["ik"]["rig"]["id"] and two["ood"] == two["ik"]["rig"]["ood"]  # one IK: also at the top level
    for small, large in zip(recorded["sampled"], sampled):
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, np.asarray(b)[:2], atol=1e-3), small, large)


@pytest.fixture
def sampler_calls(experiment, monkeypatch, tmp_path):
    """The keyword arguments of every ``sample_window_curves`` call the script makes."""
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    calls = []

    def sample(*args, **kwargs):
        calls.append(kwargs)
        return real_sample(*args, **kwargs)

    real_sample = experiment.sample_window_curves
    monkeypatch.setattr(experiment, "sample_window_curves", sample)
    return calls


def test_foot_lock_locks_the_curves_every_ik_is_given(experiment, clips, sampler_calls, tmp_path):
    common = ["--bvh-dir", str(clips), "--steps", "2", "--chunk", "4", "--windows", "2", "--ik", "rig"]
    out = tmp_path / "locked.json"
    locked = experiment.main(["--out", str(out), "--foot-lock", *common])
    plain = experiment.main(["--out", str(tmp_path / "plain.json"), *common])
    assert [c["foot_lock"] for c in sampler_calls] == [True, True, False, False]  # both conditions' curves, then the plain run's
    assert locked["settings"]["foot_lock"] and not plain["settings"]["foot_lock"]
    assert plain["settings"]["bmm_trained_on"] == "bandai_namco" and plain["settings"]["transfer"] is None  # the bundled BMM's own
    assert "feet locked on their predicted contacts" in out.with_suffix(".md").read_text()
    # Locking moves the feet (the walk has contacts), so the curves differ; handles still hold.
    assert locked["curves"]["bmm"]["id"]["dense_error_cm"] != plain["curves"]["bmm"]["id"]["dense_error_cm"]
    assert locked["curves"]["bmm"]["id"]["handles_error_cm"] < 1e-3


def test_a_bmm_of_another_skeleton_has_its_curves_transferred(experiment, clips, sampler_calls, tmp_path):
    """``--trained-on`` another skeleton: the curves are moved over by the transfer between the
    two bundled profiles (as ``bezmotion inbetween`` does) and still pass through every handle."""
    out = tmp_path / "moved.json"
    moved = experiment.main(
        ["--out", str(out), "--trained-on", "lafan1", "--bvh-dir", str(clips), "--steps", "2", "--chunk", "4", "--windows", "2", "--ik", "rig"]
    )
    expected = Transfer.between(load_profile("lafan1"), load_profile("bandai_namco"))
    assert len(sampler_calls) == 2  # both conditions' curves
    for transfer in (c["transfer"] for c in sampler_calls):
        np.testing.assert_array_equal(transfer.scale, expected.scale)
        np.testing.assert_array_equal(transfer.rot_offset, expected.rot_offset)
    assert moved["settings"]["bmm_trained_on"] == "lafan1"
    assert moved["settings"]["transfer"]["scale"] == pytest.approx(float(expected.scale))
    assert "the BMM trained on lafan1, its curves transferred" in out.with_suffix(".md").read_text()
    for cond in ("id", "ood"):
        assert moved["curves"]["bmm"][cond]["handles_error_cm"] < 1e-3


def test_trained_on_must_name_a_profile(experiment, capsys):
    with pytest.raises(SystemExit):
        experiment.main(["--out", "x.json", "--trained-on", "giraffe"])
    assert "--trained-on giraffe: not a bundled profile (bandai_namco, lafan1) nor a profile file" in capsys.readouterr().err


def test_a_folder_it_cannot_evaluate_is_one_line_naming_it(experiment, monkeypatch, tmp_path):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    malformed, short = tmp_path / "malformed", tmp_path / "short"
    malformed.mkdir(), short.mkdir()
    shutil.copy(DEMO_CLIP, malformed / "walk.bvh")
    (malformed / "cut.bvh").write_text(DEMO_CLIP.read_text()[:3000])  # stops inside the hierarchy
    motion = read_bvh(DEMO_CLIP)
    write_bvh(short / "walk.bvh", dataclasses.replace(motion, quat_local=motion.quat_local[:20], pos_local=motion.pos_local[:20]))
    for folder, message in ((malformed, f"--bvh-dir {malformed}: {malformed / 'cut.bvh'}:"), (short, f"--bvh-dir {short}: no windows of 31 frames in 1 clips (longest 20)")):
        with pytest.raises(SystemExit) as exit_:
            experiment.main(["--out", str(tmp_path / "x.json"), "--bvh-dir", str(folder), "--ik", "rig"])
        assert str(exit_.value.code).startswith(f"pipeline_eval.py: error: {message}") and "\n" not in str(exit_.value.code)
    assert not (tmp_path / "x.json").exists()


def test_per_window_draws_do_not_depend_on_the_number_of_windows(experiment, clips, monkeypatch, tmp_path):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    args = experiment.parse_options(experiment.Options, ["--out", "x.json", "--bvh-dir", str(clips)])
    _, dataset = experiment.open_windows(args)
    assert len(dataset.ctrl_pos) == 6
    draw = lambda n: make_eval_set(dataset, key=jax.random.key(3), num_windows=n, handle_frames="any", per_window=True)  # noqa: E731
    every, four = draw(None), draw(4)
    assert sorted(every.rows) == list(range(6))
    assert_trees_identical(jax.tree.map(lambda a: np.asarray(a)[:4], every), four)
    # Explicit windows (those of chains) get the very draws they get in any per-window set.
    rows = np.asarray([every.rows[3], every.rows[0], every.rows[3]])
    chosen = make_eval_set(dataset, key=jax.random.key(3), handle_frames="any", per_window=True, rows=rows)
    assert_trees_identical(jax.tree.map(lambda a: np.asarray(a)[[3, 0, 3]], every), chosen)
    with pytest.raises(ValueError, match="rows= needs per_window=True"):
        make_eval_set(dataset, key=jax.random.key(3), rows=rows)
    with pytest.raises(ValueError, match=r"rows must be dataset windows 0 … 5, got \[6\]"):
        make_eval_set(dataset, key=jax.random.key(3), per_window=True, rows=np.asarray([6]))


def test_lafan1_needs_its_models(experiment, capsys, tmp_path, monkeypatch):
    """LaFAN1's registered models are trained locally: until they are, the error names the command."""
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    with pytest.raises(SystemExit):
        experiment.main(["--out", "x.json", "--corpus", "lafan1"])
    error = capsys.readouterr().err
    assert "--bmm bundled: pretrained model 'lafan1' is not bundled" in error and "experiments/bmm_lafan1.py" in error
    with pytest.raises(SystemExit):
        experiment.main(["--out", "x.json", "--corpus", "lafan1", "--bmm", str(tmp_path / "nowhere")])
    assert "no saved model folder there" in capsys.readouterr().err


@pytest.mark.parametrize(
    "setting, message",
    [
        ("iterations", "expected NAME=VALUE"),
        ("speed=3", "expected NAME=VALUE"),
        ("iterations=many", "'many' is not a number"),
        ("iterations=-1", "must lie in [0, ∞)"),
        ("window_passes=1.5", "window_passes is a count, a whole number"),
        ("key_hold_decay=2", "must lie in [0.0, 1.0]"),
    ],
)
def test_exact_settings_are_checked(experiment, capsys, setting, message):
    with pytest.raises(SystemExit):
        experiment.main(["--out", "x.json", "--exact", setting])
    assert f"--exact {setting}: {message}" in capsys.readouterr().err


def test_exact_settings_reach_the_exact_ik(experiment):
    args = experiment.parse_options(experiment.Options, ["--out", "x.json", "--exact", "iterations=3", "--exact", "rotation_weight=2.5"])
    assert experiment.exact_settings(args.exact) == {"iterations": 3, "rotation_weight": 2.5}


def test_segments_evaluate_chains_of_windows(experiment, long_clips, monkeypatch, tmp_path):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "chains.json"
    common = ["--bvh-dir", str(long_clips), "--steps", "2", "--chunk", "4", "--ik", "rig"]
    r = experiment.main(["--out", str(out), "--windows", "2", "--segments", "2", *common])
    assert json.loads(out.read_text()) == r and "chains of 2 windows" in out.with_suffix(".md").read_text()
    seg = r["segments"]
    assert (seg["k"], seg["chains"], seg["frames_per_chain"], seg["key_frames"]) == (2, 2, 61, [0, 30, 60])
    assert r["windows"] == 4 and r["settings"]["segments"] == 2
    # Each chain: two windows of one clip, the second starting 30 frames after the first.
    rows = np.asarray(r["settings"]["rows"])
    _, dataset = experiment.open_windows(experiment.parse_options(experiment.Options, ["--out", "x.json", "--bvh-dir", str(long_clips)]))
    assert rows.shape == (2, 2) and (dataset.clip_index[rows[:, 0]] == dataset.clip_index[rows[:, 1]]).all()
    np.testing.assert_array_equal(dataset.start_frame[rows[:, 1]] - dataset.start_frame[rows[:, 0]], 30)
    # The velocity jump at the one shared key of each chain: coupled, independent, the mocap's own.
    jump = seg["boundary_velocity_jump_cm_per_frame"]
    for variant in (jump["coupled"], jump["independent"], jump["mocap"], jump["ood"]["coupled"], jump["after_ik"]["rig"]["id"]):
        assert all(np.isfinite(variant[stat]) and variant[stat] >= 0.0 for stat in ("mean", "p95", "max"))
        assert variant["mean"] <= variant["p95"] <= variant["max"]
    assert jump["coupled"]["count"] == jump["independent"]["count"] == 2 * 1 * 6  # chains × shared keys × joints
    assert jump["mocap"]["count"] == 2 * 59 * 6  # every inner frame of the same chains
    assert jump["coupled_other_frames"]["count"] == 2 * 58 * 6  # the same curves' inner frames but the key
    assert jump["coupled_inner_control_frames"]["count"] == 2 * 8 * 6  # frames 6, 12, 18, 24, 36, 42, 48, 54
    # The mocap's own per-window fits at the same keys: joined as they are, and coupled.
    fits = jump["mocap_fits"]
    assert fits["independent"]["count"] == fits["coupled"]["count"] == 2 * 1 * 6
    # Paired with the mocap at the same keys: the difference of the two means, its standard
    # error over the two chains.
    for variant in (jump["coupled"], jump["independent"], jump["after_ik"]["rig"]["id"], fits["independent"], fits["coupled"]):
        excess = variant["minus_mocap"]
        assert excess["chains"] == 2 and excess["se"] >= 0.0
        np.testing.assert_allclose(excess["mean"], variant["mean"] - jump["mocap_at_shared_keys"]["mean"], atol=1e-6)
    # The other metrics over the chains' frames; the handles moved into each chain's frame.
    for cond in ("id", "ood"):
        after = r["ik"]["rig"][cond]
        assert METRICS <= set(after) and all(np.isfinite(after[m]) for m in METRICS)
        assert after["ik_ms_per_chain"] > 0.0 and "ik_ms_per_window" not in after
        for kind in ("bmm", "bmm_independent", "reference"):
            assert r["curves"][kind][cond]["handles_error_cm"] < 1e-3
            assert np.isfinite(r["curves"][kind][cond]["dense_error_cm"])
    assert "ik_ms_per_window" in seg["not_computed"] and "key_pop_deg" in seg["metrics"]
    assert {"foot_skating_ratio", "key_pop_deg", "max_rotation_change_deg"} <= set(r["mocap"])
    assert r["labels"]["walk"]["chains"] == 2 and r["labels"]["walk"]["windows"] == 4


def test_mocap_fits_joined_as_they_are_and_coupled(experiment):
    """A motion that turns back at the shared key (every joint at |t − 30| cm/frame along x):
    each window is linear, so its fit is exact and the fits joined as they are jump as the
    mocap does (2 cm/frame); coupled, the key's tangent is the mean of +1 and −1, zero, and
    the curves ease into and out of the key instead, jumping less."""
    t = np.abs(np.arange(61, dtype=np.float32) - 30.0)
    positions = np.zeros((1, 61, 6, 3), np.float32)
    positions[..., 0] = t[None, :, None]
    positions = jnp.asarray(positions)
    layout = BezierLayout(31, 6)
    windows = jax.vmap(lambda p: split_windows(p, 2))(positions)  # (1, 2, 31, 6, 3)
    fit = fit_curves(layout, jnp.moveaxis(windows, -2, -3))
    ctrl_pos, ctrl_tangent = jnp.moveaxis(fit.ctrl_pos, -3, -2), jnp.moveaxis(fit.ctrl_tangent, -3, -2)
    mocap = chain_velocity_jumps(positions, 2).at_shared_keys
    fits = experiment.mocap_fit_jumps(ctrl_pos, ctrl_tangent, layout, mocap)
    np.testing.assert_allclose(fits["independent"]["mean"], 2.0, atol=1e-4)
    np.testing.assert_allclose(fits["independent"]["minus_mocap"]["mean"], 0.0, atol=1e-4)
    assert fits["coupled"]["max"] < 1.0 and fits["coupled"]["minus_mocap"]["mean"] < -1.0


def test_segments_must_be_positive(experiment, capsys):
    with pytest.raises(SystemExit):
        experiment.main(["--out", "x.json", "--segments", "0"])
    assert "--segments 0: must be ≥ 1" in capsys.readouterr().err


def test_segments_longer_than_every_clip(experiment, clips, monkeypatch, tmp_path):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    with pytest.raises(ValueError, match="no chain of 2 windows: it needs 61 frames of one clip, and the longest clip's windows cover 36"):
        experiment.main(["--out", str(tmp_path / "x.json"), "--bvh-dir", str(clips), "--segments", "2", "--ik", "rig"])
