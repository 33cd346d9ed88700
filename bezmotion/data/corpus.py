"""One interface for every motion corpus, and the clips every consumer reads from it.

A corpus is a set of labelled clips of one skeleton with an official train/validation
split: LaFAN1 (:func:`~bezmotion.data.lafan1.load_lafan1`), Bandai-Namco
(:func:`~bezmotion.data.bandai_namco.load_bandai_namco`), Anidance
(:func:`~bezmotion.data.anidance.load_anidance`) or a user's folder of BVH files
(:func:`~bezmotion.data.bvh_folder.load_bvh_folder`); :func:`bezmotion.data.sources.load_corpus`
opens any of them by name or path. Consumers (curve datasets, IK frames, experiments) take
a :class:`Corpus` and never branch on which one it is.

**Positions-only corpora.** Anidance stores 24 joint positions per frame, with no
hierarchy and no rotations. It has the same name, clip names, labels, split and frame rate
as every other corpus, but its ``skeleton`` and ``characteristic_map`` are ``None`` and
:meth:`Corpus.motion` raises ``ValueError``: nothing that needs rotations (curve datasets,
IK frames) can run on it, and it says so instead of inventing a skeleton.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from bezmotion.data.bvh import BvhMotion
from bezmotion.geometry.skeleton import Skeleton

SPLITS: tuple[str, ...] = ("train", "validation")


def check_split(split: str) -> None:
    """Raise ``ValueError`` unless ``split`` is one of :data:`SPLITS`."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")


@dataclasses.dataclass(frozen=True)
class MotionClips:
    """Clips of one hierarchy, frames concatenated along time (any corpus, NumPy float64).

    Attributes:
      parents, joint_names: the hierarchy.
      quat_local: ``(frames, joints, 4)`` local rotations (w, x, y, z).
      pos_local: ``(frames, joints, 3)`` local translations with animated channels
        filled in (the root's world position on joint 0 for LaFAN1), cm.
      starts: ``(clips + 1,)`` clip ``i`` is frames ``starts[i]:starts[i+1]``.
      fps: frames per second.
    """

    parents: tuple[int, ...]
    joint_names: tuple[str, ...]
    quat_local: np.ndarray
    pos_local: np.ndarray
    starts: np.ndarray
    fps: float

    def __post_init__(self):
        if len(self.joint_names) != len(self.parents):
            raise ValueError(f"MotionClips: {len(self.joint_names)} joint names for {len(self.parents)} joints")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"MotionClips.fps must be positive, got {self.fps}")
        if self.quat_local.ndim != 3:
            raise ValueError(f"MotionClips.quat_local must be (frames, joints, 4), got {self.quat_local.shape}")
        frames, joints = self.quat_local.shape[:2]
        if self.quat_local.shape != (frames, len(self.parents), 4) or self.pos_local.shape != (frames, joints, 3):
            raise ValueError(
                f"MotionClips: quat_local {self.quat_local.shape} and pos_local {self.pos_local.shape} must be "
                f"(frames, {len(self.parents)}, 4) and (frames, {len(self.parents)}, 3)"
            )
        starts = np.asarray(self.starts)
        if starts.ndim != 1 or starts.size == 0 or starts[0] != 0 or starts[-1] != frames or np.any(np.diff(starts) < 0):
            raise ValueError(f"MotionClips.starts must rise from 0 to {frames}, got {starts}")

    @property
    def num_clips(self) -> int:
        return len(self.starts) - 1

    def window_starts(self, window: int, offset: int) -> tuple[np.ndarray, np.ndarray]:
        """``(clip_index, start_frame)`` of every ``window``-frame window, ``offset`` apart,
        that fits inside its clip (``start + window ≤ clip length``)."""
        if window < 2 or offset < 1:
            raise ValueError(f"window must be ≥ 2 and offset ≥ 1, got window={window}, offset={offset}")
        starts = [np.arange(0, n - window + 1, offset, dtype=np.int64) for n in np.diff(self.starts)]
        clip_index = np.repeat(np.arange(self.num_clips, dtype=np.int64), [len(s) for s in starts])
        start_frame = np.concatenate(starts) if starts else np.zeros(0, np.int64)
        return clip_index, start_frame

    @classmethod
    def from_bvh(cls, motions: Sequence[BvhMotion]) -> MotionClips:
        """Clips read with :func:`bezmotion.data.bvh.read_bvh`; all must share hierarchy and frame rate."""
        if not motions:
            raise ValueError("MotionClips.from_bvh needs at least one motion")
        first = motions[0]
        for i, m in enumerate(motions):
            if m.skeleton.parents != first.skeleton.parents or m.skeleton.names != first.skeleton.names:
                raise ValueError(f"motion {i} has a different hierarchy from motion 0")
            if not np.isclose(m.frame_time, first.frame_time):
                raise ValueError(f"motion {i} has frame time {m.frame_time}, motion 0 has {first.frame_time}")
        return cls(
            first.skeleton.parents, first.skeleton.names,
            np.concatenate([m.quat_local for m in motions]), np.concatenate([m.pos_local for m in motions]),
            clip_starts([len(m.quat_local) for m in motions]), round(1.0 / first.frame_time, 6),
        )  # fmt: skip


