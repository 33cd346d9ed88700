"""Tests for ``bezmotion.geometry.rotations`` against plain-NumPy references and JAX contracts."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxtyping
import numpy as np
import pytest
from helpers import (
    assert_finite_gradients,
    assert_same_rotation,
    check_jacobians,
    np_fix_continuity,
    np_matrix_from_euler,
    np_matrix_from_quat,
    np_quat_from_axis_angle,
    np_quat_mul,
    np_quat_rotate,
    np_slerp,
    random_quat,
    random_quat_np,
    tree_allclose,
)

from bezmotion.geometry import rotations as R

ORDERS = R.EULER_ORDERS

#: Batch size used throughout: one shape keeps eager-mode compilation caches shared between tests.
N = 64


def random_angles(rng: np.random.Generator, shape: tuple[int, ...], margin: float = 0.05) -> np.ndarray:
    """Euler angles: outer angles in (-π, π), middle angle in (-π/2 + margin, π/2 - margin)."""
    outer = rng.uniform(-np.pi, np.pi, size=(*shape, 2))
    mid = rng.uniform(-np.pi / 2 + margin, np.pi / 2 - margin, size=shape)
    return np.stack([outer[..., 0], mid, outer[..., 1]], axis=-1)


def rotation_by_pi_matrices() -> jax.Array:
    """Rotations by π (w = 0) about x, y, z and a diagonal axis, plus the identity: Shepperd's corner cases."""
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, 0, 1]], float)
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    angles = np.array([np.pi, np.pi, np.pi, np.pi, 0.0])
    return jnp.asarray(np_matrix_from_quat(np_quat_from_axis_angle(axes, angles)), jnp.float32)


# ----------------------------------------------------------------------- runtime checking


def test_runtime_type_checking_is_active():
    """conftest installs jaxtyping+beartype on the package: a wrong last-axis size is rejected."""
    with pytest.raises(jaxtyping.TypeCheckError, match="quat_mul"):
        R.quat_mul(jnp.ones((2, 3)), jnp.ones((2, 3)))


def test_safe_norm_keepdims_shape():
    """``keepdims=True`` keeps a size-1 axis (and passes the runtime return-type check)."""
    x = jnp.array([[3.0, 4.0], [0.0, 0.0]])
    np.testing.assert_allclose(R.safe_norm(x, keepdims=True), [[5.0], [0.0]])
    np.testing.assert_allclose(R.safe_norm(x), [5.0, 0.0])


# --------------------------------------------------------------------------- quaternions


def test_quat_mul_matches_numpy_reference(rng):
    a, b = random_quat(rng, (N,)), random_quat(rng, (N,))
    np.testing.assert_allclose(R.quat_mul(a, b), np_quat_mul(a, b), atol=1e-6)


def test_quat_mul_applies_right_operand_first(rng):
    """As matrices, ``quat_mul(a, b)`` is ``R_a @ R_b``."""
    a, b = random_quat(rng, (N,)), random_quat(rng, (N,))
    np.testing.assert_allclose(
        np_matrix_from_quat(R.quat_mul(a, b)), np_matrix_from_quat(a) @ np_matrix_from_quat(b), atol=1e-5
    )


def test_quat_mul_is_associative_with_identity(rng):
    a, b, c = (random_quat(rng, (N,)) for _ in range(3))
    np.testing.assert_allclose(R.quat_mul(R.quat_mul(a, b), c), R.quat_mul(a, R.quat_mul(b, c)), atol=1e-6)
    identity = R.quat_identity((N,))
    np.testing.assert_allclose(R.quat_mul(identity, a), a, atol=1e-7)
    np.testing.assert_allclose(R.quat_mul(a, identity), a, atol=1e-7)


def test_quat_mul_broadcasts(rng):
    a, b = random_quat(rng, (4, 1)), random_quat(rng, (5,))
    out = R.quat_mul(a, b)
    assert out.shape == (4, 5, 4)
    np.testing.assert_allclose(out, np_quat_mul(a, b), atol=1e-6)


def test_quat_inverse(rng):
    """``q ⊗ q⁻¹ = 1`` also for non-unit quaternions; for unit ones the inverse is the conjugate."""
    q = random_quat(rng, (N,)) * jnp.asarray(rng.uniform(0.2, 3.0, size=(N, 1)), jnp.float32)
    np.testing.assert_allclose(R.quat_mul(q, R.quat_inverse(q)), R.quat_identity((N,)), atol=1e-5)
    np.testing.assert_allclose(R.quat_mul(R.quat_inverse(q), q), R.quat_identity((N,)), atol=1e-5)
    unit = random_quat(rng, (N,))
    np.testing.assert_allclose(R.quat_inverse(unit), R.quat_conjugate(unit), atol=1e-6)


