"""Property-based tests (hypothesis) of the kinematic layer: blends, path, motion laws, rigid IGM.

Random VALID designs (blend family and parameters, cycle placement, motion law, tf, payload) must give
finite results that satisfy the construction's constraints; random INVALID inputs must raise a
ValueError naming the problem (docs/conventions.md#bad-input), never return a silent NaN.

Budget: every checked JAX function is jitted once at module level with fixed shapes (65 samples), so
the examples of a test reuse one compilation per blend family / motion-law kind; hypothesis runs
derandomized (the same examples in every run, CI included) without a deadline or example database.
"""
import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from jaxflex import combinations as combinations_mod
from jaxflex.blends import BLENDS, make_blend
from jaxflex.path import make_cycle, make_path
from jaxflex.profiles import (PROFILES, input_shaped, make_profile, profile_eval, shaped, time_scaled,
                              trapezoid, zv, zvd)
from jaxflex.rigid import rigid_torques
from jaxflex.robot import (check_cycle_reachable, check_reachable, cycle_preset, dgm, igm, jacobian,
                           jacobian_dot, joint_motion, pose_report, robot_preset)
from jaxflex.combinations import sample_combinations
from jaxflex.trajectory import arc_motion, check_tf, task_from_arc, time_grid, trajectory


def _settings(n):
    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


ROBOT = robot_preset("default")
CYCLE = cycle_preset("default")
N = 65                                    # samples per evaluation (fixed: one compilation)
EPS = 1e-9                                # half-gap around a segment join [m]
# d/e range of the G2 clothoid pair (Fresnel C(1), S(1); jaxflex.blends.check_blend_args), kept
# strictly inside so that the bounds' rounding never matters
CLO_LO, CLO_HI = 0.43826 / 0.77989 * 1.001, 0.77989 / 0.43826 * 0.999
# the polar quintic for d != e bulges past the legs once d/e leaves about [0.8, 1.25] (0.4 mm out at
# d/e = 1.5, 3 mm at 2): the inside-the-corner property is only claimed in this range
POLAR_CONVEX = (1 / 1.2, 1.2)

finite = dict(allow_nan=False, allow_infinity=False)
bad_positive = st.one_of(st.floats(max_value=0.0, **finite), st.sampled_from([np.nan, np.inf, -np.inf]))


# ---------------------------------------------------------------------------------------------
# jitted evaluators (fixed shapes)

_task = jax.jit(task_from_arc)          # one compilation per blend family (static field of the path)


@jax.jit
def _joints(robot, x, xd, xdd):
    """Rigid IGM motion at N task samples, the DGM of the angles, the DGM Jacobian J, the task velocity
    and acceleration rebuilt from the joint motion (J q', J q'' + J' q') and the rigid torques."""
    q, qd, qdd = jax.vmap(joint_motion, in_axes=(None, 0, 0, 0))(robot, x, xd, xdd)
    jac = jax.vmap(jacobian, in_axes=(None, 0))(robot, q)
    jdot = jax.vmap(jacobian_dot, in_axes=(None, 0, 0))(robot, q, qd)
    mv = lambda m, v: jnp.einsum("tij,tj->ti", m, v)
    tau = jax.vmap(rigid_torques, in_axes=(None, 0, 0, 0))(robot, q, qd, qdd)
    # magnitudes of the summed terms (|J| |q'|, |J| |q''| + |J'| |q'|): near a singularity q' and q''
    # are large and J q', J q'' + J' q' cancel, so round-off is relative to these
    vscale = mv(jnp.abs(jac), jnp.abs(qd))
    ascale = mv(jnp.abs(jac), jnp.abs(qdd)) + mv(jnp.abs(jdot), jnp.abs(qd))
    return dict(q=q, qd=qd, qdd=qdd, jac=jac, x_fk=jax.vmap(dgm, in_axes=(None, 0))(robot, q),
                xd_fk=mv(jac, qd), xdd_fk=mv(jac, qdd) + mv(jdot, qd), tau=tau, vscale=vscale,
                ascale=ascale)


@jax.jit
def _law(profile, eta):
    """S and its first three derivatives (right limits) and, for the laws whose acceleration may
    jump, the left limits too."""
    left = profile.kind in ("trapezoid", "impulses")
    return profile_eval(profile, eta), (profile_eval(profile, eta, -1) if left else None)


