"""Rotations: unit quaternions (w, x, y, z), rotation vectors, ortho6D, rotation matrices, Euler angles, slerp.

Conventions used everywhere in bezmotion:

- Quaternions are stored ``(w, x, y, z)`` and composed with the Hamilton product;
  ``quat_mul(a, b)`` applies ``b`` first, then ``a`` (as matrices ``R_a @ R_b``).
- Rotation matrices act on column vectors: ``v' = R @ v``.
- ortho6D (Zhou et al. 2019) is the first two *columns* of the matrix, concatenated:
  ``rot6d = [R[:, 0], R[:, 1]]``.
- Euler angles are in radians; an order string such as ``"zyx"`` lists the axes as a
  BVH file lists its rotation channels and means ``R = R_z(e[0]) @ R_y(e[1]) @ R_x(e[2])``
  (intrinsic rotations in the listed order).

Every function accepts arbitrary leading batch axes and is safe under ``jit``, ``vmap``
and ``grad``: divisions, square roots and inverse trigonometry use the double-``where``
pattern so gradients stay finite at the identity, at antipodal quaternions and at
zero-length vectors.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

EULER_ORDERS: tuple[str, ...] = ("xyz", "xzy", "yxz", "yzx", "zxy", "zyx")
_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}

# Below this, a vector is treated as having zero length (normalisation returns a
# well-defined default instead of dividing by ~0).
_TINY = 1e-12
# Below this angle (rad) the exponential and logarithm maps use their Taylor series.
_SMALL_ANGLE = 1e-4


def _check_order(order: str) -> tuple[int, int, int]:
    if not isinstance(order, str) or order.lower() not in EULER_ORDERS:
        raise ValueError(f"unknown Euler order {order!r}; expected one of {EULER_ORDERS}")
    return tuple(_AXIS_INDEX[a] for a in order.lower())  # type: ignore[return-value]


def safe_norm(
    x: Float[Array, "*batch n"], keepdims: bool = False
) -> Float[Array, "*batch"] | Float[Array, "*batch 1"]:
    """Euclidean norm over the last axis whose gradient is 0 (not NaN) at the zero vector.

    With ``keepdims=True`` the reduced axis is kept with size 1 (shape ``(*batch, 1)``).
    """
    sq = jnp.sum(x * x, axis=-1, keepdims=keepdims)
    nonzero = sq > _TINY * _TINY
    return jnp.where(nonzero, jnp.sqrt(jnp.where(nonzero, sq, 1.0)), 0.0)


def normalize(x: Float[Array, "*batch n"]) -> Float[Array, "*batch n"]:
    """Unit vector along the last axis; the zero vector maps to the zero vector."""
    norm = safe_norm(x, keepdims=True)
    return x / jnp.where(norm > 0.0, norm, 1.0)


# --------------------------------------------------------------------------- quaternions


def quat_identity(shape: tuple[int, ...] = (), dtype=jnp.float32) -> Float[Array, "*shape 4"]:
    """Identity quaternions ``(1, 0, 0, 0)`` of the given batch shape."""
    return jnp.zeros((*shape, 4), dtype).at[..., 0].set(1.0)


def quat_mul(a: Float[Array, "*#batch 4"], b: Float[Array, "*#batch 4"]) -> Float[Array, "*batch 4"]:
    """Hamilton product ``a ⊗ b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return jnp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Conjugate ``(w, -x, -y, -z)``: the inverse rotation for unit quaternions."""
    return q * jnp.asarray([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def quat_inverse(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Multiplicative inverse ``conj(q) / |q|²`` (equals the conjugate for unit quaternions)."""
    sq = jnp.sum(q * q, axis=-1, keepdims=True)
    return quat_conjugate(q) / jnp.where(sq > _TINY, sq, 1.0)


