"""How the optimizers run: three nested configurations, each field in one place.

``StudyConfig`` (an optimization study: the models it trains and is evaluated on, the design space)
contains a ``TrainConfig`` (one training: the objective's power, the law's order, the blend family),
which contains an ``OptimizerConfig`` (the optax loop: steps, rate, schedule, stopping, checkpoint,
progress, memo). The defaults are the robust design of docs/conventions.md#optimization. The
command line takes its defaults and choices from these classes; this module imports no JAX, so
that ``jaxflex --help`` starts at once.

    config = StudyConfig().with_optimizer(steps=100, progress=False)
    config = dataclasses.replace(StudyConfig(), training_set="nominal", box_samples=0)
"""
from __future__ import annotations

import dataclasses
import os
from typing import Callable

from jaxflex import checks
from jaxflex.names import DESIGN_BLENDS
from jaxflex.uncertainty import Box

TRAINING_SETS = ("box", "nominal", "spanning", "perturbed")
SCENARIOS = 6                      # worst-case scenario models added to the servo refinement's training set
SCENARIO_POOL = 64                 # random models of both boxes they are chosen from (with the 32 corners)
SERVO_TRAININGS = ("fixed", "corners")  # the servo refinement's fixed models: nine, or all 32 corners of both boxes
# what the servo refinement minimizes on each model: its dwell amplitude alone (the mean square over
# the dwell), or with the perfect controller's objective's vibration energy at tf beside it (how the
# first shipped designs were refined; under a servo that energy misleads), or a smooth maximum of the
# dwell amplitude ("peak", closer to the reported residual): docs/conventions.md#servo
SERVO_OBJECTIVES = ("dwell", "energy+dwell", "peak")
SERVO_LEARNING_RATE = 0.05         # Adam's rate in the servo refinement (it starts from an optimized design)
ROBUST_POWER = 8.0                  # a power mean of this order over the training models: a smooth worst case
BLEND_FAMILY = "smoothstep"         # the optimized design's default blend family (d, e per corner; G4 joins)
LAW_ORDERS = (2, 3, 4)


def dwell_residuals(aux):
    """What a training records per step beside the objective (``OptimizerConfig.monitor``): the dwell
    residual [mm] of every training model, from the objective's terms (``metrics.Terms``)."""
    return aux.metrics["dwell_residual_mm"]


@dataclasses.dataclass(frozen=True)
class OptimizerConfig:
    """How ``loop.minimize`` runs.

    steps: updates at most; learning_rate: Adam's rate [-]; decay: warm-up and cosine decay of the
    rate over ``steps`` (``loop.schedule``); patience, rel_tol: stop when the best value has not
    improved by ``rel_tol * max(1, |best|)`` for ``patience`` steps (this works for objectives on a
    log scale, whose values cross zero); target: stop when the best value falls below it;
    checkpoint: a .npz path to save to and resume from; progress: report on stderr under ``label``;
    monitor: aux -> 1-D array of numbers recorded in every history row after (step, value); memo: a
    directory of finished optimizations, loaded instead of run again when every input is the same
    (``loop.fingerprint``)."""

    steps: int = 100
    learning_rate: float = 0.05
    decay: bool = False
    patience: int = 25
    rel_tol: float = 1e-3
    target: float | None = None
    checkpoint: str | os.PathLike | None = None
    progress: bool = True
    label: str = "optimize"
    monitor: Callable | None = None
    memo: str | os.PathLike | None = None


