"""Projection of Bézier curves onto point constraints at any frame (ours; BMM overwrites
control points only, §4.2, and names the fixed handle frames a limitation, §7.1, §8).

A curve's point at frame ``f`` is linear in the positions and tangents of the control
points around it (:func:`bezmotion.bezier.basis`), and the curves a model works with are
an affine per-(joint, coordinate) map of its variables (``P = mean + std·p̃``; identity
in world space). So "the curve of joint ``j`` passes through ``y`` at frame ``f``" is one
linear equation per coordinate in that joint's variables, and the constraints of one
joint and coordinate stack into ``A z = b`` (one row per handle on that joint).

:func:`project_off_grid` moves the variables by the smallest correction (Euclidean, in
the variables' own space) that satisfies those equations, ``z ← z + A⁺ (b − A z)``,
keeping fixed the control positions that grid constraints have already set. A handle on
a control frame is such a grid constraint: it is an overwrite of one control position
(bit for bit the paper's conditioning), so the projection takes only off-grid rows, and
everything else — padding, grid rows, other joints' rows — enters as zero rows, whose
correction is exactly zero. :func:`project_onto_handles` does both in world space.

Everything is written for one motion with static shapes (any mix of grid, off-grid and
padding handles is the same computation); ``jax.vmap`` it over a batch.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from bezmotion.bezier import BezierLayout, basis
from bezmotion.handles import Handles, grid_conditions, on_control_frame
from bezmotion._src.linalg import exact_einsum, min_norm_solve, spd_inverse


def project_off_grid(
    layout: BezierLayout,
    ctrl_pos: Float[Array, "controls joints 3"],
    ctrl_tangent: Float[Array, "controls joints 3"],
    fixed: Bool[Array, "controls joints"],
    handles: Handles,
    *,
    pos_mean: Float[ArrayLike, "*controls joints 3"] = 0.0,
    pos_std: Float[ArrayLike, "joints 3"] = 1.0,
    tangent_mean: Float[ArrayLike, "joints 3"] = 0.0,
    tangent_std: Float[ArrayLike, "joints 3"] = 1.0,
    fixed_tangent: Bool[Array, "controls joints"] | None = None,
    metric: str | CurveMetric = "variables",
) -> tuple[Float[Array, "controls joints 3"], Float[Array, "controls joints 3"]]:
    """Minimum-norm correction of the curves onto their off-grid point constraints (one motion).

    The curves are ``P = pos_mean + pos_std·ctrl_pos`` and ``T = tangent_mean +
    tangent_std·ctrl_tangent`` (defaults: the arrays are the curves themselves); each valid
    handle off the control frames asks ``evaluate(P, T)[frame, joint] = target``. Handles
    on control frames, padding (``valid=False``) and the positions marked ``fixed`` (set by
    grid constraints, which the caller has already written) do not move anything;
    constraints with no off-grid handle give exactly the input back. Fixed positions and
    tangents come back bit for bit (the solve's moves for them are zero only to
    round-off, so they are restored rather than trusted).

    Args:
      layout: the curves' layout.
      ctrl_pos, ctrl_tangent: ``(controls, joints, 3)`` the variables (e.g. normalised).
      fixed: ``(controls, joints)`` control positions that must not change.
      handles: ``(handles,)`` the constraints, their positions where the curve must be, in
        the curves' units (e.g. cm).
      pos_mean, pos_std, tangent_mean, tangent_std: the affine map from variables to
        curves, broadcastable to ``(joints, 3)`` (``pos_mean`` also to ``(controls, joints, 3)``).
      fixed_tangent: ``(controls, joints)`` control tangents that must not change either
        (e.g. a tangent shared with the next window of a chain); default none. A joint whose
        handles then outnumber its free variables in a stride meets them in slot order as
        far as the variables allow (:func:`bezmotion._src.linalg.min_norm_solve`).
      metric: which correction is smallest: ``"variables"`` (default), the
        Euclidean norm of the variables' change (in the model's normalised space when they
        are normalised); ``"curve"``, the change of the curve itself, summed over every frame
        (``Σ_f |Δcurve(f)|²``, positions and tangents weighed by what they do to it); or a
        :class:`CurveMetric` made beforehand (:func:`curve_metric`, for the same layout, fixed
        variables and scales; the chain's projection, :func:`bezmotion.bmm.sampling._projector`).
    Returns:
      ``(ctrl_pos, ctrl_tangent)`` corrected, same space as the inputs.
    """
    k, j = ctrl_pos.shape[:2]
    dtype = ctrl_pos.dtype
    joint, frame, target, valid = handles
    shape = (j, 3)
    pos_std, tangent_mean, tangent_std = (jnp.broadcast_to(jnp.asarray(a, dtype), shape) for a in (pos_std, tangent_mean, tangent_std))
    pos_mean = jnp.broadcast_to(jnp.asarray(pos_mean, dtype), (k, j, 3))  # per control point too (a chain's windows)
    on_grid, _ = on_control_frame(layout, frame)
    rows = valid & ~on_grid  # (H,)
    # Padding may hold any frame: evaluate it somewhere harmless (its row is zeroed anyway).
    w_pos, w_tan = basis(layout, jnp.where(rows, frame, 0).astype(dtype))  # (H, K)
    w_pos, w_tan = w_pos.astype(dtype), w_tan.astype(dtype)
    curve_pos = pos_mean + pos_std * ctrl_pos  # (K, J, 3)
    curve_tan = tangent_mean + tangent_std * ctrl_tangent
    safe_joint = jnp.clip(joint, 0, j - 1)
    current = exact_einsum("hk,hkd->hd", w_pos, curve_pos[:, safe_joint].swapaxes(0, 1)) + exact_einsum(
        "hk,hkd->hd", w_tan, curve_tan[:, safe_joint].swapaxes(0, 1)
    )
    owns = rows[None, :] & (joint[None, :] == jnp.arange(j)[:, None])  # (J, H): row h constrains joint j
    residual = jnp.where(owns[:, :, None], jnp.where(rows[:, None], target - current, 0.0)[None], 0.0)  # (J, H, 3)
    # A[j, d, h] = [w_pos[h]·pos_std[j, d] (free positions only) | w_tan[h]·tangent_std[j, d]].
    fixed_tangent = jnp.zeros_like(fixed) if fixed_tangent is None else fixed_tangent
    free, free_tan = ~fixed.T, ~fixed_tangent.T  # (J, K)
    a_pos = jnp.where(owns[:, None, :, None] & free[:, None, None, :], w_pos[None, None] * pos_std[:, :, None, None], 0.0)
    a_tan = jnp.where(owns[:, None, :, None] & free_tan[:, None, None, :], w_tan[None, None] * tangent_std[:, :, None, None], 0.0)
    a = jnp.concatenate([a_pos, a_tan], axis=-1)  # (J, 3, H, 2K)
    if isinstance(metric, str) and metric not in ("variables", "curve"):
        raise ValueError(f"metric must be 'variables' or 'curve' (or a CurveMetric), got {metric!r}")
    residual = jnp.moveaxis(residual, -1, 1)  # (J, 3, H)
    if isinstance(metric, str) and metric == "curve":
        metric = curve_metric(layout, fixed, pos_std, tangent_std, fixed_tangent)
    if isinstance(metric, str):
        # Minimum-norm solve of any rank: identical duplicate handles make A rank-deficient, and
        # zero rows (no off-grid handle) must give a zero correction, not a division by zero.
        step = min_norm_solve(a, residual)  # (J, 3, 2K)
    else:
        # min Δᵀ M Δ with A Δ = r is Δ = M⁻¹Aᵀz for any z with (A M⁻¹Aᵀ) z = r. A fixed variable
        # has an identity block in M and a zero column in A, so its Δ is zero.
        spread = exact_einsum("jdha,jdab->jdhb", a, metric.inverse)  # rows of A M⁻¹
        z = min_norm_solve(exact_einsum("jdha,jdga->jdhg", spread, a), residual)
        step = exact_einsum("jdh,jdha->jda", z, spread)
    delta = jnp.moveaxis(step, -1, 0)  # (2K, J, 3)
    return (
        jnp.where(fixed[..., None], ctrl_pos, ctrl_pos + delta[:k]),
        jnp.where(fixed_tangent[..., None], ctrl_tangent, ctrl_tangent + delta[k:]),
    )


class CurveMetric(NamedTuple):
    """``metric="curve"`` of :func:`project_off_grid`, made once for curves whose layout,
    fixed variables and scales stay (a sampler's every DDIM step): the inverse of the Gram
    matrix ``M = CᵀC`` of the basis at every frame, ``C`` scaled by the variables' map to the
    curve, so that ``Δᵀ M Δ = Σ_f |Δcurve(f)|²``.

    Attributes:
      inverse: ``(joints, 3, 2K, 2K)`` ``M⁻¹`` per joint and coordinate (variables: the K
        control positions, then the K tangents); a fixed variable has an identity block.
    """

    inverse: Float[Array, "joints 3 variables variables"]


def curve_metric(
    layout: BezierLayout,
    fixed: Bool[Array, "controls joints"],
    pos_std: Float[Array, "joints 3"],
    tangent_std: Float[Array, "joints 3"],
    fixed_tangent: Bool[Array, "controls joints"] | None = None,
) -> CurveMetric:
    """The smallest change of the curve over every frame as :func:`project_off_grid`'s
    ``metric``. Plain XLA solves (:mod:`bezmotion._src.linalg`), no LAPACK."""
    k, dtype = fixed.shape[0], pos_std.dtype
    fixed_tangent = jnp.zeros_like(fixed) if fixed_tangent is None else fixed_tangent
    every_pos, every_tan = (w.astype(dtype)[None, None] for w in basis(layout))  # (1, 1, F, K)
    c = jnp.concatenate([every_pos * pos_std[:, :, None, None], every_tan * tangent_std[:, :, None, None]], axis=-1)  # (J, 3, F, 2K)
    free = jnp.concatenate([~fixed.T, ~fixed_tangent.T], axis=-1)  # (J, 2K)
    keep = (free[:, :, None] & free[:, None, :])[:, None]  # (J, 1, 2K, 2K)
    gram = jnp.where(keep, exact_einsum("jdfa,jdfb->jdab", c, c), jnp.eye(2 * k, dtype=dtype))
    return CurveMetric(spd_inverse(gram))


def project_onto_handles(
    layout: BezierLayout,
    ctrl_pos: Float[Array, "controls joints 3"],
    ctrl_tangent: Float[Array, "controls joints 3"],
    handles: Handles,
    *,
    fixed: Bool[Array, "controls joints"] | None = None,
    fixed_tangent: Bool[Array, "controls joints"] | None = None,
) -> tuple[Float[Array, "controls joints 3"], Float[Array, "controls joints 3"]]:
    """World-space curves through every valid handle (one motion): handles on control
    frames overwrite their control position (exactly), the others are met by the
    minimum-norm correction of :func:`project_off_grid`.

    Args:
      ctrl_pos, ctrl_tangent: ``(controls, joints, 3)`` curves (cm).
      handles: ``(handles,)`` where the joints must be (cm).
      fixed: further control positions that must not move (e.g. the start and end poses).
      fixed_tangent: control tangents that must not move (e.g. shared with a neighbouring window).
    Returns:
      ``(ctrl_pos, ctrl_tangent)``.
    """
    mask, target = grid_conditions(layout, handles._replace(position=handles.position.astype(ctrl_pos.dtype)), ctrl_pos.shape[1])
    ctrl_pos = jnp.where(mask[..., None], target, ctrl_pos)
    if fixed is not None:
        mask = mask | fixed
    return project_off_grid(layout, ctrl_pos, ctrl_tangent, mask, handles, fixed_tangent=fixed_tangent)


__all__ = ["CurveMetric", "curve_metric", "grid_conditions", "on_control_frame", "project_off_grid", "project_onto_handles"]
