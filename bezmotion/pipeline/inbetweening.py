"""The full in-betweening pipeline: poses and handles in, a full-body motion out.

    start pose, end pose, handles ──▶ BMM curves of the six characteristic joints
        ──▶ dense trajectories (Bézier positions, slerped orientations)
        ──▶ ik_fn per frame ──▶ full-body poses of the target character ──▶ BVH

:func:`inbetween` is one jit-compiled function of arrays; the IK module is an argument
(``ik_fn(params, targets) -> pose``, :mod:`bezmotion.ik.protocol`), so any learned,
analytic or user-written IK drives any character.

:func:`inbetween_chain` does the same through any number of key poses 30 frames apart:
its windows sampled together and joined C¹ at the shared keys, one IK over the chain.

Character transfer lives in :mod:`bezmotion.pipeline.transfer`, BVH export in
:mod:`bezmotion.pipeline.export`, metrics after IK in :mod:`bezmotion.pipeline.evaluation`.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Shaped

from bezmotion.xla_options import call_with_inference_options
from bezmotion.bezier import BezierLayout, reconstruct_dense, tangent_from_velocity
from bezmotion.bmm.sampling import (
    BezierMotionModel,
    Handles,
    SampledCurves,
    held_key_tangents,
    sample_chained_curves,
    sample_curves,
    shared_key_mask,
)
from bezmotion.diffusion.projection import project_onto_handles
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.data.windows import join_windows
from bezmotion.geometry.rotations import quat_rotate
from bezmotion.ik.protocol import Character, IKFn, IKTargets, Pose, solve_frames, targets_from_pose
from bezmotion.pipeline.transfer import Placement, Transfer, curves_to_target, orientations_to_source_space, placement, to_source_space


KEY_BLEND_FRAMES = 6
"""Default frames over which the key poses' correction fades (the control stride: handles untouched)."""


class InbetweenResult(NamedTuple):
    """One in-betweened window of the target character (world frame, cm).

    Attributes:
      pose: :class:`~bezmotion.ik.protocol.Pose` per frame, ``(frames, …)``.
      curves: the BMM curves in the target character's space.
      positions: ``(frames, 6, 3)`` dense characteristic-joint trajectories given to IK.
      rot6d: ``(frames, 6, 6)`` dense characteristic-joint orientations given to IK.
    """

    pose: Pose
    curves: SampledCurves
    positions: Float[Array, "frames 6 3"]
    rot6d: Float[Array, "frames 6 6"]


class WindowCurves(NamedTuple):
    """The curves stage of one window, before IK (target character, world frame, cm).

    Attributes:
      curves: the BMM curves in the target character's space, through every handle.
      positions: ``(frames, 6, 3)`` dense characteristic-joint trajectories.
      rot6d: ``(frames, 6, 6)`` dense characteristic-joint orientations.
    """

    curves: SampledCurves
    positions: Float[Array, "frames 6 3"]
    rot6d: Float[Array, "frames 6 6"]


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


def window_curves_traced(
    bmm: BezierMotionModel,
    character: Character,
    start: Pose,
    end: Pose,
    handles: Handles,
    transfer: Transfer,
    key: Array,
    *,
    steps: int,
    guidance: float,
    foot_lock: bool | str,
    key_orientations: bool = True,
    key_velocity: Float[Array, "2 6 3"] | None = None,
) -> WindowCurves:
    """The first half of :func:`inbetween_traced`: the BMM curves and their dense
    trajectories, which any number of IK modules can then share (:func:`pose_from_curves`).

    ``key_velocity``: optionally ``(2, 6, 3)`` the six joints' velocities at the start and
    at the end pose (cm/frame, target character), where they are known (e.g. from the clip's
    frames around the keys): conditions of the curves like the key orientations
    (:func:`~bezmotion.bmm.sampling.sample_curves`'s ``key_tangent``), met exactly."""
    first, last = targets_from_pose(character, start), targets_from_pose(character, end)
    anchor = placement(transfer, first.position)
    source = functools.partial(to_source_space, transfer, anchor)
    key_rot6d = orientations_to_source_space(transfer, jnp.stack([first.rot6d, last.rot6d]), anchor.turn) if key_orientations else None
    layout = BezierLayout.from_controls(bmm.config.num_controls, bmm.config.stride)
    key_tangent = None if key_velocity is None else tangent_from_velocity(layout, key_velocity)
    curves = sample_curves(
        bmm, source(first.position), source(last.position), handles._replace(position=source(handles.position)),
        key=key, steps=steps, guidance=guidance, foot_lock=foot_lock, key_rot6d=key_rot6d,
        key_tangent=None if key_tangent is None else _tangent_to_source(transfer, anchor, key_tangent),
    )  # fmt: skip
    return _window_in_target(bmm, transfer, anchor, curves, first, last, handles, key_tangent=key_tangent)


