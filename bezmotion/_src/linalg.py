"""Small dense linear algebra in plain XLA operations: no LAPACK calls.

Why not ``jnp.linalg``: on CPU, jaxlib runs a batched ``svd``/``pinv``/``cholesky``/``det``
as a LAPACK kernel that fans its batch out into the same XLA thread pool it runs on
(``ParallelBatchMap``). When two such kernels run at once and the pool has no idle thread
(two cores), each waits on work nobody can pick up: a deadlock. It was seen in
``experiments/pipeline_eval.py`` (gdb: two threads in ``lapack_sgesdd_ffi`` →
``ParallelBatchMap`` → ``BlockingCounter::Wait``) and in ``experiments/table1.py``
(sampling, whose every DDIM step projected with ``jnp.linalg.pinv``). The matrices we solve
are small (≤ 36 rows), so loops over their rows cost little, and the code here runs the
same on CPU and GPU. ``tests/test_linalg.py`` checks that the compiled sampler, fitting and
exact IK contain no LAPACK call.

Every function takes one problem; ``jnp.vectorize``/``jax.vmap`` it over a batch (the
public functions here are already vectorised over leading axes).

Matrix products here, and wherever a result must be exact to float32 (Bézier evaluation,
the curve fit, the handle overwrite), go through :func:`exact_matmul`/:func:`exact_einsum`:
on a GPU, XLA's default multiplies float32 matrices in TF32 (a 10-bit mantissa), which
moves a point 300 cm from the origin by ~0.1 cm and kept the curve fit of every LaFAN1
training window from converging on an H200. On a CPU they are the plain products.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

EXACT = jax.lax.Precision.HIGHEST  # full float32 products on every backend (not TF32)


def exact_matmul(a: Array, b: Array) -> Array:
    """``a @ b`` in full float32 on every backend."""
    return jnp.matmul(a, b, precision=EXACT)


def exact_einsum(subscripts: str, *operands: Array) -> Array:
    """``jnp.einsum`` in full float32 on every backend."""
    return jnp.einsum(subscripts, *operands, precision=EXACT)


def inverse_3x3(m: Float[Array, "*batch 3 3"]) -> Float[Array, "*batch 3 3"]:
    """Inverse of invertible 3×3 matrices by the adjugate (LAPACK per 3×3 matrix is far slower on CPU)."""
    c0 = jnp.cross(m[..., 1, :], m[..., 2, :])
    c1 = jnp.cross(m[..., 2, :], m[..., 0, :])
    c2 = jnp.cross(m[..., 0, :], m[..., 1, :])
    det = jnp.sum(m[..., 0, :] * c0, axis=-1)[..., None, None]
    return jnp.stack([c0, c1, c2], axis=-1) / det


def _min_norm_solve_one(matrix: Float[Array, "m n"], rhs: Float[Array, " m"], rtol: float | None) -> Float[Array, " n"]:
    m, n = matrix.shape
    dtype = matrix.dtype
    tol = 10.0 * max(m, n) * float(jnp.finfo(dtype).eps) if rtol is None else rtol

    def add_row(i, carry):
        basis, x = carry  # basis: (m, n) orthonormal rows found so far (zeros elsewhere)
        row = matrix[i]
        # Gram–Schmidt against the rows before, twice ("twice is enough" for orthogonality).
        v = row - exact_matmul(basis.T, exact_matmul(basis, row))
        v = v - exact_matmul(basis.T, exact_matmul(basis, v))
        norm = jnp.linalg.norm(v)
        independent = norm > tol * jnp.linalg.norm(row)
        q = jnp.where(independent, v / jnp.where(independent, norm, 1.0), 0.0)
        # Move along q only: q ⟂ every earlier row, so their equations stay met.
        gain = exact_matmul(row, q)
        x = x + q * jnp.where(independent, (rhs[i] - exact_matmul(row, x)) / jnp.where(independent, gain, 1.0), 0.0)
        return basis.at[i].set(q), x

    _, x = jax.lax.fori_loop(0, m, add_row, (jnp.zeros_like(matrix), jnp.zeros(n, dtype)))
    return x


def min_norm_solve(
    matrix: Float[Array, "*batch m n"], rhs: Float[Array, "*batch m"], *, rtol: float | None = None
) -> Float[Array, "*batch n"]:
    """The minimum-norm ``x`` with ``matrix @ x = rhs``, for consistent systems of any rank.

    Rows are taken in order and orthogonalised against the ones before (modified
    Gram–Schmidt, twice); ``x`` moves only along each new direction, so it stays in the row
    space (minimum norm) and every equation met stays met. A row that the earlier rows
    already span (a zero row, a duplicate; relative remainder ≤ ``rtol``, default
    ``10·max(m, n)·eps``) adds nothing: for a consistent system that is exact, and where
    such a row contradicts the earlier ones, the earlier rows win (``pinv`` would return
    the least-squares compromise instead). Precision is that of a QR solve (round-off ×
    the rows' condition number, not its square as with normal equations).

    Args:
      matrix: ``(*batch, m, n)``.
      rhs: ``(*batch, m)``.
      rtol: relative size below which a row's new direction counts as dependent.
    Returns:
      ``(*batch, n)``.
    """
    solve = jnp.vectorize(lambda a, b: _min_norm_solve_one(a, b, rtol), signature="(m,n),(m)->(n)")
    return solve(matrix, rhs)


def _cholesky_factor_one(matrix: Float[Array, "n n"]) -> Float[Array, "n n"]:
    n = matrix.shape[0]
    index = jnp.arange(n)

    def factor_column(k, lower):
        # Column k of L from A's column minus the columns already found (Cholesky–Crout).
        column = matrix[:, k] - exact_matmul(lower, lower[k])
        pivot = jnp.sqrt(column[k])
        return lower.at[:, k].set(jnp.where(index >= k, column / pivot, 0.0))

    return jax.lax.fori_loop(0, n, factor_column, jnp.zeros_like(matrix))


def _cholesky_substitute_one(lower: Float[Array, "n n"], rhs: Float[Array, " n"]) -> Float[Array, " n"]:
    n = lower.shape[0]

    def forward(k, y):  # L y = b
        return y.at[k].set((rhs[k] - exact_matmul(lower[k], y)) / lower[k, k])

    def backward(step, x):  # Lᵀ x = y
        k = n - 1 - step
        return x.at[k].set((y[k] - exact_matmul(lower[:, k], x)) / lower[k, k])

    y = jax.lax.fori_loop(0, n, forward, jnp.zeros_like(rhs))
    return jax.lax.fori_loop(0, n, backward, jnp.zeros_like(rhs))


def _cholesky_solve_one(matrix: Float[Array, "n n"], rhs: Float[Array, " n"]) -> Float[Array, " n"]:
    return _cholesky_substitute_one(_cholesky_factor_one(matrix), rhs)


def _spd_inverse_one(matrix: Float[Array, "n n"]) -> Float[Array, "n n"]:
    lower = _cholesky_factor_one(matrix)  # once, for every column
    return jax.vmap(lambda unit: _cholesky_substitute_one(lower, unit))(jnp.eye(matrix.shape[0], dtype=matrix.dtype))


def cholesky_solve(matrix: Float[Array, "*batch n n"], rhs: Float[Array, "*batch n"]) -> Float[Array, "*batch n"]:
    """``x`` with ``matrix @ x = rhs`` for a symmetric positive-definite ``matrix``
    (Cholesky, then two triangular solves). Only the lower triangle is read; a matrix that
    is not positive definite gives NaN, as LAPACK's does."""
    return jnp.vectorize(_cholesky_solve_one, signature="(n,n),(n)->(n)")(matrix, rhs)


def spd_inverse(matrix: Float[Array, "*batch n n"]) -> Float[Array, "*batch n n"]:
    """The inverse of a symmetric positive-definite ``matrix``: one Cholesky factorisation,
    then :func:`cholesky_solve`'s two triangular solves per column (NaN where it is not
    positive definite)."""
    return jnp.vectorize(_spd_inverse_one, signature="(n,n)->(n,n)")(matrix)


def top_eigenvector(matrix: Float[Array, "*batch n n"], *, squarings: int = 40) -> Float[Array, "*batch n"]:
    """Unit eigenvector of a symmetric matrix's largest eigenvalue (sign arbitrary).

    ``matrix + s·I`` with ``s`` its largest absolute row sum (≥ its spectral radius) is
    positive semi-definite with the same eigenvectors; squaring it ``squarings`` times
    (normalised each time) raises it to the power ``2^squarings``, which leaves the top
    eigenvector's projector unless the two largest eigenvalues (nearly) tie, and then any
    vector of their plane. Its largest column is that eigenvector, polished by two
    multiplications.
    """

    def one(a):
        n = a.shape[-1]
        a = 0.5 * (a + a.T)
        shifted = a + jnp.abs(a).sum(-1).max() * jnp.eye(n, dtype=a.dtype)

        def square(_, p):
            p = exact_matmul(p, p)
            return p / jnp.max(jnp.abs(p))

        power = jax.lax.fori_loop(0, squarings, square, shifted / jnp.max(jnp.abs(shifted)))
        v = power[:, jnp.argmax(jnp.linalg.norm(power, axis=0))]
        for _ in range(2):
            v = exact_matmul(shifted, v)
            v = v / jnp.linalg.norm(v)
        return v

    return jnp.vectorize(one, signature="(n,n)->(n)")(matrix)


__all__ = ["cholesky_solve", "min_norm_solve", "spd_inverse", "top_eigenvector"]
