"""Sets of output files (``bezmotion._src.output_sets``): replaced whole, even by a process
killed midway; a user's own files never replaced unasked; what killed runs left cleared."""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from bezmotion._src import output_sets
from bezmotion._src.output_sets import OUTPUTS_RECORD, STAGING_PREFIX, ExistingOutputs, clear_interrupted, existing_outputs, output_set

OLD = {"a.bvh": "old a", "b.glb": "old b", "c.gif": "old c", "summary.json": "old summary"}
NEW = {"a.bvh": "new a", "b.glb": "new b", "summary.json": "new summary"}  # c.gif: the earlier set's alone

# Writes NEW over OLD, as `bezmotion inbetween --out FOLDER` does, in a process that kills
# itself (SIGKILL) just before its os.replace number MOMENT: while the files are written,
# before and after the journal, between the moves. It loads bezmotion._src.output_sets without the
# package's __init__ (which imports JAX), so that each process starts in a blink.
_KILLED_WRITER = r"""
import json, os, signal, sys, types
root, folder, moment, files = sys.argv[1], sys.argv[2], int(sys.argv[3]), json.loads(sys.argv[4])
for name, path in (("bezmotion", root), ("bezmotion._src", os.path.join(root, "_src"))):
    package = types.ModuleType(name)
    package.__path__ = [path]
    sys.modules[name] = package
from bezmotion._src import output_sets

replace, done = os.replace, [0]

def replace_or_die(source, target):
    if done[0] == moment:
        os.kill(os.getpid(), signal.SIGKILL)
    done[0] += 1
    replace(source, target)

os.replace = replace_or_die
with output_sets.output_set(folder, "", remove=["c.gif"], last="summary.json") as staging:
    for name, text in files.items():
        output_sets.atomic_write_text(os.path.join(staging, name), text)
print(done[0])
"""


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def _visible(folder) -> dict[str, str]:
    return {p.name: p.read_text() for p in sorted(folder.iterdir()) if not p.name.startswith(".")}


def _write_set(folder, files: dict[str, str], **kwargs) -> None:
    with output_set(folder, "", last="summary.json", **kwargs) as staging:
        for name, text in files.items():
            (staging / name).write_text(text)


def _run_killed(folder, moment: int) -> subprocess.CompletedProcess:
    root = Path(output_sets.__file__).parent.parent
    argv = [sys.executable, "-c", _KILLED_WRITER, str(root), str(folder), str(moment), json.dumps(NEW)]
    return subprocess.run(argv, capture_output=True, text=True, timeout=60)


def test_a_set_killed_at_any_moment_is_the_old_or_the_new_once_the_next_run_looks(tmp_path):
    """SIGKILL before each rename of a writing process: until its journal is written the
    folder shows the old set untouched; after it, the next run's look at the folder
    (existing_outputs) completes the moves. Either way the set is whole, old or new, the
    user's own file stays, and no temporary file or folder is left."""
    complete = _run_killed(tmp_path / "count", moment=-1)  # never killed: how many renames a run makes
    assert complete.returncode == 0, complete.stderr
    renames = int(complete.stdout)
    # 3 files and the record written, the journal, then 4 moves (summary.json last)
    assert renames == 9 and _visible(tmp_path / "count") == NEW
    outcomes = []
    for moment in range(renames):
        folder = tmp_path / f"killed_at_{moment}"
        _write_set(folder, OLD)
        (folder / "notes.txt").write_text("mine")
        killed = _run_killed(folder, moment)
        assert killed.returncode == -signal.SIGKILL, (moment, killed.stderr)
        assert any(p.name.startswith(STAGING_PREFIX) for p in folder.iterdir())  # what the next run clears
        if moment < 5:  # the journal not yet written: nothing of the new set is visible
            assert _visible(folder) == {**OLD, "notes.txt": "mine"}, moment
        existing = existing_outputs(folder, NEW, "")  # the next run's first look
        left = _visible(folder)
        assert left.pop("notes.txt") == "mine"
        assert left in (OLD, NEW), (moment, left)
        assert sorted(p.name for p in folder.iterdir() if p.name.startswith(".")) == [OUTPUTS_RECORD], moment
        # The record of what bezmotion wrote is the visible set's too: the earlier c.gif is stale only beside the new set.
        assert (existing.ours, existing.theirs, existing.stale) == (tuple(NEW), (), () if left == NEW else ("c.gif",)), moment
        outcomes.append("new" if left == NEW else "old")
    assert outcomes == ["old"] * 5 + ["new"] * 4


