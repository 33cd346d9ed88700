"""The Bandai-Namco-Research-Motiondataset corpora (Bandai Namco Research Inc., CC BY-NC 4.0).

Reads any release ``Bandai-Namco-Research-Motiondataset-N`` laid out like release 2:
the BVH clips and their JSON labels straight from the published ``.tar.xz`` (streamed,
nothing extracted) or from an extracted copy (the dataset folder or its parent), checks
them, and caches the parsed corpus on disk so later loads take about a second.

What release 2 looks like (checked on all 2,902 clips); other releases follow the same
naming with their own number ``N``:

- Clip names are ``dataset-N_{content}_{style}_{id}`` (``dataset-2_walk_normal_001``);
  content and style may contain hyphens (``walk-turn-left``, ``not-confident``), never
  underscores. ``id`` is a 3-digit take number counting 1, 2, … within each of the 70
  content × style classes (17 to 104 takes each).
- The JSON labels ``{"content": i, "style": j}`` are **0-based** line indices into
  ``cfg/content_label.txt`` / ``cfg/style_label.txt``, whose lines read
  ``dataset-N_walk`` etc. They agree with the file names on every clip; the loader
  checks that and raises ``ValueError`` on any disagreement. The release prefix
  (``dataset-N``) is taken from the clip names, and every clip and label line must carry
  the same one. Labels are returned without it (``"walk"``, ``"normal"``).
- Every clip has the same hierarchy: 22 joints rooted at ``joint_Root``, 6 channels
  (``Xposition Yposition Zposition Zrotation Xrotation Yrotation``) on every joint,
  4 zero-length End Sites, 30 fps. ``joint_Root`` stays at the origin with identity
  rotation in every frame.
- OFFSETs are identical across clips except the ``Hips`` OFFSET, which takes one of
  three values (e.g. ``(4.59, 91.49, -427.24)`` cm) — apparently the capture session's
  origin. It never matters for the motion: ``Hips`` has animated position channels, and
  every other joint's animated position equals its OFFSET. The corpus keeps each clip's
  own offsets anyway.

Because every joint has position channels, do FK with the animated translations,
``forward_kinematics(parents, quat_local, pos_local)``, not ``Skeleton.fk`` (which uses
the rest offsets for every joint but the root).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from collections.abc import Collection, Iterator, Mapping, Sequence
from pathlib import Path, PurePosixPath
from typing import ClassVar

import numpy as np
from tqdm.auto import tqdm

from bezmotion.data._members import check_source, count_members, fingerprint_inputs, iter_members
from bezmotion.data.bvh import BvhMotion, parse_bvh
from bezmotion.data.cache import cached_arrays, fingerprint
from bezmotion.data.corpus import (
    MotionClips,
    check_split,
    gather_clips,
    hierarchy_arrays,
    hierarchy_from_arrays,
    no_source_key,
)
from bezmotion.geometry.skeleton import Skeleton

FPS = 30
VALIDATION_EVERY = 10  # clip ids divisible by this are validation clips
_MOTION_PATTERNS = ("data/*.bvh", "data/*.json")
_LABEL_FILES = {"content": "cfg/content_label.txt", "style": "cfg/style_label.txt"}
_PATTERNS = _MOTION_PATTERNS + tuple(_LABEL_FILES.values())
_CLIP_NAME = re.compile(r"(?P<release>dataset-\d+)_(?P<content>[a-z0-9-]+)_(?P<style>[a-z0-9-]+)_(?P<clip_id>\d+)")
_FORMAT_VERSION = 1  # bump when the cached arrays change meaning


@dataclasses.dataclass(frozen=True)
class BandaiNamcoClip:
    """One labelled clip; its arrays are views into the corpus arrays.

    Attributes:
      name: file stem, e.g. ``"dataset-2_walk_normal_001"``.
      content: motion label, e.g. ``"walk"``.
      style: style label, e.g. ``"normal"``.
      clip_id: the take number at the end of the name (1-based).
      frame_time: seconds per frame (1/30).
      quat_local: ``(frames, 22, 4)`` local rotations (w, x, y, z), continuity-fixed.
      pos_local: ``(frames, 22, 3)`` animated local translations (cm).
      offsets: ``(22, 3)`` the clip's OFFSET lines (cm).
    """

    name: str
    content: str
    style: str
    clip_id: int
    frame_time: float
    quat_local: np.ndarray
    pos_local: np.ndarray
    offsets: np.ndarray

    @property
    def num_frames(self) -> int:
        return self.quat_local.shape[0]


@dataclasses.dataclass(frozen=True)
class BandaiNamcoCorpus:
    """Parsed clips sorted by name, frames concatenated along time (float64); a
    :class:`~bezmotion.data.corpus.Corpus`.

    Split: :meth:`split` (every 10th take of each class validates). Reference skeleton:
    the first clip's (clips differ only in the ``Hips`` OFFSET, which the animated
    ``Hips`` translation overrides).

    Attributes:
      names: clip names (file stems), sorted.
      content_ids, style_ids: ``(clips,)`` 0-based indices into the label tuples.
      clip_ids: ``(clips,)`` take numbers from the names.
      content_labels, style_labels: the label names in ``cfg/*.txt`` order, prefix dropped.
      frame_times: ``(clips,)`` seconds per frame.
      starts: ``(clips + 1,)`` clip ``i`` is frames ``starts[i]:starts[i+1]``.
      offsets: ``(clips, 22, 3)`` each clip's OFFSETs (cm).
      quat_local: ``(frames, 22, 4)`` local rotations (w, x, y, z).
      pos_local: ``(frames, 22, 3)`` animated local translations (cm).
      parents, joint_names: the shared hierarchy.
      channels: the shared channel list of every joint (to write clips back as BVH).
      end_sites: the shared End Sites, ``(parent joint, offset)``.
      cache_inputs: the files the corpus was read from (hashed into cache keys).
      clip_selection: the take numbers kept by ``load_bandai_namco(clip_ids=…)``, or
        ``None`` for every take.
    """

    names: tuple[str, ...]
    content_ids: np.ndarray
    style_ids: np.ndarray
    clip_ids: np.ndarray
    content_labels: tuple[str, ...]
    style_labels: tuple[str, ...]
    frame_times: np.ndarray
    starts: np.ndarray
    offsets: np.ndarray
    quat_local: np.ndarray
    pos_local: np.ndarray
    parents: tuple[int, ...]
    joint_names: tuple[str, ...]
    channels: tuple[tuple[str, ...], ...]
    end_sites: tuple[tuple[int, tuple[float, float, float]], ...]
    cache_inputs: tuple[Path, ...] = ()
    clip_selection: tuple[int, ...] | None = None

    name: ClassVar[str] = "bandai_namco"
    characteristic_map: ClassVar[str] = "bandai_namco"

    def __len__(self) -> int:
        return len(self.names)

    @property
    def num_frames(self) -> int:
        return self.quat_local.shape[0]

    @property
    def release(self) -> str:
        """The release prefix of the clip names, e.g. ``"dataset-2"``."""
        return self.names[0].split("_", 1)[0]

    @property
    def clip_names(self) -> tuple[str, ...]:
        return self.names

    @property
    def fps(self) -> float:
        """Frames per second of the first clip (:meth:`motion` checks a selection shares one)."""
        return round(1.0 / float(self.frame_times[0]), 6)

    @property
    def skeleton(self) -> Skeleton:
        """The reference skeleton: the first clip's."""
        return self.clip_skeleton(0)

    def clip_skeleton(self, clip_index: int | np.integer) -> Skeleton:
        """The shared hierarchy with one clip's offsets (NumPy float64); they differ only at ``Hips``."""
        return Skeleton(self.parents, self.joint_names, self.offsets[clip_index])

    def labels(self, index: int) -> dict[str, str | int]:
        """``{"file", "content", "style", "take"}`` of one clip."""
        clip = self.clip(index)
        return {"file": clip.name, "content": clip.content, "style": clip.style, "take": clip.clip_id}

    def split(self, split: str) -> np.ndarray:
        """Deterministic split by clip: the clip indices of ``"train"`` or ``"validation"``.

        The dataset publishes no split and no performer ids. Every 10th take of each
        content × style class (ids 10, 20, …) goes to validation: 262 of release 2's
        2,902 clips (9.0 %), at least one of each of the 70 classes (the smallest has 17
        takes), so both labels are stratified. The rule looks only at a clip's own name,
        so it does not depend on archive order or on which subset was loaded, and whole
        clips never straddle the split. Takes of one class share a performer and session,
        so this measures generalisation to unseen takes, not to unseen performers.
        """
        check_split(split)
        is_val = np.asarray(self.clip_ids) % VALIDATION_EVERY == 0
        return np.flatnonzero(is_val if split == "validation" else ~is_val)

    def motion(self, indices: Sequence[int] | np.ndarray) -> MotionClips:
        """The given clips (indices into the corpus, in the order given); they must share a frame time."""
        clips = [int(i) for i in indices]
        frames, starts = gather_clips(self.starts, clips)
        frame_times = np.unique(self.frame_times[clips]) if clips else np.asarray([1.0 / FPS])
        if len(frame_times) > 1:
            raise ValueError(f"the selected Bandai-Namco clips mix frame times {frame_times.tolist()}")
        fps = 1.0 / float(frame_times[0])
        return MotionClips(
            self.parents, self.joint_names, self.quat_local[frames], self.pos_local[frames], starts, round(fps, 6),
        )  # fmt: skip

    def source_key(self, **params) -> str:
        """:func:`~bezmotion.data.cache.fingerprint` of the archive (or the motion and label
        files of a folder) and the take selection, with ``params``."""
        if not self.cache_inputs:
            raise no_source_key(self.name)
        selection = {} if self.clip_selection is None else {"clip_ids": list(self.clip_selection)}
        return fingerprint(*self.cache_inputs, **params, **selection)

    def clip(self, index: int | np.integer) -> BandaiNamcoClip:
        """The ``index``-th clip (in name order)."""
        s, e = int(self.starts[index]), int(self.starts[index + 1])
        return BandaiNamcoClip(
            name=self.names[index],
            content=self.content_labels[self.content_ids[index]],
            style=self.style_labels[self.style_ids[index]],
            clip_id=int(self.clip_ids[index]),
            frame_time=float(self.frame_times[index]),
            quat_local=self.quat_local[s:e],
            pos_local=self.pos_local[s:e],
            offsets=self.offsets[index],
        )

    def clips(self) -> Iterator[BandaiNamcoClip]:
        """Every clip in name order."""
        return (self.clip(i) for i in range(len(self)))

    def index(self, name: str) -> int:
        """Position of the clip called ``name``; raises ``ValueError`` if absent."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"no Bandai-Namco clip named {name!r} in this corpus") from None

    def to_bvh(self, index: int | np.integer) -> BvhMotion:
        """One clip as a :class:`BvhMotion`, ready for :func:`~bezmotion.data.bvh.write_bvh`."""
        clip = self.clip(index)
        return BvhMotion(
            self.clip_skeleton(index), clip.quat_local, clip.pos_local, self.channels, clip.frame_time, self.end_sites
        )


def is_validation_clip(clip_id: int) -> bool:
    """Whether a clip with this take number belongs to the validation split (every 10th)."""
    return clip_id % VALIDATION_EVERY == 0


# ------------------------------------------------------------------------------- loading


def load_bandai_namco(
    source: str | os.PathLike,
    *,
    clip_ids: Collection[int] | None = None,
    use_cache: bool = True,
    progress: bool = True,
) -> BandaiNamcoCorpus:
    """Parse the Bandai-Namco clips in ``source``, cached on disk.

    Args:
      source: ``bandai-namco-2.tar.xz``, the extracted
        ``Bandai-Namco-Research-Motiondataset-2`` folder, or the folder holding it.
      clip_ids: keep only clips whose take number is in this set (``range(1, 3)`` gives
        140 clips covering all 70 classes); ``None`` keeps all 2,902.
      use_cache: ``False`` always parses and never touches the cache.
      progress: show a tqdm bar while parsing.
    Returns:
      The corpus, clips sorted by name. The first full load streams and parses every
      file (``benchmarks/bvh_parse.py`` times it); later loads of the same bytes read the
      cache instead, much faster.
    """
    source = check_source(source, "Bandai-Namco")
    selected = None if clip_ids is None else sorted({int(i) for i in clip_ids})
    inputs = _fingerprint_inputs(source)
    key = fingerprint(*inputs, corpus="bandai-namco", version=_FORMAT_VERSION, clip_ids=selected)
    arrays = cached_arrays(
        "bandai-namco", key, lambda: _parse_corpus(source, selected, progress=progress), use_cache=use_cache
    )
    corpus = _corpus_from_arrays(arrays)
    selection = None if selected is None else tuple(selected)
    return dataclasses.replace(corpus, cache_inputs=tuple(inputs), clip_selection=selection)


def _fingerprint_inputs(source: Path) -> list[Path]:
    inputs = fingerprint_inputs(source, _PATTERNS)
    if not inputs:
        raise ValueError(f"{source}: no Bandai-Namco files (data/*.bvh, cfg/*.txt) here or one folder down")
    return inputs


def _parse_clip_name(name: str, where: str) -> tuple[str, str, str, int]:
    """``(release, content, style, take)`` of a clip name such as ``dataset-2_walk_normal_001``."""
    match = _CLIP_NAME.fullmatch(name)
    if match is None:
        raise ValueError(f"{where}: clip names look like 'dataset-<N>_<content>_<style>_<id>', got {name!r}")
    return match["release"], match["content"], match["style"], int(match["clip_id"])


def _decode(data: bytes, where: str) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{where}: not UTF-8 text ({e})") from None


def _parse_label_index(data: bytes, where: str) -> dict[str, int]:
    try:
        labels = json.loads(_decode(data, where))
        return {field: int(labels[field]) for field in _LABEL_FILES}
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        expected = '{"content": <int>, "style": <int>}'
        raise ValueError(f"{where}: expected {expected}, got {data[:80]!r} ({e})") from None


def _read_members(source: Path, selected: list[int] | None, progress: bool):
    """Stream the archive once: parsed motions, label indices and label files, keyed by name."""
    motions: dict[str, BvhMotion] = {}
    label_index: dict[str, dict[str, int]] = {}
    label_files: dict[str, list[str]] = {}
    seen_at: dict[str, PurePosixPath] = {}
    wanted = None if selected is None else set(selected)
    total = count_members(source, ("data/*.bvh",))
    if total is not None and selected is not None:
        total = None  # the filter is applied while streaming
    with tqdm(total=total, desc="parsing Bandai-Namco", unit="clip", leave=False, disable=not progress) as bar:
        for path, data in iter_members(source, _PATTERNS):
            where = f"{source}:{path}"
            rel = "/".join(path.parts[-2:])
            if rel in _LABEL_FILES.values():
                field = next(f for f, p in _LABEL_FILES.items() if p == rel)
                if field in label_files:
                    raise ValueError(f"{source}: more than one {rel} found (the last at {path})")
                label_files[field] = _decode(data, where).split()
                continue
            *_, clip_id = _parse_clip_name(path.stem, where)
            if wanted is not None and clip_id not in wanted:
                continue
            if path.name in seen_at:
                raise ValueError(f"{source}: {path.name} found twice ({seen_at[path.name]} and {path})")
            seen_at[path.name] = path
            if path.suffix == ".json":
                label_index[path.stem] = _parse_label_index(data, where)
            else:
                motions[path.stem] = parse_bvh(_decode(data, where), where)
                bar.update(1)
    return motions, label_index, label_files


def _check_labels(source: Path, name: str, index: Mapping[str, int], label_files: Mapping[str, list[str]]) -> None:
    """The JSON indices (0-based) must name the same content and style as the file name."""
    release, content, style, _ = _parse_clip_name(name, str(source))
    for field, expected in (("content", content), ("style", style)):
        labels, i = label_files[field], index[field]
        if not 0 <= i < len(labels):
            raise ValueError(f"{source}: {name}.json: {field} index {i} outside 0..{len(labels) - 1}")
        if labels[i] != f"{release}_{expected}":
            raise ValueError(
                f"{source}: {name}.json: {field} index {i} is {labels[i]!r} but the file name says {expected!r}"
            )


def _check_same_hierarchy(
    source: Path, name: str, motion: BvhMotion, reference_name: str, reference: BvhMotion
) -> None:
    same = (
        motion.skeleton.names == reference.skeleton.names
        and motion.skeleton.parents == reference.skeleton.parents
        and motion.channels == reference.channels
        and [p for p, _ in motion.end_sites] == [p for p, _ in reference.end_sites]
    )
    if not same:
        raise ValueError(
            f"{source}: {name}.bvh: its hierarchy (joints {motion.skeleton.names}, channels, End Sites) "
            f"differs from that of {reference_name}.bvh (joints {reference.skeleton.names})"
        )


def _release_of(source: Path, names: Sequence[str], label_files: Mapping[str, list[str]]) -> str:
    """The release prefix (``dataset-N``) shared by every clip name and label line."""
    release = _parse_clip_name(names[0], str(source))[0]
    for name in names:
        if _parse_clip_name(name, str(source))[0] != release:
            raise ValueError(f"{source}: clip {name!r} is not from release {release!r} like {names[0]!r}")
    for field, path in _LABEL_FILES.items():
        other = [line for line in label_files[field] if not line.startswith(f"{release}_")]
        if other:
            raise ValueError(f"{source}: {path}: label {other[0]!r} does not start with the clips' prefix {release + '_'!r}")
    return release


def _parse_corpus(source: Path, selected: list[int] | None, *, progress: bool) -> dict[str, np.ndarray]:
    motions, label_index, label_files = _read_members(source, selected, progress)
    missing_cfg = sorted(set(_LABEL_FILES) - set(label_files))
    if missing_cfg:
        raise ValueError(f"{source}: label file(s) {[_LABEL_FILES[f] for f in missing_cfg]} not found")
    if not motions:
        which = "" if selected is None else f" with ids {selected}"
        raise ValueError(f"{source}: no Bandai-Namco clips found{which}")
    unlabelled = sorted(set(motions) - set(label_index))
    orphan_labels = sorted(set(label_index) - set(motions))
    if unlabelled or orphan_labels:
        raise ValueError(
            f"{source}: clips without a .json label {unlabelled[:5]}, labels without a .bvh {orphan_labels[:5]}"
        )

    names = sorted(motions)
    reference = motions[names[0]]
    release = _release_of(source, names, label_files)
    for name in names:
        _check_labels(source, name, label_index[name], label_files)
        _check_same_hierarchy(source, name, motions[name], names[0], reference)
    clips = [motions[n] for n in names]
    return {
        "names": np.asarray(names),
        "content_ids": np.asarray([label_index[n]["content"] for n in names], np.int64),
        "style_ids": np.asarray([label_index[n]["style"] for n in names], np.int64),
        "clip_ids": np.asarray([_parse_clip_name(n, str(source))[3] for n in names], np.int64),
        "content_labels": np.asarray([s.removeprefix(f"{release}_") for s in label_files["content"]]),
        "style_labels": np.asarray([s.removeprefix(f"{release}_") for s in label_files["style"]]),
        "frame_times": np.asarray([m.frame_time for m in clips], np.float64),
        "starts": np.concatenate([[0], np.cumsum([m.num_frames for m in clips])]).astype(np.int64),
        "offsets": np.stack([np.asarray(m.skeleton.offsets, np.float64) for m in clips]),
        "quat_local": np.concatenate([m.quat_local for m in clips]),
        "pos_local": np.concatenate([m.pos_local for m in clips]),
        "channels": np.asarray([" ".join(c) for c in reference.channels]),
        **hierarchy_arrays(reference),
    }


def _corpus_from_arrays(arrays: Mapping[str, np.ndarray]) -> BandaiNamcoCorpus:
    return BandaiNamcoCorpus(
        names=tuple(str(n) for n in arrays["names"]),
        content_ids=arrays["content_ids"],
        style_ids=arrays["style_ids"],
        clip_ids=arrays["clip_ids"],
        content_labels=tuple(str(s) for s in arrays["content_labels"]),
        style_labels=tuple(str(s) for s in arrays["style_labels"]),
        frame_times=arrays["frame_times"],
        starts=arrays["starts"],
        offsets=arrays["offsets"],
        quat_local=arrays["quat_local"],
        pos_local=arrays["pos_local"],
        channels=tuple(tuple(c.split()) for c in arrays["channels"]),
        **hierarchy_from_arrays(arrays),
    )
