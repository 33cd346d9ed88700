"""Property tests over mutated input files: a BVH file (the bundled real clip) and handles
files (JSON and TOML) either read into finite values or fail with a ``ValueError`` /
``FileNotFoundError`` on one line of about 300 characters naming the file, never with any
other exception.

The mutations and the verdict are ``benchmarks/fuzz.py``'s; here hypothesis draws their
choices (a fixed seed and a small budget: a few seconds), where the benchmark runs
thousands of random mutants. Then the verdict itself: it must catch what it is there for.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from helpers import load_experiment
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bezmotion.data.bvh
from bezmotion.assets import DEMO_CLIP

fuzz = load_experiment("fuzz", "benchmarks")

FUZZ_SETTINGS = settings(
    derandomize=True, database=None, max_examples=100, deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)  # fmt: skip — the same examples every run, and no example database written into the tree
GOOD = ("accepted_finite", "clear_error")


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("mutants")


def picker(data: st.DataObject) -> fuzz.Pick:
    """The mutations' choices, drawn by hypothesis (so that it can shrink a failing mutant)."""
    return lambda n: data.draw(st.integers(0, n - 1))


@FUZZ_SETTINGS
@given(data=st.data())
def test_a_mutated_bvh_file_reads_into_finite_values_or_fails_clearly(folder: Path, data: st.DataObject):
    mutant, applied = fuzz.mutate(DEMO_CLIP.read_bytes(), picker(data), fuzz.BVH_MUTATIONS)
    path = folder / "mutant.bvh"
    path.write_bytes(mutant)
    outcome, why = fuzz.read_bvh_outcome(path)
    assert outcome in GOOD, (applied, why)


@FUZZ_SETTINGS
@given(data=st.data())
def test_a_mutated_handles_file_reads_into_finite_values_or_fails_clearly(folder: Path, data: st.DataObject):
    pick = picker(data)
    name = sorted(fuzz.HANDLES_FILES)[pick(len(fuzz.HANDLES_FILES))]
    mutant, applied = fuzz.mutate(fuzz.HANDLES_FILES[name], pick, fuzz.HANDLES_MUTATIONS)
    path = folder / name
    path.write_bytes(mutant)
    outcome, why = fuzz.handles_outcome(path)
    assert outcome in GOOD, (applied, why)


def test_the_verdict_catches_what_it_is_there_for(tmp_path: Path, monkeypatch):
    """An error too long, on two lines or not naming the file, another exception, a value
    accepted that is not finite, or a mutant that never returns: none passes as good."""
    path = tmp_path / "clip.bvh"
    assert fuzz.unclear(f"{path}:3: OFFSET needs 3 numbers, got 2", path) is None
    assert "characters" in fuzz.unclear(f"{path}:3: " + "x" * 400, path)
    assert "lines" in fuzz.unclear(f"{path}:3: two\nlines", path)
    assert "not naming the file" in fuzz.unclear("line 3: OFFSET needs 3 numbers, got 2", path)

    def recursing(path):
        raise RecursionError("maximum recursion depth exceeded")

    monkeypatch.setattr(bezmotion.data.bvh, "read_bvh", recursing)
    assert fuzz.read_bvh_outcome(path) == ("traceback", "RecursionError: maximum recursion depth exceeded")
    motion = bezmotion.data.bvh.parse_bvh(DEMO_CLIP.read_text(), "clip.bvh")
    with_nan = dataclasses.replace(motion, pos_local=motion.pos_local * np.nan)
    monkeypatch.setattr(bezmotion.data.bvh, "read_bvh", lambda path: with_nan)
    assert fuzz.read_bvh_outcome(path) == ("traceback", "accepted with a value that is not finite")

    def forever():
        while True:
            pass

    assert fuzz.timed(0.2, forever)[0] == "hang"


def test_the_benchmark_counts_every_mutant(tmp_path: Path):
    out = tmp_path / "fuzz.json"
    result = fuzz.main(["--target", "read_bvh", "--mutants", "12", "--out", str(out)])
    assert json.loads(out.read_text())["tried"] == 12
    assert sum(result[k] for k in ("clear_error", "accepted_finite", "traceback", "hang", "files_left")) == 12
    assert result["traceback"] == result["hang"] == 0 and not result["examples"]
    again = fuzz.main(["--target", "read_bvh", "--mutants", "12"])
    assert {k: again[k] for k in GOOD} == {k: result[k] for k in GOOD}  # the same mutants from the same seed
