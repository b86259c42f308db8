"""A servo loop on each motor: the controller that drives the motors instead of prescribing them.

The paper's perfect controller prescribes the motor angles. A real robot's motors are driven by a
sampled loop: per motor, at the instants t_k = k T (T = 1 / rate),

    u_k = tau_ff(t_k) + Kp (q_ref(t_k) - q(t_k)) + Kd (q_ref'(t_k) - q'(t_k)) + Ki sum_j T (q_ref - q)(t_j),

held over [t_k, t_k + T) (with a one-sample delay over [t_k + T, t_k + 2 T)) and clipped to the
torque limit. The rotor inertia sits on the motor's axis (``Robot.rotor_inertia``; ``with_rotor``
puts the servo's there). The feedforward ``tau_ff`` is "none", "rigid" (the inverse dynamics of the
rigid robot along the reference: what a controller with a rigid model computes) or "flexible" (the
inverse dynamics of the elastodynamic model: the perfect controller's torque).

Default gains from a closed-loop bandwidth fc [Hz] and a damping ratio zeta (0.7), with J the mean of
the diagonal of the rigid joint-space inertia matrix (rotor included) at the path's midpoint by arc
length: Kp = J (2 pi fc)^2, Kd = 2 zeta J (2 pi fc) (``servo_from_bandwidth``). A sampled loop can
be unstable (the loop's gain against the sample-and-hold's delay and the elastic modes); its
spectral radius, linearized at rest at a pose, is ``sampled_radius``, and ``check_stable`` refuses a
servo that is unstable along the path.

Without structural damping (the paper's model) a sampled PD leaves some kHz elastic modes
marginally unstable at any bandwidth: at 6 kg and 8 kHz the radius is 1 + 4.5e-4 at fc 15 Hz and
1 + 8.3e-4 at 40 Hz (modes near 1.6 kHz, which grow about 7-fold and 33-fold over a 0.53 s run from
whatever the motion puts in them, next to nothing), and a structural damping ratio of a few
hundredths of a percent at the first mode removes it; from about 50 Hz a strong instability sets
in. So ``check_stable`` refuses a loop whose worst mode would grow more than ``GROWTH_LIMIT``-fold
over the simulated time (``strict=True``: any radius above 1). docs/conventions.md#servo.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks
from jaxflex import model as mdl
from jaxflex.path import Path, make_path, path_frame
from jaxflex.rigid import rigid_torques
from jaxflex.robot import Robot, igm

FEEDFORWARDS = ("none", "rigid", "flexible")
ZETA = 0.7                      # the default gain rule's damping ratio
STABILITY_TOL = 1e-7            # a sampled loop is unstable when its spectral radius exceeds 1 + this
GROWTH_LIMIT = 1e3              # ... and refused when its worst mode would grow more than this over the run
_static = dict(metadata=dict(static=True))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Servo:
    """The servo loop of both motors (module docstring).

    kp (2,) [N m/rad], kd (2,) [N m s/rad], ki (2,) [N m/(rad s)]: the gains per motor; rate [Hz]:
    the sample rate; rotor_inertia [kg m^2]: each motor's rotor; torque_limit [N m] (inf: none);
    fc [Hz]: the bandwidth the gains were set from (nan: gains given). Static: ``feedforward`` (one
    of ``FEEDFORWARDS``) and ``delay`` (the torque computed at a sample is applied one sample later).
    A pytree: its arrays may be traced (vmapped over, differentiated)."""

    kp: jax.Array
    kd: jax.Array
    ki: jax.Array
    rate: jax.Array
    rotor_inertia: jax.Array
    torque_limit: jax.Array
    fc: jax.Array
    feedforward: str = dataclasses.field(default="rigid", **_static)
    delay: bool = dataclasses.field(default=False, **_static)

    @property
    def period(self):
        """The sample period T = 1 / rate [s]."""
        return 1.0 / self.rate

    def checked(self) -> "Servo":
        """The servo with float64 arrays; ValueError naming a bad field (before anything compiles,
        docs/conventions.md#bad-input)."""
        checks.one_of("feedforward", self.feedforward, FEEDFORWARDS)
        def pair(name, v, check):
            if np.size(v) not in (1, 2):
                raise ValueError(f"{name} must be a number or one per motor, got {v!r}")
            return np.asarray([check(name, x) for x in np.broadcast_to(np.asarray(v, dtype=float), (2,))])

        kp, kd, ki = pair("kp", self.kp, checks.positive), pair("kd", self.kd, checks.nonnegative), \
            pair("ki", self.ki, checks.nonnegative)
        rate = checks.positive("servo rate", self.rate, "Hz")
        rotor = checks.nonnegative("rotor_inertia", self.rotor_inertia, "kg m^2")
        limit = float(self.torque_limit)
        if not limit > 0:
            raise ValueError(f"torque_limit must be > 0 N m (inf: none), got {limit}")
        f = jnp.asarray
        return dataclasses.replace(self, kp=f(kp), kd=f(kd), ki=f(ki), rate=f(rate), rotor_inertia=f(rotor),
                                   torque_limit=f(limit), fc=f(float(self.fc)), delay=bool(self.delay))


def with_rotor(robot: Robot, servo: Servo) -> Robot:
    """The robot with the servo's rotor inertia on both motors."""
    return robot.replace(rotor_inertia=servo.rotor_inertia)


def rigid_inertia(robot: Robot, qa) -> jax.Array:
    """The rigid robot's joint-space inertia matrix (2, 2) [kg m^2] at the motor angles qa (2,)
    [rad], rotor included: d tau / d q'' of the rigid inverse dynamics (``rigid.rigid_torques``)."""
    zero = jnp.zeros(2)
    return jax.jacfwd(lambda qdd: rigid_torques(robot, qa, zero, qdd))(zero)


def midpoint_pose(robot: Robot, path: Path) -> jax.Array:
    """The motor angles (2,) [rad] at the path's midpoint by arc length."""
    return igm(robot, path_frame(path, 0.5 * path.length).pos)


# one program per robot shape, not eager operations (the rigid model's derivatives) at every call
_midpoint_inertia = jax.jit(lambda robot, path: jnp.mean(jnp.diag(rigid_inertia(robot, midpoint_pose(robot, path)))))


def bandwidth_gains(robot: Robot, path: Path, fc, zeta=ZETA) -> tuple:
    """(Kp, Kd) (2,) each from the closed-loop bandwidth fc [Hz] and damping ratio zeta: J the mean of
    the diagonal of ``rigid_inertia`` (the robot's rotor included) at ``midpoint_pose``,
    Kp = J (2 pi fc)^2 [N m/rad], Kd = 2 zeta J (2 pi fc) [N m s/rad], the same for both motors."""
    j = _midpoint_inertia(robot, path)
    w = 2.0 * jnp.pi * fc
    return jnp.full(2, j * w**2), jnp.full(2, 2.0 * zeta * j * w)


def servo_from_bandwidth(robot: Robot, path: Path, fc: float, *, rate: float = 8000.0, rotor_inertia: float = 0.01,
                         feedforward: str = "rigid", zeta: float = ZETA, ki: float = 0.0, delay: bool = False,
                         torque_limit: float = np.inf) -> Servo:
    """A ``Servo`` with the default gain rule (``bandwidth_gains``) for the bandwidth fc [Hz], on the
    robot with this rotor inertia [kg m^2]; rate [Hz]; the other fields as ``Servo`` says."""
    fc = checks.positive("fc", fc, "Hz")
    zeta = checks.positive("zeta", zeta)
    rotor = checks.nonnegative("rotor_inertia", rotor_inertia, "kg m^2")
    kp, kd = bandwidth_gains(robot.replace(rotor_inertia=rotor), path, fc, zeta)
    return Servo(kp=kp, kd=kd, ki=jnp.full(2, float(ki)), rate=jnp.asarray(float(rate)),
                 rotor_inertia=jnp.asarray(rotor), torque_limit=jnp.asarray(float(torque_limit)),
                 fc=jnp.asarray(fc), feedforward=feedforward, delay=bool(delay)).checked()


def cycle_servo(robot: Robot, cycle, fc: float, **kwargs) -> Servo:
    """``servo_from_bandwidth`` on the cycle's paper path (Lame blends, d = e = 25 mm, n = 3): the one
    controller every trajectory of the cycle is judged with (the cycle is symmetric, so every blend's
    path has the same midpoint and the same gains). kwargs: rate, rotor_inertia, feedforward, ..."""
    return servo_from_bandwidth(robot, make_path(cycle, "lame", 0.025), fc, **kwargs)


UNITS = {"kp": "N m/rad", "kd": "N m s/rad", "ki": "N m/(rad s)", "rate": "Hz", "rotor_inertia": "kg m^2",
         "torque_limit": "N m", "fc": "Hz"}


def record(servo: Servo) -> dict:
    """The servo as a JSON-ready dict: its gains per motor, rate, rotor inertia, torque limit (None:
    none), bandwidth fc (None: gains given), feedforward kind, delay, and the units."""
    s = servo.checked()
    num = lambda v: None if not np.isfinite(float(v)) else float(v)
    return {"kp": np.asarray(s.kp).tolist(), "kd": np.asarray(s.kd).tolist(), "ki": np.asarray(s.ki).tolist(),
            "rate": float(s.rate), "rotor_inertia": float(s.rotor_inertia), "torque_limit": num(s.torque_limit),
            "fc": num(s.fc), "feedforward": s.feedforward, "delay": bool(s.delay), "units": dict(UNITS)}


@jax.jit     # one program per robot shape (its derivatives eagerly are hundreds of small ones)
def static_torque(robot: Robot, qa) -> jax.Array:
    """The motor torques (2,) [N m] that hold the robot at rest at the motor angles qa (2,) [rad]:
    the static forces (gravity, elasticity) of the full model on the motor coordinates at its
    static equilibrium with the motors there (``model.static_equilibrium``). The flexible
    feedforward's value in the dwell (the rigid one's is the rigid robot's, ``rigid.rigid_torques``
    at rest)."""
    qe = mdl.static_equilibrium(robot, qa)
    zero = jnp.zeros(2 + qe.shape[0])
    return mdl.reduced(robot, qa, qe, zero[:2], zero[2:]).force[:2]


def feedforward_advance(servo: Servo) -> jax.Array:
    """The time advance [s] of the flexible feedforward: half a sample period, one more period with
    the one-sample delay. The torque held over a period is then the model's torque at the period's
    middle, within O(T^2) of its mean over the period, instead of its value at the period's start
    (an O(T) error: the perfect controller's torque holds the links' vibration reaction, which the
    hold would delay by half a period and feed back into the modes; docs/conventions.md#servo)."""
    return (0.5 + float(bool(servo.delay))) / servo.rate


@jax.jit     # one program per robot shape (its derivatives eagerly are hundreds of small ones)
def rest_linearization(robot: Robot, qa) -> tuple:
    """The robot at rest at the motor angles qa (2,) [rad], linearized about its static equilibrium
    under gravity (q_e*, motors held at qa) in z = [q_a - qa, q_e - q_e*] (2 + ne): (M, C, K) with
    M z'' + C z' + K z = [u; 0], u (2,) the change of the motor torques [N m]."""
    qe = mdl.static_equilibrium(robot, qa)
    ne = qe.shape[0]
    zero = jnp.zeros(2 + ne)

    def force(x):            # the reduced force at rest-perturbed states, and (aux) the mass matrix
        red = mdl.reduced(robot, qa + x[:2], qe + x[2:2 + ne], x[2 + ne:4 + ne], x[4 + ne:])
        return red.force, red.mass

    jac, mass = jax.jacfwd(force, has_aux=True)(jnp.concatenate([zero, zero]))
    return mass, jac[:, 2 + ne:], jac[:, :2 + ne]


def sampled_loop(robot: Robot, servo: Servo, qa) -> jax.Array:
    """The sampled closed loop's transition matrix over one period at rest at the motor angles qa:
    x_{k+1} = P x_k with x = [z, z'] (and the held torque with a delay), the plant integrated
    exactly over the sample-and-hold (``rest_linearization``, matrix exponential), u_k = -Kp
    z_a - Kd z_a' (the integral term's state is left out: Ki only moves the slow poles). ``robot``
    must carry the servo's rotor (``with_rotor``)."""
    mass, damping, stiffness = rest_linearization(robot, qa)
    n = mass.shape[0]
    minv = jnp.linalg.inv(mass)
    # velocities scaled by 1/w (w the stiffness scale) so that the exponential's argument is of
    # the order of the highest frequency times T, not its square
    w = jnp.sqrt(jnp.max(jnp.abs(jnp.diag(minv @ stiffness))))
    a = jnp.block([[jnp.zeros((n, n)), w * jnp.eye(n)], [-minv @ stiffness / w, -minv @ damping]])
    b = jnp.concatenate([jnp.zeros((n, 2)), minv[:, :2] / w])
    t = servo.period
    aug = jnp.zeros((2 * n + 2, 2 * n + 2)).at[:2 * n, :2 * n].set(a * t).at[:2 * n, 2 * n:].set(b * t)
    e = jax.scipy.linalg.expm(aug)
    phi, gamma = e[:2 * n, :2 * n], e[:2 * n, 2 * n:]
    gain = jnp.zeros((2, 2 * n)).at[:, :2].set(jnp.diag(servo.kp)).at[:, n:n + 2].set(jnp.diag(servo.kd) * w)
    if not servo.delay:
        return phi - gamma @ gain
    return jnp.block([[phi, gamma], [-gain, jnp.zeros((2, 2))]])


_sampled_loop = jax.jit(sampled_loop)      # one program per model shape, not eager operations per call
_pose_at = jax.jit(lambda robot, path, s: igm(robot, path_frame(path, s * path.length).pos))


def sampled_radius(robot: Robot, servo: Servo, qa) -> float:
    """The spectral radius of ``sampled_loop`` (> 1: the loop is unstable there)."""
    return float(np.max(np.abs(np.linalg.eigvals(np.asarray(_sampled_loop(robot, servo, jnp.asarray(qa)))))))


def check_stable(robot: Robot, servo: Servo, path: Path, duration: float | None = None, points: int = 5,
                 strict: bool = False) -> float:
    """Refuse (ValueError) a servo whose sampled loop is unstable at rest at any of ``points`` poses
    equally spaced in arc length along the path: with ``strict``, a spectral radius above 1; else a
    worst mode that would grow more than ``GROWTH_LIMIT``-fold over ``duration`` [s] (module
    docstring; None: strict). Returns the largest spectral radius found. The robot gets the servo's
    rotor."""
    r = with_rotor(robot, servo)
    rate = float(servo.rate)
    worst, where = 0.0, 0.0
    for s in np.linspace(0.0, 1.0, points):
        qa = _pose_at(r, path, jnp.asarray(s))
        radius = sampled_radius(r, servo, qa)
        if radius > worst:
            worst, where = radius, s * float(path.length)
    growth = float(np.exp(min(np.log(worst) * rate * duration, 700.0))) if duration is not None else np.inf
    if worst > 1.0 + STABILITY_TOL and (strict or duration is None or growth > GROWTH_LIMIT):
        fc = float(servo.fc)
        which = f"fc {fc:g} Hz" if np.isfinite(fc) else f"kp {np.asarray(servo.kp).tolist()}"
        over = "" if duration is None else f", its worst mode growing {growth:.3g}-fold over {duration:g} s"
        raise ValueError(f"servo unstable: {which} at {rate:g} Hz sampling with a {float(servo.rotor_inertia):g} "
                         f"kg m^2 rotor has a sampled-loop spectral radius {worst:.6f} > 1 at arc length "
                         f"{where:.4f} m (payload {float(robot.payload):g} kg){over}; lower fc or raise the rate "
                         "(docs/conventions.md#servo)")
    return worst
