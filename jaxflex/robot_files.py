"""Robots, cycles and servo settings as plain dicts and TOML files.

A robot file holds a ``[robot]`` table (the ``make_robot`` arguments, SI units) and, optionally, a
``[servo]`` table (the settings of the servo loop, docs/conventions.md#servo); a cycle file a
``[cycle]`` table (pick, place, lift height and direction). ``examples/paper_robot.toml`` and
``examples/paper_cycle.toml`` are the paper's. Every key is checked: an unknown one (a typo) is an
error naming the keys allowed, and values go through ``make_robot`` and ``make_cycle``, which check
them before anything compiles (reachability and the model's range are checked where the robot
meets its cycle).

Reading uses the standard library (``tomllib``); ``to_toml`` writes the flat tables these files
hold (numbers, strings, booleans, lists of numbers).
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path as FilePath
from typing import Any, NamedTuple

import numpy as np

from jaxflex.path import Cycle, make_cycle
from jaxflex.robot import Robot, cycle_preset, make_robot, robot_preset

# [robot] keys -> their unit, for the written file's comments and the errors
ROBOT_KEYS = {
    "l1": "proximal link length [m]", "l2": "distal link length [m]",
    "diameter": "solid round section's diameter [m]", "rho": "density [kg/m^3]",
    "young": "Young's modulus [Pa]", "a": "half distance between the motors [m]",
    "payload": "end-effector point mass [kg]", "rotor_inertia": "rotor inertia of each motor [kg m^2]",
    "gravity": "gravity vector (x, y) [m/s^2]", "damping": "Rayleigh damping (alpha [1/s], beta [s])",
    "working_modes": "working mode of each arm, +1 or -1", "assembly": "assembly mode, +1 or -1",
    "reference_point": "a pose (x, y) [m] that fixes the assembly mode (e.g. the pick point)",
    "n_bending": "assumed bending modes of each proximal link", "n_axial": "assumed axial modes of each distal link",
}
SERVO_KEYS = {
    "fc": "closed-loop bandwidth of the default gain rule [Hz]", "rate": "sample rate [Hz]",
    "feedforward": "none, rigid or flexible", "zeta": "damping ratio of the gain rule",
    "delay": "one-sample delay (true/false)", "torque_limit": "torque limit [N m]",
    "ki": "integral gain [N m/(rad s)]",
}
CYCLE_KEYS = {
    "pick": "pick point (x, y) [m]", "place": "place point (x, y) [m]", "h": "lift height [m]",
    "lift": "unit lift direction (x, y), perpendicular to place - pick",
}


class RobotFile(NamedTuple):
    """A robot file's content: the robot and the servo settings (a dict of ``SERVO_KEYS``, None
    without a ``[servo]`` table)."""

    robot: Robot
    servo: dict | None


class Setup(NamedTuple):
    """What a run is about: the robot, its cycle, a name for records (the preset's, or the files'),
    and the robot file's servo settings (None: none given)."""

    robot: Robot
    cycle: Cycle
    name: str
    servo: dict | None = None


def setup(preset: str = "default", robot_file=None, cycle_file=None, pick=None, place=None,
          h: float | None = None) -> Setup:
    """The robot and cycle of a run. The cycle: ``cycle_file``, else the Adept cycle from ``pick`` to
    ``place`` (x, y) [m] with lift height ``h`` [m] (0.025 by default) perpendicular to the
    traverse, on the side of the preset cycle's lift, else the preset's cycle. The robot: ``robot_file`` (its assembly mode, if the file
    does not state it, from the cycle's pick point), else the preset's robot. Reachability of the
    cycle and the model's range are checked by the runs."""
    base = cycle_preset(preset)
    if cycle_file is not None:
        if pick is not None or place is not None or h is not None:
            raise ValueError("give the move either as a cycle file or as pick, place and lift, not both")
        cycle = load_cycle(cycle_file)
    elif pick is not None or place is not None:
        if pick is None or place is None:
            raise ValueError("give both the pick and the place point (x, y) [m]")
        t = np.asarray(place, dtype=float) - np.asarray(pick, dtype=float)
        normal = np.array([-t[1], t[0]]) / max(np.linalg.norm(t), 1e-300)    # the lift: perpendicular to the traverse
        normal = normal if normal @ np.asarray(base.lift) >= 0 else -normal  # on the preset's side
        cycle = make_cycle(pick, place, h=0.025 if h is None else h, lift=normal)
    elif h is not None:
        cycle = make_cycle(np.asarray(base.pick), np.asarray(base.place), h=h, lift=np.asarray(base.lift))
    else:
        cycle = base
    servo = None
    if robot_file is not None:
        robot, servo = load_robot(robot_file, reference_point=np.asarray(cycle.pick))
        name = FilePath(robot_file).name
    else:
        robot, name = robot_preset(preset), preset
    if cycle is not base:
        name += " / " + (FilePath(cycle_file).name if cycle_file is not None else
                         "pick ({:g}, {:g}) place ({:g}, {:g}) lift {:g}".format(
                             *np.asarray(cycle.pick), *np.asarray(cycle.place), float(np.asarray(cycle.h))))
    return Setup(robot, cycle, name, servo)


def _checked_keys(table: dict, allowed: dict, what: str) -> dict:
    if not isinstance(table, dict):
        raise ValueError(f"{what} must be a table of keys, got {type(table).__name__}")
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise ValueError(f"unknown {what} key(s) {', '.join(unknown)}; allowed: {', '.join(allowed)}")
    return dict(table)


