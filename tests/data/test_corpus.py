"""One corpus interface: a user's BVH folder, any Bandai-Namco release, LaFAN1 and Anidance
behind the same :class:`Corpus`, feeding curve datasets and IK frames alike.

Every folder is built in ``tmp_path`` from the bundled 40-frame Bandai-Namco clip (written
back with our own ``write_bvh``) or from the synthetic LaFAN1 zip; no real data is copied.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.anidance import AnidanceCorpus
from bezmotion.data.bandai_namco import load_bandai_namco
from bezmotion.data.bvh import BvhMotion, read_bvh, write_bvh
from bezmotion.data.bvh_folder import load_bvh_folder
from bezmotion.data.resample import resample_motion
from bezmotion.data.corpus import Corpus, MotionClips, motion_clips
from bezmotion.data.curves import build_curve_dataset, curve_dataset
from bezmotion.data.lafan1 import JOINT_NAMES
from bezmotion.data.sources import DATA_ENV, default_source, load_corpus
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.frames import corpus_character, corpus_frame_starts, corpus_frames
from bezmotion.ik.protocol import pose_from_motion

DEMO = read_bvh(DEMO_CLIP)  # 40 frames at 30 fps, 22 joints (joint_Root, Hips, …)
SLICES = {"a_walk": slice(0, 40), "b_walk": slice(0, 35), "c_walk": slice(5, 38)}  # 40, 35, 33 frames


@pytest.fixture(autouse=True)
def private_cache(tmp_path: Path, monkeypatch) -> Path:
    cache = tmp_path / "cache"
    monkeypatch.setenv("BEZMOTION_CACHE", str(cache))
    return cache


def sliced(motion: BvhMotion, frames: slice) -> BvhMotion:
    return dataclasses.replace(motion, quat_local=motion.quat_local[frames], pos_local=motion.pos_local[frames])


def write_folder(folder: Path, slices=SLICES, motion: BvhMotion = DEMO) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, frames in slices.items():
        write_bvh(folder / f"{name}.bvh", sliced(motion, frames))
    return folder


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    return write_folder(tmp_path / "my_clips")


# ---------------------------------------------------------------------------- BVH folder


def test_bvh_folder_corpus_loads_and_splits(folder: Path):
    corpus = load_bvh_folder(folder, characteristic="bandai_namco", validation_files=["c_walk.bvh"])
    assert isinstance(corpus, Corpus)
    assert corpus.name == "my_clips" and len(corpus) == 3 and corpus.clip_names == ("a_walk", "b_walk", "c_walk")
    assert corpus.split("train").tolist() == [0, 1] and corpus.split("validation").tolist() == [2]
    assert corpus.labels(2) == {"file": "c_walk"} and corpus.fps == round(1 / DEMO.frame_time, 6)
    assert corpus.skeleton.names == DEMO.skeleton.names and corpus.end_sites == DEMO.end_sites
    written = [read_bvh(folder / f"{name}.bvh") for name in SLICES]
    clips = corpus.motion([2, 0])
    assert clips.starts.tolist() == [0, 33, 73]
    np.testing.assert_array_equal(clips.quat_local[:33], written[2].quat_local)
    np.testing.assert_array_equal(clips.pos_local[33:], written[0].pos_local)
    # The default rule: every 10th file validates (none of three); or every n-th file.
    assert load_bvh_folder(folder).split("validation").tolist() == []
    assert load_bvh_folder(folder, validation_every=2).split("validation").tolist() == [1]
    # load_corpus opens a folder by path, with the same options.
    same = load_corpus(folder, characteristic="bandai_namco", validation_files=["c_walk"])
    assert same.clip_names == corpus.clip_names and same.split("validation").tolist() == [2]


def test_bvh_folder_feeds_curve_datasets_and_ik_frames(folder: Path, private_cache: Path):
    corpus = load_bvh_folder(folder, characteristic="bandai_namco", validation_files=["c_walk"])
    written = [read_bvh(folder / f"{name}.bvh") for name in SLICES]
    train = curve_dataset(corpus, "train", progress=False)
    expected = build_curve_dataset(MotionClips.from_bvh(written[:2]), "bandai_namco", progress=False)
    assert train.clip_index.tolist() == [0, 0, 1] and train.start_frame.tolist() == [0, 5, 0]
    for name in ("ctrl_pos", "ctrl_tangent", "ctrl_rot6d", "dense_pos", "dense_contacts", "fit_rms"):
        np.testing.assert_array_equal(getattr(train, name), getattr(expected, name), err_msg=name)
    assert len(list(private_cache.glob("my-clips-curves-*.npz"))) == 1
    curve_dataset(corpus, "train", progress=False)  # a cache hit: no new entry
    assert len(list(private_cache.glob("my-clips-curves-*.npz"))) == 1
    # Another split rule is another cache entry.
    other = load_bvh_folder(folder, characteristic="bandai_namco", validation_files=["a_walk"])
    assert curve_dataset(other, "train", progress=False).clip_index.tolist() == [0, 1]
    assert len(list(private_cache.glob("my-clips-curves-*.npz"))) == 2

    character, poses = corpus_frames(corpus, "validation", frame_step=2)
    assert character.name == "my_clips" and character.end_sites == DEMO.end_sites
    clip = written[2]
    want = pose_from_motion(
        character, jnp.asarray(clip.quat_local[::2], jnp.float32), jnp.asarray(clip.pos_local[::2], jnp.float32)
    )
    np.testing.assert_array_equal(np.asarray(poses.root_pos), np.asarray(want.root_pos))
    np.testing.assert_array_equal(np.asarray(poses.quat_local), np.asarray(want.quat_local))
    assert corpus_frame_starts(corpus, "train", frame_step=2).tolist() == [0, 20, 38]


def test_bvh_folder_with_another_skeleton_names_the_file(folder: Path):
    renamed = Skeleton(DEMO.skeleton.parents, ("joint_Root", "Pelvis", *DEMO.skeleton.names[2:]), DEMO.skeleton.offsets)
    write_bvh(folder / "d_other.bvh", dataclasses.replace(DEMO, skeleton=renamed))
    with pytest.raises(ValueError, match=r"d_other\.bvh: its skeleton .*'Pelvis'.* differs from that of a_walk\.bvh"):
        load_bvh_folder(folder)


def rotations_only(skeleton: Skeleton) -> BvhMotion:
    """DEMO's motion with the usual channels: positions on the root only, so OFFSETs are the bones."""
    return BvhMotion.from_skeleton(skeleton, DEMO.quat_local, DEMO.pos_local[:, 0], frame_time=DEMO.frame_time)


