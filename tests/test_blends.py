"""Corner blends: reference lengths, end conditions (G1/G2, G3/G4 for the smooth families), arc-length
parametrization, gradients."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import blends
from jaxflex.blends import BLENDS, blend_frame, make_blend

SMOOTH = ("smoothstep", "polar_g4")     # polar_g3 shares polar_g4's code (its own continuity test below)

D = 0.025
frames = jax.jit(jax.vmap(blend_frame, in_axes=(None, 0)))   # one compilation per blend family


@pytest.mark.parametrize("kind, length_mm, tol_mm", [
    ("lame", 42.156, 0.01),      # paper Table 2
    ("polar", 41.106, 0.01),     # paper Table 2
    ("clothoid", 41.998, 0.001),  # G2 pair of 45-degree clothoids (docs/conventions.md#adept-cycle-and-blends)
])
def test_reference_lengths(kind, length_mm, tol_mm):
    assert abs(float(make_blend(kind, D, D).length) * 1e3 - length_mm) < tol_mm


def test_symmetric_clothoid_length_closed_form():
    # d = L1 (C + S) with C, S the Fresnel-type integrals of a 45-degree clothoid (independent series).
    th = np.pi / 4
    k = np.arange(12)
    fact = np.array([np.prod(np.arange(1, 2 * i + 1, dtype=float)) for i in k])
    fact1 = np.array([np.prod(np.arange(1, 2 * i + 2, dtype=float)) for i in k])
    c = np.sum((-1) ** k * th ** (2 * k) / (fact * (4 * k + 1)))
    s = np.sum((-1) ** k * th ** (2 * k + 1) / (fact1 * (4 * k + 3)))
    expected = 2 * D / (c + s)
    assert abs(float(make_blend("clothoid", D, D).length) - expected) < 1e-14


@pytest.mark.parametrize("kind", BLENDS + SMOOTH)
@pytest.mark.parametrize("d, e", [(0.025, 0.025), (0.02, 0.03), (0.025, 0.044)])
def test_end_conditions(kind, d, e):
    """Start at (0,0) going +y, end at (e,d) going +x, zero curvature at both ends (G2 with lines)."""
    b = make_blend(kind, d, e)
    f = frames(b, jnp.stack([0.0, b.length]))
    start, end = jax.tree_util.tree_map(lambda a: a[0], f), jax.tree_util.tree_map(lambda a: a[1], f)
    np.testing.assert_allclose(start.pos, [0, 0], atol=1e-13)
    np.testing.assert_allclose(end.pos, [e, d], atol=1e-12)
    np.testing.assert_allclose(start.tangent, [0, 1], atol=1e-10)
    np.testing.assert_allclose(end.tangent, [1, 0], atol=1e-10)
    # curvature at the ends vanishes (a Lamé curve of order 3 has kappa ~ distance to the end)
    assert float(jnp.linalg.norm(start.curv)) < 1e-6
    assert float(jnp.linalg.norm(end.curv)) < 1e-6


@pytest.mark.parametrize("kind", BLENDS + SMOOTH)
def test_unit_speed_and_frame_consistency(kind):
    """|dP/ds| = 1 by central differences of positions, and autodiff derivatives match differences."""
    b = make_blend(kind, 0.02, 0.03)
    frame = lambda s: frames(b, s)
    s = jnp.linspace(0.05, 0.95, 37) * b.length
    h = 1e-6
    fp, fm, f0 = frame(s + h), frame(s - h), frame(s)
    speed = jnp.linalg.norm((fp.pos - fm.pos) / (2 * h), axis=-1)
    np.testing.assert_allclose(speed, 1.0, atol=1e-8)          # O(h^2 kappa^2) + round-off/h
    np.testing.assert_allclose((fp.tangent - fm.tangent) / (2 * h), f0.curv, atol=1e-5)
    np.testing.assert_allclose((fp.curv - fm.curv) / (2 * h), f0.dcurv, rtol=1e-5, atol=1e-2)
    # curvature vector is normal to the tangent
    np.testing.assert_allclose(jnp.sum(f0.curv * f0.tangent, axis=-1), 0.0, atol=1e-8)


def test_clothoid_curvature_linear_and_g2_join():
    b = make_blend("clothoid", 0.02, 0.03)
    l1 = float(b.coef[3])
    k = lambda s: float(jnp.linalg.norm(frames(b, jnp.array([s])).curv))
    # G2 at the join: curvature continuous (and maximal)
    assert abs(k(l1 - 1e-9) - k(l1 + 1e-9)) < 1e-5 * k(l1)
    np.testing.assert_allclose(k(l1), float(b.coef[2]), rtol=1e-12)
    # linear in arc length on the first clothoid
    np.testing.assert_allclose(k(0.5 * l1), 0.5 * k(l1), rtol=1e-10)


def test_polar_symmetric_is_spec_quartic():
    b = make_blend("polar", D, D)
    phi0 = np.pi / 4
    expected = [D * (1 + phi0**2 / 8), 0, -D / 4, 0, D / (8 * phi0**2), 0]
    np.testing.assert_allclose(b.coef, expected, atol=1e-14)


def test_lame_curve_equation():
    """Points satisfy the superellipse |1 - x/e|^n + |y/d|^n = 1."""
    b = make_blend("lame", 0.02, 0.03, 3.5)
    s = jnp.linspace(0, b.length, 51)
    p = frames(b, s).pos
    res = jnp.abs(1 - p[:, 0] / 0.03) ** 3.5 + jnp.abs(p[:, 1] / 0.02) ** 3.5 - 1
    assert float(jnp.max(jnp.abs(res))) < 1e-12


def _fd(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


@pytest.mark.parametrize("kind", BLENDS + ("smoothstep",))
def test_length_gradients_match_finite_differences(kind):
    for argnum in (0, 1) if kind != "lame" else (0, 1, 2):
        args = [0.022, 0.027, 3.0]

        def f(v, i=argnum):
            a = list(args)
            a[i] = v
            return make_blend(kind, *a).length

        g = float(jax.grad(f)(args[argnum]))
        fd = float(_fd(f, args[argnum], 1e-6))
        assert np.isfinite(g)
        np.testing.assert_allclose(g, fd, rtol=1e-6)   # central FD error ~ h^2 ~ 1e-12 relative


@pytest.mark.parametrize("kind", BLENDS)
def test_finite_values_and_gradients_at_blend_ends(kind):
    def f(params, s):
        b = make_blend(kind, *params)
        fr = blend_frame(b, s * b.length)
        return jnp.sum(fr.pos) + jnp.sum(fr.tangent) + jnp.sum(fr.curv)

    params = jnp.array([0.025, 0.025, 3.0])
    vg = jax.jit(jax.value_and_grad(f))
    for s in (0.0, 1.0):
        val, g = vg(params, s)
        assert np.isfinite(float(val)) and np.all(np.isfinite(np.asarray(g)))


def test_lame_order_two_is_an_ellipse_quarter():
    b = make_blend("lame", 0.025, 0.025, 2.0)
    np.testing.assert_allclose(float(b.length), np.pi / 2 * 0.025, rtol=1e-12)
    # a circle of radius d: curvature 1/d everywhere, including exactly at the ends
    for s in (0.0, 0.3, 1.0):
        k = float(jnp.linalg.norm(frames(b, jnp.array([s]) * b.length).curv))
        np.testing.assert_allclose(k, 1 / 0.025, rtol=1e-8)


@pytest.mark.parametrize("kind, order", [("lame", 2), ("clothoid", 2), ("polar", 2), ("polar_g3", 3),
                                         ("polar_g4", 4), ("smoothstep", 4)])
def test_continuity_order_at_the_joins(kind, order):
    """Near a join the curvature of a G_k blend (k >= 2) grows as sigma^(k - 1), so |dK/ds| ~ sigma^(k - 2):
    doubling the distance from the join multiplies it by 2^(k - 2) (G2: a jump of dK/ds, ratio 1; G3:
    2; G4: 4). Checked at both ends (the distance taken from the end at the horizontal leg)."""
    b = make_blend(kind, 0.025, 0.035, 3.0)
    length = float(b.length)
    h = 1e-4 * length
    for s1, s2 in ((h, 2 * h), (length - h, length - 2 * h)):
        f = frames(b, jnp.array([s1, s2]))
        j = np.linalg.norm(np.asarray(f.dcurv), axis=-1)
        # |dK/ds| includes the tangential term kappa^2 ~ sigma^(2k - 2), negligible this close to the join
        np.testing.assert_allclose(j[1] / j[0], 2.0 ** (order - 2), rtol=0.02)


def test_smoothstep_heading_is_a_smooth_step_of_warped_arc_length():
    """The smoothstep blend turns by pi/2 with heading (pi/2) H(w(u)), u = s/L; its aspect e/d spans
    the documented range at the ends of the warp bracket, and an aspect outside it is refused."""
    b = make_blend("smoothstep", 0.0245, 0.08)
    beta, length = float(b.coef[0]), float(b.length)
    u = np.linspace(0.0, 1.0, 11)
    t = np.asarray(frames(b, jnp.asarray(u * length)).tangent)
    w = np.expm1(beta * u) / np.expm1(beta)
    h = w**4 * (35 - 84 * w + 70 * w**2 - 20 * w**3)                  # independent: the degree-7 smooth step
    np.testing.assert_allclose(np.arctan2(t[:, 0], t[:, 1]), 0.5 * np.pi * h, atol=1e-12)
    for beta, bound in ((20.0, blends._SMOOTH_ASPECT[0]), (-20.0, blends._SMOOTH_ASPECT[1])):
        x, y = np.asarray(blends._smooth_extent(jnp.asarray(beta), 0.0))
        assert abs(x / y - bound) < 1e-3 * bound      # the validated range sits inside the bracket
    with pytest.raises(ValueError, match="smoothstep"):
        make_blend("smoothstep", 0.002, 0.08)
