"""Sets of output files replaced together, even across a process killed midway
(:func:`files_together`), and a record of which files in a folder bezmotion wrote
(:func:`output_set`, :func:`existing_outputs`), so that a user's own files are never replaced unasked."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from bezmotion._src.io import atomic_write_text, file_sha256
from bezmotion._src.messages import listed

STAGING_PREFIX = ".bezmotion-writing-"
"""How a staging folder's name starts (:func:`files_together`): ``.bezmotion-writing-PID-XXXXXXXX.tmp``."""

_STAGING = re.compile(re.escape(STAGING_PREFIX) + r"(\d+)-[a-z0-9_]+\.tmp")
_JOURNAL = ".commit.json"  # in a staging folder: its set is complete, and the moves that put it in place


@contextlib.contextmanager
def files_together(folder: str | os.PathLike, *, remove: Iterable[str] = (), last: str | None = None) -> Iterator[Path]:
    """Replace a set of files in ``folder`` together: yield an empty staging folder inside it
    for the caller to write the set's files into, by name; then they replace their namesakes
    in ``folder`` and the files named in ``remove`` are deleted from it. Nothing else in
    ``folder`` is touched.

    Until the set is complete in the staging folder, ``folder`` holds the earlier files
    unchanged: an exception removes the staging folder, and one a killed process left is
    removed by the next call on ``folder`` (:func:`clear_interrupted`). Then a journal marks
    the staged set complete and each file is moved in by a rename; where a process is killed
    while moving them, the next call on ``folder`` finishes the moves. ``last`` (a summary
    that describes the set) is deleted first and moved in last, so that wherever it exists
    the set beside it is whole.

    Args:
      folder: where the files go (made if missing).
      remove: names of files to delete from ``folder`` with the moves (an earlier set's
        files the new one lacks); missing ones are skipped, staged ones kept.
      last: the name of the staged file that marks the set complete, if any.
    Raises:
      ValueError: a name that is not a plain file name, or a staged entry that is not a file.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    clear_interrupted(folder)
    remove = [_plain_name(name) for name in remove]
    staging = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-", suffix=".tmp", dir=folder))
    try:
        yield staging
        names = sorted(entry.name for entry in staging.iterdir())
        for name in names:
            if not (staging / name).is_file() or (staging / name).is_symlink():
                raise ValueError(f"{staging / name}: not a file; a set holds files only")
        last = last if last in names else None
        journal = {"move": [n for n in names if n != last], "remove": [n for n in remove if n not in names], "last": last}
        atomic_write_text(staging / _JOURNAL, json.dumps(journal) + "\n")
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    _finish(folder, staging)


def _plain_name(name: str) -> str:
    if name in ("", ".", "..", _JOURNAL) or Path(name).name != name:
        raise ValueError(f"{name!r} is not a plain file name")
    return name


def _finish(folder: Path, staging: Path) -> None:
    """Carry out a complete staging folder's journal, then remove the folder. A step done
    already (by a process killed before the end) is skipped, so that this finishes its work."""
    journal = json.loads((staging / _JOURNAL).read_text(encoding="utf-8"))
    last = journal["last"]
    last_staged = last is not None and (staging / last).exists()
    if last_staged:
        _keep_mode(staging / last, folder / last)
        (folder / last).unlink(missing_ok=True)  # no summary of the earlier set beside the new files
    for name in journal["move"]:
        if (staging / name).exists():
            _keep_mode(staging / name, folder / name)
            os.replace(staging / name, folder / name)
    for name in journal["remove"]:
        (folder / name).unlink(missing_ok=True)
    if last_staged:
        os.replace(staging / last, folder / last)
    _fsync_folder(folder)
    shutil.rmtree(staging)


def _keep_mode(new: Path, old: Path) -> None:
    # As atomic_path does: a file replaced keeps its mode (one made executable stays so).
    try:
        os.chmod(new, stat.S_IMODE(os.stat(old).st_mode))
    except FileNotFoundError:
        pass


def clear_interrupted(folder: str | os.PathLike, names: Iterable[str] = ()) -> None:
    """Finish or remove what processes killed while writing left in ``folder``: a staging
    folder of :func:`files_together` (finished where its set was complete, else removed),
    and the temporary files of :func:`atomic_path` for the files ``names``. Only those of
    processes no longer running (by the process id in their names) are touched."""
    try:
        entries = list(os.scandir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return
    prefixes = [f".{name}." for name in names]
    for entry in entries:
        staging = _STAGING.fullmatch(entry.name)
        if staging is not None and entry.is_dir(follow_symlinks=False):
            if not _running(int(staging[1])):
                if (Path(entry.path) / _JOURNAL).is_file():
                    _finish(Path(folder), Path(entry.path))
                else:
                    shutil.rmtree(entry.path, ignore_errors=True)
        elif entry.name.endswith(".tmp") and entry.is_file(follow_symlinks=False):
            for prefix in prefixes:
                pid = entry.name[len(prefix) :].split(".", 1)[0] if entry.name.startswith(prefix) else ""
                if pid.isdigit() and not _running(int(pid)):
                    Path(entry.path).unlink(missing_ok=True)
                    break


def _running(pid: int) -> bool:
    """Whether a process of this id runs here; True where that cannot be told, so that
    nothing a running process is writing is ever removed."""
    if pid <= 0 or pid == os.getpid() or os.name != "posix":
        return True
    try:
        os.kill(pid, 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True
    return True


def _fsync_folder(folder: Path) -> None:
    # The renames survive a power cut once the folder's own entries are on disk (POSIX).
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


OUTPUTS_RECORD = ".bezmotion-outputs.json"
"""The file in a folder that lists the files bezmotion wrote there (:func:`output_set`),
each with its set's name and its contents' SHA-256: a file is bezmotion's while it is as written."""


