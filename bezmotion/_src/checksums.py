"""SHA-256 checksums of folders: one rule for the bundled models' manifest, saved models
and training checkpoints.

A folder's digest (:func:`folder_digest`, what ``bezmotion/assets/models/MANIFEST.json``
records) hashes each file on its own and then the sorted list of (path, file digest).
A folder can also carry its own list, :data:`CHECKSUM_FILE` (:func:`write_checksums`):
each file's size and SHA-256, so :func:`checksum_problem` names the file that was changed,
truncated or deleted. Every byte of that list is checked too: it must read back as
exactly what :func:`write_checksums` writes.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path

from bezmotion._src.io import atomic_write_text, file_sha256
from bezmotion._src.messages import listed

CHECKSUM_FILE = "checksums.json"
"""The file in which a folder lists its files' sizes and SHA-256 digests."""
CHECKSUM_FORMAT = "bezmotion.checksums/1"
DIGEST_RULE = "sha256 over the folder's files sorted by relative POSIX path: for each, the path, a NUL byte, the file's own sha256"


class ChecksumError(ValueError):
    """A folder's files do not match their recorded checksums (or have none to check)."""


class MissingChecksums(ChecksumError):
    """A folder that should carry checksums has none (saved before they were written)."""


def folder_files(folder: str | os.PathLike) -> list[Path]:
    """Every file under ``folder``, sorted by relative POSIX path."""
    folder = Path(folder)
    return sorted((p for p in folder.rglob("*") if p.is_file()), key=lambda p: p.relative_to(folder).as_posix())


def folder_digest(folder: str | os.PathLike) -> str:
    """SHA-256 hex digest of every file under ``folder`` (:data:`DIGEST_RULE`)."""
    folder = Path(folder)
    h = hashlib.sha256()
    for path in folder_files(folder):
        h.update(path.relative_to(folder).as_posix().encode() + b"\0" + bytes.fromhex(file_sha256(path)))
    return h.hexdigest()


def _render(files: dict[str, dict[str, int | str]]) -> str:
    return json.dumps({"format": CHECKSUM_FORMAT, "files": files}, indent=1, sort_keys=True) + "\n"


def write_checksums(folder: str | os.PathLike, include: Callable[[str], bool] | None = None) -> Path:
    """List the size and SHA-256 of every file under ``folder`` (those whose relative POSIX
    path ``include`` accepts; default all) in ``folder/``:data:`CHECKSUM_FILE`, atomically.

    Returns the list's path. Files added to the folder later are not covered.
    """
    folder = Path(folder)
    files = {}
    for path in folder_files(folder):
        relative = path.relative_to(folder).as_posix()
        if relative != CHECKSUM_FILE and (include is None or include(relative)):
            files[relative] = {"bytes": path.stat().st_size, "sha256": file_sha256(path)}
    target = folder / CHECKSUM_FILE
    atomic_write_text(target, _render(files))
    return target


def has_checksums(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` carries a :data:`CHECKSUM_FILE` (whatever its state)."""
    return (Path(folder) / CHECKSUM_FILE).exists()


def checksum_problem(folder: str | os.PathLike) -> str | None:
    """What differs between ``folder``'s files and its :data:`CHECKSUM_FILE`, in words
    (naming the files, relative to ``folder``), or None when every listed file matches.

    A folder without the file, or whose file is not exactly as :func:`write_checksums`
    wrote it, has a problem too. Files not in the list are not looked at.
    """
    folder = Path(folder)
    try:
        text = (folder / CHECKSUM_FILE).read_text(encoding="utf-8")
        files = json.loads(text)["files"]
        if _render(files) != text or not all(
            isinstance(r, dict) and isinstance(r.get("bytes"), int) and isinstance(r.get("sha256"), str) for r in files.values()
        ):
            raise ValueError
    except FileNotFoundError:
        return f"no {CHECKSUM_FILE}"
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError):  # unreadable, not JSON (nested absurdly deep too), not this layout
        return f"{CHECKSUM_FILE} is damaged"
    problems = []
    for relative, record in files.items():
        path = folder / relative
        if not path.is_file():
            problems.append(f"{relative} is missing")
        elif path.stat().st_size != record["bytes"]:
            problems.append(f"{relative} has {path.stat().st_size} bytes, {record['bytes']} expected")
        elif file_sha256(path) != record["sha256"]:
            problems.append(f"{relative} differs from its sha256")
    return listed(problems, shown=2, sep="; ") if problems else None


def add_checked_file(folder: str | os.PathLike, relative: str, text: str) -> Path:
    """Write ``text`` to ``folder/relative`` (atomically) and, where ``folder`` carries a
    :data:`CHECKSUM_FILE`, list that file in it too: something added to a saved model later
    (a learned IK's joint limits) is then checked like the rest.

    The files listed already are checked first, so a damaged folder is not listed anew as if
    it were sound. Returns the file's path.

    Raises:
      ChecksumError: the folder's listed files do not match their checksums (nothing written).
    """
    folder = Path(folder)
    checked = has_checksums(folder)
    if checked and (problem := checksum_problem(folder)) is not None:
        raise ChecksumError(f"{folder}: {problem}; not adding {relative} to it")
    target = folder / relative
    atomic_write_text(target, text)
    if checked:
        files = json.loads((folder / CHECKSUM_FILE).read_text(encoding="utf-8"))["files"]
        files[Path(relative).as_posix()] = {"bytes": target.stat().st_size, "sha256": file_sha256(target)}
        atomic_write_text(folder / CHECKSUM_FILE, _render(files))
    return target


__all__ = [
    "CHECKSUM_FILE",
    "ChecksumError",
    "MissingChecksums",
    "add_checked_file",
    "checksum_problem",
    "file_sha256",
    "folder_digest",
    "folder_files",
    "has_checksums",
    "write_checksums",
]