def _law_values(profile, eta):
    # the display name is a static field: normalize it so that all laws of a kind share a compilation
    return _law(dataclasses.replace(profile, name="law"), jnp.asarray(eta))


def _all_finite(tree):
    return all(np.all(np.isfinite(np.asarray(v))) for v in jax.tree_util.tree_leaves(tree))


# ---------------------------------------------------------------------------------------------
# strategies


@st.composite
def corner(draw, kind, h, half):
    """Blend parameters (d, e, n) of one corner of a cycle with lift h and half traverse ``half``."""
    d = h * draw(st.floats(0.02, 1.0))
    if kind == "clothoid":
        e = d / draw(st.floats(CLO_LO, CLO_HI))            # e <= 0.05 / 0.56 < half (>= 0.075)
    else:
        e = half * draw(st.floats(0.01, 1.0))
    return d, e, draw(st.floats(2.0, 8.0))


@st.composite
def paths(draw, cycle=None):
    """A path of any family with independent random corners, on ``cycle`` or on a random placement
    (pick point, traverse direction, lift on either side)."""
    kind = draw(st.sampled_from(BLENDS))
    if cycle is None:
        h, l = draw(st.floats(0.01, 0.05)), draw(st.floats(0.15, 0.45))
        pick = np.array([draw(st.floats(-0.3, 0.3)), draw(st.floats(-0.3, 0.5))])
        angle = draw(st.floats(-np.pi, np.pi))
        u = np.array([np.cos(angle), np.sin(angle)])
        lift = draw(st.sampled_from([1.0, -1.0])) * np.array([-u[1], u[0]])
        cycle = make_cycle(pick, pick + l * u, h=h, lift=lift)
    h, half = float(cycle.h), 0.5 * float(cycle.l)
    (d, e, n), (d2, e2, n2) = draw(corner(kind, h, half)), draw(corner(kind, h, half))
    return make_path(cycle, kind, d, e, n, d2, e2, n2)


N_COEF = 6       # the optimizer's default number of motion-law coefficients (jaxflex optimize --coef)
coefs = st.lists(st.floats(-3.0, 3.0), min_size=N_COEF, max_size=N_COEF).filter(
    lambda c: max(map(abs, c)) > 1e-3)        # (all zero is invalid: see test_bad_motion_law_parameters)


@st.composite
def laws(draw):
    """(law, zero acceleration at both ends, zero jerk at both ends) for a law of any family."""
    which = draw(st.sampled_from(["paper", "trapezoid", "shaped", "shaper"]))
    if which == "paper":
        name = draw(st.sampled_from(PROFILES))
        return make_profile(name), name == "poly7", name == "poly7"
    if which == "trapezoid":
        return trapezoid(draw(st.floats(1e-3, 0.5))), False, False
    if which == "shaped":     # the optimizer's family
        order = draw(st.sampled_from([2, 3]))
        return shaped(jnp.asarray(draw(coefs)), order), True, order == 3
    tf, freq = draw(st.floats(0.1, 2.0)), draw(st.floats(5.0, 100.0))
    assume(1.0 / freq / tf < 0.9)                      # the ZVD shaper fits in the motion time
    return draw(st.sampled_from([zv, zvd]))("poly7", freq, tf), True, False


# ---------------------------------------------------------------------------------------------
# valid designs


@_settings(60)
@given(kind=st.sampled_from(BLENDS), d=st.floats(1e-4, 0.2), ratio=st.floats(0.1, 10.0),
       n=st.floats(2.0, 20.0), scale=st.floats(0.1, 10.0))
def test_blend_length_bounds_scaling_and_symmetry(kind, d, ratio, n, scale):
    if kind == "clothoid":
        ratio = min(max(ratio, CLO_LO), CLO_HI)
    e = d / ratio
    b = make_blend(kind, d, e, n)
    length, cum = float(b.length), np.asarray(b.cum)
    assert np.isfinite(length) and _all_finite(b)
    # a curve from (0, 0) to (e, d) is at least the chord; one with x and y monotone (convex corner
    # blends) is at most the two legs it replaces
    assert length >= np.hypot(d, e) * (1 - 1e-12)
    if kind != "polar" or POLAR_CONVEX[0] <= d / e <= POLAR_CONVEX[1]:
        assert length <= (d + e) * (1 + 1e-12)
    # arc-length table: starts at 0, strictly increasing, ends at the length
    assert cum[0] == 0.0 and np.all(np.diff(cum) > 0) and cum[-1] == pytest.approx(length, rel=1e-14)
    # geometric similarity: scaling d and e scales the length (quadrature is scale-free: round-off)
    np.testing.assert_allclose(float(make_blend(kind, scale * d, scale * e, n).length), scale * length,
                               rtol=1e-10)
    # swapping d and e mirrors the blend about the corner bisector: same length
    np.testing.assert_allclose(float(make_blend(kind, e, d, n).length), length, rtol=1e-10)


