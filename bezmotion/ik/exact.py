"""An exact IK stage: any IK's pose, then a damped least-squares solve onto the six targets.

Learned and analytic IK modules come close to the six characteristic-joint targets but do
not solve all of them exactly (a network is a regression; the rig solves the hands and
feet but not the head's bend against an OOD hips). :func:`exact_ik` composes an inner
``ik_fn`` (:mod:`bezmotion.ik.protores`, :mod:`bezmotion.ik.rig`, your own) with a
Levenberg–Marquardt solve per frame (jit-compiled, vmapped over frames), over

- every joint's local rotation, as an axis-angle delta on top of the inner pose
  (``q = q_start ⊗ exp(δ)``; joints above the hips stay at identity), and
- the hips' position,

of the weighted residuals

- **positions** of the six characteristic joints (``position_weight`` per cm: large, so
  the positions are as hard as float32 allows and the other terms only choose among the
  poses that reach them; beyond ``robust_cm`` a joint that is neither a handle nor a planted
  foot costs Huber's loss, so one target out of reach does not drag the others off theirs);
- **orientations** of the six joints (``rotation_weight`` per radian);
- a **prior** keeping every joint near its start rotation (``prior_weight`` per radian):
  among the poses that reach the targets the solve picks the one closest to the inner
  IK's, so elbows and knees keep the inner pose's swivel and the spine its bend;
- soft **joint limits** measured from a corpus (:mod:`bezmotion.ik.joint_limits`): a
  hinge on each axis of the joint's rotation relative to its corpus mean
  (``limit_weight`` per radian beyond the range); without them, no limits.

The solver is ours rather than ``optimistix.LevenbergMarquardt``: the same damped
Gauss–Newton steps with exact Jacobians, but FK's Jacobian is analytic (a joint's turn
moves its subtree's points by axis × lever) and the normal equations are solved in their
dual form (a 36 × 36 system per frame instead of QR on the 69-column Jacobian), so one pass
on the demo window (31 frames) takes ~8 ms against optimistix's 263 ms at the same accuracy.
A fixed step count keeps a batch of frames in lock step. Gradients pass through the unrolled
steps.

A target out of reach is approached as closely as the limbs allow (the positions'
residual cannot vanish, the other terms keep the pose finite and near its start);
:meth:`ExactIKFn.with_residual` reports what is left per joint. The exponential and
logarithm maps use the double-``where`` pattern, so poses and gradients stay finite at
the identity and at full extension.

Frames are solved independently by the ``ik_fn`` (:class:`ExactIKFn`); its
:meth:`ExactIKFn.solve_window` solves a whole window ``(frames, …)`` from the inner IK's
poses filtered over time (:mod:`bezmotion.ik.temporal`: one-frame flips replaced by their
neighbours, lasting flips turned into ramps, then a ``[w, 1 − 2w, w]`` filter of
neighbouring frames), so a learned IK's frame-to-frame jitter does not reach the result.
The pipeline uses it through :func:`bezmotion.ik.protocol.solve_frames`, which also hands it

- the **keys**: the start poses are joined to the key poses first
  (:func:`~bezmotion.ik.key_blend.blend_to_keys`) and the frames next to a key are held
  near them (``key_hold_weight``, decaying by ``key_hold_decay`` a frame). Where the curves next
  to a key are hard to reach exactly, an unheld solve swings whole arms for the last
  centimetres and the joint turns tens of degrees in the frame after the key (a pop);
- the **handles** (``IKTargets.pinned``): their position rows weigh ``handle_weight``
  times more, so where the six targets conflict the unpinned joints give way: a handle
  beyond the limb's reach moves the hips, which Levenberg–Marquardt does only with its
  damping scaled to each unknown's curvature and a trust region that never shortens the
  hips' translation (see ``_levenberg_marquardt``).

What it achieves on Bandai-Namco and LaFAN1 (handles, MPJPE, foot skating, key pop, speed)
is in docs/authoring.md's *Precision after IK*.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bezmotion.geometry.rotations import (
    matrix_from_quat,
    quat_angle,
    quat_conjugate,
    quat_exp,
    quat_from_rot6d,
    quat_log,
    quat_mul,
    right_jacobian,
    right_jacobian_inverse,
    safe_norm,
    skew,
)
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.key_blend import blend_to_chain_keys, distances_to_keys, key_chain
from bezmotion.ik.protocol import Character, IKFn, IKTargets, Pose, pose_fk
from bezmotion.ik.rig import Rig, elbows_from_keys
from bezmotion.ik.temporal import FLIP_TURN, KEY_TURN, limit_turns, planted_feet, remove_flips, smooth, turn_out_of_keys
from bezmotion._src.linalg import cholesky_solve, inverse_3x3

# Levenberg–Marquardt damping, relative to each unknown's own curvature (the diagonal of
# JᵀW²J: a hand's position rows weigh a shoulder turn by its ~50 cm lever, the hips' by a
# few cm): none while steps lower the cost (the inner IK's pose is already close), from
# _DAMPING_FIRST up after a refused step, so a refused step's successor is a short,
# gradient-like one in every unknown alike, the hips' translation included.
_DAMPING_FIRST, _DAMPING_UP, _DAMPING_DOWN = 1.0, 10.0, 0.1
# Row weights below this count as this (a zero weight, e.g. rotation_weight=0, would put 1/0
# on the dual system's diagonal).
_MIN_ROW_WEIGHT_SQ = 1e-12
# The trust region (ExactIKParams.max_turn) after a taken step and after a refused one.
_RADIUS_GROW, _RADIUS_SHRINK = 2.0, 0.25


# ------------------------------------------------------------------------------- settings


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ExactIKParams:
    """Settings of :class:`ExactIKFn`: the inner IK's params, the character, and the solve's
    weights, temporal filters, trust region and step counts.

    Each weight multiplies a residual, so its square enters the least-squares cost. The
    positions weigh most; every other term only chooses among the poses that reach them.

    Model:
      inner: the inner ``ik_fn``'s params (a :class:`~bezmotion.ik.protores.ProtoResModel`, a
        :class:`~bezmotion.ik.rig.Rig`, …).
      character: the skeleton and its six characteristic joints.
      limits: soft joint limits (:class:`JointLimits`; :meth:`JointLimits.unlimited` for none).

    Target weights:
      position_weight: per cm of a characteristic joint's position miss (≥ 0; large, so the
        positions are as hard as float32 allows).
      hips_position_scale: the hips' position weight relative to the other joints' (≥ 0).
      handle_weight: a pinned target's (a handle's) position weight relative to the others' (≥ 0):
        least squares splits a miss by inverse squared weight, so unpinned joints give way.
      handle_spread: how far a handle's weight reaches into its neighbouring frames, so they follow
        the curve through it: ``d`` frames away, ``handle_weight^(handle_spread^d)`` (0 … 1; 0: off).
      robust_cm: an unpinned, unplanted joint's position miss beyond which Huber's loss replaces the
        square, so one unreachable target does not bend the body (cm, ≥ 0; 0: least squares).
      rotation_weight: per unit of ortho6D difference of the six joints' orientations (≈ per rad, ≥ 0).

    Planted feet (window solve):
      plant_weight: a standing foot's position weight relative to the others', so it does not slide
        where a handle pulls the body (≥ 0; 1: like any target).
      plant_height_scale: a planted foot's miss above its target weighs ``plant_weight`` times this,
        so a foot pulled out of reach lifts rather than slides (≥ 0; 1: like its horizontal miss).
      plant_step: horizontal motion to the next frame under which a foot target stands still (cm per
        frame, ≥ 0).

    Pose regularisation and keys:
      prior_weight: per radian of a joint's rotation away from its start (inner IK) pose; it also
        keeps independently solved neighbouring frames alike (≥ 0).
      root_weight: per cm of the hips' position away from its start (≥ 0).
      limit_weight: per radian beyond a joint's limits (≥ 0).
      key_hold_weight: per radian of a joint's turn away from its start pose at the frame next to a
        key, so reaching the last centimetres there does not swing the body into a pop (≥ 0).
      key_hold_decay: the hold ``d`` frames from the nearest key is ``key_hold_weight ·
        key_hold_decay^(d − 1)`` (0 … 1).

    Temporal filters (window solve):
      smoothing: weight of each neighbouring frame in the ``[w, 1 − 2w, w]`` filter
        (:func:`~bezmotion.ik.temporal.smooth`; 0 … 0.5; 0: none).
      key_smoothing: the same filter's weight within ``key_blend_frames`` of a key, where an inner
        IK that spins a joint fast makes the key pop (0 … 0.5).
      spike_turn: the inner IK's one-frame flips beyond this are replaced by their neighbours and
        lasting ones become ramps (rad, ≥ 0; 0: off).
      finish_turn: after the last pass, the most a joint turns in one frame, the keys' and handles'
        frames kept (rad, ≥ 0; 0: off).
      key_turn: with keys joined, the finish's limit on the steps that touch a key, easing to
        ``finish_turn`` (rad, ≥ 0; 0: ``finish_turn`` there too).

    Trust region and iterations:
      max_turn: the most any joint turns in one step; shrinks 4× after a refused step and grows 2×
        after a taken one (rad, > 0; a far start, such as the rig's, wants 0.2).
      iterations: Levenberg–Marquardt steps per frame and pass (static, ≥ 0).
      window_passes: how many times the window solve filters the poses over time and solves again
        from them (static, ≥ 1; each pass costs one solve).
    """

    inner: Any
    character: Character
    limits: JointLimits
    position_weight: Float[Array, ""] | float = 100.0
    hips_position_scale: Float[Array, ""] | float = 1.0
    handle_weight: Float[Array, ""] | float = 25.0
    key_hold_weight: Float[Array, ""] | float = 3000.0
    key_hold_decay: Float[Array, ""] | float = 0.85
    plant_weight: Float[Array, ""] | float = 4.0
    plant_height_scale: Float[Array, ""] | float = 0.25
    plant_step: Float[Array, ""] | float = 0.25
    max_turn: Float[Array, ""] | float = 1.0
    rotation_weight: Float[Array, ""] | float = 20.0
    prior_weight: Float[Array, ""] | float = 50.0
    root_weight: Float[Array, ""] | float = 0.05
    limit_weight: Float[Array, ""] | float = 10.0
    smoothing: Float[Array, ""] | float = 0.25
    key_smoothing: Float[Array, ""] | float = 0.5
    spike_turn: Float[Array, ""] | float = FLIP_TURN
    robust_cm: Float[Array, ""] | float = 5.0
    handle_spread: Float[Array, ""] | float = 0.25
    finish_turn: Float[Array, ""] | float = FLIP_TURN
    key_turn: Float[Array, ""] | float = KEY_TURN
    iterations: int = dataclasses.field(default=6, metadata=dict(static=True))
    window_passes: int = dataclasses.field(default=2, metadata=dict(static=True))


class ExactIKResult(NamedTuple):
    """A solved pose and what is left of each characteristic joint's target.

    Attributes:
      pose: the :class:`~bezmotion.ik.protocol.Pose` (``(*batch, …)``).
      position_error: ``(*batch, 6)`` distance (cm) of each characteristic joint from its target.
      rotation_error: ``(*batch, 6)`` angle (rad) of each from its target orientation.
    """

    pose: Pose
    position_error: Float[Array, "*batch 6"]
    rotation_error: Float[Array, "*batch 6"]


# --------------------------------------------------------------------------------- solver


def _free_joints(character: Character) -> np.ndarray:
    """Joints whose rotation the solve changes: all but those above the hips."""
    above = set(character.ancestors_of_hips())
    return np.asarray([j for j in range(character.num_joints) if j not in above])


def _apply(character: Character, start: Pose, delta: Float[Array, "free 3"], root_delta: Float[Array, "3"]) -> Pose:
    free = _free_joints(character)
    quat = start.quat_local.at[free].set(quat_mul(start.quat_local[free], quat_exp(delta)))
    return Pose(start.root_pos + root_delta, quat)


class _Problem(NamedTuple):
    """One frame's fixed data: the start pose, the targets and how much each position weighs."""

    start: Pose
    target_pos: Float[Array, "6 3"]
    target_quat: Float[Array, "6 4"]
    position_scale: Array  # (6, 3): per-joint, per-axis factors on the position rows (_position_scale)
    hold: Array  # () per rad: how hard the frame is held at its start pose (next to a key)
    robust: Array | float = 0.0  # (6, 1) cm: each position's Huber threshold (0: least squares)


def _limit_excess(params: ExactIKParams, start_quat: Array, delta: Array) -> tuple[Array, Array]:
    """Per free joint: how far (rad, per axis) its rotation lies outside its limits ``(free, 3)``,
    and that rotation as ``ρ = log(center⁻¹ ⊗ start ⊗ exp(δ))`` ``(free, 3)``."""
    free = _free_joints(params.character)
    limits = params.limits
    rel = quat_log(quat_mul(quat_conjugate(limits.center[free]), quat_mul(start_quat[free], quat_exp(delta))))
    excess = jnp.maximum(rel - limits.upper[free], 0.0) + jnp.minimum(rel - limits.lower[free], 0.0)
    return excess, rel


def _limit_jacobian(params: ExactIKParams, rel: Array, delta: Array) -> Array:
    """``(free, 3, 3)``: the Jacobian of :func:`_limit_excess`'s excess with respect to ``δ``.

    Analytic: ``exp(δ + dδ) ≈ exp(δ) ⊗ exp(J_r(δ) dδ)`` and ``log(R ⊗ exp(ε)) ≈ log(R) +
    J_r⁻¹(ρ) ε``, so ``dρ/dδ = J_r⁻¹(ρ) J_r(δ)`` on the axes outside their range (a quarter
    of the solve's time went to ``jax.jacfwd`` of the maps). ``rel`` is the excess' ``ρ``,
    so the logarithm is not taken twice.
    """
    free = _free_joints(params.character)
    outside = ((rel > params.limits.upper[free]) | (rel < params.limits.lower[free])).astype(delta.dtype)[..., None]
    return outside * (right_jacobian_inverse(rel) @ right_jacobian(delta))


def _evaluate(params: ExactIKParams, problem: _Problem, delta: Array, root_delta: Array):
    """FK of the pose at ``(delta, root_delta)``: global matrices, positions, residuals, cost."""
    character = params.character
    pose = _apply(character, problem.start, delta, root_delta)
    quat_global, pos_global = pose_fk(character, pose)
    rot = matrix_from_quat(quat_global)
    idx = np.asarray(character.characteristic)
    miss = pos_global[idx] - problem.target_pos
    # Huber's loss beyond ``problem.robust`` cm: the rows of a position that far off are scaled
    # by sqrt(robust / distance) for the step (iteratively reweighted least squares: the same
    # gradient as Huber's), and the cost is Huber's, so a step is judged by the loss it descends.
    distance = safe_norm(miss, keepdims=True)  # (6, 1)
    far = (problem.robust > 0.0) & (distance > problem.robust)
    safe_distance = jnp.where(far, distance, 1.0)
    # A planted foot's lighter height (plant_height_scale) only upwards: below its target it
    # weighs as horizontally, so a foot rises where the body pulls it and never sinks into the
    # floor. (The weight switches where the miss does, so the cost stays smooth.) Other joints
    # weigh their three axes alike, where this changes nothing.
    scale = problem.position_scale
    scale = scale.at[:, 1].set(jnp.where(miss[:, 1] < 0.0, scale[:, 0], scale[:, 1]))
    row_scale = scale * jnp.where(far, jnp.sqrt(problem.robust / safe_distance), 1.0)
    e_pos = miss * row_scale
    # Huber's joints are never planted, so their three axes weigh alike (any one stands for all).
    position_cost = jnp.where(
        far,
        scale[:, :1] ** 2 * (2.0 * problem.robust * safe_distance - problem.robust**2),
        jnp.sum(jnp.square(miss * scale), axis=-1, keepdims=True),
    )
    # Orientation: 2·vec of the world-frame difference q·q_t⁻¹ (short way), ≈ angle × axis.
    rel = quat_mul(quat_global[idx], quat_conjugate(problem.target_quat))
    rel = jnp.where(rel[..., :1] < 0.0, -rel, rel)
    e_rot = 2.0 * rel[..., 1:]
    excess, limit_rel = _limit_excess(params, problem.start.quat_local, delta)
    cost = (
        params.position_weight**2 * jnp.sum(position_cost)
        + params.rotation_weight**2 * jnp.sum(e_rot * e_rot)
        + params.limit_weight**2 * jnp.sum(excess * excess)
    )
    return rot, pos_global, rel, e_pos, row_scale, e_rot, excess, limit_rel, cost


def _position_scale(params: ExactIKParams, pinned: Array, planted: Array, dtype, near: Array | None = None) -> Array:
    """``(6, 3)`` per-joint, per-axis factors on the position residuals: the hips'
    ``hips_position_scale``, times ``handle_weight`` where ``pinned`` ``(6,)``, else
    ``plant_weight`` where ``planted`` ``(6,)`` (its height times ``plant_height_scale``), else
    ``handle_weight^near`` where ``near`` ``(6,)`` (0 … 1: next to a handle of that joint)."""
    scale = jnp.ones(6, dtype).at[0].set(params.hips_position_scale)
    other = 1.0 if near is None else jnp.maximum(jnp.asarray(params.handle_weight, dtype) ** near, 1.0)
    factor = jnp.where(pinned, params.handle_weight, jnp.where(planted, params.plant_weight, other))
    height = jnp.where(planted & ~pinned, params.plant_height_scale, 1.0)  # +Y up
    axes = jnp.ones((6, 3), dtype).at[:, 1].set(height)
    return (scale * factor).astype(dtype)[:, None] * axes


def _hold_weights(params: ExactIKParams, problem: _Problem) -> tuple[Array, Array]:
    """``(per rad, per cm)``: the weights holding a frame next to a key at its start pose."""
    return problem.hold, problem.hold * params.root_weight / params.prior_weight


def _prior_cost(params: ExactIKParams, problem: _Problem, delta: Array, root_delta: Array, anchor) -> Array:
    """The prior (towards ``anchor``) and the key hold (towards the start pose, ``δ = 0``)."""
    d, r = delta - anchor[0], root_delta - anchor[1]
    hold, hold_root = _hold_weights(params, problem)
    return (
        params.prior_weight**2 * jnp.sum(d * d) + params.root_weight**2 * jnp.sum(r * r)
        + hold**2 * jnp.sum(delta * delta) + hold_root**2 * jnp.sum(root_delta * root_delta)
    )  # fmt: skip


def _step(params: ExactIKParams, problem: _Problem, delta: Array, root_delta: Array, evaluated, damping: Array, anchor):
    """The damped Gauss–Newton step from ``(delta, root_delta)``, as ``(free·3 + 3,)``.

    Exact Jacobians (analytic for FK). The normal equations ``(D + JᵀW²J) Δ = −(JᵀW²r + g_D)``
    — ``J, r`` the six joints' position and orientation rows, ``W`` their weights, ``D, g_D``
    the prior's and limits' block-diagonal Hessian and gradient — are solved in their dual
    form ``Δ = −D⁻¹(g_D + Jᵀμ)``, ``(W⁻² + J D⁻¹ Jᵀ) μ = r − J D⁻¹ g_D``. Forming ``JᵀW²J``
    in float32 would bury the prior under the rounding of the (large-weight) position rows;
    the dual form never adds the two, and ``W⁻²`` only regularises ``μ`` (a position weight
    → ∞ makes the step the exact constrained one).
    Levenberg–Marquardt damping adds ``damping · diag(JᵀW²J)`` to ``D`` (each unknown's own curvature).
    """
    character = params.character
    rot, pos, rel, e_pos, scale, e_rot, excess, limit_rel, _ = evaluated
    free = _free_joints(character)
    idx = np.asarray(character.characteristic)
    n_free = len(free)
    dtype = delta.dtype
    # d(q ⊗ exp(δ)) turns the joint's subtree about the world axis G·J_r(δ)·dδ: a point p
    # moves by axis × (p − joint), a frame column c by axis × c. The Jacobian is built
    # transposed, ``(free joint, k, row)``, the layout every product below reads without a
    # copy.
    axes = jnp.swapaxes(rot[free] @ right_jacobian(delta), -1, -2)  # (free, k, xyz)
    mask = jnp.asarray(_ancestry(character).T, dtype)[:, None, :, None]  # (free, 1, 6, 1)
    lever = pos[idx][None, :, :] - pos[free][:, None, :]  # (free, 6, xyz)
    j_pos = mask * jnp.cross(axes[:, :, None, :], lever[:, None, :, :]) * scale[None, None]  # (free, k, 6, xyz)
    # A world turn ω of the joint changes 2·vec(q_rel) by (w I − [v]×) ω, (w, v) = q_rel.
    w, v = rel[:, :1, None], rel[:, 1:]
    turn = w * jnp.eye(3, dtype=dtype) - skew(v)  # (6, xyz out, xyz in)
    j_rot = mask * jnp.einsum("eab,fkb->fkea", turn, axes)  # (free, k, 6, xyz)
    # Rows: 18 positions then 18 orientations (joint-major); columns: (free joint, k), then the root.
    jac_free = jnp.concatenate([j_pos.reshape(n_free, 3, 18), j_rot.reshape(n_free, 3, 18)], axis=-1)  # (free, k, 36)
    jac_root = jnp.concatenate([(scale[:, :, None] * jnp.eye(3, dtype=dtype)).reshape(18, 3).T, jnp.zeros((3, 18), dtype)], axis=-1)
    res = jnp.concatenate([e_pos.reshape(-1), e_rot.reshape(-1)])
    row_weight_sq = jnp.maximum(
        jnp.concatenate([jnp.full(18, params.position_weight**2, dtype), jnp.full(18, params.rotation_weight**2, dtype)]),
        _MIN_ROW_WEIGHT_SQ,
    )
    # Marquardt's scaling: the damping of each unknown in proportion to its curvature.
    curvature = jnp.sum(row_weight_sq * jac_free * jac_free, axis=-1)  # (free, 3)
    root_curvature = params.position_weight**2 * jnp.sum(scale * scale, axis=0)  # (3,): per root axis

    d_excess = _limit_jacobian(params, limit_rel, delta)
    d_excess_t = jnp.swapaxes(d_excess, -1, -2)
    hold, hold_root = _hold_weights(params, problem)
    blocks = (
        (params.prior_weight**2 + hold**2) * jnp.eye(3, dtype=dtype)
        + damping * curvature[..., None] * jnp.eye(3, dtype=dtype)
        + params.limit_weight**2 * (d_excess_t @ d_excess)
    )
    block_grad = (
        params.prior_weight**2 * (delta - anchor[0]) + hold**2 * delta
        + params.limit_weight**2 * jnp.einsum("fab,fb->fa", d_excess_t, excess)
    )  # fmt: skip
    root_block = (params.root_weight**2 + hold_root**2 + damping * root_curvature) * jnp.ones(3, dtype)
    root_grad = params.root_weight**2 * (root_delta - anchor[1]) + hold_root**2 * root_delta

    inv_blocks = inverse_3x3(blocks)
    jd_free = jnp.swapaxes(inv_blocks, -1, -2) @ jac_free  # (J D⁻¹)ᵀ, (free, k, 36)
    jd_root = jac_root / root_block[:, None]
    rows = jac_free.shape[-1]
    schur = jd_free.reshape(-1, rows).T @ jac_free.reshape(-1, rows) + jd_root.T @ jac_root + jnp.diag(1.0 / row_weight_sq)
    rhs = res - jnp.einsum("fkr,fk->r", jd_free, block_grad) - root_grad @ jd_root
    mu = cholesky_solve(schur, rhs)
    move_free = -jnp.einsum("fab,fb->fa", inv_blocks, block_grad + jac_free @ mu)
    move_root = -(root_grad + jac_root @ mu) / root_block
    return move_free, move_root


def _levenberg_marquardt(params: ExactIKParams, problems: _Problem, iterations: int):
    """Fixed-count Levenberg–Marquardt on a batch of frames (``problems``: leading frame
    axis): ``(delta, root_delta, cost)``, each frame's own solve.

    A step that lowers the cost is taken and the damping relaxed; one that does not is
    refused and the damping raised. A fixed count keeps every frame of a batch in step
    (no data-dependent loop under vmap).

    The prior pulls towards the start pose for the first half of the steps; then it is
    measured from each step's own starting point (a proximal step: the least change that
    reaches the targets). Gauss–Newton converges only linearly while the prior pulls
    against the targets (it ignores the targets' curvature times that pull); the proximal
    half converges quadratically onto reachable targets from the prior's near-solution.

    The frames run in lock step (the loop over steps outside the map over frames) so that a
    step evaluates its second trust-region candidate only where some frame needs one: where
    no joint's turn exceeds its frame's radius, both candidates are the whole step, and one
    evaluation gives the very numbers two would. Under an outer ``vmap`` the branch becomes a
    select and both are evaluated.
    """
    n_free = len(_free_joints(params.character))
    frames, dtype = problems.start.root_pos.shape[0], problems.start.root_pos.dtype
    delta, root_delta = jnp.zeros((frames, n_free, 3), dtype), jnp.zeros((frames, 3), dtype)
    evaluate = jax.vmap(lambda problem, d, r: _evaluate(params, problem, d, r))
    prior_cost = jax.vmap(lambda problem, d, r, anchor: _prior_cost(params, problem, d, r, anchor))
    evaluated = evaluate(problems, delta, root_delta)

    def where_frames(mask, a, b):
        """``a`` where a frame's ``mask`` ``(frames,)`` holds, else ``b`` (pytrees of per-frame arrays)."""
        return jax.tree.map(lambda x, y: jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 1)), x, y), a, b)

    def propose(problem, delta, root_delta, damping, radius, evaluated, proximal):
        """One frame's step and its two trust-region shapes."""
        zero = (jnp.zeros_like(delta), jnp.zeros_like(root_delta))
        anchor = jax.tree.map(lambda a, b: jnp.where(proximal, a, b), (delta, root_delta), zero)
        current = evaluated[-1] + _prior_cost(params, problem, delta, root_delta, anchor)
        move_free, move_root = _step(params, problem, delta, root_delta, evaluated, damping, anchor)
        ok = jnp.all(jnp.isfinite(move_free)) & jnp.all(jnp.isfinite(move_root))
        # The trust region: no joint turns more than ``radius`` in one step (far from the
        # solution the linearised step overshoots, and a refused step costs an iteration).
        # Two shapes of it are tried and the lower cost kept: the whole step shortened until
        # its largest turn fits (its direction kept: what a far start, the rig's, needs),
        # and each joint's turn clipped on its own (near a straight limb or a twist axis
        # the linearisation asks one joint for tens of radians, and shortening everything
        # by that froze the hips' translation the targets needed). The translation, linear
        # in the positions, is never shortened. The region shrinks after a refused step and
        # grows back after a taken one: near a straight limb the right steps are long.
        turns = safe_norm(move_free)
        clipped = delta + jnp.where(ok, move_free * jnp.minimum(1.0, radius / jnp.maximum(turns, 1e-12))[..., None], 0.0)
        shortened = delta + jnp.where(ok, move_free * jnp.minimum(1.0, radius / jnp.maximum(jnp.max(turns), 1e-12)), 0.0)
        new_root = root_delta + jnp.where(ok, move_root, 0.0)
        return anchor, current, ok, clipped, shortened, new_root, jnp.max(turns) > radius

    def step(carry, proximal):
        delta, root_delta, damping, radius, evaluated = carry
        anchor, current, ok, clipped, shortened, new_root, shapes_differ = jax.vmap(propose, in_axes=(0, 0, 0, 0, 0, 0, None))(
            problems, delta, root_delta, damping, radius, evaluated, proximal
        )

        def attempt(new_delta):
            candidate = evaluate(problems, new_delta, new_root)
            return new_delta, candidate, candidate[-1] + prior_cost(problems, new_delta, new_root, anchor)

        def better_shape():
            by_joint, whole = attempt(clipped), attempt(shortened)
            return where_frames(by_joint[-1] <= whole[-1], by_joint, whole)

        new_delta, candidate, new_cost = jax.lax.cond(jnp.any(shapes_differ), better_shape, lambda: attempt(clipped))
        better = ok & (new_cost <= current)
        delta, root_delta, evaluated = where_frames(better, (new_delta, new_root, candidate), (delta, root_delta, evaluated))
        damping = jnp.where(better, damping * _DAMPING_DOWN, jnp.maximum(damping * _DAMPING_UP, _DAMPING_FIRST))
        radius = jnp.where(better, jnp.minimum(radius * _RADIUS_GROW, params.max_turn), radius * _RADIUS_SHRINK)
        return (delta, root_delta, damping, radius, evaluated), None

    proximal = jnp.arange(iterations) >= iterations // 2
    init = (delta, root_delta, jnp.zeros(frames, dtype), jnp.full(frames, params.max_turn, dtype), evaluated)
    (delta, root_delta, _, _, evaluated), _ = jax.lax.scan(step, init, proximal)
    return delta, root_delta, evaluated[-1]


