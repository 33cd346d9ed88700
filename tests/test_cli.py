"""The embedded default: ``bezmotion demo`` on the bundled clip."""

from __future__ import annotations

import json

import pytest

from bezmotion.cli import main


def test_demo_writes_bvh_files_and_interpolation_beats_zero_velocity(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--gap", "8"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["gap"] == 8 and summary["joints"] == 22
    for method in ("interpolation", "zero_velocity"):
        assert (tmp_path / f"{method}.bvh").read_text().startswith("HIERARCHY\n")
        assert summary[method]["bvh_roundtrip_error_cm"] < 1e-3
    assert summary["interpolation"]["mean_joint_error_cm"] < summary["zero_velocity"]["mean_joint_error_cm"]
    assert "Bandai Namco Research" in capsys.readouterr().out


@pytest.mark.parametrize("gap", ["0", "30"])
def test_demo_rejects_gaps_that_do_not_fit(tmp_path, capsys, gap):
    assert main(["demo", "--out", str(tmp_path), "--gap", gap]) == 2
    assert f"--gap must be between 1 and 29 for this 40-frame clip, got {gap}" in capsys.readouterr().err
