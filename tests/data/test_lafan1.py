"""LaFAN1 corpus loading, official windowing and the benchmark runner.

Runs without ../shared on a synthetic corpus in the LaFAN1 layout (the ``synthetic_zip``
fixture in conftest: our own skeleton offsets and motion — never LaFAN1 data, which is
NoDerivatives); the real-data numbers are checked against an independent NumPy reference
in test_lafan1_reference.py.
"""

from __future__ import annotations

import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.data import lafan1
from bezmotion.data.windows import facing_rotation, sliding_window_starts
from bezmotion.evaluation.lafan1 import (
    evaluate_baselines,
    evaluate_transitions,
    format_table,
    interpolation_inbetweener,
    lafan1_benchmark,
)
from bezmotion.geometry import quat_between, quat_rotate


def test_sliding_windows_are_strict():
    # A window ending exactly on the last frame is dropped: 0+50 < 100, 20+50 < 100, 40+50 < 100; 60+50 > 100.
    assert sliding_window_starts(100, 50, 20).tolist() == [0, 20, 40]
    assert sliding_window_starts(90, 50, 20).tolist() == [0, 20]  # 40 + 50 == 90 is dropped
    assert sliding_window_starts(50, 50, 20).tolist() == []
    with pytest.raises(ValueError, match="window and offset must be positive"):
        sliding_window_starts(100, 0, 20)