def _tangent_to_source(transfer: Transfer, anchor: Placement, tangent: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """Tangents (or velocities) of the target character → the BMM's space: turned and scaled like positions."""
    return quat_rotate(anchor.turn.astype(tangent.dtype), tangent) / transfer.scale


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
) -> WindowCurves:
    """Sampled curves of one window (BMM's space) → the target character's, through its
    keys and handles exactly, and their dense trajectories. ``shared``: control tangents a
    chain shares with the neighbouring windows, which the handle projection keeps;
    ``key_tangent``: the keys' own tangents (target character), set and kept likewise."""
    cfg = bmm.config
    curves = curves_to_target(transfer, anchor, curves)
    ends = jnp.asarray([0, cfg.num_controls - 1])
    if key_tangent is not None:  # exactly, undoing the scale round trip's rounding
        # Where a handle next to a key moved that key's tangent in the sampler, the moved one.
        held = held_key_tangents(handles.frame, handles.joint, handles.valid, cfg.num_controls, curves.ctrl_pos.shape[1], cfg.stride)
        held = held if shared is None else held | shared  # a chain's shared key keeps its tangent
        keyed = curves.ctrl_tangent.at[ends].set(key_tangent)
        curves = curves._replace(ctrl_tangent=jnp.where(held[..., None], keyed, curves.ctrl_tangent))
        shared = held if shared is None else shared | held
    # The end control points are the given poses themselves: their positions exactly
    # (undoing the scale round trip's rounding) and their orientations (which, without
    # ``key_orientations``, the BMM never saw).
    curves = curves._replace(
        ctrl_pos=curves.ctrl_pos.at[ends].set(jnp.stack([first.position, last.position])),
        ctrl_rot6d=curves.ctrl_rot6d.at[ends].set(jnp.stack([first.rot6d, last.rot6d])),
    )
    # The handles exactly again after the transfer: control frames overwritten, handles
    # between them by the minimum-norm correction; the keys' control points stay put.
    layout = BezierLayout.from_controls(cfg.num_controls, cfg.stride)
    keys_fixed = jnp.zeros(curves.ctrl_pos.shape[:2], bool).at[ends].set(True)
    ctrl_pos, ctrl_tangent = project_onto_handles(
        layout, curves.ctrl_pos, curves.ctrl_tangent, handles.joint, handles.frame, handles.position, handles.valid,
        fixed=keys_fixed, fixed_tangent=shared,
    )  # fmt: skip
    curves = curves._replace(ctrl_pos=ctrl_pos, ctrl_tangent=ctrl_tangent)
    positions, rot6d = reconstruct_dense(layout, curves.ctrl_pos, curves.ctrl_tangent, curves.ctrl_rot6d)
    return WindowCurves(curves, positions, rot6d)


def pinned_frames(handles: Handles, num_frames: int) -> Bool[Array, "frames 6"]:
    """``(frames, 6)``: which characteristic joint is held by a (valid) handle at each frame
    of a window or chain (``handles`` unbatched, at its frames), for ``IKTargets.pinned``."""
    hit = (handles.frame[:, None] == jnp.arange(num_frames)[None, :]) & handles.valid[:, None]  # (handles, frames)
    return jnp.any(hit[:, :, None] & (handles.joint[:, None, None] == jnp.arange(len(CHARACTERISTIC_JOINTS))), axis=0)


