"""Helpers shared by the test modules.

Import them as ``from helpers import ...`` (pytest puts ``tests/`` on ``sys.path``);
``conftest`` re-exports the data-location helpers too.

- Data locations: ``SHARED_DATA`` and the ``requires_shared`` skip marker.
- Plain-NumPy reference implementations (written from the textbook definitions, not from
  the library's formulas) that the JAX code is compared against.
- Random inputs and a derivative checker (``jacfwd == jacrev == central differences``).

Nothing here imports ``bezmotion``, so importing this module never bypasses the jaxtyping
import hook that ``conftest`` installs.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from types import ModuleType
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

# ------------------------------------------------------------------------- data locations

#: ``../shared/data`` beside the repository (real mocap corpora; absent on fresh machines).
REPO_ROOT = Path(__file__).resolve().parents[1]  # the repository (tests/ lies directly under it)
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"

#: Skip marker for tests that need :data:`SHARED_DATA`.
requires_shared = pytest.mark.skipif(
    not SHARED_DATA.exists(), reason=f"shared mocap data not found at {SHARED_DATA}"
)

# ---------------------------------------------------------------------- NumPy references


def load_experiment(name: str, scripts: str = "experiments") -> ModuleType:
    """``<scripts>/<name>.py`` (``experiments/`` or ``benchmarks/``) loaded as a module, its
    folder on ``sys.path`` while it runs its imports, as when the script is started from the
    command line."""
    folder = REPO_ROOT / scripts
    sys.path.insert(0, str(folder))
    try:
        spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(folder))
    return module


def np_quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product from the scalar/vector form: ``(a0 b0 - a·b, a0 b + b0 a + a × b)``."""
    a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
    w = a[..., 0] * b[..., 0] - np.sum(a[..., 1:] * b[..., 1:], axis=-1)
    v = a[..., :1] * b[..., 1:] + b[..., :1] * a[..., 1:] + np.cross(a[..., 1:], b[..., 1:])
    return np.concatenate([w[..., None], v], axis=-1)


def np_quat_conj(q: np.ndarray) -> np.ndarray:
    """Quaternion conjugate."""
    return np.asarray(q, float) * np.array([1.0, -1.0, -1.0, -1.0])


def np_quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate ``v`` by unit ``q`` as the sandwich product ``q (0, v) q*``."""
    v = np.asarray(v, float)
    pure = np.concatenate([np.zeros((*v.shape[:-1], 1)), v], axis=-1)
    return np_quat_mul(np_quat_mul(q, pure), np_quat_conj(q))[..., 1:]


def np_matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix whose columns are the rotated basis vectors."""
    q = np.asarray(q, float)
    cols = [np_quat_rotate(q, np.broadcast_to(e, (*q.shape[:-1], 3))) for e in np.eye(3)]
    return np.stack(cols, axis=-1)


def np_axis_matrix(axis: str, angle: np.ndarray) -> np.ndarray:
    """Elementary rotation matrix about ``"x"``, ``"y"`` or ``"z"`` (batched over ``angle``)."""
    angle = np.asarray(angle, float)
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(c), np.zeros_like(c)
    rows = {
        "x": [[one, zero, zero], [zero, c, -s], [zero, s, c]],
        "y": [[c, zero, s], [zero, one, zero], [-s, zero, c]],
        "z": [[c, -s, zero], [s, c, zero], [zero, zero, one]],
    }[axis]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def np_matrix_from_euler(angles: np.ndarray, order: str) -> np.ndarray:
    """``R = R_a(e0) @ R_b(e1) @ R_c(e2)`` for ``order == "abc"``."""
    angles = np.asarray(angles, float)
    mats = [np_axis_matrix(axis, angles[..., k]) for k, axis in enumerate(order)]
    return mats[0] @ mats[1] @ mats[2]