def test_corpus_from_zip_and_directory_agree(synthetic_zip, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    corpus = lafan1.load_lafan1(synthetic_zip)
    assert corpus.sequences == ("dance1", "run2", "walk1")  # sorted by file name
    assert corpus.subjects == (5, 2, 1)
    assert corpus.starts.tolist() == [0, 300, 450, 680]
    extracted = tmp_path / "bvh"
    with zipfile.ZipFile(synthetic_zip) as zf:
        zf.extractall(extracted)
    from_dir = lafan1.load_lafan1(extracted)
    np.testing.assert_array_equal(from_dir.quat_local, corpus.quat_local)
    np.testing.assert_array_equal(from_dir.root_pos, corpus.root_pos)
    assert len(list((tmp_path / "cache").glob("lafan1-*.npz"))) == 2  # one entry per distinct input


def test_corpus_cache_is_reused(synthetic_zip, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    calls = []
    original = lafan1._parse_corpus
    monkeypatch.setattr(lafan1, "_parse_corpus", lambda src: calls.append(src) or original(src))
    first = lafan1.load_lafan1(synthetic_zip)
    second = lafan1.load_lafan1(synthetic_zip)
    assert len(calls) == 1
    np.testing.assert_array_equal(first.quat_local, second.quat_local)


def test_windows_follow_the_official_steps(synthetic_zip, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    corpus = lafan1.load_lafan1(synthetic_zip)
    w = lafan1.lafan1_windows(corpus, lafan1.TRAIN_SUBJECTS, window=50, offset=20)
    # walk1 (230 frames): starts 0..160 → 9 windows; run2 (150): 0..80 → 5 windows.
    assert w.num_windows == 14
    assert w.quat_local.shape == (14, 50, 22, 4) and w.quat_local.dtype == np.float64
    # XZ-centering: the window-mean root X and Z are zero (rotation about Y keeps that).
    np.testing.assert_allclose(w.root_pos[..., [0, 2]].mean(axis=1), 0.0, atol=1e-9)
    # Facing: at frame 9 the hips' +Y axis, projected on the ground, points along +X.
    with jax.enable_x64(True):
        fwd = np.array(quat_rotate(jnp.asarray(w.quat_local[:, 9, 0]), jnp.asarray([0.0, 1.0, 0.0])))
    fwd[:, 1] = 0
    fwd /= np.linalg.norm(fwd, axis=-1, keepdims=True)
    np.testing.assert_allclose(fwd, np.broadcast_to([1.0, 0.0, 0.0], fwd.shape), atol=1e-9)
    # Non-root local rotations are untouched by the facing rotation; heights are untouched.
    f, s = int(w.file_index[3]), int(w.start_frame[3])
    raw_q, raw_root = corpus.clip(f)
    np.testing.assert_allclose(w.quat_local[3, :, 1:], raw_q[s : s + 50, 1:], atol=1e-12)
    np.testing.assert_allclose(w.root_pos[3, :, 1], raw_root[s : s + 50, 1], atol=1e-9)
    # Contacts come from the raw window: recompute them from plain FK positions.
    with jax.enable_x64(True):
        _, pos = corpus.clip_skeleton(f).fk(jnp.asarray(raw_q[s : s + 50]), jnp.asarray(raw_root[s : s + 50]))
    step = np.sum(np.diff(np.asarray(pos)[:, [3, 4]], axis=0) ** 2, axis=-1) < 0.02
    np.testing.assert_array_equal(w.contacts_left[3], np.concatenate([step, step[-1:]]))


def test_window_errors(synthetic_zip, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    corpus = lafan1.load_lafan1(synthetic_zip)
    with pytest.raises(ValueError, match="subjects are 1-5, got \\[7\\]"):
        lafan1.lafan1_windows(corpus, [7], 50, 20)
    with pytest.raises(ValueError, match="no LaFAN1 windows of 500 frames"):
        lafan1.lafan1_windows(corpus, [1], 500, 20)
    with pytest.raises(ValueError, match="must exceed the 10 past frames"):
        lafan1.lafan1_windows(corpus, [1], 10, 20)


def test_bad_sources(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        lafan1.load_lafan1(tmp_path / "missing.zip")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ValueError, match="expected the LaFAN1 zip or a directory"):
        lafan1.load_lafan1(tmp_path / "notes.txt", use_cache=False)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no .bvh files found"):
        lafan1.load_lafan1(empty, use_cache=False)
    bad = tmp_path / "badname"
    bad.mkdir()
    (bad / "walk.bvh").write_text("HIERARCHY\n")
    with pytest.raises(ValueError, match="walk.bvh: LaFAN1 file names look like"):
        lafan1.load_lafan1(bad, use_cache=False)


def test_facing_rotation_is_a_yaw():
    with jax.enable_x64(True):
        q = jnp.asarray(np.random.default_rng(0).normal(size=(50, 4)))
        q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
        y = np.asarray(facing_rotation(q))
    np.testing.assert_allclose(y[:, [1, 3]], 0.0, atol=1e-12)  # rotation about Y only
    np.testing.assert_allclose(np.linalg.norm(y, axis=-1), 1.0, atol=1e-12)


def test_benchmark_runner_on_synthetic_corpus(synthetic_zip, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    bench = lafan1_benchmark(synthetic_zip)
    # dance1_subject5 has 300 frames: starts 0, 40, …, 200 (200 + 65 < 300; 240 + 65 > 300).
    assert bench.num_windows == 6
    results = evaluate_baselines(bench, lengths=(5, 15))
    for method in ("zerov", "interp"):
        for metric in ("l2q", "l2p", "npss"):
            values = results[method][metric]
            assert set(values) == {"5", "15"} and all(np.isfinite(v) and v >= 0 for v in values.values())
    # Longer gaps are harder and interpolation beats standing still on smooth motion.
    assert results["zerov"]["l2p"]["15"] > results["zerov"]["l2p"]["5"]
    assert results["interp"]["l2p"]["15"] < results["zerov"]["l2p"]["15"]
    assert "| L2P | interp |" in format_table(results, lengths=(5, 15))

    def ground_truth(past_q, past_r, target_q, target_r, n):
        return jnp.asarray(bench.windows.quat_local[:, 10 : 10 + n]), jnp.asarray(bench.windows.root_pos[:, 10 : 10 + n])

    perfect = evaluate_transitions(bench, ground_truth, lengths=(5,))
    assert perfect == {"l2q": {"5": 0.0}, "l2p": {"5": 0.0}, "npss": {"5": 0.0}}
    delta = evaluate_transitions(bench, interpolation_inbetweener, lengths=(5,), variant="delta")
    assert delta["l2p"] == {"5": results["interp"]["l2p"]["5"]}  # the variant only touches L2Q/NPSS

    with pytest.raises(ValueError, match="unknown metric variant 'fancy'"):
        evaluate_transitions(bench, interpolation_inbetweener, lengths=(5,), variant="fancy")
    with pytest.raises(ValueError, match="transition length 60 does not fit 65-frame windows"):
        evaluate_transitions(bench, interpolation_inbetweener, lengths=(60,))
    with pytest.raises(ValueError, match="in-betweener returned shapes"):
        evaluate_transitions(bench, lambda q, r, tq, tr, n: (q, r), lengths=(5,))


@pytest.mark.parametrize("deviation", [0.0, 3.7e-4, -1e-6])
def test_facing_rotation_near_minus_x_stays_a_yaw(deviation):
    """Regression: three LaFAN1 training windows face within 0.02° of −X at frame 9; a
    generic opposite-vector fallback turned them upside down and skewed x_std."""
    with jax.enable_x64(True):
        facing = jnp.asarray([-1.0, 0.0, deviation])
        # A root rotation whose +Y axis points along `facing`: rotate +Y onto it.
        root = quat_between(jnp.asarray([0.0, 1.0, 0.0]), facing)
        yaw = facing_rotation(root)
        np.testing.assert_allclose(np.asarray(yaw)[[1, 3]], 0.0, atol=1e-15)
        turned = np.asarray(quat_rotate(yaw, jnp.asarray([1.0, 0.0, 0.0])))
    np.testing.assert_allclose(turned, np.asarray(facing) / np.linalg.norm(facing), atol=1e-12)


def test_quat_between_nearly_opposite_is_exact():
    with jax.enable_x64(True):
        u = jnp.asarray([1.0, 0.0, 0.0])
        v = jnp.asarray([-1.0, 0.0, 3.7e-4])
        q = quat_between(u, v)
        np.testing.assert_allclose(quat_rotate(q, u), v / jnp.linalg.norm(v), atol=1e-12)
