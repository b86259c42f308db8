"""Adept path (arc length, G2 joins, gradients) and motion laws (boundary conditions, consistency)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex.blends import BLENDS
from jaxflex.path import make_path, path_frame
from jaxflex import profiles
from jaxflex.profiles import PROFILES, make_profile, shaped, trapezoid
from jaxflex.robot import cycle_preset

# the law evaluated as one compiled program per law kind and shape (evaluated op by op, each of its
# hundreds of operations compiles a kernel of its own)
profile_eval = jax.jit(profiles.profile_eval, static_argnames="side")

frames = jax.jit(jax.vmap(path_frame, in_axes=(None, 0)))


@pytest.fixture(scope="module", params=["default", "table6"])
def cycle(request):
    return cycle_preset(request.param)


@pytest.mark.parametrize("kind", BLENDS)
def test_path_ends_and_length(cycle, kind):
    p = make_path(cycle, kind, 0.02, 0.03)
    f = frames(p, jnp.stack([0.0, p.length]))
    np.testing.assert_allclose(f.pos[0], cycle.pick, atol=1e-13)
    np.testing.assert_allclose(f.pos[1], cycle.place, atol=1e-12)
    b = p.blend1
    expected = 2 * (0.025 - 0.02) + 0.35 - 2 * 0.03 + 2 * float(b.length)
    np.testing.assert_allclose(float(p.length), expected, rtol=1e-14)
    # lift direction: the tangent at the pick point is the cycle's lift vector
    np.testing.assert_allclose(f.tangent[0], cycle.lift, atol=1e-10)
    np.testing.assert_allclose(f.tangent[1], -cycle.lift, atol=1e-10)


@pytest.mark.parametrize("kind", BLENDS)
def test_unit_speed_along_path(kind):
    p = make_path(cycle_preset("default"), kind, 0.02, 0.03)
    s = jnp.linspace(0.0005, float(p.length) - 0.0005, 301)
    h = 1e-6
    speed = jnp.linalg.norm((frames(p, s + h).pos - frames(p, s - h).pos) / (2 * h), axis=-1)
    # unit speed to O(h^2 kappa^2) except where a difference straddles a join (still 1 to O(h kappa))
    np.testing.assert_allclose(speed, 1.0, atol=1e-7)


@pytest.mark.parametrize("kind", BLENDS)
def test_g2_at_every_join(kind):
    """Position, tangent and curvature are continuous across the 4 line/blend joins (d != e, and
    different corners) -- the curvature jump across a join is O(eps) only."""
    p = make_path(cycle_preset("default"), kind, 0.02, 0.03, d2=0.024, e2=0.028)
    br = p.breaks[1:5]
    eps = 1e-9
    left, right = frames(p, br - eps), frames(p, br + eps)
    np.testing.assert_allclose(left.pos, right.pos, atol=3e-9)
    np.testing.assert_allclose(left.tangent, right.tangent, atol=1e-6)
    np.testing.assert_allclose(left.curv, right.curv, atol=1e-4)   # |curv| up to ~75 1/m inside


def test_path_gradients_match_finite_differences():
    c = cycle_preset("default")

    def length(x, kind):
        return make_path(c, kind, x[0], x[1], x[2]).length

    def max_curv(x, kind):
        p = make_path(c, kind, x[0], x[1], x[2])
        s = jnp.linspace(0.0, 1.0, 201) * p.length
        return jnp.max(jnp.linalg.norm(jax.vmap(path_frame, in_axes=(None, 0))(p, s).curv, axis=-1))

    x0 = jnp.array([0.022, 0.027, 3.2])
    for kind in BLENDS:
        for fn in (length, max_curv):
            f = jax.jit(lambda x: fn(x, kind))
            g = np.asarray(jax.grad(f)(x0))
            assert np.all(np.isfinite(g))
            for i in range(3 if kind == "lame" else 2):
                h = 1e-6 * (1.0 if i == 2 else 0.01)
                dx = jnp.zeros(3).at[i].set(h)
                fd = (float(f(x0 + dx)) - float(f(x0 - dx))) / (2 * h)
                # central FD: truncation O(h^2); round-off ~1e-16 * f / h ~ 4e-9 for the length
                # (dL/de nearly cancels: -1 for the traverse, +dLb/de for the blends)
                np.testing.assert_allclose(g[i], fd, rtol=1e-5, atol=5e-8)


# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", PROFILES)
def test_profile_boundary_conditions(name):
    v = profile_eval(make_profile(name), jnp.array([0.0, 1.0]))
    np.testing.assert_allclose(v.s, [0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(v.ds, [0.0, 0.0], atol=1e-15)
    if name == "poly7":
        np.testing.assert_allclose(v.dds, [0.0, 0.0], atol=1e-15)
        np.testing.assert_allclose(v.ddds, [0.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("profile", [make_profile(p) for p in PROFILES]
                         + [trapezoid(0.3), shaped(jnp.array([1.0, 3.0, 0.2, 2.0])),
                            shaped(jnp.array([0.5, -1.0, 2.0]), order=2)],
                         ids=lambda p: p.name + str(p.order))
def test_profile_derivatives_consistent_and_monotone(profile):
    f = jax.jit(lambda e: profile_eval(profile, e))
    eta = jnp.linspace(0.01, 0.99, 197)
    h = 1e-6
    vp, vm, v0 = f(eta + h), f(eta - h), f(eta)
    # at the trapezoid's kinks the central difference of s is off by up to h |S''| / 2 ~ 1e-5
    np.testing.assert_allclose((vp.s - vm.s) / (2 * h), v0.ds, atol=2e-5 if profile.kind == "trapezoid" else 1e-7)
    if profile.kind != "trapezoid":       # the trapezoid's acceleration jumps: skip its kinks
        np.testing.assert_allclose((vp.ds - vm.ds) / (2 * h), v0.dds, atol=1e-5)
        np.testing.assert_allclose((vp.dds - vm.dds) / (2 * h), v0.ddds, rtol=1e-5, atol=1e-3)
    dense = f(jnp.linspace(0.0, 1.0, 2001))
    assert float(jnp.min(dense.ds)) >= 0.0
    np.testing.assert_allclose(dense.s[-1], 1.0, atol=1e-13)


def test_shaped_family_contains_poly7_and_keeps_end_conditions():
    eta = jnp.linspace(0.0, 1.0, 101)
    a, b = profile_eval(shaped(jnp.ones(5)), eta), profile_eval(make_profile("poly7"), eta)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, atol=1e-12)
    rnd = profile_eval(shaped(jnp.array([0.3, -2.0, 1.5, 0.7]), order=2), jnp.array([0.0, 1.0]))
    np.testing.assert_allclose(rnd.s, [0.0, 1.0], atol=1e-14)
    np.testing.assert_allclose(rnd.ds, [0.0, 0.0], atol=1e-14)
    np.testing.assert_allclose(rnd.dds, [0.0, 0.0], atol=1e-14)


def test_shaped_order_4_is_poly9_at_equal_coefficients_and_its_jerk_vanishes_at_the_ends():
    """Order 4: S' = 630 eta^4 (1 - eta)^4 for g = 1 (the 9th-degree law); for any coefficients S
    goes from 0 to 1 with zero velocity, acceleration and jerk at both ends, and the jerk leaves
    the ends as eta^2 (order 3: as eta, with a jump of the fourth derivative there)."""
    eta = jnp.linspace(0.0, 1.0, 41)
    v = profile_eval(shaped(jnp.ones(4), order=4), eta)
    x = np.asarray(eta)
    np.testing.assert_allclose(v.ds, 630 * x**4 * (1 - x) ** 4, atol=1e-12)
    np.testing.assert_allclose(v.s, x**5 * (126 - 420 * x + 540 * x**2 - 315 * x**3 + 70 * x**4), atol=1e-12)
    rnd = profile_eval(shaped(jnp.array([0.3, -2.0, 1.5, 0.7, 1.1]), order=4), jnp.array([0.0, 1e-3, 1.0]))
    np.testing.assert_allclose(np.asarray(rnd.s)[[0, 2]], [0.0, 1.0], atol=1e-14)
    for d in (rnd.ds, rnd.dds, rnd.ddds):
        np.testing.assert_allclose(np.asarray(d)[[0, 2]], [0.0, 0.0], atol=1e-12)
    # near the start the jerk grows as eta^2 (order 4), not as eta (order 3)
    j3 = profile_eval(shaped(jnp.ones(4), order=3), jnp.array([1e-3])).ddds[0]
    assert abs(float(rnd.ddds[1])) < 1e-2 * abs(float(j3))


def test_trapezoid_cruise_speed_and_bang_bang():
    v = profile_eval(make_profile("trap_1_4"), jnp.array([0.5]))
    np.testing.assert_allclose(v.ds, 1 / (1 - 0.25), rtol=1e-15)
    bb = profile_eval(make_profile("bang_bang"), jnp.array([0.2, 0.7]))
    np.testing.assert_allclose(bb.s, [2 * 0.2**2, 1 - 2 * 0.3**2], rtol=1e-14)


@pytest.mark.parametrize("prof", [make_profile("poly7"), make_profile("trap_1_4"),
                                  shaped(jnp.array([1.0, 3.0, 0.2, 2.0]), name="a shaped law")])
def test_compiled_profile_values_equal_the_eager_evaluation(prof):
    """``profiles.profile_values`` (one compiled program per kind of law, for plots) gives the eager
    ``profile_eval``'s S, S', S'', S''' to round-off, right and left limits alike (at the trapezoid's
    acceleration jumps the two differ by the jump)."""
    eta = jnp.linspace(0.0, 1.0, 257)
    for side in (1, -1):
        ours, ref = profiles.profile_values(prof, eta, side), profiles.profile_eval(prof, eta, side)
        for a, b in zip(ours, ref):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(b))))
