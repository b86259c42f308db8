"""Small dense linear algebra in pure ``jax.numpy`` (no LAPACK custom calls).

Used by the batched fast rollouts (``jaxflex.simulate``), where tiny (12 x 12) matrices are factorized
thousands of times inside one vmapped, jitted program. jaxlib's CPU LAPACK kernels (``getrf`` behind
``jnp.linalg.solve`` and ``inv``) can deadlock intermittently when XLA runs several of them
concurrently in a large batched program (the process waits forever with all threads idle; the same
class as jax-ml/jax#24219; neither ``--xla_cpu_multi_thread_eigen=false`` nor synchronous dispatch
avoids it). The model and every rollout therefore avoid LAPACK solves: the model
(``jaxflex.model``) uses ``spd_solve`` for its mass matrices and ``solve`` for the static Newton
step, the closed loop (``jaxflex.servo_simulate``) ``inv`` and ``solve``, so the rollouts can run
side by side from threads. These eliminations are plain arithmetic, so they fuse, batch and
differentiate like any other jnp code and cannot hit that bug. LAPACK remains where it runs once
per rollout or per model, never batched over steps or intervals: ``jnp.linalg.eigh`` (modal
analysis, and the low modes at rest at the end of each rollout), the servo's stability check
(``servo.sampled_loop``: an inverse and a matrix exponential per model and pose) and the full
reference model's Newton step under a servo (``reference_servo``).

Derivatives: each function has a custom JVP from the matrix identities (d(A^-1) = -A^-1 dA A^-1,
dL = L Phi(L^-1 dA L^-T) for Cholesky, ...), made of matrix products only. Differentiating through
the eliminations themselves would also be exact, but reverse mode through hundreds of tiny unrolled
or looped updates is far slower than these few products (docs/performance.md).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp


def _check_solve(a, b, name):
    n = a.shape[-1]
    if a.shape != (n, n) or b.shape[0] != n:
        raise ValueError(f"{name}: shapes {a.shape} and {b.shape} do not match")


@jax.custom_jvp
def solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """Solve a x = b by Gaussian elimination with partial pivoting.

    a: (n, n); b: (n,) or (n, k). Returns x with the shape of b. Differentiable (the pivot choice is
    piecewise constant; derivatives flow through the arithmetic as for LU). The elimination is a
    rolled ``fori_loop`` so that the compiled program stays small inside scans and autodiff."""
    _check_solve(a, b, "solve")
    n = a.shape[-1]
    vec = b.ndim == 1
    m = jnp.concatenate([a, b[:, None] if vec else b], axis=1)
    rows = jnp.arange(n)

    def eliminate(k, m):
        colk = jax.lax.dynamic_index_in_dim(m, k, axis=1, keepdims=False)
        p = jnp.argmax(jnp.where(rows >= k, jnp.abs(colk), -1.0))
        rk = jax.lax.dynamic_index_in_dim(m, k, keepdims=False)
        rp = jax.lax.dynamic_index_in_dim(m, p, keepdims=False)
        m = jnp.where((rows == p)[:, None], rk[None], jnp.where((rows == k)[:, None], rp[None], m))
        pivot = rp[k]
        colk = jnp.where(rows == p, colk[k], jnp.where(rows == k, pivot, colk))
        factor = jnp.where(rows > k, colk / pivot, 0.0)
        return m - factor[:, None] * rp[None, :]

    m = jax.lax.fori_loop(0, n, eliminate, m)
    u, y = m[:, :n], m[:, n:]

    def back(i, x):
        k = n - 1 - i
        uk = jax.lax.dynamic_index_in_dim(u, k, keepdims=False)
        yk = jax.lax.dynamic_index_in_dim(y, k, keepdims=False)
        xk = (yk - uk @ x) / uk[k]
        return jax.lax.dynamic_update_index_in_dim(x, xk, k, axis=0)

    x = jax.lax.fori_loop(0, n, back, jnp.zeros_like(y))
    return x[:, 0] if vec else x


@solve.defjvp
def _solve_jvp(primals, tangents):
    a, b = primals
    da, db = tangents
    x = solve(a, b)
    ai = inv(a)
    return x, ai @ (db - da @ x)


@jax.custom_jvp
def inv(a: jax.Array) -> jax.Array:
    """Inverse of a small square matrix (see ``solve``)."""
    return solve(a, jnp.eye(a.shape[-1], dtype=a.dtype))


@inv.defjvp
def _inv_jvp(primals, tangents):
    (a,), (da,) = primals, tangents
    ai = inv(a)
    return ai, -ai @ da @ ai


def _lower_sym(a):
    """The symmetric matrix with the lower triangle of a."""
    return jnp.tril(a) + jnp.tril(a, -1).T


@jax.custom_jvp
def cholesky(a: jax.Array) -> jax.Array:
    """Lower Cholesky factor L (a = L L^T) of a symmetric positive definite matrix, (n, n)."""
    n = a.shape[-1]
    rows = jnp.arange(n)
    lower = jnp.zeros_like(a)
    for j in range(n):             # column j from the columns before it: one matrix-vector product
        v = a[:, j] - lower @ lower[j]
        lower = lower.at[:, j].set(jnp.where(rows >= j, v / jnp.sqrt(v[j]), 0.0))
    return lower


@cholesky.defjvp
def _cholesky_jvp(primals, tangents):
    (a,), (da,) = primals, tangents
    lower = cholesky(a)
    li = lower_inverse(lower)
    x = li @ _lower_sym(da) @ li.T                  # only the lower triangle of a is read
    phi = jnp.tril(x) - 0.5 * jnp.diag(jnp.diag(x))
    return lower, lower @ phi


def forward_substitution(lower: jax.Array, b: jax.Array) -> jax.Array:
    """Solve L y = b for lower-triangular L (n, n); b (n,) or (n, k) (unrolled, one row at a time)."""
    y = jnp.zeros_like(b)
    for i in range(lower.shape[-1]):
        y = y.at[i].set((b[i] - lower[i] @ y) / lower[i, i])
    return y


@jax.custom_jvp
def lower_inverse(lower: jax.Array) -> jax.Array:
    """Inverse of a lower-triangular matrix by forward substitution, (n, n)."""
    return forward_substitution(lower, jnp.eye(lower.shape[-1], dtype=lower.dtype))


@lower_inverse.defjvp
def _lower_inverse_jvp(primals, tangents):
    (lower,), (dl,) = primals, tangents
    li = lower_inverse(lower)
    return li, -li @ jnp.tril(dl) @ li


@jax.custom_jvp
def spd_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """Solve a x = b for a small symmetric positive definite a (n, n); b (n,) or (n, k).

    Unrolled Cholesky factorization and forward/backward substitution (2 n steps, no pivoting needed
    for SPD matrices); only the lower triangle of a is read."""
    _check_solve(a, b, "spd_solve")
    n = a.shape[-1]
    lower = cholesky(a)
    y = forward_substitution(lower, b)
    x = jnp.zeros_like(b)
    for i in reversed(range(n)):     # L^T x = y, one row at a time
        x = x.at[i].set((y[i] - lower[:, i] @ x) / lower[i, i])
    return x


@spd_solve.defjvp
def _spd_solve_jvp(primals, tangents):
    a, b = primals
    da, db = tangents
    x = spd_solve(a, b)
    li = lower_inverse(cholesky(a))
    return x, li.T @ (li @ (db - _lower_sym(da) @ x))   # only the lower triangle of a is read
