"""A folder of BVH files of one skeleton (a user's own clips) as a corpus.

Every ``*.bvh`` directly in the folder is one clip, in file-name order. They must share
one skeleton — the same joint names and parents, the same OFFSETs (within
:data:`OFFSET_TOLERANCE` cm) on joints without animated position channels — and one
frame time, unless ``fps`` resamples every file to one; the first file that does not
raises ``ValueError`` naming it. The parsed
clips are cached on disk like the published corpora.

Split: the files listed in ``validation_files``, or else every ``validation_every``-th
file in name order (the 10th, 20th, …), validate; the rest train.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from bezmotion.data.bvh import BvhMotion, parse_bvh
from bezmotion.data.cache import cached_arrays, fingerprint
from bezmotion.data.corpus import (
    MotionClips,
    check_split,
    clip_starts,
    gather_clips,
    hierarchy_arrays,
    hierarchy_from_arrays,
    no_source_key,
)
from bezmotion.data.resample import resample_motion
from bezmotion.geometry.skeleton import Skeleton

VALIDATION_EVERY = 10  # default: the 10th, 20th, … file validates
OFFSET_TOLERANCE = 1e-3  # cm; OFFSETs of non-translated joints may differ by this much between files
_FORMAT_VERSION = 2  # bump when the cached arrays change meaning (2: frame rates read from the written decimals)


@dataclasses.dataclass(frozen=True)
class BvhFolderCorpus:
    """Clips of one skeleton read from a folder, frames concatenated along time (float64);
    a :class:`~bezmotion.data.corpus.Corpus`. The reference skeleton is the first file's.

    Attributes:
      name: the corpus name (the folder's name unless given).
      parents, joint_names: the shared hierarchy.
      end_sites: the first file's End Sites ``(parent joint, offset cm)``.
      frame_time: seconds per frame, shared by every file.
      clip_names: file stems, sorted.
      is_validation: ``(clips,)`` whether each clip is in the validation split.
      starts: ``(clips + 1,)`` clip ``i`` is frames ``starts[i]:starts[i+1]``.
      offsets: ``(clips, joints, 3)`` each file's OFFSET lines (cm).
      quat_local: ``(frames, joints, 4)`` local rotations (w, x, y, z), continuity-fixed.
      pos_local: ``(frames, joints, 3)`` local translations, animated channels filled in (cm).
      characteristic_map: role → joint name of the six characteristic joints (or a preset
        name), ``None`` if not given.
      cache_inputs: the files read (hashed into cache keys).
    """

    name: str
    parents: tuple[int, ...]
    joint_names: tuple[str, ...]
    end_sites: tuple[tuple[int, tuple[float, float, float]], ...]
    frame_time: float
    clip_names: tuple[str, ...]
    is_validation: np.ndarray
    starts: np.ndarray
    offsets: np.ndarray
    quat_local: np.ndarray
    pos_local: np.ndarray
    characteristic_map: str | Mapping[str, str] | None = None
    cache_inputs: tuple[Path, ...] = ()

    def __len__(self) -> int:
        return len(self.clip_names)

    @property
    def fps(self) -> float:
        return round(1.0 / self.frame_time, 6)

    @property
    def skeleton(self) -> Skeleton:
        """The reference skeleton: the first file's."""
        return Skeleton(self.parents, self.joint_names, self.offsets[0])

    def labels(self, index: int) -> dict[str, str | int]:
        """``{"file"}``: the clip's file stem."""
        return {"file": self.clip_names[index]}

    def split(self, split: str) -> np.ndarray:
        """Clip indices of ``"train"`` or ``"validation"``, in name order."""
        check_split(split)
        return np.flatnonzero(self.is_validation if split == "validation" else ~self.is_validation)

    def motion(self, indices: Sequence[int] | np.ndarray) -> MotionClips:
        """The clips at ``indices``, in the order given."""
        frames, starts = gather_clips(self.starts, indices)
        return MotionClips(self.parents, self.joint_names, self.quat_local[frames], self.pos_local[frames], starts, self.fps)

    def source_key(self, **params) -> str:
        """:func:`~bezmotion.data.cache.fingerprint` of the BVH files and the split, with ``params``."""
        if not self.cache_inputs:
            raise no_source_key(self.name)
        validation = [n for n, v in zip(self.clip_names, self.is_validation) if v]
        return fingerprint(*self.cache_inputs, **params, validation=validation)


def load_bvh_folder(
    path: str | os.PathLike,
    *,
    characteristic: str | Mapping[str, str] | None = None,
    validation_every: int | None = VALIDATION_EVERY,
    validation_files: Collection[str] | None = None,
    name: str | None = None,
    fps: float | None = None,
    use_cache: bool = True,
    progress: bool = True,
) -> BvhFolderCorpus:
    """Read every ``*.bvh`` directly in ``path`` as one corpus (cached on disk).

    Args:
      path: the folder.
      characteristic: the six characteristic joints (a preset name such as ``"lafan1"``
        or a role → joint-name dict), needed for curve datasets and IK frames.
      validation_every: every ``validation_every``-th file in name order validates
        (``None``: none); ignored when ``validation_files`` is given.
      validation_files: file names or stems of the validation clips.
      name: the corpus name (default: the folder's name).
      fps: resample every file to this rate on reading
        (:func:`~bezmotion.data.resample.resample_motion`, through its first frame), so files
        of different rates make one corpus; ``None``: as they are (every file at the first's).
      use_cache: ``False`` always parses and never touches the cache.
      progress: show a tqdm bar while parsing.
    Raises:
      FileNotFoundError: ``path`` does not exist.
      ValueError: not a folder, no ``.bvh`` files, a file whose skeleton or (without
        ``fps``) frame time differs from the first file's (named), or a bad split rule.
    """
    folder = Path(path)
    if not folder.exists():
        raise FileNotFoundError(f"BVH folder {folder} does not exist")
    if not folder.is_dir():
        raise ValueError(f"{folder}: expected a folder of .bvh files")
    files = sorted(p for p in folder.glob("*.bvh") if p.is_file())
    if not files:
        raise ValueError(f"{folder}: no .bvh files found")
    stems = tuple(p.stem for p in files)
    is_validation = _validation_mask(folder, stems, validation_every, validation_files)
    key = fingerprint(*files, corpus="bvh-folder", version=_FORMAT_VERSION, **({} if fps is None else {"fps": float(fps)}))
    arrays = cached_arrays("bvh-folder", key, lambda: _parse_folder(files, progress, fps), use_cache=use_cache)
    return BvhFolderCorpus(
        name=name if name is not None else folder.resolve().name,
        **hierarchy_from_arrays(arrays),
        frame_time=float(arrays["frame_time"]),
        clip_names=stems,
        is_validation=is_validation,
        **{k: arrays[k] for k in ("starts", "offsets", "quat_local", "pos_local")},
        characteristic_map=characteristic,
        cache_inputs=tuple(files),
    )


def _validation_mask(
    folder: Path, stems: tuple[str, ...], every: int | None, listed: Collection[str] | None
) -> np.ndarray:
    if listed is not None:
        wanted = {Path(f).stem for f in listed}
        unknown = sorted(wanted - set(stems))
        if unknown:
            raise ValueError(f"{folder}: validation files {unknown} are not among its .bvh files")
        return np.asarray([s in wanted for s in stems], bool)
    if every is None:
        return np.zeros(len(stems), bool)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"validation_every must be a positive integer or None, got {every!r}")
    return (np.arange(1, len(stems) + 1) % every) == 0


