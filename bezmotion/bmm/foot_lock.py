"""Foot locking on Bézier control points: pin a foot in the ground plane while the model
says it is in contact (an optional clean-up after sampling; BMM itself has none).

Why: the foot-skating ratio counts frames where both feet are within 5 cm of the floor
and both move faster than 7.5 cm/s, i.e. 0.25 cm per frame at 30 fps. Half a centimetre
of noise on the ground-truth control positions of LaFAN1 subject 5 already raises the
ratio from 0.055 to 0.068, so a sampled curve skates unless its planted feet are still
to a fraction of a centimetre — which the contact labels BMM predicts can enforce.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bezmotion.data.characteristic import FEET, HIPS
from bezmotion.diffusion.projection import on_control_frame

if TYPE_CHECKING:
    from bezmotion.bezier import BezierLayout
    from bezmotion.handles import Handles

# X and Z; +Y is up. NumPy, not jnp: importing bezmotion must not start a JAX backend
# (jax.distributed.initialize has to come first when several processes train).
HORIZONTAL = np.asarray([True, False, True])
ANCHORS = ("nearest", "mean")
"""Where a planted run's control points are held (:func:`lock_feet`'s ``anchor``); the first is the default."""
MAX_STRETCH = 1.1
"""How much farther from the hips than the curves ever put a foot in the window a held foot may stand
(:func:`lock_feet`). 10 %: the lock holds a foot back by the few centimetres its curve slides, never
by a stride."""


def lock_anchor(foot_lock: bool | str) -> str | None:
    """The anchor a sampler's ``foot_lock`` asks for: ``None`` for no lock (``False``), the
    default (:data:`ANCHORS`' first) for ``True``, else the name itself, checked."""
    if foot_lock is False or foot_lock is None:
        return None
    if foot_lock is True:
        return ANCHORS[0]
    if foot_lock not in ANCHORS:
        raise ValueError(f"foot_lock must be True, False or one of {ANCHORS}, got {foot_lock!r}")
    return foot_lock


def lock_feet(
    ctrl_pos: Float[Array, "*batch controls joints 3"],
    ctrl_tangent: Float[Array, "*batch controls joints 3"],
    contacts: Float[Array, "*batch controls 2"],
    constrained: Bool[Array, "*batch controls joints"],
    *,
    threshold: float = 0.5,
    handles: Handles | None = None,
    layout: BezierLayout | None = None,
    anchor: str = ANCHORS[0],
    max_stretch: float | None = MAX_STRETCH,
) -> tuple[Float[Array, "*batch controls joints 3"], Float[Array, "*batch controls joints 3"]]:
    """Hold each foot still horizontally over every run of consecutive contact control points.

    For each foot (:data:`~bezmotion.data.characteristic.FEET`) and each maximal run of
    control points whose contact probability exceeds ``threshold``: the horizontal
    tangents become zero, and each unconstrained point's horizontal position moves to its
    anchor. Constrained points (start, end, handles) never move, so handles stay exact;
    heights and all other joints are untouched.

    ``anchor="nearest"`` (the default): where the run's constrained point nearest in time
    puts the foot (equally near ones: their mean), or, in a run without one, the mean of
    the whole run. A run whose conditions put the foot in two places (a key here, a key or
    a handle there) then steps once, between control points, from one to the other.
    ``anchor="mean"``: the mean of the run's constrained points.
    That holds such a run at a place between them, so the foot leaves each condition and
    reaches the next with zero horizontal velocity at every control point on the way: a
    stop-and-go inside the window and, at a key two windows of a chain share, a velocity jump.

    A foot's handle between two control frames (``handles``, off the ``layout``'s grid)
    whose two control points lie in one contact run counts as one of the run's constrained
    points, at its own frame: the run is planted where the handle puts the foot. Otherwise the
    run would be planted elsewhere, and the handle projection that follows
    (:func:`~bezmotion.diffusion.projection.project_off_grid`) would move the planted
    control points and their tangents back through the handle, sliding the foot. (With
    ``"mean"`` it counts only in a run with no constrained control point.)

    A held foot must stay within reach of the hips: a planted control point whose anchor lies
    farther from the hips than ``max_stretch`` times the farthest the curves themselves put
    that foot from the hips in the window (at any control point, keys included) keeps its own
    position and tangent. A contact predicted for too long (a foot "planted" for a second
    while the body walks on) would otherwise hold the foot behind, out of the leg's reach,
    and the IK would drag the body back to it.

    Args:
      ctrl_pos, ctrl_tangent: Bézier control points (cm).
      contacts: left/right foot contact probabilities at the control points.
      constrained: which control positions are conditions and must not change.
      threshold: contact probability above which a foot is planted.
      handles: ``(*batch, slots)`` conditions at any frame (positions in the curves' frame,
        cm); those on control frames are already in ``constrained`` and are skipped here.
      layout: the curves' layout (needed with ``handles``).
      anchor: ``"nearest"`` or ``"mean"`` (:data:`ANCHORS`), above.
      max_stretch: the reach limit above, a factor ≥ 1; ``None``: no limit.
    Returns:
      ``(ctrl_pos, ctrl_tangent)``.
    """
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"threshold must be in (0, 1), got {threshold}")
    if anchor not in ANCHORS:
        raise ValueError(f"anchor must be one of {ANCHORS}, got {anchor!r}")
    if max_stretch is not None and not max_stretch >= 1.0:
        raise ValueError(f"max_stretch must be a factor of at least 1 (or None), got {max_stretch!r}")
    feet = jnp.asarray(FEET)
    planted = contacts > threshold  # (..., K, 2)
    fixed = constrained[..., feet]  # (..., K, 2)
    pos = ctrl_pos[..., feet, :]  # (..., K, 2, 3)
    starts = planted & ~jnp.concatenate([jnp.zeros_like(planted[..., :1, :]), planted[..., :-1, :]], axis=-2)
    run = jnp.cumsum(starts, axis=-2)
    # same[..., k, l, f]: control points k and l belong to the same contact run of foot f.
    same = planted[..., :, None, :] & planted[..., None, :, :] & (run[..., :, None, :] == run[..., None, :, :])
    fixed_in_run = same & fixed[..., None, :, :]  # [..., k, l, f]: l is constrained and in k's run
    # member[..., k, h, f]: foot f's off-grid handle h lies inside control k's contact run.
    member = None if handles is None else _off_grid_members(handles, layout, planted, run, feet)
    if anchor == "nearest":
        when = None if handles is None else handles.frame / layout.stride  # (..., H), in control points
        weight, member = _nearest_weights(fixed_in_run, same, member, when)
    else:
        weight, member = _mean_weights(fixed_in_run, same, member)
    weight = weight.astype(pos.dtype)
    total, count = jnp.einsum("...klf,...lfd->...kfd", weight, pos), weight.sum(axis=-2)
    if member is not None:
        member = member.astype(pos.dtype)
        # Padding slots hold anything, NaN too, and 0 × NaN is NaN: they enter as zeros.
        held_at = jnp.where(handles.valid[..., None], handles.position, 0.0)
        total = total + jnp.einsum("...khf,...hd->...kfd", member, held_at)
        count = count + member.sum(axis=-2)
    target = total / jnp.maximum(count, 1.0)[..., None]
    move = (planted & ~fixed)[..., None] & HORIZONTAL
    new_pos = jnp.where(move, target, pos)
    tangent = ctrl_tangent[..., feet, :]
    new_tangent = jnp.where(planted[..., None] & HORIZONTAL, 0.0, tangent)
    if max_stretch is not None:
        hips = ctrl_pos[..., HIPS, None, :]  # (..., K, 1, 3)
        reach = jnp.linalg.norm(pos - hips, axis=-1).max(axis=-2, keepdims=True)  # (..., 1, 2): the curves' own
        beyond = (planted & ~fixed) & (jnp.linalg.norm(new_pos - hips, axis=-1) > max_stretch * reach)
        new_pos = jnp.where(beyond[..., None], pos, new_pos)
        new_tangent = jnp.where(beyond[..., None], tangent, new_tangent)
    return ctrl_pos.at[..., feet, :].set(new_pos), ctrl_tangent.at[..., feet, :].set(new_tangent)


