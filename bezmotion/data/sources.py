"""Where the corpora live, resolved in one place, and one loader for any corpus by name or path.

The published corpora are looked for under a data folder: ``$BEZMOTION_DATA`` if set,
else ``../shared/data`` beside the repository (a checkout's layout). Inside it:
``lafan1/lafan1-subset.zip``, ``bandai-namco/bandai-namco-2.tar.xz`` and
``anidance/anidance.tar.xz``. Cache keys hash the files read, so a corpus read from its
archive and from an extracted copy has two cache entries (same arrays): the default is
always the archive.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from bezmotion.data.anidance import load_anidance
from bezmotion.data.bandai_namco import load_bandai_namco
from bezmotion.data.bvh_folder import load_bvh_folder
from bezmotion.data.corpus import Corpus
from bezmotion.data.lafan1 import load_lafan1

DATA_ENV = "BEZMOTION_DATA"
CORPORA: tuple[str, ...] = ("lafan1", "bandai_namco", "anidance")
_DEFAULT_FILES = {
    "lafan1": Path("lafan1") / "lafan1-subset.zip",
    "bandai_namco": Path("bandai-namco") / "bandai-namco-2.tar.xz",
    "anidance": Path("anidance") / "anidance.tar.xz",
}
_LOADERS: dict[str, Callable[..., Corpus]] = {  # (source, *, use_cache, progress) -> corpus
    "lafan1": lambda source, *, use_cache, progress: load_lafan1(source, use_cache=use_cache),  # parses in seconds
    "bandai_namco": load_bandai_namco,
    "anidance": load_anidance,
}


def data_dir() -> Path:
    """``$BEZMOTION_DATA`` if set, else ``../shared/data`` beside the repository."""
    return Path(os.environ.get(DATA_ENV) or Path(__file__).resolve().parents[3] / "shared" / "data")


def default_source(corpus: str, root: str | os.PathLike | None = None) -> Path:
    """The archive a published corpus is read from by default, under ``root`` (default :func:`data_dir`)."""
    if corpus not in CORPORA:
        raise ValueError(f"corpus must be one of {CORPORA}, got {corpus!r}")
    return (data_dir() if root is None else Path(root)) / _DEFAULT_FILES[corpus]


def load_corpus(
    name_or_path: str | os.PathLike,
    *,
    source: str | os.PathLike | None = None,
    use_cache: bool = True,
    progress: bool = True,
    **folder_options,
) -> Corpus:
    """Open a corpus: ``"lafan1"``, ``"bandai_namco"``, ``"anidance"`` or a folder of BVH files.

    Args:
      name_or_path: a published corpus's name, or the path of a folder of ``.bvh`` files
        of one skeleton (:func:`~bezmotion.data.bvh_folder.load_bvh_folder`).
      source: the archive or folder of a published corpus (default :func:`default_source`).
      use_cache: ``False`` always parses and never touches the cache.
      progress: show a tqdm bar while parsing.
      folder_options: keyword arguments of :func:`~bezmotion.data.bvh_folder.load_bvh_folder`
        (``characteristic``, ``validation_every``, ``validation_files``, ``name``).
    Raises:
      ValueError: neither a known name nor a folder; options that do not apply.
    """
    key = os.fspath(name_or_path)
    if key in _LOADERS:
        if folder_options:
            raise ValueError(f"{sorted(folder_options)} apply to BVH folders only, not to {key!r}")
        path = default_source(key) if source is None else source
        return _LOADERS[key](path, use_cache=use_cache, progress=progress)
    if source is not None:
        raise ValueError(f"source is for the published corpora {CORPORA}; {key!r} is a path already")
    if not Path(key).is_dir():
        raise ValueError(f"corpus must be one of {CORPORA} or a folder of .bvh files, got {key!r}")
    return load_bvh_folder(key, use_cache=use_cache, progress=progress, **folder_options)


__all__ = ["CORPORA", "DATA_ENV", "data_dir", "default_source", "load_corpus"]