def _check_same_skeleton(path: Path, motion: BvhMotion, first_path: Path, first: BvhMotion) -> None:
    """Raise ``ValueError`` naming ``path`` if its skeleton or frame time is not ``first``'s."""
    skeleton, reference = motion.skeleton, first.skeleton
    if skeleton.names != reference.names or skeleton.parents != reference.parents:
        raise ValueError(
            f"{path}: its skeleton (joints {skeleton.names}, parents {skeleton.parents}) differs from that of "
            f"{first_path.name} (joints {reference.names}, parents {reference.parents}); a corpus has one skeleton"
        )
    translated = [
        any(c.lower().endswith("position") for c in a + b) for a, b in zip(motion.channels, first.channels)
    ]  # animated positions replace the OFFSET, so only the others must agree
    gap = np.abs(np.asarray(skeleton.offsets) - np.asarray(reference.offsets)).max(axis=-1)
    gap[np.asarray(translated)] = 0.0
    if gap.max(initial=0.0) > OFFSET_TOLERANCE:
        j = int(np.argmax(gap))
        raise ValueError(
            f"{path}: joint {skeleton.names[j]!r} has OFFSET {np.asarray(skeleton.offsets)[j].tolist()}, "
            f"{first_path.name} has {np.asarray(reference.offsets)[j].tolist()}; a corpus has one skeleton"
        )
    if not np.isclose(motion.frame_time, first.frame_time):
        raise ValueError(f"{path}: frame time {motion.frame_time} s, {first_path.name} has {first.frame_time} s")


def _parse_folder(files: Sequence[Path], progress: bool, fps: float | None = None) -> dict[str, np.ndarray]:
    motions: list[BvhMotion] = []
    for path in tqdm(files, desc="parsing BVH folder", unit="file", leave=False, disable=not progress):
        try:
            text = path.read_bytes().decode("utf-8")
        except UnicodeDecodeError as e:
            raise ValueError(f"{path}: not UTF-8 text ({e})") from None
        motion = parse_bvh(text, str(path))
        if fps is not None:
            motion, _ = resample_motion(motion, fps)
        if motions:
            _check_same_skeleton(path, motion, files[0], motions[0])
        motions.append(motion)
    first = motions[0]
    return {
        "starts": clip_starts([m.num_frames for m in motions]),
        "offsets": np.stack([np.asarray(m.skeleton.offsets, np.float64) for m in motions]),
        "quat_local": np.concatenate([m.quat_local for m in motions]),
        "pos_local": np.concatenate([m.pos_local for m in motions]),
        "frame_time": np.asarray(first.frame_time, np.float64),
        **hierarchy_arrays(first),
    }


__all__ = ["BvhFolderCorpus", "load_bvh_folder"]