@_settings(45)
@given(path=paths())
def test_path_is_continuous_unit_speed_and_inside_the_cycle(path):
    c, b1, b2 = path.cycle, path.blend1, path.blend2
    br = np.asarray(path.breaks)
    # N - 8 uniform samples, then both sides of the 4 joins (line/blend/line)
    s = np.clip(np.concatenate([np.linspace(0.0, br[-1], N - 8), br[1:5] - EPS, br[1:5] + EPS]), 0.0, br[-1])
    one, zero = np.ones(N), np.zeros(N)
    # with s' = 1, s'' = s''' = 0 the task derivatives are the frame: tangent, curvature vector, ...
    frame = _task(path, *(jnp.asarray(v) for v in (s, one, zero, zero)))
    assert _all_finite(frame)
    pos, tan, curv = (np.asarray(v) for v in frame[:3])
    h, l = float(c.h), float(c.l)
    # segment lengths: lift h - d, blend, traverse l - e - e2, blend, lower h - d2 (all >= 0, L > 0)
    expected = (h - float(b1.d)) + float(b1.length) + (l - float(b1.e) - float(b2.e)) + float(b2.length) \
        + (h - float(b2.d))
    assert br[0] == 0.0 and np.all(np.diff(br) >= 0) and br[-1] > 0
    np.testing.assert_allclose(br[-1], expected, rtol=1e-13)
    # ends: pick and place, leaving along +lift and arriving along -lift
    last = N - 9
    np.testing.assert_allclose(pos[0], c.pick, atol=1e-12)
    np.testing.assert_allclose(pos[last], c.place, atol=1e-12)
    np.testing.assert_allclose(tan[0], c.lift, atol=1e-9)
    np.testing.assert_allclose(tan[last], -np.asarray(c.lift), atol=1e-9)
    # arc-length parametrization: unit tangent, and the path is 1-Lipschitz in s (chord <= arc)
    np.testing.assert_allclose(np.linalg.norm(tan, axis=1), 1.0, atol=1e-9)
    chords = np.linalg.norm(np.diff(pos[:last + 1], axis=0), axis=1)
    assert np.all(chords <= np.diff(s[:last + 1]) + 1e-12)
    # joins: position continuous (the two samples are 2 EPS of arc apart) and tangent continuous (it
    # turns by at most |curvature| * 2 EPS across the gap; a kink would show as an O(1) jump)
    left, right = slice(N - 8, N - 4), slice(N - 4, N)
    gap = np.linalg.norm(pos[right] - pos[left], axis=1)
    assert np.all(gap <= 2 * EPS * (1 + 1e-6) + 1e-13), gap
    turn = np.linalg.norm(tan[right] - tan[left], axis=1)
    kmax = np.maximum(np.linalg.norm(curv[left], axis=1), np.linalg.norm(curv[right], axis=1))
    assert np.all(turn <= 2 * EPS * kmax + 1e-7), (turn, kmax)
    # every blend stays inside its corner, so the path stays in the unblended cycle's rectangle
    # (cycle frame: 0 <= along <= l, 0 <= up <= h); not claimed for the polar bulge (POLAR_CONVEX)
    ratios = [float(b.d / b.e) for b in (b1, b2)]
    if path.kind != "polar" or all(POLAR_CONVEX[0] <= r <= POLAR_CONVEX[1] for r in ratios):
        local = (pos - np.asarray(c.pick)) @ np.asarray(c.basis)
        tol = 1e-12
        assert np.all(local[:, 0] >= -tol) and np.all(local[:, 0] <= l + tol), local[:, 0]
        assert np.all(local[:, 1] >= -tol) and np.all(local[:, 1] <= h + tol), local[:, 1]


FD_H = 1e-5


