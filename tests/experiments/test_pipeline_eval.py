"""experiments/pipeline_eval.py: one evaluation of the whole pipeline, every IK on the same curves.

Runs on a folder holding copies of the bundled Bandai-Namco clip (``--bvh-dir``) with the
bundled models, so it needs no shared data.
"""

from __future__ import annotations

import importlib.util
import json
import shutil

import jax
import numpy as np
import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.bmm.evaluation import make_eval_set
from helpers import REPO_ROOT, assert_trees_identical

METRICS = {"handles_error_cm", "handles_error_max_cm", "unreachable_fraction", "mpjpe_cm", "foot_skating_ratio", "key_pop_deg"}


@pytest.fixture(scope="module")
def experiment():
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(REPO_ROOT / "experiments"))
        spec = importlib.util.spec_from_file_location("pipeline_eval", REPO_ROOT / "experiments" / "pipeline_eval.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """Three copies of the bundled 40-frame clip: two 31-frame windows each (offset 5)."""
    folder = tmp_path_factory.mktemp("my_clips")
    for i in range(3):
        shutil.copy(DEMO_CLIP, folder / f"walk_{i + 1}.bvh")
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
    common = ["--bvh-dir", str(clips), "--steps", "2", "--chunk", "4"]
    out = tmp_path / "four.json"
    four = experiment.main(["--out", str(out), "--windows", "4", "--ik", "learned", "rig", *common])
    assert json.loads(out.read_text()) == four and out.with_suffix(".md").exists()
    assert four["windows"] == 4 and set(four) >= {"ik", "curves", "mocap", "labels", "settings"}
    assert "id" not in four  # several IKs: the id / ood per IK
    for name in ("learned", "rig"):
        section = four["ik"][name]
        assert section["compile_s"] > 0.0
        for cond in ("id", "ood"):
            assert METRICS | {"ik_ms_per_window", "handles_missed_fraction"} <= set(section[cond])
            assert section[cond]["unreachable_fraction"] <= section[cond]["handles_missed_fraction"]
            assert section[cond]["handles_error_cm"] <= section[cond]["handles_error_max_cm"]
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

    # A smaller run: its windows are the first ones of the larger, with the same handles and curves.
    recorded["sampled"].clear()
    two = experiment.main(["--out", str(tmp_path / "two.json"), "--windows", "2", "--ik", "rig", *common])
    assert two["settings"]["rows"] == four["settings"]["rows"][:2]
    assert two["id"] == two["ik"]["rig"]["id"] and two["ood"] == two["ik"]["rig"]["ood"]  # one IK: the shape
    for small, large in zip(recorded["sampled"], sampled):
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, np.asarray(b)[:2], atol=1e-3), small, large)


def test_per_window_draws_do_not_depend_on_the_number_of_windows(experiment, clips, monkeypatch, tmp_path):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    args = experiment.parse_options(experiment.Options, ["--out", "x.json", "--bvh-dir", str(clips)])
    _, dataset = experiment.open_windows(args)
    assert len(dataset.ctrl_pos) == 6
    draw = lambda n: make_eval_set(dataset, key=jax.random.key(3), num_windows=n, handle_frames="any", per_window=True)  # noqa: E731
    every, four = draw(None), draw(4)
    assert sorted(every.rows) == list(range(6))
    assert_trees_identical(jax.tree.map(lambda a: np.asarray(a)[:4], every), four)


def test_lafan1_needs_its_models(experiment, capsys):
    with pytest.raises(SystemExit):
        experiment.main(["--out", "x.json", "--corpus", "lafan1"])
    assert "no bundled BMM model for lafan1: pass --bmm PATH" in capsys.readouterr().err


@pytest.mark.parametrize(
    "setting, message",
    [("iterations", "expected NAME=VALUE"), ("speed=3", "expected NAME=VALUE"), ("iterations=many", "'many' is not a number")],
)
def test_exact_settings_are_checked(experiment, capsys, setting, message):
    with pytest.raises(SystemExit):
        experiment.main(["--out", "x.json", "--exact", setting])
    assert f"--exact {setting}: {message}" in capsys.readouterr().err


def test_exact_settings_reach_the_exact_ik(experiment):
    args = experiment.parse_options(experiment.Options, ["--out", "x.json", "--exact", "iterations=3", "--exact", "rotation_weight=2.5"])
    assert experiment.exact_settings(args) == {"iterations": 3, "rotation_weight": 2.5}