def pose_from_curves(
    ik_fn: IKFn,
    ik_params: Any,
    window: WindowCurves,
    start: Pose,
    end: Pose,
    *,
    keep_keyframes: bool,
    key_blend_frames: int = 0,
    handles: Handles | None = None,
) -> Pose:
    """The second half of :func:`inbetween_traced`: IK of every frame of ``window``'s dense
    trajectories, with (``keep_keyframes``) the given keys joined in
    (:func:`~bezmotion.ik.protocol.solve_frames`). ``(frames, …)`` poses.

    ``handles`` (unbatched): the IK is told which targets they hold (``IKTargets.pinned``),
    so one that weighs its targets hits them first."""
    pinned = None if handles is None else pinned_frames(handles, window.positions.shape[0])
    return solve_frames(
        ik_fn, ik_params, IKTargets(window.positions, window.rot6d, pinned),
        keys=(start, end) if keep_keyframes else None, key_blend_frames=key_blend_frames,
    )  # fmt: skip


def inbetween_traced(
    bmm: BezierMotionModel,
    ik_params: Any,
    character: Character,
    start: Pose,
    end: Pose,
    handles: Handles,
    transfer: Transfer,
    key: Array,
    *,
    ik_fn: IKFn,
    steps: int,
    guidance: float,
    foot_lock: bool | str,
    keep_keyframes: bool,
    key_blend_frames: int = 0,
    key_orientations: bool = True,
    key_velocity: Float[Array, "2 6 3"] | None = None,
) -> InbetweenResult:
    """The traceable body of :func:`inbetween`, for callers that batch or compile it
    themselves (``jax.vmap`` over windows in :mod:`bezmotion.pipeline.evaluation`).

    Same arguments as :func:`inbetween` (``transfer`` required, ``key`` positional) but no
    input checks and no compiler options: the caller validates and compiles. It is
    :func:`window_curves_traced` followed by :func:`pose_from_curves`.
    """
    window = window_curves_traced(
        bmm, character, start, end, handles, transfer, key,
        steps=steps, guidance=guidance, foot_lock=foot_lock, key_orientations=key_orientations, key_velocity=key_velocity,
    )  # fmt: skip
    pose = pose_from_curves(
        ik_fn, ik_params, window, start, end, keep_keyframes=keep_keyframes, key_blend_frames=key_blend_frames, handles=handles
    )  # fmt: skip
    return InbetweenResult(pose, *window)


def _checked_finite(pose: Pose, name: str) -> Pose:
    """``pose``, after checking that it holds finite numbers only.

    Concrete values are checked here, before compiling (``ValueError``). Inside a caller's
    ``jax.jit`` they are known only at run time, so the check becomes part of that
    computation (``eqx.error_if``: the same message when it runs). Eager calls keep the
    check out of the compiled :func:`inbetween_traced`.
    """
    message = f"the {name} pose contains non-finite values"
    if any(isinstance(x, jax.core.Tracer) for x in pose):
        bad = ~(jnp.isfinite(pose.root_pos).all() & jnp.isfinite(pose.quat_local).all())
        return eqx.error_if(pose, bad, message)
    if not (np.isfinite(np.asarray(pose.root_pos)).all() and np.isfinite(np.asarray(pose.quat_local)).all()):
        raise ValueError(message)
    return pose


@functools.cache
def _compiled(options: tuple[tuple[str, str], ...]):
    return jax.jit(
        inbetween_traced,
        static_argnames=("ik_fn", "steps", "guidance", "foot_lock", "keep_keyframes", "key_blend_frames", "key_orientations"),
        compiler_options=dict(options) or None,
    )  # fmt: skip


