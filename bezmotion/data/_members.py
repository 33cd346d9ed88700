"""Read a corpus's files from a tar archive (streamed, never extracted) or a directory.

A corpus ships as an archive (``.tar.xz``) whose files sit under an optional top folder,
or as that archive extracted somewhere. Both look the same to a loader: a stream of
``(relative path, bytes)`` for the files matching a few relative patterns such as
``"data/*.bvh"``, found either at the given directory or one folder below it (so the
dataset root and its parent both work).
"""

from __future__ import annotations

import os
import tarfile
from collections.abc import Iterator, Sequence
from pathlib import Path, PurePosixPath

_ARCHIVE_SUFFIXES = (".tar", ".tar.xz", ".txz", ".tar.gz", ".tgz", ".tar.bz2", ".tbz2")


def is_archive(source: str | os.PathLike) -> bool:
    """Whether ``source`` is a tar file (by name), as opposed to a directory."""
    return Path(source).is_file() and str(source).lower().endswith(_ARCHIVE_SUFFIXES)


def _matches(path: PurePosixPath, patterns: Sequence[str]) -> bool:
    """``path`` is ``pattern`` itself or ``<one folder>/pattern`` for one of the patterns."""
    for pattern in patterns:
        depth = len(PurePosixPath(pattern).parts)
        if len(path.parts) in (depth, depth + 1) and path.match(pattern):
            return True
    return False


def check_source(source: str | os.PathLike, what: str) -> Path:
    """``source`` as a Path; raises ``FileNotFoundError``/``ValueError`` if it is neither archive nor directory."""
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"{what} source {path} does not exist")
    if not (path.is_dir() or is_archive(path)):
        raise ValueError(f"{path}: expected the {what} .tar.xz archive or a directory extracted from it")
    return path


def directory_files(root: Path, patterns: Sequence[str]) -> list[Path]:
    """Files under directory ``root`` matching ``patterns`` there or one folder down, sorted."""
    found: set[Path] = set()
    for pattern in patterns:
        found.update(p for p in root.glob(pattern) if p.is_file())
        found.update(p for p in root.glob(f"*/{pattern}") if p.is_file())
    return sorted(found)


def count_members(source: Path, patterns: Sequence[str]) -> int | None:
    """How many files match in a directory; ``None`` for an archive (unknown until streamed)."""
    return None if is_archive(source) else len(directory_files(source, patterns))


def iter_members(source: Path, patterns: Sequence[str]) -> Iterator[tuple[PurePosixPath, bytes]]:
    """``(path, bytes)`` of every file matching ``patterns`` in an archive or directory.

    Archives are streamed in their stored order (one pass of decompression, nothing
    written to disk); directories are read in sorted order. Paths are relative to
    ``source`` (archive member names for archives).
    """
    if is_archive(source):
        with tarfile.open(source, "r|*") as archive:
            for member in archive:
                path = PurePosixPath(member.name)
                if member.isfile() and _matches(path, patterns):
                    handle = archive.extractfile(member)
                    assert handle is not None  # regular files always have a stream
                    yield path, handle.read()
        return
    for path in directory_files(source, patterns):
        yield PurePosixPath(path.relative_to(source).as_posix()), path.read_bytes()


def fingerprint_inputs(source: Path, patterns: Sequence[str]) -> list[Path]:
    """The files a cache key must hash: the archive itself, or the matching files of a directory.

    Hashing only the matching files keeps the key stable when the directory also holds
    other things (the extraction cache folder holds other corpora and the cache itself).
    """
    return [source] if is_archive(source) else directory_files(source, patterns)
