"""Sets of models to simulate a trajectory on: the nominal robot and its perturbations (payload,
stiffness, damping), stacked along a leading axis, each with a structured identity (``ModelId``).

Used by the evaluation engine (``jaxflex.engine.LawEvaluator``), the optimization studies' training
and evaluation sets and the robustness reports (docs/conventions.md#uncertainty-box).
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

import jax.numpy as jnp
import numpy as np

from jaxflex import trees
from jaxflex.frequencies import modes_at_point
from jaxflex.path import Cycle
from jaxflex.robot import Robot
from jaxflex.uncertainty import ModelId


def place_first_mode_hz(robot: Robot, cycle: Cycle) -> float:
    """First locked-motor natural frequency [Hz] at the place pose (payload included)."""
    return float(modes_at_point(robot, np.asarray(cycle.place))[0])


def build_model(model: ModelId, nominal: Robot, cycle: Cycle | None = None) -> Robot:
    """The model ``model`` (its changes) built from the ``nominal`` robot, its payload replaced by
    the model's case; ``cycle`` is needed for a damping ratio > 0 (stiffness-proportional Rayleigh
    damping with that ratio at the first mode of the place pose)."""
    host = lambda v: np.asarray(v, dtype=float)           # numpy: building a model compiles nothing
    r = nominal.replace(payload=model.payload * model.payload_scale,
                        young=host(nominal.young) * model.stiffness_scale,
                        l1=host(nominal.l1) + model.l1_delta, l2=host(nominal.l2) + model.l2_delta,
                        rotor_inertia=host(nominal.rotor_inertia) * model.rotor_scale)
    if model.damping_ratio > 0:
        if cycle is None:
            raise ValueError("a model with damping needs the cycle (its first mode at the place pose)")
        w1 = 2 * np.pi * place_first_mode_hz(r, cycle)
        r = r.replace(damping=jnp.asarray([0.0, 2 * model.damping_ratio / w1]))
    return r


class ModelSet(NamedTuple):
    """K robots stacked (leading axis) and the identity (``ModelId``) of each."""

    robots: Robot
    ids: tuple

    def singles(self) -> list[Robot]:
        """The K robots, one by one."""
        return trees.unstack(self.robots)

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
    ids = [ModelId(float(m), float(ps), float(k), float(damping_ratio))
           for m in payloads for k in stiffness for ps in payload_scale]
    return models_of(robot, ids, cycle)


def models_of(robot: Robot, ids: Sequence[ModelId], cycle: Cycle | None = None) -> ModelSet:
    """The models ``ids`` built from the nominal ``robot`` (``ModelId.robot``), stacked."""
    ids = tuple(ids)
    if not ids:
        raise ValueError("a model set needs at least one model")
    return ModelSet(trees.stack([build_model(i, robot, cycle) for i in ids], dtype=float), ids)