def clip_starts(lengths: Sequence[int]) -> np.ndarray:
    """``(clips + 1,)`` int64 offsets of clips of the given lengths laid end to end."""
    return np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)]).astype(np.int64)


def gather_clips(starts: np.ndarray, indices: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(frames, new_starts)``: the frame indices of clips ``indices`` (of a corpus whose clip
    ``i`` is frames ``starts[i]:starts[i+1]``) laid end to end, and where each one starts."""
    spans = [(int(starts[i]), int(starts[i + 1])) for i in indices]
    frames = np.concatenate([np.arange(s, e) for s, e in spans]) if spans else np.zeros(0, np.int64)
    return frames, clip_starts([e - s for s, e in spans])


def hierarchy_arrays(motion: BvhMotion) -> dict[str, np.ndarray]:
    """A motion's hierarchy (parents, joint names, End Sites) as plain arrays, for a corpus cache."""
    return {
        "parents": np.asarray(motion.skeleton.parents, np.int64),
        "joint_names": np.asarray(motion.skeleton.names),
        "end_site_parents": np.asarray([p for p, _ in motion.end_sites], np.int64),
        "end_site_offsets": np.asarray([o for _, o in motion.end_sites], np.float64).reshape(-1, 3),
    }


def hierarchy_from_arrays(arrays: Mapping[str, np.ndarray]) -> dict:
    """``{"parents", "joint_names", "end_sites"}`` back from :func:`hierarchy_arrays`."""
    end_sites = tuple(
        (int(p), tuple(float(v) for v in o)) for p, o in zip(arrays["end_site_parents"], arrays["end_site_offsets"])
    )
    return {
        "parents": tuple(int(p) for p in arrays["parents"]),
        "joint_names": tuple(str(n) for n in arrays["joint_names"]),
        "end_sites": end_sites,
    }


def concat_frames(arrays: Sequence[np.ndarray], empty_shape: tuple[int, ...]) -> np.ndarray:
    """``np.concatenate(arrays)``, or zeros of ``empty_shape`` when there are none."""
    return np.concatenate(arrays) if arrays else np.zeros(empty_shape)


@runtime_checkable
class Corpus(Protocol):
    """What every corpus offers its consumers (LaFAN1, Bandai-Namco, Anidance, a BVH folder).

    Attributes:
      name: ``"lafan1"``, ``"bandai_namco"``, ``"anidance"`` or a folder corpus's name;
        it names cache entries and characters.
      skeleton: the reference skeleton (a :class:`Skeleton` with the offsets of one
        reference clip, stated by each corpus), ``None`` for positions-only corpora.
      fps: frames per second.
      clip_names: one name per clip (file stems), in corpus order.
      characteristic_map: role → joint name of the six characteristic joints (or a preset
        name of :data:`~bezmotion.data.characteristic.SKELETON_MAPS`); ``None`` when unknown.
      end_sites: the skeleton's End Sites ``(parent joint, offset cm)``, for export.
    """

    @property
    def name(self) -> str: ...

    @property
    def skeleton(self) -> Skeleton | None: ...

    @property
    def fps(self) -> float: ...

    @property
    def clip_names(self) -> tuple[str, ...]: ...

    @property
    def characteristic_map(self) -> str | Mapping[str, str] | None: ...

    @property
    def end_sites(self) -> tuple[tuple[int, tuple[float, float, float]], ...]: ...

    def __len__(self) -> int: ...

    def labels(self, index: int) -> dict[str, str | int]:
        """The labels of clip ``index`` (e.g. subject, content, style, file name)."""
        ...

    def split(self, split: str) -> np.ndarray:
        """Clip indices of the official ``"train"`` or ``"validation"`` split, in corpus order."""
        ...

    def motion(self, indices: Sequence[int] | np.ndarray) -> MotionClips:
        """Local rotations and translations of the clips at ``indices``, in the order given."""
        ...

    def source_key(self, **params) -> str:
        """Cache key of the files (and clip selection) this corpus was loaded from, with ``params``."""
        ...


def no_source_key(corpus_name: str) -> ValueError:
    """The error of :meth:`Corpus.source_key` on a corpus built in memory (nothing to hash)."""
    return ValueError(f"{corpus_name}: this corpus was not loaded from files, so it has no cache key; pass use_cache=False")


def motion_clips(corpus: Corpus, split: str) -> MotionClips:
    """The clips of one split of ``corpus`` (``"train"`` or ``"validation"``), in corpus order."""
    check_split(split)
    return corpus.motion(corpus.split(split))


__all__ = ["SPLITS", "Corpus", "MotionClips", "check_split", "clip_starts", "motion_clips"]