def inbetween(
    bmm: BezierMotionModel,
    ik_fn: IKFn,
    ik_params: Any,
    character: Character,
    start: Pose,
    end: Pose,
    handles: Handles,
    *,
    key: Array,
    transfer: Transfer | None = None,
    steps: int = 10,
    guidance: float = 1.0,
    foot_lock: bool | str = False,
    keep_keyframes: bool = True,
    key_blend_frames: int = KEY_BLEND_FRAMES,
    key_orientations: bool = True,
    key_velocity: Float[ArrayLike, "2 6 3"] | None = None,
) -> InbetweenResult:
    """In-between a window of ``character`` from ``start`` to ``end`` through ``handles``.

    Args:
      bmm: a trained BMM (:func:`bezmotion.bmm.sampling.load_model`); its window is
        ``bmm.config.num_frames`` frames (31), the start pose at frame 0, the end at the last.
      ik_fn, ik_params: the character's IK module (one frame; vmapped over the window).
      character: the target skeleton and its characteristic joints.
      start, end: unbatched :class:`~bezmotion.ik.protocol.Pose` of the first and last frame.
      handles: intermediate handles in the target character's world frame
        (:meth:`Handles.from_frames`: joint name, frame 1…29, position in cm).
      key: PRNG key of the diffusion sampler.
      transfer: when the BMM was trained on another skeleton (:meth:`Transfer.between`);
        default none.
      steps, guidance, foot_lock: passed to :func:`~bezmotion.bmm.sampling.sample_curves`.
      keep_keyframes: output the given start and end poses at the first and last frame
        (rather than their IK reconstruction), so the window joins its neighbours exactly.
      key_blend_frames: with ``keep_keyframes``, the keys' difference from the IK's pose
        fades out over this many frames after the start and before the end
        (:func:`~bezmotion.ik.key_blend.blend_to_keys`), so no joint pops next to a
        key; 0 replaces the two frames alone (the behaviour before the blend).
      key_orientations: the start and end poses' global orientations of the six joints are
        conditions of the BMM, overwritten like their positions (``sample_curves``'s
        ``key_rot6d``), so the curves leave and reach the keys facing their way; ``False``
        is the paper's position-only conditioning.
      key_velocity: optionally ``(2, 6, 3)`` the six joints' velocities at the start and at
        the end pose (cm/frame, :data:`CHARACTERISTIC_JOINTS` order), where they are known,
        e.g. :func:`key_velocities` of a clip's frames around the keys: the curves then leave
        and reach the keys at those velocities (conditions met exactly), which keeps the
        limbs from popping next to the keys. Default: the BMM chooses them.
    Returns:
      :class:`InbetweenResult`; its curves pass through every handle exactly, so the
      full-body handle error is the IK module's alone.

    Raises:
      ValueError: poses not of this character, handles not of one motion, a start or
        end pose with non-finite values, or a ``key_velocity`` not of shape ``(2, 6, 3)``
        or not finite.
      equinox.EquinoxRuntimeError: inside a caller's ``eqx.filter_jit``, when the
        computation runs with a non-finite start or end pose (same message, from
        ``eqx.error_if``; a plain ``jax.jit`` re-wraps it in JAX's own runtime error).
    """
    if start.quat_local.shape != (character.num_joints, 4) or end.quat_local.shape != start.quat_local.shape:
        raise ValueError(
            f"start and end must be single poses of {character.name} ({character.num_joints} joints): quat_local "
            f"{start.quat_local.shape}, {end.quat_local.shape}"
        )
    if handles.position.ndim != 2:
        raise ValueError(f"handles must describe one motion ((handles, 3) positions), got {handles.position.shape}")
    start, end = _checked_finite(start, "start"), _checked_finite(end, "end")
    if key_velocity is not None:
        key_velocity = _checked_key_velocity(key_velocity, 2, start.root_pos.dtype, "start and end")
    transfer = Transfer.identity() if transfer is None else transfer
    return call_with_inference_options(
        _compiled, bmm, ik_params, character, start, end, handles, transfer, key,
        ik_fn=ik_fn, steps=steps, guidance=guidance, foot_lock=foot_lock, keep_keyframes=keep_keyframes,
        key_blend_frames=key_blend_frames, key_orientations=key_orientations, key_velocity=key_velocity,
    )  # fmt: skip


def _checked_key_velocity(key_velocity: ArrayLike, keys: int, dtype, which: str) -> Array:
    """``key_velocity`` as a ``(keys, 6, 3)`` array of ``dtype``: raises naming its shape, or
    its values when they are not finite (at run time inside a trace, like :func:`_checked_finite`)."""
    key_velocity = jnp.asarray(key_velocity, dtype)
    if key_velocity.shape != (keys, len(CHARACTERISTIC_JOINTS), 3):
        raise ValueError(f"key_velocity must be ({keys}, 6, 3) ({which}, six joints, cm/frame), got {key_velocity.shape}")
    message = "key_velocity contains non-finite values"
    if isinstance(key_velocity, jax.core.Tracer):  # known at run time only, as _checked_finite's poses
        return eqx.error_if(key_velocity, ~jnp.isfinite(key_velocity).all(), message)
    if not np.isfinite(np.asarray(key_velocity)).all():
        raise ValueError(f"{message}: {np.asarray(key_velocity).tolist()}")
    return key_velocity


