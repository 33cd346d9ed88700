"""Tests for ``bezmotion.bezier``: the Bernstein form against de Casteljau, the layout, C1
continuity, fitting against closed-form least squares and on a real clip, derivatives, JAX
transformations and bad input.

The references (control polygons, de Casteljau, the Bernstein design matrix) are written here
in plain NumPy from the module docstring's definition of a segment,
``(P_k, P_k + a_k T_k, P_{k+1} − a_k T_{k+1}, P_{k+1})`` with ``a_k = d_k / s``.
"""

from __future__ import annotations

import functools
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from helpers import assert_same_rotation, check_jacobians, np_slerp, random_quat, random_quat_np, tree_allclose

from bezmotion.assets import DEMO_CLIP
from bezmotion.bezier import (
    BezierLayout,
    basis,
    bernstein,
    evaluate,
    finite_difference_tangents,
    fit_curves,
    from_segments,
    interpolate_rotations,
    reconstruct_dense,
    to_segments,
)
from bezmotion.data.bvh import read_bvh
from bezmotion.geometry.rotations import rot6d_from_quat, slerp
from bezmotion.geometry.skeleton import forward_kinematics

#: Layouts with full-stride segments only, with a shorter last segment (31/4, 31/7, 31/12),
#: a 1-frame last segment (20/6) and a stride longer than the window (5/10).
LAYOUTS = [(31, 1), (31, 4), (31, 6), (31, 7), (31, 12), (20, 6), (5, 10)]
LAYOUT_IDS = [f"{n}f-s{s}" for n, s in LAYOUTS]

#: XLA options for the tests' own one-off ``jit`` programs: without backend optimisation they
#: compile about twice as fast (most of this file's run time) and still run in milliseconds.
FAST_COMPILE = {"xla_backend_optimization_level": 0}

# ---------------------------------------------------------------------- NumPy references


def np_knots(num_frames: int, stride: int) -> np.ndarray:
    """Control frames by the docstring's rule: every ``stride`` frames, plus the last frame."""
    knots = list(range(0, num_frames, stride))
    return np.array(knots if knots[-1] == num_frames - 1 else [*knots, num_frames - 1])


def np_segments(knots: np.ndarray, stride: int, ctrl_pos: np.ndarray, ctrl_tangent: np.ndarray) -> np.ndarray:
    """``(segments, 4, dim)`` control polygons of ``(controls, dim)`` positions and tangents."""
    p, t = np.asarray(ctrl_pos, float), np.asarray(ctrl_tangent, float)
    a = (np.diff(knots) / stride)[:, None]
    return np.stack([p[:-1], p[:-1] + a * t[:-1], p[1:] - a * t[1:], p[1:]], axis=-2)


def np_segment_of(knots: np.ndarray, frame: float) -> tuple[int, float]:
    """Segment ``k`` holding ``frame`` (a knot starts its segment; the last frame ends the last one;
    frames outside the window extrapolate the end segments) and the local parameter ``t``."""
    k = int(np.clip(np.searchsorted(knots, frame, side="right") - 1, 0, len(knots) - 2))
    return k, (frame - knots[k]) / (knots[k + 1] - knots[k])


def np_de_casteljau(polygon: np.ndarray, t: float) -> np.ndarray:
    """A point of the Bézier curve of ``polygon`` ``(4, dim)`` by repeated linear interpolation."""
    points = list(np.asarray(polygon, float))
    while len(points) > 1:
        points = [(1.0 - t) * p + t * q for p, q in itertools.pairwise(points)]
    return points[0]


def np_design_matrix(knots: np.ndarray, stride: int, frames: np.ndarray) -> np.ndarray:
    """``(frames, 2·controls)`` matrix ``A`` with ``x(f) = A @ [P; T]`` (per coordinate), built from
    the cubic Bernstein polynomials ``C(3, i) (1−t)^(3−i) t^i`` applied to each control polygon."""
    k_count = len(knots)
    a_mat = np.zeros((len(frames), 2 * k_count))
    for row, frame in enumerate(frames):
        k, t = np_segment_of(knots, frame)
        a = (knots[k + 1] - knots[k]) / stride
        b = [math.comb(3, i) * (1.0 - t) ** (3 - i) * t**i for i in range(4)]
        # x = b0 P_k + b1 (P_k + a T_k) + b2 (P_{k+1} − a T_{k+1}) + b3 P_{k+1}
        a_mat[row, k] += b[0] + b[1]
        a_mat[row, k + 1] += b[2] + b[3]
        a_mat[row, k_count + k] += a * b[1]
        a_mat[row, k_count + k + 1] -= a * b[2]
    return a_mat


def random_controls(rng: np.random.Generator, layout: BezierLayout, batch=(), dim: int = 3, scale: float = 1.0):
    """Random control positions and tangents ``(*batch, controls, dim)`` (float32, float64 under x64)."""
    shape = (*batch, layout.num_controls, dim)
    dtype = jnp.result_type(float)
    return tuple(jnp.asarray(rng.normal(scale=scale, size=shape), dtype) for _ in range(2))


