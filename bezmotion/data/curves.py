"""Curve datasets: windows of mocap reduced to Bézier curves of the six characteristic joints.

This is what the Bézier Motion Model trains on (BMM §4.1, §5.2): every ``window``-frame
window (31 by default) of a corpus is run through FK, reduced to the six characteristic
joints, translated so the hips start at the origin in XZ, labelled with foot contacts,
and fitted once with :func:`bezmotion.bezier.fit_curves`. Results are cached on disk
(:mod:`bezmotion.data.cache`), so the fit runs once per corpus and configuration.

Splits: LaFAN1 subjects 1–4 train and subject 5 validates (as in the paper);
Bandai-Namco uses :func:`bezmotion.data.bandai_namco.bandai_namco_split` — every 10th take
of each content × style class validates, whole clips on one side.

Any other corpus works through :class:`MotionClips` (e.g. :meth:`MotionClips.from_bvh`)
and :func:`build_curve_dataset` with a characteristic-joint map.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable, Iterator, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from bezmotion.bezier import DEFAULT_STRIDE, BezierLayout, fit_curves
from bezmotion.data import bandai_namco as _bandai_namco
from bezmotion.data import lafan1 as _lafan1
from bezmotion.data.bvh import BvhMotion
from bezmotion.data.cache import cached_arrays, fingerprint
from bezmotion.data.characteristic import (
    CHARACTERISTIC_JOINTS,
    align_to_start,
    characteristic_indices,
    characteristic_trajectories,
    contact_labels,
)

DEFAULT_WINDOW = 31  # frames; BMM trains on 31-frame windows (§5.2)
DEFAULT_OFFSET = 5  # frames between consecutive window starts
SPLITS = ("train", "validation")
_CHUNK = 1024  # windows per compiled fitting call (fixed, so one compilation serves all)
_FORMAT_VERSION = 1  # bump when the cached arrays change meaning


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
    def from_lafan1(cls, corpus: _lafan1.Lafan1Corpus, files: Sequence[int] | np.ndarray) -> MotionClips:
        """The given LaFAN1 files (raw, no benchmark preprocessing)."""
        files = [int(f) for f in files]
        quat, pos = [], []
        for f in files:
            q, root = corpus.clip(f)
            p = np.broadcast_to(corpus.offsets[f], q.shape[:1] + corpus.offsets.shape[1:]).copy()
            p[:, 0] = root
            quat.append(q)
            pos.append(p)
        lengths = [len(q) for q in quat]
        return cls(
            _lafan1.PARENTS, _lafan1.JOINT_NAMES, _concat(quat, (0, 22, 4)), _concat(pos, (0, 22, 3)),
            np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64), float(_lafan1.FPS),
        )  # fmt: skip

    @classmethod
    def from_bandai_namco(
        cls, corpus: _bandai_namco.BandaiNamcoCorpus, clips: Sequence[int] | np.ndarray
    ) -> MotionClips:
        """The given Bandai-Namco clips (indices into the corpus)."""
        clips = [int(i) for i in clips]
        spans = [(int(corpus.starts[i]), int(corpus.starts[i + 1])) for i in clips]
        frames = np.concatenate([np.arange(s, e) for s, e in spans]) if spans else np.zeros(0, np.int64)
        frame_times = np.unique(corpus.frame_times[clips]) if clips else np.asarray([1.0 / _bandai_namco.FPS])
        if len(frame_times) > 1:
            raise ValueError(f"the selected Bandai-Namco clips mix frame times {frame_times.tolist()}")
        fps = 1.0 / float(frame_times[0])
        return cls(
            corpus.parents, corpus.joint_names, corpus.quat_local[frames], corpus.pos_local[frames],
            np.concatenate([[0], np.cumsum([e - s for s, e in spans])]).astype(np.int64), round(fps, 6),
        )  # fmt: skip

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
            np.concatenate([[0], np.cumsum([len(m.quat_local) for m in motions])]).astype(np.int64),
            round(1.0 / first.frame_time, 6),
        )  # fmt: skip


def _concat(arrays: list[np.ndarray], empty_shape: tuple[int, ...]) -> np.ndarray:
    return np.concatenate(arrays) if arrays else np.zeros(empty_shape)


@dataclasses.dataclass(frozen=True)
class CurveDataset:
    """Fitted Bézier curves of the six characteristic joints, one row per window (float32).

    Joint axes follow :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS`; positions
    are aligned (hips start at the origin in XZ) and in cm.

    Attributes:
      layout: window length and stride of the curves.
      fps: frame rate of the source motion.
      ctrl_pos, ctrl_tangent: ``(windows, controls, 6, 3)`` the curves.
      ctrl_rot6d: ``(windows, controls, 6, 6)`` global joint orientations at control frames.
      ctrl_contacts: ``(windows, controls, 2)`` left/right foot contact at control frames.
      dense_pos: ``(windows, frames, 6, 3)`` the mocap trajectories the curves were fitted to.
      dense_contacts: ``(windows, frames, 2)`` foot contacts at every frame.
      fit_rms: ``(windows, 6)`` RMS fit error per joint (cm).
      clip_index, start_frame: ``(windows,)`` where each window comes from (indices into
        the :class:`MotionClips` it was built from).
    """

    layout: BezierLayout
    fps: float
    ctrl_pos: np.ndarray
    ctrl_tangent: np.ndarray
    ctrl_rot6d: np.ndarray
    ctrl_contacts: np.ndarray
    dense_pos: np.ndarray
    dense_contacts: np.ndarray
    fit_rms: np.ndarray
    clip_index: np.ndarray
    start_frame: np.ndarray

    _ARRAYS = (
        "ctrl_pos", "ctrl_tangent", "ctrl_rot6d", "ctrl_contacts", "dense_pos", "dense_contacts", "fit_rms",
        "clip_index", "start_frame",
    )  # fmt: skip

    def __len__(self) -> int:
        return self.ctrl_pos.shape[0]

    def subset(self, indices: np.ndarray | Sequence[int]) -> CurveDataset:
        """The windows at ``indices`` (any NumPy index: ints or a boolean mask)."""
        return dataclasses.replace(self, **{k: getattr(self, k)[indices] for k in self._ARRAYS})

    def to_arrays(self) -> dict[str, np.ndarray]:
        arrays = {k: getattr(self, k) for k in self._ARRAYS}
        arrays.update(num_frames=np.asarray(self.layout.num_frames), stride=np.asarray(self.layout.stride))
        arrays["fps"] = np.asarray(self.fps)
        return arrays

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> CurveDataset:
        layout = BezierLayout(int(arrays["num_frames"]), int(arrays["stride"]))
        return cls(layout, float(arrays["fps"]), **{k: np.asarray(arrays[k]) for k in cls._ARRAYS})


@functools.partial(jax.jit, static_argnames=("parents", "indices", "layout", "fps", "pin_positions"))
def _window_curves(quat_local, pos_local, *, parents, indices, layout, fps, pin_positions):
    """One chunk of windows ``(chunk, frames, joints, ·)`` → the dataset's per-window arrays."""
    pos, rot6d = characteristic_trajectories(parents, indices, quat_local, pos_local)
    pos, _ = align_to_start(pos)
    contacts = contact_labels(pos, fps)
    fit = fit_curves(layout, jnp.moveaxis(pos, -2, -3), pin_positions=pin_positions)  # per joint: (chunk, 6, frames, 3)
    ctrl = layout.control_frames
    return {
        "ctrl_pos": jnp.moveaxis(fit.ctrl_pos, -3, -2),
        "ctrl_tangent": jnp.moveaxis(fit.ctrl_tangent, -3, -2),
        "ctrl_rot6d": rot6d[:, ctrl],
        "ctrl_contacts": contacts[:, ctrl],
        "dense_pos": pos,
        "dense_contacts": contacts,
        "fit_rms": fit.rms_error,
        "fit_ok": fit.succeeded,
    }


def characteristic_windows(
    clips: MotionClips,
    mapping: str | Mapping[str, str],
    *,
    window: int = DEFAULT_WINDOW,
    offset: int = DEFAULT_OFFSET,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Aligned six-joint trajectories of every window, without fitting.

    Returns:
      ``(positions (windows, window, 6, 3) cm, rot6d (windows, window, 6, 6),
      clip_index (windows,), start_frame (windows,))``, float32.
    """
    indices = characteristic_indices(clips.joint_names, mapping)
    clip_index, start_frame = clips.window_starts(window, offset)
    pos = [np.zeros((0, window, 6, 3), np.float32)]
    rot = [np.zeros((0, window, 6, 6), np.float32)]
    for chunk in _chunks(clips, clip_index, start_frame, window):
        p, r = _aligned_trajectories(*chunk, parents=clips.parents, indices=indices)
        pos.append(np.asarray(p))
        rot.append(np.asarray(r))
    n = len(clip_index)
    return np.concatenate(pos)[:n], np.concatenate(rot)[:n], clip_index, start_frame


@functools.partial(jax.jit, static_argnames=("parents", "indices"))
def _aligned_trajectories(quat_local, pos_local, *, parents, indices):
    pos, rot6d = characteristic_trajectories(parents, indices, quat_local, pos_local)
    return align_to_start(pos)[0], rot6d


def _chunks(
    clips: MotionClips, clip_index: np.ndarray, start_frame: np.ndarray, window: int
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Float32 ``(quat_local, pos_local)`` of ``_CHUNK`` windows at a time; the last chunk is
    padded by repeating its first window, so every call has the same shape."""
    frames = clips.starts[clip_index] + start_frame
    for lo in range(0, len(frames), _CHUNK):
        part = frames[lo : lo + _CHUNK]
        part = np.concatenate([part, np.full(_CHUNK - len(part), part[0])])
        idx = part[:, None] + np.arange(window)
        yield clips.quat_local[idx].astype(np.float32), clips.pos_local[idx].astype(np.float32)


def build_curve_dataset(
    clips: MotionClips,
    mapping: str | Mapping[str, str],
    *,
    window: int = DEFAULT_WINDOW,
    stride: int = DEFAULT_STRIDE,
    offset: int = DEFAULT_OFFSET,
    pin_positions: bool = True,
    progress: bool = True,
    description: str = "fitting curves",
) -> CurveDataset:
    """Fit curves to every window of ``clips`` (no cache; see the corpus functions for that).

    Args:
      clips: the motion.
      mapping: characteristic-joint map (preset name or dict, see
        :func:`~bezmotion.data.characteristic.characteristic_indices`).
      window: frames per window; stride: frames between control points; offset: frames
        between window starts; pin_positions: see :func:`~bezmotion.bezier.fit_curves`.
      progress: show a tqdm bar over windows.
    Raises:
      RuntimeError: a fit did not converge (names the window).
    """
    layout = BezierLayout(window, stride)
    indices = characteristic_indices(clips.joint_names, mapping)
    clip_index, start_frame = clips.window_starts(window, offset)
    n = len(clip_index)
    parts: dict[str, list[np.ndarray]] = {}
    with tqdm(total=n, desc=description, unit="window", disable=not progress, leave=False) as bar:
        for chunk in _chunks(clips, clip_index, start_frame, window):
            out = _window_curves(
                *chunk, parents=clips.parents, indices=indices, layout=layout, fps=clips.fps,
                pin_positions=pin_positions,
            )  # fmt: skip
            for k, v in out.items():
                parts.setdefault(k, []).append(np.asarray(v))
            bar.update(min(_CHUNK, n - bar.n))
    if n == 0:
        raise ValueError(f"no windows of {window} frames in {clips.num_clips} clips (longest {np.diff(clips.starts).max(initial=0)})")
    arrays = {k: np.concatenate(v)[:n] for k, v in parts.items()}
    failed = np.flatnonzero(~arrays.pop("fit_ok").all(axis=1))
    if failed.size:
        i = failed[0]
        raise RuntimeError(
            f"curve fit did not converge for {failed.size} windows, first: clip {clip_index[i]}, frame {start_frame[i]}"
        )
    return CurveDataset(layout, clips.fps, clip_index=clip_index, start_frame=start_frame, **arrays)


def _check_split(split: str) -> None:
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")


def lafan1_clips(source: str | os.PathLike, split: str, *, use_cache: bool = True) -> MotionClips:
    """The clips behind :func:`lafan1_curve_dataset` (its ``clip_index`` indexes these)."""
    _check_split(split)
    corpus = _lafan1.load_lafan1(source, use_cache=use_cache)
    return MotionClips.from_lafan1(corpus, corpus.files_of(_lafan1.TRAIN_SUBJECTS if split == "train" else _lafan1.TEST_SUBJECTS))


def bandai_namco_clips(
    source: str | os.PathLike, split: str, *, use_cache: bool = True, progress: bool = True
) -> MotionClips:
    """The clips behind :func:`bandai_namco_curve_dataset` (its ``clip_index`` indexes these)."""
    _check_split(split)
    corpus = _bandai_namco.load_bandai_namco(source, use_cache=use_cache, progress=progress)
    train, validation = _bandai_namco.bandai_namco_split(corpus)
    return MotionClips.from_bandai_namco(corpus, train if split == "train" else validation)


def _corpus_curve_dataset(
    label: str,
    mapping: str,
    load_clips: Callable[[], MotionClips],
    source_key: Callable[..., str],
    *,
    split: str,
    window: int,
    stride: int,
    offset: int,
    pin_positions: bool,
    use_cache: bool,
    progress: bool,
) -> CurveDataset:
    """Build (or load from the cache) one split of a corpus's curve dataset."""
    params = dict(split=split, window=window, stride=stride, offset=offset, pin=pin_positions, v=_FORMAT_VERSION)

    def build() -> dict[str, np.ndarray]:
        return build_curve_dataset(
            load_clips(), mapping, window=window, stride=stride, offset=offset, pin_positions=pin_positions,
            progress=progress, description=f"fitting {label} {split} curves",
        ).to_arrays()  # fmt: skip

    name = f"{mapping.replace('_', '-')}-curves"
    key = source_key(corpus=name, **params) if use_cache else ""
    return CurveDataset.from_arrays(cached_arrays(name, key, build, use_cache=use_cache))


def lafan1_curve_dataset(
    source: str | os.PathLike,
    split: str = "train",
    *,
    window: int = DEFAULT_WINDOW,
    stride: int = DEFAULT_STRIDE,
    offset: int = DEFAULT_OFFSET,
    pin_positions: bool = True,
    use_cache: bool = True,
    progress: bool = True,
) -> CurveDataset:
    """LaFAN1 curve dataset: ``"train"`` = subjects 1–4, ``"validation"`` = subject 5.

    ``clip_index`` indexes the files of that split's subjects in corpus order
    (``corpus.files_of(subjects)``). Fitted once per configuration and cached.
    """
    _check_split(split)
    return _corpus_curve_dataset(
        "LaFAN1", "lafan1", functools.partial(lafan1_clips, source, split, use_cache=use_cache), functools.partial(fingerprint, source), split=split, window=window,
        stride=stride, offset=offset, pin_positions=pin_positions, use_cache=use_cache, progress=progress,
    )  # fmt: skip


def bandai_namco_curve_dataset(
    source: str | os.PathLike,
    split: str = "train",
    *,
    window: int = DEFAULT_WINDOW,
    stride: int = DEFAULT_STRIDE,
    offset: int = DEFAULT_OFFSET,
    pin_positions: bool = True,
    use_cache: bool = True,
    progress: bool = True,
) -> CurveDataset:
    """Bandai-Namco curve dataset, split by clip with
    :func:`~bezmotion.data.bandai_namco.bandai_namco_split` (every 10th take validates).

    ``clip_index`` indexes that split's clips (``bandai_namco_split(corpus)[0 or 1]``).
    Clips shorter than ``window`` contribute no windows.
    """
    _check_split(split)
    return _corpus_curve_dataset(
        "Bandai-Namco", "bandai_namco",
        functools.partial(bandai_namco_clips, source, split, use_cache=use_cache, progress=progress), functools.partial(_bandai_namco.source_fingerprint, source),
        split=split, window=window, stride=stride, offset=offset, pin_positions=pin_positions, use_cache=use_cache,
        progress=progress,
    )  # fmt: skip


__all__ = [
    "CHARACTERISTIC_JOINTS",
    "CurveDataset",
    "MotionClips",
    "bandai_namco_clips",
    "bandai_namco_curve_dataset",
    "build_curve_dataset",
    "characteristic_windows",
    "lafan1_clips",
    "lafan1_curve_dataset",
]
