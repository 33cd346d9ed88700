"""The full in-betweening pipeline: key poses and handles in, a full-body motion out.

    key poses, handles ──▶ BMM curves of the six characteristic joints, one window
        between each pair of consecutive keys, joined C¹ at the shared keys
        ──▶ dense trajectories (Bézier positions, slerped orientations)
        ──▶ the IK module over every frame ──▶ full-body poses of the target character

:func:`inbetween` is the one entry point: ``K ≥ 2`` keys ``bmm.config.num_frames − 1``
(30) frames apart, so two keys are one window and more are a chain. The model it runs is
an :class:`~bezmotion.pipeline.model.Inbetweener` (the BMM, the IK module as a function
argument, the character and the transfer); its options are one hashable
:class:`InbetweenOptions`. Its two halves, :func:`curves_traced` and
:func:`pose_from_curves`, are exposed for callers that batch windows or share one set of
curves between several IK modules (:mod:`bezmotion.evaluation`).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from bezmotion._src.problems import Problem, raise_first, raised_in_program
from bezmotion._src.xla_options import inference_jit, traced
from bezmotion.bezier import BezierLayout, reconstruct_dense, tangent_from_velocity
from bezmotion.bmm.sampling import (
    MAX_WINDOW_FRAMES,
    BezierMotionModel,
    Handles,
    SampledCurves,
    held_key_tangents,
    release_unknown_tangents,
    sample_chained_curves,
    shared_key_mask,
    window_handle_problems,
)
from bezmotion.diffusion.projection import project_onto_handles
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.data.windows import join_windows
from bezmotion.geometry.rotations import quat_rotate
from bezmotion.ik.protocol import Character, IKFn, IKTargets, Pose, solve_frames, targets_from_pose
from bezmotion.ik.rig import with_rest_pose
from bezmotion.pipeline.transfer import Placement, Transfer, curves_to_target, orientations_to_source_space, placement, to_source_space

if TYPE_CHECKING:
    from bezmotion.pipeline.model import Inbetweener


KEY_BLEND_FRAMES = 6
"""Default frames over which the key poses' correction fades (the control stride: handles untouched)."""