def random_walks(rng: np.random.Generator, shape: tuple[int, ...], num_frames: int, dim: int = 3) -> np.ndarray:
    """Random-walk trajectories ``(*shape, frames, dim)``: smooth enough to fit, never exactly a Bézier."""
    return np.cumsum(rng.normal(size=(*shape, num_frames, dim)), axis=-2)


# -------------------------------------------------------------------------------- layout


@pytest.mark.parametrize(
    ("num_frames", "stride", "knots"),
    [
        (31, 6, [0, 6, 12, 18, 24, 30]),
        (31, 4, [0, 4, 8, 12, 16, 20, 24, 28, 30]),
        (31, 7, [0, 7, 14, 21, 28, 30]),
        (31, 1, list(range(31))),
        (20, 6, [0, 6, 12, 18, 19]),
        (5, 10, [0, 4]),
        (2, 1, [0, 1]),
    ],
)
def test_control_frames(num_frames, stride, knots):
    layout = BezierLayout(num_frames, stride)
    np.testing.assert_array_equal(layout.control_frames, knots)
    assert layout.num_controls == len(knots) and layout.num_segments == len(knots) - 1
    np.testing.assert_array_equal(layout.segment_lengths, np.diff(knots))
    np.testing.assert_array_equal(layout.frames(), np.arange(num_frames, dtype=np.float64))


def test_from_controls_and_hashing():
    assert BezierLayout.from_controls(6, 6) == BezierLayout(31, 6)
    assert BezierLayout.from_controls(9, 4) == BezierLayout(33, 4)
    assert BezierLayout.from_controls(2) == BezierLayout(7)  # default stride 6 (BMM appendix A.2)
    assert BezierLayout.from_controls(6, 6).num_controls == 6
    assert hash(BezierLayout(31, 6)) == hash(BezierLayout(31, 6)) and BezierLayout(31, 6) != BezierLayout(31, 5)
    with pytest.raises(ValueError, match="a curve needs at least 2 control points, got 1"):
        BezierLayout.from_controls(1, 6)


@pytest.mark.parametrize(
    ("num_frames", "stride", "message"),
    [
        (1, 6, r"BezierLayout needs at least 2 frames, got num_frames=1"),
        (-3, 6, r"BezierLayout needs at least 2 frames, got num_frames=-3"),
        (31, 0, r"BezierLayout.stride must be ≥ 1, got 0"),
        (31, True, r"BezierLayout.stride must be an integer, got True"),
        (False, 6, r"BezierLayout.num_frames must be an integer, got False"),
    ],
    ids=["one-frame", "negative-frames", "zero-stride", "bool-stride", "bool-frames"],
)
def test_invalid_layouts_are_rejected(num_frames, stride, message):
    with pytest.raises(ValueError, match=message):
        BezierLayout(num_frames, stride)


@pytest.mark.parametrize(("num_frames", "stride"), [(31.0, 6), (31, 6.0), ("31", 6)],
                         ids=["float-frames", "float-stride", "str"])  # fmt: skip
def test_non_integer_layouts_are_rejected(num_frames, stride):
    """Caught by the runtime annotation check (``TypeCheckError``, a ``TypeError``) when the
    jaxtyping hook is on, by ``__post_init__`` (``ValueError``) otherwise; either way the message
    names the field."""
    with pytest.raises((ValueError, TypeError), match="num_frames" if not isinstance(num_frames, int) else "stride"):
        BezierLayout(num_frames, stride)


# ----------------------------------------------------------------------- Bernstein form


