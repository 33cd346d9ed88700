"""In-betweening metrics.

- The LaFAN1 benchmark's L2Q, L2P and NPSS. Definitions follow the official Ubisoft La
  Forge evaluator (github.com/ubisoft/ubisoft-laforge-animation-dataset,
  ``lafan1/benchmarks.py``). Call them on float64 arrays (inside
  ``jax.enable_x64(True)``) to reproduce the published numbers; in float32 they agree to
  about 1e-6.
- BMM's curve metrics: handles error, foot-skating ratio, contact accuracy, mean
  position error (BMM §5.1 and appendix B).
- Pops: per-frame joint rotation change, and its largest value next to the keys.
- Joins: the velocity jump of each joint at the keys a chain of windows shares, and its
  summary (mean, 95th percentile, max) beside the mocap's own frame-to-frame change.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from bezmotion.handles import Handles
from bezmotion.geometry.rotations import quat_angle, quat_fix_continuity


def l2q(
    quat_global_pred: Float[Array, "batch frames joints 4"], quat_global_true: Float[Array, "batch frames joints 4"]
) -> Float[Array, ""]:
    """Mean over (window, frame) of the L2 norm of the global-quaternion difference, all
    joints' components together. No hemisphere alignment: signs matter, as in the benchmark."""
    diff = quat_global_pred - quat_global_true
    return jnp.mean(jnp.sqrt(jnp.sum(diff * diff, axis=(-2, -1))))


def l2p(
    pos_global_pred: Float[Array, "batch frames joints 3"],
    pos_global_true: Float[Array, "batch frames joints 3"],
    x_std: Float[Array, "features"],
) -> Float[Array, ""]:
    """Mean over (window, frame) of ‖(p̂ − p) / x_std‖₂ over the flattened global positions.

    ``x_std`` is the training std of the ``joints × 3`` coordinates (the mean cancels).
    """
    batch, frames = pos_global_pred.shape[:2]
    diff = (pos_global_pred - pos_global_true).reshape(batch, frames, -1) / x_std
    return jnp.mean(jnp.sqrt(jnp.sum(diff * diff, axis=-1)))


def npss(pred: Float[Array, "batch frames features"], true: Float[Array, "batch frames features"]) -> Float[Array, ""]:
    """Normalized Power Spectrum Similarity (Gopalakrishnan et al. 2019), LaFAN1 variant.

    Power is the squared *real part* of the FFT over time; per (window, feature) it is
    normalised by its total, accumulated over frequency, and the EMD is the L1 distance
    of the two cumulative spectra. The result averages the EMD weighted by the ground
    truth's total power.
    """
    pred_power = jnp.real(jnp.fft.fft(pred, axis=1)) ** 2
    true_power = jnp.real(jnp.fft.fft(true, axis=1)) ** 2
    pred_total = jnp.sum(pred_power, axis=1, keepdims=True)
    true_total = jnp.sum(true_power, axis=1, keepdims=True)
    pred_cdf = jnp.cumsum(pred_power / pred_total, axis=1)
    true_cdf = jnp.cumsum(true_power / true_total, axis=1)
    emd = jnp.sum(jnp.abs(pred_cdf - true_cdf), axis=1)  # (batch, features)
    weights = true_total[:, 0, :]
    return jnp.sum(emd * weights) / jnp.sum(weights)


def align_to_context(
    quat_global: Float[Array, "batch frames joints 4"], quat_global_last_context: Float[Array, "batch joints 4"]
) -> Float[Array, "batch frames joints 4"]:
    """Hemisphere-align a transition to the last past frame (the Δ-interpolator code's variant).

    Prepends the last context frame, makes the sequence sign-continuous over time, and
    drops the prepended frame again.
    """
    seq = jnp.concatenate([quat_global_last_context[:, None], quat_global], axis=1)
    return quat_fix_continuity(seq, axis=1)[:, 1:]


# ------------------------------------------------------------------ Bézier-curve metrics (BMM)


