"""Foot locking on Bézier control points: pin a foot in the ground plane while the model
says it is in contact (an optional clean-up after sampling; BMM itself has none).

Why: the foot-skating ratio counts frames where both feet are within 5 cm of the floor
and both move faster than 7.5 cm/s, i.e. 0.25 cm per frame at 30 fps. Half a centimetre
of noise on the ground-truth control positions of LaFAN1 subject 5 already raises the
ratio from 0.055 to 0.068, so a sampled curve skates unless its planted feet are still
to a fraction of a centimetre — which the contact labels BMM predicts can enforce.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bezmotion.data.characteristic import FEET

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
) -> tuple[Float[Array, "*batch controls joints 3"], Float[Array, "*batch controls joints 3"]]:
    """Hold each foot still horizontally over every run of consecutive contact control points.

    For each foot (:data:`~bezmotion.data.characteristic.FEET`) and each maximal run of
    control points whose contact probability exceeds ``threshold``: the horizontal
    tangents become zero, and the horizontal positions move to the run's anchor — the
    mean of the run's constrained points when it has any, else the mean of the whole run.
    Constrained points (start, end, handles) never move, so handles stay exact; heights
    and all other joints are untouched.

    Args:
      ctrl_pos, ctrl_tangent: Bézier control points (cm).
      contacts: left/right foot contact probabilities at the control points.
      constrained: which control positions are conditions and must not change.
      threshold: contact probability above which a foot is planted.
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
    weight = (same & (fixed[..., None, :, :] | ~run_has_fixed[..., :, None, :])).astype(pos.dtype)
    anchor = jnp.einsum("...klf,...lfd->...kfd", weight, pos) / jnp.maximum(weight.sum(axis=-2), 1.0)[..., None]
    move = (planted & ~fixed)[..., None] & HORIZONTAL
    new_pos = jnp.where(move, anchor, pos)
    new_tangent = jnp.where(planted[..., None] & HORIZONTAL, 0.0, ctrl_tangent[..., feet, :])
    return ctrl_pos.at[..., feet, :].set(new_pos), ctrl_tangent.at[..., feet, :].set(new_tangent)
