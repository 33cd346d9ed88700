"""Bandai-Namco and Anidance loaders: tiny synthetic corpora (always run) and the real archives (when present)."""

from __future__ import annotations

import json
import tarfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import SHARED_DATA

from bezmotion.assets import DEMO_CLIP
from bezmotion.data import anidance, bandai_namco
from bezmotion.data.anidance import (
    COLUMNS,
    anidance_statistics,
    anidance_windows,
    load_anidance,
    parse_anidance_csv,
)
from bezmotion.data.bandai_namco import is_validation_clip, load_bandai_namco
from bezmotion.data.bvh import format_bvh, parse_bvh, read_bvh

FIXTURE = DEMO_CLIP  # the bundled real clip (attribution: bezmotion/assets/README.md)
BANDAI_ARCHIVE = SHARED_DATA / "bandai-namco" / "bandai-namco-2.tar.xz"
ANIDANCE_ARCHIVE = SHARED_DATA / "anidance" / "anidance.tar.xz"
BANDAI_ROOT = "Bandai-Namco-Research-Motiondataset-2"
CONTENTS = ("walk", "walk-turn-left", "walk-turn-right", "run", "wave-both-hands", "wave-left-hand",
            "wave-right-hand", "raise-up-both-hands", "raise-up-left-hand", "raise-up-right-hand")  # fmt: skip
STYLES = ("active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful")


