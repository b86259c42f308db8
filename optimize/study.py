"""Motion-law optimization against the paper's best combination and the industrial baselines.

``optimize_law`` is the whole study for one or several payloads at a fixed motion time:

1. the 12 paper combinations (``jaxflex.sweep``) give the best one (smallest dwell residual; for
   several payloads the smallest worst-case ratio to each payload's best) and the torque bound
   (the poly7-Lamé peak torque);
2. a shaped monotone law (``jaxflex.profiles.shaped``) on the best combination's path is optimized
   by gradient (reverse mode through the whole second-order rollout, optax Adam) on the training
   models, each normalized by the best paper law on the same model;
3. the optimized law and every baseline (best paper law, its ZV/ZVD shaping, Ruckig) are evaluated
   on the same path and models: nominal, perturbed (E x {0.95, 1.05}, payload x {0.9, 1.1}), and
   with 1 % damping at the first mode.
"""
from __future__ import annotations

import functools
import time
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.path import Cycle, make_path
from jaxflex.profiles import make_profile, shaped
from jaxflex.robot import Robot
from jaxflex.simulate import Grid
from jaxflex.sweep import Case, default_grid, run_sweep

from .baselines import LawEvaluator, model_set, place_first_mode_hz, ruckig_samples, shaper_profiles
from .loop import OptResult, minimize
from .objective import Scales, law_objective

PERTURB_E = (0.95, 1.0, 1.05)
PERTURB_PAYLOAD = (0.9, 1.0, 1.1)
DAMPING_RATIO = 0.01
TORQUE_WEIGHT = 1e3     # penalty weight on (peak torque / bound - 1)^2: 1 % excess costs 0.1


class LawStudy(NamedTuple):
    """Everything the study measured. ``evaluations[set][law]`` is a metrics dict name -> (K,)
    array over that set's models; ``sets`` maps a set name to its model labels."""

    payloads: tuple
    tf: float
    blend: str
    best_paper: str
    coef: np.ndarray
    result: OptResult
    evaluations: dict
    sets: dict
    paper: dict
    torque_bound: np.ndarray
    ruckig_limits: tuple | None
    first_mode_hz: tuple
    grid: Grid
    wall_s: float
    laws: dict                  # name -> Profile or MotionSamples (every law evaluated)
    nominal: LawEvaluator       # the nominal models' evaluator (time series: ``nominal.series(law)``)


def paper_best(robot: Robot, cycle: Cycle, payloads, tf, dwell, grid):
    """Paper sweep per payload and the best combination (blend, law) for all of them together."""
    res = run_sweep(robot, cycle, [Case(m, tf) for m in payloads], dwell=dwell, grid=grid)
    dw = res.metrics["dwell_residual_mm"]                                  # (B, P, C)
    ratio = np.max(dw / dw.min(axis=(0, 1), keepdims=True), axis=-1)       # worst over payloads
    i, j = np.unravel_index(np.argmin(ratio), ratio.shape)
    return res, res.blends[i], res.profiles[j]