@dataclasses.dataclass(frozen=True)
class InbetweenOptions:
    """How :func:`inbetween` samples and joins a motion (frozen and hashable: one static argument).

    Attributes:
      steps: DDIM steps (the paper's 10).
      guidance: classifier-free guidance scale; ``1.0`` runs the conditional model alone.
      foot_lock: hold each foot still on the ground while its predicted contact lasts
        (:func:`~bezmotion.bmm.foot_lock.lock_feet`); handles do not move.
      keep_keyframes: the given keys exactly at their frames, rather than the IK's reconstruction.
      key_blend_frames: frames over which the keys' difference from the IK's poses fades
        (:func:`~bezmotion.ik.key_blend.blend_to_keys`), so no joint pops next to a key.
      key_orientations: the keys' global orientations of the six joints are conditions of
        the BMM, like their positions; ``False`` is the paper's position-only conditioning.
      coupled: a chain's windows share their tangent, orientation and contacts at each
        shared key (C¹ across keys); ``False`` samples them independently (BMM Appendix D.1).
    """

    steps: int = 10
    guidance: float = 1.0
    foot_lock: bool = False
    keep_keyframes: bool = True
    key_blend_frames: int = KEY_BLEND_FRAMES
    key_orientations: bool = True
    coupled: bool = True

    def __post_init__(self) -> None:
        for name in ("steps", "key_blend_frames"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < (1 if name == "steps" else 0):
                raise ValueError(f"InbetweenOptions.{name} must be an integer ≥ {1 if name == 'steps' else 0}, got {value!r}")
        if not np.isfinite(self.guidance) or self.guidance < 0:
            raise ValueError(f"InbetweenOptions.guidance must be a finite number ≥ 0, got {self.guidance!r}")
        for name in ("foot_lock", "keep_keyframes", "key_orientations", "coupled"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise ValueError(f"InbetweenOptions.{name} must be True or False, got {getattr(self, name)!r}")


class InbetweenResult(NamedTuple):
    """An in-betweened motion through ``K`` keys (target character, world frame, cm).

    With 31-frame windows the motion has ``(K − 1)·30 + 1`` frames, key ``k`` at frame ``30·k``.

    Attributes:
      pose: :class:`~bezmotion.ik.protocol.Pose` per frame, ``(frames, …)``.
      curves: the BMM curves of each window in the target character's space, batched
        ``(K − 1, controls, …)``; window ``i`` runs from key ``i`` to key ``i + 1``
        (:meth:`joined_curves`: one curve through every key).
      positions: ``(frames, 6, 3)`` dense characteristic-joint trajectories given to IK.
      rot6d: ``(frames, 6, 6)`` dense characteristic-joint orientations given to IK.
    """

    pose: Pose
    curves: SampledCurves
    positions: Float[Array, "frames 6 3"]
    rot6d: Float[Array, "frames 6 6"]

    def joined_curves(self) -> SampledCurves:
        """The windows' curves as one curve through every key (:func:`join_chain_curves`)."""
        return join_chain_curves(self.curves)


class WindowCurves(NamedTuple):
    """The curves stage, before IK (target character, world frame, cm), batched per window.

    Attributes:
      curves: the BMM curves in the target character's space, through every handle.
      positions: ``(…, frames, 6, 3)`` dense characteristic-joint trajectories.
      rot6d: ``(…, frames, 6, 6)`` dense characteristic-joint orientations.
    """

    curves: SampledCurves
    positions: Float[Array, "*windows frames 6 3"]
    rot6d: Float[Array, "*windows frames 6 6"]


def key_velocities(character: Character, poses: Pose) -> Float[Array, "*batch 2 6 3"]:
    """The six joints' velocities at a window's two keys (cm/frame) from four poses
    ``(*batch, 4, …)``: a frame next to the start key, the start key, the end key, a frame
    next to the end key, one frame apart each — ``[p₁ − p₀, p₃ − p₂]``. From a clip, the
    frame before the start and the one after the end (the motion kept around the window)."""
    position = targets_from_pose(character, poses).position  # (*batch, 4, 6, 3)
    return jnp.stack([position[..., 1, :, :] - position[..., 0, :, :], position[..., 3, :, :] - position[..., 2, :, :]], axis=-3)


def chain_key_velocities(character: Character, poses: Pose, stride: int = 30) -> Float[Array, "*batch keys 6 3"]:
    """The six joints' velocities (cm/frame) at every key of a chain from its poses
    ``(*batch, frames, …)``, keys every ``stride`` frames from the first to the last frame:
    the central difference ``(p_{k+1} − p_{k−1}) / 2`` at a shared key (the velocity both
    windows take), and inside the chain at its two ends (``p₁ − p₀``, ``p_F − p_{F−1}``)."""
    position = targets_from_pose(character, poses).position  # (*batch, frames, 6, 3)
    frames = position.shape[-3]
    if frames < 2 or (frames - 1) % stride:
        raise ValueError(f"a chain's frames must be keys {stride} apart (K·{stride} + 1), got {frames}")
    key_frames = np.arange(0, frames, stride)
    after = np.minimum(key_frames + 1, frames - 1)
    before = np.maximum(key_frames - 1, 0)
    span = (after - before).astype(np.float32)[:, None, None]  # 2 inside, 1 at the ends
    return (position[..., after, :, :] - position[..., before, :, :]) / span


def _tangent_to_source(transfer: Transfer, anchor: Placement, tangent: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """Tangents (or velocities) of the target character → the BMM's space: turned and scaled like positions."""
    return quat_rotate(anchor.turn.astype(tangent.dtype), tangent) / transfer.scale


def window_layout(config: Any, span: int | None = None) -> BezierLayout:
    """The layout of one window whose keys are ``span`` frames apart (default the model's,
    ``config.num_frames − 1``): a control point every ``config.stride`` frames, the last
    segment shorter where ``span`` is not a multiple of it.

    Raises:
      ValueError: a span that is not an integer in 2 … :data:`~bezmotion.bmm.sampling.MAX_WINDOW_FRAMES` − 1.
    """
    if span is None:
        return BezierLayout(config.num_frames, config.stride)
    if isinstance(span, (bool, np.bool_)) or not isinstance(span, (int, np.integer)) or not 2 <= span < MAX_WINDOW_FRAMES:
        raise ValueError(f"span, the frames from one key to the next, is an integer in 2 … {MAX_WINDOW_FRAMES - 1}, got {span!r}")
    return BezierLayout(int(span) + 1, config.stride)


def _window_in_target(
    bmm: BezierMotionModel,
    transfer: Transfer,
    anchor: Placement,
    curves: SampledCurves,
    first: IKTargets,
    last: IKTargets,
    handles: Handles,
    shared: Bool[Array, "controls 6"] | None = None,
    key_tangent: Float[Array, "2 6 3"] | None = None,
    *,
    layout: BezierLayout,
) -> WindowCurves:
    """Sampled curves of one window of ``layout`` (BMM's space) → the target character's,
    through its keys and handles exactly, and their dense trajectories. ``shared``: control
    tangents a chain shares with the neighbouring windows, which the handle projection keeps;
    ``key_tangent``: the keys' own tangents (target character), set and kept likewise."""
    cfg = bmm.config
    curves = curves_to_target(transfer, anchor, curves)
    ends = jnp.asarray([0, layout.num_controls - 1])
    if key_tangent is not None:  # exactly, undoing the scale round trip's rounding
        # Where a handle next to a key moved that key's tangent in the sampler, the moved one.
        held = _kept_tangents(cfg, layout, handles, shared, keyed=True)
        held = release_unknown_tangents(held, key_tangent)  # as the sampler did
        keyed = curves.ctrl_tangent.at[ends].set(key_tangent)
        curves = curves._replace(ctrl_tangent=jnp.where(held[..., None], keyed, curves.ctrl_tangent))
        shared = held
    # The end control points are the given poses themselves: their positions exactly
    # (undoing the scale round trip's rounding) and their orientations (which, without
    # ``key_orientations``, the BMM never saw).
    curves = curves._replace(
        ctrl_pos=curves.ctrl_pos.at[ends].set(jnp.stack([first.position, last.position])),
        ctrl_rot6d=curves.ctrl_rot6d.at[ends].set(jnp.stack([first.rot6d, last.rot6d])),
    )
    # The handles exactly again after the transfer.
    return _through_handles(layout, curves, handles, shared)


def _kept_tangents(
    cfg: Any, layout: BezierLayout, handles: Handles, shared: Bool[Array, "controls 6"] | None, *, keyed: bool
) -> Bool[Array, "controls 6"] | None:
    """The control tangents of one window that the handle projection keeps: a chain's shared
    keys' (``shared``) and, where the keys' tangents were given (``keyed``), every key's
    except those a handle next to the key moved (:func:`held_key_tangents`)."""
    if not keyed:
        return shared
    held = held_key_tangents(handles, layout.num_controls, cfg.num_joints, layout.stride, num_frames=layout.num_frames)
    return held if shared is None else held | shared  # a chain's shared key keeps its tangent


def _through_handles(layout: BezierLayout, curves: SampledCurves, handles: Handles, kept: Bool[Array, "controls 6"] | None) -> WindowCurves:
    """One window's curves (target character, ``layout``) through its handles exactly, and
    their dense trajectories: control frames overwritten, handles between them by the
    minimum-norm correction; the keys' control points, and the tangents ``kept``, stay put."""
    ends = jnp.asarray([0, layout.num_controls - 1])
    keys_fixed = jnp.zeros(curves.ctrl_pos.shape[:2], bool).at[ends].set(True)
    ctrl_pos, ctrl_tangent = project_onto_handles(
        layout, curves.ctrl_pos, curves.ctrl_tangent, handles, fixed=keys_fixed, fixed_tangent=kept,
    )  # fmt: skip
    curves = curves._replace(ctrl_pos=ctrl_pos, ctrl_tangent=ctrl_tangent)
    positions, rot6d = reconstruct_dense(layout, curves.ctrl_pos, curves.ctrl_tangent, curves.ctrl_rot6d)
    return WindowCurves(curves, positions, rot6d)


def reproject_curves(
    bmm: BezierMotionModel,
    curves: SampledCurves,
    handles: Handles,
    options: InbetweenOptions = InbetweenOptions(),
    *,
    keyed: bool = False,
    span: int | None = None,
) -> WindowCurves:
    """Curves already sampled (:attr:`InbetweenResult.curves`, batched ``(K − 1, controls, …)``,
    target character, cm) moved onto other handle positions by the same exact projection
    :func:`curves_traced` ends with, no diffusion: what an editor shows while a handle is
    dragged. Traceable.

    The keys' control points stay, and so do the tangents the in-between held (a coupled
    chain's shared keys; with ``keyed``, the keys' given velocities, as ``key_velocity`` held
    them). Handles on the same joints and frames as those the curves were sampled with give
    what projecting the sample itself onto the new positions gives.

    Args:
      curves: the sampled curves of every window.
      handles: each window's, ``(K − 1, slots)`` in its own frames (:func:`window_handles`).
      options: those of the in-between (``coupled`` is read).
      keyed: the in-between was given ``key_velocity``.
      span: frames between its keys (default the model's window, 30).
    Returns:
      :class:`WindowCurves` batched ``(K − 1, …)``.
    """
    cfg = bmm.config
    layout = window_layout(cfg, span)
    windows = curves.ctrl_pos.shape[0]
    coupled = options.coupled and windows > 1
    shared = shared_key_mask(windows, layout.num_controls, cfg.num_joints) if coupled else None

    def one(window: SampledCurves, window_handles: Handles, window_shared: Array | None) -> WindowCurves:
        return _through_handles(layout, window, window_handles, _kept_tangents(cfg, layout, window_handles, window_shared, keyed=keyed))

    if shared is None:
        return jax.vmap(lambda c, h: one(c, h, None))(curves, handles)
    return jax.vmap(one)(curves, handles, shared)


def pinned_frames(handles: Handles, num_frames: int) -> Bool[Array, "frames 6"]:
    """``(frames, 6)``: which characteristic joint is held by a (valid) handle at each frame
    of a window or chain (``handles`` unbatched, at its frames), for ``IKTargets.pinned``."""
    hit = (handles.frame[:, None] == jnp.arange(num_frames)[None, :]) & handles.valid[:, None]  # (handles, frames)
    return jnp.any(hit[:, :, None] & (handles.joint[:, None, None] == jnp.arange(len(CHARACTERISTIC_JOINTS))), axis=0)



def window_handles(handles: Handles, windows: int, span: int) -> Handles:
    """Handles in the in-between's frames ``(slots,)`` → each window's ``(windows, slots)``,
    in that window's own frames, for keys ``span`` frames apart (:func:`handles_per_window`)."""
    return handles_per_window(handles, span * np.arange(windows + 1))


def handles_per_window(handles: Handles, key_frames: Int[ArrayLike, "keys"]) -> Handles:
    """Handles in the in-between's frames ``(slots,)`` → each window's ``(keys − 1, slots)``,
    in that window's own frames, the keys at ``key_frames`` (increasing): every window sees
    every slot, valid where the handle lies strictly inside it (window ``i`` spans frames
    ``key_frames[i] … key_frames[i + 1]``)."""
    key_frames = jnp.asarray(key_frames, handles.frame.dtype)
    local = handles.frame[None, :] - key_frames[:-1, None]
    inside = (local > 0) & (local < jnp.diff(key_frames)[:, None])
    return Handles(
        joint=jnp.broadcast_to(handles.joint, local.shape),
        frame=jnp.where(inside, local, 0),
        position=jnp.broadcast_to(handles.position, (*local.shape, 3)),
        valid=handles.valid[None, :] & inside,
    )


def _source_frame(character: Character, keys: Pose, transfer: Transfer):
    """``(targets, anchor, source)``: the keys' six joints (target character), the transfer's
    anchor (the first key's hips), and the map of target positions into the BMM's space."""
    targets = targets_from_pose(character, keys)  # (keys, 6, ·)
    anchor = placement(transfer, targets.position[0])
    return targets, anchor, functools.partial(to_source_space, transfer, anchor)


def curves_traced(
    bmm: BezierMotionModel,
    character: Character,
    keys: Pose,
    handles: Handles,
    transfer: Transfer,
    key: Array,
    options: InbetweenOptions = InbetweenOptions(),
    key_velocity: Float[Array, "keys 6 3"] | None = None,
    checked: bool = True,
    span: int | None = None,
) -> WindowCurves:
    """The first half of :func:`inbetween`, traceable: the curves of every
    window between consecutive ``keys`` (batched ``(K, …)``) and their dense trajectories,
    batched ``(K − 1, …)``, which any number of IK modules can then share
    (:func:`pose_from_curves`).

    ``handles``: each window's, ``(K − 1, slots)`` in its own frames (:func:`window_handles`).
    One transfer anchor (the first key's hips on the floor) for the whole motion, so a
    shared key is one point in the BMM's space too. ``key_velocity``: optionally
    ``(K, 6, 3)`` the six joints' velocities at every key (cm/frame, target character),
    conditions met exactly, by both windows of a shared key. ``checked``: check the handles'
    values in the computation (``False``: the caller did, :func:`input_problems`).
    ``span``: frames from one key to the next (default the model's window, 30).
    """
    targets, anchor, source = _source_frame(character, keys, transfer)
    key_rot6d = orientations_to_source_space(transfer, targets.rot6d, anchor.turn) if options.key_orientations else None
    windows, cfg = targets.position.shape[0] - 1, bmm.config
    layout = window_layout(cfg, span)
    key_tangent = None if key_velocity is None else tangent_from_velocity(layout, key_velocity)
    curves = sample_chained_curves(
        bmm, source(targets.position), handles._replace(position=source(handles.position)),
        key=key, steps=options.steps, guidance=options.guidance, coupled=options.coupled, foot_lock=options.foot_lock,
        key_rot6d=key_rot6d, key_tangent=None if key_tangent is None else _tangent_to_source(transfer, anchor, key_tangent),
        checked=checked, num_frames=layout.num_frames,
    )  # fmt: skip
    first = jax.tree.map(lambda a: a[:-1], targets)
    last = jax.tree.map(lambda a: a[1:], targets)
    tangent_pairs = None if key_tangent is None else jnp.stack([key_tangent[:-1], key_tangent[1:]], axis=1)  # (windows, 2, 6, 3)
    finish = functools.partial(_window_in_target, bmm, transfer, anchor, layout=layout)
    if windows == 1:  # a window alone: nothing shared, and no vmap of one
        one = lambda x: None if x is None else jax.tree.map(lambda a: a[0], x)  # noqa: E731
        window = finish(one(curves), one(first), one(last), one(handles), None, one(tangent_pairs))
        return jax.tree.map(lambda a: a[None], window)
    # The handle projection after the transfer must keep the tangents the chain shares.
    shared = shared_key_mask(windows, layout.num_controls, cfg.num_joints) if options.coupled else None
    return jax.vmap(finish)(curves, first, last, handles, shared, tangent_pairs)


def join_chain_curves(curves: SampledCurves) -> SampledCurves:
    """Curves batched per window ``(windows, controls, …)`` (``InbetweenResult.curves``),
    as one curve through every key ``(windows·(controls − 1) + 1, …)``: each shared key's
    control point once (the earlier window's). A coupled chain's windows share it bit for
    bit (position, tangent, orientation and contacts), so the joined curve is the same
    motion, C¹ at the keys, for anything that takes one window's curves (glTF, preview)."""
    return jax.tree.map(join_windows, curves)



def pose_from_curves(
    ik_fn: IKFn,
    ik_params: Any,
    windows: WindowCurves,
    keys: Pose,
    *,
    keep_keyframes: bool = True,
    key_blend_frames: int = KEY_BLEND_FRAMES,
    handles: Handles | None = None,
    start: Pose | None = None,
) -> Pose:
    """The second half of :func:`inbetween`, traceable: one IK over the joined frames of
    every window, then (``keep_keyframes``) each window's frames blended to its two keys.

    Args:
      windows: the curves stage (:func:`curves_traced`), batched ``(K − 1, …)``; only its
        dense ``positions`` and ``rot6d`` are read.
      keys: :class:`~bezmotion.ik.protocol.Pose` of every key, batched ``(K, …)``.
      handles: each window's handles ``(K − 1, slots)`` in its own frames, which the IK is
        told it must hit first (``IKTargets.pinned``); ``None``: none.
      start: ``((K − 1)·(window_frames − 1) + 1, …)`` poses for an IK that solves whole
        windows from a warm start (``ik_fn.solve_window(…, start=…)``, as
        :class:`~bezmotion.ik.exact.ExactIKFn`'s does) to begin from instead of its own first
        guess: e.g. its solution for curves that have moved a little since; ``None``: none.
    Returns:
      ``((K − 1)·(window_frames − 1) + 1, …)`` poses, the given keys exactly at the key
      frames with ``keep_keyframes``.
    Raises:
      ValueError: a ``start`` for an IK that does not solve whole windows.
    """
    positions, rot6d = join_windows(windows.positions), join_windows(windows.rot6d)
    frames = windows.positions.shape[1]
    pinned = None if handles is None else join_windows(jax.vmap(lambda h: pinned_frames(h, frames))(handles))
    # One IK over the whole motion (an IK that smooths over time sees across the keys), each
    # window joined to its two keys: the fades of neighbouring windows meet only at their
    # shared key, where both put that key exactly. An IK that solves whole windows (the
    # exact one) starts from poses already joined to the keys and holds their neighbours.
    targets, joined = IKTargets(positions, rot6d, pinned), keys if keep_keyframes else None
    if start is None:
        return solve_frames(ik_fn, ik_params, targets, keys=joined, key_blend_frames=key_blend_frames)
    window = getattr(ik_fn, "solve_window", None)
    if window is None:
        raise ValueError(f"a start pose needs an IK that solves whole windows (one with solve_window), got {type(ik_fn).__name__}")
    return window(ik_params, targets, keys=joined, key_blend_frames=key_blend_frames, start=start)


def inbetween_traced(
    model: Inbetweener,
    keys: Pose,
    handles: Handles,
    key: Array,
    options: InbetweenOptions = InbetweenOptions(),
    key_velocity: Float[Array, "keys 6 3"] | None = None,
    checked: bool = True,
    span: int | None = None,
) -> InbetweenResult:
    """:func:`inbetween` without its checks of the keys and its compilation, for callers that
    trace it into their own ``jax.jit`` or ``jax.vmap``: ``handles`` are each window's already
    (``(K − 1, slots)``, :func:`window_handles`). The IK's rig (if any) takes the first key
    as its rest pose (:func:`~bezmotion.ik.rig.with_rest_pose`). ``checked``, ``span``: as :func:`curves_traced`'s."""
    transfer = _transfer(model)
    windows = curves_traced(model.bmm, model.character, keys, handles, transfer, key, options, key_velocity, checked=checked, span=span)
    return result_from_curves(model, windows, keys, handles, options)


def result_from_curves(
    model: Inbetweener,
    windows: WindowCurves,
    keys: Pose,
    handles: Handles,
    options: InbetweenOptions = InbetweenOptions(),
    *,
    start: Pose | None = None,
) -> InbetweenResult:
    """The IK half of :func:`inbetween_traced`, traceable: ``model``'s IK over the curves of
    every window (:func:`pose_from_curves`, its rig's rest pose the first key's), and the
    result. ``windows``: :func:`curves_traced`'s or :func:`reproject_curves`'; ``handles``:
    each window's ``(K − 1, slots)``; ``start``: a warm start for an IK that takes one."""
    ik_params = with_rest_pose(model.ik_params, keys.quat_local[0])
    pose = pose_from_curves(
        model.ik_fn, ik_params, windows, keys, keep_keyframes=options.keep_keyframes, key_blend_frames=options.key_blend_frames,
        handles=handles, start=start,
    )  # fmt: skip
    return InbetweenResult(pose, windows.curves, join_windows(windows.positions), join_windows(windows.rot6d))


def _check_shapes(model: Inbetweener, keys: Pose, handles: Handles, key_velocity) -> int:
    """The number of keys, after checking every shape (``ValueError`` naming it)."""
    character = model.character
    root, quat = np.shape(keys.root_pos), np.shape(keys.quat_local)
    if len(root) != 2 or root[1:] != (3,) or quat != (root[0], character.num_joints, 4):
        raise ValueError(
            f"keys must be poses of {character.name} batched (K, …): root_pos (K, 3), quat_local "
            f"(K, {character.num_joints}, 4); got {root}, {quat}"
        )
    if root[0] < 2:
        raise ValueError(f"an in-between needs at least 2 keys, got {root[0]}")
    shape = np.shape(handles.position)
    if len(shape) != 2 or shape[1] != 3:
        raise ValueError(f"handles must be (slots, 3) positions in the in-between's frames, got {shape}")
    for name in ("joint", "frame", "valid"):
        if np.shape(getattr(handles, name)) != shape[:1]:
            raise ValueError(f"handles.{name} must be {shape[:1]} like the positions, got {np.shape(getattr(handles, name))}")
    if key_velocity is not None and np.shape(key_velocity) != (root[0], len(CHARACTERISTIC_JOINTS), 3):
        raise ValueError(f"key_velocity must be ({root[0]}, 6, 3) (one per key, six joints, cm/frame), got {np.shape(key_velocity)}")
    return root[0]


def _transfer(model: Inbetweener) -> Transfer:
    return Transfer.identity() if model.transfer is None else model.transfer


def _value_problems(keys: Pose, handles: Handles, key_velocity, span: int) -> list[Problem]:
    """What is wrong with the inputs' values: a key not finite (naming the first), a valid
    handle outside the in-between or on a key's frame (a handle there would fall out of every
    window; the sampler's :func:`~bezmotion.bmm.sampling.window_handle_problems` has the rest of
    each handle's rules), a ``key_velocity`` not finite."""
    num_keys = keys.root_pos.shape[0]
    finite = jnp.isfinite(keys.root_pos).all(axis=-1) & jnp.isfinite(keys.quat_local).all(axis=(-1, -2))
    last = span * (num_keys - 1)
    frame, valid = handles.frame, handles.valid
    misplaced = valid & ((frame <= 0) | (frame >= last) | (frame % span == 0))
    problems = [
        Problem(~finite, [f"key {k} contains non-finite values" for k in range(num_keys)]),
        Problem(
            misplaced.any(keepdims=True),
            [f"a handle's frame is outside the in-between or on a key: handles go on frames 1 … {last - 1}, "
             f"not on the keys' frames {list(range(0, last + 1, span))}"],
        ),  # fmt: skip
    ]
    if key_velocity is not None:  # NaN is allowed: a velocity not known
        problems.append(Problem(jnp.isinf(key_velocity).any(keepdims=True), ["key_velocity contains infinite values (NaN marks one not known)"]))
    return problems


@functools.partial(jax.jit, static_argnames=("span",))
def input_problems(model: Inbetweener, keys: Pose, handles: Handles, key_velocity=None, span: int | None = None) -> list[Problem]:
    """Every check :func:`inbetween` makes of its inputs' values, as problems
    (:mod:`bezmotion._src.problems`) computed in a program of their own: the keys', then each
    window's handles' in the BMM's space, as its sampler checks them. ``handles``: the whole
    in-between's ``(slots,)``; ``span``: frames from one key to the next (default the model's window, 30)."""
    layout = window_layout(model.bmm.config, span)
    span = layout.num_frames - 1
    problems = _value_problems(keys, handles, key_velocity, span)
    windows = window_handles(handles, keys.root_pos.shape[0] - 1, span)
    targets, _, source = _source_frame(model.character, keys, _transfer(model))
    in_source = windows._replace(position=source(windows.position))
    return problems + window_handle_problems(model.bmm.config, source(targets.position), in_source, layout.num_frames)


@functools.partial(inference_jit, static_argnames=("options", "checked", "span"))
def _inbetween(model, keys, handles, key, options, key_velocity, checked=True, span=None) -> InbetweenResult:
    span = window_layout(model.bmm.config, span).num_frames - 1
    if checked:
        keys, handles, key_velocity = raised_in_program((keys, handles, key_velocity), _value_problems(keys, handles, key_velocity, span))
    windows = window_handles(handles, keys.root_pos.shape[0] - 1, span)
    return inbetween_traced(model, keys, windows, key, options, key_velocity, checked=checked, span=span)


def inbetween(
    model: Inbetweener,
    keys: Pose,
    handles: Handles | None = None,
    *,
    key: Array,
    options: InbetweenOptions = InbetweenOptions(),
    key_velocity: Float[ArrayLike, "keys 6 3"] | None = None,
    span: int | None = None,
) -> InbetweenResult:
    """In-between ``model``'s character through ``keys`` and ``handles``.

    Args:
      model: the BMM, IK, character and transfer (:class:`~bezmotion.pipeline.model.Inbetweener`,
        e.g. ``bm.pretrained("bandai_namco")`` or ``bm.Inbetweener.from_bvh(clip)``).
      keys: :class:`~bezmotion.ik.protocol.Pose` of ``K ≥ 2`` key poses batched ``(K, …)``,
        ``span`` frames apart: two keys are one window, more a chain whose windows are
        joined C¹ at the shared keys.
      handles: where joints must be, in the in-between's frames (key ``k`` at frame
        ``span·k``; handles on the frames between keys), target character's world frame, cm
        (:meth:`~bezmotion.pipeline.model.Inbetweener.handles`); ``None``: none.
      key: PRNG key of the diffusion sampler.
      options: :class:`InbetweenOptions`.
      key_velocity: optionally ``(K, 6, 3)`` the six joints' velocities at every key
        (cm/frame, e.g. :func:`chain_key_velocities` of a clip around the keys): the curves
        pass every key at that velocity, which keeps limbs from popping next to the keys;
        NaN for a joint at a key whose velocity is not known (the model chooses it there).
      span: frames from one key to the next, 2 … 900 (default the model's window,
        ``bmm.config.num_frames − 1``: 30). Another span samples the model over a window of
        that length (its control grid extended, :func:`window_layout`): handles are met
        exactly at any span, the motion is as good as the model at that length (the
        bundled ones learned 30). A chain's span is a multiple of the stride (6) unless
        ``options.coupled`` is off.
    Returns:
      :class:`InbetweenResult` of ``(K − 1)·span + 1`` frames; its curves pass through every
      handle exactly, so the full-body handle error is the IK module's alone.

    Raises:
      ValueError: keys not ``K ≥ 2`` poses of the character, handles not ``(slots,)``, a
        ``key_velocity`` not ``(K, 6, 3)``; and, when called outside a ``jax.jit``, a key
        that is not finite (naming it), a handle on a key's frame or outside the
        in-between, a handle or velocity that is not finite. Inside a caller's ``jax.jit``
        those value checks run with the computation (``eqx.error_if``, the same messages).
    """
    handles = Handles.empty() if handles is None else handles
    span = window_layout(model.bmm.config, span).num_frames - 1
    _check_shapes(model, keys, handles, key_velocity)
    if key_velocity is not None:
        key_velocity = jnp.asarray(key_velocity, keys.root_pos.dtype)
    if traced((model, keys, handles, key, key_velocity)):
        return _inbetween(model, keys, handles, key, options, key_velocity, span=span)
    # Checked here first, the in-between's program holds no host callback: XLA's cache keeps it.
    raise_first(input_problems(model, keys, handles, key_velocity, span))
    return _inbetween(model, keys, handles, key, options, key_velocity, checked=False, span=span)