@pytest.fixture(autouse=True)
def private_cache(tmp_path: Path, monkeypatch) -> Path:
    """Every test gets its own empty cache folder (never the user's)."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("BEZMOTION_CACHE", str(cache))
    return cache


def count_builds(monkeypatch, module) -> list[int]:
    """Wrap ``module._parse_corpus`` so the test can count how often the corpus is really parsed."""
    calls: list[int] = []
    original = module._parse_corpus

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, "_parse_corpus", counting)
    return calls


def make_tar_xz(folder: Path, archive: Path) -> Path:
    """Pack the contents of ``folder`` (members relative to it), as the published archives are."""
    with tarfile.open(archive, "w:xz") as tar:
        for path in sorted(folder.rglob("*")):
            tar.add(path, arcname=str(path.relative_to(folder)), recursive=False)
    return archive


# ----------------------------------------------------------------- synthetic Bandai-Namco

FIXTURE_LINES = FIXTURE.read_text().split("\n")
FRAMES_LINE = FIXTURE_LINES.index("Frames:\t40")


def clip_text(frames: int) -> str:
    """The fixture cut to its first ``frames`` frames (a real clip, shorter)."""
    header, rows = FIXTURE_LINES[:FRAMES_LINE], FIXTURE_LINES[FRAMES_LINE + 1 : FRAMES_LINE + 2 + frames]
    lines = header + [f"Frames:\t{frames}"] + rows  # rows: the Frame Time line, then the frames
    return "\n".join(lines) + "\n"


SYNTHETIC_CLIPS = {  # name: (frames, json label)
    "dataset-2_walk_normal_001": (40, {"content": 0, "style": 5}),
    "dataset-2_walk_normal_010": (25, {"content": 0, "style": 5}),
    "dataset-2_run_active_002": (12, {"content": 3, "style": 0}),
}


def make_bandai(parent: Path, clips=SYNTHETIC_CLIPS, texts: dict[str, str] | None = None) -> Path:
    """A miniature Bandai-Namco folder under ``parent`` laid out like the real one; returns its root."""
    root = parent / BANDAI_ROOT
    (root / "data").mkdir(parents=True)
    (root / "cfg").mkdir()
    (root / "cfg" / "content_label.txt").write_text("\n".join(f"dataset-2_{c}" for c in CONTENTS))
    (root / "cfg" / "style_label.txt").write_text("\n".join(f"dataset-2_{s}" for s in STYLES))
    for name, (frames, label) in clips.items():
        (root / "data" / f"{name}.bvh").write_text((texts or {}).get(name, clip_text(frames)))
        (root / "data" / f"{name}.json").write_text(json.dumps(label))
    return root


def test_bandai_namco_from_directory_parent_and_archive_agree(tmp_path: Path):
    root = make_bandai(tmp_path / "extracted")
    archive = make_tar_xz(tmp_path / "extracted", tmp_path / "bandai.tar.xz")
    corpora = [load_bandai_namco(s, progress=False) for s in (root, root.parent, archive)]
    for corpus in corpora[1:]:
        assert corpus.names == corpora[0].names
        np.testing.assert_array_equal(corpus.quat_local, corpora[0].quat_local)
        np.testing.assert_array_equal(corpus.pos_local, corpora[0].pos_local)
        np.testing.assert_array_equal(corpus.offsets, corpora[0].offsets)

    corpus = corpora[0]
    assert corpus.names == tuple(sorted(SYNTHETIC_CLIPS))
    assert corpus.content_labels == CONTENTS and corpus.style_labels == STYLES
    np.testing.assert_array_equal(corpus.starts, [0, 12, 52, 77])
    run, walk1, walk10 = (corpus.clip(i) for i in range(3))
    assert (run.content, run.style, run.clip_id, run.num_frames) == ("run", "active", 2, 12)
    assert (walk10.content, walk10.style, walk10.clip_id) == ("walk", "normal", 10)
    assert walk1.frame_time == 0.0333333 and corpus.skeleton.names[:2] == ("joint_Root", "Hips")
    reference = read_bvh(FIXTURE)
    np.testing.assert_array_equal(walk1.quat_local, reference.quat_local)
    np.testing.assert_array_equal(walk1.pos_local, reference.pos_local)
    np.testing.assert_array_equal(walk1.offsets, np.asarray(reference.skeleton.offsets))
    # A clip written back reads as the same motion.
    again = parse_bvh(format_bvh(corpus.to_bvh(1)))
    np.testing.assert_array_equal(again.quat_local, reference.quat_local)
    assert again.end_sites == reference.end_sites and again.channels == reference.channels


def test_bandai_namco_split_is_by_clip_id(tmp_path: Path):
    corpus = load_bandai_namco(make_bandai(tmp_path), progress=False)
    train, validation = corpus.split("train"), corpus.split("validation")
    assert [corpus.names[i] for i in validation] == ["dataset-2_walk_normal_010"]
    assert sorted(np.concatenate([train, validation])) == list(range(len(corpus)))
    assert [is_validation_clip(i) for i in (1, 9, 10, 20, 101)] == [False, False, True, True, False]


def test_bandai_namco_clip_id_filter(tmp_path: Path):
    root = make_bandai(tmp_path)
    corpus = load_bandai_namco(root, clip_ids=[1, 2], progress=False)
    assert corpus.names == ("dataset-2_run_active_002", "dataset-2_walk_normal_001")
    with pytest.raises(ValueError, match=r"no Bandai-Namco clips found with ids \[7\]"):
        load_bandai_namco(root, clip_ids=[7], progress=False)


@pytest.mark.parametrize(
    ("label", "message"),
    [
        ({"content": 3, "style": 5}, r"_010\.json: content index 3 is 'dataset-2_run' but the file name says 'walk'"),
        ({"content": 0, "style": 7}, r"dataset-2_walk_normal_010\.json: style index 7 outside 0\.\.6"),
        ({"content": 0}, r"dataset-2_walk_normal_010\.json: expected \{\"content\": <int>, \"style\": <int>\}"),
    ],
)  # fmt: skip
def test_bandai_namco_label_problems_name_the_clip(label, message, tmp_path: Path):
    clips = dict(SYNTHETIC_CLIPS, **{"dataset-2_walk_normal_010": (25, label)})
    with pytest.raises(ValueError, match=message):
        load_bandai_namco(make_bandai(tmp_path, clips), progress=False)


def test_bandai_namco_rejects_a_clip_with_another_hierarchy(tmp_path: Path):
    texts = {"dataset-2_run_active_002": clip_text(12).replace("JOINT Chest", "JOINT Torso")}
    expected = r"walk_normal_001\.bvh: its hierarchy .* differs from that of dataset-2_run_active_002\.bvh"
    with pytest.raises(ValueError, match=expected):
        load_bandai_namco(make_bandai(tmp_path, texts=texts), progress=False)


def test_bandai_namco_malformed_clip_names_file_and_line(tmp_path: Path):
    texts = {"dataset-2_walk_normal_010": clip_text(25).replace("Frames:\t25", "Frames:\t26")}
    root = make_bandai(tmp_path, texts=texts)
    expected = r"dataset-2_walk_normal_010\.bvh:159: 'Frames:' announces 26 frames but the file has 25"
    with pytest.raises(ValueError, match=expected):
        load_bandai_namco(root, progress=False)


def test_bandai_namco_second_load_hits_the_cache(tmp_path: Path, private_cache: Path, monkeypatch):
    builds = count_builds(monkeypatch, bandai_namco)
    root = make_bandai(tmp_path)
    first = load_bandai_namco(root, progress=False)
    second = load_bandai_namco(root.parent, progress=False)  # same files, same key
    assert len(builds) == 1 and len(list(private_cache.glob("bandai-namco-*.npz"))) == 1
    np.testing.assert_array_equal(first.quat_local, second.quat_local)
    assert first.names == second.names and first.end_sites == second.end_sites and first.channels == second.channels
    load_bandai_namco(root, clip_ids=[1], progress=False)  # another selection is another entry
    (root / "data" / "dataset-2_walk_normal_010.bvh").write_text(clip_text(24))  # changed data
    load_bandai_namco(root, progress=False)
    assert len(builds) == 3
    load_bandai_namco(root, use_cache=False, progress=False)
    assert len(builds) == 4 and len(list(private_cache.glob("*.npz"))) == 3


def test_bandai_namco_missing_source():
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_bandai_namco("/nonexistent/bandai.tar.xz")


# --------------------------------------------------------------------- synthetic Anidance

HEADER = ",".join(COLUMNS)


def csv_text(frames: int, seed: int) -> str:
    values = np.random.default_rng(seed).normal(scale=50.0, size=(frames, 72))
    return HEADER + "\n" + "\n".join(",".join(repr(float(v)) for v in row) for row in values) + "\n"


ANIDANCE_FILES = {"dance_a_1": 300, "dance_a_2": 200, "dance_b_1": 150}
ANIDANCE_SPLIT = {
    "training_files": ["dances/dance_a_1.csv", "dances/dance_x_9.csv", "dances/dance_a_2.csv"],
    "validation_files": ["dances/dance_b_1.csv", "dances/dance_y_3.csv"],
}


def make_anidance(folder: Path, texts: dict[str, str] | None = None) -> Path:
    """A miniature Anidance folder laid out like the archive (``split.json`` + ``dances/``)."""
    (folder / "dances").mkdir(parents=True)
    (folder / "split.json").write_text(json.dumps(ANIDANCE_SPLIT, indent=4))
    for k, (name, frames) in enumerate(ANIDANCE_FILES.items()):
        (folder / "dances" / f"{name}.csv").write_text((texts or {}).get(name, csv_text(frames, seed=k)))
    return folder


def load_quietly(source, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_anidance(source, progress=False, **kwargs)


def test_anidance_drops_missing_files_with_one_warning_naming_them(tmp_path: Path):
    root = make_anidance(tmp_path / "anidance")
    with pytest.warns(UserWarning) as record:
        corpus = load_anidance(root, progress=False)
    messages = [str(w.message) for w in record]
    assert len(messages) == 1
    assert "2 file(s) listed in split.json are absent" in messages[0]
    assert "dances/dance_x_9.csv" in messages[0] and "dances/dance_y_3.csv" in messages[0]
    assert corpus.missing == ("dances/dance_x_9.csv", "dances/dance_y_3.csv")
    assert corpus.names == ("dance_a_1", "dance_a_2", "dance_b_1")
    np.testing.assert_array_equal(corpus.is_validation, [False, False, True])
    np.testing.assert_array_equal(corpus.indices(validation=False), [0, 1])
    expected = np.loadtxt(root / "dances" / "dance_a_2.csv", delimiter=",", skiprows=1).reshape(-1, 24, 3)
    np.testing.assert_array_equal(corpus.sequence(1), expected)
    assert corpus.positions.dtype == np.float64 and corpus.positions.shape == (650, 24, 3)


def test_anidance_from_archive_directory_and_parent_agree(tmp_path: Path):
    root = make_anidance(tmp_path / "extracted")
    archive = make_tar_xz(root, tmp_path / "anidance.tar.xz")
    corpora = [load_quietly(s) for s in (root, tmp_path, archive)]
    for corpus in corpora[1:]:
        assert corpus.names == corpora[0].names and corpus.missing == corpora[0].missing
        np.testing.assert_array_equal(corpus.positions, corpora[0].positions)


def test_anidance_ignores_unlisted_files_with_a_warning(tmp_path: Path):
    root = make_anidance(tmp_path)
    (root / "dances" / "dance_z_1.csv").write_text(csv_text(10, seed=9))
    with pytest.warns(UserWarning) as record:
        corpus = load_anidance(root, progress=False)
    assert any("1 file(s) not in split.json were ignored: dance_z_1" in str(w.message) for w in record)
    assert "dance_z_1" not in corpus.names


def test_anidance_windows_and_statistics(tmp_path: Path):
    corpus = load_quietly(make_anidance(tmp_path))
    train = anidance_windows(corpus, validation=False)
    # 300 frames → starts 0, 64, 128 (192 + 128 = 320 > 300); 200 frames → 0, 64.
    np.testing.assert_array_equal(train.file_index, [0, 0, 0, 1, 1])
    np.testing.assert_array_equal(train.start_frame, [0, 64, 128, 0, 64])
    assert train.positions.shape == (5, 128, 24, 3)
    np.testing.assert_array_equal(train.positions[4], corpus.sequence(1)[64:192])
    validation = anidance_windows(corpus, validation=True)
    np.testing.assert_array_equal(validation.start_frame, [0])
    np.testing.assert_array_equal(validation.positions[0], corpus.sequence(2)[:128])

    stats = anidance_statistics(corpus)
    frames = np.concatenate([corpus.sequence(f)[s : s + 128] for f, s in zip(train.file_index, train.start_frame)])
    np.testing.assert_allclose(stats.x_mean, frames.reshape(-1, 72).mean(axis=0), rtol=1e-12)
    deviation = frames.reshape(-1, 72) - stats.x_mean
    np.testing.assert_allclose(stats.x_std, np.sqrt((deviation**2).mean(axis=0)), rtol=1e-12)  # ddof 0
    with pytest.raises(ValueError, match="no Anidance validation windows of 200 frames"):
        anidance_windows(corpus, validation=True, window=200)


def _with_line(text: str, lineno: int, line: str) -> str:
    lines = text.split("\n")
    lines[lineno - 1] = line
    return "\n".join(lines)


GOOD_ROW = ",".join(["1.5"] * 72)
MALFORMED_CSV = {
    "too few columns": (5, ",".join(["1.5"] * 71), r"expected 72 comma-separated values, got 71"),
    "too many columns": (3, GOOD_ROW + ",2", r"expected 72 comma-separated values, got 73"),
    "non-numeric": (4, ",".join(["1.5"] * 10 + ["abc"] + ["1.5"] * 61), r"column bone_2_y: 'abc' is not a number"),
    "empty field": (6, ",".join(["1.5"] * 71 + [""]), r"column bone_22_z: '' is not a number"),
    "nan": (2, ",".join(["nan"] + ["1.5"] * 71), r"column center_x: non-finite value 'nan'"),
    "wrong header": (1, HEADER.replace("bone_0_x", "bone_O_x"), r"expected the header center_x,…,bone_22_z"),
}


@pytest.mark.parametrize("case", list(MALFORMED_CSV))
def test_malformed_csv_names_file_and_line(case: str, tmp_path: Path):
    lineno, line, phrase = MALFORMED_CSV[case]
    text = _with_line(csv_text(8, seed=0), lineno, line)
    with pytest.raises(ValueError, match=rf"^<mem>:{lineno}: {phrase}"):
        parse_anidance_csv(text, "<mem>")
    root = make_anidance(tmp_path, texts={"dance_a_2": text})
    with pytest.raises(ValueError, match=rf"dances/dance_a_2\.csv:{lineno}: {phrase}"):
        load_quietly(root)


def test_anidance_second_load_hits_the_cache_and_still_warns(tmp_path: Path, private_cache: Path, monkeypatch):
    builds = count_builds(monkeypatch, anidance)
    root = make_anidance(tmp_path)
    first = load_quietly(root)
    with pytest.warns(UserWarning, match="dance_x_9"):
        second = load_anidance(root, progress=False)
    assert len(builds) == 1 and len(list(private_cache.glob("anidance-*.npz"))) == 1
    np.testing.assert_array_equal(first.positions, second.positions)
    assert first.names == second.names and first.missing == second.missing


# -------------------------------------------------------------------------- real archives


@pytest.mark.skipif(not BANDAI_ARCHIVE.exists(), reason=f"{BANDAI_ARCHIVE} not found")
def test_real_bandai_namco_subset_from_the_archive():
    corpus = load_bandai_namco(BANDAI_ARCHIVE, clip_ids=[1, 10], progress=False)
    assert len(corpus) == 140  # takes 1 and 10 of each of the 70 content × style classes
    assert corpus.content_labels == CONTENTS and corpus.style_labels == STYLES
    classes = {(corpus.content_ids[i], corpus.style_ids[i]) for i in range(len(corpus))}
    assert len(classes) == 70
    for clip in corpus.clips():
        assert clip.name == f"dataset-2_{clip.content}_{clip.style}_{clip.clip_id:03d}"
        assert clip.frame_time == 0.0333333
    train, validation = corpus.split("train"), corpus.split("validation")
    assert len(train) == len(validation) == 70
    assert all(corpus.clip_ids[validation] == 10)
    np.testing.assert_allclose(np.linalg.norm(corpus.quat_local, axis=-1), 1.0, atol=1e-12)
    # Only the Hips OFFSET differs between clips, and it is overridden by its position channels.
    spread = corpus.offsets.max(axis=0) - corpus.offsets.min(axis=0)
    assert np.all(np.delete(spread, 1, axis=0) == 0)
    walk = corpus.clip(corpus.index("dataset-2_walk_normal_001"))
    fixture = read_bvh(FIXTURE)
    np.testing.assert_array_equal(walk.quat_local[:40], fixture.quat_local)
    np.testing.assert_array_equal(walk.pos_local[:40], fixture.pos_local)


@pytest.mark.skipif(not ANIDANCE_ARCHIVE.exists(), reason=f"{ANIDANCE_ARCHIVE} not found")
def test_real_anidance_archive():
    with pytest.warns(UserWarning) as record:
        corpus = load_anidance(ANIDANCE_ARCHIVE, progress=False)
    (message,) = [str(w.message) for w in record]
    absent = ["dance_c_1", "dance_c_3", "dance_r_1"] + [f"dance_t_{k}" for k in range(1, 10)]
    assert all(f"dances/{name}.csv" in message for name in absent)
    assert len(corpus) == 49 and corpus.is_validation.sum() == 11
    assert corpus.positions.shape == (39_500, 24, 3)
    train = anidance_windows(corpus, validation=False)
    validation = anidance_windows(corpus, validation=True)
    assert (train.num_windows, validation.num_windows) == (403, 143)
    stats = anidance_statistics(corpus)
    assert stats.x_mean.shape == stats.x_std.shape == (72,)
    assert np.all(np.isfinite(stats.x_mean)) and np.all(stats.x_std > 0)
