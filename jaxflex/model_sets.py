"""Sets of models to simulate a trajectory on: the nominal robot and its perturbations (payload,
stiffness, damping), stacked along a leading axis, each with a structured identity (``ModelId``).

Used by the evaluation engine (``jaxflex.engine.LawEvaluator``), the optimization studies' training
and evaluation sets and the robustness reports (SPEC 6).
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

import jax.numpy as jnp
import numpy as np

from jaxflex import model as mdl
from jaxflex import trees
from jaxflex.path import Cycle
from jaxflex.robot import Robot


def place_first_mode_hz(robot: Robot, cycle: Cycle) -> float:
    """First locked-motor natural frequency [Hz] at the place pose (payload included)."""
    return float(mdl.modes_at_point(robot, np.asarray(cycle.place))[0])


class ModelId(NamedTuple):
    """Which model of a set: the payload case [kg] and the factors applied to the nominal robot
    (payload, Young's modulus) and the damping ratio at the first mode (0: the robot's own)."""

    payload: float
    payload_scale: float = 1.0
    stiffness_scale: float = 1.0
    damping_ratio: float = 0.0

    @property
    def nominal(self) -> bool:
        """The nominal robot with this payload (no perturbation, no added damping)."""
        return self.payload_scale == 1.0 and self.stiffness_scale == 1.0 and self.damping_ratio == 0.0

    @property
    def label(self) -> str:
        """Readable name, e.g. '6 kg x1.1, E x0.95' (JSON, tables, figures)."""
        zeta = f", zeta {self.damping_ratio:g}" if self.damping_ratio else ""
        return f"{self.payload:g} kg x{self.payload_scale:g}, E x{self.stiffness_scale:g}{zeta}"


class ModelSet(NamedTuple):
    """K robots stacked (leading axis) and the identity (``ModelId``) of each."""

    robots: Robot
    ids: tuple

    @property
    def labels(self) -> tuple:
        return tuple(i.label for i in self.ids)

    def index(self, model: ModelId) -> int:
        """Position of a model in the set (ValueError if absent)."""
        if model not in self.ids:
            raise ValueError(f"no model {model.label!r} among {list(self.labels)}")
        return self.ids.index(model)


def model_set(robot: Robot, payloads: Sequence[float], *, stiffness=(1.0,), payload_scale=(1.0,),
              damping_ratio: float = 0.0, cycle: Cycle | None = None) -> ModelSet:
    """Every payload [kg] x Young's modulus factor x payload factor; with ``damping_ratio`` > 0 a
    stiffness-proportional (Rayleigh beta) damping giving that ratio at the first mode of the place
    pose (``cycle`` needed)."""
    robots, ids = [], []
    for m in payloads:
        for k in stiffness:
            for ps in payload_scale:
                r = robot.replace(payload=m * ps, young=robot.young * k)
                if damping_ratio > 0:
                    w1 = 2 * np.pi * place_first_mode_hz(r, cycle)
                    r = r.replace(damping=jnp.asarray([0.0, 2 * damping_ratio / w1]))
                robots.append(r)
                ids.append(ModelId(float(m), float(ps), float(k), float(damping_ratio)))
    stacked = trees.stack(robots, dtype=float)
    return ModelSet(stacked, tuple(ids))