class ChainResult(NamedTuple):
    """A chain of in-betweened windows through ``keys`` key poses (target character, world frame, cm).

    With 31-frame windows the motion has ``(keys − 1)·30 + 1`` frames, key ``k`` at frame
    ``30·k`` (each shared key once).

    Attributes:
      pose: :class:`~bezmotion.ik.protocol.Pose` per frame of the whole motion, ``(frames, …)``.
      curves: the BMM curves of each window in the target character's space, batched
        ``(keys − 1, controls, …)``; window ``i`` runs from key ``i`` to key ``i + 1``.
      positions: ``(frames, 6, 3)`` dense characteristic-joint trajectories given to IK.
      rot6d: ``(frames, 6, 6)`` dense characteristic-joint orientations given to IK.
    """

    pose: Pose
    curves: SampledCurves
    positions: Float[Array, "frames 6 3"]
    rot6d: Float[Array, "frames 6 6"]


def chain_curves_traced(
    bmm: BezierMotionModel,
    character: Character,
    keys: Pose,
    handles: Handles,
    transfer: Transfer,
    key: Array,
    *,
    steps: int,
    guidance: float,
    foot_lock: bool | str,
    coupled: bool = True,
    key_orientations: bool = True,
    key_velocity: Float[Array, "keys 6 3"] | None = None,
) -> WindowCurves:
    """:func:`window_curves_traced` for a chain: the curves of every window between
    consecutive ``keys`` (batched ``(keys, …)``) from one
    :func:`~bezmotion.bmm.sampling.sample_chained_curves` call, and their dense
    trajectories, batched ``(keys − 1, …)``. One transfer anchor (the first key's hips on
    the floor) for the whole chain, so a shared key is one point in the BMM's space too.
    ``key_velocity``: optionally ``(keys, 6, 3)`` the six joints' velocities at every key
    (cm/frame, target character), conditions met exactly, by both windows of a shared key."""
    targets = targets_from_pose(character, keys)  # (keys, 6, ·)
    anchor = placement(transfer, targets.position[0])
    source = functools.partial(to_source_space, transfer, anchor)
    key_rot6d = orientations_to_source_space(transfer, targets.rot6d, anchor.turn) if key_orientations else None
    windows, cfg = targets.position.shape[0] - 1, bmm.config
    layout = BezierLayout.from_controls(cfg.num_controls, cfg.stride)
    key_tangent = None if key_velocity is None else tangent_from_velocity(layout, key_velocity)
    curves = sample_chained_curves(
        bmm, source(targets.position), handles._replace(position=source(handles.position)),
        key=key, steps=steps, guidance=guidance, coupled=coupled, foot_lock=foot_lock, key_rot6d=key_rot6d,
        key_tangent=None if key_tangent is None else _tangent_to_source(transfer, anchor, key_tangent),
    )  # fmt: skip
    # The handle projection after the transfer must keep the tangents the chain shares.
    shared = shared_key_mask(windows, cfg.num_controls, cfg.num_joints) if coupled else None
    first = jax.tree.map(lambda a: a[:-1], targets)
    last = jax.tree.map(lambda a: a[1:], targets)
    tangent_pairs = None if key_tangent is None else jnp.stack([key_tangent[:-1], key_tangent[1:]], axis=1)  # (windows, 2, 6, 3)
    finish = functools.partial(_window_in_target, bmm, transfer, anchor)
    return jax.vmap(finish)(curves, first, last, handles, shared, tangent_pairs)


def join_chain_curves(curves: SampledCurves) -> SampledCurves:
    """A chain's curves, batched per window ``(windows, controls, …)`` (``ChainResult.curves``),
    as one curve through every key ``(windows·(controls − 1) + 1, …)``: each shared key's
    control point once (the earlier window's). A coupled chain's windows share it bit for
    bit (position, tangent, orientation and contacts), so the joined curve is the same
    motion, C¹ at the keys, for anything that takes one window's curves (glTF, preview)."""
    return jax.tree.map(join_windows, curves)