def _problem(
    params: ExactIKParams,
    start: Pose,
    targets: IKTargets,
    hold: Array | float = 0.0,
    planted: Array | None = None,
    near: Array | None = None,
) -> _Problem:
    """One frame's problem: the least-squares pose from ``start`` (held there with weight
    ``hold`` per rad), the feet marked in ``planted`` ``(6,)`` weighing ``plant_weight``, the
    joints next to a handle of theirs weighing ``handle_weight^near`` (``near`` ``(6,)``,
    :func:`_near_handles`)."""
    pinned = jnp.zeros(6, bool) if targets.pinned is None else targets.pinned
    planted = jnp.zeros(6, bool) if planted is None else planted
    dtype = start.root_pos.dtype
    scale = _position_scale(params, pinned, planted, dtype, near)
    # Handles and planted feet stay least squares: under Huber's loss a planted foot pulled
    # several cm gives way much further.
    robust = jnp.where(pinned | planted, 0.0, jnp.asarray(params.robust_cm, dtype))[:, None]
    return _Problem(start, targets.position, quat_from_rot6d(targets.rot6d), scale, jnp.asarray(hold, dtype), robust)


def _solve(params: ExactIKParams, problems: _Problem, iterations: int) -> Pose:
    """The frames' poses ``(frames, …)`` solving ``problems`` (:func:`_problem`, stacked)."""
    delta, root_delta, _ = _levenberg_marquardt(params, problems, iterations)
    return jax.vmap(lambda start, d, r: _apply(params.character, start, d, r))(problems.start, delta, root_delta)


