"""LAPACK-free small solves (``bezmotion._src.linalg``) against numpy's LAPACK, and the
library's jitted paths free of LAPACK calls (the sampler's and the exact IK's are checked
beside their other tests: ``tests/bmm/test_off_grid.py``, ``tests/ik/test_exact.py``)."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import lapack_calls, np_matrix_from_quat, np_quat_from_axis_angle, np_quat_mul, random_quat

from bezmotion.bezier import BezierLayout, evaluate, fit_curves
from bezmotion._src.linalg import cholesky_solve, inverse_3x3, min_norm_solve, top_eigenvector
from bezmotion.pipeline.transfer import mean_rotation


def test_min_norm_solve_is_pinv_on_consistent_systems_of_any_rank(rng):
    a = rng.normal(size=(5, 4, 12))
    a[:, 1] = 0.0  # a zero row (padding)
    a[:, 3] = a[:, 0]  # a duplicate
    a[1] = 0.0  # a system with no equation at all
    x_true = rng.normal(size=(5, 12))
    b = np.einsum("bmn,bn->bm", a, x_true)  # consistent
    got = np.asarray(min_norm_solve(jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)))
    expected = np.einsum("bnm,bm->bn", np.linalg.pinv(a), b)
    np.testing.assert_allclose(got, expected, atol=2e-5 * np.abs(expected).max())
    np.testing.assert_allclose(np.einsum("bmn,bn->bm", a, got), b, atol=1e-4 * np.abs(b).max())
    np.testing.assert_array_equal(got[1], 0.0)  # nothing to meet: no move


def test_min_norm_solve_keeps_the_first_of_contradicting_rows():
    a = jnp.asarray([[1.0, 0.0], [1.0, 0.0]])
    np.testing.assert_allclose(min_norm_solve(a, jnp.asarray([2.0, 5.0])), [2.0, 0.0])


def test_min_norm_solve_reaches_float64_precision(x64, rng):
    a = rng.normal(size=(6, 12)) * np.logspace(0, 3, 6)[:, None]  # rows of very different scale
    b = rng.normal(size=6)
    got = np.asarray(min_norm_solve(jnp.asarray(a), jnp.asarray(b)))
    np.testing.assert_allclose(got, np.linalg.pinv(a) @ b, rtol=1e-10, atol=1e-12)


def test_cholesky_solve_matches_lapack(rng):
    j = rng.normal(size=(3, 36, 40))
    spd = j @ j.swapaxes(-1, -2) + np.eye(36)
    rhs = rng.normal(size=(3, 36))
    got = np.asarray(cholesky_solve(jnp.asarray(spd, jnp.float32), jnp.asarray(rhs, jnp.float32)))
    expected = np.linalg.solve(spd, rhs[..., None])[..., 0]
    np.testing.assert_allclose(got, expected, rtol=1e-3, atol=1e-4 * np.abs(expected).max())
    assert np.isnan(np.asarray(cholesky_solve(-jnp.eye(3), jnp.ones(3)))).all()  # not positive definite


def test_inverse_3x3_matches_lapack(rng):
    m = rng.normal(size=(4, 2, 3, 3)) + 3.0 * np.eye(3)
    np.testing.assert_allclose(np.asarray(inverse_3x3(jnp.asarray(m))), np.linalg.inv(m), rtol=1e-5, atol=1e-6)


def test_top_eigenvector_matches_eigh(rng):
    m = rng.normal(size=(4, 5, 5))
    sym = m + m.swapaxes(-1, -2)
    got = np.asarray(top_eigenvector(jnp.asarray(sym, jnp.float32)))
    _, vectors = np.linalg.eigh(sym)
    expected = vectors[..., -1]
    sign = np.sign(np.sum(got * expected, -1, keepdims=True))
    np.testing.assert_allclose(got * sign, expected, atol=1e-4)


def test_mean_rotation_is_the_svd_chordal_mean(rng):
    # Poses of one joint: spread up to ~60° about a centre, each rotation with either sign.
    axis = rng.normal(size=(50, 3))
    spread = np_quat_from_axis_angle(axis / np.linalg.norm(axis, axis=-1, keepdims=True), rng.uniform(0, 1.0, 50))
    quat = np_quat_mul(np.asarray(random_quat(rng)), spread) * np.sign(rng.normal(size=(50, 1)))
    got = np.asarray(jax.jit(mean_rotation)(jnp.asarray(quat, jnp.float32)))
    u, _, vt = np.linalg.svd(np_matrix_from_quat(quat).mean(0))
    nearest = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    np.testing.assert_allclose(np_matrix_from_quat(got), nearest, atol=1e-4)
    assert got[0] >= 0


@pytest.mark.parametrize(
    "name, fn, args",
    [
        ("mean_rotation", jax.vmap(mean_rotation, in_axes=1), (jnp.ones((20, 6, 4)),)),
        ("fit_curves", lambda p: fit_curves(BezierLayout.from_controls(6, 6), p), (jnp.ones((8, 6, 31, 3)),)),
    ],
)
def test_no_lapack_calls(name, fn, args):
    assert lapack_calls(fn, *args) == set(), name


@pytest.mark.parametrize(
    "name, fn, args",
    [
        ("evaluate", lambda p, t: evaluate(BezierLayout.from_controls(6, 6), p, t), (jnp.ones((2, 6, 3)), jnp.ones((2, 6, 3)))),
        ("fit_curves", lambda p: fit_curves(BezierLayout.from_controls(6, 6), p), (jnp.ones((2, 31, 3)),)),
        ("min_norm_solve", min_norm_solve, (jnp.ones((4, 6)), jnp.ones(4))),
        ("cholesky_solve", cholesky_solve, (jnp.eye(4), jnp.ones(4))),
    ],
)
def test_geometric_products_ask_for_full_float32(name, fn, args):
    """Every matrix product of these asks for full precision, so a GPU does not run it in
    TF32 (which kept the curve fit from converging on an H200); CPUs ignore the request."""
    text = jax.jit(fn).lower(*args).as_text()
    dots = re.findall(r"stablehlo\.dot_general.*", text)
    assert dots, name
    assert all("HIGHEST" in d for d in dots), (name, [d for d in dots if "HIGHEST" not in d][:2])
