"""Pure-jnp small linear algebra (jaxflex.linalg) against numpy's LAPACK: the package uses it instead
of jnp.linalg solves (a jaxlib CPU deadlock), so it must agree to round-off."""
import math

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


def test_custom_derivatives_match_lapack_reference():
    """The custom JVPs (matrix identities) against jnp.linalg's own derivatives, forward and reverse,
    with symmetric tangents for the SPD routines (they read the lower triangle only)."""
    rng = np.random.default_rng(7)
    n = 6
    a = jnp.asarray(rng.normal(size=(n, n)) + 3 * np.eye(n))
    spd = a @ a.T
    da = jnp.asarray(rng.normal(size=(n, n)))
    ds = da + da.T
    b, db = jnp.asarray(rng.normal(size=n)), jnp.asarray(rng.normal(size=n))
    pairs = [
        (lambda m, v: linalg.solve(m, v), lambda m, v: jnp.linalg.solve(m, v), a, da),
        (lambda m, v: linalg.inv(m) @ v, lambda m, v: jnp.linalg.inv(m) @ v, a, da),
        (lambda m, v: linalg.spd_solve(m, v), lambda m, v: jnp.linalg.solve(m, v), spd, ds),
        (lambda m, v: linalg.cholesky(m) @ v, lambda m, v: jnp.linalg.cholesky(m) @ v, spd, ds),
        (lambda m, v: linalg.lower_inverse(jnp.tril(m)) @ v,
         lambda m, v: jnp.linalg.inv(jnp.tril(m)) @ v, a, da),
    ]
    for ours, ref, m, dm in pairs:
        t_ours = jax.jvp(ours, (m, b), (dm, db))[1]
        t_ref = jax.jvp(ref, (m, b), (dm, db))[1]
        np.testing.assert_allclose(t_ours, t_ref, rtol=1e-10, atol=1e-12)
        g_ours = jax.grad(lambda v: jnp.sum(ours(m, v) ** 2))(b)
        g_ref = jax.grad(lambda v: jnp.sum(ref(m, v) ** 2))(b)
        np.testing.assert_allclose(g_ours, g_ref, rtol=1e-10, atol=1e-12)
    # reverse mode w.r.t. the matrix: the VJP of the (transposed) custom JVP, checked on a symmetric direction
    f = lambda m: jnp.sum(linalg.cholesky(m) @ b)
    g = jax.grad(f)(spd)
    fd = (f(spd + 1e-6 * ds) - f(spd - 1e-6 * ds)) / 2e-6
    np.testing.assert_allclose(jnp.sum(g * ds), fd, rtol=1e-7)


def _oscillators(rng, omega, damped, decay, spread):
    """A non-normal 5 x 5 matrix V D V^-1 whose eigenvalues are an undamped oscillator +-i omega, a
    damped one ``damped`` = (sigma, omega') and a real decay, V = I + ``spread`` N(0, 1); and the
    matrix function of a scalar function on those eigenvalues (by the eigendecomposition)."""
    d = np.zeros((5, 5))
    d[:2, :2] = [[0.0, omega], [-omega, 0.0]]
    d[2:4, 2:4] = [[damped[0], damped[1]], [-damped[1], damped[0]]]
    d[4, 4] = decay
    v = np.eye(5) + spread * rng.normal(size=(5, 5))
    a = v @ d @ np.linalg.inv(v)
    lam, vec = np.linalg.eig(a)
    inv = np.linalg.inv(vec)
    return a, lam, lambda f: np.real(vec @ np.diag(f) @ inv)


def test_phi_functions_match_their_closed_form_on_a_stiff_oscillator():
    """``expm.phi_times`` (the exponential integrator's matrix functions) against phi_k(z) =
    (e^z - sum_{j<k} z^j / j!) / z^k on the eigenvalues of a non-normal matrix with an undamped
    oscillator at h omega = 2.5 (the regime of the reference's 18.6 kHz mode at 20 us), a lightly
    damped one and a real decay. Taylor degree 12 with ||a|| / 2^s <= 1/2 is accurate to ~1e-14."""
    from jaxflex.expm import phi_times, squarings_for

    rng = np.random.default_rng(3)
    a, lam, of = _oscillators(rng, 2.5, (-0.05, 0.8), -1.7, 0.3)

    def phi(k):
        fact = [math.factorial(j) for j in range(k)]
        return of((np.exp(lam) - sum(lam**j / fact[j] for j in range(k))) / lam**k)

    vs = [rng.normal(size=5) for _ in range(3)]
    s = squarings_for(np.abs(a).sum(axis=0).max())
    for p in (1, 2, 3):
        want = sum(phi(k + 1) @ vs[k] for k in range(p))
        got = np.asarray(phi_times(jnp.asarray(a), [jnp.asarray(x) for x in vs[:p]], s))
        assert np.abs(got - want).max() < 1e-12 * np.abs(want).max(), (p, got, want)
    # zero vectors (the reference's padding steps of size zero) give zero, not NaN
    assert np.all(np.asarray(phi_times(jnp.asarray(a), [jnp.zeros(5)], s)) == 0.0)


def test_phi_series_matches_the_closed_form_in_the_servo_loops_small_steps():
    """``expm.phi_series`` (the closed loop's sub-step matrix functions, by Paterson and Stockmeyer)
    against e^z, phi_1(z) = (e^z - 1) / z and phi_2(z) = (e^z - 1 - z) / z^2 on the eigenvalues of a
    non-normal matrix whose norm is that of the servo loop's sub-steps (about 0.8): an undamped
    oscillator at omega delta = 0.7, a damped one and a real decay. The series' truncation at 20
    terms is ~1e-20, so what is left is round-off (the closed form's own, ~1e-15 here); the series
    cut at 14 terms instead fails the check."""
    from jaxflex.expm import phi_series

    a, lam, of = _oscillators(np.random.default_rng(5), 0.7, (-0.3, 0.5), -0.6, 0.2)
    closed = [np.exp(lam), (np.exp(lam) - 1) / lam, (np.exp(lam) - 1 - lam) / lam**2]
    got = phi_series(jnp.asarray(a), 20)
    for k, (g, f) in enumerate(zip(got, closed)):
        want = of(f)
        assert np.abs(np.asarray(g) - want).max() < 1e-13 * np.abs(want).max(), (k, np.abs(np.asarray(g) - want).max())
    # batched (vmapped or with leading axes) as one matrix at a time
    both = phi_series(jnp.stack([jnp.asarray(a), 0.5 * jnp.asarray(a)]), 20)
    np.testing.assert_array_equal(np.asarray(both[2][0]), np.asarray(got[2]))
