"""The embedded default: ``bezmotion demo`` on the bundled clip with the bundled models."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bezmotion.cli import main
from bezmotion.data.bvh import read_bvh


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """One demo run in a small setting (2 DDIM steps), shared by the checks below."""
    out = tmp_path_factory.mktemp("demo")
    code = main(["demo", "--out", str(out), "--steps", "2"])
    return code, out, json.loads((out / "summary.json").read_text()) if code == 0 else None


def test_demo_runs_and_its_curves_pass_through_the_handle(demo_run):
    code, out, summary = demo_run
    assert code == 0
    assert summary["frames"] == 31 and summary["joints"] == 22 and summary["steps"] == 2
    assert summary["curve_handle_error_cm"] == 0.0  # overwrite: the handle, bit for bit
    # The handle moves the right hand 25 cm above the mocap; the default IK (learned, then
    # exact two-bone limbs) puts the hand on it.
    assert summary["ik"] == "refined"
    assert summary["joint_moved_cm"] > 20.0
    assert summary["full_body_handle_error_cm"] < 1e-2


def test_demo_bvh_reads_back_and_matches_the_pipeline(demo_run):
    _, out, summary = demo_run
    assert summary["bvh_fk_error_cm"] < 1e-3  # FK of the re-read file vs the pipeline's poses
    for name in ("inbetween.bvh", "ground_truth.bvh"):
        motion = read_bvh(out / name)
        assert motion.num_frames == 31 and motion.skeleton.num_joints == 22
        assert np.isfinite(motion.quat_local).all()
    assert (out / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_prints_the_data_attribution(demo_run, capsys):
    _, out, summary = demo_run
    assert "Bandai Namco Research" in summary["attribution"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--frame", "7"], "multiples of 6"),
        (["--frame", "30"], "multiples of 6"),
        (["--steps", "0"], "--steps must be at least 1, got 0"),
        (["--bmm-corpus", "amass"], "--bmm-corpus must be one of"),
    ],
)
def test_demo_rejects_bad_arguments_with_a_clear_message(tmp_path, capsys, args, message):
    assert main(["demo", "--out", str(tmp_path), *args]) == 2
    assert message in capsys.readouterr().err