def handles_error(positions: Float[Array, "*batch steps joints 3"], handles: Handles) -> Float[Array, ""]:
    """Mean distance (cm) between each valid handle and ``positions`` at its step (BMM §5.1).

    ``handles.frame`` indexes ``positions``' steps: the frames of dense positions, or, for
    curves' control points ``ctrl_pos``, the control index (``frame // stride``: a curve
    passes through its control point at that control's frame). Pass only intermediate
    handles: the paper excludes the first and last frames.
    """
    k, j = positions.shape[-3:-1]
    flat = positions.reshape(*positions.shape[:-3], k * j, 3)
    slot = jnp.clip(handles.frame, 0, k - 1) * j + jnp.clip(handles.joint, 0, j - 1)
    picked = jnp.take_along_axis(flat, slot[..., None], axis=-2)
    error = jnp.linalg.norm(picked - handles.position, axis=-1)
    valid = handles.valid.astype(error.dtype)
    # where, not a product: padding slots may hold anything, NaN included.
    return jnp.sum(jnp.where(handles.valid, error, 0.0)) / jnp.maximum(jnp.sum(valid), 1.0)


def foot_skating_ratio(
    feet_pos: Float[Array, "*batch frames 2 3"],
    fps: float,
    *,
    floor_height: float = 0.0,
    height_threshold: float = 5.0,
    speed_threshold: float = 7.5,
    heights_from: Float[Array, "*batch frames 2 3"] | None = None,
) -> Float[Array, ""]:
    """Fraction of frames on which the feet skate (BMM appendix B, after Zhang et al. 2021).

    A frame (each pair of consecutive frames) skates when *both* feet are within
    ``height_threshold`` cm of the floor and *both* move horizontally faster than
    ``speed_threshold`` cm/s. ``feet_pos`` are the left and right foot joints (cm, +Y up);
    heights are measured from ``floor_height`` — for ankle joints, the ankle's height with
    the foot flat on the ground, so that the test is on the heel as the paper states.

    ``heights_from`` (the same shape; default ``feet_pos``): the feet whose heights decide
    which frames are on the floor, the speeds still ``feet_pos``'. Given the curves two IKs
    were both given, it judges them on the same frames: by the paper's test an IK whose
    sliding feet hover more than ``height_threshold`` above the floor where the curves put
    them on it skates less than one that keeps them there.
    """
    if heights_from is not None and heights_from.shape != feet_pos.shape:
        raise ValueError(f"heights_from has shape {heights_from.shape}, feet_pos {feet_pos.shape}: they must match")
    height = (feet_pos if heights_from is None else heights_from)[..., 1:, :, 1] - floor_height
    step = feet_pos[..., 1:, :, :] - feet_pos[..., :-1, :, :]
    speed = jnp.sqrt(step[..., 0] ** 2 + step[..., 2] ** 2) * fps
    skating = jnp.all((height < height_threshold) & (speed > speed_threshold), axis=-1)
    return jnp.mean(skating.astype(feet_pos.dtype))


def contact_accuracy(
    contact_prob: Float[Array, "*batch controls 2"], contact_true: Bool[Array, "*batch controls 2"]
) -> Float[Array, ""]:
    """Fraction of foot-contact labels predicted right (probability thresholded at 0.5)."""
    return jnp.mean(((contact_prob > 0.5) == contact_true).astype(contact_prob.dtype))


def mean_position_error(
    pred: Float[Array, "*batch frames joints 3"], true: Float[Array, "*batch frames joints 3"]
) -> Float[Array, ""]:
    """Mean per-joint position error (cm) over all batch entries, frames and joints."""
    return jnp.mean(jnp.linalg.norm(pred - true, axis=-1))


def rotation_change_deg(quat_local: Float[Array, "*batch frames joints 4"]) -> Float[Array, "*batch frames-1 joints"]:
    """Angle (degrees) each joint's local rotation turns from each frame to the next (either quaternion sign)."""
    return jnp.degrees(quat_angle(quat_local[..., :-1, :, :], quat_local[..., 1:, :, :]))


def key_pop_deg(quat_local: Float[Array, "*batch frames joints 4"]) -> Float[Array, ""]:
    """Largest per-frame change (degrees) of any joint's local rotation next to the keys:
    frames 0 → 1 and the last but one → last (29 → 30 in a 31-frame window), over every
    joint and batch entry. Compare with the mocap's own (the same function of the mocap)."""
    change = rotation_change_deg(quat_local)
    return jnp.max(jnp.stack([change[..., 0, :], change[..., -1, :]]))


