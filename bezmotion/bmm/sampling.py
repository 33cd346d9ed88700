"""Sampling Bézier motion curves from a trained BMM: key positions and sparse handles in,
curves that pass through every handle out (BMM §4.2, Appendix A.3).

:func:`sample_chained_curves` is pure and jit-compiled once per input shape: the windows
between consecutive key poses in one batched DDIM loop, by default joined at their shared
keys (the two windows' tangents, orientations and contacts there averaged in the same
overwrite), so the curves are C¹ across the keys; independent windows (BMM Appendix D.1)
for comparison. :func:`sample_curves` is the same for two keys (one window). Leading batch
axes on the inputs sample several motions at once, each with its own key.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float

from bezmotion._src.xla_options import inference_jit
from bezmotion.training.checkpoint import cast_floating, open_model_folder, save_model_folder
from bezmotion.data.characteristic import HIPS
from bezmotion.bezier import BezierLayout
from bezmotion.diffusion.ddim import ddim_sample
from bezmotion.diffusion.projection import CurveMetric, curve_metric, project_off_grid
from bezmotion.bmm.foot_lock import lock_anchor, lock_feet
from bezmotion.diffusion.schedule import cosine_schedule
from bezmotion.bmm.denoiser import BMMConfig, init_denoiser
from bezmotion._src.problems import Problem, raised_in_program
from bezmotion.handles import Handles, grid_conditions, handle_problems, straight_line
from bezmotion.bmm.features import (
    FeatureStats,
    from_tokens,
    inbetween_conditions,
    normalize_conditions,
    predict_x0,
    split_features,
    to_tokens,
)


@functools.partial(
    jax.tree_util.register_dataclass, data_fields=("params", "stats"), meta_fields=("graphdef", "config")
)
@dataclasses.dataclass(frozen=True)
class BezierMotionModel:
    """A trained BMM: parameters and normalisation (arrays) plus structure (static)."""

    params: nnx.State
    stats: FeatureStats
    graphdef: nnx.GraphDef
    config: BMMConfig


class SampledCurves(NamedTuple):
    """BMM output for one motion (world frame, cm), joints in ``CHARACTERISTIC_JOINTS`` order.

    Attributes:
      ctrl_pos, ctrl_tangent: ``(*batch, controls, 6, 3)`` Bézier control points.
      ctrl_rot6d: ``(*batch, controls, 6, 6)`` global orientations at control points.
      contacts: ``(*batch, controls, 2)`` left/right foot-contact probabilities.
    """

    ctrl_pos: Float[Array, "*batch controls joints 3"]
    ctrl_tangent: Float[Array, "*batch controls joints 3"]
    ctrl_rot6d: Float[Array, "*batch controls joints 6"]
    contacts: Float[Array, "*batch controls 2"]


class _Chain(NamedTuple):
    """Where a window sits in a chain: ``jax.vmap`` over the chain's ``size`` windows runs
    under the axis name ``axis``, so each window can read its neighbours' boundaries."""

    axis: str
    size: int


def share_boundaries(x: Float[Array, "windows controls ..."]) -> Float[Array, "windows controls ..."]:
    """A chain's per-window control values with every shared key's set to the mean of its
    two windows' (window ``i``'s last and window ``i + 1``'s first). The chain's own first
    and last keys have no neighbour and keep theirs; both sides get the same bits."""
    mean = 0.5 * (x[:-1, -1] + x[1:, 0])
    return x.at[:-1, -1].set(mean).at[1:, 0].set(mean)


def shared_key_mask(windows: int, num_controls: int, num_joints: int) -> Bool[Array, "windows controls joints"]:
    """The control points a window shares with a neighbour in a chain of ``windows``: its
    first unless it starts the chain, its last unless it ends it (every joint)."""
    rows = jnp.zeros((windows, num_controls), bool).at[1:, 0].set(True).at[:-1, -1].set(True)
    return jnp.broadcast_to(rows[:, :, None], (windows, num_controls, num_joints))


def _couple(x: Float[Array, "controls ..."], chain: _Chain) -> Float[Array, "controls ..."]:
    """:func:`share_boundaries` seen from one window, inside ``jax.vmap`` over ``chain.axis``."""
    return share_boundaries(jax.lax.all_gather(x, chain.axis))[jax.lax.axis_index(chain.axis)]


def _shared_keys(chain: _Chain, num_controls: int, num_joints: int) -> Bool[Array, "controls joints"]:
    """:func:`shared_key_mask` of this window, inside ``jax.vmap`` over ``chain.axis``."""
    return shared_key_mask(chain.size, num_controls, num_joints)[jax.lax.axis_index(chain.axis)]