def _near_handles(pinned: Bool[Array, "frames 6"], spread: Array | float, dtype) -> Array:
    """``(frames, 6)``: ``spread^d`` for a joint ``d ≥ 1`` frames from its nearest handle
    (``pinned``); 0 on the handle's own frame, where that falls below 0.05, and for a joint
    without handles. The exponent of :func:`_position_scale`'s weight next to a handle."""
    frames = pinned.shape[0]
    t = np.arange(frames)
    distance = np.abs(t[:, None] - t[None, :])  # (frames, frames)
    d = jnp.min(jnp.where(pinned[None, :, :], jnp.asarray(distance)[:, :, None], frames + 1), axis=1)  # (frames, 6)
    strength = jnp.asarray(spread, dtype) ** d.astype(dtype)
    return jnp.where((d > 0) & (d <= frames) & (strength >= 0.05), strength, 0.0)  # d > frames: no handle


def _ancestry(character: Character) -> np.ndarray:
    """``(6, free)``: whether free joint f is the characteristic joint e or one of its ancestors."""
    free = _free_joints(character)
    parents = character.skeleton.parents
    out = np.zeros((len(character.characteristic), len(free)), bool)
    for e, joint in enumerate(character.characteristic):
        j = joint
        while j >= 0:
            hit = np.flatnonzero(free == j)
            if hit.size:
                out[e, hit[0]] = True
            j = parents[j]
    return out