@_settings(60)
@given(law=laws())
def test_motion_laws_boundary_conditions_monotone_and_consistent(law):
    profile, zero_acc, zero_jerk = law
    eta = np.linspace(0.0, 1.0, N)
    (right, left), (plus, _), (minus, _) = (_law_values(profile, e) for e in (eta, eta + FD_H, eta - FD_H))
    left = right if left is None else left           # continuous acceleration: no separate limits
    assert _all_finite((right, left, plus, minus))
    s, ds, dds, ddds = (np.asarray(v) for v in right)
    # S(0) = 0, S(1) = 1, at rest at both ends
    np.testing.assert_allclose([s[0], s[-1]], [0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose([ds[0], left.ds[-1]], [0.0, 0.0], atol=1e-12)
    if zero_acc:     # poly7, the shaped family, poly7 with a shaper: zero acceleration at both ends
        np.testing.assert_allclose([dds[0], left.dds[-1]], [0.0, 0.0], atol=1e-9)
    if zero_jerk:    # poly7 and the shaped family with r = 3 start and stop jerk-free
        np.testing.assert_allclose([ddds[0], left.ddds[-1]], [0.0, 0.0], atol=1e-8)
    if profile.kind == "trapezoid":    # acceleration +-1 / (ta (1 - ta)) at the ends, cruise 1 / (1 - ta)
        ta = float(profile.ta)
        acc = 1 / (ta * (1 - ta))
        np.testing.assert_allclose([dds[0], left.dds[-1]], [acc, -acc], rtol=1e-12)
        np.testing.assert_allclose(ds.max(), 1 / (1 - ta), rtol=1e-12)
    # monotone from 0 to 1 (a law never reverses along the path)
    assert np.all(ds >= -1e-12 * ds.max()) and np.all(np.diff(s) >= -1e-15) and s.max() <= 1 + 1e-12
    # the returned derivatives are the derivatives of S: central differences (step FD_H) at interior
    # points away from the trapezoids' acceleration jumps; truncation O(FD_H^2) relative to the next
    # derivatives' scale, round-off ~1e-16 / FD_H
    inner = np.ones(N, bool)
    inner[[0, -1]] = False
    if profile.kind == "trapezoid":
        ta = float(profile.ta)
        inner &= (np.abs(eta - ta) > 2 * FD_H) & (np.abs(eta - 1 + ta) > 2 * FD_H)
    fd = [(np.asarray(a) - np.asarray(b)) / (2 * FD_H) for a, b in zip(plus[:3], minus[:3])]
    for k, (got, want) in enumerate(zip(fd, (ds, dds, ddds))):
        scale = 1 + np.abs((dds, ddds, ddds)[k]).max()
        np.testing.assert_allclose(got[inner], want[inner], rtol=1e-6, atol=(1e-6 if k < 2 else 1e-4) * scale)


@_settings(25)
@given(coef=coefs, factor=st.one_of(st.floats(0.05, 20.0), st.floats(-20.0, -0.05)),
       const=st.floats(0.05, 5.0), order=st.sampled_from([2, 3]))
def test_shaped_family_invariances(coef, factor, const, order):
    eta = np.linspace(0.0, 1.0, N)
    base = _law_values(shaped(jnp.asarray(coef), order), eta)[0]
    # S' = t^r (1-t)^r g^2 / Z: multiplying every coefficient by any factor != 0 changes nothing
    scaled = _law_values(shaped(jnp.asarray(coef) * factor, order), eta)[0]
    for a, b in zip(base, scaled):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * (1 + np.abs(np.asarray(b)).max()))
    # r = 3 with equal coefficients (g constant) is exactly poly7, whatever the constant
    flat = _law_values(shaped(jnp.full(N_COEF, const), 3), eta)[0]
    poly7 = _law_values(make_profile("poly7"), eta)[0]
    for a, b in zip(flat, poly7):
        np.testing.assert_allclose(a, b, atol=1e-10)


def _check_joint_motion(robot, x, xd, xdd):
    """The rigid IGM motion is finite and round-trips through the DGM (position, J q', J q'' + J' q');
    the rigid torques are finite and affine in the payload: tau(m) - tau(0) = m J^T (x'' - g)."""
    args = [jnp.asarray(v) for v in (x, xd, xdd)]
    out = _joints(robot, *args)
    assert _all_finite(out)
    np.testing.assert_allclose(out["x_fk"], x, atol=1e-11)
    np.testing.assert_allclose(out["xd_fk"], xd, atol=1e-10 * (1 + np.max(out["vscale"])))
    np.testing.assert_allclose(out["xdd_fk"], xdd, atol=1e-10 * (1 + np.max(out["ascale"])))
    tau, tau0 = np.asarray(out["tau"]), np.asarray(_joints(robot.replace(payload=0.0), *args)["tau"])
    acc = np.asarray(out["xdd_fk"]) - np.asarray(robot.gravity)      # the motors' rigid x''
    pay = float(robot.payload) * np.einsum("tji,tj->ti", np.asarray(out["jac"]), acc)
    np.testing.assert_allclose(tau - tau0, pay, atol=1e-9 * (1 + np.abs(tau).max()))


@_settings(30)
@given(data=st.data())
def test_trajectory_is_finite_and_the_igm_roundtrips(data):
    # default robot and cycle placement with random lift and traverse, any blend and motion law
    cycle = cycle_preset("default", h=data.draw(st.floats(0.01, 0.04)), l=data.draw(st.floats(0.15, 0.35)))
    path = data.draw(paths(cycle=cycle))
    profile, zero_acc, _ = data.draw(laws())
    tf, payload = data.draw(st.floats(0.1, 2.0)), data.draw(st.floats(0.0, 10.0))
    robot = ROBOT.replace(payload=payload)
    check_cycle_reachable(robot, cycle)                       # a valid design is accepted
    # arc_motion on t = eta tf: s = L S(t / tf) and its time derivatives
    L = float(path.length)
    law = time_scaled(_law_values(profile, np.linspace(0.0, 1.0, N))[0], tf)
    s, ds, dds, ddds = (L * np.asarray(v) for v in law)
    np.testing.assert_allclose([s[0], s[-1]], [0.0, L], atol=1e-12)
    assert np.all(np.diff(s) >= -1e-15) and np.all(ds >= -1e-12 * L / tf)
    x, xd, xdd, xddd = (np.asarray(v) for v in _task(path, *(jnp.asarray(v) for v in (s, ds, dds, ddds))))
    assert _all_finite((x, xd, xdd, xddd))
    np.testing.assert_allclose(x[0], cycle.pick, atol=1e-12)
    np.testing.assert_allclose(x[-1], cycle.place, atol=1e-12)
    np.testing.assert_allclose(np.stack([xd[0], xd[-1]]), 0.0, atol=1e-12)      # at rest at both ends
    if zero_acc:   # S'' = 0 at both ends (at tf the right limit, the default side, of these laws)
        np.testing.assert_allclose(np.stack([xdd[0], xdd[-1]]), 0.0, atol=1e-8 * L / tf**2)
    # unit tangent: the task speed is s'
    np.testing.assert_allclose(np.linalg.norm(xd, axis=1), ds, rtol=1e-9, atol=1e-12)
    _check_joint_motion(robot, x, xd, xdd)


@_settings(30)
@given(a=st.floats(0.05, 0.15), l1=st.floats(0.2, 0.3), l2=st.floats(0.3, 0.45), payload=st.floats(0.0, 10.0),
       pts=st.lists(st.tuples(st.floats(-0.4, 0.4), st.floats(-0.6, 0.6)), min_size=N, max_size=N),
       rates=st.lists(st.floats(-5.0, 5.0), min_size=4, max_size=4))
def test_igm_roundtrips_at_every_accepted_pose_of_random_robots(a, l1, l2, payload, pts, rates):
    # random geometry; fixed working and assembly modes (static fields: one compilation)
    robot = ROBOT.replace(a=a, l1=l1, l2=l2, payload=payload)
    ok = []
    for p in pts:
        try:
            check_reachable(robot, np.asarray(p))
            ok.append(p)
        except ValueError:
            pass
    assume(ok)
    x = np.asarray((ok * N)[:N])                               # fixed shape (N, 2)
    # the numpy diagnostics (pose_report) and the JAX IGM are independent implementations of the
    # inverse geometric model (docs/conventions.md#frames-and-geometry)
    q = np.asarray(_joints(robot, jnp.asarray(x), jnp.zeros((N, 2)), jnp.zeros((N, 2)))["q"])
    np.testing.assert_allclose(q, pose_report(robot, x)["q"], atol=1e-12)
    # every accepted pose, with any velocity and acceleration: DGM(IGM(x)) = x, J q' = x', ... (a
    # pose of the other assembly mode would map to the other intersection of the distal circles)
    xd = np.broadcast_to(np.asarray(rates[:2]), (N, 2))
    xdd = np.broadcast_to(10.0 * np.asarray(rates[2:]), (N, 2))
    _check_joint_motion(robot, x, xd, xdd)


# ---------------------------------------------------------------------------------------------
# invalid inputs: ValueError naming the problem, before any compilation


T = jnp.linspace(0.0, 0.43, 9)
PATH = make_path(CYCLE, "lame", 0.02)


def _no_compile(call, match):
    before = combinations_mod.cache_size()
    with pytest.raises(ValueError, match=match):
        call()
    assert combinations_mod.cache_size() == before


@_settings(25)
@given(tf=bad_positive)
def test_bad_motion_time_is_rejected_everywhere(tf):
    match = r"motion time tf must be finite and > 0 s"
    for call in (lambda: time_grid(tf, 10), lambda: check_tf(tf),
                 lambda: trajectory(ROBOT, PATH, make_profile("poly7"), tf, T),
                 lambda: arc_motion(PATH, make_profile("poly7"), tf, T),
                 lambda: zv("poly7", 40.0, tf)):
        with pytest.raises(ValueError, match=r"tf must be finite and > 0"):
            call()
    _no_compile(lambda: sample_combinations(ROBOT, CYCLE, tf, T), match)


@_settings(25)
@given(payload=st.one_of(st.floats(max_value=-1e-300, **finite), st.sampled_from([np.nan, np.inf, -np.inf])))
def test_bad_payload_is_rejected(payload):
    with pytest.raises(ValueError, match=r"robot parameter payload must be (finite|>= 0)"):
        robot_preset(payload=payload)
    with pytest.raises(ValueError, match=r"robot parameter payload must be (finite|>= 0)"):
        ROBOT.replace(payload=payload)


@_settings(50)
@given(kind=st.sampled_from(BLENDS), data=st.data())
def test_blends_longer_than_their_legs_or_non_finite_are_rejected(kind, data):
    h, l = float(CYCLE.h), float(CYCLE.l)
    d, e, n = 0.8 * h, 0.8 * h, 3.0
    case = data.draw(st.sampled_from(["d>h", "d2>h", "e+e2>l", "nonpositive", "nonfinite"]))
    kw = {}
    if case == "d>h":          # (e = d keeps the clothoid's d/e valid)
        big = h * data.draw(st.floats(1.001, 100.0))
        kw, match = dict(d=big, e=big), r"blend parameter d = .* m exceeds the lift height h"
    elif case == "d2>h":
        big = h * data.draw(st.floats(1.001, 100.0))
        kw, match = dict(d2=big, e2=big), r"blend parameter d2 = .* m exceeds the lift height h"
    elif case == "e+e2>l":
        e1 = l * data.draw(st.floats(0.01, 0.99))
        kw, match = dict(e=e1, e2=l - e1 + l * data.draw(st.floats(1e-3, 10.0))), r"exceed the traverse l"
        kind = "lame" if kind == "clothoid" else kind     # the clothoid's d/e check would fire first
    elif case == "nonpositive":
        name = data.draw(st.sampled_from(["d", "e", "d2", "e2"]))
        kw, match = {name: data.draw(st.floats(max_value=0.0, **finite))}, rf"blend parameter {name} must be > 0"
    else:
        name = data.draw(st.sampled_from(["d", "e", "n", "d2", "e2", "n2"]))
        kw = {name: data.draw(st.sampled_from([np.nan, np.inf, -np.inf]))}
        match = rf"blend parameter {name} must be finite"
    args = dict(d=d, e=e, n=n)
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        make_path(CYCLE, kind, **args)
    if set(kw) <= {"d", "e", "n"} and case != "e+e2>l":      # sample_combinations takes one corner
        _no_compile(lambda: sample_combinations(ROBOT, CYCLE, 0.43, T, blends=(kind,), **args), match)


@_settings(25)
@given(n=st.floats(max_value=1.999, **finite), low=st.booleans(), ratio=st.floats(1.8, 50.0))
def test_lame_order_and_clothoid_ratio_out_of_range(n, low, ratio):
    with pytest.raises(ValueError, match=r"Lamé order n must be >= 2"):
        make_blend("lame", 0.02, 0.02, n)
    with pytest.raises(ValueError, match=r"Lamé order n2 must be >= 2"):
        make_path(CYCLE, "lame", 0.02, 0.02, 3.0, n2=n)
    d, e = (0.02 / ratio, 0.02) if low else (0.02, 0.02 / ratio)
    with pytest.raises(ValueError, match=r"no G2 clothoid pair with d/e"):
        make_blend("clothoid", d, e)
    with pytest.raises(ValueError, match=r"no G2 clothoid pair with d2/e2"):
        make_path(CYCLE, "clothoid", 0.02, 0.02, d2=d, e2=e)


@_settings(25)
@given(where=st.sampled_from(["pick point", "place point", "path point"]), radius=st.floats(0.8, 5.0),
       angle=st.floats(0.0, 2 * np.pi), near=st.booleans())
def test_unreachable_poses_are_rejected_with_the_point_and_arm(where, radius, angle, near):
    # far: more than l1 + l2 from both motors; near: closer than |l1 - l2| to both motors (a = 0.1)
    pick, place, h = np.asarray(CYCLE.pick), np.asarray(CYCLE.place), 0.025
    if where == "pick point":
        pick = np.array([np.cos(angle), np.sin(angle)]) * (0.02 if near else radius)
        place = pick + np.array([0.05, 0.0])
        bad = pick
    elif where == "place point":
        place = bad = pick + np.array([radius + 0.3, 0.0])
    else:
        h = radius                       # the lift leaves the workspace
        bad = pick + np.array([0.0, h])
    cycle = make_cycle(pick, place, h=h)
    match = rf"{where} \(.*\) m is unreachable by arm [12] .*(exceeds l1 \+ l2|is below \|l1 - l2\|)"
    if where == "path point":      # the lift meets the edge of the workspace (aligned links) first
        match = r"path point \(.*\) m is (unreachable by arm|at a serial singularity of arm) [12]"
    with pytest.raises(ValueError, match=match):
        check_cycle_reachable(ROBOT, cycle)
    _no_compile(lambda: sample_combinations(ROBOT, cycle, 0.43, T, blends=("lame",), d=0.02), match)
    with pytest.raises(ValueError, match=match):       # before: NaN joint angles
        trajectory(ROBOT, make_path(cycle, "lame", 0.02), make_profile("poly7"), 0.43, T)
    with pytest.raises(ValueError, match=r"reference point .* is unreachable"):
        robot_preset(reference_point=bad)


@_settings(40)
@given(name=st.text(max_size=12))
def test_unknown_profile_and_blend_names(name):
    assume(name not in PROFILES and name not in BLENDS)
    with pytest.raises(ValueError, match=re.escape(f"unknown motion profile {name!r}")):
        make_profile(name)
    _no_compile(lambda: sample_combinations(ROBOT, CYCLE, 0.43, T, profiles=(name,)),
                re.escape(f"unknown motion profile {name!r}"))
    with pytest.raises(ValueError, match=re.escape(f"unknown blend {name!r}")):
        make_path(CYCLE, name, 0.02)


@_settings(40)
@given(data=st.data())
def test_bad_motion_law_parameters(data):
    case = data.draw(st.sampled_from(["ta", "coef_bad", "coef_zero", "order", "shaper_freq", "impulses"]))
    if case == "ta":
        ta = data.draw(st.one_of(st.floats(max_value=0.0), st.floats(min_value=0.5000001)))
        call, match = (lambda: trapezoid(ta)), r"ta must be in \(0, 1/2\]"
    elif case == "coef_bad":              # before: S = NaN everywhere
        m = data.draw(st.integers(1, 8))
        coef = np.array(data.draw(st.lists(st.floats(-3.0, 3.0), min_size=m, max_size=m)))
        coef[data.draw(st.integers(0, m - 1))] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]))
        call, match = (lambda: shaped(coef)), r"coefficients must be finite"
    elif case == "coef_zero":             # g = 0: no normalization (before: S = 0/0 = NaN)
        m = data.draw(st.integers(1, 8))
        call, match = (lambda: shaped(np.zeros(m), data.draw(st.sampled_from([2, 3, 4])))), r"all zero"
    elif case == "order":
        order = data.draw(st.integers(-5, 10).filter(lambda r: r not in (2, 3, 4)))
        call, match = (lambda: shaped(np.ones(4), order)), r"order must be 2, 3 or 4"
    elif case == "shaper_freq":           # before: ZeroDivisionError for 0
        freq = data.draw(bad_positive)
        call, match = (lambda: data.draw(st.sampled_from([zv, zvd]))("poly7", freq, 0.43)), \
            r"mode frequency freq_hz must be finite and > 0"
    else:                                 # before: NaN amplitudes or times gave a NaN law
        bad = data.draw(st.sampled_from([np.nan, np.inf]))
        amps, times = [0.25, 0.5, 0.25], [0.0, 0.1, 0.2]
        (amps if data.draw(st.booleans()) else times)[data.draw(st.integers(1, 2))] = bad
        call, match = (lambda: input_shaped("poly7", amps, times)), r"must be finite"
    with pytest.raises(ValueError, match=match):
        call()


