"""Piecewise cubic Bézier motion curves with symmetric (C1) tangents (BMM §3.2, §4.1).

A curve over a window of ``num_frames`` frames has a control point every ``stride``
frames — frames ``0, s, 2s, …`` — plus one on the last frame when ``num_frames - 1`` is
not a multiple of ``s`` (so a 31-frame window has 6 control points at stride 6, and 9 at
stride 4, the last segment 2 frames long). Control point ``k`` carries a position
``ctrl_pos[k]`` and a tangent ``ctrl_tangent[k]``; segment ``k`` (frames ``f_k … f_{k+1}``,
length ``d_k``) is the cubic Bézier with the four points

    P_k,   P_k + a_k·T_k,   P_{k+1} − a_k·T_{k+1},   P_{k+1},      a_k = d_k / s,

so the handles on either side of a control point are mirror images (symmetric tangents)
and the velocity ``3·T_k / s`` (units per frame) is continuous across every control point
(C1, also across a shorter last segment). For the usual full-stride segments ``a_k = 1``
and ``T_k`` is simply the handle offset an animation tool stores.

Everything here is pure and batch-polymorphic: curves are ``(*batch, controls, dim)``
arrays and evaluation is linear in them, ``x(f) = Σ_k w_pos[f, k]·P_k + w_tan[f, k]·T_k``
(:func:`basis`). Fitting (:func:`fit_curves`) is a least-squares problem solved with
optimistix. Orientations between control points are slerped (:func:`interpolate_rotations`).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from bezmotion.geometry.rotations import quat_from_rot6d, rot6d_from_quat, slerp
from bezmotion._src.linalg import exact_einsum, exact_matmul

DEFAULT_STRIDE = 6  # frames between control points (BMM appendix A.2)


@dataclasses.dataclass(frozen=True)
class BezierLayout:
    """Where the control points of a window sit in time (static, hashable: a jit argument).

    Attributes:
      num_frames: window length in frames (≥ 2).
      stride: frames between consecutive control points (≥ 1).
    """

    num_frames: int | np.integer
    stride: int | np.integer = DEFAULT_STRIDE

    def __post_init__(self):
        for name in ("num_frames", "stride"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ValueError(f"BezierLayout.{name} must be an integer, got {value!r}")
            object.__setattr__(self, name, int(value))  # plain ints: hashable, JSON-friendly
        if self.num_frames < 2:
            raise ValueError(f"BezierLayout needs at least 2 frames, got num_frames={self.num_frames}")
        if self.stride < 1:
            raise ValueError(f"BezierLayout.stride must be ≥ 1, got {self.stride}")

    @property
    def control_frames(self) -> np.ndarray:
        """``(controls,)`` int frame index of every control point, 0 first, the last frame last."""
        last = self.num_frames - 1
        frames = np.arange(0, last + 1, self.stride)
        return frames if frames[-1] == last else np.append(frames, last)

    @property
    def num_controls(self) -> int:
        return len(self.control_frames)

    @property
    def num_segments(self) -> int:
        return self.num_controls - 1

    @property
    def last_control(self) -> int:
        """Index of the last control point (:class:`PaddedLayout`'s is traced)."""
        return self.num_controls - 1

    @property
    def control_valid(self) -> np.ndarray:
        """``(controls,)`` which control points are the window's: all (padding in :class:`PaddedLayout`)."""
        return np.ones(self.num_controls, bool)

    @property
    def frame_valid(self) -> np.ndarray:
        """``(frames,)`` which frames are the window's: all (padding in :class:`PaddedLayout`)."""
        return np.ones(self.num_frames, bool)

    @property
    def segment_lengths(self) -> np.ndarray:
        """``(segments,)`` frames spanned by each segment (all ``stride`` except maybe the last)."""
        return np.diff(self.control_frames)

    def frames(self) -> np.ndarray:
        """``(num_frames,)`` the integer frame times ``0 … num_frames − 1`` as float64."""
        return np.arange(self.num_frames, dtype=np.float64)

    def segment_of(self, frames: Float[Array, "*shape"]) -> Int[Array, "*shape"]:
        """The segment each frame time falls in (the first or last outside the window)."""
        return jnp.clip(jnp.floor(frames / self.stride).astype(jnp.int32), 0, self.num_segments - 1)

    @classmethod
    def from_controls(cls, num_controls: int | np.integer, stride: int | np.integer = DEFAULT_STRIDE) -> BezierLayout:
        """The layout of ``num_controls`` control points ``stride`` frames apart."""
        if num_controls < 2:
            raise ValueError(f"a curve needs at least 2 control points, got {num_controls}")
        return cls((num_controls - 1) * stride + 1, stride)


@dataclasses.dataclass(frozen=True, eq=False)
class PaddedLayout(BezierLayout):
    """The layout of a window whose length is a traced value, on a fixed-size grid: what one
    compiled training step uses to learn windows of many lengths at once.

    The window has ``num_frames`` frames (a traced int32 scalar, 2 … ``max_frames``) and its
    control points are :class:`BezierLayout`'s for that length; the arrays are padded to
    ``BezierLayout(max_frames, stride)``'s control count and to ``max_frames`` frames. The
    padding continues the grid past the last frame (``last + stride``, ``last + 2·stride``,
    …), so the frames stay increasing and every padding segment has a non-zero length: the
    window's own frames evaluate exactly as under its :class:`BezierLayout`, and
    :attr:`control_valid` / :attr:`frame_valid` mark what is the window's.

    Attributes:
      num_frames: the window's frames (traced, int32 scalar).
      stride: frames between control points (static).
      max_frames: the padded frame count (static).
    """

    num_frames: Int[ArrayLike, ""]
    stride: int = DEFAULT_STRIDE
    max_frames: int = 0

    def __post_init__(self):
        if not isinstance(self.max_frames, int) or self.max_frames < 2:
            raise ValueError(f"PaddedLayout.max_frames must be an integer ≥ 2, got {self.max_frames!r}")
        if not isinstance(self.stride, int) or self.stride < 1:
            raise ValueError(f"PaddedLayout.stride must be an integer ≥ 1, got {self.stride!r}")

    @property
    def num_controls(self) -> int:
        return BezierLayout(self.max_frames, self.stride).num_controls

    @property
    def last_control(self) -> Int[Array, ""]:
        """Index of the window's last control point (its last frame)."""
        return (self.num_frames - 2) // self.stride + 1

    @property
    def control_frames(self) -> Int[Array, "controls"]:
        k = jnp.arange(self.num_controls, dtype=jnp.int32)
        last, end = self.last_control, jnp.asarray(self.num_frames, jnp.int32) - 1
        return jnp.where(k < last, k * self.stride, end + (k - last) * self.stride)

    @property
    def segment_lengths(self) -> Int[Array, "segments"]:
        return jnp.diff(self.control_frames)

    @property
    def control_valid(self) -> Bool[Array, "controls"]:
        return jnp.arange(self.num_controls) <= self.last_control

    @property
    def frame_valid(self) -> Bool[Array, "frames"]:
        return jnp.arange(self.max_frames) < self.num_frames

    def frames(self) -> Float[Array, "frames"]:
        return jnp.arange(self.max_frames, dtype=jnp.float32)


@dataclasses.dataclass(frozen=True)
class JoinedLayout(BezierLayout):
    """Windows of several lengths joined end to end at their keys: keys any distance apart.

    Window ``i`` spans ``spans[i]`` frames, from key ``i`` to key ``i + 1``, with
    :class:`BezierLayout`'s control points (every ``stride`` frames from its first key, its
    last segment shorter where its span is not a multiple of ``stride``); each key is one
    control point, the last of one window and the first of the next. Tangents keep the
    module's convention (velocity ``3·T / stride`` at every control point), so a curve on this
    layout is C¹ at the keys as everywhere else. With equal spans that are multiples of
    ``stride`` it is :class:`BezierLayout`'s grid.

    Attributes:
      num_frames: ``sum(spans) + 1`` (:meth:`of` computes it).
      stride: frames between control points within a window.
      spans: frames from each key to the next (each ≥ 1).
    """

    spans: tuple[int, ...] = ()

    def __post_init__(self):
        super().__post_init__()
        spans = tuple(self.spans)
        if not spans or any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 1 for s in spans):
            raise ValueError(f"JoinedLayout.spans must be one or more integers ≥ 1, got {self.spans!r}")
        object.__setattr__(self, "spans", tuple(int(s) for s in spans))
        if self.num_frames != sum(self.spans) + 1:
            raise ValueError(f"JoinedLayout.num_frames must be sum(spans) + 1 = {sum(self.spans) + 1}, got {self.num_frames}")

    @classmethod
    def of(cls, spans, stride: int | np.integer = DEFAULT_STRIDE) -> JoinedLayout:
        """The layout of windows ``spans`` frames long (keys ``spans[i]`` frames apart), joined."""
        spans = tuple(spans)
        return cls(sum(int(s) for s in spans) + 1, stride, spans)

    @property
    def key_frames(self) -> np.ndarray:
        """``(windows + 1,)`` the keys' frames: 0, then each window's last."""
        return np.concatenate([[0], np.cumsum(self.spans)])

    @property
    def key_controls(self) -> np.ndarray:
        """``(windows + 1,)`` the index of each key's control point."""
        return np.searchsorted(self.control_frames, self.key_frames)

    @property
    def control_frames(self) -> np.ndarray:
        starts = self.key_frames[:-1]
        inner = [start + BezierLayout(span + 1, self.stride).control_frames[:-1] for start, span in zip(starts, self.spans)]
        return np.concatenate([*inner, [self.num_frames - 1]])

    def segment_of(self, frames: Float[Array, "*shape"]) -> Int[Array, "*shape"]:
        inner = jnp.asarray(self.control_frames[1:-1], frames.dtype)
        return jnp.clip(jnp.searchsorted(inner, frames, side="right").astype(jnp.int32), 0, self.num_segments - 1)


