"""Atomic file writing: a file is either absent, the old version, or complete — never half-written."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically.

    The temporary file lives in the destination directory so ``os.replace`` is a rename
    on one filesystem; its name, ``.NAME.PID.XXXXXXXX[suffix].tmp``, carries this process's
    id, so that one a killed process left is known for stale (:func:`clear_interrupted`).
    On any exception the temporary file is removed and ``path`` is left untouched.
    ``suffix`` keeps tools that dispatch on the extension (``np.savez``) happy. The file
    gets the mode an ordinary ``open`` would give it (``0o666`` less the umask), or the mode
    of the file it replaces.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=suffix + ".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp makes the file 0o600; without this every output would be private to its owner.
        try:
            mode = stat.S_IMODE(os.stat(path).st_mode)
        except FileNotFoundError:
            mode = 0o666 & ~_umask()
        os.chmod(tmp_path, mode)
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def check_writable_folder(folder: str | os.PathLike) -> None:
    """Raise ValueError unless files can be written in ``folder`` (made if missing): its nearest
    existing ancestor (itself, if it exists) must be a folder we may write in. For a command's
    checks before any work, so a bad output path fails first, not after the work."""
    existing = Path(folder).absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{existing} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"cannot write in {existing}")


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 hex digest of one file's bytes."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _umask() -> int:
    """The process umask, read without changing it where the system says it (Linux)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    # Elsewhere the only way is to set it and put it back (briefly process-wide).
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | os.PathLike, text: str, *, newline: str | None = None) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline=newline) as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def write_results(out: str | os.PathLike, results: dict, report: str) -> None:
    """Print an experiment's Markdown ``report`` and write it beside its JSON ``results``
    (``out`` and ``out`` with suffix ``.md``), both atomically."""
    out = Path(out)
    print(report)
    atomic_write_text(out, json.dumps(results, indent=2) + "\n")
    atomic_write_text(out.with_suffix(".md"), report + "\n")
    print(f"wrote {out} and {out.with_suffix('.md')}")


def save_figure(fig, path: str | os.PathLike, **savefig_kwargs) -> None:
    """Save a Matplotlib figure as PNG to ``path`` atomically."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", **savefig_kwargs)