def _projector(
    layout: BezierLayout,
    conditions: Handles,
    fixed: Bool[Array, "controls joints"],
    fixed_tangent: Bool[Array, "controls joints"] | None,
    chain: _Chain | None,
    *,
    pos_std: Float[ArrayLike, "joints 3"] | float = 1.0,
    tangent_std: Float[ArrayLike, "joints 3"] | float = 1.0,
):
    """``project(ctrl_pos, ctrl_tangent, target, pos_mean=0, tangent_mean=0)``: one window's
    curves through ``conditions`` (:func:`~bezmotion.diffusion.projection.project_off_grid`,
    the variables ``(P − pos_mean) / pos_std`` and ``(T − tangent_mean) / tangent_std``, the
    targets ``target``), with what stays the same from call to call (the sampler's every DDIM
    step) worked out once, here.

    In a coupled chain (inside ``jax.vmap`` over ``chain.axis``) the windows' curves are
    joined into one, a shared key's control point counted once: its position is a key (fixed),
    its tangent one variable of both windows. A joint with a handle within a stride of a
    shared key is met over the chain, its shared tangents free (moved in both windows alike),
    by the smallest change of its curve (:func:`~bezmotion.diffusion.projection.curve_metric`).
    Projected window by window with the shared tangent held, a handle one frame from a shared
    key could move only the next control point, whose weight there is small, and the curve
    would swing far out. The curve's change rather than the model's normalised variables', because in those the next control
    point's position is the cheap variable (its scale is ten times the tangent's): a window
    alone has the model's own tangent, chosen with the handle in view, but a chain's shared one
    is the mean of two windows' that each saw half the handles. Every other joint keeps its
    shared tangents and the variables' metric (what window by window gives). ``fixed_tangent``:
    tangents that stay as they are in any case (a key's given velocity). Returned curves: the
    window's fixed positions bit for bit, a shared tangent the same bits in both windows.
    """
    k, j = fixed.shape

    def scales(dtype, *values):  # each a (joints, 3) array (the projection's type hints want arrays)
        return (jnp.broadcast_to(jnp.asarray(v, dtype), (j, 3)) for v in values)

    if chain is None:
        def project(ctrl_pos, ctrl_tangent, target, pos_mean=0.0, tangent_mean=0.0):
            p_mean, p_std, t_mean, t_std = scales(ctrl_pos.dtype, pos_mean, pos_std, tangent_mean, tangent_std)
            return project_off_grid(
                layout, ctrl_pos, ctrl_tangent, fixed, conditions._replace(position=target),
                pos_mean=p_mean, pos_std=p_std, tangent_mean=t_mean, tangent_std=t_std, fixed_tangent=fixed_tangent,
            )  # fmt: skip

        return project
    step = k - 1  # a window adds this many control points to the chain
    whole = BezierLayout.from_controls(chain.size * step + 1, layout.stride)
    fixed_tangent = jnp.zeros_like(fixed) if fixed_tangent is None else fixed_tangent

    def gather(x):
        return jax.lax.all_gather(x, chain.axis)

    def join(x):  # (windows, k, ...) → (windows·step + 1, ...): window i's last point is window i + 1's first
        return jnp.concatenate([x[0], x[1:, 1:].reshape(-1, *x.shape[2:])])

    held, held_tangent = join(gather(fixed)), join(gather(fixed_tangent))
    joint, valid = gather(conditions.joint).reshape(-1), gather(conditions.valid).reshape(-1)
    frame = (gather(conditions.frame) + (jnp.arange(chain.size) * step * layout.stride)[:, None]).reshape(-1)  # the chain's frames
    chain_conditions = Handles(joint, frame, None, valid)  # positions: each call's targets
    near = gather(handles_next_to_keys(conditions, k, j, layout.stride, num_frames=layout.num_frames))  # (windows, 2, J)
    over_chain = jnp.any(near[:-1, 1] | near[1:, 0], axis=0)  # (J,)
    shared = jnp.zeros(whole.num_controls, bool).at[jnp.arange(1, chain.size) * step].set(True)
    held_tangent = held_tangent | (shared[:, None] & ~over_chain[None, :])
    # Where no joint is met over the chain (most chains: no handle next to a shared key), the
    # joined problem falls apart into the windows' own, each with its shared tangents held:
    # each window solves its own (the same result to rounding) rather than every window
    # solving the whole chain, whose cost grows with the chain's length.
    # `over_chain` comes from `all_gather`, one value for the whole chain, so the branch is
    # a real `lax.cond`, not a select (only under a further `vmap`, a batch of chains,
    # do both run).
    anywhere = jnp.any(over_chain)
    alone = _projector(layout, conditions, fixed, fixed_tangent | _shared_keys(chain, k, j), None, pos_std=pos_std, tangent_std=tangent_std)

    def make_metric():  # loop-invariant: made once per sample, and only where some joint needs it
        return curve_metric(whole, held, *scales(jnp.float32, pos_std, tangent_std), held_tangent).inverse

    # The chain's solve measures every joint by the curve; the joints not met over the chain
    # then take their window's own solve (`alone`), the variables' metric.
    metric = CurveMetric(jax.lax.cond(anywhere, make_metric, lambda: jnp.zeros(jax.eval_shape(make_metric).shape, jnp.float32)))
    mine = functools.partial(jax.lax.dynamic_slice_in_dim, start_index=jax.lax.axis_index(chain.axis) * step, slice_size=k)

    def project(ctrl_pos, ctrl_tangent, target, pos_mean=0.0, tangent_mean=0.0):
        def over_the_chain():
            p_mean, p_std, t_mean, t_std = scales(ctrl_pos.dtype, pos_mean, pos_std, tangent_mean, tangent_std)
            offsets = join(jnp.broadcast_to(gather(p_mean)[:, None], (chain.size, k, j, 3)))  # each window's own
            pos, tangent = project_off_grid(
                whole, join(gather(ctrl_pos)), join(gather(ctrl_tangent)), held, chain_conditions._replace(position=gather(target).reshape(-1, 3)),
                pos_mean=offsets, pos_std=p_std, tangent_mean=t_mean, tangent_std=t_std, fixed_tangent=held_tangent, metric=metric,
            )  # fmt: skip
            # A shared key's position comes from the window before in the joined curve (in its frame): this window's own.
            pos, tangent = jnp.where(fixed[..., None], ctrl_pos, mine(pos)), mine(tangent)
            own_pos, own_tangent = alone(ctrl_pos, ctrl_tangent, target, pos_mean, tangent_mean)
            return jnp.where(over_chain[:, None], pos, own_pos), jnp.where(over_chain[:, None], tangent, own_tangent)

        return jax.lax.cond(anywhere, over_the_chain, lambda: alone(ctrl_pos, ctrl_tangent, target, pos_mean, tangent_mean))

    return project


