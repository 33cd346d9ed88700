"""Training losses of the Bézier Motion Model (BMM §4.2, Appendix C.2, Table 5).

All terms are mean squared errors ("L2 loss" in the paper, as in MDM) on one motion;
geometric terms are computed in metres so their weights mean what they meant for the
paper's (metre-scaled) data. The per-motion total is weighted by Min-SNR-γ
(:func:`min_snr_weight`) in the training step.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from bezmotion.bezier import BezierLayout, evaluate
from bezmotion.data.characteristic import FEET
from bezmotion.handles import Handles

CM_PER_M = 100.0


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """Relative weights of the loss terms (paper, Table 5)."""

    position: float = 1.0  # L_b: control-point positions
    tangent: float = 5.0  # L_t: control-point tangents
    orientation: float = 1.0  # L_o: control-point 6D orientations
    velocity: float = 10.0  # L_v: finite-difference velocities of the evaluated curves
    dense_position: float = 1.0  # L_p: evaluated curves against the mocap
    condition: float = 5.0  # L_c: control positions at the conditioned slots
    contact: float = 0.01  # L_gc: foot-contact labels at control points
    skate: float = 10.0  # L_skate: foot velocity where contact is predicted

    def total(self, terms: dict[str, Array]) -> Array:
        return sum(getattr(self, name) * value for name, value in terms.items())


def dense_velocity(positions: Float[Array, "*batch frames joints 3"]) -> Float[Array, "*batch frames_minus_1 joints 3"]:
    """``v^i = P^i − P^{i−1}`` (Eq. 12), per frame."""
    return positions[..., 1:, :, :] - positions[..., :-1, :, :]


def bmm_loss_terms(
    layout: BezierLayout,
    pred_pos: Float[Array, "controls joints 3"],
    pred_tangent: Float[Array, "controls joints 3"],
    pred_rot6d: Float[Array, "controls joints 6"],
    contact_logits: Float[Array, "controls 2"],
    target_pos: Float[Array, "controls joints 3"],
    target_tangent: Float[Array, "controls joints 3"],
    target_rot6d: Float[Array, "controls joints 6"],
    target_contacts: Bool[Array, "controls 2"],
    dense_target: Float[Array, "frames joints 3"],
    condition_mask: Bool[Array, "controls joints"],
    *,
    off_grid_conditions: Handles | None = None,
) -> dict[str, Float[Array, ""]]:
    """Unweighted loss terms for one motion (positions and tangents in cm in, metres inside).

    ``condition_mask`` marks the conditions on control points; ``off_grid_conditions``
    ``(frame, joint, position, valid)`` the handles between them, whose error is the
    evaluated curve's at their frame; both enter the condition term ``L_c``.

    Returns:
      ``{"position", "tangent", "orientation", "velocity", "dense_position", "condition",
      "contact", "skate"}`` scalars (:class:`LossWeights` names).
    """
    to_m = 1.0 / CM_PER_M
    # A padded layout's padding frames and control points are no part of the window: every
    # mean is over the window's own (all of them for a BezierLayout).
    frames_in, controls_in = jnp.asarray(layout.frame_valid), jnp.asarray(layout.control_valid)
    per_frame, per_control = frames_in[:, None, None], controls_in[:, None, None]
    per_velocity = (frames_in[1:] & frames_in[:-1])[:, None, None]
    pred_dense = jnp.moveaxis(evaluate(layout, jnp.moveaxis(pred_pos, 1, 0), jnp.moveaxis(pred_tangent, 1, 0)), 0, 1)
    pred_vel = dense_velocity(pred_dense) * to_m
    contact = jax.nn.sigmoid(contact_logits)
    # Velocity at each control frame towards the next frame (the last control looks back).
    vel_frames = jnp.minimum(jnp.asarray(layout.control_frames), layout.num_frames - 2)
    feet_vel = pred_vel[vel_frames][:, jnp.asarray(FEET)]  # (controls, 2, 3)
    cond = condition_mask[..., None].astype(pred_pos.dtype)
    pos_err = ((pred_pos - target_pos) * to_m) ** 2
    off_err, off_count = 0.0, 0.0
    if off_grid_conditions is not None:
        joint, frame, position, valid = off_grid_conditions
        err = jnp.sum(((pred_dense[frame, joint] - position) * to_m) ** 2, axis=-1)
        off_err, off_count = jnp.sum(jnp.where(valid, err, 0.0)), jnp.sum(valid.astype(pred_pos.dtype))
    return {
        "position": _masked_mean(pos_err, per_control),
        "tangent": _masked_mean(((pred_tangent - target_tangent) * to_m) ** 2, per_control),
        "orientation": _masked_mean((pred_rot6d - target_rot6d) ** 2, per_control),
        "velocity": _masked_mean((pred_vel - dense_velocity(dense_target) * to_m) ** 2, per_velocity),
        "dense_position": _masked_mean(((pred_dense - dense_target) * to_m) ** 2, per_frame),
        "condition": (jnp.sum(cond * pos_err) + off_err) / jnp.maximum(3.0 * (jnp.sum(cond) + off_count), 1.0),
        "contact": _masked_mean((contact - target_contacts.astype(contact.dtype)) ** 2, controls_in[:, None]),
        "skate": _masked_mean((contact[..., None] * feet_vel) ** 2, per_control),
    }


def _masked_mean(x: Float[Array, "rows *rest"], rows: Bool[Array, "rows *ones"]) -> Float[Array, ""]:
    """The mean of ``x`` over the rows ``rows`` marks (broadcast over the other axes)."""
    mask = jnp.broadcast_to(rows, x.shape)
    return jnp.sum(jnp.where(mask, x, 0.0)) / jnp.maximum(jnp.sum(mask), 1)


def min_snr_weight(snr: Float[Array, "*batch"], gamma: float | None) -> Float[Array, "*batch"]:
    """Min-SNR-γ loss weight for x₀-prediction (Hang et al. 2023): ``min(SNR_t, γ)``;
    ``gamma=None`` weights every timestep equally (plain MDM)."""
    return jnp.ones_like(snr) if gamma is None else jnp.minimum(snr, gamma)
