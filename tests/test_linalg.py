"""Pure-jnp small linear algebra (jaxflex.linalg) against numpy's LAPACK: the package uses it instead
of jnp.linalg solves (a jaxlib CPU deadlock), so it must agree to round-off."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import linalg


@pytest.mark.parametrize("n", [1, 3, 12, 14])
def test_solvers_match_numpy(n):
    rng = np.random.default_rng(n)
    a, b, bm = rng.normal(size=(n, n)) + 0.1 * np.eye(n), rng.normal(size=n), rng.normal(size=(n, 3))
    spd = a @ a.T + n * np.eye(n)
    tol = 1e-12
    np.testing.assert_allclose(linalg.solve(a, b), np.linalg.solve(a, b), atol=tol * np.linalg.cond(a))
    np.testing.assert_allclose(linalg.solve(a, bm), np.linalg.solve(a, bm), atol=tol * np.linalg.cond(a))
    np.testing.assert_allclose(linalg.spd_solve(spd, b), np.linalg.solve(spd, b), atol=tol)
    np.testing.assert_allclose(linalg.spd_solve(spd, bm), np.linalg.solve(spd, bm), atol=tol)
    low = linalg.cholesky(spd)
    np.testing.assert_allclose(low, np.linalg.cholesky(spd), atol=tol * n)
    np.testing.assert_allclose(linalg.lower_inverse(low) @ low, np.eye(n), atol=tol)


def test_solve_pivots_on_a_zero_diagonal_and_differentiates_like_lapack():
    np.testing.assert_allclose(linalg.solve(jnp.array([[0.0, 1.0], [1.0, 0.0]]), jnp.array([1.0, 2.0])),
                               [2.0, 1.0], atol=0)
    a = jnp.asarray(np.random.default_rng(5).normal(size=(5, 5)) + 3 * np.eye(5))
    b = jnp.arange(5.0)
    g_ours = jax.grad(lambda m: linalg.solve(m, b).sum())(a)
    g_ref = jax.grad(lambda m: jnp.linalg.solve(m, b).sum())(a)
    np.testing.assert_allclose(g_ours, g_ref, atol=1e-12)


def test_shape_mismatch_is_rejected():
    with pytest.raises(ValueError, match="do not match"):
        linalg.spd_solve(jnp.eye(3), jnp.ones(4))
    with pytest.raises(ValueError, match="do not match"):
        linalg.solve(jnp.eye(3), jnp.ones(2))