def boundary_velocity_jump(
    positions: Float[Array, "*batch frames joints 3"], boundary_frames: Int[ArrayLike, "boundaries"] | Sequence[int]
) -> Float[Array, "*batch boundaries joints"]:
    """How much each joint's velocity changes at each boundary frame (cm/frame):
    ``‖v_after − v_before‖`` with ``v_before = p[b] − p[b − 1]`` and ``v_after = p[b + 1] − p[b]``.

    At the keys two chained windows share it says whether the motion is C¹ across the join
    (0 for a curve with one tangent there, up to the curve's own second difference). The
    mocap's analogue is the same quantity at its ordinary frames,
    ``boundary_velocity_jump(mocap, np.arange(1, frames - 1))``: its own frame-to-frame
    velocity change, the scale a join's jump compares against. Multiply by the frame rate
    for cm/s per frame.

    Args:
      positions: ``(*batch, frames, joints, 3)`` joint positions (cm), one per frame.
      boundary_frames: ``(boundaries,)`` integer frames ``1 … frames − 2`` (each needs a
        neighbour on either side).
    Returns:
      ``(*batch, boundaries, joints)`` jumps in cm/frame.

    Raises:
      ValueError: a boundary frame without a neighbour on both sides (checked when the
        frames are concrete).
    """
    frames = positions.shape[-3]
    if not isinstance(boundary_frames, jax.core.Tracer):
        concrete = np.asarray(boundary_frames)
        if concrete.ndim != 1 or not np.issubdtype(concrete.dtype, np.integer) or ((concrete < 1) | (concrete > frames - 2)).any():
            raise ValueError(f"boundary frames must be integers in 1 … {frames - 2} ({frames} frames), got {concrete.tolist()}")
    b = jnp.asarray(boundary_frames)
    before = positions[..., b, :, :] - positions[..., b - 1, :, :]
    after = positions[..., b + 1, :, :] - positions[..., b, :, :]
    return jnp.linalg.norm(after - before, axis=-1)


class ChainJumps(NamedTuple):
    """:func:`boundary_velocity_jump` over a chain's frames (cm/frame), split by where.

    Attributes:
      at_shared_keys: ``(*batch, windows − 1, joints)`` at the keys two windows share.
      other_frames: ``(*batch, frames − 1 − windows, joints)`` at every other frame with a
        neighbour on either side.
      all_frames: ``(*batch, frames − 2, joints)`` at every frame with a neighbour on either
        side, the shared keys included (the mocap's own frame-to-frame change).
    """

    at_shared_keys: Float[Array, "*batch keys joints"]
    other_frames: Float[Array, "*batch others joints"]
    all_frames: Float[Array, "*batch inner joints"]


def chain_velocity_jumps(positions: Float[Array, "*batch frames joints 3"], windows: int) -> ChainJumps:
    """The velocity jump of every joint at every inner frame of a chain of ``windows``
    equal windows, split into the shared keys and the rest.

    Args:
      positions: ``(*batch, frames, joints, 3)`` joint positions (cm), one per frame, with
        ``frames = windows·(window_frames − 1) + 1`` (the windows joined, each shared key
        once: key ``k`` at frame ``k·(window_frames − 1)``).
      windows: windows in the chain, ``≥ 1`` (one window: no shared key).
    Returns:
      :class:`ChainJumps`, cm/frame.
    Raises:
      ValueError: ``windows < 1`` or ``frames`` not a chain of ``windows`` windows of at
        least 2 frames each.
    """
    frames = positions.shape[-3]
    if windows < 1 or frames < 3 or (frames - 1) % windows:
        raise ValueError(f"{frames} frames are not a chain of {windows} windows ((window frames − 1)·windows + 1)")
    inner = np.arange(1, frames - 1)
    shared = np.arange(1, windows) * ((frames - 1) // windows)
    jumps = boundary_velocity_jump(positions, inner)
    return ChainJumps(jumps[..., shared - 1, :], jumps[..., np.setdiff1d(inner, shared) - 1, :], jumps)


def distribution_summary(x: ArrayLike) -> dict[str, float | int]:
    """Mean, 95th percentile and max of all of ``x`` (float64; its units), and how many values.

    Raises:
      ValueError: ``x`` is empty (nothing to summarise).
    """
    x = np.asarray(x, np.float64).ravel()
    if x.size == 0:
        raise ValueError("no values to summarise (an empty array)")
    return {"mean": float(x.mean()), "p95": float(np.percentile(x, 95)), "max": float(x.max()), "count": int(x.size)}