def robot_to_dict(robot: Robot) -> dict:
    """The ``[robot]`` table of a robot (concrete, unbatched values): every ``ROBOT_KEYS`` entry but
    ``reference_point`` (the assembly mode is stored as such). ``robot_from_dict`` inverts it."""
    v = lambda x: float(np.asarray(x))
    return {"l1": v(robot.l1), "l2": v(robot.l2), "diameter": v(robot.diameter), "rho": v(robot.rho),
            "young": v(robot.young), "a": v(robot.a), "payload": v(robot.payload),
            "rotor_inertia": v(robot.rotor_inertia), "gravity": [float(g) for g in np.asarray(robot.gravity)],
            "damping": [float(d) for d in np.asarray(robot.damping)], "working_modes": list(robot.modes),
            "assembly": int(robot.assembly), "n_bending": int(robot.n_bending), "n_axial": int(robot.n_axial)}


def robot_from_dict(table: dict, reference_point=None) -> Robot:
    """A robot from a ``[robot]`` table (``ROBOT_KEYS``; missing keys take ``make_robot``'s defaults,
    the paper's Table 3 links). The assembly mode comes from ``assembly``, else from the table's
    ``reference_point``, else from ``reference_point`` given here (the cycle's pick point)."""
    t = _checked_keys(table, ROBOT_KEYS, "[robot]")
    if "working_modes" in t:
        t["modes"] = t.pop("working_modes")
    if "reference_point" not in t and "assembly" not in t:
        if reference_point is None:
            raise ValueError("the [robot] table needs assembly (+1/-1) or reference_point (x, y), or a cycle "
                             "whose pick point fixes the assembly mode")
        t["reference_point"] = [float(x) for x in np.asarray(reference_point)]
    return make_robot(**t)


def cycle_to_dict(cycle: Cycle) -> dict:
    """The ``[cycle]`` table of a cycle; ``cycle_from_dict`` inverts it."""
    vec = lambda x: [float(c) for c in np.asarray(x)]
    return {"pick": vec(cycle.pick), "place": vec(cycle.place), "h": float(np.asarray(cycle.h)),
            "lift": vec(cycle.lift)}


def cycle_from_dict(table: dict) -> Cycle:
    """A cycle from a ``[cycle]`` table (``CYCLE_KEYS``; ``pick`` and ``place`` required, ``h``
    0.025 m and ``lift`` (0, 1) by default)."""
    t = _checked_keys(table, CYCLE_KEYS, "[cycle]")
    missing = [k for k in ("pick", "place") if k not in t]
    if missing:
        raise ValueError(f"the [cycle] table needs {' and '.join(missing)} (x, y) [m]")
    return make_cycle(t["pick"], t["place"], h=t.get("h", 0.025), lift=t.get("lift", (0.0, 1.0)))


def servo_settings(table: dict) -> dict:
    """The ``[servo]`` table checked (``SERVO_KEYS``; ``fc`` required)."""
    t = _checked_keys(table, SERVO_KEYS, "[servo]")
    if "fc" not in t:
        raise ValueError("the [servo] table needs fc, the closed-loop bandwidth [Hz]")
    return t


def _read(path) -> dict:
    path = FilePath(path)
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ValueError(f"no such file: {path}") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{path} is not valid TOML: {err}") from None


def load_robot(path, reference_point=None) -> RobotFile:
    """The robot (and servo settings) of the TOML file ``path``: a ``[robot]`` table, an optional
    ``[servo]`` table (``robot_from_dict``, ``servo_settings``)."""
    data = _checked_keys(_read(path), {"robot": "", "servo": "", "cycle": ""}, f"{path}: top-level")
    if "robot" not in data:
        raise ValueError(f"{path} has no [robot] table")
    servo = servo_settings(data["servo"]) if "servo" in data else None
    return RobotFile(robot_from_dict(data["robot"], reference_point), servo)


def load_cycle(path) -> Cycle:
    """The cycle of the TOML file ``path`` (a ``[cycle]`` table, ``cycle_from_dict``)."""
    data = _read(path)
    if "cycle" not in data:
        raise ValueError(f"{path} has no [cycle] table")
    return cycle_from_dict(data["cycle"])


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"TOML files hold finite numbers only, got {v}")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def to_toml(tables: dict, comments: dict | None = None) -> str:
    """TOML text of ``tables`` (table name -> flat dict of numbers, strings, booleans or lists of
    them), each key followed by its comment in ``comments`` (key -> text) when there is one."""
    comments = comments or {}
    lines = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        for key, v in table.items():
            note = comments.get(key)
            lines.append(f"{key} = {_value(v)}" + (f"    # {note}" if note else ""))
        lines.append("")
    return "\n".join(lines)


def robot_toml(robot: Robot, servo: dict | None = None) -> str:
    """A robot file's text (``load_robot`` reads it back): ``[robot]`` and, with ``servo``, ``[servo]``."""
    tables = {"robot": robot_to_dict(robot)}
    if servo is not None:
        tables["servo"] = servo_settings(servo)
    return to_toml(tables, {**ROBOT_KEYS, **SERVO_KEYS})


def cycle_toml(cycle: Cycle) -> str:
    """A cycle file's text (``load_cycle`` reads it back)."""
    return to_toml({"cycle": cycle_to_dict(cycle)}, CYCLE_KEYS)