def quat_normalize(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Unit quaternion; a zero quaternion maps to the identity rather than to NaN."""
    norm = safe_norm(q, keepdims=True)
    unit = q / jnp.where(norm > 0.0, norm, 1.0)
    return jnp.where(norm > 0.0, unit, quat_identity(q.shape[:-1], q.dtype))


def quat_rotate(q: Float[Array, "*#batch 4"], v: Float[Array, "*#batch 3"]) -> Float[Array, "*batch 3"]:
    """Rotate vectors ``v`` by unit quaternions ``q`` (``q v q*``, expanded with cross products)."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * jnp.cross(u, v)
    return v + w * t + jnp.cross(u, t)


def quat_fix_continuity(q: Float[Array, "*batch 4"], axis: int = -3) -> Float[Array, "*batch 4"]:
    """Flip signs along the time ``axis`` so consecutive quaternions have a non-negative dot.

    Frame t is negated when its dot product with the (already fixed) frame t-1 is
    negative — the LaFAN1 reader's rule — computed in closed form as a running product
    of the signs of consecutive dot products. ``axis`` indexes the quaternion array's
    axes; the default ``-3`` is the time axis of a ``(..., frames, joints, 4)`` layout.
    """
    q = jnp.moveaxis(q, axis, 0)
    dots = jnp.sum(q[1:] * q[:-1], axis=-1)
    step_sign = jnp.where(dots < 0.0, -1.0, 1.0).astype(q.dtype)
    sign = jnp.concatenate([jnp.ones_like(step_sign[:1]), jnp.cumprod(step_sign, axis=0)], axis=0)
    return jnp.moveaxis(q * sign[..., None], 0, axis)


def quat_from_axis_angle(axis: Float[ArrayLike, "*#batch 3"], angle: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch 4"]:
    """Quaternion rotating by ``angle`` radians about the (normalised) ``axis``."""
    half = 0.5 * jnp.asarray(angle)[..., None]
    return jnp.concatenate([jnp.cos(half), jnp.sin(half) * normalize(jnp.asarray(axis, half.dtype))], axis=-1)


def quat_between(u: Float[Array, "*#batch 3"], v: Float[Array, "*#batch 3"]) -> Float[Array, "*batch 4"]:
    """Shortest-arc unit quaternion rotating direction ``u`` onto direction ``v``.

    For opposite directions the rotation is by π about an axis perpendicular to ``u``.
    """
    u = normalize(u)
    v = normalize(v)
    w = 1.0 + jnp.sum(u * v, axis=-1, keepdims=True)
    xyz = jnp.cross(u, v)
    # Opposite directions: any perpendicular axis works; take u × (the basis vector least
    # aligned with u) so the axis is never degenerate.
    least = jnp.argmin(jnp.abs(u), axis=-1)
    basis = jnp.eye(3, dtype=u.dtype)[least]
    perp = normalize(jnp.cross(u, basis))
    # Only fall back when the half-way quaternion (1 + u·v, u × v) itself vanishes: for
    # directions δ away from opposite it has length ≈ δ, so nearly opposite directions
    # (δ ~ 1e-4, seen in LaFAN1 windows) keep their exact, well-defined rotation.
    # For exactly opposite inputs rounding leaves a length of a few eps.
    half_way = jnp.concatenate([w, xyz], axis=-1)
    opposite = safe_norm(half_way, keepdims=True) < 64.0 * float(jnp.finfo(w.dtype).eps)
    q = jnp.where(opposite, jnp.concatenate([jnp.zeros_like(w), perp], axis=-1), half_way)
    return quat_normalize(q)


def slerp(
    q0: Float[Array, "*#batch 4"],
    q1: Float[Array, "*#batch 4"],
    t: Float[ArrayLike, "*#batch"],
    *,
    linear_threshold: float = 0.01,
) -> Float[Array, "*batch 4"]:
    """Spherical linear interpolation along the shortest path, as the LaFAN1 benchmark does it.

    Both ends are normalised; ``q1`` is negated when ``dot(q0, q1) < 0`` — decided before
    ``acos``, so the short arc is always taken. When ``1 - |dot| < linear_threshold`` the
    ends are nearly equal and normalised lerp is used instead (it avoids dividing by
    ``sin ω ≈ 0``). The result is normalised.

    Args:
      q0, q1: end rotations, ``(..., 4)``.
      t: interpolation weight(s) in [0, 1], broadcast against the batch axes.
    Returns:
      ``(..., 4)`` unit quaternions.
    """
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    t = jnp.asarray(t, dtype=q0.dtype)[..., None]
    dot = jnp.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = jnp.where(dot < 0.0, -q1, q1)
    dot = jnp.abs(dot)
    linear = (1.0 - dot) < linear_threshold
    # Double where: acos and 1/sin only ever see a safe value on the linear branch.
    safe_dot = jnp.where(linear, 0.5, jnp.minimum(dot, 1.0))
    omega = jnp.arccos(safe_dot)
    sin_omega = jnp.sin(omega)
    w0 = jnp.where(linear, 1.0 - t, jnp.sin((1.0 - t) * omega) / sin_omega)
    w1 = jnp.where(linear, t, jnp.sin(t * omega) / sin_omega)
    return quat_normalize(w0 * q0 + w1 * q1)


def quat_angle(a: Float[Array, "*#batch 4"], b: Float[Array, "*#batch 4"]) -> Float[Array, "*batch"]:
    """Angle (rad, in [0, π]) of the rotation from ``a`` to ``b`` (unit quaternions, either sign).

    ``2·atan2(|vec(a⁻¹ b)|, |w(a⁻¹ b)|)``: accurate for small angles (``acos`` of the dot
    product loses them in float32) and with a finite gradient where ``a = ±b``.
    """
    rel = quat_mul(quat_conjugate(a), b)
    return 2.0 * jnp.arctan2(safe_norm(rel[..., 1:]), jnp.abs(rel[..., 0]))


def quat_exp(v: Float[Array, "*batch 3"]) -> Float[Array, "*batch 4"]:
    """Unit quaternion of the rotation vector ``v`` (axis × angle, rad); finite gradients at 0.

    Below ``_SMALL_ANGLE`` rad, ``sin(θ/2)/θ`` and ``cos(θ/2)`` take their Taylor series.
    """
    theta = safe_norm(v, keepdims=True)
    small = theta < _SMALL_ANGLE
    safe_theta = jnp.where(small, 1.0, theta)
    sinc_half = jnp.where(small, 0.5 - theta * theta / 48.0, jnp.sin(0.5 * safe_theta) / safe_theta)
    cos_half = jnp.where(small, 1.0 - theta * theta / 8.0, jnp.cos(0.5 * safe_theta))
    return jnp.concatenate([cos_half, sinc_half * v], axis=-1)


def quat_log(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 3"]:
    """Rotation vector (axis × angle, rad, angle ≤ π: the short way) of unit quaternions
    ``q``; the inverse of :func:`quat_exp`, with finite gradients at the identity."""
    q = jnp.where(q[..., :1] < 0.0, -q, q)
    w, xyz = q[..., :1], q[..., 1:]
    n = safe_norm(xyz, keepdims=True)
    small = n < _SMALL_ANGLE
    # 2·atan2(n, w)/n, and 2/w (its limit) for small n (w ≈ 1 there).
    scale = jnp.where(small, 2.0 / jnp.where(small, w, 1.0), 2.0 * jnp.arctan2(n, w) / jnp.where(small, 1.0, n))
    return scale * xyz


# ------------------------------------------------------------------------------ SO(3) Jacobians


def _angle_of(v: Float[Array, "*batch 3"]) -> tuple[Array, Array, Array, Array]:
    """``(θ², small, safe θ², safe θ)`` of rotation vectors, each ``(*batch, 1, 1)``: ``small``
    where θ < ``_SMALL_ANGLE`` (the series apply there), the safe values 1 there (no 0/0)."""
    theta_sq = jnp.sum(v * v, axis=-1)[..., None, None]
    small = theta_sq < _SMALL_ANGLE**2
    safe_sq = jnp.where(small, 1.0, theta_sq)
    return theta_sq, small, safe_sq, jnp.sqrt(safe_sq)


def right_jacobian(v: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """``J`` with ``exp(v + dv) ≈ exp(v) ⊗ exp(J dv)`` (SO(3)'s right Jacobian of the rotation
    vector ``v``, :func:`quat_exp`); Taylor series below ``_SMALL_ANGLE``."""
    theta_sq, small, safe_sq, theta = _angle_of(v)
    a = jnp.where(small, 0.5 - theta_sq / 24.0, (1.0 - jnp.cos(theta)) / safe_sq)
    b = jnp.where(small, 1.0 / 6.0 - theta_sq / 120.0, (theta - jnp.sin(theta)) / (safe_sq * theta))
    cross = skew(v)
    return jnp.eye(3, dtype=v.dtype) - a * cross + b * (cross @ cross)


def right_jacobian_inverse(v: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """``J_r(v)⁻¹``: ``log(exp(v) ⊗ exp(ε)) ≈ v + J_r⁻¹(v) ε`` (angle ≤ π); series near 0.

    ``I + ½[v]× + c [v]×²`` with ``c = 1/θ² − cot(θ/2)/(2θ)``, finite up to θ = π.
    """
    theta_sq, small, safe_sq, theta = _angle_of(v)
    c = jnp.where(small, 1.0 / 12.0 + theta_sq / 720.0, 1.0 / safe_sq - jnp.cos(0.5 * theta) / (2.0 * theta * jnp.sin(0.5 * theta)))
    cross = skew(v)
    return jnp.eye(3, dtype=v.dtype) + 0.5 * cross + c * (cross @ cross)


def skew(v: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """``[v]×``: the matrix of ``x ↦ v × x``."""
    zero = jnp.zeros_like(v[..., 0])
    return jnp.stack(
        [
            jnp.stack([zero, -v[..., 2], v[..., 1]], axis=-1),
            jnp.stack([v[..., 2], zero, -v[..., 0]], axis=-1),
            jnp.stack([-v[..., 1], v[..., 0], zero], axis=-1),
        ],
        axis=-2,
    )


# ------------------------------------------------------------------------------ matrices


def matrix_from_quat(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 3 3"]:
    """Rotation matrix of a (normalised) quaternion."""
    w, x, y, z = jnp.moveaxis(quat_normalize(q), -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        [1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
        [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
        [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def quat_from_matrix(m: Float[Array, "*batch 3 3"]) -> Float[Array, "*batch 4"]:
    """Unit quaternion (with w ≥ 0) of a rotation matrix, by Shepperd's method.

    Of the four algebraically equivalent formulas the one with the largest square root
    is used, which keeps the result accurate (and the gradient finite) for every
    rotation, including the identity and rotations by π.
    """
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    # 4·(w², x², y², z²) up to the same positive factor.
    diag = jnp.stack(
        [
            1.0 + m00 + m11 + m22,
            1.0 + m00 - m11 - m22,
            1.0 - m00 + m11 - m22,
            1.0 - m00 - m11 + m22,
        ],
        axis=-1,
    )
    candidates = jnp.stack(
        [
            jnp.stack([diag[..., 0], m21 - m12, m02 - m20, m10 - m01], axis=-1),
            jnp.stack([m21 - m12, diag[..., 1], m10 + m01, m02 + m20], axis=-1),
            jnp.stack([m02 - m20, m10 + m01, diag[..., 2], m21 + m12], axis=-1),
            jnp.stack([m10 - m01, m20 + m02, m21 + m12, diag[..., 3]], axis=-1),
        ],
        axis=-2,
    )  # (..., 4 candidates, 4 components): candidate k is 4·q·q_k
    best = jnp.argmax(diag, axis=-1)
    chosen = jnp.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q = quat_normalize(chosen)
    return jnp.where(q[..., :1] < 0.0, -q, q)


def matrix_from_rot6d(r6: Float[Array, "*batch 6"]) -> Float[Array, "*batch 3 3"]:
    """Rotation matrix from ortho6D by Gram–Schmidt (Zhou et al. 2019), columns ``b1 b2 b3``."""
    a1, a2 = r6[..., :3], r6[..., 3:]
    b1 = normalize(a1)
    b2 = normalize(a2 - jnp.sum(b1 * a2, axis=-1, keepdims=True) * b1)
    b3 = jnp.cross(b1, b2)
    return jnp.stack([b1, b2, b3], axis=-1)


def rot6d_from_matrix(m: Float[Array, "*batch 3 3"]) -> Float[Array, "*batch 6"]:
    """ortho6D: the first two columns of the rotation matrix, concatenated."""
    return jnp.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def rot6d_from_quat(q: Float[Array, "*batch 4"]) -> Float[Array, "*batch 6"]:
    """ortho6D of a quaternion."""
    return rot6d_from_matrix(matrix_from_quat(q))


def quat_from_rot6d(r6: Float[Array, "*batch 6"]) -> Float[Array, "*batch 4"]:
    """Unit quaternion (w ≥ 0) of an ortho6D rotation."""
    return quat_from_matrix(matrix_from_rot6d(r6))


# -------------------------------------------------------------------------------- Euler


def quat_from_euler(angles: Float[Array, "*batch 3"], order: str) -> Float[Array, "*batch 4"]:
    """Quaternion of Euler angles (radians): ``q = q_a(e0) ⊗ q_b(e1) ⊗ q_c(e2)`` for order ``"abc"``."""
    axes = _check_order(order)
    half = 0.5 * angles
    parts = []
    for k, axis in enumerate(axes):
        c, s = jnp.cos(half[..., k]), jnp.sin(half[..., k])
        zero = jnp.zeros_like(c)
        xyz = [zero, zero, zero]
        xyz[axis] = s
        parts.append(jnp.stack([c, *xyz], axis=-1))
    return quat_mul(parts[0], quat_mul(parts[1], parts[2]))


def euler_from_matrix(m: Float[Array, "*batch 3 3"], order: str) -> Float[Array, "*batch 3"]:
    """Euler angles (radians) of a rotation matrix for ``order``; inverse of ``quat_from_euler``.

    The middle angle lies in [-π/2, π/2], the others in (-π, π]. At gimbal lock
    (middle angle ±π/2) only the sum or difference of the outer angles is defined; the
    last angle is then set to 0.
    """
    i, j, k = _check_order(order)
    # +1 for cyclic orders (xyz, yzx, zxy), -1 for the others.
    sign = 1.0 if (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    cos_mid = safe_norm(jnp.stack([m[..., i, i], m[..., i, j]], axis=-1))
    mid = jnp.arctan2(sign * m[..., i, k], cos_mid)
    locked = cos_mid < 1e-6
    # Double where keeps atan2's gradient finite at (0, 0) on the branch not taken.
    def _atan2(y, x, use):
        both_zero = (jnp.abs(y) + jnp.abs(x)) == 0.0
        safe = use & ~both_zero
        return jnp.where(safe, jnp.arctan2(jnp.where(safe, y, 0.0), jnp.where(safe, x, 1.0)), 0.0)

    first_free = _atan2(-sign * m[..., j, k], m[..., k, k], ~locked)
    last_free = _atan2(-sign * m[..., i, j], m[..., i, i], ~locked)
    first_locked = _atan2(sign * m[..., k, j], m[..., j, j], locked)
    first = jnp.where(locked, first_locked, first_free)
    last = jnp.where(locked, 0.0, last_free)
    return jnp.stack([first, mid, last], axis=-1)


def euler_from_quat(q: Float[Array, "*batch 4"], order: str) -> Float[Array, "*batch 3"]:
    """Euler angles (radians) of a quaternion for ``order``; see ``euler_from_matrix``."""
    return euler_from_matrix(matrix_from_quat(q), order)