@_settings(40)
@given(data=st.data())
def test_wrong_shapes_are_rejected(data):
    k = data.draw(st.integers(0, 5))
    vec = [0.01] * k
    case = data.draw(st.sampled_from(["d", "tf", "cycle", "h", "points", "coef", "impulses", "ta"]))
    if case == "d":                        # before: TypeError or a broadcasting error in the quadrature
        name = data.draw(st.sampled_from(["d", "e", "n"]))
        kw = dict(d=0.02, e=0.02, n=3.0)
        kw[name] = np.full((k, 1) if k else (1, 2), 0.02)
        call, match = (lambda: make_path(CYCLE, "lame", **kw)), rf"blend parameter {name} must be a scalar"
    elif case == "tf":                     # before: a (T, k) time grid
        call, match = (lambda: time_grid(np.full(k + 1, 0.4), 10)), r"tf must be a scalar"
    elif case == "cycle":
        assume(k != 2)
        call, match = (lambda: make_cycle(vec, (0.1, 0.3))), r"must be 2-vectors"
    elif case == "h":                      # before: TypeError
        call, match = (lambda: make_cycle((-0.1, 0.3), (0.1, 0.3), h=[0.02] * (k + 2))), r"h must be a scalar"
    elif case == "points":                 # before: numpy broadcasting error
        assume(k != 2)
        call, match = (lambda: check_reachable(ROBOT, np.zeros((3, k)))), r"must have shape \(2,\) or \(N, 2\)"
    elif case == "coef":
        coef = np.ones((k, 2)) if k else np.ones(0)
        call, match = (lambda: shaped(coef)), r"non-empty 1-D"
    elif case == "impulses":
        call, match = (lambda: input_shaped("poly7", [1.0], [0.0] * (k + 2))), r"equal length"
    else:
        call, match = (lambda: trapezoid(np.full(k + 2, 0.25))), r"ta must be in"
    with pytest.raises(ValueError, match=match):
        call()