def test_a_set_replaces_its_own_earlier_files_removes_the_stale_ones_and_keeps_the_rest(tmp_path):
    folder = tmp_path / "take"
    _write_set(folder, OLD)
    (folder / "notes.txt").write_text("mine")
    existing = existing_outputs(folder, NEW, "")
    assert existing == ExistingOutputs(ours=("a.bvh", "b.glb", "summary.json"), theirs=(), stale=("c.gif",))
    assert existing.refusal() is None
    assert existing.note(folder) == f"replaced a.bvh, b.glb, summary.json and removed c.gif (of the earlier set) in {folder}"
    os.chmod(folder / "a.bvh", 0o750)
    _write_set(folder, NEW, remove=existing.stale)
    assert _visible(folder) == {**NEW, "notes.txt": "mine"}
    assert _mode(folder / "a.bvh") == 0o750  # a file replaced keeps its mode, as with atomic_path
    # A file changed since bezmotion wrote it, or never written by it, is the user's.
    (folder / "a.bvh").write_text("edited by hand")
    (folder / "d.bvh").write_text("the user's")
    existing = existing_outputs(folder, [*NEW, "d.bvh"], "")
    assert existing.theirs == ("a.bvh", "d.bvh") and existing.stale == ()
    assert existing.refusal() == "would replace a.bvh, d.bvh, which are not bezmotion's own output (unrecorded, or changed since)"
    # Another set's files (a file output's numbered samples, say) are not this one's to remove.
    with output_set(folder, "x.bvh") as staging:
        (staging / "x_0.bvh").write_text("sample 0")
    assert existing_outputs(folder, NEW, "").stale == () and existing_outputs(folder, ["x.bvh"], "x.bvh").stale == ("x_0.bvh",)


def test_a_set_whose_writing_fails_leaves_the_folder_as_it_was(tmp_path):
    folder = tmp_path / "take"
    _write_set(folder, OLD)
    before = sorted(os.listdir(folder))
    with pytest.raises(RuntimeError, match="boom"):
        with output_set(folder, "", remove=["c.gif"], last="summary.json") as staging:
            (staging / "a.bvh").write_text("new a")
            raise RuntimeError("boom")
    assert sorted(os.listdir(folder)) == before and _visible(folder) == OLD


def test_only_what_dead_processes_left_is_cleared(tmp_path):
    """A staging folder or a temporary file is cleared by the id of the process in its name:
    one whose process still runs (this test's parent) stays; a dead one's goes, and of the
    temporary files only those of the set's names."""
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    dead, alive = int(gone.stdout), os.getppid()
    names = [f"{STAGING_PREFIX}{dead}-abc123.tmp", f"{STAGING_PREFIX}{alive}-abc123.tmp"]
    for name in names:
        (tmp_path / name).mkdir()
        (tmp_path / name / "a.bvh").write_text("half")
    temporaries = [f".a.bvh.{dead}.k2j4m1x0.tmp", f".a.bvh.{alive}.k2j4m1x0.tmp", f".other.bvh.{dead}.k2j4m1x0.tmp"]
    for name in temporaries:
        (tmp_path / name).write_text("half")
    clear_interrupted(tmp_path, ["a.bvh"])
    assert sorted(os.listdir(tmp_path)) == sorted([names[1], *temporaries[1:]])