def test_bvh_folder_with_other_bone_lengths_or_frame_time_names_the_file(tmp_path: Path):
    folder = write_folder(tmp_path / "usual", {"a": slice(0, 40), "b": slice(0, 30)}, rotations_only(DEMO.skeleton))
    assert len(load_bvh_folder(folder, use_cache=False)) == 2
    offsets = np.asarray(DEMO.skeleton.offsets).copy()
    offsets[DEMO.skeleton.names.index("Head"), 1] += 2.0  # a longer neck: another skeleton
    write_bvh(folder / "b.bvh", rotations_only(Skeleton(DEMO.skeleton.parents, DEMO.skeleton.names, offsets)))
    with pytest.raises(ValueError, match=r"b\.bvh: joint 'Head' has OFFSET .* a\.bvh has"):
        load_bvh_folder(folder)
    slower = write_folder(tmp_path / "slow", {"a": slice(0, 40)})
    write_bvh(slower / "b.bvh", dataclasses.replace(DEMO, frame_time=1 / 60))
    with pytest.raises(ValueError, match=r"b\.bvh: frame time 0\.01666"):
        load_bvh_folder(slower)


def test_bvh_folder_at_one_rate_resamples_files_of_others(tmp_path: Path):
    """``fps=30``: a 60 fps file (DEMO upsampled) joins a 30 fps one, both at 30 fps, the
    60 fps file's every other frame being DEMO's own; the rate is part of the cache key."""
    folder = write_folder(tmp_path / "mixed", {"a": slice(0, 40)})
    fast, _ = resample_motion(DEMO, 60.0)
    write_bvh(folder / "b.bvh", fast, precision=10)
    corpus = load_bvh_folder(folder, fps=30.0)
    assert corpus.fps == pytest.approx(30.0, abs=1e-4) and corpus.starts.tolist() == [0, 40, 80]
    np.testing.assert_allclose(corpus.quat_local[40:], DEMO.quat_local, atol=1e-9)
    np.testing.assert_allclose(corpus.pos_local[40:], DEMO.pos_local, atol=1e-8)
    with pytest.raises(ValueError, match=r"b\.bvh: frame time 0\.01666"):
        load_bvh_folder(folder)  # cached at 30 fps above; as they are, the rates still differ


