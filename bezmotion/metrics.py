"""In-betweening metrics of the LaFAN1 benchmark: L2Q, L2P and NPSS.

Definitions follow the official Ubisoft La Forge evaluator (``../shared/REFERENCE.md``
§1). Call them on float64 arrays (inside ``jax.enable_x64(True)``) to reproduce the
published numbers; in float32 they agree to about 1e-6.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from bezmotion.geometry.rotations import quat_fix_continuity


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
