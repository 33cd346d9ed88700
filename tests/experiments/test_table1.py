"""experiments/table1.py: every Table 1 row on one corpus, FID / diversity / multimodality,
Table 6 and Figure 12, and rows whose model is missing.

Runs without shared data: the corpus is a folder of two copies of the bundled Bandai-Namco
clip (one trains, one validates: two 31-frame windows each), the models are untrained tiny
ones saved into the test's folder (the bundled learned IK), so only the plumbing is tested.
"""

from __future__ import annotations

import json
import math
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bmm.common import TINY
from helpers import load_experiment

from bezmotion.assets import DEMO_CLIP
from bezmotion.evaluation.ablations import DenseBMMConfig, DenseMotionModel, dense_windows, init_dense_network, save_dense_model
from bezmotion.bmm.denoiser import init_denoiser
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, save_model
from bezmotion.data.bvh import read_bvh
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import build_curve_dataset
from bezmotion.evaluation.motion_features import (
    MotionFeatureConfig,
    MotionFeatureExtractor,
    WindowStats,
    canonical_windows,
    init_motion_autoencoder,
    save_motion_features,
)


@pytest.fixture(scope="module")
def experiment():
    return load_experiment("table1")


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """The corpus folder and untrained tiny models of every row, saved as the trainers save them."""
    root = tmp_path_factory.mktemp("table1")
    (root / "clips").mkdir()
    for i in range(2):
        shutil.copy(DEMO_CLIP, root / "clips" / f"walk_{i + 1}.bvh")
    clips = MotionClips.from_bvh([read_bvh(DEMO_CLIP)])
    curves = build_curve_dataset(clips, "bandai_namco", window=31, offset=1, progress=False)
    feats = np.concatenate([curves.ctrl_pos, curves.ctrl_tangent, curves.ctrl_rot6d], axis=-1).reshape(-1, 6, 12)
    stats = FeatureStats.from_features(feats[None])
    graphdef, params = init_denoiser(TINY, key=jax.random.key(0))
    save_model(root / "bmm", BezierMotionModel(params, stats, graphdef, TINY))
    for name, config in (
        ("minus_b", DenseBMMConfig.minus_b("tiny", dropout=0.0)),
        ("minus_ik_b", DenseBMMConfig.minus_ik_b(clips.joint_names, "bandai_namco", "tiny", dropout=0.0)),
        ("condmdi_g", DenseBMMConfig.condmdi_g(clips.joint_names, "bandai_namco", "tiny")),
    ):
        arrays, _, _ = dense_windows(clips, "bandai_namco", config, offset=1)
        graphdef, params = init_dense_network(config, key=jax.random.key(1))
        save_dense_model(root / name, DenseMotionModel(params, FeatureStats.from_features(arrays.features), graphdef, config))
    config = MotionFeatureConfig.tiny()
    graphdef, params = init_motion_autoencoder(config, key=jax.random.key(2))
    window_stats = WindowStats.from_windows(np.asarray(canonical_windows(jnp.asarray(curves.dense_pos), 90.0)))
    save_motion_features(root / "features", MotionFeatureExtractor(params, window_stats, graphdef, config))
    return root