def pose_from_chain_curves(
    ik_fn: IKFn,
    ik_params: Any,
    windows: WindowCurves,
    keys: Pose,
    *,
    keep_keyframes: bool,
    key_blend_frames: int = 0,
    handles: Handles | None = None,
) -> Pose:
    """:func:`pose_from_curves` for a chain: one IK over the chain's joined frames, then
    (``keep_keyframes``) each window's frames blended to its two keys.

    Args:
      windows: the chain's curves stage (:func:`chain_curves_traced`), batched
        ``(keys − 1, …)``; only its dense ``positions`` and ``rot6d`` are read.
      keys: :class:`~bezmotion.ik.protocol.Pose` of every key, batched ``(keys, …)``.
      handles: each window's handles ``(keys − 1, handles)`` at its own frames, pinned
        for the IK (:func:`pose_from_curves`); ``None``: none.
    Returns:
      ``((keys − 1)·(window_frames − 1) + 1, …)`` poses, the given keys exactly at the key
      frames with ``keep_keyframes``.
    """
    positions, rot6d = join_windows(windows.positions), join_windows(windows.rot6d)
    frames = windows.positions.shape[1]
    pinned = None if handles is None else join_windows(jax.vmap(lambda h: pinned_frames(h, frames))(handles))
    # One IK over the whole chain (an IK that smooths over time sees across the keys), each
    # window joined to its two keys: the fades of neighbouring windows meet only at their
    # shared key, where both put that key exactly. An IK that solves whole windows (the
    # exact one) starts from poses already joined to the keys and holds their neighbours.
    return solve_frames(
        ik_fn, ik_params, IKTargets(positions, rot6d, pinned), keys=keys if keep_keyframes else None, key_blend_frames=key_blend_frames
    )


def inbetween_chain_traced(
    bmm: BezierMotionModel,
    ik_params: Any,
    character: Character,
    keys: Pose,
    handles: Handles,
    transfer: Transfer,
    key: Array,
    *,
    ik_fn: IKFn,
    steps: int,
    guidance: float,
    foot_lock: bool | str,
    keep_keyframes: bool,
    key_blend_frames: int = 0,
    coupled: bool = True,
    key_orientations: bool = True,
    key_velocity: Float[Array, "keys 6 3"] | None = None,
) -> ChainResult:
    """The traceable body of :func:`inbetween_chain` (no input checks, no compiler options)."""
    windows = chain_curves_traced(
        bmm, character, keys, handles, transfer, key,
        steps=steps, guidance=guidance, foot_lock=foot_lock, coupled=coupled, key_orientations=key_orientations,
        key_velocity=key_velocity,
    )  # fmt: skip
    pose = pose_from_chain_curves(
        ik_fn, ik_params, windows, keys, keep_keyframes=keep_keyframes, key_blend_frames=key_blend_frames, handles=handles
    )
    return ChainResult(pose, windows.curves, join_windows(windows.positions), join_windows(windows.rot6d))


@functools.cache
def _compiled_chain(options: tuple[tuple[str, str], ...]):
    return jax.jit(
        inbetween_chain_traced,
        static_argnames=(
            "ik_fn", "steps", "guidance", "foot_lock", "keep_keyframes", "key_blend_frames", "coupled", "key_orientations",
        ),
        compiler_options=dict(options) or None,
    )  # fmt: skip


def _checked_chain_handles(handles: Handles, windows: int, num_frames: int) -> None:
    """Handles of a chain, when concrete: ``(windows, handles)`` slots, valid ones on frames
    strictly inside their window and at finite positions (padding may hold anything)."""
    shape = handles.position.shape
    if len(shape) != 3 or shape[:1] != (windows,) or shape[-1] != 3:
        raise ValueError(f"handles must be ({windows}, handles, 3) positions (one row per window), got {shape}")
    for name in ("joint", "frame", "valid"):
        if getattr(handles, name).shape != shape[:2]:
            raise ValueError(f"handles.{name} must be {shape[:2]} like the positions, got {getattr(handles, name).shape}")
    if any(isinstance(x, jax.core.Tracer) for x in handles):
        return
    valid = np.asarray(handles.valid)
    frame = np.asarray(handles.frame)
    outside = valid & ((frame < 1) | (frame > num_frames - 2))
    if outside.any():
        raise ValueError(
            f"handle frames are within each window, 1 … {num_frames - 2}; got {frame[outside].tolist()} "
            f"(window, slot) {np.argwhere(outside).tolist()}"
        )
    bad = valid & ~np.isfinite(np.asarray(handles.position)).all(axis=-1)
    if bad.any():
        raise ValueError(f"handle positions must be finite; (window, slot) {np.argwhere(bad).tolist()} are not")


