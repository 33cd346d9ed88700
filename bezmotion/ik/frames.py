"""Single-frame poses of LaFAN1 and Bandai-Namco, for training and evaluating frame IK.

Each corpus becomes one :class:`~bezmotion.ik.protocol.Character` and a batch of
:class:`~bezmotion.ik.protocol.Pose` frames (float32, every ``frame_step``-th frame of
each clip), via :func:`~bezmotion.ik.protocol.pose_from_motion`.

**One skeleton per corpus.** A frame IK is skeleton-specific, so each corpus is posed on
one skeleton:

- LaFAN1: the offsets of the first training file (``corpus.files_of(TRAIN_SUBJECTS)[0]``).
  Files differ only in the root's OFFSET line (replaced by the animated root) and by
  ≤ 3.3e-5 cm elsewhere, so every frame keeps its global joint positions to that accuracy.
- Bandai-Namco: the offsets of the first clip. Clips differ only in the ``Hips`` OFFSET
  (a session origin), which the animated ``Hips`` translation overrides; the static
  ``joint_Root`` above it is held at identity, as in every :class:`Pose`.

Splits: LaFAN1 subjects 1–4 train, subject 5 validates (BMM §5.1); Bandai-Namco follows
:func:`~bezmotion.data.bandai_namco.bandai_namco_split` (every 10th take validates).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data import bandai_namco as _bandai_namco
from bezmotion.data import lafan1 as _lafan1
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.protocol import Character, Pose, pose_from_motion

CORPORA: tuple[str, ...] = ("lafan1", "bandai_namco")
SPLITS: tuple[str, ...] = ("train", "validation")
_CHUNK = 8192  # frames per conversion call (one compiled shape)


def _check(split: str, frame_step: int) -> None:
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if isinstance(frame_step, bool) or not isinstance(frame_step, int) or frame_step < 1:
        raise ValueError(f"frame_step must be a positive integer, got {frame_step!r}")


def _clip_frames(starts: np.ndarray, clips: list[int], frame_step: int) -> np.ndarray:
    """Global frame indices of every ``frame_step``-th frame of the given clips."""
    parts = [np.arange(int(starts[c]), int(starts[c + 1]), frame_step) for c in clips]
    return np.concatenate(parts) if parts else np.zeros(0, np.int64)


@jax.jit
def _to_pose(character: Character, quat_local, pos_local) -> Pose:
    return pose_from_motion(character, quat_local, pos_local)


def _convert(character: Character, quat_local: np.ndarray, pos_local: np.ndarray) -> Pose:
    """:func:`pose_from_motion` over many frames, in fixed-size chunks (float32)."""
    n = len(quat_local)
    roots, quats = [], []
    for lo in range(0, n, _CHUNK):
        q = quat_local[lo : lo + _CHUNK].astype(np.float32)
        p = pos_local[lo : lo + _CHUNK].astype(np.float32)
        pad = _CHUNK - len(q)
        if pad:
            q = np.concatenate([q, np.repeat(q[:1], pad, axis=0)])
            p = np.concatenate([p, np.repeat(p[:1], pad, axis=0)])
        pose = _to_pose(character, jnp.asarray(q), jnp.asarray(p))
        roots.append(np.asarray(pose.root_pos)[: _CHUNK - pad])
        quats.append(np.asarray(pose.quat_local)[: _CHUNK - pad])
    if not roots:
        return Pose(jnp.zeros((0, 3)), jnp.zeros((0, character.num_joints, 4)))
    return Pose(jnp.asarray(np.concatenate(roots)), jnp.asarray(np.concatenate(quats)))


def _float32(skeleton: Skeleton) -> Skeleton:
    return Skeleton(skeleton.parents, skeleton.names, np.asarray(skeleton.offsets, np.float32))


def lafan1_character(corpus: _lafan1.Lafan1Corpus) -> Character:
    """The LaFAN1 character: the first training file's skeleton (see the module docstring)."""
    first = corpus.files_of(_lafan1.TRAIN_SUBJECTS)[0]
    skeleton = corpus.skeleton(first)
    return Character.from_skeleton(_float32(skeleton), "lafan1")


def bandai_namco_character(corpus: _bandai_namco.BandaiNamcoCorpus) -> Character:
    """The Bandai-Namco character: the first clip's skeleton, with its End Sites."""
    character = Character.from_skeleton(_float32(corpus.skeleton(0)), "bandai_namco")
    return dataclasses.replace(character, end_sites=tuple(corpus.end_sites))