def test_quat_normalize_maps_zero_to_identity(rng):
    q = jnp.concatenate([jnp.zeros((1, 4)), 3.0 * random_quat(rng, (3,))])
    out = R.quat_normalize(q)
    np.testing.assert_allclose(out[0], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(jnp.linalg.norm(out, axis=-1), 1.0, atol=1e-6)


def test_quat_rotate_matches_matrix_and_sandwich_product(rng):
    q, v = random_quat(rng, (N,)), jnp.asarray(rng.normal(size=(N, 3)), jnp.float32)
    rotated = R.quat_rotate(q, v)
    np.testing.assert_allclose(rotated, np.einsum("nij,nj->ni", R.matrix_from_quat(q), v), atol=1e-5)
    np.testing.assert_allclose(rotated, np_quat_rotate(q, v), atol=1e-5)


def test_quat_from_axis_angle_matches_numpy():
    axis = np.array([0.0, 0.6, 0.8])
    q = R.quat_from_axis_angle(jnp.asarray(axis * 5.0, jnp.float32), jnp.asarray(1.1, jnp.float32))
    np.testing.assert_allclose(q, np_quat_from_axis_angle(axis, 1.1), atol=1e-6)


def test_quat_between_rotates_u_onto_v(rng):
    """Generic, parallel and exactly opposite directions (float32 rounding at the opposite case)."""
    u, v = rng.normal(size=(N, 3)), rng.normal(size=(N, 3))
    u[0], v[0] = [1.0, 2.0, 3.0], [-2.0, -4.0, -6.0]  # opposite
    u[1], v[1] = [1.0, 0.0, 0.0], [-3.0, 0.0, 0.0]  # opposite, along a basis axis
    u[2], v[2] = [1.0, 2.0, 3.0], [0.5, 1.0, 1.5]  # parallel
    q = R.quat_between(jnp.asarray(u, jnp.float32), jnp.asarray(v, jnp.float32))
    u_unit = u / np.linalg.norm(u, axis=-1, keepdims=True)
    v_unit = v / np.linalg.norm(v, axis=-1, keepdims=True)
    np.testing.assert_allclose(np_quat_rotate(q, u_unit), v_unit, atol=1e-5)
    np.testing.assert_allclose(q[2], [1.0, 0.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(q[:2, 0], 0.0, atol=1e-6)  # rotations by π


@pytest.mark.parametrize("axis", [-3, 0, 1])
def test_quat_fix_continuity_matches_sequential_loop(rng, axis):
    """Closed-form sign fix == the sequential loop (frame t flipped when dot(fixed t-1, q_t) < 0)."""
    frames, joints = 25, 3
    # A smooth motion (spinning about z at a different speed per joint), randomly sign-flipped.
    spin = np.linspace(0.0, 2.0, frames)[:, None] * rng.uniform(0.5, 2.0, joints)
    q = np_quat_mul(random_quat_np(rng, (1, joints)), np_quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), spin))
    q = q * rng.choice([-1.0, 1.0], size=(frames, joints, 1))
    expected = np_fix_continuity(q)  # time on axis 0
    layout = {-3: (0, 1, 2), 0: (0, 1, 2), 1: (1, 0, 2)}[axis]
    out = R.quat_fix_continuity(jnp.asarray(q.transpose(layout), jnp.float32), axis=axis)
    np.testing.assert_allclose(np.asarray(out).transpose(layout), expected, atol=1e-6)
    assert np.all(np.sum(expected[1:] * expected[:-1], axis=-1) >= 0.0)


# ------------------------------------------------------------------ matrices and ortho6D


def test_matrix_from_quat_matches_numpy(rng):
    q = random_quat(rng, (N,))
    m = R.matrix_from_quat(q)
    np.testing.assert_allclose(m, np_matrix_from_quat(q), atol=1e-6)
    np.testing.assert_allclose(jnp.linalg.det(m), 1.0, atol=1e-5)


def test_quat_matrix_round_trip(rng):
    """quat → matrix → quat recovers the rotation (w ≥ 0), including all of Shepperd's branches."""
    q = random_quat(rng, (N,))
    back = R.quat_from_matrix(R.matrix_from_quat(q))
    assert_same_rotation(back, q, atol=1e-5)
    assert np.all(np.asarray(back[..., 0]) >= 0.0)
    m = rotation_by_pi_matrices()
    np.testing.assert_allclose(R.matrix_from_quat(R.quat_from_matrix(m)), m, atol=1e-6)


def test_rot6d_is_first_two_columns_and_round_trips(rng):
    q = random_quat(rng, (N,))
    m = R.matrix_from_quat(q)
    r6 = R.rot6d_from_quat(q)
    np.testing.assert_allclose(r6, np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1), atol=1e-7)
    np.testing.assert_allclose(R.matrix_from_rot6d(r6), m, atol=1e-5)
    assert_same_rotation(R.quat_from_rot6d(r6), q, atol=1e-5)