def bernstein(t: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 4"]:
    """The four cubic Bernstein polynomials ``C(3,i)·(1−t)^(3−i)·t^i`` at ``t`` (Eq. 3)."""
    t = jnp.asarray(t)
    u = 1.0 - t
    return jnp.stack([u * u * u, 3.0 * u * u * t, 3.0 * u * t * t, t * t * t], axis=-1)


def locate(
    layout: BezierLayout, frames: Real[ArrayLike, "*shape"]
) -> tuple[Int[Array, "*shape"], Float[Array, "*shape"]]:
    """Segment index and local parameter ``t ∈ [0, 1]`` of each (fractional) frame time.

    Frames outside ``[0, num_frames − 1]`` extrapolate the first or last segment's cubic
    (``t`` outside ``[0, 1]``); the last frame belongs to the last segment at ``t = 1``.
    """
    frames = jnp.asarray(frames)
    if not jnp.issubdtype(frames.dtype, jnp.floating):
        frames = frames.astype(jnp.result_type(float))
    segment = layout.segment_of(frames)
    starts = jnp.asarray(layout.control_frames[:-1], frames.dtype)
    lengths = jnp.asarray(layout.segment_lengths, frames.dtype)
    t = (frames - starts[segment]) / lengths[segment]
    return segment, t


def basis(
    layout: BezierLayout, frames: Real[ArrayLike, "frames"] | None = None
) -> tuple[Float[Array, "frames controls"], Float[Array, "frames controls"]]:
    """Weights of the control positions and tangents at each frame time.

    ``evaluate(...)[f] = w_pos[f] @ ctrl_pos + w_tan[f] @ ctrl_tangent``. At most two
    control points have non-zero weight at any frame.

    Args:
      layout: the control-point layout.
      frames: ``(frames,)`` frame times (may be fractional); default every integer frame.
    Returns:
      ``(w_pos, w_tan)``, each ``(frames, controls)``.
    """
    frames = layout.frames() if frames is None else frames
    segment, t = locate(layout, frames)
    b = bernstein(t)
    scale = jnp.asarray(layout.segment_lengths / layout.stride, t.dtype)[segment]
    first = jax.nn.one_hot(segment, layout.num_controls, dtype=t.dtype)
    second = jax.nn.one_hot(segment + 1, layout.num_controls, dtype=t.dtype)
    w_pos = (b[:, 0] + b[:, 1])[:, None] * first + (b[:, 2] + b[:, 3])[:, None] * second
    w_tan = (scale * b[:, 1])[:, None] * first - (scale * b[:, 2])[:, None] * second
    return w_pos, w_tan


def _check_frames(layout: BezierLayout, points: Array) -> None:
    if points.ndim < 2 or points.shape[-2] != layout.num_frames:
        raise ValueError(f"expected (..., {layout.num_frames}, dim) points for {layout}, got shape {points.shape}")


def _check_controls(layout: BezierLayout, *arrays: Array) -> None:
    for a in arrays:
        if a.ndim < 2 or a.shape[-2] != layout.num_controls:
            raise ValueError(
                f"expected (..., {layout.num_controls}, dim) control arrays for {layout}, got shape {a.shape}"
            )


def evaluate(
    layout: BezierLayout,
    ctrl_pos: Float[Array, "*batch controls dim"],
    ctrl_tangent: Float[Array, "*batch controls dim"],
    frames: Real[ArrayLike, "frames"] | None = None,
) -> Float[Array, "*batch frames dim"]:
    """Evaluate curves at frame times (Bernstein form, Eq. 3).

    Args:
      layout: the control-point layout.
      ctrl_pos, ctrl_tangent: ``(*batch, controls, dim)`` control positions and tangents
        (same units, e.g. cm).
      frames: ``(frames,)`` frame times, fractional allowed; default every integer frame.
    Returns:
      ``(*batch, frames, dim)`` points on the curves.
    """
    ctrl_pos, ctrl_tangent = jnp.asarray(ctrl_pos), jnp.asarray(ctrl_tangent)
    _check_controls(layout, ctrl_pos, ctrl_tangent)
    w_pos, w_tan = basis(layout, frames)
    dtype = jnp.result_type(ctrl_pos, ctrl_tangent)
    return exact_einsum("fk,...kd->...fd", w_pos.astype(dtype), ctrl_pos) + exact_einsum("fk,...kd->...fd", w_tan.astype(dtype), ctrl_tangent)


def to_segments(
    layout: BezierLayout,
    ctrl_pos: Float[Array, "*batch controls dim"],
    ctrl_tangent: Float[Array, "*batch controls dim"],
) -> Float[Array, "*batch segments 4 dim"]:
    """The explicit 4-point form of every segment, as animation tools store it.

    Segment ``k`` is ``(P_k, P_k + a_k T_k, P_{k+1} − a_k T_{k+1}, P_{k+1})``, ``a_k = d_k/s``.
    """
    ctrl_pos, ctrl_tangent = jnp.asarray(ctrl_pos), jnp.asarray(ctrl_tangent)
    _check_controls(layout, ctrl_pos, ctrl_tangent)
    scale = jnp.asarray(layout.segment_lengths / layout.stride, ctrl_tangent.dtype)[:, None]
    start, end = ctrl_pos[..., :-1, :], ctrl_pos[..., 1:, :]
    out_handle = start + scale * ctrl_tangent[..., :-1, :]
    in_handle = end - scale * ctrl_tangent[..., 1:, :]
    return jnp.stack([start, out_handle, in_handle, end], axis=-2)


def from_segments(
    layout: BezierLayout, segments: Float[Array, "*batch segments 4 dim"]
) -> tuple[Float[Array, "*batch controls dim"], Float[Array, "*batch controls dim"]]:
    """Control positions and tangents from the 4-point form (inverse of :func:`to_segments`).

    Segments written by another tool need not be joined or symmetric: shared end points
    are averaged, and so are the two tangents each interior control point's handles
    imply. That is a simple projection onto symmetric C1 curves — not the least-squares
    nearest one when the input is far from joined — and the exact inverse for curves
    from :func:`to_segments`.
    """
    segments = jnp.asarray(segments)
    if segments.ndim < 3 or segments.shape[-3:-1] != (layout.num_segments, 4):
        raise ValueError(f"expected (..., {layout.num_segments}, 4, dim) segments for {layout}, got {segments.shape}")
    inv_scale = jnp.asarray(layout.stride / layout.segment_lengths, segments.dtype)[:, None]
    starts, ends = segments[..., :, 0, :], segments[..., :, 3, :]
    out_tangent = (segments[..., :, 1, :] - starts) * inv_scale  # tangents of controls 0 … K−2
    in_tangent = (ends - segments[..., :, 2, :]) * inv_scale  # tangents of controls 1 … K−1

    def merge(leading, trailing):  # leading: defined for controls 0…K−2, trailing for 1…K−1
        middle = 0.5 * (leading[..., 1:, :] + trailing[..., :-1, :])
        return jnp.concatenate([leading[..., :1, :], middle, trailing[..., -1:, :]], axis=-2)

    return merge(starts, ends), merge(out_tangent, in_tangent)


def tangent_from_velocity(layout: BezierLayout, velocity: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """The control tangent ``T = v·s/3`` whose curve moves at ``velocity`` (units per frame)
    through its control point (the velocity there is ``3T/s`` on both sides)."""
    return jnp.asarray(velocity) * (layout.stride / 3.0)


def velocity_from_tangent(layout: BezierLayout, tangent: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """The velocity ``3T/s`` (units per frame) of a curve through a control point of tangent
    ``tangent``: the inverse of :func:`tangent_from_velocity`."""
    return jnp.asarray(tangent) * (3.0 / layout.stride)


def finite_difference_tangents(
    layout: BezierLayout, points: Float[Array, "*batch frames dim"]
) -> Float[Array, "*batch controls dim"]:
    """Tangents whose velocity ``3T/s`` matches the central finite difference of ``points``
    at each control frame (one-sided at the window ends) — the fit's starting point."""
    _check_frames(layout, points)
    velocity = jnp.gradient(points, axis=-2)  # units per frame
    return tangent_from_velocity(layout, velocity[..., layout.control_frames, :])


class FitResult(NamedTuple):
    """Fitted curves and how well they fit.

    Attributes:
      ctrl_pos, ctrl_tangent: ``(*batch, controls, dim)`` the curves.
      rms_error: ``(*batch,)`` root-mean-square distance between the curve and the data
        over the window's frames (data units, e.g. cm).
      max_error: ``(*batch,)`` largest such distance.
      result: ``(*batch,)`` optimistix result code of each solve
        (``result == optx.RESULTS.successful``).
      num_steps: ``(*batch,)`` Gauss-Newton steps taken.
    """

    ctrl_pos: Float[Array, "*batch controls dim"]
    ctrl_tangent: Float[Array, "*batch controls dim"]
    rms_error: Float[Array, "*batch"]
    max_error: Float[Array, "*batch"]
    result: optx.RESULTS
    num_steps: Int[Array, "*batch"]

    @property
    def succeeded(self) -> Bool[Array, "*batch"]:
        return self.result == optx.RESULTS.successful


# The Gauss-Newton step's linear solve. LSMR (iterative, plain XLA ops) gives the same
# minimum-norm solution as an SVD, to float32 round-off. Not lx.SVD: jaxlib's batched LAPACK
# kernels fan the batch out into the XLA thread pool they run on, and when two such kernels
# run at once on a 2-core machine both pool threads wait on work nobody can pick up — a
# deadlock seen in experiments/pipeline_eval.py (gdb: two threads in lapack_sgesdd_ffi →
# ParallelBatchMap → BlockingCounter::Wait, the main thread in block_until_ready).
def _linear_solver(dtype) -> lx.LSMR:
    eps = float(jnp.finfo(dtype).eps)  # the solve converged to round-off: an SVD's precision
    return lx.LSMR(rtol=eps, atol=eps, max_steps=256)


@functools.partial(jax.jit, static_argnames=("layout", "pin_positions", "rtol", "atol", "max_steps"))
def fit_curves(
    layout: BezierLayout,
    points: Float[Array, "*batch frames dim"],
    *,
    pin_positions: bool = True,
    rtol: float | None = None,
    atol: float | None = None,
    max_steps: int = 8,
) -> FitResult:
    """Least-squares fit of Bézier curves to dense trajectories (optimistix Gauss-Newton).

    Minimises ``Σ_f ‖x(f) − points[f]‖²`` over the window's integer frames. Two variants:

    - ``pin_positions=True`` (default): control positions are the data at the control
      frames and only tangents are fitted. The curve passes exactly through the mocap at
      every control frame, so a handle taken from the data *is* a control point: ground
      truth, conditions and the overwrite at sampling time all agree, and handles are hit
      with zero error. It costs some dense accuracy between control points: 0.211 vs
      0.170 cm mean six-joint error at stride 6 on LaFAN1 subject 5
      (``experiments/bezier_stride.py``).
    - ``pin_positions=False``: positions and tangents are both free — the lowest dense
      error, but the curve misses the data at its own control frames (0.174 cm mean at
      stride 6, as much as its dense error), so handles taken from the data would not
      lie on the ground-truth curves and a model could never hit them and match the
      ground truth at once. Exact handles matter more than 0.04 cm in between.

    The problem is linear, so Gauss-Newton lands on the minimiser in its first step; two
    more steps confirm it (three in all, so ``max_steps`` must be at least 3). Where the
    data do not fully determine the tangents (stride 1 — every frame is a control point —
    stride 2, or a 1-frame last segment) the linear solve is the minimum-norm correction
    from the finite-difference tangents (LSMR from a zero step): the part the data leave free keeps its
    finite-difference value instead of being arbitrary (at stride 1, all of it). The three coordinates of a curve are independent problems and are
    solved separately, which keeps every Jacobian at ``frames × (2·controls)``.

    Args:
      layout: the control-point layout; ``points`` must have ``layout.num_frames`` frames.
      points: ``(*batch, frames, dim)`` dense trajectories (e.g. cm).
      pin_positions: pin control positions to the data (see above).
      rtol, atol: Gauss-Newton convergence tolerances (relative, and absolute in data
        units, on the step); default ``√eps`` of the data's dtype (3.5e-4 in float32,
        1.5e-8 in float64). Tighter than that, float32 round-off in the residual of
        trajectories hundreds of cm from the origin keeps the steps from settling; the
        solution itself does not depend on it, since the first step already is it.
      max_steps: Gauss-Newton step budget.
    Returns:
      a :class:`FitResult`, batched like ``points``.
    """
    _check_frames(layout, points)
    batch_shape, dim = points.shape[:-2], points.shape[-1]
    # One scalar curve per (batch element, coordinate): (n, frames, 1).
    scalar = jnp.moveaxis(points, -1, -2).reshape(-1, layout.num_frames, 1)
    w_pos, w_tan = (w.astype(points.dtype) for w in basis(layout))
    default_tol = float(jnp.finfo(points.dtype).eps) ** 0.5
    rtol, atol = (default_tol if tol is None else tol for tol in (rtol, atol))
    solver = optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=_linear_solver(points.dtype))
    ctrl = layout.control_frames

    def solve_one(x):
        pinned_pos = x[ctrl]
        y0 = finite_difference_tangents(layout, x) if pin_positions else (pinned_pos, finite_difference_tangents(layout, x))

        def residual(y, x):
            pos, tangent = (pinned_pos, y) if pin_positions else y
            return exact_matmul(w_pos, pos) + exact_matmul(w_tan, tangent) - x

        sol = optx.least_squares(residual, solver, y0, args=x, max_steps=max_steps, throw=False)
        pos, tangent = (pinned_pos, sol.value) if pin_positions else sol.value
        return pos, tangent, sol.result, sol.stats["num_steps"]

    pos, tangent, result, num_steps = jax.vmap(solve_one)(scalar)

    def unflatten(a):  # (n, controls, 1) -> (*batch, controls, dim)
        return jnp.moveaxis(a.reshape(*batch_shape, dim, layout.num_controls), -1, -2)

    ctrl_pos, ctrl_tangent = unflatten(pos), unflatten(tangent)
    error = jnp.linalg.norm(evaluate(layout, ctrl_pos, ctrl_tangent) - points, axis=-1)
    # A curve's solve succeeded only if all its coordinates' solves did; report the worst.
    result = jax.tree.map(lambda r: jnp.max(r.reshape(*batch_shape, dim), axis=-1), result)
    num_steps = jnp.max(num_steps.reshape(*batch_shape, dim), axis=-1)
    return FitResult(
        ctrl_pos=ctrl_pos,
        ctrl_tangent=ctrl_tangent,
        rms_error=jnp.sqrt(jnp.mean(error**2, axis=-1)),
        max_error=jnp.max(error, axis=-1),
        result=result,
        num_steps=num_steps,
    )


@functools.partial(jax.jit, static_argnums=0)
def _fit_operator_parts(layout: BezierLayout):
    """``(basis, finite-difference tangents (controls, frames))`` of ``layout``, compiled
    once per layout (op by op they take ten times as long)."""
    fd = finite_difference_tangents(layout, jnp.eye(layout.num_frames, dtype=jnp.float32)[:, :, None])
    return basis(layout), fd[..., 0].T


def fit_operator(layout: BezierLayout) -> np.ndarray:
    """The pinned-position fit (:func:`fit_curves`) as one linear map: ``(controls, frames)``
    float64 ``M`` with ``ctrl_tangent = M @ points`` for any ``(frames, dim)`` points (the
    positions are ``points[layout.control_frames]``).

    The fit is linear in the data, and this is its closed form: the finite-difference
    tangents ``D x`` plus the minimum-norm least-squares correction of the residual they
    leave, ``D + W_tan⁺ (I − W_pos S − W_tan D)`` with ``S`` the control-frame selection —
    the solution :func:`fit_curves`' Gauss-Newton step lands on, in float64. Training on
    windows of many lengths fits each drawn window with it, inside the compiled step.
    """
    n = layout.num_frames
    (w_pos, w_tan), fd = (jax.tree.map(lambda a: np.asarray(a, np.float64), part) for part in _fit_operator_parts(layout))
    select = np.eye(n)[layout.control_frames]  # (controls, frames)
    residual = np.eye(n) - w_pos @ select - w_tan @ fd
    return fd + np.linalg.pinv(w_tan) @ residual


def interpolate_rotations(
    layout: BezierLayout,
    ctrl_quat: Float[Array, "*batch controls 4"],
    frames: Real[ArrayLike, "frames"] | None = None,
) -> Float[Array, "*batch frames 4"]:
    """Orientations between control points by slerp (BMM §4.3), linear in frame time.

    Outside the window the end orientations are held (``evaluate`` extrapolates
    positions; rotations have no natural extrapolation).

    Args:
      ctrl_quat: ``(*batch, controls, 4)`` unit quaternions (w, x, y, z) at the control points.
      frames: ``(frames,)`` frame times; default every integer frame.
    Returns:
      ``(*batch, frames, 4)`` unit quaternions.
    """
    ctrl_quat = jnp.asarray(ctrl_quat)
    _check_controls(layout, ctrl_quat)
    segment, t = locate(layout, layout.frames() if frames is None else frames)
    q0 = jnp.take(ctrl_quat, segment, axis=-2)
    q1 = jnp.take(ctrl_quat, segment + 1, axis=-2)
    return slerp(q0, q1, jnp.clip(t, 0.0, 1.0).astype(ctrl_quat.dtype))


def reconstruct_dense(
    layout: BezierLayout,
    ctrl_pos: Float[Array, "*batch controls joints 3"],
    ctrl_tangent: Float[Array, "*batch controls joints 3"],
    ctrl_rot6d: Float[Array, "*batch controls joints 6"],
    frames: Real[ArrayLike, "frames"] | None = None,
) -> tuple[Float[Array, "*batch frames joints 3"], Float[Array, "*batch frames joints 6"]]:
    """Dense joint trajectories from curves: Bézier positions and slerped orientations.

    Control arrays are laid out like the BMM frame tokens, ``(controls, joints, ·)``.

    Returns:
      ``(positions (*batch, frames, joints, 3), rot6d (*batch, frames, joints, 6))``.
    """
    ctrl_pos, ctrl_tangent, ctrl_rot6d = (jnp.asarray(a) for a in (ctrl_pos, ctrl_tangent, ctrl_rot6d))
    for a in (ctrl_pos, ctrl_tangent, ctrl_rot6d):
        if a.ndim < 3 or a.shape[-3] != layout.num_controls:
            raise ValueError(
                f"expected (..., {layout.num_controls}, joints, ·) control arrays for {layout}, got shape {a.shape}"
            )
    pos = evaluate(layout, jnp.moveaxis(ctrl_pos, -2, -3), jnp.moveaxis(ctrl_tangent, -2, -3), frames)
    quat = interpolate_rotations(layout, jnp.moveaxis(quat_from_rot6d(ctrl_rot6d), -2, -3), frames)
    return jnp.moveaxis(pos, -3, -2), jnp.moveaxis(rot6d_from_quat(quat), -3, -2)


def checked_controls(
    ctrl_pos: ArrayLike | None, ctrl_tangent: ArrayLike | None, layout: BezierLayout, num_joints: int
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Curves handed to a writer (glTF, preview), as float64 NumPy: both or neither given,
    each ``(layout.num_controls, num_joints, 3)`` and finite.

    Raises:
      ValueError: naming the array and its shape, or the non-finite one.
    """
    if (ctrl_pos is None) != (ctrl_tangent is None):
        raise ValueError("give both ctrl_pos and ctrl_tangent, or neither")
    if ctrl_pos is None:
        return None, None
    ctrl_pos, ctrl_tangent = np.asarray(ctrl_pos, np.float64), np.asarray(ctrl_tangent, np.float64)
    expected = (layout.num_controls, num_joints, 3)
    for label, a in (("ctrl_pos", ctrl_pos), ("ctrl_tangent", ctrl_tangent)):
        if a.shape != expected:
            raise ValueError(
                f"{label} must be {expected} for {layout.num_frames} frames at stride {layout.stride}, got {a.shape}"
            )
        if not np.isfinite(a).all():
            raise ValueError(f"{label} contains non-finite values")
    return ctrl_pos, ctrl_tangent
