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

from bezmotion.data.characteristic import FEET
from bezmotion.diffusion.projection import on_control_frame

if TYPE_CHECKING:
    from bezmotion.bezier import BezierLayout
    from bezmotion.bmm.denoiser import Conditions

# X and Z; +Y is up. NumPy, not jnp: importing bezmotion must not start a JAX backend
# (jax.distributed.initialize has to come first when several processes train).
HORIZONTAL = np.asarray([True, False, True])


def lock_feet(
    ctrl_pos: Float[Array, "*batch controls joints 3"],
    ctrl_tangent: Float[Array, "*batch controls joints 3"],
    contacts: Float[Array, "*batch controls 2"],
    constrained: Bool[Array, "*batch controls joints"],
    *,
    threshold: float = 0.5,
    handles: Conditions | None = None,
    layout: BezierLayout | None = None,
) -> tuple[Float[Array, "*batch controls joints 3"], Float[Array, "*batch controls joints 3"]]:
    """Hold each foot still horizontally over every run of consecutive contact control points.

    For each foot (:data:`~bezmotion.data.characteristic.FEET`) and each maximal run of
    control points whose contact probability exceeds ``threshold``: the horizontal
    tangents become zero, and the horizontal positions move to the run's anchor — the
    mean of the run's constrained points when it has any, else the mean of the whole run.
    Constrained points (start, end, handles) never move, so handles stay exact; heights
    and all other joints are untouched.

    A foot's handle between two control frames (``handles``, off the ``layout``'s grid)
    whose two control points lie in one contact run counts as one of the run's constrained
    points: the run is planted where the handle puts the foot. Otherwise the run would be
    planted at its own mean, and the handle projection that follows
    (:func:`~bezmotion.diffusion.projection.project_off_grid`) would move the planted
    control points and their tangents back through the handle, sliding the foot.

    Args:
      ctrl_pos, ctrl_tangent: Bézier control points (cm).
      contacts: left/right foot contact probabilities at the control points.
      constrained: which control positions are conditions and must not change.
      threshold: contact probability above which a foot is planted.
      handles: ``(*batch, slots)`` conditions at any frame (positions in the curves' frame,
        cm); those on control frames are already in ``constrained`` and are skipped here.
      layout: the curves' layout (needed with ``handles``).
    Returns:
      ``(ctrl_pos, ctrl_tangent)``.
    """
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"threshold must be in (0, 1), got {threshold}")
    feet = jnp.asarray(FEET)
    planted = contacts > threshold  # (..., K, 2)
    fixed = constrained[..., feet]  # (..., K, 2)
    pos = ctrl_pos[..., feet, :]  # (..., K, 2, 3)
    starts = planted & ~jnp.concatenate([jnp.zeros_like(planted[..., :1, :]), planted[..., :-1, :]], axis=-2)
    run = jnp.cumsum(starts, axis=-2)
    # same[..., k, l, f]: control points k and l belong to the same contact run of foot f.
    same = planted[..., :, None, :] & planted[..., None, :, :] & (run[..., :, None, :] == run[..., None, :, :])
    run_has_fixed = jnp.any(same & fixed[..., None, :, :], axis=-2)  # (..., K, 2)
    if handles is not None:
        # member[..., k, h, f]: foot f's off-grid handle h lies inside control k's contact
        # run, and that run has no constrained control point (those already set it).
        member = _off_grid_members(handles, layout, planted, run, feet) & ~run_has_fixed[..., None, :]
        run_has_fixed = run_has_fixed | jnp.any(member, axis=-2)
    weight = (same & (fixed[..., None, :, :] | ~run_has_fixed[..., :, None, :])).astype(pos.dtype)
    total, count = jnp.einsum("...klf,...lfd->...kfd", weight, pos), weight.sum(axis=-2)
    if handles is not None:
        member = member.astype(pos.dtype)
        total = total + jnp.einsum("...khf,...hd->...kfd", member, handles.position)
        count = count + member.sum(axis=-2)
    anchor = total / jnp.maximum(count, 1.0)[..., None]
    move = (planted & ~fixed)[..., None] & HORIZONTAL
    new_pos = jnp.where(move, anchor, pos)
    new_tangent = jnp.where(planted[..., None] & HORIZONTAL, 0.0, ctrl_tangent[..., feet, :])
    return ctrl_pos.at[..., feet, :].set(new_pos), ctrl_tangent.at[..., feet, :].set(new_tangent)


def _off_grid_members(
    handles: Conditions, layout: BezierLayout | None, planted: Array, run: Array, feet: Array
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
