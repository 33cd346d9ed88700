"""experiments/cross_skeleton.py: each skeleton driven by its own BMM and the other's, through pipeline_eval."""

from __future__ import annotations

import json
import shutil

import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.pipeline.authoring import load_profile
from bezmotion.pipeline.transfer import Transfer
from helpers import load_experiment


@pytest.fixture(scope="module")
def experiment():
    return load_experiment("cross_skeleton")


def test_each_target_is_driven_by_its_own_bmm_and_the_others_through_its_own_iks(experiment, tmp_path):
    args = experiment.parse_options(
        experiment.Options,
        ["--out", str(tmp_path / "x.json"), "--model", "lafan1=lafan1_cpu", "--windows", "7", "--ik", "learned", "exact", "--foot-lock"],
    )
    planned = {(target, source): argv for target, source, argv in experiment.runs(args)}
    assert list(planned) == [("lafan1", "lafan1"), ("lafan1", "bandai_namco"), ("bandai_namco", "bandai_namco"), ("bandai_namco", "lafan1")]
    model = {"lafan1": "lafan1_cpu", "bandai_namco": "bandai_namco"}
    for (target, source), argv in planned.items():
        flag = lambda name: argv[argv.index(name) + 1]  # noqa: E731
        assert (flag("--corpus"), flag("--bmm"), flag("--ik-model")) == (target, model[source], model[target])
        assert flag("--windows") == "7" and "--foot-lock" in argv
        assert argv[argv.index("--ik") + 1 : argv.index("--ik") + 3] == ["learned", "exact"]
        assert flag("--out") == str(tmp_path / f"x.{target}.{source}.json")


@pytest.mark.parametrize(
    "items, message",
    [
        (["lafan1"], "--model lafan1: expected CORPUS=NAME"),
        (["giraffe=bandai_namco"], "--model giraffe=bandai_namco: expected CORPUS=NAME with CORPUS one of"),
        (["lafan1=zebra"], "--model lafan1=zebra: 'zebra' is not a registered model"),
        (["lafan1=bandai_namco"], "--model lafan1=bandai_namco: bandai_namco poses the bandai_namco skeleton, not lafan1's"),
        (["lafan1=lafan1_cpu", "lafan1=lafan1"], "--model lafan1=lafan1_cpu and --model lafan1=lafan1: one model per corpus"),
    ],
)
def test_a_model_must_be_a_registered_one_of_its_corpus_skeleton(experiment, capsys, items, message):
    with pytest.raises(SystemExit):
        experiment.main(["--out", "x.json", *(a for item in items for a in ("--model", item))])
    assert message in capsys.readouterr().err


def test_a_model_not_trained_here_is_refused_before_any_run(experiment, capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))  # no LaFAN1 model trained there
    monkeypatch.setattr(experiment.pipeline_eval, "main", lambda argv: pytest.fail(f"ran {argv}"))
    with pytest.raises(SystemExit):
        experiment.main(["--out", str(tmp_path / "x.json"), "--targets", "bandai_namco"])
    error = capsys.readouterr().err
    # The Bandai-Namco windows driven by LaFAN1's BMM: named, with pipeline_eval's reason.
    assert "cross_skeleton.py (bandai_namco driven by lafan1's BMM): error: --bmm lafan1: pretrained model 'lafan1' is not bundled" in error
    assert not (tmp_path / "x.json").exists()


def test_the_report_gathers_each_runs_figures(experiment, monkeypatch, tmp_path):
    """A real run on a folder of the bundled clip, the bundled BMM standing in for LaFAN1's
    (``--trained-on lafan1``: its curves are transferred as LaFAN1's would be)."""
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    clips = tmp_path / "clips"
    clips.mkdir()
    for i in range(2):
        shutil.copy(DEMO_CLIP, clips / f"walk_{i + 1}.bvh")
    real_main, calls = experiment.pipeline_eval.main, []

    def small(argv):
        calls.append(argv)
        if argv[argv.index("--bmm") + 1] == "lafan1":
            argv = [*argv, "--bmm", "bandai_namco", "--trained-on", "lafan1"]  # the later flag wins
        return real_main([*argv, "--bvh-dir", str(clips), "--steps", "2", "--chunk", "2"])

    monkeypatch.setattr(experiment.pipeline_eval, "main", small)
    monkeypatch.setattr(experiment, "check_runs", lambda args: None)  # LaFAN1's model is not trained here
    out = tmp_path / "cross.json"
    result = experiment.main(["--out", str(out), "--targets", "bandai_namco", "--windows", "2", "--ik", "rig"])
    report = out.with_suffix(".md").read_text()
    assert json.loads(out.read_text()) == result and "(transferred, × " in report and "feet locked" not in report
    assert len(calls) == 2 and [(r["target"], r["bmm"], r["ik"]) for r in result["rows"]] == [
        ("bandai_namco", "bandai_namco", "rig"), ("bandai_namco", "lafan1", "rig")
    ]  # fmt: skip
    own, moved = (json.loads((tmp_path / f"cross.bandai_namco.{s}.json").read_text()) for s in ("bandai_namco", "lafan1"))
    assert own["settings"]["rows"] == moved["settings"]["rows"]  # the same windows and handles for both BMMs
    expected = Transfer.between(load_profile("lafan1"), load_profile("bandai_namco"))
    assert result["rows"][0]["transfer_scale"] is None and result["rows"][1]["transfer_scale"] == pytest.approx(float(expected.scale))
    for row, run in zip(result["rows"], (own, moved)):
        assert row["handles_error_cm"] == run["ik"]["rig"]["id"]["handles_error_cm"]
        assert row["ood_mpjpe_cm"] == run["ik"]["rig"]["ood"]["mpjpe_cm"]
        assert row["curves_dense_error_cm"] == run["curves"]["bmm"]["id"]["dense_error_cm"]
