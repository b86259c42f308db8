"""The trajectory-design problem as two small values: what is simulated (``Problem``: the nominal
robot, the pick-and-place cycle, the payload cases) and when (``Timing``: motion time, dwell, grid).

    problem = Problem(robot_preset("default"), cycle_preset(), payloads=(6.0,), timing=Timing(tf=0.43))
    study = optimize_design(problem, StudyConfig(steps=50))

Both are NamedTuples (immutable, printable, ``_replace`` for variants such as another tf); the
model order and the optimizer's settings live in the configurations of the functions that use them.
"""
from __future__ import annotations

from typing import NamedTuple

from jaxflex import checks
from jaxflex.path import Cycle
from jaxflex.robot import Robot
from jaxflex.simulate import Grid, check_grid


class Timing(NamedTuple):
    """Motion time ``tf`` [s] from the pick to the place point, the ``dwell`` [s] simulated after it,
    and the rollout ``grid`` (None: the default grid for tf, ``jaxflex.sweep.default_grid``)."""

    tf: float = 0.43
    dwell: float = 0.1
    grid: Grid | None = None

    def checked(self) -> "Timing":
        """The timing with float tf and dwell; ValueError naming a bad field (docs/conventions.md#bad-input)."""
        tf, dwell = checks.positive("tf", self.tf, "s"), checks.positive("dwell", self.dwell, "s")
        if self.grid is not None:
            check_grid(self.grid)
        return Timing(tf, dwell, self.grid)


class Problem(NamedTuple):
    """The nominal ``robot``, the ``cycle`` (pick, place, lift, ...), the ``payloads`` [kg] (one
    design serves them all) and the ``timing``."""

    robot: Robot
    cycle: Cycle
    payloads: tuple = (6.0,)
    timing: Timing = Timing()

    def grid(self) -> Grid:
        """The rollout grid: the timing's, or the default one for its tf."""
        from jaxflex.sweep import default_grid

        t = self.timing
        return t.grid if t.grid is not None else default_grid(self.robot, [t.tf], t.dwell)