def test_matrix_from_rot6d_orthonormalises(rng):
    """Any generic 6D vector maps to a proper rotation whose first column is the normalised a1."""
    r6 = jnp.asarray(rng.normal(size=(N, 6)), jnp.float32)
    m = np.asarray(R.matrix_from_rot6d(r6), np.float64)
    np.testing.assert_allclose(np.swapaxes(m, -1, -2) @ m, np.broadcast_to(np.eye(3), m.shape), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-5)
    a1 = np.asarray(r6[:, :3])
    np.testing.assert_allclose(m[..., 0], a1 / np.linalg.norm(a1, axis=-1, keepdims=True), atol=1e-6)


# ---------------------------------------------------------------------------------- Euler


@pytest.mark.parametrize("order", ORDERS)
def test_quat_from_euler_matches_matrix_product(rng, order):
    """``"abc"`` means ``R_a(e0) @ R_b(e1) @ R_c(e2)``."""
    angles = random_angles(rng, (N,))
    np.testing.assert_allclose(
        R.matrix_from_quat(R.quat_from_euler(jnp.asarray(angles, jnp.float32), order)), np_matrix_from_euler(angles, order), atol=1e-5
    )


@pytest.mark.parametrize("order", ORDERS)
def test_euler_round_trip_recovers_angles(rng, order):
    angles = random_angles(rng, (N,))
    back = R.euler_from_quat(R.quat_from_euler(jnp.asarray(angles, jnp.float32), order), order)
    np.testing.assert_allclose(back, angles, atol=2e-4)


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("mid", [np.pi / 2, -np.pi / 2])
def test_euler_round_trip_at_gimbal_lock_recovers_rotation(rng, order, mid):
    """At gimbal lock the angles are not unique: the rotation is recovered and the last angle is 0."""
    angles = random_angles(rng, (N,))
    angles[:, 1] = mid
    q = R.quat_from_euler(jnp.asarray(angles, jnp.float32), order)
    back = R.euler_from_quat(q, order)
    np.testing.assert_allclose(np.abs(back[:, 1]), np.pi / 2, atol=2e-3)
    np.testing.assert_allclose(back[:, 2], 0.0, atol=1e-6)
    np.testing.assert_allclose(np_matrix_from_euler(back, order), np_matrix_from_euler(angles, order), atol=1e-4)


def test_euler_order_is_case_insensitive(rng):
    angles = jnp.asarray(random_angles(rng, (5,)), jnp.float32)
    np.testing.assert_allclose(R.quat_from_euler(angles, "ZXY"), R.quat_from_euler(angles, "zxy"))


@pytest.mark.parametrize("fn", [R.quat_from_euler, R.euler_from_quat])
def test_unknown_euler_order_raises(fn):
    with pytest.raises(ValueError, match="'xyy'"):
        fn(jnp.zeros((2, 4 if fn is R.euler_from_quat else 3)), "xyy")


# ----------------------------------------------------------------------------------- slerp


def test_slerp_endpoints(rng):
    q0, q1 = random_quat(rng, (N,)), random_quat(rng, (N,))
    np.testing.assert_allclose(R.slerp(q0, q1, 0.0), q0, atol=1e-6)
    # At t = 1 the shortest-path end is ±q1, whichever is closer to q0.
    near_q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0.0, -q1, q1)
    np.testing.assert_allclose(R.slerp(q0, q1, 1.0), near_q1, atol=1e-6)


