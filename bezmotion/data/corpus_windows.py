"""Training windows of local rotations cut from any corpus (the Δ-interpolator's data).

:func:`motion_windows` runs the LaFAN1 extractor's steps (:mod:`bezmotion.data.windows`:
strict sliding windows, XZ-centering, facing normalised at one frame) on the clips of any
:class:`~bezmotion.data.corpus.Corpus` with rotations. On LaFAN1 it reproduces
:func:`~bezmotion.data.lafan1.lafan1_windows` (rotations, root positions and offsets
below the root; see :class:`MotionWindows`), without the foot contacts, which the
Δ-interpolator does not train on and which need the toes that a characteristic map
does not name.

**The windows' root is the hips.** The Δ-interpolator and the facing normalisation read
the trajectory and heading of joint 0. LaFAN1's joint 0 is the animated ``Hips``;
Bandai-Namco's is a static ``joint_Root`` at the origin with the motion on the ``Hips``
below it. So joint 0 takes the hips' world rotation and position (the hips of the
corpus's characteristic map; joint 0 itself when the corpus names none), and the joints
from joint 0's child down to the hips get identity rotations and zero offsets: world
rotations and positions of every joint are unchanged, the hierarchy (and so the model's
``DeltaConfig.parents``) is the corpus's, and LaFAN1 is untouched. This is the hips
re-rooting of :func:`bezmotion.ik.protocol.pose_from_motion`, with the hips' transform on
joint 0 rather than on the hips.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data.characteristic import HIPS, characteristic_indices
from bezmotion.data.corpus import Corpus, motion_clips
from bezmotion.data.windows import center_xz, face_forward_at_frame, sliding_window_starts
from bezmotion.geometry.skeleton import Skeleton, forward_kinematics

FACING_FRAME = 9
"""Default frame whose facing is normalised: the last of LaFAN1's 10 past frames."""

LAFAN1_FORWARD: tuple[float, float, float] = (0.0, 1.0, 0.0)
"""The hips' local forward axis on LaFAN1 (Bandai-Namco's is ``(0, 0, 1)``)."""


@dataclasses.dataclass(frozen=True)
class MotionWindows:
    """Preprocessed windows of one split (NumPy float64); a ``bezmotion.delta.train.RotationWindows``.

    Attributes:
      parents, joint_names: the corpus's hierarchy (joint 0 holds the hips' motion).
      quat_local: ``(windows, frames, joints, 4)`` local rotations (w, x, y, z), joint 0's
        facing-normalised (its rotation is the hips' world rotation).
      root_pos: ``(windows, frames, 3)`` the hips' world position, XZ-centred on the
        window mean and rotated with the facing (cm).
      offsets: ``(windows, joints, 3)`` each window's local translations at its first
        frame (cm), zero for joint 0 (``root_pos`` places it) and for the joints merged
        into it. LaFAN1's windows keep the file's root OFFSET line in row 0 instead, which
        forward kinematics never reads.
      clip_index, start_frame: ``(windows,)`` the corpus clip and frame each window starts at.
    """

    parents: tuple[int, ...]
    joint_names: tuple[str, ...]
    quat_local: np.ndarray
    root_pos: np.ndarray
    offsets: np.ndarray
    clip_index: np.ndarray
    start_frame: np.ndarray

    @property
    def num_windows(self) -> int:
        return self.quat_local.shape[0]

    def skeleton(self, window: int = 0) -> Skeleton:
        """The skeleton of one window (its offsets), e.g. for ``delta_inbetweener``."""
        return Skeleton(self.parents, self.joint_names, self.offsets[window])