def test_bernstein_polynomials(x64):
    t = np.array([-0.5, 0.0, 0.25, 0.5, 0.9, 1.0, 1.5])
    b = np.asarray(jax.jit(bernstein)(jnp.asarray(t)))
    expected = np.stack([math.comb(3, i) * (1.0 - t) ** (3 - i) * t**i for i in range(4)], axis=-1)
    np.testing.assert_allclose(b, expected, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(b.sum(-1), 1.0, rtol=1e-14)  # partition of unity
    assert bernstein(jnp.zeros((2, 3))).shape == (2, 3, 4)


@pytest.fixture(scope="module")
def curves():
    """Random curves ``(2, controls, 3)`` on every layout of :data:`LAYOUTS` and what the module
    computes from them, float64, all in one ``jit`` (one compilation, not one per primitive).

    Frame times: fractional ones inside the window and outside it (extrapolation), the knots,
    and 1e-9 frames before every interior knot / after every knot but the last.
    Returns ``{(num_frames, stride): (inputs, outputs)}``, NumPy arrays.
    """
    rng = np.random.default_rng(6)
    inputs = {}
    for num_frames, stride in LAYOUTS:
        knots = np_knots(num_frames, stride).astype(float)
        inputs[num_frames, stride] = {
            "ctrl_pos": rng.normal(size=(2, len(knots), 3)),
            "ctrl_tangent": rng.normal(size=(2, len(knots), 3)),
            "frames": np.concatenate([np.linspace(0.0, num_frames - 1, 4 * num_frames - 3),
                                      rng.uniform(-2.0, num_frames + 1, 16)]),
            "knots": knots, "left": knots[1:-1] - 1e-9, "right": knots[:-1] + 1e-9,
        }  # fmt: skip

    @functools.partial(jax.jit, compiler_options=FAST_COMPILE)
    def compute(inputs):
        out = {}
        for (num_frames, stride), x in inputs.items():
            layout = BezierLayout(num_frames, stride)
            # One evaluation (and its derivative in frame time) at all the frame times at once.
            times = ("frames", "knots", "left", "right")
            frames = jnp.concatenate([x[name] for name in times])
            position, velocity = jax.jvp(functools.partial(evaluate, layout, x["ctrl_pos"], x["ctrl_tangent"]),
                                         (frames,), (jnp.ones_like(frames),))  # fmt: skip
            split = np.cumsum([len(x[name]) for name in times])[:-1]
            segments = to_segments(layout, x["ctrl_pos"], x["ctrl_tangent"])
            out[num_frames, stride] = {
                **{name: (p, v) for name, p, v in zip(times, jnp.split(position, split, axis=-2),
                                                       jnp.split(velocity, split, axis=-2))},
                "segments": segments, "round_trip": from_segments(layout, segments),
                "default": evaluate(layout, x["ctrl_pos"], x["ctrl_tangent"]),
                "basis": basis(layout, x["frames"]), "default_basis": basis(layout),
            }  # fmt: skip
        return out

    with jax.enable_x64(True):
        outputs = jax.device_get(compute(inputs))
    return {key: (inputs[key], outputs[key]) for key in inputs}


@pytest.mark.parametrize(("num_frames", "stride"), LAYOUTS, ids=LAYOUT_IDS)
def test_evaluate_matches_de_casteljau(curves, num_frames, stride):
    """Every control polygon is the docstring's, and ``evaluate`` at fractional frame times (inside
    the window and extrapolated outside it) equals de Casteljau on the ``to_segments`` polygons."""
    x, out = curves[num_frames, stride]
    knots = np_knots(num_frames, stride)
    for b in range(2):
        segments = out["segments"][b]
        np.testing.assert_allclose(segments, np_segments(knots, stride, x["ctrl_pos"][b], x["ctrl_tangent"][b]),
                                   rtol=0, atol=1e-14)  # fmt: skip
        expected = [np_de_casteljau(segments[k], t) for k, t in (np_segment_of(knots, f) for f in x["frames"])]
        np.testing.assert_allclose(out["frames"][0][b], expected, rtol=0, atol=1e-12)
        # The default frame times are the window's integer frames.
        integer = [np_de_casteljau(segments[k], t) for k, t in (np_segment_of(knots, f) for f in range(num_frames))]
        np.testing.assert_allclose(out["default"][b], integer, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("num_frames", "stride"), LAYOUTS, ids=LAYOUT_IDS)
def test_basis_matches_bernstein_design_matrix(curves, num_frames, stride):
    x, out = curves[num_frames, stride]
    w_pos, w_tan = out["basis"]
    expected = np_design_matrix(np_knots(num_frames, stride), stride, x["frames"])
    np.testing.assert_allclose(np.concatenate([w_pos, w_tan], axis=-1), expected, rtol=0, atol=1e-13)
    assert np.all(np.count_nonzero(w_pos, axis=-1) <= 2)  # at most two control points per frame
    np.testing.assert_allclose(w_pos.sum(-1), 1.0, rtol=1e-13)
    integer = np_design_matrix(np_knots(num_frames, stride), stride, np.arange(num_frames, dtype=float))
    np.testing.assert_allclose(np.concatenate(out["default_basis"], axis=-1), integer, rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------- continuity


@pytest.mark.parametrize(("num_frames", "stride"), LAYOUTS, ids=LAYOUT_IDS)
def test_c1_continuity_at_every_control_point(curves, num_frames, stride):
    """Position and velocity (``jax.jvp`` in frame time) agree on both sides of every interior
    control point, across a shorter last segment too, and the velocity there is ``3 T_k / s``."""
    x, out = curves[num_frames, stride]
    ctrl_pos, ctrl_tangent = x["ctrl_pos"], x["ctrl_tangent"]
    # At a knot the frame starts its segment (the last frame ends the last segment); 1e-9 frames
    # before it, the previous segment's cubic is evaluated at t ≈ 1.
    (at_x, at_v), (left_x, left_v), (right_x, right_v) = out["knots"], out["left"], out["right"]
    np.testing.assert_allclose(at_x, ctrl_pos, rtol=0, atol=1e-12)
    np.testing.assert_allclose(at_v, 3.0 * ctrl_tangent / stride, rtol=0, atol=1e-11)
    np.testing.assert_allclose(left_x, ctrl_pos[:, 1:-1], rtol=0, atol=1e-7)
    np.testing.assert_allclose(left_v, at_v[:, 1:-1], rtol=0, atol=1e-6)
    np.testing.assert_allclose(right_x, ctrl_pos[:, :-1], rtol=0, atol=1e-7)
    np.testing.assert_allclose(right_v, at_v[:, :-1], rtol=0, atol=1e-6)
    # The same from the 4-point form: end-point derivatives of a cubic Bézier are 3·(handle offset)/d.
    seg, d = out["segments"], np.diff(x["knots"])[:, None]
    np.testing.assert_array_equal(seg[:, :-1, 3], seg[:, 1:, 0])
    velocity_in = 3.0 * (seg[:, :-1, 3] - seg[:, :-1, 2]) / d[:-1]
    velocity_out = 3.0 * (seg[:, 1:, 1] - seg[:, 1:, 0]) / d[1:]
    np.testing.assert_allclose(velocity_in, velocity_out, rtol=0, atol=1e-12)


# ------------------------------------------------------------------- fitting (float64)

FIT_FRAMES = 31
#: Every stride on 31 frames, plus a 1-frame last segment (32 frames at stride 5: knots …, 30, 31).
FIT_LAYOUTS = tuple(BezierLayout(FIT_FRAMES, s) for s in range(1, 13)) + (BezierLayout(32, 5),)
NUM_EXACT, NUM_WALKS = 3, 3


@pytest.fixture(scope="module")
def fits():
    """Both variants of ``fit_curves`` on every layout of :data:`FIT_LAYOUTS`, float64.

    Each layout gets ``NUM_EXACT`` representable curves (random controls through the NumPy
    design matrix) followed by ``NUM_WALKS`` random walks. All 26 solves are traced into one
    ``jit`` (one XLA compilation is about half the cost of 26 separate ones).
    Returns ``{(num_frames, stride): {"ctrl_pos", "ctrl_tangent", "points", "design", (pin, field): ...}}``.
    """
    rng = np.random.default_rng(31)
    data = {}
    for layout in FIT_LAYOUTS:
        knots = np_knots(layout.num_frames, layout.stride)
        design = np_design_matrix(knots, layout.stride, np.arange(layout.num_frames, dtype=float))
        ctrl = rng.normal(size=(NUM_EXACT, 2 * len(knots), 3))
        exact = np.einsum("fc,ncd->nfd", design, ctrl)
        points = np.concatenate([exact, random_walks(rng, (NUM_WALKS,), layout.num_frames)])
        data[layout.num_frames, layout.stride] = {
            "design": design, "points": points,
            "ctrl_pos": ctrl[:, : len(knots)], "ctrl_tangent": ctrl[:, len(knots) :],
        }  # fmt: skip

    @functools.partial(jax.jit, compiler_options=FAST_COMPILE)
    def fit_all(points):
        out = {}
        for layout in FIT_LAYOUTS:
            key = (layout.num_frames, layout.stride)
            for pin in (False, True):
                r = fit_curves(layout, points[key], pin_positions=pin)
                out[(*key, pin)] = {"ctrl_pos": r.ctrl_pos, "ctrl_tangent": r.ctrl_tangent, "max_error": r.max_error,
                                    "rms_error": r.rms_error, "succeeded": r.succeeded}  # fmt: skip
        return out

    with jax.enable_x64(True):
        results = jax.device_get(fit_all({key: d["points"] for key, d in data.items()}))
    for (num_frames, stride, pin), result in results.items():
        data[num_frames, stride].update({(pin, name): value for name, value in result.items()})
    return data


def to_columns(points: np.ndarray) -> np.ndarray:
    """``(n, frames, dim)`` → ``(frames, n·dim)``: one least-squares right-hand side per column."""
    return np.moveaxis(points, 0, 1).reshape(points.shape[1], -1)


def from_columns(columns: np.ndarray, n: int) -> np.ndarray:
    """``(unknowns, n·dim)`` → ``(n, unknowns, dim)``."""
    return np.moveaxis(columns.reshape(len(columns), n, -1), 1, 0)


def lstsq_controls(design: np.ndarray, points: np.ndarray, knots: np.ndarray, pin: bool):
    """Closed-form least squares ``(ctrl_pos, ctrl_tangent)`` for ``(n, frames, dim)`` points."""
    k_count, rhs = len(knots), to_columns(points)
    if pin:
        pos = rhs[knots]
        tangent = np.linalg.lstsq(design[:, k_count:], rhs - design[:, :k_count] @ pos, rcond=None)[0]
    else:
        sol = np.linalg.lstsq(design, rhs, rcond=None)[0]
        pos, tangent = sol[:k_count], sol[k_count:]
    return from_columns(pos, len(points)), from_columns(tangent, len(points))


@pytest.mark.parametrize("stride", range(3, 13))
def test_fit_recovers_representable_curves(fits, stride):
    """Curves that are exactly Bézier at this layout come back to 1e-5 (here: 1e-9, float64)."""
    fit = fits[FIT_FRAMES, stride]
    exact = slice(0, NUM_EXACT)
    assert fit[False, "succeeded"].all() and fit[True, "succeeded"].all()
    np.testing.assert_allclose(fit[False, "ctrl_pos"][exact], fit["ctrl_pos"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(fit[False, "ctrl_tangent"][exact], fit["ctrl_tangent"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(fit[True, "ctrl_pos"][exact], fit["ctrl_pos"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fit[True, "ctrl_tangent"][exact], fit["ctrl_tangent"], rtol=0, atol=1e-9)
    for pin in (False, True):
        assert fit[pin, "max_error"][exact].max() < 1e-9


@pytest.mark.parametrize("stride", range(3, 13))
def test_fit_equals_closed_form_least_squares(fits, stride):
    """On random walks both variants land on the ``np.linalg.lstsq`` solution of the Bernstein
    design matrix, and the reported errors are those of the fitted curves."""
    fit = fits[FIT_FRAMES, stride]
    walks = slice(NUM_EXACT, None)
    points = fit["points"][walks]
    knots = np_knots(FIT_FRAMES, stride)
    for pin in (False, True):
        pos, tangent = lstsq_controls(fit["design"], points, knots, pin)
        np.testing.assert_allclose(fit[pin, "ctrl_pos"][walks], pos, rtol=0, atol=1e-9, err_msg=f"pin={pin}")
        np.testing.assert_allclose(fit[pin, "ctrl_tangent"][walks], tangent, rtol=0, atol=1e-9, err_msg=f"pin={pin}")
        curve = np.einsum("fc,ncd->nfd", fit["design"], np.concatenate([pos, tangent], axis=-2))
        error = np.linalg.norm(curve - points, axis=-1)
        np.testing.assert_allclose(fit[pin, "max_error"][walks], error.max(-1), rtol=1e-9)
        np.testing.assert_allclose(fit[pin, "rms_error"][walks], np.sqrt(np.mean(error**2, -1)), rtol=1e-9)
        assert error.max() > 1e-3  # the walks are not representable: the test compares real minimisers
    np.testing.assert_array_equal(fit[True, "ctrl_pos"][walks], points[:, knots])
    # Free positions fit the dense data at least as well (it is the unconstrained minimum).
    assert np.all(fit[False, "rms_error"] <= fit[True, "rms_error"] + 1e-12)


@pytest.mark.parametrize(("num_frames", "stride"), [(31, 1), (31, 2), (32, 5)],
                         ids=["stride-1", "stride-2", "1-frame-tail"])  # fmt: skip
def test_fit_with_undetermined_tangents(fits, num_frames, stride):
    """Where the data leave tangents undetermined, the fit still reproduces the data at every
    integer frame (all data at strides 1 and 2, representable curves otherwise), stays finite,
    and is the minimum-norm correction from the finite-difference tangents (so stride-1 tangents
    *are* the finite-difference tangents)."""
    fit = fits[num_frames, stride]
    points, design = fit["points"], fit["design"]
    knots = np_knots(num_frames, stride)
    k_count = len(knots)
    assert np.linalg.matrix_rank(design) < 2 * k_count  # really rank-deficient
    fd_tangent = np.gradient(points, axis=-2)[:, knots] * stride / 3.0
    with jax.enable_x64(True):
        np.testing.assert_allclose(finite_difference_tangents(BezierLayout(num_frames, stride), jnp.asarray(points)),
                                   fd_tangent, rtol=0, atol=1e-12)  # fmt: skip
    for pin in (False, True):
        pos, tangent = fit[pin, "ctrl_pos"], fit[pin, "ctrl_tangent"]
        assert np.isfinite(pos).all() and np.isfinite(tangent).all() and fit[pin, "succeeded"].all()
        # Strides 1 and 2 have a knot or a free tangent difference per frame: every data set is
        # reproduced. With the 1-frame tail only the representable curves are.
        reproduced = slice(None) if stride <= 2 else slice(0, NUM_EXACT)
        curve = np.einsum("fc,ncd->nfd", design, np.concatenate([pos, tangent], axis=-2))
        np.testing.assert_allclose(curve[reproduced], points[reproduced], rtol=0, atol=1e-9, err_msg=f"pin={pin}")
        assert fit[pin, "max_error"][reproduced].max() < 1e-9
        # Minimum-norm correction from y0 = (data at the knots, FD tangents): y = y0 + lstsq(A, x − A y0),
        # lstsq giving the minimum-norm solution (A: the tangent columns only when positions are pinned).
        y0 = np.concatenate([points[:, knots], fd_tangent], axis=-2)
        unknowns = slice(k_count, None) if pin else slice(None)
        residual = to_columns(points - np.einsum("fc,ncd->nfd", design, y0))
        step = np.linalg.lstsq(design[:, unknowns], residual, rcond=None)[0]
        expected = y0[:, unknowns] + from_columns(step, len(points))
        np.testing.assert_allclose(np.concatenate([pos, tangent], axis=-2)[:, unknowns], expected, rtol=0, atol=1e-9,
                                   err_msg=f"pin={pin}")  # fmt: skip
    if stride == 1:
        np.testing.assert_allclose(fit[False, "ctrl_tangent"], fd_tangent, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fit[True, "ctrl_tangent"], fd_tangent, rtol=0, atol=1e-12)
    if num_frames == 32:  # the last control point (frame 31) has no interior frame: its tangent stays put
        np.testing.assert_allclose(fit[True, "ctrl_tangent"][:, -1], fd_tangent[:, -1], rtol=0, atol=1e-9)


# ------------------------------------------------------------------------- real clip


@functools.cache
def demo_clip_positions() -> np.ndarray:
    """Global joint positions ``(joints, frames, 3)`` (cm) of the bundled Bandai-Namco clip, float32."""
    motion = read_bvh(DEMO_CLIP)
    _, pos = forward_kinematics(motion.skeleton.parents, jnp.asarray(motion.quat_local, jnp.float32),
                                jnp.asarray(motion.pos_local, jnp.float32))  # fmt: skip
    return np.moveaxis(np.asarray(pos), 0, 1)


def test_fit_error_on_real_clip():
    """All 22 joints of the first 31 frames of a real walk at stride 6 (float32, cm)."""
    layout = BezierLayout(31, 6)
    points = jnp.asarray(demo_clip_positions()[:, :31])
    assert points.shape == (22, 31, 3) and np.ptp(points, axis=1).max() > 50.0  # it really walks

    @functools.partial(jax.jit, compiler_options=FAST_COMPILE)
    def fit_both(points):
        out = {}
        for pin in (True, False):
            fit = fit_curves(layout, points, pin_positions=pin)
            out[pin] = (evaluate(layout, fit.ctrl_pos, fit.ctrl_tangent), fit.rms_error, fit.max_error, fit.succeeded)
        return out

    errors = {}
    for pin, (curve, rms_error, max_error, succeeded) in jax.device_get(fit_both(points)).items():
        assert succeeded.shape == (22,) and succeeded.all()
        errors[pin] = np.linalg.norm(curve - np.asarray(points), axis=-1)
        np.testing.assert_allclose(max_error, errors[pin].max(-1), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(rms_error, np.sqrt(np.mean(errors[pin] ** 2, -1)), rtol=1e-5, atol=1e-6)
    # Measured: mean 0.0395 cm pinned, 0.0331 cm free; worst frame 0.29 / 0.28 cm.
    assert errors[True].mean() < 0.08 and errors[True].max() < 0.6
    assert errors[False].mean() < 0.07 and errors[False].max() < 0.6
    assert errors[False].mean() <= errors[True].mean()
    assert np.sqrt(np.mean(errors[False] ** 2)) <= np.sqrt(np.mean(errors[True] ** 2))
    # Pinned curves pass exactly through the mocap at the control frames; free ones miss it (by up to 0.18 cm).
    np.testing.assert_array_equal(errors[True][:, layout.control_frames], 0.0)
    assert errors[False][:, layout.control_frames].max() > 0.01


# ------------------------------------------------------------------------- derivatives


def test_evaluate_jacobians(rng, x64):
    """jacfwd == jacrev == central differences w.r.t. control positions, tangents and (fractional,
    off-knot) frame times: full segments, the shorter last segment (28…30) and outside the window."""
    layout = BezierLayout(31, 4)
    ctrl_pos, ctrl_tangent = random_controls(rng, layout, batch=(2,))
    frames = jnp.asarray([-0.7, 0.3, 3.5, 13.25, 17.9, 28.1, 29.6, 30.4])
    check_jacobians(lambda p, t, f: evaluate(layout, p, t, f), (ctrl_pos, ctrl_tangent, frames), argnums=(0, 1, 2))


# -------------------------------------------------------------------- JAX transformations


def test_jit_matches_eager(rng):
    layout = BezierLayout(31, 4)
    ctrl_pos, ctrl_tangent = random_controls(rng, layout)
    quat = random_quat(rng, (layout.num_controls,))
    frames = jnp.asarray(rng.uniform(-1.0, 31.0, size=17), jnp.float32)

    def everything(p, t, q, f):
        segments = to_segments(layout, p, t)
        return evaluate(layout, p, t, f), segments, from_segments(layout, segments), interpolate_rotations(layout, q, f)

    tree_allclose(jax.jit(everything)(ctrl_pos, ctrl_tangent, quat, frames),
                  everything(ctrl_pos, ctrl_tangent, quat, frames), rtol=1e-5, atol=1e-5)  # fmt: skip


def test_evaluate_vmap_and_batch_axes_match_python_loop(rng):
    layout = BezierLayout(31, 7)
    ctrl_pos, ctrl_tangent = random_controls(rng, layout, batch=(2, 3))
    frames = jnp.asarray(rng.uniform(0.0, 30.0, size=(4, 9)), jnp.float32)
    curve = functools.partial(evaluate, layout)

    @functools.partial(jax.jit, compiler_options=FAST_COMPILE)
    def all_ways(p, t, frames):
        looped = jnp.stack([jnp.stack([curve(p[i, j], t[i, j]) for j in range(3)]) for i in range(2)])
        by_frames = jax.vmap(lambda f: curve(p[0, 0], t[0, 0], f))(frames)
        looped_frames = jnp.stack([curve(p[0, 0], t[0, 0], f) for f in frames])
        return curve(p, t), jax.vmap(jax.vmap(curve))(p, t), looped, by_frames, looped_frames

    batched, vmapped, looped, by_frames, looped_frames = all_ways(ctrl_pos, ctrl_tangent, frames)
    assert batched.shape == (2, 3, 31, 3) and by_frames.shape == (4, 9, 3)
    np.testing.assert_allclose(batched, looped, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(vmapped, looped, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(by_frames, looped_frames, rtol=1e-6, atol=1e-6)
    assert np.ptp(np.asarray(looped), axis=(0, 1)).min() > 0.1  # the curves differ: the loop order matters


def test_fit_vmap_and_batch_axes_match_python_loop(rng):
    """``(2, 3, frames, dim)`` in one call == ``vmap`` over the leading axis == a loop of single curves."""
    layout = BezierLayout(31, 6)
    points = jnp.asarray(random_walks(rng, (2, 3), 31), jnp.float32)

    def fields(r):
        return (r.ctrl_pos, r.ctrl_tangent, r.rms_error, r.max_error, r.num_steps, r.succeeded)

    @functools.partial(jax.jit, compiler_options=FAST_COMPILE)
    def batched_and_vmapped(x):
        return fields(fit_curves(layout, x)), fields(jax.vmap(functools.partial(fit_curves, layout))(x))

    batched, vmapped = batched_and_vmapped(points)
    looped = [[fields(fit_curves(layout, points[i, j])) for j in range(3)] for i in range(2)]
    looped = jax.tree.map(lambda *x: jnp.stack(x), *[jax.tree.map(lambda *y: jnp.stack(y), *row) for row in looped])
    assert batched[0].shape == (2, 3, 6, 3) and batched[2].shape == (2, 3) and batched[5].shape == (2, 3)
    assert bool(batched[5].all())
    tree_allclose(batched, looped, rtol=1e-4, atol=1e-4)
    tree_allclose(vmapped, looped, rtol=1e-4, atol=1e-4)


def test_fit_reports_the_worst_coordinate_of_each_curve(rng):
    """A curve's solve succeeded only if all its coordinates' did. With a 2-step budget a constant
    coordinate converges (1 step) and a random walk does not (it needs 3: step, confirm, stop)."""
    walk = np.cumsum(rng.normal(size=31))
    const = np.full(31, 2.0)
    points = jnp.asarray([np.stack([walk, const, const], -1), np.stack([const, const, const], -1)], jnp.float32)
    fit = fit_curves(BezierLayout(31, 6), points, max_steps=2)
    np.testing.assert_array_equal(fit.succeeded, [False, True])
    np.testing.assert_array_equal(fit.num_steps, [2, 1])
    assert bool((fit.result == optx.RESULTS.nonlinear_max_steps_reached)[0])


# -------------------------------------------------------------------------- 4-point form


@pytest.mark.parametrize(("num_frames", "stride"), LAYOUTS, ids=LAYOUT_IDS)
def test_segments_round_trip(curves, num_frames, stride):
    x, out = curves[num_frames, stride]
    assert out["segments"].shape == (2, BezierLayout(num_frames, stride).num_segments, 4, 3)
    pos, tangent = out["round_trip"]
    np.testing.assert_array_equal(pos, x["ctrl_pos"])  # shared end points are copies: exact
    np.testing.assert_allclose(tangent, x["ctrl_tangent"], rtol=1e-12, atol=1e-12)


def test_from_segments_averages_asymmetric_handles():
    """Hand-made segments that neither join nor mirror their handles (1-D curves, 8 frames at
    stride 3: knots 0, 3, 6, 7 — the last segment is 1 frame long, ``a = 1/3``)."""
    layout = BezierLayout(8, 3)
    segments = jnp.asarray([
        [0.0, 1.0, 2.0, 3.0],   # ends at 3 with in-handle offset 3 − 2 = 1
        [4.0, 6.0, 7.0, 9.0],   # starts at 4 (not 3) with out-handle offset 2; ends at 9, in-handle offset 2
        [8.0, 9.0, 9.5, 10.0],  # starts at 8, out-handle offset 1, in-handle offset 0.5, both over a = 1/3
    ])[:, :, None]  # fmt: skip
    pos, tangent = from_segments(layout, segments)
    # Shared end points: averages of the two ends that meet; the window's ends are kept.
    np.testing.assert_allclose(pos[:, 0], [0.0, 3.5, 8.5, 10.0])
    # Tangents: the two handle offsets of an interior control point (each divided by its a) averaged.
    np.testing.assert_allclose(tangent[:, 0], [1.0, (1.0 + 2.0) / 2, (2.0 + 1.0 * 3) / 2, 0.5 * 3])
    # The result is symmetric: its own 4-point form round-trips.
    again = from_segments(layout, to_segments(layout, pos, tangent))
    tree_allclose(again, (pos, tangent))


# ------------------------------------------------------------------------------ rotations


def test_interpolate_rotations(rng):
    """Control quaternions at control frames, slerp at every frame (midway == ``rotations.slerp``),
    clamped outside the window; a shorter last segment (31 frames at stride 4) included."""
    layout = BezierLayout(31, 4)
    knots = layout.control_frames
    quat = random_quat_np(rng, (2, layout.num_controls))
    midway = knots[:-1] + np.diff(knots) // 2  # 2, 6, …, 26 and 29 in the 2-frame last segment

    @functools.partial(jax.jit, compiler_options=FAST_COMPILE)
    def compute(q):
        return (interpolate_rotations(layout, q), slerp(q[:, :-1], q[:, 1:], 0.5),
                interpolate_rotations(layout, q, jnp.asarray([-3.0, 33.5])))  # fmt: skip

    dense, halfway, outside = jax.device_get(compute(jnp.asarray(quat, jnp.float32)))
    assert dense.shape == (2, 31, 4)
    np.testing.assert_allclose(np.linalg.norm(dense, axis=-1), 1.0, atol=1e-6)
    assert_same_rotation(dense[:, knots], quat, atol=1e-6)
    assert_same_rotation(dense[:, midway], halfway, atol=1e-6)
    segment = np.minimum(np.arange(31) // 4, layout.num_segments - 1)
    t = (np.arange(31) - knots[segment]) / np.diff(knots)[segment]
    assert_same_rotation(dense, np_slerp(quat[:, segment], quat[:, segment + 1], t), atol=1e-5)
    assert_same_rotation(outside, quat[:, [0, -1]], atol=1e-6)


def test_reconstruct_dense(rng):
    """``(controls, joints, ·)`` → ``(frames, joints, ·)``: per joint the Bézier curve of
    :func:`evaluate` and the slerp of :func:`interpolate_rotations`; control frames hit exactly.
    Extra leading axes and fractional frame times pass through."""
    layout = BezierLayout(31, 6)
    joints = 4
    ctrl_pos, ctrl_tangent = random_controls(rng, layout, batch=(2,), dim=joints * 3, scale=10.0)
    ctrl_pos, ctrl_tangent = (a.reshape(2, layout.num_controls, joints, 3) for a in (ctrl_pos, ctrl_tangent))
    ctrl_quat = random_quat(rng, (2, layout.num_controls, joints))
    frames = jnp.asarray([0.5, 7.25, 29.0], jnp.float32)

    @functools.partial(jax.jit, compiler_options=FAST_COMPILE)
    def compute(p, t, q):
        r6 = rot6d_from_quat(q)
        per_joint = [(evaluate(layout, p[0, :, j], t[0, :, j]),
                      rot6d_from_quat(interpolate_rotations(layout, q[0, :, j]))) for j in range(joints)]  # fmt: skip
        return r6, reconstruct_dense(layout, p[0], t[0], r6[0]), per_joint, reconstruct_dense(layout, p, t, r6, frames)

    r6, (pos, rot6d), per_joint, (pos_f, rot6d_f) = jax.device_get(compute(ctrl_pos, ctrl_tangent, ctrl_quat))
    assert pos.shape == (31, joints, 3) and rot6d.shape == (31, joints, 6)
    for j, (curve, slerped) in enumerate(per_joint):
        np.testing.assert_allclose(pos[:, j], curve, rtol=1e-6, atol=1e-5)
        np.testing.assert_allclose(rot6d[:, j], slerped, atol=1e-5)  # ortho6D is sign-free: compare directly
    np.testing.assert_allclose(pos[layout.control_frames], ctrl_pos[0], atol=1e-5)
    np.testing.assert_allclose(rot6d[layout.control_frames], r6[0], atol=1e-5)
    assert pos_f.shape == (2, 3, joints, 3) and rot6d_f.shape == (2, 3, joints, 6)
    np.testing.assert_allclose(pos_f[0, -1], pos[29], atol=1e-5)
    np.testing.assert_allclose(rot6d_f[0, -1], rot6d[29], atol=1e-5)
    assert np.abs(pos_f[1] - pos_f[0]).max() > 1.0  # the second batch element is a different curve


# ------------------------------------------------------------------------------ bad input

WRONG = r"expected \(\.\.\., 6, dim\) control arrays for BezierLayout\(num_frames=31, stride=6\)"


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda L: evaluate(L, jnp.zeros((2, 5, 3)), jnp.zeros((2, 5, 3))), WRONG + r", got shape \(2, 5, 3\)"),
        (lambda L: to_segments(L, jnp.zeros((7, 3)), jnp.zeros((7, 3))), WRONG + r", got shape \(7, 3\)"),
        (lambda L: from_segments(L, jnp.zeros((2, 4, 4, 3))),
         r"expected \(\.\.\., 5, 4, dim\) segments for BezierLayout\(num_frames=31, stride=6\), got \(2, 4, 4, 3\)"),
        (lambda L: interpolate_rotations(L, jnp.zeros((3, 5, 4))), WRONG + r", got shape \(3, 5, 4\)"),
        (lambda L: reconstruct_dense(L, jnp.zeros((5, 2, 3)), jnp.zeros((5, 2, 3)), jnp.zeros((5, 2, 6))),
         r"expected \(\.\.\., 6, joints, ·\) control arrays for BezierLayout\(num_frames=31, stride=6\), "
         r"got shape \(5, 2, 3\)"),
        (lambda L: fit_curves(L, jnp.zeros((2, 30, 3))),
         r"expected \(\.\.\., 31, dim\) points for BezierLayout\(num_frames=31, stride=6\), got shape \(2, 30, 3\)"),
        (lambda L: finite_difference_tangents(L, jnp.zeros((20, 3))),
         r"expected \(\.\.\., 31, dim\) points for BezierLayout\(num_frames=31, stride=6\), got shape \(20, 3\)"),
    ],
    ids=["evaluate", "to_segments", "from_segments", "interpolate_rotations", "reconstruct_dense", "fit_curves",
         "finite_difference_tangents"],
)  # fmt: skip
def test_wrong_control_or_frame_counts_are_rejected(call, message):
    with pytest.raises(ValueError, match=message):
        call(BezierLayout(31, 6))


def test_numpy_integers_are_accepted_and_stored_as_int():
    layout = BezierLayout(np.int64(31), np.int32(6))
    assert layout == BezierLayout(31, 6) and type(layout.num_frames) is int and type(layout.stride) is int
    assert BezierLayout.from_controls(np.int64(3)) == BezierLayout(13, 6)
    np.testing.assert_allclose(evaluate(layout, jnp.zeros((6, 3)), jnp.zeros((6, 3)), np.arange(3)), 0.0)
