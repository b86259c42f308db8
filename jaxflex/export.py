"""A trajectory as a motion controller is given it: ``trajectory.csv`` and ``controller.json``.

The CSV samples one design (path, law, tf) at a rate of the controller's choice (1, 4, 8, 10 kHz,
any rate): the time, the desired end-effector position, the motor angles from the rigid inverse
kinematics with their rates and accelerations, and the feedforward torque the design was optimized
with, of its kind (docs/conventions.md#servo). The JSON beside it states the controller: its gains,
sample rate, rotor inertia, feedforward kind and bandwidth, and the unit of every column
(docs/conventions.md#file-formats).
"""
from __future__ import annotations

from pathlib import Path as FilePath

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.engine import run, sample_motion
from jaxflex.files import atomic_path, write_json
from jaxflex.path import Path
from jaxflex.profiles import Profile
from jaxflex.rigid import rigid_torques
from jaxflex.robot import Robot
from jaxflex.servo import Servo, feedforward_advance, record, static_torque, with_rotor
from jaxflex.simulate import Grid
from jaxflex.tables import path_tables
from jaxflex.trajectory import check_cycle_reachable, check_tf, trajectory

COLUMNS = ("t", "x", "y", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "tau1", "tau2")
UNITS = {"t": "s", "x": "m", "y": "m", "q1": "rad", "q2": "rad", "dq1": "rad/s", "dq2": "rad/s",
         "ddq1": "rad/s^2", "ddq2": "rad/s^2", "tau1": "N m", "tau2": "N m"}
RATES_HZ = (1_000, 4_000, 8_000, 10_000)      # the rates controllers commonly take
DEFAULT_RATE_HZ = 10_000
EXPORT_DWELL = 0.1          # s: the dwell of the rollout the flexible feedforward is read from (the studies')


def sample_times(tf: float, rate: float) -> np.ndarray:
    """t = k / rate for k = 0 .. round(tf rate) [s], the last clipped to tf."""
    if not rate > 0:
        raise ValueError(f"the export rate must be > 0 Hz, got {rate}")
    t = np.arange(int(round(float(tf) * float(rate))) + 1) / float(rate)
    t[-1] = min(t[-1], float(tf))
    return t


@jax.jit
def _rigid(robot, q, qd, qdd):
    return jax.vmap(lambda a, b, c: rigid_torques(robot, a, b, c))(q, qd, qdd)


def feedforward_at(kind: str, robot: Robot, path: Path, profile: Profile, tf: float, t: np.ndarray,
                   q=None, qd=None, qdd=None, grid: Grid | None = None, advance: float = 0.0) -> np.ndarray:
    """The feedforward torque (T, 2) [N m] of kind ``kind`` at the instants t [s] of the motion:
    "none" zeros; "rigid" the rigid inverse dynamics of ``robot`` (rotor included) along the motor
    motion q, qd, qdd (T, 2); "flexible" the torque of the robot's perfect-controller rollout (the
    second-order fast model on ``grid``, default ``sweep.default_grid``) at t + ``advance`` [s]
    (``servo.feedforward_advance``: the torque a controller should hold from t), linear between the
    rollout's nodes and held at its value at tf beyond."""
    if kind == "none":
        return np.zeros((len(t), 2))
    if kind == "rigid":
        return np.asarray(_rigid(robot, jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd)))
    if kind == "flexible":
        from jaxflex.sweep import default_grid

        grid = grid or default_grid(robot, [tf], EXPORT_DWELL)
        series = run(path_tables(robot, path), sample_motion(path.length, profile, tf, grid), tf, EXPORT_DWELL, robot,
                     grid)
        nodes, tau = np.asarray(series.t), np.asarray(series.tau)
        at = np.clip(np.asarray(t) + advance, 0.0, float(tf))
        return np.column_stack([np.interp(at, nodes, tau[:, i]) for i in range(2)])
    raise ValueError(f"unknown feedforward {kind!r}; expected one of none, rigid, flexible")


_trajectory = jax.jit(trajectory)      # one program, not the path's and the IGM's operations one by one


def rest_torque(kind: str, robot: Robot, qa) -> np.ndarray:
    """The feedforward (2,) [N m] of kind ``kind`` that holds the robot at rest at the motor angles qa
    (2,) [rad]: zeros, the rigid robot's static torque, or the elastic model's
    (``servo.static_torque``). What a servo's feedforward holds through the dwell."""
    if kind == "none":
        return np.zeros(2)
    if kind == "rigid":
        zero = jnp.zeros((1, 2))
        return np.asarray(_rigid(robot, jnp.asarray(qa)[None], zero, zero))[0]
    if kind == "flexible":
        return np.asarray(static_torque(robot, jnp.asarray(qa)))
    raise ValueError(f"unknown feedforward {kind!r}; expected one of none, rigid, flexible")