def lafan1_frames(
    corpus: _lafan1.Lafan1Corpus, split: str = "train", *, frame_step: int = 1
) -> tuple[Character, Pose]:
    """LaFAN1 frames as poses of :func:`lafan1_character`: subjects 1–4 (``"train"``) or 5.

    Args:
      corpus: from :func:`~bezmotion.data.lafan1.load_lafan1`.
      split: ``"train"`` or ``"validation"``.
      frame_step: keep every ``frame_step``-th frame of each file.
    Returns:
      ``(character, poses (frames, …))``.
    """
    _check(split, frame_step)
    character = lafan1_character(corpus)
    subjects = _lafan1.TRAIN_SUBJECTS if split == "train" else _lafan1.TEST_SUBJECTS
    files = corpus.files_of(subjects)
    frames = _clip_frames(corpus.starts, files, frame_step)
    offsets = np.asarray(character.skeleton.offsets)
    pos_local = np.broadcast_to(offsets, (len(frames), *offsets.shape)).copy()
    pos_local[:, 0] = corpus.root_pos[frames]
    return character, _convert(character, corpus.quat_local[frames], pos_local)


def lafan1_clip_starts(corpus: _lafan1.Lafan1Corpus, split: str = "train", *, frame_step: int = 1) -> np.ndarray:
    """``(files + 1,)`` where each file's frames start in :func:`lafan1_frames`'s output
    (same ``split`` and ``frame_step``), so windows never straddle two files."""
    _check(split, frame_step)
    subjects = _lafan1.TRAIN_SUBJECTS if split == "train" else _lafan1.TEST_SUBJECTS
    counts = [len(range(int(corpus.starts[f]), int(corpus.starts[f + 1]), frame_step)) for f in corpus.files_of(subjects)]
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def bandai_namco_frames(
    corpus: _bandai_namco.BandaiNamcoCorpus, split: str = "train", *, frame_step: int = 1
) -> tuple[Character, Pose]:
    """Bandai-Namco frames as poses of :func:`bandai_namco_character` (split by take).

    Args:
      corpus: from :func:`~bezmotion.data.bandai_namco.load_bandai_namco`.
      split: ``"train"`` or ``"validation"`` (:func:`~bezmotion.data.bandai_namco.bandai_namco_split`).
      frame_step: keep every ``frame_step``-th frame of each clip.
    Returns:
      ``(character, poses (frames, …))``.
    """
    _check(split, frame_step)
    character = bandai_namco_character(corpus)
    train, validation = _bandai_namco.bandai_namco_split(corpus)
    clips = [int(c) for c in (train if split == "train" else validation)]
    frames = _clip_frames(corpus.starts, clips, frame_step)
    return character, _convert(character, corpus.quat_local[frames], corpus.pos_local[frames])


def default_source(corpus: str) -> Path:
    """Where the corpus is looked for by default: ``../shared/data`` beside the repository
    (Bandai-Namco: the extracted folder in the bezmotion cache when present)."""
    shared = Path(__file__).resolve().parents[3] / "shared" / "data"
    if corpus == "lafan1":
        return shared / "lafan1" / "lafan1-subset.zip"
    if corpus == "bandai_namco":
        from bezmotion.data.cache import cache_dir

        extracted = cache_dir() / "Bandai-Namco-Research-Motiondataset-2"
        return extracted if extracted.exists() else shared / "bandai-namco" / "bandai-namco-2.tar.xz"
    raise ValueError(f"corpus must be one of {CORPORA}, got {corpus!r}")


def load_frames(
    corpus: str, split: str = "train", *, source: str | os.PathLike | None = None, frame_step: int = 1, progress: bool = True
) -> tuple[Character, Pose]:
    """Load a corpus (cached parse) and return ``(character, poses)`` of one split.

    Args:
      corpus: ``"lafan1"`` or ``"bandai_namco"``.
      split: ``"train"`` or ``"validation"``.
      source: the corpus archive or folder (default :func:`default_source`).
      frame_step: keep every ``frame_step``-th frame of each clip.
    """
    if corpus not in CORPORA:
        raise ValueError(f"corpus must be one of {CORPORA}, got {corpus!r}")
    _check(split, frame_step)
    source = default_source(corpus) if source is None else source
    if corpus == "lafan1":
        return lafan1_frames(_lafan1.load_lafan1(source), split, frame_step=frame_step)
    return bandai_namco_frames(_bandai_namco.load_bandai_namco(source, progress=progress), split, frame_step=frame_step)


__all__ = [
    "CORPORA",
    "SPLITS",
    "bandai_namco_character",
    "bandai_namco_frames",
    "default_source",
    "lafan1_character",
    "lafan1_clip_starts",
    "lafan1_frames",
    "load_frames",
]
