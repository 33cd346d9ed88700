"""The Anidance corpus (Tang, Mao & Jia, ACM MM 2018) as packaged for the Δ-interpolator benchmark.

Reads ``dances/*.csv`` and ``split.json`` straight from ``anidance.tar.xz`` (streamed,
nothing extracted) or from an extracted copy (the folder holding ``split.json`` or its
parent), and caches the parsed corpus on disk.

Each CSV row is one frame at 25 fps: ``center_x, center_y, center_z`` then
``bone_0_x … bone_22_z`` — 24 points × 3 = 72 values, no rotations. Values are returned
exactly as stored, as ``(frames, 24, 3)`` float64 with the center as point 0. (In the
files the center moves around the room while the 23 bones stay near the origin: the bones
are stored relative to the center in all three axes;
:func:`bezmotion.evaluation.anidance.anidance_to_world` adds it back.)

``split.json`` lists the benchmark's 61 files; the published archive holds 49 of them.
Listed files that are absent are dropped with one warning that names them all; files
present but not listed are ignored with a warning too.

Benchmark protocol (Duan et al. 2022, as the Δ-interpolator's public code runs it,
github.com/boreshkinai/delta-interpolator ``src/evaluation/anidance_benchmark.py``): windows of
128 frames every 64 frames, no centering or rotation, and L2P normalised by the 72-d
mean and population std of the training windows.
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from collections.abc import Mapping
from pathlib import Path, PurePosixPath
from typing import ClassVar, NoReturn

import numpy as np
from jaxtyping import Float, Int
from tqdm.auto import tqdm

from bezmotion.data._members import check_source, count_members, fingerprint_inputs, iter_members
from bezmotion.data.cache import cached_arrays, fingerprint
from bezmotion.data.corpus import check_split, no_source_key
from bezmotion.data.windows import sliding_window_starts

FPS = 25
NUM_POINTS = 24  # the center, then bones 0-22
COLUMNS: tuple[str, ...] = tuple(
    f"{point}_{axis}" for point in ("center", *(f"bone_{k}" for k in range(NUM_POINTS - 1))) for axis in "xyz"
)
WINDOW = 128
OFFSET = 64
_SPLIT_FILE = "split.json"
_CSV_PATTERN = "dances/*.csv"
_PATTERNS = (_CSV_PATTERN, _SPLIT_FILE)
_SPLIT_KEYS = ("training_files", "validation_files")
_FORMAT_VERSION = 1  # bump when the cached arrays change meaning


@dataclasses.dataclass(frozen=True)
class AnidanceCorpus:
    """The split's present sequences, sorted by name, frames concatenated along time.

    A positions-only :class:`~bezmotion.data.corpus.Corpus`: 24 points per frame with no
    hierarchy and no rotations, so ``skeleton`` and ``characteristic_map`` are ``None`` and
    :meth:`motion` raises; windows come from :func:`anidance_windows`. Split: the
    benchmark's ``split.json``.

    Attributes:
      names: file stems, e.g. ``"dance_w_8"``.
      is_validation: ``(files,)`` whether each file is in the benchmark's validation split.
      starts: ``(files + 1,)`` file ``i`` is frames ``starts[i]:starts[i+1]``.
      positions: ``(frames, 24, 3)`` point positions as stored (cm), center first.
      missing: split entries absent from the source (as written in ``split.json``).
      cache_inputs: the files the corpus was read from (hashed into cache keys).
    """

    names: tuple[str, ...]
    is_validation: np.ndarray
    starts: np.ndarray
    positions: np.ndarray
    missing: tuple[str, ...] = ()
    cache_inputs: tuple[Path, ...] = ()

    name: ClassVar[str] = "anidance"
    skeleton: ClassVar[None] = None
    characteristic_map: ClassVar[None] = None
    end_sites: ClassVar[tuple] = ()
    fps: ClassVar[float] = float(FPS)

    def __len__(self) -> int:
        return len(self.names)

    @property
    def clip_names(self) -> tuple[str, ...]:
        return self.names

    def labels(self, index: int) -> dict[str, str | int]:
        """``{"file", "split"}`` of one file."""
        return {"file": self.names[index], "split": "validation" if self.is_validation[index] else "train"}

    def split(self, split: str) -> np.ndarray:
        """File indices of the benchmark's ``"train"`` or ``"validation"`` files."""
        check_split(split)
        return self.indices(split == "validation")

    def motion(self, indices) -> NoReturn:
        """Always raises: Anidance has joint positions only (see :attr:`positions`)."""
        raise ValueError("anidance: the corpus stores joint positions only (no hierarchy or rotations); use anidance_windows")

    def source_key(self, **params) -> str:
        """:func:`~bezmotion.data.cache.fingerprint` of the archive (or the split and CSV files of a folder)."""
        if not self.cache_inputs:
            raise no_source_key(self.name)
        return fingerprint(*self.cache_inputs, **params)

    def sequence(self, index: int | np.integer) -> Float[np.ndarray, "frames 24 3"]:
        """Positions ``(frames, 24, 3)`` of one file."""
        return self.positions[self.starts[index] : self.starts[index + 1]]

    def indices(self, validation: bool) -> np.ndarray:
        """File indices of the validation (``True``) or training (``False``) split."""
        return np.flatnonzero(self.is_validation == validation)