def optimize_law(robot: Robot, cycle: Cycle, payloads: Sequence[float] = (6.0,), tf: float = 0.43, *,
                 dwell: float = 0.1, n_coef: int = 6, steps: int = 150, learning_rate: float = 0.05,
                 robust: bool = False, checkpoint=None, ruckig: bool = True, progress: bool = True,
                 grid: Grid | None = None) -> LawStudy:
    """Run the study (see module docstring). ``robust`` trains on the perturbed models instead of
    the nominal ones. Returns a ``LawStudy``."""
    started = time.time()
    payloads = tuple(float(m) for m in payloads)
    grid = grid or default_grid(robot, [tf], dwell)
    res, blend, law = paper_best(robot, cycle, payloads, tf, dwell, grid)
    path = make_path(cycle, blend, 0.025)
    if progress:
        print(f"best paper combination at tf = {tf:g} s for {list(payloads)} kg: {blend} / {law}", flush=True)
    sets = {
        "nominal": model_set(robot, payloads),
        "perturbed": model_set(robot, payloads, stiffness=PERTURB_E, payload_scale=PERTURB_PAYLOAD),
        "damped": model_set(robot, payloads, damping_ratio=DAMPING_RATIO, cycle=cycle),
    }
    evaluators = {k: LawEvaluator(s, path, tf, dwell, grid) for k, s in sets.items()}
    train = evaluators["perturbed" if robust else "nominal"]
    freqs = tuple(place_first_mode_hz(robot.replace(payload=m), cycle) for m in payloads)

    # baselines: the best paper law, its shaped versions (tuned to the first payload's mode), Ruckig
    laws = {f"{blend}/{law} (best paper)": make_profile(law)}
    for p in shaper_profiles(law, freqs[0], tf):
        laws[f"{blend}/{p.name}"] = p
    limits = None
    if ruckig:
        try:
            smp, limits = ruckig_samples(float(path.length), tf, grid)
            laws[f"{blend}/ruckig"] = smp
        except ImportError as err:
            if progress:
                print(f"  (Ruckig baseline skipped: {err})", flush=True)
    ref = train(laws[f"{blend}/{law} (best paper)"])
    i_lame = res.blends.index("lame") if "lame" in res.blends else 0
    torque_bound = np.asarray(res.metrics["max_torque_nm"][i_lame, res.profiles.index("poly7"), :])
    # per training model: the bound of its payload
    k_per = len(train.models.labels) // len(payloads)
    bound = jnp.asarray(np.repeat(torque_bound, k_per))
    amp_ref = ref["dwell_residual_mm"] * 1e-3
    scales = Scales(energy=jnp.asarray(ref["residual_energy"]), dwell_ms=jnp.asarray(amp_ref**2 / 2),
                    torque_bound=bound)
    result = train_law(train, path, tf, scales, jnp.ones(n_coef), steps=steps, learning_rate=learning_rate,
                       checkpoint=checkpoint, progress=progress)
    coef = np.asarray(result.params)
    laws["optimized"] = shaped(jnp.asarray(coef), name="optimized")
    evaluations = {name: {k: ev(p) for k, p in laws.items()} for name, ev in evaluators.items()}
    paper = {k: np.asarray(v) for k, v in res.metrics.items()}
    return LawStudy(payloads, tf, blend, law, coef, result, evaluations,
                    {k: s.labels for k, s in sets.items()}, paper, torque_bound, limits, freqs, grid,
                    time.time() - started, laws, evaluators["nominal"])


@functools.lru_cache(maxsize=None)
def _training_objective(grid: Grid, order: int = 3, torque_weight: float = TORQUE_WEIGHT):
    """The law objective for one grid, as one function object per grid (so that ``minimize``
    compiles once for every tf, payload set and scale of the same shapes)."""
    def f(coef, tables, length, tf, dwell, scales, robots):
        return law_objective(coef, tables, length, tf, dwell, grid, scales, order=order, robots=robots,
                             torque_weight=torque_weight)
    return f


def train_law(train: LawEvaluator, path, tf: float, scales: Scales, init, *, steps: int = 150,
              learning_rate: float = 0.05, checkpoint=None, progress: bool = True,
              patience: int = 40) -> OptResult:
    """Optimize the shaped-law coefficients (start ``init`` (m + 1,)) on the training models of
    ``train`` at motion time tf [s] with the normalization ``scales``."""
    f = _training_objective(train.grid)
    args = (train.tables, jnp.asarray(path.length), jnp.asarray(tf, dtype=float),
            jnp.asarray(train.dwell, dtype=float), scales, train.models.robots)
    return minimize(f, jnp.asarray(init, dtype=float), args=args, steps=steps, learning_rate=learning_rate,
                    checkpoint=checkpoint, patience=patience, progress=progress, label=f"law tf={tf:g}")


def verify_law(robot: Robot, cycle: Cycle, blend: str, laws: dict, payload: float, tf: float, *,
               dwell: float = 0.1, rk4_dt: float = 1e-5) -> dict:
    """Independent check of the residual claims: every law (name -> Profile) re-simulated with the
    fast model at a quarter of the default step and with the full nonlinear model by RK4 at
    ``rk4_dt`` [s]. Returns law -> {method: dwell residual [mm]}."""
    from jaxflex.metrics import metrics
    from jaxflex.reference import reference_rollout
    from jaxflex.simulate import Grid

    from .baselines import LawEvaluator, model_set

    path = make_path(cycle, blend, 0.025)
    r = robot.replace(payload=payload)
    g = default_grid(robot, [tf], dwell)
    fine = Grid(coarse=4 * g.coarse, fine=g.fine, dwell_steps=4 * g.dwell_steps, squarings=g.squarings)
    models = model_set(robot, [payload])
    out = {name: {} for name in laws}
    for label, grid in (("fast", g), ("fast dt/4", fine)):
        ev = LawEvaluator(models, path, tf, dwell, grid)
        for name, law in laws.items():
            out[name][label] = float(ev(law)["dwell_residual_mm"][0])
    ref = jax.vmap(metrics)(reference_rollout(r, path, list(laws.values()), tf, dwell, dt=rk4_dt))
    for i, name in enumerate(laws):
        out[name][f"full model RK4 {rk4_dt:g} s"] = float(ref["dwell_residual_mm"][i])
    return out
