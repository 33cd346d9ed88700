"""In-betweens through keys at any frames: ``[0, 20, 65, 90]``, each gap its own window.

:func:`inbetween_at` takes the keys' frames. Keys evenly spaced are :func:`inbetween`'s
chain (one program, its windows coupled at the shared keys). Keys at unequal distances are
in-betweened one window after another, each of its own length: at each shared key one
window chooses the velocity and the other takes it (where ``key_velocity`` does not give
it), so the joined curves are C¹ at every key as a coupled chain's are. One
compiled program per distinct gap (a gap seen before reuses its program).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from bezmotion.bezier import JoinedLayout, velocity_from_tangent
from bezmotion.bmm.sampling import MAX_WINDOW_FRAMES, Handles, SampledCurves
from bezmotion.data.windows import join_unequal_windows
from bezmotion.ik.protocol import Pose
from bezmotion.pipeline.inbetweening import InbetweenOptions, InbetweenResult, _check_shapes, handles_per_window, inbetween

if TYPE_CHECKING:
    from bezmotion.pipeline.model import Inbetweener


@dataclasses.dataclass(frozen=True)
class TimedInbetween:
    """An in-between through keys at given frames (target character, world frame, cm).

    Frame ``f`` of the motion is frame ``times[0] + f`` of the caller's count; key ``k`` is at
    motion frame ``layout.key_frames[k]``.

    Attributes:
      pose: :class:`~bezmotion.ik.protocol.Pose` per frame, ``(frames, …)``.
      curves: one curve through every key, ``(controls, …)`` on ``layout``
        (:class:`~bezmotion.bezier.JoinedLayout`): each window's control points, each key once.
      positions: ``(frames, 6, 3)`` dense characteristic-joint trajectories given to IK.
      rot6d: ``(frames, 6, 6)`` dense characteristic-joint orientations given to IK.
      layout: where the control points and the keys sit in time.
      times: the keys' frames as given.
      windows: the :class:`~bezmotion.pipeline.inbetweening.InbetweenResult` s it is made of:
        one chain for evenly spaced keys, else one per pair of consecutive keys.
    """

    pose: Pose
    curves: SampledCurves
    positions: Float[Array, "frames 6 3"]
    rot6d: Float[Array, "frames 6 6"]
    layout: JoinedLayout
    times: tuple[int, ...]
    windows: tuple[InbetweenResult, ...]

    def joined_curves(self) -> SampledCurves:
        """:attr:`curves` (as :meth:`InbetweenResult.joined_curves`)."""
        return self.curves


def checked_key_times(times: Sequence[int] | ArrayLike, num_keys: int) -> tuple[int, ...]:
    """``times`` as a tuple of ints, after checking there is one per key, increasing, each gap
    2 … :data:`~bezmotion.bmm.sampling.MAX_WINDOW_FRAMES` − 1 frames.

    Raises:
      ValueError: naming the offending value.
    """
    array = np.asarray(times)
    if array.ndim != 1 or array.dtype.kind not in "iu":
        raise ValueError(f"times must be the keys' frames, integers in a list, got {times!r}")
    if len(array) != num_keys:
        raise ValueError(f"times must give one frame per key ({num_keys}), got {len(array)}: {array.tolist()}")
    gaps = np.diff(array)
    bad = np.flatnonzero((gaps < 2) | (gaps >= MAX_WINDOW_FRAMES))
    if len(bad):
        i = int(bad[0])
        raise ValueError(
            f"times must increase by 2 … {MAX_WINDOW_FRAMES - 1} frames from one key to the next, got {array.tolist()} "
            f"(keys {i} and {i + 1} are {int(gaps[i])} apart)"
        )
    return tuple(int(t) for t in array)


def _placed_handles(handles: Handles, times: tuple[int, ...]) -> Handles:
    """``handles`` (frames in ``times``' count) with frames counted from the first key, after
    checking every valid one lies strictly between the first and last keys, off every key."""
    frame = np.asarray(handles.frame) - times[0]
    valid = np.asarray(handles.valid, bool)
    keys = np.asarray(times) - times[0]
    misplaced = valid & ((frame <= 0) | (frame >= keys[-1]) | np.isin(frame, keys))
    if misplaced.any():
        i = int(np.flatnonzero(misplaced)[0])
        raise ValueError(
            f"handle {i}: frame {int(handles.frame[i])} is outside the in-between or on a key: handles go on the frames "
            f"strictly between {times[0]} and {times[-1]}, off the keys' frames {list(times)}"
        )
    return handles._replace(frame=jnp.asarray(frame, jnp.asarray(handles.frame).dtype))


def _where_unknown(velocity: Float[Array, "6 3"], layout: JoinedLayout, tangent: Float[Array, "6 3"]) -> Float[Array, "6 3"]:
    """``velocity`` where known, else the velocity of a neighbouring window's ``tangent`` at the key."""
    return jnp.where(jnp.isnan(velocity), velocity_from_tangent(layout, tangent), velocity)


def _joined(results: Sequence[InbetweenResult], layout: JoinedLayout, times: tuple[int, ...]) -> TimedInbetween:
    join = lambda *parts: join_unequal_windows(parts)  # noqa: E731
    return TimedInbetween(
        pose=jax.tree.map(join, *(r.pose for r in results)),
        curves=jax.tree.map(join, *(r.joined_curves() for r in results)),
        positions=join(*(r.positions for r in results)),
        rot6d=join(*(r.rot6d for r in results)),
        layout=layout,
        times=times,
        windows=tuple(results),
    )


def inbetween_at(
    model: Inbetweener,
    keys: Pose,
    times: Sequence[int] | ArrayLike,
    handles: Handles | None = None,
    *,
    key: Array,
    options: InbetweenOptions = InbetweenOptions(),
    key_velocity: Float[ArrayLike, "keys 6 3"] | None = None,
) -> TimedInbetween:
    """In-between ``model``'s character through ``keys`` at the frames ``times``.

    Evenly spaced keys are one :func:`~bezmotion.pipeline.inbetweening.inbetween` (a chain
    where its windows can share their control points: its spacing a multiple of the stride,
    6 frames, or ``options.coupled`` off). Otherwise each pair of consecutive keys is a window
    of its own length; with ``options.coupled``, one of the two windows at each shared key
    chooses the velocity there and the other takes it (unless ``key_velocity`` gives it), so
    the motion is C¹ at the keys: the window after the key where a handle lies within a
    stride (6 frames) after it, else the window before. (Handles on the same joint within a
    stride on both sides of a key free that joint's velocity in both windows: it may differ.) Runs on the host (a Python loop over the
    windows): inside a ``jax.jit``, use :func:`inbetween` with evenly spaced keys.

    Args:
      model: the BMM, IK, character and transfer.
      keys: :class:`~bezmotion.ik.protocol.Pose` of ``K ≥ 2`` key poses batched ``(K, …)``.
      times: ``(K,)`` the keys' frames, increasing, each 2 … 900 frames after the one before
        (at the BMM's 30 fps), e.g. ``[0, 20, 65, 90]``.
      handles: where joints must be, their frames in ``times``' count (strictly between the
        first and last key, off the keys), target character's world frame, cm; ``None``: none.
      key: PRNG key of the diffusion sampler (window ``i`` of unequal keys draws with
        ``jax.random.fold_in(key, i)``).
      options: :class:`~bezmotion.pipeline.inbetweening.InbetweenOptions`.
      key_velocity: optionally ``(K, 6, 3)`` the six joints' velocities at every key
        (cm/frame); NaN for one not known.
    Returns:
      :class:`TimedInbetween` of ``times[-1] − times[0] + 1`` frames, through every key and
      every handle exactly (on its curves).
    Raises:
      ValueError: keys, handles or ``key_velocity`` of the wrong shape, ``times`` not one
        increasing frame per key 2 … 900 apart, a handle outside the in-between or on a key,
        and what :func:`~bezmotion.pipeline.inbetweening.inbetween` refuses in a window.
    """
    handles = Handles.empty() if handles is None else handles
    num_keys = _check_shapes(model, keys, handles, key_velocity)
    times = checked_key_times(times, num_keys)
    handles = _placed_handles(handles, times)
    spans = tuple(int(s) for s in np.diff(times))
    stride = model.bmm.config.stride
    layout = JoinedLayout.of(spans, stride)
    if len(set(spans)) == 1 and (num_keys == 2 or spans[0] % stride == 0 or not options.coupled):
        result = inbetween(model, keys, handles, key=key, options=options, key_velocity=key_velocity, span=spans[0])
        return _joined([result], layout, times)
    given = jnp.full((num_keys, 6, 3), jnp.nan, keys.root_pos.dtype) if key_velocity is None else jnp.asarray(key_velocity, keys.root_pos.dtype)
    per_window = handles_per_window(handles, layout.key_frames)
    # Which window sets each shared key's tangent for the other: the one after it where a
    # handle within a stride after the key frees that tangent there (as the sampler does),
    # else the one before it.
    frame, valid = np.asarray(per_window.frame), np.asarray(per_window.valid)
    later_sets = [False] + [bool((valid[k] & (frame[k] < min(stride, spans[k]))).any()) for k in range(1, num_keys - 1)] + [False]
    windows = len(spans)
    done: dict[int, InbetweenResult] = {}
    while len(done) < windows:
        for i in range(windows):
            before = options.coupled and i > 0 and not later_sets[i]  # key i's tangent from window i − 1
            after = options.coupled and i + 1 < windows and later_sets[i + 1]  # key i + 1's from window i + 1
            if i in done or (before and i - 1 not in done) or (after and i + 1 not in done):
                continue
            velocity = given[i : i + 2]
            if before:
                velocity = velocity.at[0].set(_where_unknown(velocity[0], layout, done[i - 1].curves.ctrl_tangent[-1, -1]))
            if after:
                velocity = velocity.at[1].set(_where_unknown(velocity[1], layout, done[i + 1].curves.ctrl_tangent[0, 0]))
            done[i] = inbetween(
                model, jax.tree.map(lambda a: a[i : i + 2], keys), jax.tree.map(lambda a: a[i], per_window),
                key=jax.random.fold_in(key, i), options=options, key_velocity=None if bool(jnp.isnan(velocity).all()) else velocity,
                span=spans[i],
            )  # fmt: skip
    results = [done[i] for i in range(windows)]
    return _joined(results, layout, times)


__all__ = ["TimedInbetween", "checked_key_times", "inbetween_at"]