def _nearest_weights(
    fixed_in_run: Array, same: Array, member: Array | None, when: Array | None
) -> tuple[Bool[Array, "*batch controls controls 2"], Bool[Array, "*batch controls handles 2"] | None]:
    """``anchor="nearest"``: which constrained control points (``[..., k, l, f]``) and
    off-grid handles (``[..., k, h, f]``, at control-point times ``when``) control point ``k``
    is held at: those of its run nearest to it in time, equally near ones together; a run
    without any, at all of its points (its mean)."""
    k = jnp.arange(fixed_in_run.shape[-2])
    far = jnp.inf
    gap = jnp.where(fixed_in_run, jnp.abs(k[:, None] - k[None, :])[:, :, None], far)
    nearest = gap.min(axis=-2)  # (..., K, 2)
    if member is not None:
        gap_handles = jnp.where(member, jnp.abs(k[:, None] - when[..., None, :])[..., None], far)
        nearest = jnp.minimum(nearest, gap_handles.min(axis=-2))
        member = member & (gap_handles == nearest[..., None, :])
    free = jnp.isinf(nearest)  # no condition in the run
    return (fixed_in_run & (gap == nearest[..., None, :])) | (same & free[..., :, None, :]), member


def _mean_weights(
    fixed_in_run: Array, same: Array, member: Array | None
) -> tuple[Bool[Array, "*batch controls controls 2"], Bool[Array, "*batch controls handles 2"] | None]:
    """``anchor="mean"``: the run's constrained control points; its off-grid handles only
    where it has none of those; a run with neither, all of its points."""
    has_fixed = jnp.any(fixed_in_run, axis=-2)  # (..., K, 2)
    if member is not None:
        member = member & ~has_fixed[..., None, :]
        has_fixed = has_fixed | jnp.any(member, axis=-2)
    return fixed_in_run | (same & ~has_fixed[..., :, None, :]), member


def _off_grid_members(
    handles: Handles, layout: BezierLayout | None, planted: Array, run: Array, feet: Array
) -> Bool[Array, "*batch controls handles 2"]:
    """``member[..., k, h, f]``: handle ``h`` is foot ``f``'s, off the control grid, both
    control points around its frame are planted in one run, and control ``k`` is in that run."""
    if layout is None:
        raise ValueError("lock_feet: handles need the curves' layout")
    on_grid, after = on_control_frame(layout, handles.frame)  # after: the control point after the frame
    before = jnp.clip(after - 1, 0, layout.num_controls - 1)
    gather = lambda a, c: jnp.take_along_axis(a, jnp.broadcast_to(c[..., None], (*c.shape, 2)), axis=-2)  # noqa: E731
    run_before = gather(run, before)  # (..., H, 2)
    inside = gather(planted, before) & gather(planted, after) & (run_before == gather(run, after))
    own = (handles.valid & ~on_grid)[..., None] & (handles.joint[..., None] == feet)  # (..., H, 2)
    held = own & inside
    return held[..., None, :, :] & planted[..., :, None, :] & (run[..., :, None, :] == run_before[..., None, :, :])