def test_table1_every_row_table6_and_figure12(experiment, models, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "table1.json"
    c = "bandai_namco="
    results = experiment.main([
        "--out", str(out), "--corpora", "bandai_namco", "--data", c + str(models / "clips"), "--features", str(models / "features"),
        "--bmm", c + str(models / "bmm"), "--minus-b", c + str(models / "minus_b"), "--minus-ik-b", c + str(models / "minus_ik_b"),
        "--condmdi-g", c + str(models / "condmdi_g"), "--ik", "learned", "--windows", "0", "--steps", "2", "--table6-steps", "2", "--mm-conditions", "1",
        "--mm-samples", "2", "--chunk", "4", "--no-progress",
    ])  # fmt: skip
    saved = json.loads(out.read_text())
    table = saved["bandai_namco"]
    assert list(table) == ["mocap", "reference", "bmm", "bmm_exact", "bmm_minus_b", "bmm_minus_ik_b", "condmdi_g"]
    for row in table.values():
        assert set(experiment.METRICS) <= set(row)
    assert saved["info"]["bandai_namco"]["windows"] == 2
    # Rows with a model: every metric a finite number (the mocap's handles and multimodality excepted).
    for name in ("bmm", "bmm_minus_b", "bmm_minus_ik_b", "condmdi_g"):
        assert all(math.isfinite(table[name][m]) for m in experiment.METRICS), (name, table[name])
        assert table[name]["diversity"] > 0 and table[name]["multimodality"] > 0
    assert "note" not in table["bmm_minus_b"]  # after the learned IK
    mocap, ref = table["mocap"], table["reference"]
    assert mocap["handles_error_cm"] is None and mocap["multimodality"] is None and mocap["fid"] >= 0
    assert ref["handles_error_cm"] < 1e-3 and ref["ood_handles_error_cm"] < 1e-3 and ref["multimodality"] == 0.0
    assert table["bmm_exact"]["fid"] is None and "not requested" in table["bmm_exact"]["missing"]
    # CondMDIᴳ: evaluated as BMM⁻ᴵᴷ⁻ᴮ, at its own guidance.
    assert table["condmdi_g"]["guidance"] == 2.5 and table["bmm_minus_ik_b"]["guidance"] == 1.0
    assert table["condmdi_g"]["model"] == str(models / "condmdi_g") and "missing" not in table["condmdi_g"]
    assert list(saved["table6"]["bandai_namco"]) == ["2"]
    assert all(math.isfinite(r["fid"]) for r in saved["table6"]["bandai_namco"].values())
    assert results["bandai_namco"] == saved["bandai_namco"]
    assert out.with_suffix(".png").stat().st_size > 1000 and "Table 6 analogue" in out.with_suffix(".md").read_text()


def test_table1_missing_models_are_null_rows_naming_their_command(experiment, models, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "missing.json"
    c = "bandai_namco="
    experiment.main([
        "--out", str(out), "--corpora", "bandai_namco", "--data", c + str(models / "clips"), "--features", str(tmp_path / "none"),
        "--bmm", c + str(tmp_path / "no_bmm"), "--ik-model", c + str(tmp_path / "no_ik"), "--ik", "learned", "--windows", "0", "--no-progress",
    ])  # fmt: skip
    table = json.loads(out.read_text())["bandai_namco"]
    assert "experiments/bmm_lafan1.py --corpus bandai_namco" in table["bmm"]["missing"] and table["bmm"]["fid"] is None
    assert "experiments/train_ik.py --corpus bandai_namco" in table["bmm"]["missing"]  # both models lack: both commands
    assert "experiments/ablations.py --corpus bandai_namco --ablation minus_b" in table["bmm_minus_b"]["missing"]
    assert "--ablation minus_ik_b" in table["bmm_minus_ik_b"]["missing"]
    assert "CondMDIᴳ" in table["condmdi_g"]["missing"] and "--ablation condmdi_g" in table["condmdi_g"]["missing"]
    assert "ablation_condmdi_g_bandai_namco_cpu" in table["condmdi_g"]["missing"] and table["condmdi_g"]["fid"] is None
    assert table["mocap"]["fid"] is None and "experiments/motion_features.py" in table["mocap"]["naturalness_missing"]
    assert table["reference"]["handles_error_cm"] < 1e-3 and math.isfinite(table["mocap"]["foot_skating_ratio"])
    assert not out.with_suffix(".png").exists()
    # A later run of some rows takes the others from the earlier JSON of the same settings.
    again = experiment.main([
        "--out", str(tmp_path / "merged.json"), "--corpora", "bandai_namco", "--data", c + str(models / "clips"),
        "--features", str(tmp_path / "none"), "--rows", "mocap", "--merge", str(out), "--windows", "0", "--no-progress",
    ])["bandai_namco"]  # fmt: skip
    assert again["reference"]["merged_from"] == str(out) and again["bmm"]["missing"] == table["bmm"]["missing"]
    assert "merged_from" not in again["mocap"]
    with pytest.raises(ValueError, match="measured with other"):
        experiment.main(["--out", str(tmp_path / "m.json"), "--corpora", "bandai_namco", "--data", c + str(models / "clips"),
                         "--features", str(tmp_path / "none"), "--rows", "mocap", "--merge", str(out), "--windows", "1", "--no-progress"])


@pytest.mark.parametrize(
    "flags",
    [["--bmm", "amass=x"], ["--condmdi-g", "nowhere"], ["--mm-samples", "1"], ["--table6-steps", "0"], ["--rows", "nothing"], ["--exact", "speed=3"]],
)
def test_table1_bad_options_exit_through_the_parser(experiment, flags, capsys):
    with pytest.raises(SystemExit) as exit_:
        experiment.main(["--out", "x.json", *flags])
    assert exit_.value.code == 2 and "error" in capsys.readouterr().err