def _errors(character: Character, pose: Pose, targets: IKTargets) -> tuple[Array, Array]:
    quat_global, pos_global = pose_fk(character, pose)
    idx = np.asarray(character.characteristic)
    position = safe_norm(pos_global[..., idx, :] - targets.position)
    rotation = quat_angle(quat_global[..., idx, :], quat_from_rot6d(targets.rot6d))
    return position, rotation


@dataclasses.dataclass(frozen=True)
class ExactIKFn:
    """``ik_fn(params, targets) -> pose``: the inner IK, then the exact solve (one frame).

    Build with :func:`exact_ik`. Hashable (a static argument of ``jax.jit``) as long as the
    inner ``ik_fn`` is.

    Attributes:
      inner: the inner ``ik_fn`` giving the start pose.
    """

    inner: IKFn

    def __call__(self, params: ExactIKParams, targets: IKTargets) -> Pose:
        return self.with_residual(params, targets).pose

    def with_residual(self, params: ExactIKParams, targets: IKTargets) -> ExactIKResult:
        """One frame, with what is left of each target (:class:`ExactIKResult`)."""
        problem = jax.tree.map(lambda x: x[None], _problem(params, self.inner(params.inner, targets), targets))
        pose = jax.tree.map(lambda x: x[0], _solve(params, problem, params.iterations))
        return ExactIKResult(pose, *_errors(params.character, pose, targets))

    def solve_window(
        self,
        params: ExactIKParams,
        targets: IKTargets,
        keys: tuple[Pose, Pose] | Pose | None = None,
        key_blend_frames: int = 0,
        start: Pose | None = None,
    ) -> Pose:
        """A window ``(frames, …)``: the inner IK's poses smoothed over time, then solved per
        frame (the :func:`~bezmotion.ik.protocol.solve_frames` protocol)."""
        return self.solve_window_with_residual(params, targets, keys, key_blend_frames, start).pose

    def solve_window_with_residual(
        self,
        params: ExactIKParams,
        targets: IKTargets,
        keys: tuple[Pose, Pose] | Pose | None = None,
        key_blend_frames: int = 0,
        start: Pose | None = None,
    ) -> ExactIKResult:
        """:meth:`solve_window` with what is left of each target, per frame.

        With ``keys`` ``(start, end)``, the poses each pass starts from (and its prior pulls
        towards) are joined to the keys first (:func:`~bezmotion.ik.key_blend.blend_to_keys`
        over ``key_blend_frames``), and the keys replace the first and last frame: the
        frames next to a key start from nearly the key's pose, so they leave it no faster
        than the targets move (no pop), and the solve still hits every target there. A
        chain's keys (batched ``(K + 1, …)``, ``targets`` of ``K·(W − 1) + 1`` frames) join
        each window to its own two keys and hold the frames on both sides of every key.
        After the last pass no joint turns more than ``finish_turn`` in a frame (``key_turn``
        on the steps out of a joined key: :func:`~bezmotion.ik.temporal.turn_out_of_keys`), the
        keys' and handles' frames kept (:func:`~bezmotion.ik.temporal.limit_turns`).
        With keys and the rig as the inner IK (``exact_rig``), the rig's arms first bend their
        elbows the way the keys around each frame do (:func:`~bezmotion.ik.rig.elbows_from_keys`).

        ``start``: ``(frames, …)`` poses to begin from instead of the inner IK's, a warm start
        (e.g. this solve's result for targets that have since moved a little: an editor's
        drag); the filters and passes then run on them as on the inner IK's poses.

        Raises:
          ValueError: a ``start`` that is not ``(frames, joints, …)`` poses of the targets' frames.
        """
        if start is None:
            pose = jax.vmap(self.inner, in_axes=(None, 0))(params.inner, targets)
            if keys is not None and isinstance(params.inner, Rig):  # the rig's elbows bend as the keys' do
                pose = elbows_from_keys(params.inner, pose, targets, key_chain(keys))
        elif start.quat_local.shape != (targets.position.shape[0], params.character.num_joints, 4):
            raise ValueError(f"start must be poses of the targets' {targets.position.shape[0]} frames, got quat_local {start.quat_local.shape}")
        else:
            pose = start
        frames = pose.root_pos.shape[0]
        hold = jnp.zeros(frames, pose.root_pos.dtype)
        at_key = jnp.zeros(frames, bool)
        filter_weight = jnp.full(frames, params.smoothing, pose.root_pos.dtype)
        if keys is not None:
            distance = distances_to_keys(frames, keys)  # raises for a non-chain
            decay = jnp.asarray(params.key_hold_decay, hold.dtype) ** jnp.asarray(np.maximum(distance - 1, 0), hold.dtype)
            hold = params.key_hold_weight * decay
            at_key = jnp.asarray(distance == 0)
            filter_weight = jnp.where(jnp.asarray(distance < key_blend_frames), params.key_smoothing, filter_weight)
        planted = planted_feet(targets.position, params.plant_step)
        pinned = jnp.zeros((frames, 6), bool) if targets.pinned is None else targets.pinned
        pose = remove_flips(pose, params.spike_turn, at_key)
        # After a pass, a frame with a handle may have turned far from its neighbours (held near
        # their start poses, they weigh less than the handle): the next pass starts from a ramp into it.
        at_handle = at_key | jnp.any(pinned, axis=-1)
        near = _near_handles(pinned, params.handle_spread, pose.root_pos.dtype)

        def one_pass(pose: Pose, first: Array) -> tuple[Pose, None]:
            pose = jax.lax.cond(first, lambda q: q, lambda q: limit_turns(q, params.spike_turn, at_handle), pose)
            start = smooth(pose, filter_weight)
            if keys is not None:
                start = blend_to_chain_keys(start, keys, key_blend_frames)
            problems = jax.vmap(lambda s, t, h, p, n: _problem(params, s, t, h, p, n))(start, targets, hold, planted, near)
            return _solve(params, problems, params.iterations), None

        # The passes as a loop, not unrolled: the solve is traced and compiled once, not once a pass.
        pose, _ = jax.lax.scan(one_pass, pose, jnp.arange(params.window_passes) == 0)
        # Ramped into the keys as given (not the solve's frames there) and into the handles' frames.
        if keys is not None:
            pose = blend_to_chain_keys(pose, keys, 0)
        if keys is not None and key_blend_frames > 0:  # the keys joined: out of them no faster than key_turn
            pose = turn_out_of_keys(pose, distance, params.key_turn, params.finish_turn, key_blend_frames, at_handle)
        else:
            pose = limit_turns(pose, params.finish_turn, at_handle)
        return ExactIKResult(pose, *_errors(params.character, pose, targets))