ROBOT6 = robot_preset("table6")        # assembly -1; its other mode reaches into x ~ 0, y ~ 0.1-0.17


@_settings(20)
@given(x=st.floats(-0.04, 0.04), y=st.floats(0.11, 0.16))
def test_poses_of_the_other_assembly_mode_are_rejected(x, y):
    p = np.array([x, y])
    check_reachable(ROBOT6, p, assembly=False)               # each arm reaches it, no singularity
    assume(np.sign(pose_report(ROBOT6, p[None])["distal_sine"][0]) != ROBOT6.assembly)
    # the DGM of its IGM is the other intersection of the distal circles: a silently wrong pose
    # before check_reachable knew the assembly mode
    assert np.linalg.norm(np.asarray(dgm(ROBOT6, igm(ROBOT6, jnp.asarray(p)))) - p) > 1e-2
    match = r"is in assembly mode \+1, not the robot's -1: .* parallel singularity"
    with pytest.raises(ValueError, match=match):
        check_reachable(ROBOT6, p)
    cycle = make_cycle(p, p + np.array([0.05, 0.0]), h=0.005)
    with pytest.raises(ValueError, match=r"pick point .* " + match):
        trajectory(ROBOT6, make_path(cycle, "lame", 0.004), make_profile("poly7"), 0.43, T)
    _no_compile(lambda: sample_combinations(ROBOT6, cycle, 0.43, T, d=0.004), r"pick point .* " + match)