@dataclasses.dataclass(frozen=True)
class AnidanceWindows:
    """Fixed-length windows cut from one split.

    Attributes:
      positions: ``(windows, frames, 24, 3)`` positions (cm), not centred or rotated.
      file_index: ``(windows,)`` index into ``AnidanceCorpus.names``.
      start_frame: ``(windows,)`` first frame of each window in its file.
    """

    positions: Float[np.ndarray, "windows frames 24 3"]
    file_index: Int[np.ndarray, " windows"]
    start_frame: Int[np.ndarray, " windows"]

    @property
    def num_windows(self) -> int:
        return self.positions.shape[0]


@dataclasses.dataclass(frozen=True)
class AnidanceStatistics:
    """Training statistics for L2P: ``x_mean``/``x_std`` ``(72,)`` over (window, frame), population std (cm)."""

    x_mean: Float[np.ndarray, " 72"]
    x_std: Float[np.ndarray, " 72"]


# ------------------------------------------------------------------------------- parsing


def parse_anidance_csv(text: str, source: str = "<string>") -> Float[np.ndarray, "frames 24 3"]:
    """Parse one Anidance CSV (header + one row of 72 numbers per frame) to ``(frames, 24, 3)``.

    Raises ``ValueError("<source>:<line>: ...")`` on a wrong header, a row without 72
    values, or a value that is not a finite number. Blank lines are skipped.
    """
    lines = text.splitlines()
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    if tuple(header) != COLUMNS:
        expected = f"{COLUMNS[0]},…,{COLUMNS[-1]} (72 columns)"
        raise ValueError(f"{source}:1: expected the header {expected}, got {lines[:1]}")
    rows = [(k + 2, line) for k, line in enumerate(lines[1:]) if line.strip()]
    try:
        values = np.array([v for _, line in rows for v in line.split(",")], dtype=np.float64)
        ok = values.size == len(rows) * len(COLUMNS) and np.isfinite(values).all()
    except ValueError:
        ok = False
    if ok and all(line.count(",") == len(COLUMNS) - 1 for _, line in rows):
        return values.reshape(len(rows), NUM_POINTS, 3)
    _raise_first_bad_row(rows, source)
    raise AssertionError("unreachable: the fast path failed on a file with no bad row")


def _raise_first_bad_row(rows: list[tuple[int, str]], source: str) -> None:
    """Find and report the first malformed row (slow path, only after the fast one failed)."""
    for lineno, line in rows:
        fields = line.split(",")
        if len(fields) != len(COLUMNS):
            raise ValueError(f"{source}:{lineno}: expected {len(COLUMNS)} comma-separated values, got {len(fields)}")
        for column, field in zip(COLUMNS, fields):
            try:
                value = float(field)
            except ValueError:
                raise ValueError(f"{source}:{lineno}: column {column}: {field.strip()!r} is not a number") from None
            if not np.isfinite(value):
                raise ValueError(f"{source}:{lineno}: column {column}: non-finite value {field.strip()!r}")


def _parse_split(data: bytes, where: str) -> dict[str, list[str]]:
    try:
        split = json.loads(data.decode("utf-8"))
        entries = {key: [str(name) for name in split[key]] for key in _SPLIT_KEYS}
    except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as e:
        expected = '{"training_files": [...], "validation_files": [...]}'
        raise ValueError(f"{where}: expected {expected} ({e})") from None
    both = set(entries[_SPLIT_KEYS[0]]) & set(entries[_SPLIT_KEYS[1]])
    if both:
        raise ValueError(f"{where}: files in both training and validation: {sorted(both)}")
    return entries


def _stem(entry: str) -> str:
    return PurePosixPath(entry).stem