def inbetween_chain(
    bmm: BezierMotionModel,
    ik_fn: IKFn,
    ik_params: Any,
    character: Character,
    keys: Pose,
    handles: Handles,
    *,
    key: Array,
    coupled: bool = True,
    transfer: Transfer | None = None,
    steps: int = 10,
    guidance: float = 1.0,
    foot_lock: bool | str = False,
    keep_keyframes: bool = True,
    key_blend_frames: int = KEY_BLEND_FRAMES,
    key_orientations: bool = True,
    key_velocity: Float[ArrayLike, "keys 6 3"] | None = None,
) -> ChainResult:
    """In-between ``character`` through ``keys`` key poses ``bmm.config.num_frames − 1`` (30)
    frames apart, with handles anywhere between them: one window per pair of consecutive
    keys, all sampled in one batched call (:func:`~bezmotion.bmm.sampling.sample_chained_curves`),
    then one IK over the whole motion. One compilation per shape.

    Args:
      bmm, ik_fn, ik_params, character: as in :func:`inbetween`.
      keys: :class:`~bezmotion.ik.protocol.Pose` of every key, batched ``(keys, …)``, ``keys ≥ 2``.
      handles: each window's handles, batched ``(keys − 1, handles)``: window ``i``'s
        frames 1 … 29 lie between key ``i`` and key ``i + 1`` (the chain's frames
        ``30·i + 1 … 30·i + 29``); pad with ``valid=False`` to give windows different counts.
      key: PRNG key of the diffusion sampler.
      coupled: join the windows C¹ at their shared keys (the same tangent, orientation and
        contacts on both sides); ``False`` samples them independently (BMM Appendix D.1),
        for comparison.
      transfer, steps, guidance, foot_lock, keep_keyframes, key_blend_frames,
        key_orientations: as in :func:`inbetween`, applied to every window.
      key_velocity: optionally ``(keys, 6, 3)`` the six joints' velocities at every key
        (cm/frame), e.g. :func:`chain_key_velocities` of the clip around the keys: the
        curves pass every key at that velocity (both windows of a shared key), as
        :func:`inbetween`'s ``key_velocity`` does for one window.
    Returns:
      :class:`ChainResult`: ``(keys − 1)·30 + 1`` frames, exactly the given keys at frames
      ``0, 30, 60, …`` with ``keep_keyframes``; the curves pass through every handle.

    Raises:
      ValueError: fewer than two keys, keys not poses of this character, handles not
        ``(keys − 1, handles)``, a valid handle outside its window or at a non-finite
        position, a key with non-finite values (naming it), or a ``key_velocity`` not
        ``(keys, 6, 3)`` or not finite.
    """
    num_keys = keys.root_pos.shape[0] if keys.root_pos.ndim == 2 else None
    if num_keys is None or keys.quat_local.shape != (num_keys, character.num_joints, 4):
        raise ValueError(
            f"keys must be poses of {character.name} batched (keys, …): root_pos (keys, 3), quat_local "
            f"(keys, {character.num_joints}, 4); got {keys.root_pos.shape}, {keys.quat_local.shape}"
        )
    if num_keys < 2:
        raise ValueError(f"a chain needs at least 2 keys, got {num_keys}")
    _checked_chain_handles(handles, num_keys - 1, bmm.config.num_frames)
    checked = [_checked_finite(jax.tree.map(lambda a, k=k: a[k], keys), f"key {k}") for k in range(num_keys)]
    keys = Pose(*(jnp.stack(a) for a in zip(*checked)))
    if key_velocity is not None:
        key_velocity = _checked_key_velocity(key_velocity, num_keys, keys.root_pos.dtype, "one per key")
    transfer = Transfer.identity() if transfer is None else transfer
    return call_with_inference_options(
        _compiled_chain, bmm, ik_params, character, keys, handles, transfer, key,
        ik_fn=ik_fn, steps=steps, guidance=guidance, foot_lock=foot_lock, keep_keyframes=keep_keyframes,
        key_blend_frames=key_blend_frames, coupled=coupled, key_orientations=key_orientations, key_velocity=key_velocity,
    )  # fmt: skip
