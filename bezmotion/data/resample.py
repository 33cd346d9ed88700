"""A BVH motion at another frame rate, on sample times through one of its frames.

The BMM and the learned IK were trained on 30 fps clips (LaFAN1 and Bandai-Namco), and
every per-frame figure of the pipeline (the 30-frame window, planted feet, the foot lock's
speeds, key velocities in cm/frame) counts 30 fps frames. A clip at 60 or 120 fps is
therefore moved onto 30 fps first; in-betweened at its own rate, its keys 30 frames apart
would be a quarter of a second apart at 120 fps and the in-between four times too fast.

Samples fall on ``t_anchor + k / fps`` (the anchor frame's time plus whole steps), so the
anchor frame, and every frame a whole number of steps from it, is kept exactly. Between two
frames of the clip, local rotations are slerped the short way
(:func:`~bezmotion.geometry.rotations.slerp`) and local translations interpolated linearly.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from bezmotion.data.bvh import BvhMotion
from bezmotion.geometry.rotations import slerp

# Frames per second of the corpora every model here was trained on (LaFAN1 and Bandai-Namco both):
# clips at another rate are resampled to it before they meet a model.
TRAINED_FPS = 30.0

# A sample within this many source frames of a frame takes that frame as it is (rounding of
# the sample times must not blend a key pose with its neighbour).
_ON_FRAME = 1e-6


def resample_motion(motion: BvhMotion, fps: float, anchor: int = 0) -> tuple[BvhMotion, int]:
    """``motion`` at ``fps`` frames per second, sampled through frame ``anchor``.

    Args:
      motion: any BVH motion; its rate is :attr:`BvhMotion.nominal_fps`.
      fps: the new rate (frames per second, positive).
      anchor: a frame of ``motion`` that the samples pass through.
    Returns:
      ``(resampled, index)``: every sample time ``t_anchor + k / fps`` within the clip's
      first and last frame, and the index of the anchor's sample in it. At ``motion``'s own
      rate, ``(motion, anchor)`` unchanged.
    Raises:
      ValueError: ``fps`` not a positive number, or ``anchor`` not a frame of ``motion``
        (the message gives the value).
    """
    if isinstance(fps, bool) or not (isinstance(fps, (int, float)) and np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}")
    frames = motion.num_frames
    if isinstance(anchor, bool) or not isinstance(anchor, (int, np.integer)) or not 0 <= anchor < frames:
        raise ValueError(f"anchor must be a frame 0…{frames - 1} of the motion, got {anchor!r}")
    step = motion.nominal_fps / fps  # source frames per new frame
    if abs(step - 1.0) < _ON_FRAME:
        return motion, int(anchor)
    before = int(np.floor(anchor / step + _ON_FRAME))  # new frames before the anchor's
    after = int(np.floor((frames - 1 - anchor) / step + _ON_FRAME))  # and after it
    source = anchor + step * np.arange(-before, after + 1)  # (new frames,) in source frames
    lower = np.clip(np.floor(source + _ON_FRAME).astype(int), 0, frames - 1)
    weight = np.where(source - lower < _ON_FRAME, 0.0, source - lower)
    upper = np.minimum(lower + 1, frames - 1)
    q0, q1 = motion.quat_local[lower], motion.quat_local[upper]
    blended = np.asarray(slerp(jnp.asarray(q0), jnp.asarray(q1), jnp.asarray(weight[:, None])), np.float64)
    on_frame = (weight == 0.0)[:, None, None]
    quat = np.where(on_frame, q0, blended)
    w = weight[:, None, None]
    pos = np.where(on_frame, motion.pos_local[lower], (1.0 - w) * motion.pos_local[lower] + w * motion.pos_local[upper])
    resampled = dataclasses.replace(motion, quat_local=quat, pos_local=pos, frame_time=1.0 / fps, frame_time_decimals=None)
    return resampled, before


__all__ = ["TRAINED_FPS", "resample_motion"]