def held_key_tangents(
    handles: Handles, num_controls: int, num_joints: int, stride: int, *, num_frames: int | None = None
) -> Bool[Array, "controls joints"]:
    """Which key tangents (``key_tangent``: the first and last control point's) the handle
    projection keeps as they are: every joint's, except where the joint has a handle between
    that key and the control frame next to it (frames 1…stride−1 after the start, the same
    before the end).

    There the tangent is the only variable near the handle besides the next control point,
    whose weight at frame 1 is 0.07: holding the key's velocity while the handle asks the
    joint 20 cm off its line in one frame threw the curve 2.5 m out at frame 6. The handle
    wins: the model chooses that tangent, as without ``key_tangent`` (where the projection
    moved the key's instead, in the model's normalised space it moved the next control
    point, cheaper there, and the curve still swung 2.2 m). A key two windows of a chain
    share keeps its tangent all the same (the sampler adds them back): both windows must
    leave and reach it alike. ``num_frames``: the window's (default ``(num_controls − 1)·stride + 1``).
    """
    released = handles_next_to_keys(handles, num_controls, num_joints, stride, num_frames=num_frames)
    return jnp.zeros((num_controls, num_joints), bool).at[jnp.asarray([0, num_controls - 1])].set(~released)


def release_unknown_tangents(held: Bool[Array, "controls joints"], key_tangent: Float[Array, "2 joints 3"]) -> Bool[Array, "controls joints"]:
    """``held`` key tangents (rows 0 and −1: the window's two keys) less those given as NaN:
    a velocity not known, the model's to choose as without ``key_tangent``."""
    ends = jnp.asarray([0, held.shape[0] - 1])
    return held.at[ends].set(held[ends] & ~jnp.isnan(key_tangent).any(axis=-1))


