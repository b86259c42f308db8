"""Robot parameters (paper Table 3), presets (docs/conventions.md#frames-and-geometry) and rigid kinematics
of the five-bar.

The five-bar has motors at B1 = (-a, 0) and B2 = (+a, 0); proximal links (length l1, angle q_i from
the x axis) end at the elbows E_i, distal links (length l2) meet at the end effector X. The working
mode (m1, m2) picks the elbow side in the inverse geometric model (IGM); the assembly mode (+1/-1:
X to the left/right of E1 -> E2) picks the solution of the direct geometric model (DGM).
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.names import PRESETS
from jaxflex.path import Cycle, make_cycle


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Robot:
    """Five-bar robot: links (Table 3), placement, payload, gravity (all SI units).

    Array fields (differentiable, vmappable): ``l1``, ``l2`` link lengths [m]; ``diameter`` solid
    round bar diameter [m]; ``rho`` density [kg/m^3]; ``young`` Young's modulus [Pa]; ``a`` half
    distance between the motors [m]; ``payload`` point mass at the end effector [kg];
    ``rotor_inertia`` motor rotor inertia [kg m^2]; ``gravity`` (2,) acceleration vector [m/s^2];
    ``damping`` (2,) Rayleigh coefficients (alpha [1/s], beta [s]) of the elastic coordinates.

    Static fields: ``modes`` working mode (m1, m2) in {+1, -1}^2; ``assembly`` +1/-1;
    ``n_bending`` and ``n_axial`` numbers of assumed modes of the proximal (bending) and distal (axial)
    links; ``n_axial_proximal`` and ``n_bending_distal`` (default 0, the paper's model) add tension-
    compression modes to the proximal links and bending modes to the distal links: the richer model
    (``jaxflex.model.richer``) that validates designs and never trains them
    (docs/conventions.md#elastodynamic-model).
    """

    l1: jax.Array
    l2: jax.Array
    diameter: jax.Array
    rho: jax.Array
    young: jax.Array
    a: jax.Array
    payload: jax.Array
    rotor_inertia: jax.Array
    gravity: jax.Array
    damping: jax.Array
    modes: tuple = dataclasses.field(metadata=dict(static=True), default=(1, -1))
    assembly: int = dataclasses.field(metadata=dict(static=True), default=1)
    n_bending: int = dataclasses.field(metadata=dict(static=True), default=3)
    n_axial: int = dataclasses.field(metadata=dict(static=True), default=3)
    n_axial_proximal: int = dataclasses.field(metadata=dict(static=True), default=0)
    n_bending_distal: int = dataclasses.field(metadata=dict(static=True), default=0)

    @property
    def area(self):
        """Cross-section area pi d^2 / 4 [m^2]."""
        return jnp.pi * self.diameter**2 / 4.0

    @property
    def second_moment(self):
        """Second moment of area pi d^4 / 64 [m^4]."""
        return jnp.pi * self.diameter**4 / 64.0

    @property
    def bases(self):
        """(2, 2) motor positions B1, B2 [m]."""
        zero = jnp.zeros_like(self.a)
        return jnp.stack([jnp.stack([-self.a, zero]), jnp.stack([self.a, zero])])

    def replace(self, **changes) -> "Robot":
        """Copy with fields replaced (values are converted to float64 arrays)."""
        static = {"modes", "assembly", "n_bending", "n_axial", "n_axial_proximal", "n_bending_distal"}
        conv = {k: (v if k in static else jnp.asarray(v, dtype=float) if isinstance(v, jax.Array)
                    else jax.device_put(np.asarray(v, dtype=np.float64))) for k, v in changes.items()}
        out = dataclasses.replace(self, **conv)
        check_robot(out)
        return out


_PRESET_DATA = {
    # a [m], working mode, pick, place, lift direction
    "default": (0.10, (1, -1), (-0.175, 0.26), (0.175, 0.26), (0.0, 1.0)),
    "table6": (0.1302, (-1, 1), (-0.175, 0.2815), (0.175, 0.2815), (0.0, -1.0)),
}


def _check_name(name):
    if name not in _PRESET_DATA:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")


def make_robot(a=0.10, modes=(1, -1), *, l1=0.24, l2=0.38079, diameter=0.035, rho=2710.0,
               young=70e9, payload=0.0, rotor_inertia=0.0, gravity=(0.0, 9.81),
               damping=(0.0, 0.0), reference_point=None, assembly=None, n_bending=3,
               n_axial=3) -> Robot:
    """A five-bar robot with the paper's Table 3 links unless told otherwise.

    Args:
        a: half distance between the motors [m].
        modes: working mode (m1, m2), each +1 or -1 (sign of the acos term of the IGM).
        l1, l2, diameter, rho, young: Table 3 (m, m, m, kg/m^3, Pa).
        payload: end-effector point mass [kg].
        rotor_inertia: motor rotor inertia [kg m^2] (the paper has none).
        gravity: gravity vector [m/s^2]; the paper takes gravity "upwards": (0, +9.81).
        damping: Rayleigh (alpha [1/s], beta [s]) damping of the elastic coordinates (paper: none).
        reference_point: a pose (x, y) [m] used to fix the assembly mode (e.g. the pick point);
            ignored if ``assembly`` is given.
        assembly: +1 / -1, side of the end effector w.r.t. the elbow line E1 -> E2.
        n_bending, n_axial: numbers of assumed modes (>= 1).
    """
    modes = tuple(int(m) for m in modes)
    if len(modes) != 2 or any(m not in (1, -1) for m in modes):
        raise ValueError(f"working modes must be a pair of +1/-1, got {modes}")
    for name, k in (("n_bending", n_bending), ("n_axial", n_axial)):
        if int(k) != k or k < 1:
            raise ValueError(f"{name} (number of assumed modes) must be a positive integer, got {k}")
    # host values first (numpy: building a robot compiles nothing), then device arrays
    arr = lambda v: jax.device_put(np.asarray(v, dtype=np.float64))
    robot = Robot(
        l1=arr(l1), l2=arr(l2), diameter=arr(diameter), rho=arr(rho), young=arr(young), a=arr(a),
        payload=arr(payload), rotor_inertia=arr(rotor_inertia), gravity=arr(gravity), damping=arr(damping),
        modes=modes, assembly=1, n_bending=int(n_bending), n_axial=int(n_axial))
    check_robot(robot)
    if assembly is None:
        if reference_point is None:
            raise ValueError("give either assembly (+1/-1) or a reference_point to deduce it")
        point = np.asarray(reference_point, dtype=float)[None]
        check_reachable(robot, point, "reference point", assembly=False)
        assembly = 1 if pose_report(robot, point)["distal_sine"][0] > 0 else -1
    if assembly not in (1, -1):
        raise ValueError(f"assembly mode must be +1 or -1, got {assembly}")
    return dataclasses.replace(robot, assembly=int(assembly))


def robot_preset(name: str = "default", **overrides) -> Robot:
    """Robot of a preset (``default`` or ``table6``, docs/conventions.md#frames-and-geometry); keyword
    overrides go to ``make_robot``."""
    _check_name(name)
    a, modes, pick, _, _ = _PRESET_DATA[name]
    kw = dict(a=a, modes=modes, reference_point=pick)
    kw.update(overrides)
    return make_robot(**kw)


def cycle_preset(name: str = "default", h: float = 0.025, l: float = 0.35) -> Cycle:
    """Adept cycle placement of a preset (docs/conventions.md#frames-and-geometry), centred on the
    symmetry axis (h, l in m)."""
    _check_name(name)
    if not (np.ndim(l) == 0 and np.isfinite(float(l)) and float(l) > 0):
        raise ValueError(f"traverse length l must be finite and > 0 m, got {l}")
    _, _, pick, _, lift = _PRESET_DATA[name]
    y = pick[1]
    return make_cycle((-0.5 * l, y), (0.5 * l, y), h=h, lift=lift)


SMALL_DEFLECTION = 0.05     # the largest deflection / link length the small-deflection model is taken to cover


def deflection_ratio(robot: Robot, acceleration) -> float:
    """An order-of-magnitude estimate of the links' deflection relative to their length under an
    acceleration load ``acceleration`` [m/s^2] on the payload and on the links' own mass: each link
    a cantilever of its length and the robot's section, with the whole payload at its tip
    (P L^3 / 3 E I) and its own mass spread along it (w L^4 / 8 E I); the larger ratio of the two
    links (the largest over a batch of robots). Eager: numpy values."""
    ei = np.asarray(robot.young, dtype=float) * np.pi * np.asarray(robot.diameter, dtype=float) ** 4 / 64.0
    line = np.asarray(robot.rho, dtype=float) * np.pi * np.asarray(robot.diameter, dtype=float) ** 2 / 4.0
    ratios = [float(np.max(acceleration * (np.asarray(robot.payload, dtype=float) * length**2 / (3.0 * ei)
                                           + line * length**3 / (8.0 * ei))))
              for length in (np.asarray(robot.l1, dtype=float), np.asarray(robot.l2, dtype=float))]
    return max(ratios)


def check_motion_loads(robot: Robot, cycle: Cycle, tf: float) -> None:
    """ValueError, before anything compiles, when a rest-to-rest motion from the pick to the place in
    tf [s] must load the links beyond the model's small deflections: every such motion reaches a
    peak acceleration of at least 4 |place - pick| / tf^2, and ``deflection_ratio`` under it must stay
    below ``SMALL_DEFLECTION`` (docs/conventions.md#model-range)."""
    tf = float(tf)
    distance = float(np.linalg.norm(np.asarray(cycle.place, dtype=float) - np.asarray(cycle.pick, dtype=float)))
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        least = np.float64(4.0 * distance) / np.float64(tf) / np.float64(tf) if tf > 0 else np.inf
        ratio = deflection_ratio(robot, least) if np.isfinite(least) else np.inf
    if not ratio <= SMALL_DEFLECTION:
        raise ValueError(f"motion time tf {tf:g} s is too short for this robot: any move from the pick to the "
                         f"place in it accelerates at {least:.3g} m/s^2 or more, which bends the links by about "
                         f"{100 * ratio:.3g} % of their length (a cantilever estimate), beyond the small deflections "
                         f"the model covers ({100 * SMALL_DEFLECTION:g} %); see docs/conventions.md#model-range")


def check_robot(robot: Robot) -> None:
    """Eager validation: finite, positive physical parameters, and a static sag under gravity within
    the model's small deflections (``deflection_ratio``; docs/conventions.md#model-range). Skipped
    for traced values."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError("jaxflex computes in float64, but JAX is in float32 mode: call "
                           "jax.config.update(\"jax_enable_x64\", True) before anything else (before any array "
                           "is created), or set JAX_ENABLE_X64=1 (docs/conventions.md#units-and-precision)")
    positive = ("l1", "l2", "diameter", "rho", "young", "a")
    nonneg = ("payload", "rotor_inertia")
    for name in positive + nonneg + ("gravity", "damping"):
        v = getattr(robot, name)
        if isinstance(v, jax.core.Tracer):
            continue
        v = np.asarray(v)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"robot parameter {name} must be finite, got {v}")
        if name in positive and np.any(v <= 0):
            raise ValueError(f"robot parameter {name} must be > 0, got {v}")
        if name in nonneg + ("damping",) and np.any(v < 0):
            raise ValueError(f"robot parameter {name} must be >= 0, got {v}")
    fields = (robot.l1, robot.l2, robot.diameter, robot.rho, robot.young, robot.payload, robot.gravity)
    if not any(isinstance(v, jax.core.Tracer) for v in fields):
        g = np.linalg.norm(np.asarray(robot.gravity, dtype=float), axis=-1)
        ratio = deflection_ratio(robot, np.max(g))
        if ratio > SMALL_DEFLECTION:
            raise ValueError(f"payload {float(np.max(np.asarray(robot.payload))):g} kg: the links' static sag under "
                             f"gravity is about {100 * ratio:.3g} % of their length (a cantilever estimate), beyond "
                             f"the small deflections the model covers ({100 * SMALL_DEFLECTION:g} %); take a lighter "
                             "payload or stiffer links (docs/conventions.md#model-range)")


# ----------------------------------------------------------------------------------------------
# rigid kinematics (JAX)


def igm(robot: Robot, x) -> jax.Array:
    """Inverse geometric model: end-effector position x (2,) [m] -> motor angles q (2,) [rad]."""
    out = []
    for i in range(2):
        d = x - robot.bases[i]
        r = jnp.linalg.norm(d)
        c = (r**2 + robot.l1**2 - robot.l2**2) / (2.0 * robot.l1 * r)
        out.append(jnp.arctan2(d[1], d[0]) + robot.modes[i] * jnp.arccos(c))
    return jnp.stack(out)


def elbows(robot: Robot, q) -> jax.Array:
    """(2, 2) elbow positions E1, E2 [m] for motor angles q (2,)."""
    return robot.bases + robot.l1 * jnp.stack([jnp.cos(q), jnp.sin(q)], axis=-1)


def circle_intersection(p1, r1, p2, r2, side):
    """Intersection of circles (p1, r1) and (p2, r2) on the ``side`` (+1 left / -1 right) of p1 -> p2."""
    v = p2 - p1
    dist2 = v @ v
    dist = jnp.sqrt(dist2)
    along = (dist2 + r1**2 - r2**2) / (2.0 * dist)
    height = jnp.sqrt(r1**2 - along**2)
    u = v / dist
    perp = jnp.stack([-u[1], u[0]])
    return p1 + along * u + side * height * perp


def dgm(robot: Robot, q) -> jax.Array:
    """Direct geometric model: motor angles q (2,) [rad] -> end-effector position (2,) [m]."""
    e = elbows(robot, q)
    return circle_intersection(e[0], robot.l2, e[1], robot.l2, robot.assembly)


def jacobian(robot: Robot, q) -> jax.Array:
    """(2, 2) Jacobian dX/dq of the DGM [m/rad] (autodiff)."""
    return jax.jacfwd(lambda qq: dgm(robot, qq))(q)


def jacobian_dot(robot: Robot, q, qd) -> jax.Array:
    """(2, 2) time derivative of ``jacobian`` along the joint velocity qd [rad/s]."""
    return jax.jvp(lambda qq: jacobian(robot, qq), (q,), (qd,))[1]


def joint_motion(robot: Robot, x, xd, xdd):
    """Joint angles, rates and accelerations (each (2,)) from task position, velocity, acceleration.

    q = IGM(x), qd = D IGM . xd, qdd = D^2 IGM[xd, xd] + D IGM . xdd (forward-mode autodiff).
    """
    f = lambda p: igm(robot, p)
    q, qd = jax.jvp(f, (x,), (xd,))
    dir_deriv = lambda p: jax.jvp(f, (p,), (xd,))[1]
    _, qdd_vel = jax.jvp(dir_deriv, (x,), (xd,))
    qdd = qdd_vel + jax.jvp(f, (x,), (xdd,))[1]
    return q, qd, qdd


# ----------------------------------------------------------------------------------------------
# eager reachability / singularity checks (numpy; run before any compilation)


def _host_bases(robot: Robot) -> np.ndarray:
    """(2, 2) motor positions [m] as numpy (no device computation)."""
    a = float(robot.a)
    return np.array([[-a, 0.0], [a, 0.0]])


def pose_report(robot: Robot, points) -> dict:
    """Numpy diagnostics of poses (N, 2): per-arm acos argument c, distal-link crossing sine."""
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    l1, l2 = float(robot.l1), float(robot.l2)
    bases = _host_bases(robot)
    cs = []
    q = []
    for i in range(2):
        d = pts - bases[i]
        r = np.linalg.norm(d, axis=1)
        c = (r**2 + l1**2 - l2**2) / (2 * l1 * np.maximum(r, 1e-300))
        cs.append(c)
        q.append(np.arctan2(d[:, 1], d[:, 0]) + robot.modes[i] * np.arccos(np.clip(c, -1, 1)))
    q = np.stack(q, axis=1)
    el = bases[None] + l1 * np.stack([np.cos(q), np.sin(q)], -1)
    w1, w2 = pts - el[:, 0], pts - el[:, 1]
    sine = (w1[:, 0] * w2[:, 1] - w1[:, 1] * w2[:, 0]) / (l2 * l2)
    return {"c": np.stack(cs, axis=1), "distal_sine": sine, "q": q}


def check_reachable(robot: Robot, points, what: str = "pose", margin: float = 1e-3,
                    assembly: bool = True) -> None:
    """Raise ValueError naming the first point that an arm cannot reach or that is (near) singular.

    ``margin`` bounds |c| <= 1 - margin for the IGM acos argument (serial singularity: proximal and
    distal link aligned) and |sin| >= margin for the angle between the distal links (parallel
    singularity). With ``assembly`` (default) a point must also lie in the robot's assembly mode (the
    sign of that sine): in the other mode the DGM of its IGM is another point, and the robot could
    only get there through a parallel singularity.
    """
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"{what}: points must have shape (2,) or (N, 2), got {np.shape(points)}")
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"{what}: non-finite coordinates")
    rep = pose_report(robot, pts)
    l1, l2 = float(robot.l1), float(robot.l2)
    bases = _host_bases(robot)
    for k, p in enumerate(pts):
        for i in range(2):
            c = rep["c"][k, i]
            r = np.linalg.norm(p - bases[i])
            where = f"{what} ({p[0]:.4f}, {p[1]:.4f}) m"
            if abs(c) > 1:
                why = (f"its distance {r:.4f} m from the motor exceeds l1 + l2 = {l1 + l2:.4f} m"
                       if r > l1 + l2 else
                       f"its distance {r:.4f} m from the motor is below |l1 - l2| = {abs(l1 - l2):.4f} m")
                raise ValueError(f"{where} is unreachable by arm {i + 1} (motor at "
                                 f"({bases[i][0]:.4f}, 0)): {why}")
            if abs(c) > 1 - margin:
                raise ValueError(f"{where} is at a serial singularity of arm {i + 1}: proximal and "
                                 f"distal links (nearly) aligned (|cos| = {abs(c):.6f})")
        if abs(rep["distal_sine"][k]) < margin:
            raise ValueError(f"{what} ({p[0]:.4f}, {p[1]:.4f}) m is at a parallel singularity: the "
                             f"distal links are (nearly) aligned (sin = {rep['distal_sine'][k]:.2e})")
        if assembly and np.sign(rep["distal_sine"][k]) != robot.assembly:
            raise ValueError(f"{what} ({p[0]:.4f}, {p[1]:.4f}) m is in assembly mode "
                             f"{-robot.assembly:+d}, not the robot's {robot.assembly:+d}: it is reached "
                             "only through a parallel singularity (distal links aligned)")


def check_cycle_reachable(robot: Robot, cycle: Cycle, samples: int = 200) -> None:
    """Check the pick and place points, then a dense sample of the unblended cycle (which encloses
    every blend), for reachability and singularities."""
    pick, place = np.asarray(cycle.pick), np.asarray(cycle.place)
    up = np.asarray(cycle.lift) * float(cycle.h)
    check_reachable(robot, pick[None], "pick point")
    check_reachable(robot, place[None], "place point")
    corners = [pick, pick + up, place + up, place]
    for a, b in zip(corners[:-1], corners[1:]):
        t = np.linspace(0.0, 1.0, samples)[:, None]
        check_reachable(robot, a + t * (b - a), "path point")