TRAINING = OptimizerConfig(steps=100, decay=True, patience=40, label="design")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """How ``training.train_design`` and ``training.train_law`` run: the ``optimizer`` (default: Adam
    warmed up, then cosine-decayed, stopping after 40 steps without improvement; the training
    records the training models' dwell residuals at every step unless the optimizer has a monitor of
    its own), the objective's ``power`` (order of the power mean over the models,
    ``objective.combine``), the shaped law's end-factor ``order`` and the design's ``blend`` family
    (``train_design`` only)."""

    optimizer: OptimizerConfig = TRAINING
    power: float = 1.0
    order: int = 3
    blend: str = BLEND_FAMILY

    def with_optimizer(self, **changes) -> "TrainConfig":
        """This configuration with the optimizer's fields ``changes`` (e.g. steps=200, label="law")."""
        return dataclasses.replace(self, optimizer=dataclasses.replace(self.optimizer, **changes))


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """How an optimization study runs (defaults: the robust design, docs/conventions.md#optimization).

    train: the training (``TrainConfig``: the optimizer, 50 steps by default; the power mean of
    order ``ROBUST_POWER`` over the training models, a smooth worst case; the shaped law's order
    3: zero velocity, acceleration and jerk at both ends, poly7 at the start; 4: zero snap too; the
    design's blend family, default "smoothstep", G4 joins). The optimizer's progress, checkpoint and
    memo serve the whole study.

    n_coef: free coefficients of the shaped motion law; training_set: the training models ("box"
    (default): ``box.grid(payloads, box_points)``, per payload a box_points x box_points grid over E
    and the payload mass; "nominal", "spanning" or "perturbed", ``training.training_models``);
    free_path: optimize the blends too (False: the law alone on the best paper path); init: the
    starting design (None: ``training.start_design``); ruckig: include the Ruckig baseline (needs
    the optional dependency).

    absolute (default): scale every training model by the best paper combination's residual on its
    payload's nominal model; False: by that combination's residual on the same model (a relative
    objective, which follows the reference's luck).

    box: the uncertainty box (``jaxflex.uncertainty.Box``, docs/conventions.md#uncertainty-box);
    box_samples: random models of the box (seed ``box_seed``) on which every trajectory is evaluated
    after training (the "box" evaluation set; 0: none); richer_modes: modes of each kind added to
    every link of the richer validation model (``jaxflex.model.richer``; the "richer" evaluation
    set: the nominal payloads; 0: none). Neither set ever trains the design."""

    train: TrainConfig = TrainConfig(optimizer=dataclasses.replace(TRAINING, steps=50), power=ROBUST_POWER)
    n_coef: int = 6
    training_set: str = "box"
    free_path: bool = True
    init: object | None = None
    ruckig: bool = True
    absolute: bool = True
    box: Box = Box()
    box_points: int = 3
    box_samples: int = 200
    box_seed: int = 0
    richer_modes: int = 3

    def with_optimizer(self, **changes) -> "StudyConfig":
        """This configuration with the optimizer's fields ``changes`` (e.g. steps=100, progress=False)."""
        return dataclasses.replace(self, train=self.train.with_optimizer(**changes))

    def with_train(self, **changes) -> "StudyConfig":
        """This configuration with the training's fields ``changes`` (e.g. power=1.0, blend="lame")."""
        return dataclasses.replace(self, train=dataclasses.replace(self.train, **changes))

    def checked(self) -> "StudyConfig":
        """Validate the fields (before anything compiles); ValueError naming the field."""
        if not isinstance(self.train, TrainConfig) or not isinstance(self.train.optimizer, OptimizerConfig):
            raise TypeError("train must be a TrainConfig holding an OptimizerConfig, got "
                            f"{type(self.train).__name__}")
        o, t = self.train.optimizer, self.train
        checks.count("steps", o.steps, 0)
        checks.positive("learning_rate", o.learning_rate)
        checks.count("n_coef", self.n_coef, 1)
        checks.one_of("training set", self.training_set, TRAINING_SETS)
        checks.one_of("blend", t.blend, DESIGN_BLENDS)
        box = self.box.checked() if isinstance(self.box, Box) else None
        if box is None:
            raise ValueError(f"box must be a jaxflex.uncertainty.Box, got {type(self.box).__name__}")
        points = checks.count("box_points", self.box_points, 1)
        if points % 2 == 0:
            raise ValueError(f"box_points must be odd (the grid must hold the nominal model), got {points}")
        checks.count("box_samples", self.box_samples, 0)
        checks.count("box_seed", self.box_seed, 0)
        checks.count("richer_modes", self.richer_modes, 0)
        checks.positive("robust power", t.power)
        if t.order not in LAW_ORDERS:
            raise ValueError(f"law order must be 2, 3 or 4, got {t.order!r}")
        return dataclasses.replace(self, box=box)

    def record(self) -> dict:
        """The configuration as a flat JSON record (the box as its fields; no checkpoint, memo,
        monitor or initial design)."""
        o, t = self.train.optimizer, self.train
        return {"steps": o.steps, "learning_rate": o.learning_rate, "n_coef": self.n_coef, "train": self.training_set,
                "free_path": self.free_path, "ruckig": self.ruckig, "progress": o.progress, "absolute": self.absolute,
                "robust_power": t.power, "law_order": t.order, "blend": t.blend, "box": dataclasses.asdict(self.box),
                "box_points": self.box_points, "box_samples": self.box_samples, "box_seed": self.box_seed,
                "richer_modes": self.richer_modes}