def _parse_corpus(source: Path, *, progress: bool) -> dict[str, np.ndarray]:
    """Stream the source once; keep the split's files; report absent and unlisted ones."""
    sequences: dict[str, np.ndarray] = {}
    split: dict[str, list[str]] | None = None
    total = count_members(source, (_CSV_PATTERN,))
    with tqdm(total=total, desc="parsing Anidance", unit="file", leave=False, disable=not progress) as bar:
        for path, data in iter_members(source, _PATTERNS):
            where = f"{source}:{path}"
            if path.name == _SPLIT_FILE:
                if split is not None:
                    raise ValueError(f"{source}: more than one {_SPLIT_FILE} found (the last at {path})")
                split = _parse_split(data, where)
                continue
            if path.stem in sequences:
                raise ValueError(f"{source}: {path.name} found twice")
            try:
                text = data.decode("utf-8")
            except UnicodeDecodeError as e:
                raise ValueError(f"{where}: not UTF-8 text ({e})") from None
            sequences[path.stem] = parse_anidance_csv(text, where)
            bar.update(1)
    if split is None:
        raise ValueError(f"{source}: no {_SPLIT_FILE} found (here or one folder down)")

    validation = {_stem(e) for e in split["validation_files"]}
    listed = [e for key in _SPLIT_KEYS for e in split[key]]
    missing = sorted(e for e in listed if _stem(e) not in sequences)
    unlisted = sorted(set(sequences) - {_stem(e) for e in listed})
    names = sorted({_stem(e) for e in listed} & set(sequences))
    if not names:
        raise ValueError(f"{source}: none of the {len(listed)} files in {_SPLIT_FILE} is present")
    return {
        "names": np.asarray(names),
        "is_validation": np.asarray([n in validation for n in names]),
        "starts": np.concatenate([[0], np.cumsum([len(sequences[n]) for n in names])]).astype(np.int64),
        "positions": np.concatenate([sequences[n] for n in names]),
        "missing": np.asarray(missing, dtype=str),
        "unlisted": np.asarray(unlisted, dtype=str),
    }


def _warn_about_files(arrays: Mapping[str, np.ndarray], source: Path) -> None:
    missing = [str(m) for m in arrays["missing"]]
    unlisted = [str(u) for u in arrays["unlisted"]]
    if missing:
        warnings.warn(
            f"Anidance ({source}): {len(missing)} file(s) listed in {_SPLIT_FILE} are absent and were dropped: "
            + ", ".join(missing),
            stacklevel=3,
        )
    if unlisted:
        warnings.warn(
            f"Anidance ({source}): {len(unlisted)} file(s) not in {_SPLIT_FILE} were ignored: " + ", ".join(unlisted),
            stacklevel=3,
        )


def load_anidance(source: str | os.PathLike, *, use_cache: bool = True, progress: bool = True) -> AnidanceCorpus:
    """Parse the Anidance CSVs of the benchmark split in ``source``, cached on disk.

    Args:
      source: ``anidance.tar.xz``, the extracted folder holding ``split.json`` and
        ``dances/``, or the folder holding that one.
      use_cache: ``False`` always parses and never touches the cache.
      progress: show a tqdm bar while parsing.
    Warns:
      ``UserWarning`` naming every split entry absent from ``source`` (they are dropped).
    """
    source = check_source(source, "Anidance")
    inputs = fingerprint_inputs(source, _PATTERNS)
    if not inputs:
        raise ValueError(f"{source}: no Anidance files ({_SPLIT_FILE}, {_CSV_PATTERN}) here or one folder down")
    key = fingerprint(*inputs, corpus="anidance", version=_FORMAT_VERSION)
    arrays = cached_arrays("anidance", key, lambda: _parse_corpus(source, progress=progress), use_cache=use_cache)
    _warn_about_files(arrays, source)
    return AnidanceCorpus(
        names=tuple(str(n) for n in arrays["names"]),
        is_validation=arrays["is_validation"].astype(bool),
        starts=arrays["starts"],
        positions=arrays["positions"],
        missing=tuple(str(m) for m in arrays["missing"]),
        cache_inputs=tuple(inputs),
    )


# ------------------------------------------------------------------------------- windows


def anidance_windows(
    corpus: AnidanceCorpus, *, validation: bool, window: int = WINDOW, offset: int = OFFSET
) -> AnidanceWindows:
    """Windows of one split: ``window`` frames every ``offset`` frames, positions untouched.

    Start frames follow the LaFAN1 extractor's rule (``start + window < frames``, see
    :func:`~bezmotion.data.windows.sliding_window_starts`), which the Anidance benchmark
    reuses; files shorter than a window contribute none.
    """
    files, starts = [], []
    for f in corpus.indices(validation):
        s = sliding_window_starts(int(corpus.starts[f + 1] - corpus.starts[f]), window, offset)
        files.append(np.full(len(s), f, np.int64))
        starts.append(s)
    file_index = np.concatenate(files) if files else np.zeros(0, np.int64)
    start_frame = np.concatenate(starts) if starts else np.zeros(0, np.int64)
    if file_index.size == 0:
        split = "validation" if validation else "training"
        raise ValueError(f"no Anidance {split} windows of {window} frames (files: {len(files)})")
    frame_idx = corpus.starts[file_index][:, None] + start_frame[:, None] + np.arange(window)
    return AnidanceWindows(corpus.positions[frame_idx], file_index, start_frame)


def anidance_statistics(corpus: AnidanceCorpus, *, window: int = WINDOW, offset: int = OFFSET) -> AnidanceStatistics:
    """L2P statistics: mean and population std (ddof 0) of the 72 flattened coordinates
    over every (window, frame) of the training windows (overlapping frames count twice,
    as in the LaFAN1 protocol)."""
    flat = anidance_windows(corpus, validation=False, window=window, offset=offset).positions.reshape(-1, 72)
    return AnidanceStatistics(flat.mean(axis=0), flat.std(axis=0))

