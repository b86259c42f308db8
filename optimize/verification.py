"""An independent check of a study's residual claims: each trajectory simulated again with the fast
model at a quarter of its step and with the full nonlinear model (``jaxflex.reference``)."""
from __future__ import annotations

import jax

from jaxflex import checks
from jaxflex.engine import LawEvaluator
from jaxflex.metrics import metrics
from jaxflex.model_sets import model_set
from jaxflex.problem import Problem
from jaxflex.reference import DEFAULT_DT, METHODS, reference_rollout
from jaxflex.simulate import Grid


def verify(problem: Problem, trajectories: dict, method: str = "exprb3", full_dt: float | None = None) -> dict:
    """Independent check of the residual claims on the problem's robot with its one payload [kg],
    at its tf and dwell [s]: every trajectory (name -> (Path, Profile)) is re-simulated with the
    fast model on the timing's grid (None: the default grid), at a quarter of its step, and with the
    full nonlinear model (``jaxflex.reference.reference_rollout`` with ``method`` at ``full_dt``
    [s], its default step if None). Returns name -> {method: dwell residual [mm]}."""
    robot, cycle, payloads, _ = problem
    if len(payloads) != 1:
        raise ValueError(f"payloads: verify takes one payload, got {list(payloads)}")
    payload = checks.nonnegative("payload", payloads[0], "kg")
    checks.one_of("full-model method", method, METHODS)
    timing = problem.timing.checked()
    tf, dwell = timing.tf, timing.dwell
    full_dt = checks.positive("full_dt", DEFAULT_DT[method] if full_dt is None else full_dt, "s")
    r = robot.replace(payload=payload)
    g = problem._replace(timing=timing).grid()
    fine = Grid(coarse=4 * g.coarse, fine=g.fine, dwell_steps=4 * g.dwell_steps, squarings=g.squarings)
    models = model_set(robot, [payload])
    out = {name: {} for name in trajectories}
    for name, (path, law) in trajectories.items():
        ev = LawEvaluator(models, path, tf, dwell, g)          # tables built once, used on both grids
        for label, evaluator in (("fast", ev), ("fast dt/4", ev.with_grid(fine))):
            out[name][label] = float(evaluator(law)["dwell_residual_mm"][0])
    paths, laws = zip(*trajectories.values())
    ref = jax.vmap(metrics)(reference_rollout(r, list(paths), list(laws), tf, dwell, dt=full_dt, method=method))
    for i, name in enumerate(trajectories):
        out[name][f"full model {method} {full_dt:g} s"] = float(ref["dwell_residual_mm"][i])
    return out
