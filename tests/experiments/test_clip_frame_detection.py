"""``experiments/clip_frame_detection.py`` counts each clip told right, wrong or refused per
corpus and convention, and lists the misses (here on the bundled clip and a copy lying down
in every frame, standing in for the corpus's archive)."""

from __future__ import annotations

import json

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from helpers import load_experiment, turned_about_z


def test_counts_and_misses(tmp_path, monkeypatch):
    script = load_experiment("clip_frame_detection")
    clip = read_bvh(DEMO_CLIP)
    monkeypatch.setattr(script, "clips", lambda corpus, every: iter([("walk.bvh", clip), ("lying.bvh", turned_about_z(clip, 90.0))]))
    out = tmp_path / "detect.json"
    report = script.main(["--every", "1", "--corpora", "bandai_namco", "--frames", "cm/y", "m/z", "--out", str(out)])
    assert json.loads(out.read_text()) == report
    assert report["counts"] == {"bandai_namco": {"cm/y": {"right": 1, "wrong": 0, "refused": 1}, "m/z": {"right": 1, "wrong": 0, "refused": 1}}}
    assert [(m["file"], m["frame"]) for m in report["misses"]] == [("lying.bvh", "cm/y"), ("lying.bvh", "m/z")]
    assert all(m["refused"].startswith("cannot tell the clip's up axis") for m in report["misses"])