def np_quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Quaternion of a rotation by ``angle`` about the unit ``axis``."""
    half = 0.5 * np.asarray(angle, float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * np.asarray(axis, float)], axis=-1)


def np_slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Shortest-path slerp as ``q0 ⊗ (q0* ⊗ q1)^t`` through the relative rotation's axis/angle."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0.0, -q1, q1)
    rel = np_quat_mul(np_quat_conj(q0), q1)
    vec_norm = np.linalg.norm(rel[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(vec_norm[..., 0], rel[..., 0])
    axis = rel[..., 1:] / np.where(vec_norm > 0.0, vec_norm, 1.0)
    return np_quat_mul(q0, np_quat_from_axis_angle(axis, np.asarray(t, float) * angle))


def np_fix_continuity(q: np.ndarray) -> np.ndarray:
    """Sequential sign fix along axis 0: frame t is negated when ``dot(fixed[t-1], q[t]) < 0``."""
    out = np.array(q, float, copy=True)
    for t in range(1, len(out)):
        flip = np.sum(out[t - 1] * out[t], axis=-1) < 0.0
        out[t] = np.where(flip[..., None], -out[t], out[t])
    return out


def np_forward_kinematics(
    parents: Sequence[int], quat_local: np.ndarray, pos_local: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Joint-by-joint forward kinematics over ``(..., J, 4)`` rotations and ``(..., J, 3)`` translations."""
    quat_local = np.asarray(quat_local, float)
    pos_local = np.broadcast_to(np.asarray(pos_local, float), (*quat_local.shape[:-1], 3))
    rot = np.empty_like(quat_local)
    pos = np.empty_like(pos_local)
    for j, p in enumerate(parents):
        if p < 0:
            rot[..., j, :] = quat_local[..., j, :]
            pos[..., j, :] = pos_local[..., j, :]
        else:
            rot[..., j, :] = np_quat_mul(rot[..., p, :], quat_local[..., j, :])
            pos[..., j, :] = np_quat_rotate(rot[..., p, :], pos_local[..., j, :]) + pos[..., p, :]
    return rot, pos


def turned_about_z(motion, degrees: float):
    """A BVH motion turned ``degrees`` about the world Z axis (its root's rotation and position):
    90° lays a Y-up body along −X."""
    import dataclasses

    turn = np_quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians(degrees))
    quat, pos = motion.quat_local.copy(), motion.pos_local.copy()
    quat[:, 0] = np_quat_mul(turn, quat[:, 0])
    pos[:, 0] = np_quat_rotate(turn, pos[:, 0])
    return dataclasses.replace(motion, quat_local=quat, pos_local=pos)


