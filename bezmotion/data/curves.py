"""Curve datasets: windows of mocap reduced to Bézier curves of the six characteristic joints.

This is what the Bézier Motion Model trains on (BMM §4.1, §5.2): every ``window``-frame
window (31 by default) of a corpus is run through FK, reduced to the six characteristic
joints, translated so the hips start at the origin in XZ, labelled with foot contacts,
and fitted once with :func:`bezmotion.bezier.fit_curves`. Results are cached on disk
(:mod:`bezmotion.data.cache`), so the fit runs once per corpus and configuration.

:func:`curve_dataset` takes any :class:`~bezmotion.data.corpus.Corpus` and one of its
official splits (LaFAN1: subjects 1–4 train, subject 5 validates, as in the paper;
Bandai-Namco: every 10th take of each content × style class validates; a BVH folder: its
own rule). Any other motion works through :class:`~bezmotion.data.corpus.MotionClips`
(e.g. :meth:`~bezmotion.data.corpus.MotionClips.from_bvh`) and :func:`build_curve_dataset`
with a characteristic-joint map.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Iterator, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from bezmotion.bezier import DEFAULT_STRIDE, BezierLayout, fit_curves
from bezmotion.data.cache import cached_arrays
from bezmotion.data.characteristic import (
    CHARACTERISTIC_JOINTS,
    HIPS,
    align_to_start,
    characteristic_indices,
    characteristic_trajectories,
    contact_labels,
)
from bezmotion.data.corpus import Corpus, MotionClips, check_split, motion_clips
from bezmotion.geometry.skeleton import forward_kinematics

DEFAULT_WINDOW = 31  # frames; BMM trains on 31-frame windows (§5.2)
DEFAULT_OFFSET = 5  # frames between consecutive window starts
_CHUNK = 1024  # windows per compiled fitting call (fixed, so one compilation serves all)
_FORMAT_VERSION = 1  # bump when the cached arrays change meaning


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
        the :class:`~bezmotion.data.corpus.MotionClips` it was built from).
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

    @classmethod
    def concatenate(cls, parts: Sequence[CurveDataset]) -> CurveDataset:
        """The windows of every part in order (the first part's layout and rate; each window's
        ``clip_index`` stays its own split's)."""
        return dataclasses.replace(parts[0], **{k: np.concatenate([getattr(p, k) for p in parts]) for k in cls._ARRAYS})

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


def skeleton_windows(
    clips: MotionClips,
    mapping: str | Mapping[str, str],
    *,
    window: int = DEFAULT_WINDOW,
    offset: int = DEFAULT_OFFSET,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Aligned positions of *every* joint of the skeleton in every window, without fitting
    (the data of the full-skeleton ablation, :mod:`bezmotion.evaluation.ablations`).

    The windows and their alignment are :func:`characteristic_windows`' (the same
    ``clip_index``/``start_frame`` for the same ``window`` and ``offset``, translated so
    the characteristic hips start at the origin in XZ), so its six joints are this one's
    joints ``characteristic_indices(clips.joint_names, mapping)``.

    Returns:
      ``(positions (windows, window, joints, 3) cm, clip_index (windows,), start_frame
      (windows,))``, positions float32, joints in the skeleton's order.
    """
    hips = characteristic_indices(clips.joint_names, mapping)[HIPS]
    clip_index, start_frame = clips.window_starts(window, offset)
    pos = [np.zeros((0, window, len(clips.parents), 3), np.float32)]
    for chunk in _chunks(clips, clip_index, start_frame, window):
        pos.append(np.asarray(_aligned_skeleton(*chunk, parents=clips.parents, hips=hips)))
    return np.concatenate(pos)[: len(clip_index)], clip_index, start_frame


@functools.partial(jax.jit, static_argnames=("parents", "hips"))
def _aligned_skeleton(quat_local, pos_local, *, parents, hips):
    _, pos = forward_kinematics(parents, quat_local, pos_local)
    translation = pos[..., 0, hips, :] * jnp.asarray([1.0, 0.0, 1.0], pos.dtype)  # align_to_start's, on the hips' joint
    return pos - translation[..., None, None, :]


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
    """Fit curves to every window of ``clips`` (no cache; :func:`curve_dataset` caches a corpus split).

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


def curve_dataset(
    corpus: Corpus,
    split: str = "train",
    *,
    mapping: str | Mapping[str, str] | None = None,
    window: int = DEFAULT_WINDOW,
    stride: int = DEFAULT_STRIDE,
    offset: int = DEFAULT_OFFSET,
    pin_positions: bool = True,
    use_cache: bool = True,
    progress: bool = True,
) -> CurveDataset:
    """One split of a corpus's curve dataset, fitted once per configuration and cached.

    Args:
      corpus: any corpus with rotations (:func:`~bezmotion.data.sources.load_corpus`).
      split: ``"train"`` or ``"validation"`` (the corpus's official split).
      mapping: the characteristic-joint map (default ``corpus.characteristic_map``).
      window, stride, offset, pin_positions, progress: as in :func:`build_curve_dataset`.
      use_cache: ``False`` always fits and never touches the cache.
    Returns:
      The dataset; its ``clip_index`` indexes ``motion_clips(corpus, split)`` (the split's
      clips in corpus order). Clips shorter than ``window`` contribute no windows.
    Raises:
      ValueError: unknown split, a positions-only corpus, or no characteristic-joint map.
    """
    check_split(split)
    if corpus.skeleton is None:
        raise ValueError(f"{corpus.name}: a positions-only corpus has no rotations to fit curves to")
    mapping = corpus.characteristic_map if mapping is None else mapping
    if mapping is None:
        raise ValueError(f"{corpus.name}: the corpus names no characteristic joints; pass mapping={{role: joint}}")
    params = dict(split=split, window=window, stride=stride, offset=offset, pin=pin_positions, v=_FORMAT_VERSION)
    if mapping != corpus.name:  # the bundled corpora's own preset is implied by their name (keys unchanged)
        params["mapping"] = mapping if isinstance(mapping, str) else dict(sorted(mapping.items()))

    def build() -> dict[str, np.ndarray]:
        return build_curve_dataset(
            motion_clips(corpus, split), mapping, window=window, stride=stride, offset=offset,
            pin_positions=pin_positions, progress=progress, description=f"fitting {corpus.name} {split} curves",
        ).to_arrays()  # fmt: skip

    name = re.sub(r"[^A-Za-z0-9.-]+", "-", corpus.name) + "-curves"
    key = corpus.source_key(corpus=name, **params) if use_cache else ""
    return CurveDataset.from_arrays(cached_arrays(name, key, build, use_cache=use_cache))


__all__ = [
    "CHARACTERISTIC_JOINTS",
    "CurveDataset",
    "build_curve_dataset",
    "characteristic_windows",
    "curve_dataset",
    "skeleton_windows",
]