@pytest.mark.parametrize("angle", [0.9, 2.5, 3.1])
def test_slerp_halfway_about_an_axis(rng, angle):
    """Halfway from q0 to q0 ⊗ rot(axis, θ) is q0 ⊗ rot(axis, θ/2)."""
    axis = np.array([0.48, -0.6, 0.64])
    q0 = random_quat_np(rng)
    q1 = np_quat_mul(q0, np_quat_from_axis_angle(axis, angle))
    out = R.slerp(jnp.asarray(q0, jnp.float32), jnp.asarray(q1, jnp.float32), 0.5)
    np.testing.assert_allclose(out, np_quat_mul(q0, np_quat_from_axis_angle(axis, angle / 2)), atol=1e-5)


def test_slerp_takes_shortest_path(rng):
    q0, q1 = random_quat(rng, (N,)), random_quat(rng, (N,))
    t = jnp.asarray(rng.uniform(size=N), jnp.float32)
    np.testing.assert_allclose(R.slerp(q0, q1, t), R.slerp(q0, -q1, t), atol=1e-6)
    # The path never goes further than the end: the angle to q0 grows to at most π/2 (in w).
    np.testing.assert_array_less(-1e-6, np.abs(np.sum(np.asarray(R.slerp(q0, q1, t)) * np.asarray(q0), axis=-1)))


def test_slerp_matches_numpy_reference(rng):
    q0, q1 = random_quat(rng, (N,)), random_quat(rng, (N,))
    t = jnp.asarray(rng.uniform(size=N), jnp.float32)
    far = np.abs(np.sum(q0 * q1, axis=-1)) < 0.98  # away from the nlerp branch
    assert far.sum() > 0.8 * N
    np.testing.assert_allclose(R.slerp(q0, q1, t)[far], np_slerp(q0, q1, t)[far], atol=2e-5)