def assert_same_rotation(q: np.ndarray, ref: np.ndarray, atol: float) -> None:
    """Assert two quaternion arrays are equal up to the sign of each quaternion."""
    q, ref = np.asarray(q, float), np.asarray(ref, float)
    sign = np.where(np.sum(q * ref, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    np.testing.assert_allclose(q * sign, ref, atol=atol)


# ------------------------------------------------------------------------- random inputs


def random_quat_np(rng: np.random.Generator, shape: tuple[int, ...] = ()) -> np.ndarray:
    """Uniformly distributed random unit quaternions (both signs of w), NumPy float64."""
    q = rng.normal(size=(*shape, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def random_quat(rng: np.random.Generator, shape: tuple[int, ...] = (), dtype=None) -> jax.Array:
    """:func:`random_quat_np` as a JAX array (float32, or float64 under ``jax.enable_x64``)."""
    return jnp.asarray(random_quat_np(rng, shape), dtype or jnp.result_type(float))


def random_parents(rng: np.random.Generator, joints: int) -> tuple[int, ...]:
    """A random tree topology: root first, every joint's parent drawn among earlier joints."""
    return (-1, *(int(rng.integers(0, j)) for j in range(1, joints)))


def tree_allclose(a, b, rtol: float = 1e-6, atol: float = 1e-6) -> None:
    """Assert two pytrees of arrays have the same structure and close leaves."""
    leaves_a, tree_a = jax.tree_util.tree_flatten(a)
    leaves_b, tree_b = jax.tree_util.tree_flatten(b)
    assert tree_a == tree_b
    for x, y in zip(leaves_a, leaves_b, strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol)


# --------------------------------------------------------------------------- derivatives


def central_difference_jacobian(fn: Callable, args: Sequence, argnum: int, eps: float = 1e-6) -> jax.Array:
    """Jacobian of ``fn`` w.r.t. ``args[argnum]`` by central differences (all probes in one ``vmap``).

    Traceable, so it can run inside the same ``jit`` as the autodiff Jacobians.
    """
    x = jnp.asarray(args[argnum])
    basis = jnp.eye(x.size, dtype=x.dtype).reshape(x.size, *x.shape)

    def at(point):
        return fn(*args[:argnum], point, *args[argnum + 1 :])

    jac = (jax.vmap(at)(x + eps * basis) - jax.vmap(at)(x - eps * basis)) / (2.0 * eps)  # (x.size, *out)
    return jnp.moveaxis(jac, 0, -1).reshape(*jac.shape[1:], *x.shape)


def check_jacobians(
    fn: Callable, args: Sequence, argnums: Sequence[int], *, fd_rtol: float = 1e-5, fd_atol: float = 1e-6
) -> None:
    """Assert ``jacfwd == jacrev == central differences`` for each argument in ``argnums``.

    The inputs must be float64 (create them inside ``jax.enable_x64(True)``) so that
    central differences are accurate to ~1e-9 and the tolerances can stay tight.
    ``fn`` must return one array. Everything is computed in one ``jit`` (one compilation
    is far cheaper than compiling every primitive eagerly).
    """
    args = tuple(jnp.asarray(a) for a in args)
    for argnum in argnums:
        assert args[argnum].dtype == jnp.float64, "check_jacobians needs float64 inputs"

    @jax.jit
    def jacobians(*args):
        return [
            (jax.jacfwd(fn, argnums=i)(*args), jax.jacrev(fn, argnums=i)(*args), central_difference_jacobian(fn, args, i))
            for i in argnums
        ]

    for argnum, (fwd, rev, fd) in zip(argnums, jacobians(*args), strict=True):
        assert np.all(np.isfinite(fwd)), f"non-finite jacfwd w.r.t. argument {argnum}"
        np.testing.assert_allclose(fwd, rev, rtol=1e-9, atol=1e-12, err_msg=f"jacfwd != jacrev (argument {argnum})")
        np.testing.assert_allclose(
            fwd, fd, rtol=fd_rtol, atol=fd_atol, err_msg=f"jacfwd != finite differences (argument {argnum})"
        )


def assert_finite_gradients(cases: Mapping[str, tuple[Callable, Sequence, Sequence[int]]]) -> None:
    """Assert forward- and reverse-mode Jacobians are finite (no NaN/inf) for every case.

    ``cases`` maps a name to ``(fn, args, argnums)``. All Jacobians are computed in a
    single ``jit`` (one compilation); every non-finite one is reported by name.
    """
    static = {name: (fn, tuple(argnums)) for name, (fn, _, argnums) in cases.items()}

    @jax.jit
    def jacobians(all_args):
        return {
            (name, mode.__name__, i): mode(fn, argnums=i)(*all_args[name])
            for name, (fn, argnums) in static.items()
            for mode in (jax.jacfwd, jax.jacrev)
            for i in argnums
        }

    jacs = jacobians({name: tuple(args) for name, (_, args, _) in cases.items()})
    bad = [f"{name}: {mode} w.r.t. argument {i}" for (name, mode, i), jac in jacs.items() if not np.all(np.isfinite(jac))]
    assert not bad, "non-finite derivatives:\n" + "\n".join(bad)


# --------------------------------------------------------------------- comparing pytrees


def leaves(tree) -> list[np.ndarray]:
    """Leaves as NumPy arrays, typed PRNG keys as their raw data."""
    out = []
    for x in jax.tree.leaves(tree):
        if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
            x = jax.random.key_data(x)
        out.append(np.asarray(x))
    return out


def assert_trees_identical(a, b) -> None:
    """Same structure and bit-identical leaves."""
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(leaves(a), leaves(b), strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y)


def assert_trees_close(a, b, tol: float = 1e-6) -> None:
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(leaves(a), leaves(b), strict=True):
        np.testing.assert_allclose(x, y, rtol=tol, atol=tol)


def trees_differ(a, b) -> bool:
    return any(not np.array_equal(x, y) for x, y in zip(leaves(a), leaves(b), strict=True))


def without_key_bias(tree):
    """``tree`` with the key part of every attention input bias zeroed. That bias adds the
    same ``q·b_k`` to all of a query's logits, which softmax ignores: its true gradient is
    0, so Adam turns pure rounding noise into ±lr updates whose signs depend on how the
    computation was batched."""

    def strip(path, x):
        names = [str(getattr(p, "key", getattr(p, "name", ""))) for p in path]
        if "in_proj" in names and "bias" in names and x.shape[-1] % 3 == 0:
            w = x.shape[-1] // 3
            return x.at[..., w : 2 * w].set(0)
        return x

    return jax.tree_util.tree_map_with_path(strip, tree)


def lapack_calls(fn: Callable, *args, **kwargs) -> set[str]:
    """The LAPACK kernels ``jax.jit(fn)(*args, **kwargs)`` would call (from its lowering,
    nothing is compiled). Our code must call none: see :mod:`bezmotion._src.linalg` for the
    deadlock jaxlib's batched CPU kernels cause."""
    text = jax.jit(fn).lower(*args, **kwargs).as_text()
    return {name for name in re.findall(r"custom_call @(\w+)", text) if "lapack" in name.lower()}