def test_bvh_folder_bad_input(tmp_path: Path, folder: Path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_bvh_folder(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no .bvh files found"):
        load_bvh_folder(tmp_path / "empty")
    with pytest.raises(ValueError, match=r"validation files \['z_walk'\] are not among"):
        load_bvh_folder(folder, validation_files=["z_walk"])
    with pytest.raises(ValueError, match="validation_every must be a positive integer or None, got 0"):
        load_bvh_folder(folder, validation_every=0)
    corpus = load_bvh_folder(folder)  # no characteristic joints named
    with pytest.raises(ValueError, match=r"my_clips: the corpus names no characteristic joints"):
        curve_dataset(corpus, "train")
    with pytest.raises(ValueError, match=r"my_clips: the corpus names no characteristic joints"):
        corpus_character(corpus)
    with pytest.raises(ValueError, match="split must be one of"):
        corpus.split("test")
    with pytest.raises(ValueError, match="not loaded from files"):
        dataclasses.replace(corpus, cache_inputs=()).source_key(v=1)


def test_load_corpus_names_and_errors(tmp_path: Path, monkeypatch, synthetic_zip):
    with pytest.raises(ValueError, match=r"corpus must be one of \('lafan1', 'bandai_namco', 'anidance'\) .*'amass'"):
        load_corpus("amass")
    with pytest.raises(ValueError, match=r"\['validation_every'\] apply to BVH folders only"):
        load_corpus("lafan1", validation_every=3)
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "data"))
    assert default_source("bandai_namco") == tmp_path / "data" / "bandai-namco" / "bandai-namco-2.tar.xz"
    (tmp_path / "data" / "lafan1").mkdir(parents=True)
    shutil.copy(synthetic_zip, tmp_path / "data" / "lafan1" / "lafan1-subset.zip")
    assert load_corpus("lafan1", progress=False).clip_names == ("dance1_subject5", "run2_subject2", "walk1_subject1")


# ---------------------------------------------------------------------------- LaFAN1


def test_lafan1_is_a_corpus(synthetic_zip):
    corpus = load_corpus("lafan1", source=synthetic_zip, use_cache=False, progress=False)
    assert isinstance(corpus, Corpus) and corpus.name == "lafan1" and corpus.fps == 30.0
    assert corpus.labels(1) == {"file": "run2_subject2", "sequence": "run2", "subject": 2}
    assert corpus.split("train").tolist() == [1, 2] and corpus.split("validation").tolist() == [0]
    np.testing.assert_array_equal(corpus.skeleton.offsets, corpus.offsets[1])  # the first training file's
    clips = motion_clips(corpus, "validation")
    quat, root = corpus.clip(0)
    np.testing.assert_array_equal(clips.quat_local, quat)
    np.testing.assert_array_equal(clips.pos_local[:, 0], root)
    np.testing.assert_array_equal(clips.pos_local[:, 1:], np.broadcast_to(corpus.offsets[0, 1:], (300, 21, 3)))
    character, poses = corpus_frames(corpus, "validation", frame_step=5)
    assert character.name == "lafan1" and character.skeleton.names == JOINT_NAMES and character.end_sites == ()
    np.testing.assert_array_equal(np.asarray(poses.root_pos), root[::5].astype(np.float32))
    np.testing.assert_array_equal(np.asarray(poses.quat_local), quat[::5].astype(np.float32))


