"""experiments/_common.py: opening a published corpus or a user's BVH folder for the scripts."""

from __future__ import annotations

import dataclasses
import importlib.util
import json

import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh, write_bvh
from helpers import REPO_ROOT

ROLES = {"hips": "Hips", "head": "Head", "left_hand": "Hand_L", "right_hand": "Hand_R", "left_foot": "Foot_L", "right_foot": "Foot_R"}


@pytest.fixture(scope="module")
def common():
    spec = importlib.util.spec_from_file_location("_experiments_common", REPO_ROOT / "experiments" / "_common.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def clips(tmp_path, monkeypatch):
    """Three slices of the bundled Bandai-Namco clip as a user's folder (cache in tmp)."""
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    clip = read_bvh(DEMO_CLIP)
    folder = tmp_path / "my_clips"
    folder.mkdir()
    for i, start in enumerate((0, 10, 20)):
        part = dataclasses.replace(clip, quat_local=clip.quat_local[start : start + 20], pos_local=clip.pos_local[start : start + 20])
        write_bvh(folder / f"take_{i}.bvh", part)
    return folder


def test_a_folder_opens_with_a_json_map_of_its_joints(common, clips, tmp_path):
    mapping = tmp_path / "joints.json"
    mapping.write_text(json.dumps(ROLES))
    corpus = common.open_corpus(str(clips), characteristic=str(mapping), progress=False)
    assert corpus.name == "my_clips" and len(corpus) == 3
    assert dict(corpus.characteristic_map) == ROLES
    assert common.corpus_label(str(clips) + "/") == "my_clips" and common.corpus_label("lafan1") == "lafan1"


def test_a_folder_opens_with_a_preset_map(common, clips):
    assert common.open_corpus(str(clips), characteristic="bandai_namco", progress=False).characteristic_map == "bandai_namco"


def test_options_that_do_not_apply_are_refused(common, clips, tmp_path):
    with pytest.raises(ValueError, match="--characteristic is for BVH folders; lafan1"):
        common.open_corpus("lafan1", characteristic="lafan1")
    with pytest.raises(ValueError, match="--data is for the published corpora"):
        common.open_corpus(str(clips), data="somewhere.zip")
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(ValueError, match="broken.json: not a readable JSON map"):
        common.open_corpus(str(clips), characteristic=str(broken))
    with pytest.raises(ValueError, match="or a folder of .bvh files, got 'no_such_corpus'"):
        common.open_corpus("no_such_corpus")