def test_slerp_uses_nlerp_near_identity(rng):
    """When ``1 - |dot| < 0.01`` slerp is normalised lerp — still within 1e-4 of true slerp."""
    q0 = random_quat_np(rng, (N,))
    axes = rng.normal(size=(N, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    q1 = np_quat_mul(q0, np_quat_from_axis_angle(axes, rng.uniform(0.01, 0.25, N)))  # 1 - dot < 0.008
    t = rng.uniform(size=N)
    out = R.slerp(jnp.asarray(q0, jnp.float32), jnp.asarray(q1, jnp.float32), jnp.asarray(t, jnp.float32))
    lerp = (1 - t[:, None]) * q0 + t[:, None] * q1
    np.testing.assert_allclose(out, lerp / np.linalg.norm(lerp, axis=-1, keepdims=True), atol=1e-6)
    np.testing.assert_allclose(out, np_slerp(q0, q1, t), atol=1e-4)
    assert not np.allclose(out, np_slerp(q0, q1, t), atol=1e-7)  # the branch really is nlerp


def test_slerp_broadcasts_weights(rng):
    q0, q1 = random_quat(rng, ()), random_quat(rng, ())
    t = jnp.linspace(0.0, 1.0, 7)
    out = R.slerp(q0, q1, t)
    assert out.shape == (7, 4)
    np.testing.assert_allclose(out[3], R.slerp(q0, q1, t[3]), atol=1e-6)


def test_quat_exp_matches_axis_angle_and_log_inverts_it(rng):
    axis = rng.normal(size=(64, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.concatenate([rng.uniform(0.0, np.pi - 1e-3, 60), [0.0, 1e-6, 5e-5, 2e-4]])  # across the series threshold
    v = jnp.asarray(axis * angle[:, None], jnp.float32)
    q = R.quat_exp(v)
    expected = R.quat_from_axis_angle(jnp.asarray(axis, jnp.float32), jnp.asarray(angle, jnp.float32))
    np.testing.assert_allclose(np.asarray(q), np.asarray(expected), atol=1e-6)
    np.testing.assert_allclose(np.asarray(R.quat_log(q)), np.asarray(v), atol=2e-6)
    np.testing.assert_allclose(np.asarray(R.quat_log(-q)), np.asarray(v), atol=2e-6)  # either sign: the short way


def test_quat_angle_is_the_relative_rotation_angle(rng):
    q0 = random_quat(rng, (32,))
    axis = jnp.asarray(rng.normal(size=(32, 3)), jnp.float32)
    angle = jnp.asarray(rng.uniform(0.0, np.pi, 32), jnp.float32)
    q1 = R.quat_mul(q0, R.quat_from_axis_angle(axis, angle))
    np.testing.assert_allclose(np.asarray(R.quat_angle(q0, q1)), np.asarray(angle), atol=2e-5)
    np.testing.assert_allclose(np.asarray(R.quat_angle(q0, -q1)), np.asarray(angle), atol=2e-5)
    np.testing.assert_allclose(np.asarray(R.quat_angle(q1, q0)), np.asarray(angle), atol=2e-5)
    tiny = R.quat_mul(q0, R.quat_from_axis_angle(axis, jnp.full(32, 1e-4, jnp.float32)))
    np.testing.assert_allclose(np.asarray(R.quat_angle(q0, tiny)), 1e-4, rtol=0.05)  # acos(dot) would lose it


# --------------------------------------------------------------------------- JAX contracts


def _contract_cases(rng: np.random.Generator) -> dict:
    """``name -> (fn, args)``: every public function with a small float32 batch of 4."""
    q0, q1 = random_quat(rng, (4,)), random_quat(rng, (4,))
    vec = jnp.asarray(rng.normal(size=(4, 3)), jnp.float32)
    vec2 = jnp.asarray(rng.normal(size=(4, 3)), jnp.float32)
    r6 = jnp.asarray(rng.normal(size=(4, 6)), jnp.float32)
    t = jnp.asarray(rng.uniform(size=4), jnp.float32)
    angle = jnp.asarray(rng.normal(size=4), jnp.float32)
    m = R.matrix_from_quat(q0)
    return {
        "quat_mul": (R.quat_mul, (q0, q1)),
        "quat_inverse": (R.quat_inverse, (q0,)),
        "quat_rotate": (R.quat_rotate, (q0, vec)),
        "quat_from_axis_angle": (R.quat_from_axis_angle, (vec, angle)),
        "quat_between": (R.quat_between, (vec, vec2)),
        "slerp": (R.slerp, (q0, q1, t)),
        "matrix_from_quat": (R.matrix_from_quat, (q0,)),
        "quat_from_matrix": (R.quat_from_matrix, (m,)),
        "matrix_from_rot6d": (R.matrix_from_rot6d, (r6,)),
        "quat_from_rot6d": (R.quat_from_rot6d, (r6,)),
        "quat_from_euler": (functools.partial(R.quat_from_euler, order="yzx"), (vec,)),
        "euler_from_quat": (functools.partial(R.euler_from_quat, order="zxy"), (q0,)),
        "normalize": (R.normalize, (vec,)),
        "quat_angle": (R.quat_angle, (q0, q1)),
        "quat_exp": (R.quat_exp, (vec,)),
        "quat_log": (R.quat_log, (q0,)),
    }


CASE_NAMES = sorted(_contract_cases(np.random.default_rng(0)))


@pytest.mark.parametrize("name", CASE_NAMES)
def test_jit_matches_eager(rng, name):
    fn, args = _contract_cases(rng)[name]
    tree_allclose(jax.jit(fn)(*args), fn(*args), atol=1e-6)


@pytest.mark.parametrize("name", CASE_NAMES)
def test_vmap_matches_python_loop(rng, name):
    fn, args = _contract_cases(rng)[name]
    single = jax.jit(fn)  # jit both sides: two compilations instead of every primitive eagerly
    looped = jnp.stack([single(*(a[i] for a in args)) for i in range(len(args[0]))])
    tree_allclose(jax.jit(jax.vmap(fn))(*args), looped, atol=1e-6)


def test_jacobians_slerp(rng, x64):
    """slerp w.r.t. both ends and the weight, on the slerp branch and on the nlerp branch."""
    q0 = random_quat(rng, (3,))
    q1 = jnp.concatenate([random_quat(rng, (2,)), q0[2:] + 0.01])  # last pair: nlerp
    t = jnp.asarray(rng.uniform(0.1, 0.9, size=3))
    check_jacobians(R.slerp, (q0, q1, t), argnums=(0, 1, 2))


def test_jacobians_quat_from_matrix(rng, x64):
    """Generic rotations and a near-π rotation (w ≈ 0, a non-w Shepperd branch)."""
    # The last one is near a rotation by π (w ≈ 0) with a clear largest component (no branch tie).
    q = jnp.concatenate([random_quat(rng, (3,)), jnp.asarray([[0.05, 0.1, -0.75, 0.65]])])
    check_jacobians(R.quat_from_matrix, (R.matrix_from_quat(q),), argnums=(0,))


def test_jacobians_matrix_from_rot6d(rng, x64):
    check_jacobians(R.matrix_from_rot6d, (jnp.asarray(rng.normal(size=(3, 6))),), argnums=(0,))


def test_jacobians_euler_from_quat(rng, x64):
    """One cyclic and one acyclic order (their formulas differ by a sign), checked in one function."""
    q = R.quat_from_euler(jnp.asarray(random_angles(rng, (3,), margin=0.3)), "zyx")

    def both_orders(q):
        return jnp.stack([R.euler_from_quat(q, "zyx"), R.euler_from_quat(q, "yzx")])

    assert np.all(np.abs(np.asarray(both_orders(q))[:, :, 1]) < np.pi / 2 - 0.1)  # away from gimbal lock
    check_jacobians(both_orders, (q,), argnums=(0,))


def _singular_cases() -> dict:
    """``name -> (fn, args, argnums)`` at removable singularities (call with x64 enabled)."""
    identity = R.quat_identity((2,), jnp.float64)
    q = jnp.asarray([[0.5, 0.5, -0.5, 0.5], [0.0, 0.6, 0.0, 0.8]])  # the second is a rotation by π
    t = jnp.asarray([0.3, 0.7])
    u = jnp.asarray([[1.0, 2.0, 3.0], [0.0, 0.0, 1.0]])
    zyx = functools.partial(R.euler_from_quat, order="zyx")
    locked = R.quat_from_euler(jnp.asarray([[0.3, np.pi / 2, 0.2], [0.1, -np.pi / 2, 0.0]]), "zyx")
    return {
        "slerp_identity": (R.slerp, (identity, identity, t), (0, 1, 2)),
        "slerp_equal": (R.slerp, (q, q, t), (0, 1, 2)),
        "slerp_antipodal": (R.slerp, (q, -q, t), (0, 1, 2)),
        "normalize_zero": (R.normalize, (jnp.zeros((2, 3)),), (0,)),
        "safe_norm_zero": (R.safe_norm, (jnp.zeros((2, 3)),), (0,)),
        "quat_normalize_zero": (R.quat_normalize, (jnp.zeros((2, 4)),), (0,)),
        "quat_between_parallel": (R.quat_between, (u, 2.0 * u), (0, 1)),
        "quat_between_opposite": (R.quat_between, (u, -u), (0, 1)),
        "quat_from_matrix_identity": (R.quat_from_matrix, (jnp.broadcast_to(jnp.eye(3), (2, 3, 3)),), (0,)),
        "quat_from_matrix_pi": (R.quat_from_matrix, (R.matrix_from_quat(q),), (0,)),
        "quat_exp_zero": (R.quat_exp, (jnp.zeros((2, 3)),), (0,)),
        "quat_log_identity": (R.quat_log, (identity,), (0,)),
        "quat_angle_equal": (R.quat_angle, (q, q), (0, 1)),
        "quat_angle_antipodal": (R.quat_angle, (q, -q), (0, 1)),
        "euler_identity": (zyx, (identity,), (0,)),
        "euler_gimbal_lock": (zyx, (locked,), (0,)),
    }


def test_gradients_finite_at_singular_inputs(x64):
    """No NaN where the math has removable singularities: identity, antipodes, zero vectors."""
    assert_finite_gradients(_singular_cases())


@pytest.mark.parametrize("angle", [0.0, 1e-6, 0.3, 2.0, 3.1])
def test_right_jacobians_are_the_exponential_maps_derivative(rng, x64, angle):
    """``exp(v + dv) ≈ exp(v) ⊗ exp(J_r(v) dv)`` and ``log(exp(v) ⊗ exp(ε)) ≈ v + J_r⁻¹(v) ε`` to
    second order, on both sides of the Taylor-series switch and near π; ``J_r⁻¹`` inverts
    ``J_r``; ``skew(v) @ x`` is ``v × x``."""
    axis = rng.normal(size=3)
    v = jnp.asarray(angle * axis / np.linalg.norm(axis))
    d = jnp.asarray(1e-6 * rng.normal(size=3))
    jr, jr_inv = R.right_jacobian(v), R.right_jacobian_inverse(v)
    np.testing.assert_allclose(
        np.asarray(R.quat_mul(R.quat_exp(v), R.quat_exp(jr @ d))), np.asarray(R.quat_exp(v + d)), atol=1e-11
    )
    np.testing.assert_allclose(np.asarray(R.quat_log(R.quat_mul(R.quat_exp(v), R.quat_exp(d)))), np.asarray(v + jr_inv @ d), atol=1e-11)
    np.testing.assert_allclose(np.asarray(jr_inv @ jr), np.eye(3), atol=1e-12)
    x = jnp.asarray(rng.normal(size=3))
    np.testing.assert_allclose(np.asarray(R.skew(v) @ x), np.cross(np.asarray(v), np.asarray(x)), atol=1e-15)