def handles_next_to_keys(
    handles: Handles, num_controls: int, num_joints: int, stride: int, *, num_frames: int | None = None
) -> Bool[Array, "2 joints"]:
    """``(2, joints)``: which joints have a (valid) handle between the first key and the
    control frame after it (frames 1…stride−1), and between the last key and the control
    frame before it (row 1). ``num_frames``: the window's (default ``(num_controls − 1)·stride + 1``;
    another length's last segment may be shorter)."""
    joint, frame, _, valid = handles
    last = (num_controls - 1) * stride if num_frames is None else num_frames - 1
    before_last = ((last - 1) // stride) * stride  # the control frame before the last key
    near_start = valid & (frame > 0) & (frame < min(stride, last))
    near_end = valid & (frame > before_last) & (frame < last)
    return jnp.zeros((2, num_joints), bool).at[0, joint].max(near_start).at[1, joint].max(near_end)


def guided_denoiser(denoiser, conditions: Handles, guidance: float):
    """``denoise(x_t, t) -> (x̂₀, contact logits)`` for DDIM: ``denoiser(x_t, t, conditions)``,
    with classifier-free guidance at scale ``guidance`` (``1.0``: the conditional pass alone).

    Args:
      denoiser: ``denoiser(x_t, t, conditions) -> (x̂₀, logits)``, e.g. :func:`predict_x0`
        closed over a model and its statistics.
      conditions: the normalised condition slots of one motion.
      guidance: the guidance scale (static).
    """

    def denoise(x_t, t):
        if guidance == 1.0:
            return denoiser(x_t, t, conditions)
        # Classifier-free guidance: the unconditional pass sees no condition at all.
        both = jax.tree.map(lambda c, u: jnp.stack([c, u]), conditions, conditions._replace(valid=jnp.zeros_like(conditions.valid)))
        x0, logits = jax.vmap(lambda c: denoiser(x_t, t, c))(both)
        return x0[1] + guidance * (x0[0] - x0[1]), logits[0]

    return denoise


def _sample_one(
    model: BezierMotionModel,
    start,
    end,
    handles: Handles,
    key_rot6d,
    key_tangent,
    key,
    steps,
    guidance,
    overwrite,
    foot_lock,
    layout: BezierLayout,
    chain: _Chain | None = None,
):
    """One window of ``layout``'s frames; with ``chain`` (inside ``jax.vmap`` over its
    windows) its boundary tangents, orientations and contacts are shared with the
    neighbouring windows."""
    cfg, stats = model.config, model.stats
    controls = layout.num_controls
    ends = jnp.asarray([0, controls - 1])
    translation = start[HIPS] * jnp.asarray([1.0, 0.0, 1.0], start.dtype)
    world = inbetween_conditions(layout.num_frames, start, end, handles)
    normalized = normalize_conditions(stats, world, translation)
    mask, target = grid_conditions(layout, normalized, cfg.num_joints)
    _, world_target = grid_conditions(layout, world, cfg.num_joints)
    # The conditions where x̂₀'s positions are measured from (cm): the window's own frame; a
    # chain's windows, each in its own, are met together in the world frame.
    x0_target = world.position - translation if chain is None else world.position
    x0_pos_mean = stats.mean[:, :3] if chain is None else stats.mean[:, :3] + translation
    denoiser = functools.partial(predict_x0, nnx.merge(model.graphdef, model.params), stats, layout=layout)
    # The keys' tangents are conditions: the projection keeps them too (but a handle next to
    # a key may release it, held_key_tangents). A key two windows of a chain share keeps its
    # given tangent whatever the handles: both windows must leave and reach it alike.
    held = None
    if key_tangent is not None:
        held = held_key_tangents(world, controls, cfg.num_joints, cfg.stride, num_frames=layout.num_frames)
        held = held if chain is None else held | _shared_keys(chain, controls, cfg.num_joints)
        held = release_unknown_tangents(held, key_tangent)
    couple = (lambda x: x) if chain is None else functools.partial(_couple, chain=chain)
    # A chain's joints with a handle next to a shared key are met over the whole chain, each
    # shared tangent one variable (_projector); the others window by window. In x̂₀'s
    # normalised variables at every step, in world units at the end.
    project_x0 = _projector(layout, world, mask, held, chain, pos_std=stats.std[:, :3], tangent_std=stats.std[:, 3:6])
    project_world = _projector(layout, world, mask, held, chain)

    denoise = guided_denoiser(denoiser, normalized, guidance)

    def fix(x0_tokens):
        # Conditions on control frames replace their control positions (BMM's overwrite);
        # those between control frames then move x̂₀ by the smallest correction, in the
        # model's normalised space, that puts the curves through them.
        feats = from_tokens(x0_tokens)
        if key_rot6d is not None:  # the keys' orientations, overwritten like their positions
            feats = feats.at[ends, :, 6:].set((key_rot6d - stats.mean[:, 6:]) / stats.std[:, 6:])
        if key_tangent is not None:  # and their tangents (velocities), like positions too, where held
            keyed = (key_tangent - stats.mean[:, 3:6]) / stats.std[:, 3:6]
            feats = feats.at[ends, :, 3:6].set(jnp.where(held[ends][..., None], keyed, feats[ends, :, 3:6]))
        pos = jnp.where(mask[..., None], target, feats[..., :3])
        # A chain's shared keys: tangents and orientations averaged with the neighbour's.
        # Every window normalises them by the same affine map (no translation), so the
        # mean here is the mean in world units.
        tangent, rot6d = couple(feats[..., 3:6]), couple(feats[..., 6:])
        pos, tangent = project_x0(pos, tangent, x0_target, pos_mean=x0_pos_mean, tangent_mean=stats.mean[:, 3:6])
        return to_tokens(jnp.concatenate([pos, tangent, rot6d], axis=-1))

    def exact(pos, tangent):
        # The handles themselves, to float rounding of the curve, not through a
        # normalise/denormalise round trip: control frames bit for bit, the others by a
        # (tiny) world-space correction; shared tangents equal in world units, bit for bit.
        pos = jnp.where(mask[..., None], world_target, pos)
        if key_tangent is not None:  # exactly, not through the normalisation round trip
            tangent = tangent.at[ends].set(jnp.where(held[ends][..., None], key_tangent, tangent[ends]))
        return project_world(pos, couple(tangent), world.position)

    x_T = jax.random.normal(key, (controls, cfg.frame_features))
    x0, logits = ddim_sample(
        denoise, cosine_schedule(cfg.num_timesteps), x_T, steps=steps, overwrite=fix if overwrite else None, has_aux=True
    )
    pos, tangent, rot6d = split_features(stats.denormalize(from_tokens(x0)))
    pos = pos + translation
    if overwrite:
        pos, tangent = exact(pos, tangent)
        if key_rot6d is not None:  # exactly, not through the normalisation round trip
            rot6d = rot6d.at[ends].set(key_rot6d)
    rot6d = couple(rot6d)  # after denormalising: equal bits at shared keys (a no-op with key_rot6d)
    # A shared key is one frame: both windows agree on whether a foot is planted there.
    contacts = couple(jax.nn.sigmoid(logits))
    if foot_lock is not None:  # the anchor's name (lock_anchor), or None: no lock
        pos, tangent = lock_feet(pos, tangent, contacts, mask, handles=world, layout=layout, anchor=foot_lock)
        if overwrite:  # locking moves control points that off-grid handles depend on
            pos, tangent = exact(pos, tangent)
    return SampledCurves(pos, tangent, rot6d, contacts)


def sample_curves(
    model: BezierMotionModel, start: Float[Array, "*batch 6 3"], end: Float[Array, "*batch 6 3"], handles: Handles, *, key: Array, **options
) -> SampledCurves:
    """Sample Bézier curves of the six characteristic joints between a start and an end pose:
    :func:`sample_chained_curves` of these two keys (one window).

    Args:
      model: the trained BMM.
      start, end: ``(*batch, 6, 3)`` world positions of the characteristic joints at the
        first and last frame of the window (cm). Their values are not checked here (a NaN
        gives NaN curves): :func:`bezmotion.pipeline.inbetweening.inbetween` checks its
        poses, and :meth:`Handles.from_frames` its positions.
      handles: sparse intermediate handles, batched like ``start``.
      key: PRNG key; split per motion when batched.
      options: :func:`sample_chained_curves`' (``steps``, ``guidance``, ``overwrite``,
        ``foot_lock``, and ``key_rot6d`` ``(*batch, 2, 6, 6)``, ``key_tangent``
        ``(*batch, 2, 6, 3)`` of the two keys).
    Returns:
      :class:`SampledCurves` ``(*batch, controls, …)`` in the world frame.
    """
    joints = model.config.num_joints
    start, end = jnp.asarray(start), jnp.asarray(end)
    if start.shape[-2:] != (joints, 3) or end.shape != start.shape:
        raise ValueError(f"start and end must both be (..., {joints}, 3), got {start.shape}, {end.shape}")
    batch = start.shape[:-2]
    if handles.position.shape[:-2] != batch:
        raise ValueError(f"handles must be batched like start {batch}, got {handles.position.shape[:-2]}")
    one_window = Handles(*(jnp.expand_dims(x, len(batch)) for x in handles))
    curves = sample_chained_curves(model, jnp.stack([start, end], axis=-3), one_window, key=key, coupled=False, **options)
    return jax.tree.map(lambda x: jnp.squeeze(x, len(batch)), curves)


def over_batch(fn, batch: tuple[int, ...], key: Array, *args):
    """``fn(*args, key)`` vmapped over the leading ``batch`` axes of every argument, each
    entry with its own key (``key`` itself when unbatched)."""
    if not batch:
        # Not a vmap of one: under it every `lax.cond` inside (a chain's projection) would
        # become a select that runs both branches.
        return fn(*args, key)
    n = int(np.prod(batch, dtype=int))
    flat = lambda x: x.reshape(n, *x.shape[len(batch) :])  # noqa: E731
    keys = jax.random.split(key, n)
    out = jax.vmap(fn)(*(jax.tree.map(flat, a) for a in args), keys)  # None (no key_rot6d, …) has no leaves
    return jax.tree.map(lambda x: x.reshape(*batch, *x.shape[1:]), out)


def sample_chained_curves(
    model: BezierMotionModel,
    key_pos: Float[Array, "*batch keys 6 3"],
    handles: Handles,
    *,
    key: Array,
    steps: int = 10,
    guidance: float = 1.0,
    coupled: bool = True,
    overwrite: bool = True,
    foot_lock: bool | str = False,
    key_rot6d: Float[Array, "*batch keys 6 6"] | None = None,
    key_tangent: Float[Array, "*batch keys 6 3"] | None = None,
    checked: bool = True,
    num_frames: int | None = None,
) -> SampledCurves:
    """Sample the curves of a chain of windows through ``keys`` key poses, one window
    (``model.config.num_frames`` frames, 31) between each pair of consecutive keys, all in
    one batched DDIM loop.

    The sampler aligns each window (its start hips at the origin in XZ, as in training), runs
    DDIM with x̂₀ put through the conditions at every step and after the last (control
    points on control frames overwritten, handles between them met by the minimum-norm
    correction of x̂₀), and moves the curves back. Window ``i`` runs from key ``i`` (its
    frame 0) to key ``i + 1`` (its last frame) through its own handles (frames 1 … 29 of
    that window); two keys are one window (:func:`sample_curves`). With ``coupled`` the windows are also joined at every shared key, in x̂₀ at
    every DDIM step and exactly after the last: the two windows' tangents there are set to
    their mean, and so are their orientations and contact probabilities, before the
    handles are projected onto with those tangents held fixed. The curves are then C¹
    across the keys — the same position (the key), the same velocity ``3·T/stride``
    (cm/frame) on both sides — and still pass through every handle. ``coupled=False``
    samples the windows independently (BMM Appendix D.1), for comparison; with the same
    ``key`` both variants start from the same noise.

    Args:
      model: the trained BMM.
      key_pos: ``(*batch, keys, 6, 3)`` world positions of the six characteristic joints at
        each key (cm), ``keys ≥ 2``; consecutive keys are ``num_frames − 1`` (30) frames apart.
      handles: intermediate handles of each window, batched ``(*batch, keys − 1, handles)``
        (frames within the window, 1 … 29).
      key: PRNG key; split per chain when batched, then per window (a single window takes
        it as it is).
      steps: DDIM steps (the paper uses 10).
      guidance: classifier-free guidance scale; ``1.0`` (default) runs the conditional
        model alone, in one pass per step.
      coupled: join the windows at the shared keys (default); ``False``: independent windows.
      overwrite: put the curves through the conditions in x̂₀ at every step and after the
        last (:func:`~bezmotion.diffusion.projection.project_off_grid` between control
        frames); ``False`` reproduces the paper's "w/o overwrite" ablation (a coupled chain
        needs it: the coupling is part of it).
      foot_lock: afterwards, hold each foot still in the ground plane while its predicted
        contact lasts (:func:`~bezmotion.bmm.foot_lock.lock_feet`; ours, not the paper's),
        each planted control point where the nearest condition of its contact run puts the
        foot. Constrained points do not move.
      key_rot6d: optionally ``(*batch, keys, 6, 6)`` global orientations (6-D, world frame)
        of the six joints at every key. With ``overwrite`` they are conditions like the key
        positions, so the curves leave and reach each key facing the way it does (ours; the
        paper conditions on positions only, ``None``).
      key_tangent: optionally ``(*batch, keys, 6, 3)`` the curves' tangents at every key (cm,
        world frame; a velocity ``v`` in cm/frame is the tangent ``v·stride/3``,
        :func:`~bezmotion.bezier.tangent_from_velocity`), conditions like ``key_rot6d``: the
        curves leave and reach each key at its own velocity. A joint's handle within a
        stride of a key takes precedence (:func:`held_key_tangents`); both windows of a
        shared key take its tangent, so a coupled chain keeps it. A NaN tangent (a key whose
        velocity is not known, e.g. a target pose alone) leaves that joint's tangent at that
        key to the model, as without ``key_tangent``.
      checked: check the handles' values in the computation (:func:`window_handle_problems`,
        ``eqx.error_if``); ``False`` when the caller checked them already, which leaves the
        program free of host callbacks (XLA's persistent cache then stores it).
      num_frames: frames of each window, keys ``num_frames − 1`` apart (default the model's,
        31): a control point every ``stride`` frames, the last segment shorter where the
        span is not a multiple of it (:class:`~bezmotion.bezier.BezierLayout`). Handles are
        met exactly at any length; the model was trained at its own. A coupled chain needs
        spans that are multiples of ``stride``.
    Returns:
      :class:`SampledCurves` batched ``(*batch, keys − 1, controls, …)``, world frame; window
      ``i``'s last control point and window ``i + 1``'s first are the same key.

    Compiled once per input shape and static argument, with the backend's inference compiler
    options (:mod:`bezmotion._src.xla_options`); inside a caller's own ``jax.jit`` it is
    traced into that computation.
    """
    return _sample_chained_curves(
        model, key_pos, handles, key_rot6d, key_tangent,
        key=key, steps=steps, guidance=guidance, coupled=coupled, overwrite=overwrite, foot_lock=lock_anchor(foot_lock), checked=checked,
        num_frames=window_frames(model.config, num_frames),
    )  # fmt: skip


MAX_WINDOW_FRAMES = 901
"""The longest window :func:`sample_chained_curves` samples (30 s at 30 fps)."""


def window_frames(config: Any, num_frames: Any = None) -> int:
    """``num_frames`` checked (an integer in 3 … :data:`MAX_WINDOW_FRAMES`), or the config's
    window length when it is ``None``."""
    if num_frames is None:
        return config.num_frames
    if isinstance(num_frames, (bool, np.bool_)) or not isinstance(num_frames, (int, np.integer)) or not 3 <= num_frames <= MAX_WINDOW_FRAMES:
        raise ValueError(f"a window's num_frames is an integer in 3 … {MAX_WINDOW_FRAMES} (keys 2 … {MAX_WINDOW_FRAMES - 1} frames apart), got {num_frames!r}")
    return int(num_frames)


def window_handle_problems(config: Any, key_pos: Float[Array, "*batch keys 6 3"], handles: Handles, num_frames: int | None = None) -> list[Problem]:
    """What is wrong with each window's ``handles`` (batched ``(*batch, keys − 1, slots)``)
    between consecutive ``key_pos`` in a chain of ``num_frames``-frame windows (default
    ``config.num_frames``): :func:`~bezmotion.handles.handle_problems`, the straight line
    from each window's keys."""
    start, end = key_pos[..., :-1, :, :], key_pos[..., 1:, :, :]
    frames = config.num_frames if num_frames is None else num_frames
    return handle_problems(handles, num_frames=frames, num_joints=config.num_joints, line=straight_line(start, end, handles, frames))


CHAIN_AXIS = "chain_window"  # the vmap axis the windows of one chain are coupled over


@functools.partial(inference_jit, static_argnames=("steps", "guidance", "coupled", "overwrite", "foot_lock", "checked", "num_frames"))
def _sample_chained_curves(
    model, key_pos, handles, key_rot6d, key_tangent, *, key, steps, guidance, coupled, overwrite, foot_lock, checked=True, num_frames=None
) -> SampledCurves:
    joints = model.config.num_joints
    if key_pos.ndim < 3 or key_pos.shape[-2:] != (joints, 3) or key_pos.shape[-3] < 2:
        raise ValueError(f"key_pos must be (..., keys ≥ 2, {joints}, 3), got {key_pos.shape}")
    *batch, num_keys = key_pos.shape[:-2]
    batch = tuple(batch)
    if key_rot6d is not None and key_rot6d.shape != (*batch, num_keys, joints, 6):
        raise ValueError(f"key_rot6d must be {(*batch, num_keys, joints, 6)} (one orientation per key), got {key_rot6d.shape}")
    if key_tangent is not None and key_tangent.shape != (*batch, num_keys, joints, 3):
        raise ValueError(f"key_tangent must be {(*batch, num_keys, joints, 3)} (one tangent per key), got {key_tangent.shape}")
    if handles.position.shape[:-2] != (*batch, num_keys - 1):
        raise ValueError(
            f"handles must be batched (..., windows, handles) = {(*batch, num_keys - 1)} for {num_keys} keys, "
            f"got {handles.position.shape[:-2]}"
        )
    if coupled and not overwrite:
        raise ValueError("a coupled chain needs overwrite=True (the coupling is part of the overwrite); use coupled=False")
    windows = num_keys - 1
    layout = BezierLayout(window_frames(model.config, num_frames), model.config.stride)
    if coupled and windows > 1 and (layout.num_frames - 1) % layout.stride:
        raise ValueError(
            f"a coupled chain's windows span a multiple of the stride ({layout.stride} frames); "
            f"got {layout.num_frames - 1}: use coupled=False"
        )
    start, end = key_pos[..., :-1, :, :], key_pos[..., 1:, :, :]
    if checked:
        handles = raised_in_program(handles, window_handle_problems(model.config, key_pos, handles, layout.num_frames))
    window_ends = lambda x: None if x is None else jnp.stack([x[..., :-1, :, :], x[..., 1:, :, :]], axis=-3)  # noqa: E731
    rot6d_pairs, tangent_pairs = window_ends(key_rot6d), window_ends(key_tangent)
    one = functools.partial(
        _sample_one, model, steps=steps, guidance=guidance, overwrite=overwrite, foot_lock=foot_lock, layout=layout,
        chain=_Chain(CHAIN_AXIS, windows) if coupled and windows > 1 else None,  # one window: the window alone
    )  # fmt: skip

    def chain(start, end, handles, rot6d_pairs, tangent_pairs, key):
        if windows == 1:  # a window alone: sampled with the key itself, and no vmap of one
            first = lambda x: None if x is None else jax.tree.map(lambda a: a[0], x)  # noqa: E731
            out = one(first(start), first(end), first(handles), first(rot6d_pairs), first(tangent_pairs), key)
            return jax.tree.map(lambda a: a[None], out)
        # One vmap over the windows: its DDIM scans run as one batched loop.
        return jax.vmap(one, axis_name=CHAIN_AXIS)(start, end, handles, rot6d_pairs, tangent_pairs, jax.random.split(key, windows))

    return over_batch(chain, batch, key, start, end, handles, rot6d_pairs, tangent_pairs)


def save_model(directory: str | os.PathLike, model: BezierMotionModel, *, storage_dtype: str = "float32") -> None:
    """Write a trained BMM (parameters, statistics, config, and the checksums of their
    files) to ``directory``, atomically.

    ``storage_dtype="float16"`` halves the file (for bundling); :func:`load_model` casts
    the parameters back to float32. The statistics are always stored in float32.
    """
    params = cast_floating(model.params, storage_dtype)
    save_model_folder(directory, {"params": params, "stats": model.stats}, {"model": dataclasses.asdict(model.config), "storage_dtype": storage_dtype})


def load_model(directory: str | os.PathLike, *, verify: bool = True) -> BezierMotionModel:
    """Read a BMM written by :func:`save_model` (its config says how to rebuild it).

    Args:
      directory: the saved model's folder.
      verify: check its files against the checksums :func:`save_model` wrote first.
        ``False`` (it warns) loads a folder without them, saved before models carried them.

    Raises:
      FileNotFoundError: ``directory`` holds no saved BMM.
      ChecksumError: its files differ from their checksums (naming them), or it has none.
      ValueError: its parameters or statistics hold NaN or inf (naming them).
    """
    store = open_model_folder(directory, "BMM", verify=verify)
    try:
        saved = store.config()
        if "model" not in saved:
            raise FileNotFoundError(f"{directory}: not a saved BMM (its config.json describes no model)")
        config = BMMConfig(**saved["model"])
        graphdef, params = init_denoiser(config, key=jax.random.key(0))
        j = config.num_joints
        storage = jnp.dtype(saved.get("storage_dtype", "float32"))
        like = {"params": cast_floating(params, storage), "stats": FeatureStats(jnp.zeros((j, 12)), jnp.ones((j, 12)))}
        restored = store.restore(like, step=store.latest_step(), verify=False)  # the folder's checksums cover it
    finally:
        store.close()
    return BezierMotionModel(cast_floating(restored["params"], jnp.float32), restored["stats"], graphdef, config)


def with_off_grid_prior(model: BezierMotionModel, off_grid_prior: str) -> BezierMotionModel:
    """The same trained model, its residual added to another reference between control
    frames (:attr:`BMMConfig.off_grid_prior`, ``"linear"`` or ``"projection"``): the
    parameters are shared, only the structure is rebuilt. Handles on control frames sample
    exactly as before; a model trained over ``"projection"`` is sampled the way it was trained.

    Raises:
      ValueError: ``off_grid_prior`` is not one of them.
    """
    config = dataclasses.replace(model.config, off_grid_prior=off_grid_prior)  # checks the value
    graphdef, _ = init_denoiser(config, key=jax.random.key(0))
    return dataclasses.replace(model, graphdef=graphdef, config=config)
