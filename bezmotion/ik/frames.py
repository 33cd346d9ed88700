"""Single-frame poses of any corpus, for training and evaluating frame IK.

A corpus becomes one :class:`~bezmotion.ik.protocol.Character` (:func:`corpus_character`)
and a batch of :class:`~bezmotion.ik.protocol.Pose` frames (:func:`corpus_frames`: float32,
every ``frame_step``-th frame of each clip of one split), via
:func:`~bezmotion.ik.protocol.pose_from_motion`.

**One skeleton per corpus.** A frame IK is skeleton-specific, so each corpus is posed on
its reference skeleton (:attr:`Corpus.skeleton <bezmotion.data.corpus.Corpus>`). A pose
keeps each frame's own rotations and hips position, so it depends on the reference only
through the rest offsets below the hips: LaFAN1 files differ from its reference (the first
training file) by ≤ 3.3e-5 cm; Bandai-Namco clips differ only in the ``Hips`` OFFSET (a
session origin), which the animated ``Hips`` translation overrides, and the static
``joint_Root`` above it is held at identity, as in every :class:`Pose`.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data.corpus import Corpus, check_split
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.protocol import Character, Pose, pose_from_motion

_CHUNK = 8192  # frames per conversion call (one compiled shape)


def _check(split: str, frame_step: int) -> None:
    check_split(split)
    if isinstance(frame_step, bool) or not isinstance(frame_step, int) or frame_step < 1:
        raise ValueError(f"frame_step must be a positive integer, got {frame_step!r}")


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


def corpus_character(corpus: Corpus) -> Character:
    """The corpus's character: its reference skeleton (float32), characteristic joints and End Sites.

    Raises:
      ValueError: a positions-only corpus, or one that names no characteristic joints.
    """
    if corpus.skeleton is None:
        raise ValueError(f"{corpus.name}: a positions-only corpus has no skeleton to pose")
    if corpus.characteristic_map is None:
        raise ValueError(f"{corpus.name}: the corpus names no characteristic joints (load it with characteristic=...)")
    character = Character.from_skeleton(_float32(corpus.skeleton), corpus.characteristic_map, corpus.name)
    return dataclasses.replace(character, end_sites=tuple(corpus.end_sites))


def _split_frames(corpus: Corpus, split: str, frame_step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(quat_local, pos_local, starts)`` of every ``frame_step``-th frame of each clip of
    the split, clip by clip (never a copy of the whole split)."""
    quat, pos, counts = [], [], []
    for clip in corpus.split(split):
        motion = corpus.motion([int(clip)])
        quat.append(motion.quat_local[::frame_step])
        pos.append(motion.pos_local[::frame_step])
        counts.append(len(quat[-1]))
    joints = len(corpus.skeleton.parents)
    quat_local = np.concatenate(quat) if quat else np.zeros((0, joints, 4))
    pos_local = np.concatenate(pos) if pos else np.zeros((0, joints, 3))
    return quat_local, pos_local, np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def corpus_frames(corpus: Corpus, split: str = "train", *, frame_step: int = 1) -> tuple[Character, Pose]:
    """One split of a corpus as poses of :func:`corpus_character`.

    Args:
      corpus: any corpus with rotations (:func:`~bezmotion.data.sources.load_corpus`).
      split: ``"train"`` or ``"validation"`` (the corpus's official split).
      frame_step: keep every ``frame_step``-th frame of each clip.
    Returns:
      ``(character, poses (frames, …))``, clips in corpus order.
    """
    _check(split, frame_step)
    character = corpus_character(corpus)
    quat_local, pos_local, _ = _split_frames(corpus, split, frame_step)
    return character, _convert(character, quat_local, pos_local)


def corpus_frame_starts(corpus: Corpus, split: str = "train", *, frame_step: int = 1) -> np.ndarray:
    """``(clips + 1,)`` where each clip's frames start in :func:`corpus_frames`'s output
    (same ``split`` and ``frame_step``), so windows never straddle two clips."""
    _check(split, frame_step)
    return _split_frames(corpus, split, frame_step)[2]


__all__ = ["corpus_character", "corpus_frame_starts", "corpus_frames"]