def exact_settings(items: tuple[str, ...] | list[str], label: str = "exact setting") -> dict[str, float | int]:
    """``NAME=VALUE`` strings (e.g. from a command line) as :func:`exact_ik` keyword
    arguments: floats, ints for the static counts.

    Raises:
      ValueError: ``"{label} {item}: …"``, for a malformed item, an unknown NAME, a
        non-number, a fractional step count or a value out of the setting's range
        (:func:`exact_ik`'s checks).
    """
    fields = {f.name: f for f in dataclasses.fields(ExactIKParams)}
    settable = sorted(set(fields) - {"inner", "character", "limits"})
    settings: dict[str, float | int] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in settable:
            raise ValueError(f"{label} {item}: expected NAME=VALUE with NAME one of {settable}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"{label} {item}: {value!r} is not a number") from None
        if fields[name].metadata.get("static"):
            if not number.is_integer():
                raise ValueError(f"{label} {item}: {name} is a count, a whole number")
            number = int(number)
        problem = _setting_problem(name, number)
        if problem:
            raise ValueError(f"{label} {item}: {problem}")
        settings[name] = number
    return settings


def exact_ik(
    inner_fn: IKFn,
    inner_params: Any,
    character: Character,
    *,
    limits: JointLimits | None = None,
    **settings: Any,
) -> tuple[ExactIKFn, ExactIKParams]:
    """``(ik_fn, params)`` of the exact stage on top of ``inner_fn``.

    Args:
      inner_fn, inner_params: the IK whose pose the solve starts from (and stays near).
      character: the skeleton the inner IK poses.
      limits: soft joint limits (:func:`~bezmotion.ik.joint_limits.joint_limits_from_motion`, :meth:`JointLimits.load`);
        default none.
      settings: weights and step counts of :class:`ExactIKParams`.
    """
    limits = JointLimits.unlimited(character.num_joints) if limits is None else limits
    if limits.center.shape != (character.num_joints, 4):
        raise ValueError(f"joint limits for {limits.center.shape[0]} joints, the character has {character.num_joints}")
    unknown = set(settings) - {f.name for f in dataclasses.fields(ExactIKParams)} - {"inner", "character", "limits"}
    if unknown:
        raise ValueError(f"unknown exact IK settings {sorted(unknown)}")
    for name, value in settings.items():
        _check_setting(name, value)
    return ExactIKFn(inner_fn), ExactIKParams(inner_params, character, limits, **settings)


# Allowed ranges of the settings given as numbers, ``(low, high, low excluded)``; every other
# number setting is a weight, a threshold or a count, ≥ 0.
_SETTING_RANGES = {
    "max_turn": (0.0, np.inf, True),
    "smoothing": (0.0, 0.5, False),
    "key_smoothing": (0.0, 0.5, False),
    "handle_spread": (0.0, 1.0, False),
    "key_hold_decay": (0.0, 1.0, False),
    "window_passes": (1, np.inf, False),
}


def _check_setting(name: str, value: Any) -> None:
    """Raise ValueError, naming the setting and value, for a plain number out of its range (or
    NaN), or a non-integer step count; arrays (e.g. traced values) pass unchecked."""
    problem = _setting_problem(name, value)
    if problem:
        raise ValueError(f"exact IK setting {name}={value!r}: {problem}")


def _setting_problem(name: str, value: Any) -> str | None:
    """What is wrong with ``value`` for the setting ``name`` (None: nothing, or not a plain number)."""
    is_integer = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    static = next(f for f in dataclasses.fields(ExactIKParams) if f.name == name).metadata.get("static")
    if static and not is_integer:
        return "must be an integer"
    if not (is_integer or isinstance(value, (float, np.floating))):
        return None
    low, high, low_excluded = _SETTING_RANGES.get(name, (0, np.inf, False) if static else (0.0, np.inf, False))
    above_low = low < value if low_excluded else low <= value
    if not (above_low and value <= high):  # NaN fails both
        return f"must lie in {'(' if low_excluded else '['}{low}, {'∞)' if high == np.inf else f'{high}]'}"
    return None