def trajectory_table(robot: Robot, path: Path, profile: Profile, tf: float, rate: float = DEFAULT_RATE_HZ,
                     feedforward: str = "rigid", grid: Grid | None = None, advance: float = 0.0,
                     hold_rest: bool = False) -> np.ndarray:
    """The (T, 11) rows of ``COLUMNS`` sampled at ``rate`` [Hz] over [0, tf] [s] (``sample_times``):
    t [s], x, y [m] the desired end-effector position, q1, q2 [rad] the rigid-IGM motor angles,
    their rates [rad/s] and accelerations [rad/s^2], and the ``feedforward`` torque [N m] of the
    robot (its rotor included; ``feedforward_at`` with ``advance`` [s]).

    With ``hold_rest`` the row at tf carries the torque a servo holds from tf on, through the dwell:
    the rest torque at the place (``rest_torque``), as in the closed-loop model
    (docs/conventions.md#servo). A controller that holds the file's last row after the motion then
    holds what the design was optimized with. Without it, the row at tf is the motion's left limit,
    which for the flexible kind includes the reaction of the links' vibration at tf: a few hundredths
    of a N m which, held, move a soft servo's rest pose by micrometres."""
    t = sample_times(tf, rate)
    check_tf(tf)
    check_cycle_reachable(robot, path.cycle)
    tr = _trajectory(robot, path, profile, jnp.asarray(float(tf)), jnp.asarray(t))
    q, qd, qdd = (np.asarray(a) for a in (tr.q, tr.qd, tr.qdd))
    tau = np.array(feedforward_at(feedforward, robot, path, profile, tf, t, q, qd, qdd, grid, advance))
    if hold_rest:
        tau[t >= float(tf)] = rest_torque(feedforward, robot, q[-1])
    return np.column_stack([t, np.asarray(tr.x), q, qd, qdd, tau])


def controller_record(servo: Servo | None, rate: float, tf: float, rotor_inertia: float | None = None) -> dict:
    """The controller file's content: the servo (``servo.record``: kp, kd, ki per motor, rate,
    rotor inertia, feedforward kind, fc, units; without a servo, the perfect controller: gains null,
    feedforward "flexible", the robot's ``rotor_inertia``), the CSV's rate [Hz], tf [s], and its
    columns with their units."""
    if servo is None:
        head = {"kp": None, "kd": None, "ki": None, "rate": None, "rotor_inertia": rotor_inertia,
                "torque_limit": None, "fc": None, "feedforward": "flexible", "delay": False,
                "controller": "perfect (motor angles prescribed)"}
    else:
        head = {**record(servo), "controller": "servo"}
    return {**head, "csv_rate": float(rate), "tf": float(tf), "columns": list(COLUMNS),
            "column_units": dict(UNITS)}


def write_controller_files(directory, robot: Robot, path: Path, profile: Profile, tf: float,
                           servo: Servo | None = None, rate: float = DEFAULT_RATE_HZ, grid: Grid | None = None,
                           name: str = "trajectory") -> tuple:
    """Write ``<name>.csv`` (``trajectory_table`` at ``rate`` [Hz] with the servo's feedforward kind,
    the robot with the servo's rotor, its row at tf the rest torque the servo holds through the dwell;
    without a servo, the perfect controller's torque, "flexible")
    and the controller file beside it (``controller_record``; ``controller.json``, or
    ``<name>.controller.json`` for another name) in ``directory``, atomically. Returns both paths."""
    directory = FilePath(directory)
    robot = robot if servo is None else with_rotor(robot, servo)
    kind = "flexible" if servo is None else servo.feedforward
    advance = 0.0 if servo is None else float(feedforward_advance(servo))
    rows = trajectory_table(robot, path, profile, tf, rate, kind, grid, advance, hold_rest=servo is not None)
    csv = directory / f"{name}.csv"
    with atomic_path(csv) as tmp:
        np.savetxt(tmp, rows, delimiter=",", header=",".join(COLUMNS), comments="", fmt="%.12g")
    js = directory / ("controller.json" if name == "trajectory" else f"{name}.controller.json")
    write_json(js, controller_record(servo, rate, tf, float(robot.rotor_inertia)))
    return csv, js
