"""On-disk cache for parsed corpora, keyed by a hash of the inputs.

Parsing a corpus (hundreds of BVH files, a tar.xz archive) takes seconds to minutes; the
arrays it produces are cached as ``.npz`` under :func:`cache_dir`, keyed by a SHA-256 of
the input files' bytes, the parameters and a format version. Change any of them and the
cache misses; delete the folder at any time. Entries are written atomically.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from bezmotion._src.io import atomic_path

CACHE_ENV = "BEZMOTION_CACHE"


def cache_dir() -> Path:
    """``$BEZMOTION_CACHE`` if set, else ``~/.cache/bezmotion``."""
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "bezmotion")


def _hash_file(h, path: Path) -> None:
    with open(path, "rb") as f:
        h.update(hashlib.file_digest(f, "sha256").digest())


def fingerprint(*inputs: str | os.PathLike, **params) -> str:
    """SHA-256 hex digest of input files (directories: every file under them, sorted) and ``params``.

    ``params`` must be JSON-serialisable (they include the loader's format version).
    """
    h = hashlib.sha256()
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            files = sorted(p for p in path.rglob("*") if p.is_file())
            for p in files:
                h.update(str(p.relative_to(path)).encode())
                _hash_file(h, p)
        elif path.is_file():
            h.update(path.name.encode())
            _hash_file(h, path)
        else:
            raise FileNotFoundError(f"cannot fingerprint {path}: no such file or directory")
    h.update(json.dumps(params, sort_keys=True, default=str).encode())
    return h.hexdigest()


def cached_arrays(
    name: str,
    key: str,
    build: Callable[[], Mapping[str, np.ndarray]],
    *,
    use_cache: bool = True,
) -> dict[str, np.ndarray]:
    """Load ``name``'s arrays for ``key`` from the cache, or ``build()`` and store them.

    Args:
      name: a short label for the file name (e.g. ``"lafan1"``).
      key: a :func:`fingerprint` of everything the arrays depend on.
      build: returns a mapping of plain (non-object) NumPy arrays.
      use_cache: ``False`` always builds and never touches the disk.
    """
    if not use_cache:
        return {k: np.asarray(v) for k, v in build().items()}
    path = cache_dir() / f"{name}-{key[:20]}.npz"
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as data:
                return {k: data[k] for k in data.files}
        except (OSError, ValueError, EOFError):
            path.unlink(missing_ok=True)  # a corrupt entry is rebuilt, never trusted
    arrays = {k: np.asarray(v) for k, v in build().items()}
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return arrays