def motion_windows(
    corpus: Corpus,
    split: str,
    *,
    window: int,
    offset: int,
    facing_frame: int = FACING_FRAME,
    forward_axis: tuple[float, float, float] = LAFAN1_FORWARD,
) -> MotionWindows:
    """Windows of ``window`` frames every ``offset`` frames over the clips of one split.

    Windows start at 0, ``offset``, … while ``start + window < clip frames`` (the LaFAN1
    extractor's strict rule, :func:`~bezmotion.data.windows.sliding_window_starts`). Each
    is re-rooted at the hips (module docstring), XZ-centred and rotated about +Y so that
    the hips' ``forward_axis``, projected on the ground, points along +X at ``facing_frame``.

    Args:
      corpus: any corpus with rotations.
      split: ``"train"`` or ``"validation"``.
      window, offset: window length and stride (frames); LaFAN1's training protocol is 50, 20.
      facing_frame: the frame whose facing is normalised (< ``window``).
      forward_axis: the hips' local forward axis (:data:`LAFAN1_FORWARD`; Bandai-Namco: +Z).
    Raises:
      ValueError: a positions-only corpus, a bad split, window, offset or facing frame, a
        joint hanging off the joints merged into the root, or no clip longer than ``window``.
    """
    if corpus.skeleton is None:
        raise ValueError(f"{corpus.name}: a positions-only corpus has no rotations to cut rotation windows from")
    for name, value, low in (("window", window, 2), ("offset", offset, 1), ("facing_frame", facing_frame, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"{name} must be an integer ≥ {low}, got {value!r}")
    if facing_frame >= window:
        raise ValueError(f"facing_frame {facing_frame} must lie inside the {window}-frame window")
    clips = motion_clips(corpus, split)
    lengths = np.diff(clips.starts)
    starts = [sliding_window_starts(int(n), window, offset) for n in lengths]
    start_frame = np.concatenate(starts) if starts else np.zeros(0, np.int64)
    if start_frame.size == 0:
        longest = f"its longest has {int(lengths.max())} frames" if lengths.size else "it has none"
        raise ValueError(
            f"{corpus.name}: no {window}-frame windows in the {split!r} split: a window needs a clip of more than "
            f"{window} frames, and {longest} ({lengths.size} clips)"
        )
    local_clip = np.repeat(np.arange(len(lengths)), [len(s) for s in starts])
    frame_idx = clips.starts[local_clip][:, None] + start_frame[:, None] + np.arange(window)
    chain = _chain_to_hips(corpus, clips.parents, clips.joint_names)
    with jax.enable_x64(True):
        # Only joints 0..hips place the root: gather no more translations than those.
        pos = jnp.asarray(clips.pos_local[:, : chain[-1] + 1][frame_idx])
        quat = jnp.asarray(clips.quat_local[frame_idx])
        quat, root_pos = _rerooted(clips.parents, chain, quat, pos)
        quat, root_pos = _normalise(quat, root_pos, facing_frame, tuple(float(a) for a in forward_axis))
        quat, root_pos = np.asarray(quat), np.asarray(root_pos)
    offsets = clips.pos_local[frame_idx[:, 0]].copy()
    offsets[:, list(chain)] = 0.0
    return MotionWindows(
        clips.parents, clips.joint_names, quat, root_pos, offsets,
        np.asarray(corpus.split(split), np.int64)[local_clip], start_frame,
    )  # fmt: skip


def _chain_to_hips(corpus: Corpus, parents: tuple[int, ...], names: tuple[str, ...]) -> tuple[int, ...]:
    """Joints from 0 down to the hips (``(0,)`` when the hips are joint 0 or unnamed).

    Raises ``ValueError`` when another joint hangs off one above the hips: once they are
    merged into joint 0 it would follow the hips instead of its own parent.
    """
    if corpus.characteristic_map is None:
        return (0,)
    j, chain = characteristic_indices(names, corpus.characteristic_map)[HIPS], []
    while j >= 0:
        chain.append(j)
        j = parents[j]
    chain = tuple(reversed(chain))
    above = set(chain[:-1])
    stray = [names[j] for j, p in enumerate(parents) if p in above and j not in chain]
    if stray:
        raise ValueError(
            f"{corpus.name}: joints {stray} hang off {[names[j] for j in chain[:-1]]}, above the hips "
            f"{names[chain[-1]]!r}; windows rooted at the hips cannot place them"
        )
    return chain


@functools.partial(jax.jit, static_argnums=(0, 1))
def _rerooted(parents: tuple[int, ...], chain: tuple[int, ...], quat_local, pos_local):
    """``(quat_local, root_pos)`` with the hips' world transform on joint 0 and identity rotations
    on the rest of ``chain``; ``pos_local`` holds the translations of joints 0..hips."""
    if len(chain) == 1:
        return quat_local, pos_local[..., 0, :]
    hips = chain[-1]
    # Parents precede children, so joints 0..hips hold the hips' whole ancestry.
    quat_g, pos_g = forward_kinematics(parents[: hips + 1], quat_local[..., : hips + 1, :], pos_local)
    merged = jnp.asarray(chain[1:])
    quat_local = quat_local.at[..., merged, :].set(jnp.asarray([1.0, 0.0, 0.0, 0.0], quat_local.dtype))
    return quat_local.at[..., 0, :].set(quat_g[..., hips, :]), pos_g[..., hips, :]


@functools.partial(jax.jit, static_argnums=(2, 3))
def _normalise(quat_local, root_pos, facing_frame: int, forward_axis: tuple[float, float, float]):
    """LaFAN1's window steps after the contacts: XZ-centering, then facing at ``facing_frame``."""
    return face_forward_at_frame(quat_local, center_xz(root_pos), facing_frame, forward_axis)


__all__ = ["FACING_FRAME", "LAFAN1_FORWARD", "MotionWindows", "motion_windows"]
