"""Filters over a window's frames: what the exact IK's window solve does to the poses it starts from.

A learned IK solves every frame on its own, so its poses jitter, and now and then one joint
flips for a frame (:func:`remove_spikes`) or for good (:func:`limit_turns`); :func:`remove_flips`
does both. The window solve (:meth:`bezmotion.ik.exact.ExactIKFn.solve_window`) takes those out,
then smooths the poses over time (:func:`smooth`) before each of its passes, and limits the
turns after its last; a per-frame IK's window gets :func:`remove_flips` in
:func:`~bezmotion.ik.protocol.solve_frames`, and slower turns out of the keys
(:func:`turn_out_of_keys`).
:func:`planted_feet` marks the frames whose foot targets stand still. Every function takes one
window ``(frames, …)``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bezmotion.data.characteristic import FEET
from bezmotion.data.windows import foot_contacts
from bezmotion.geometry.rotations import quat_angle, quat_normalize, slerp

if TYPE_CHECKING:  # protocol.solve_frames removes flips: no import cycle at run time
    from bezmotion.ik.protocol import Pose

# rad: the LaFAN1 mocap's largest turn of any joint in one frame (43°); a per-frame IK's turn
# beyond it is a flip (the default of remove_flips in solve_frames and of the exact IK's spike_turn).
FLIP_TURN = 0.75
# rad: a per-frame IK's largest turn of a joint on the step next to a key (solve_frames), easing to
# FLIP_TURN over the key blend's frames. Under both corpora's mocap key pops.
KEY_TURN = 0.4
_SLACK = 1e-4  # rad: a ramped step may measure this much over its limit after rounding; not ramped again
_SKIP_MARGIN = 1e-5  # rad: limit_turns skips its ramps only where every step is this far within its limit
_AGREE = 1e-4  # rad: two passes of limit_turns this close count as one where it splits a stretch
_HORIZONTAL = np.asarray([1.0, 0.0, 1.0], np.float32)  # X and Z; +Y is up


def planted_feet(position: Float[Array, "*batch frames 6 3"], plant_step: Float[Array, ""] | float) -> Array:
    """``(*batch, frames, 6)``: the feet whose targets move less than ``plant_step`` cm horizontally
    to the next frame or from the one before (both frames of a still step); hips, head and
    hands never.

    Both frames: the last frame of a foot's still run is still against the frame before it.
    Marked by the step to the next frame only, it would not be planted, and the exact IK, its
    foot weighing ``plant_weight`` on the frame before and 1 on it, would let the foot jump off
    its still target there: a one-frame slide at the end of a stance.

    Horizontally, like the foot-skating metric (:func:`~bezmotion.evaluation.metrics.foot_skating_ratio`)
    and the curves' foot lock (:func:`~bezmotion.bmm.foot_lock.lock_feet`, which holds X and Z
    only): a locked foot whose heel rises is still planted. Counting height too would leave
    unplanted many still feet at the frames where the exact IK skates most.
    """
    still_next = foot_contacts(position * _HORIZONTAL, FEET, threshold=jnp.square(plant_step))  # (…, frames, 2)
    still_before = jnp.concatenate([jnp.zeros_like(still_next[..., :1, :]), still_next[..., :-1, :]], axis=-2)
    contact = still_next | still_before
    return jnp.zeros(position.shape[:-1], bool).at[..., np.asarray(FEET)].set(contact)


def remove_spikes(pose: Pose, turn: Float[Array, ""] | float) -> Pose:
    """``pose`` ``(frames, …)`` with each joint's one-frame outliers replaced by its neighbours.

    A learned IK solves every frame on its own and now and then turns a joint far away for
    a single frame (an arm's twist flipped by 150° between two frames that agree). The
    temporal filter (:func:`smooth`) only halves such a spike, and the key hold then holds
    the frames next to a key at what is left of it: on LaFAN1 the exact IK's largest turn at
    a key came from exactly that (a learned-IK flip on the key frame or two frames before it).

    A joint's rotation at frame ``t`` is a spike when it lies more than ``turn`` (rad) from
    both neighbours while they lie less than half that distance from each other (a joint
    turning fast one way has its neighbours farther apart than either is from it); it
    becomes their midpoint. At the first and last frame the two frames inside the window are the
    neighbours and the nearer one replaces it. Windows under 3 frames and ``turn ≤ 0`` are
    left alone; the hips' position is never changed.
    """
    q = pose.quat_local
    if q.shape[0] < 3:
        return pose
    # Each frame's two neighbours; at the ends both lie inside the window (frames 1, 2 and T−2, T−3).
    a = jnp.concatenate([q[1:2], q[:-2], q[-2:-1]])
    b = jnp.concatenate([q[2:3], q[2:], q[-3:-2]])
    share = jnp.asarray([0.0] + [0.5] * (q.shape[0] - 2) + [0.0], q.dtype)[:, None, None]  # of b in the replacement
    b = jnp.where(jnp.sum(a * b, axis=-1, keepdims=True) < 0.0, -b, b)
    replacement = quat_normalize((1.0 - share) * a + share * b)
    away = jnp.minimum(quat_angle(q, a), quat_angle(q, b))
    spike = (away > turn) & (quat_angle(a, b) < 0.5 * away) & (turn > 0.0)
    return pose._replace(quat_local=jnp.where(spike[..., None], replacement, q))


def limit_turns(
    pose: Pose, turn: Float[Array, ""] | Float[Array, " steps"] | float, anchors: Bool[Array, " frames"] | None = None
) -> Pose:
    """``pose`` ``(frames, …)`` with no joint turning more than ``turn`` rad from one frame to
    the next, the frames at both ends of the window and the ``anchors`` ``(frames,)`` kept;
    ``turn`` is one limit, or one per step ``(steps,)`` = ``(frames − 1,)`` (step ``t``: frame ``t`` → ``t + 1``).

    A learned IK sometimes flips a joint for good rather than for one frame (an arm's twist
    by ~180° between two frames, where the curves' hand orientation lies far from any pose it
    learned): :func:`remove_spikes` keeps such a step, and the key hold then holds the frames
    next to the key on whichever side of it they lie. Here each joint's rotation follows the
    poses forwards from each kept frame, and again backwards from the next kept frame,
    moving at most ``turn`` a frame (a step becomes a ramp over as many frames as it needs).
    Between two kept frames the result takes the forward pass up to the frame where the two
    passes agree best (both back on the given poses), the backward pass after it: the ramp
    lies on the side of the step away from the nearer kept frame, and the frames next to each
    stay continuous with it; where that side is too short for the ramp, once more forwards
    and backwards spreads it over both sides. The window solve keeps its keys, and between
    its passes and after the last also the frames with a handle, so a bend that only the
    handle's frame made (the frames next to it held at their start) becomes a ramp into it.
    Between two kept frames, a joint that cannot turn within the limits along its poses (kept
    frames too close along a fast spin for a ramp) turns the shortest way from the one to the
    other instead, each step a share in proportion to its limit, where that fits the limits;
    else it keeps its poses there. Poses that never turn that
    fast are returned unchanged (bit for bit); ``turn ≤ 0`` turns it off (per step: that
    step); the hips' position is never changed.
    """
    q = pose.quat_local
    frames = q.shape[0]
    if frames < 3:
        return pose
    turns = jnp.broadcast_to(jnp.asarray(turn, q.dtype), (frames - 1,))
    ends = jnp.zeros(frames, bool).at[jnp.asarray([0, frames - 1])].set(True)
    kept = ends if anchors is None else ends | anchors
    # Most windows turn no joint that fast, and the ramps below (six loops over the frames)
    # would return them unchanged: skip them then. Steps within _SKIP_MARGIN of their limit,
    # either way round, take the ramps, so the skip never depends on rounding. (Under vmap both
    # branches run.)
    limit = turns[:, None] - _SKIP_MARGIN
    fast = (turns[:, None] > 0.0) & ((quat_angle(q[:-1], q[1:]) > limit) | (quat_angle(q[1:], q[:-1]) > limit))
    return jax.lax.cond(jnp.any(fast), lambda: pose._replace(quat_local=_ramped(q, turns, kept)), lambda: pose)


def _ramped(q: Array, turns: Array, kept: Array) -> Array:
    """:func:`limit_turns`' ramps: ``q`` ``(frames, joints, 4)`` turning at most ``turns``
    ``(frames − 1,)`` a step, the frames where ``kept`` ``(frames,)`` kept."""
    frames = q.shape[0]

    def follow(sequence: Array, keep: Array, limit: Array, slack: float = 0.0) -> Array:
        def step(previous, inputs):  # quat_angle and slerp take either sign of current
            current, restart, turn = inputs
            angle = quat_angle(previous, current)[..., None]
            limited = (turn > 0.0) & (angle > turn + slack) & ~restart
            fraction = jnp.where(limited, turn / jnp.where(limited, angle, 1.0), 1.0)
            moved = jnp.where(limited, slerp(previous, current, fraction[..., 0]), current)
            return moved, moved

        _, rest = jax.lax.scan(step, sequence[0], (sequence[1:], keep[1:], limit))
        return jnp.concatenate([sequence[:1], rest])

    forward, backward = follow(q, kept, turns), follow(q[::-1], kept[::-1], turns[::-1])[::-1]
    # Per joint and stretch between kept frames, the frame where the passes lie closest
    # (ties: the one nearest the stretch's middle); the kept frames never.
    index = jnp.arange(frames)
    before = jax.lax.cummax(jnp.where(kept, index, 0))  # the kept frame at or before t
    after = jax.lax.cummin(jnp.where(kept, index, frames - 1), reverse=True)  # at or after t
    middle = jnp.abs(index - 0.5 * (before + after)) / frames
    # Passes within _AGREE of each other agree: where both are back on the poses on either side
    # of a fast stretch, their float rounding must not choose the side (a cm clip and the same in
    # metres, or the same window compiled otherwise, put a ramp on opposite sides of a stretch
    # centred in its window: an elbow 25 cm apart). Equal distances from the middle go to the
    # earlier frame.
    apart = quat_angle(forward, backward)
    apart = jnp.where(apart < _AGREE, 0.0, apart)
    score = apart + (1e-3 * middle + 1e-6 * index / frames).astype(q.dtype)[:, None]
    score = jnp.where(kept[:, None], jnp.inf, score)
    # t lies before its stretch's split when the lowest score so far in the stretch is above
    # the lowest still to come in it (the split is the first lowest; kept frames score ∞, so
    # the running minima start afresh at them).
    so_far = _running_min(score, kept, reverse=False)
    to_come = jnp.concatenate([_running_min(score, kept, reverse=True)[1:], jnp.full_like(score[:1], jnp.inf)])
    take_forward = so_far > to_come
    limited = jnp.where(take_forward[..., None], forward, backward)
    limited = jnp.where(kept[:, None, None], q, limited)
    # The split ramps each step from one side only; a step too large for the frames on that side
    # (149° three frames from each kept frame, at 43° a frame) leaves the rest at the split. Once
    # more forwards and then backwards over the result, each from its kept frames, spreads it over
    # both sides; steps already within their limit (to rounding) are left as they are.
    limited = follow(limited, kept, turns, _SLACK)
    limited = follow(limited[::-1], kept[::-1], turns[::-1], _SLACK)[::-1]
    # Where two kept frames lie too far apart along the poses' path for the frames between to
    # ramp at the limits (a joint spinning fast between a key and a handle), the passes cannot
    # meet and the rest falls on one step, often one with a tight limit (next to a key). Such a
    # joint turns the shortest way from the one kept frame to the other instead, each step a
    # share of that turn in proportion to its limit, where that fits within every step's limit:
    # the long way round is an IK's twist following curves whose orientations spin (the
    # Bandai-Namco BMM's on LaFAN1's falls turned an upper arm 260° in the six frames between a
    # handle and a key), not motion (the mocap's joints turn at most 43° a frame). Where even the
    # shortest way does not fit, the joint keeps its poses there (the kept frames are the same in all).
    steps_over = (turns[:, None] > 0.0) & (quat_angle(limited[:-1], limited[1:]) > turns[:, None] + 2.0 * _SLACK)
    failed = jax.ops.segment_max(steps_over.astype(jnp.int32), before[:-1], num_segments=frames) > 0  # (stretch, joints)
    shortest, fits = _shortest_ramps(q, turns, before, after)
    fallback = jnp.where(fits[:, :, None], shortest, q)
    limited = jnp.where(failed[before][:, :, None], fallback, limited)
    # Unchanged frames keep their own quaternion (not slerp's sign of it): a no-op stays exact.
    same = jnp.abs(jnp.sum(limited * q, axis=-1, keepdims=True)) >= 1.0 - 1e-7
    return jnp.where(same, q, limited)


def remove_flips(pose: Pose, turn: Float[Array, ""] | float = FLIP_TURN, anchors: Bool[Array, " frames"] | None = None) -> Pose:
    """``pose`` ``(frames, …)`` with one-frame flips replaced by their neighbours
    (:func:`remove_spikes`) and lasting ones ramped at most ``turn`` rad a frame
    (:func:`limit_turns`, the window's ends and ``anchors`` kept); ``turn ≤ 0``: unchanged."""
    return limit_turns(remove_spikes(pose, turn), turn, anchors)


def turns_near_keys(
    distance: np.ndarray, key_turn: Float[Array, ""] | float, turn: Float[Array, ""] | float, frames: int
) -> Float[Array, " steps"]:
    """``(frames − 1,)`` per-step turn limits for :func:`limit_turns`: ``key_turn`` rad on the
    steps that touch a key (``distance`` ``(frames,)``: each frame's distance to the nearest
    key, 0 at the keys), easing linearly to ``turn`` over ``frames`` frames from it;
    ``turn ≤ 0``: the other steps unlimited; ``key_turn ≤ 0``: ``turn`` on every step."""
    step_distance = np.minimum(distance[:-1], distance[1:])
    share = jnp.asarray(np.minimum(step_distance / max(frames, 1), 1.0), jnp.float32)
    eased = key_turn + (turn - key_turn) * share
    eased = jnp.where(turn <= 0.0, jnp.where(jnp.asarray(step_distance == 0), key_turn, 0.0), eased)
    return jnp.where(key_turn <= 0.0, jnp.broadcast_to(jnp.asarray(turn, eased.dtype), eased.shape), eased)


def turn_out_of_keys(
    pose: Pose,
    distance: np.ndarray,
    key_turn: Float[Array, ""] | float,
    turn: Float[Array, ""] | float,
    frames: int,
    anchors: Bool[Array, " frames"],
) -> Pose:
    """``pose`` ``(frames, …)`` (the keys joined) turning each joint at most ``key_turn`` rad on
    the steps out of a key, easing to ``turn`` over ``frames`` frames from it
    (:func:`turns_near_keys`; ``distance`` ``(frames,)``: each frame's distance to the nearest
    key), at most ``turn`` elsewhere (:func:`limit_turns`); the keys' frames and ``anchors`` kept.

    A joint that cannot leave a key that slowly (it spins fast up to the next kept frame, so
    :func:`limit_turns` leaves it alone there) keeps its step out of the key, and the rest is
    ramped at ``turn`` where it can: ramped at ``turn`` alone, the excess could land on the
    step out of the key and pop it.

    Raises:
      ValueError: naming the shapes, when ``distance`` is not one value per frame.
    """
    if np.shape(distance) != pose.root_pos.shape[:1]:
        raise ValueError(f"distance must be one value per frame, {pose.root_pos.shape[:1]}, got {np.shape(distance)}")
    kept = anchors | jnp.asarray(distance == 0)
    pose = limit_turns(pose, turns_near_keys(distance, key_turn, turn, frames), kept)
    return limit_turns(pose, turn, kept | jnp.asarray(distance == 1))


def _shortest_ramps(q: Array, turns: Array, before: Array, after: Array) -> tuple[Array, Array]:
    """``(ramps, fits)``: every joint of ``q`` ``(frames, joints, 4)`` turning the shortest way
    from the kept frame at or before each frame (``before`` ``(frames,)``) to the one at or after
    it (``after``), each step ``(frames − 1,)`` turning a share of that turn in proportion to its
    limit (``turns``; π for an unlimited step), and ``(frames, joints)`` whether that keeps every
    step of the stretch within its limit (the shortest turn ≤ the sum of the stretch's limits)."""
    weight = jnp.where(turns > 0.0, turns, jnp.pi)
    reach = jnp.concatenate([jnp.zeros(1, turns.dtype), jnp.cumsum(weight)])  # (frames,): the limits summed up to each frame
    budget = reach[after] - reach[before]  # (frames,): the stretch's limits summed
    fraction = (reach - reach[before]) / jnp.where(budget > 0.0, budget, 1.0)
    start, end = q[before], q[after]
    ramps = slerp(start, end, jnp.broadcast_to(fraction[:, None], q.shape[:2]))
    fits = quat_angle(start, end) <= budget[:, None] + _SLACK
    return ramps, fits


def _running_min(values: Array, restart: Array, reverse: bool) -> Array:
    """``values`` ``(frames, …)``' running minimum over frames, starting afresh at each frame
    where ``restart`` ``(frames,)`` (from the last frame backwards when ``reverse``)."""

    def step(low, inputs):
        value, fresh = inputs
        low = jnp.where(fresh, value, jnp.minimum(low, value))
        return low, low

    xs = (values[::-1], restart[::-1]) if reverse else (values, restart)
    _, out = jax.lax.scan(step, jnp.full_like(values[0], jnp.inf), xs)
    return out[::-1] if reverse else out


def smooth(pose: Pose, weight: Float[Array, " frames"] | Float[Array, ""] | float) -> Pose:
    """``pose`` ``(frames, …)`` filtered over time by ``[w, 1 − 2w, w]``, ``w = weight`` (0 … 0.5;
    one for every frame, or ``(frames,)``: each frame's own).

    Each frame's local rotations (its neighbours' turned to its hemisphere, the sum
    normalised) and the hips' position are averaged with the neighbouring frames'. At the
    window's ends the missing neighbour is the frame itself, so it keeps ``1 − w``.
    """
    w = jnp.broadcast_to(jnp.asarray(weight, pose.root_pos.dtype), pose.root_pos.shape[:1])  # (frames,)
    q = pose.quat_local
    prev = jnp.concatenate([q[:1], q[:-1]])
    nxt = jnp.concatenate([q[1:], q[-1:]])
    align = lambda a: jnp.where(jnp.sum(a * q, axis=-1, keepdims=True) < 0.0, -a, a)  # noqa: E731
    wq = w[:, None, None]  # over joints and quaternion components
    quat = quat_normalize((1.0 - 2.0 * wq) * q + wq * (align(prev) + align(nxt)))
    r, wr = pose.root_pos, w[:, None]
    root = (1.0 - 2.0 * wr) * r + wr * (jnp.concatenate([r[:1], r[:-1]]) + jnp.concatenate([r[1:], r[-1:]]))
    return pose._replace(root_pos=root, quat_local=quat)