@dataclasses.dataclass(frozen=True)
class ExistingOutputs:
    """What a set of outputs would replace in a folder (:func:`existing_outputs`).

    Attributes:
      ours: files of the new set present as bezmotion wrote them (:data:`OUTPUTS_RECORD`).
      theirs: files of the new set present that bezmotion did not write, or that changed since.
      stale: the earlier files of the same set that the new one lacks, as bezmotion wrote them.
    """

    ours: tuple[str, ...] = ()
    theirs: tuple[str, ...] = ()
    stale: tuple[str, ...] = ()

    def refusal(self) -> str | None:
        """Why the set should not be written without the user's say-so (it would replace
        :attr:`theirs`), or None."""
        if not self.theirs:
            return None
        which = "which is" if len(self.theirs) == 1 else "which are"
        return f"would replace {listed(self.theirs)}, {which} not bezmotion's own output (unrecorded, or changed since)"

    def note(self, folder: str | os.PathLike) -> str | None:
        """What writing the set in ``folder`` replaced and removed, for the user; None for nothing."""
        done = [f"replaced {listed([*self.ours, *self.theirs])}"] if self.ours or self.theirs else []
        done += [f"removed {listed(self.stale)} (of the earlier set)"] if self.stale else []
        return f"{' and '.join(done)} in {folder}" if done else None


def existing_outputs(folder: str | os.PathLike, names: Iterable[str], set_name: str) -> ExistingOutputs:
    """Which of the files ``names`` already exist in ``folder``, and whether bezmotion wrote
    them; and the files of the earlier set called ``set_name`` that the new one lacks. What
    a killed run left there is finished or removed first (:func:`clear_interrupted`).

    Raises:
      ValueError: one of ``names`` is a folder there (no file replaces it).
    """
    folder = Path(folder)
    names = list(names)
    clear_interrupted(folder, names)
    record = _read_record(folder)
    present = [name for name in names if os.path.lexists(folder / name)]
    for name in present:
        if (folder / name).is_dir():
            raise ValueError(f"{folder / name} is a folder, not a file")
    ours = [name for name in present if _as_written(folder / name, record.get(name))]
    stale = [
        name for name, entry in sorted(record.items())
        if entry.get("set") == set_name and name not in names and _as_written(folder / name, entry)
    ]  # fmt: skip
    return ExistingOutputs(tuple(ours), tuple(n for n in present if n not in ours), tuple(stale))


@contextlib.contextmanager
def output_set(folder: str | os.PathLike, set_name: str, *, remove: Iterable[str] = (), last: str | None = None) -> Iterator[Path]:
    """:func:`files_together`, the files also recorded as bezmotion's in :data:`OUTPUTS_RECORD`
    under ``set_name`` (a folder's set, or a file's name and its numbered siblings), for a
    later run's :func:`existing_outputs`."""
    folder = Path(folder)
    remove = list(remove)
    with files_together(folder, remove=remove, last=last) as staging:
        yield staging
        staged = {entry.name: {"set": set_name, "sha256": file_sha256(entry)} for entry in staging.iterdir()}
        kept = {
            name: entry for name, entry in _read_record(folder).items()
            if name not in remove and name not in staged and (folder / name).is_file()
        }  # fmt: skip
        atomic_write_text(staging / OUTPUTS_RECORD, json.dumps({"files": kept | staged}, indent=1, sort_keys=True) + "\n")


def _read_record(folder: Path) -> dict[str, dict[str, str]]:
    """The files :data:`OUTPUTS_RECORD` lists in ``folder``; none where it is missing or unreadable."""
    try:
        files = json.loads((folder / OUTPUTS_RECORD).read_text(encoding="utf-8"))["files"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return {}
    if not isinstance(files, dict):
        return {}
    return {name: entry for name, entry in files.items() if isinstance(entry, dict) and _plain(name)}


def _plain(name: object) -> bool:
    return isinstance(name, str) and name not in ("", ".", "..", OUTPUTS_RECORD) and Path(name).name == name


def _as_written(path: Path, entry: dict[str, str] | None) -> bool:
    """Whether ``path`` is a file whose contents are those ``entry`` recorded."""
    return entry is not None and path.is_file() and not path.is_symlink() and file_sha256(path) == entry.get("sha256")