# ------------------------------------------------------------------ Bandai-Namco, any release

RELEASE_1 = "Bandai-Namco-Research-Motiondataset-1"
CONTENTS_1 = ("bow", "walk")
STYLES_1 = ("normal", "not-confident")
CLIPS_1 = {  # name: (frames, json label)
    "dataset-1_walk_not-confident_001": (slice(0, 40), {"content": 1, "style": 1}),
    "dataset-1_walk_not-confident_010": (slice(0, 36), {"content": 1, "style": 1}),
    "dataset-1_bow_normal_002": (slice(10, 30), {"content": 0, "style": 0}),
}


def make_release(parent: Path, clips=CLIPS_1, styles=STYLES_1) -> Path:
    """A miniature ``Bandai-Namco-Research-Motiondataset-1`` folder laid out like release 2."""
    root = parent / RELEASE_1
    (root / "data").mkdir(parents=True)
    (root / "cfg").mkdir()
    (root / "cfg" / "content_label.txt").write_text("\n".join(f"dataset-1_{c}" for c in CONTENTS_1) + "\n")
    (root / "cfg" / "style_label.txt").write_text("\n".join(f"dataset-1_{s}" for s in styles) + "\n")
    for name, (frames, label) in clips.items():
        write_bvh(root / "data" / f"{name}.bvh", sliced(DEMO, frames))
        (root / "data" / f"{name}.json").write_text(json.dumps(label))
    return root


def test_bandai_namco_reads_another_release_with_hyphenated_styles(tmp_path: Path):
    corpus = load_corpus("bandai_namco", source=make_release(tmp_path).parent, progress=False)
    assert isinstance(corpus, Corpus) and corpus.release == "dataset-1"
    assert corpus.content_labels == CONTENTS_1 and corpus.style_labels == STYLES_1
    assert corpus.clip_names == tuple(sorted(CLIPS_1))
    assert corpus.labels(2) == {"file": "dataset-1_walk_not-confident_010", "content": "walk", "style": "not-confident", "take": 10}
    assert corpus.split("validation").tolist() == [2] and corpus.split("train").tolist() == [0, 1]
    assert corpus.motion(corpus.split("train")).starts.tolist() == [0, 20, 60]
    assert curve_dataset(corpus, "validation", progress=False).start_frame.tolist() == [0, 5]


def test_bandai_namco_release_prefixes_must_agree(tmp_path: Path):
    mixed = dict(CLIPS_1, **{"dataset-2_walk_normal_003": (slice(0, 20), {"content": 1, "style": 0})})
    with pytest.raises(ValueError, match=r"clip 'dataset-2_walk_normal_003' is not from release 'dataset-1'"):
        load_bandai_namco(make_release(tmp_path / "mixed", mixed), progress=False)
    root = make_release(tmp_path / "labels")
    (root / "cfg" / "style_label.txt").write_text("dataset-1_normal\ndataset-2_not-confident\n")
    expected = r"cfg/style_label\.txt: label 'dataset-2_not-confident' does not start with the clips' prefix 'dataset-1_'"
    with pytest.raises(ValueError, match=expected):
        load_bandai_namco(root, progress=False)


# ---------------------------------------------------------------------------- Anidance


def test_anidance_is_a_positions_only_corpus():
    corpus = AnidanceCorpus(
        names=("dance_a", "dance_b"), is_validation=np.array([False, True]), starts=np.array([0, 3, 5]),
        positions=np.zeros((5, 24, 3)),
    )  # fmt: skip
    assert isinstance(corpus, Corpus) and corpus.skeleton is None and corpus.fps == 25.0
    assert corpus.split("validation").tolist() == [1] and corpus.labels(0) == {"file": "dance_a", "split": "train"}
    with pytest.raises(ValueError, match="anidance: the corpus stores joint positions only"):
        motion_clips(corpus, "train")
    with pytest.raises(ValueError, match="anidance: a positions-only corpus has no rotations"):
        curve_dataset(corpus, "train")
    with pytest.raises(ValueError, match="anidance: a positions-only corpus has no skeleton"):
        corpus_frames(corpus, "train")
