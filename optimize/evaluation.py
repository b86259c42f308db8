"""What every trajectory of a study is evaluated on, and the baselines evaluated there.

``paper_sweep`` runs the paper's 12 combinations on a set of models; ``best_combination`` picks the
best. ``evaluation_sets`` are the models of a study's evaluation (nominal, perturbed: E x {0.95, 1,
1.05} and payload x {0.9, 1, 1.1}, damped at the first mode; random models of the uncertainty box;
the richer validation model, docs/conventions.md#uncertainty-box); none of them trains a design.
``baselines`` evaluates the best paper combination, its ZV/ZVD input shaping and a Ruckig
jerk-limited law on the best paper path on every set (beside the optimizer, in the study).
"""
from __future__ import annotations

import contextlib
from typing import NamedTuple

import numpy as np

from jaxflex.engine import LawEvaluator
from jaxflex.model import richer
from jaxflex.model_sets import ModelSet, model_set, models_of, place_first_mode_hz
from jaxflex.path import Cycle, make_path
from jaxflex.problem import Problem
from jaxflex.profiles import make_profile
from jaxflex.progress import Progress
from jaxflex.sweep import SweepConfig, default_grid, estimate_grid
from jaxflex.uncertainty import ModelId

from .baselines import shaper_profiles
from .config import StudyConfig
from .training import PERTURB_E, PERTURB_PAYLOAD

DAMPING_RATIO = 0.01        # the damped evaluation set: this damping ratio at the first mode


class Candidate(NamedTuple):
    """A trajectory to evaluate: the name of its path (a key of ``DesignStudy.paths``) and its law."""

    path: str
    law: object         # Profile or MotionSamples


class PaperSweep(NamedTuple):
    """The 12 paper combinations on a set of models: ``metrics`` name -> (B, P, K) arrays (blend,
    law, model), ``evaluators`` blend -> ``LawEvaluator`` of that blend's paper path (d = e = 25 mm,
    n = 3) on the models."""

    metrics: dict
    blends: tuple
    profiles: tuple
    evaluators: dict


def paper_sweep(models: ModelSet, cycle: Cycle, tf: float, config: SweepConfig) -> PaperSweep:
    """Every blend x paper law of ``config`` (``jaxflex.sweep.SweepConfig``: its blends, laws, blend
    parameters, dwell [s], grid, which must be given, and progress on stderr) on the models at motion
    time tf [s]: one table build per blend and one compiled rollout program (the evaluators') for
    every law, blend and later evaluation on the same number of models. Same model and metrics as
    ``jaxflex.sweep.run_sweep`` with that config."""
    c = config.checked(cycle)
    if c.grid is None:
        raise ValueError("paper_sweep needs the config's grid (jaxflex.sweep.default_grid gives the default one)")
    if not c.second_order:
        raise ValueError("paper_sweep runs the second-order fast model (the evaluators'): second_order=False "
                         "is run_sweep's")
    blends, profiles, dwell, grid, progress = c.blends, c.profiles, c.dwell, c.grid, c.progress
    bar = Progress(f"paper combinations on {len(models.labels)} model(s)", total=len(blends) * len(profiles),
                   unit="combination", enabled=progress)
    evaluators, runs = {}, []
    with bar:
        for b in blends:
            with bar.waiting(f"{b} path tables") if not bar.counting else contextlib.nullcontext():
                evaluators[b] = LawEvaluator(models, make_path(cycle, b, c.d, c.e, c.n), tf, dwell, grid)
            runs.append([])
            for p in profiles:
                with bar.waiting(f"{b}/{p} (compiling the rollout unless cached)") if not bar.counting \
                        else contextlib.nullcontext():
                    runs[-1].append(evaluators[b](make_profile(p)))
                bar.update(note=f"{b}/{p}")
    mets = {k: np.stack([np.stack([r[k] for r in row]) for row in runs]) for k in runs[0][0]}
    return PaperSweep(mets, blends, profiles, evaluators)


def best_combination(dwell_residual) -> tuple[int, int]:
    """(blend, law) indices of the best paper combination from dwell residuals (B, P, C): the
    smallest one, for several payloads C the smallest worst-case ratio to each payload's best."""
    dw = np.asarray(dwell_residual)
    ratio = np.max(dw / dw.min(axis=(0, 1), keepdims=True), axis=-1)
    i, j = np.unravel_index(np.argmin(ratio), ratio.shape)
    return int(i), int(j)


def evaluation_sets(problem: Problem, config: StudyConfig) -> tuple[dict, dict]:
    """(sets, grids): the models every trajectory of a study of ``problem`` is evaluated on, set name
    -> ModelSet (nominal, perturbed, damped; box and richer as ``config`` asks), and the grids of the
    sets that need another one than the problem's (the richer model's faster modes may need more
    squarings of the same steps)."""
    robot, cycle, payloads, (tf, dwell, _) = problem
    grid = problem.grid()
    sets = {
        "nominal": model_set(robot, payloads),
        "perturbed": model_set(robot, payloads, stiffness=PERTURB_E, payload_scale=PERTURB_PAYLOAD),
        "damped": model_set(robot, payloads, damping_ratio=DAMPING_RATIO, cycle=cycle),
    }
    if config.box_samples:
        sets["box"] = models_of(robot, config.box.random(payloads, config.box_samples, config.box_seed), cycle)
    grids = {}
    if config.richer_modes:
        rich = richer(robot, config.richer_modes)
        sets["richer"] = models_of(rich, [ModelId(m) for m in payloads], cycle)
        grids["richer"] = grid._replace(squarings=max(grid.squarings, default_grid(rich, [tf], dwell).squarings))
    return sets, grids


class Baselines(NamedTuple):
    """The baselines of a study and their evaluations: ``freqs`` the first locked-motor mode at the
    place pose [Hz] per payload; ``candidates`` name -> ``Candidate``; ``sets`` set name -> ``ModelSet``
    and ``grids`` the sets' own grids where they need one (``evaluation_sets``); ``evaluators`` set ->
    {"paper": LawEvaluator} (the nominal set's only for a free path); ``evaluations`` set -> candidate
    -> metrics dict name -> (K,)."""

    freqs: tuple
    candidates: dict
    sets: dict
    grids: dict
    evaluators: dict
    evaluations: dict


def baselines(cancelled, problem: Problem, config, path, best: tuple, ruckig_candidate) -> Baselines | None:
    """The baselines of ``problem`` (its timing's grid given) on the best paper path ``path`` (``best``: the
    best paper combination's (blend, law)) and their evaluations (``Baselines``): the best law, its
    input-shaped versions at the first payload's mode, then ``ruckig_candidate`` ((name, Candidate) unless
    None). None when ``cancelled`` is set (``jaxflex.runtime.threads.Beside``)."""
    robot, cycle, payloads, (tf, _, _) = problem
    blend, law = best
    freqs = tuple(place_first_mode_hz(robot.replace(payload=m), cycle) for m in payloads)
    candidates = {f"{blend}/{law} (best paper)": Candidate("paper", make_profile(law))}
    for p in shaper_profiles(law, freqs[0], tf):
        candidates[f"{blend}/{p.name}"] = Candidate("paper", p)
    if ruckig_candidate is not None:
        candidates[ruckig_candidate[0]] = ruckig_candidate[1]
    out = _paper_evaluations(cancelled, problem, config, path, candidates)
    return None if out is None else Baselines(freqs, candidates, *out)


def _paper_evaluations(cancelled, problem: Problem, config, path, candidates):
    """The evaluation sets of ``problem`` (its timing's grid given), the best paper path's evaluators on them
    and every candidate on that path (the baselines) evaluated: (sets, grids, evaluators set -> {"paper":
    LawEvaluator} (for a free path the nominal set's only, else {}), evaluations set -> candidate -> metrics).
    Stops early when ``cancelled`` is set."""
    sets, grids = evaluation_sets(problem, config)
    tf, dwell, grid = problem.timing
    evaluators, evaluations = {}, {}
    for k, s in sets.items():
        if cancelled.is_set():
            return None
        # a free path's design is evaluated along its own path, and of the paper path's tables only
        # the nominal models' are used again (``DesignStudy.series``): the other sets' are not kept
        # (built, used for every candidate and dropped in groups of models)
        keep = k == "nominal" or not config.free_path
        ev = LawEvaluator(s, path, tf, dwell, grids.get(k, grid), keep=keep)
        evaluations[k] = dict(zip(candidates, ev.metrics_many([cand.law for cand in candidates.values()])))
        evaluators[k] = {"paper": ev} if keep else {}
    return sets, grids, evaluators, evaluations


def nominal_accuracy(evaluators: dict, candidates: dict, evaluations: dict, robot, *, progress: bool = False):
    """The discretization error of every candidate's metrics on the nominal models
    (docs/conventions.md#accuracy): the same candidates along the same paths on the coarser grid
    (``jaxflex.accuracy.coarser_grid``, step doubling). ``evaluators``: path name -> the nominal
    models' ``LawEvaluator``; ``candidates``: name -> ``Candidate``; ``evaluations``: name -> their
    metrics there; ``robot`` sets the exponential's squarings for the longer steps. Returns name ->
    ``jaxflex.accuracy.Accuracy`` (arrays over the nominal models). A sampled law (Ruckig's, sampled
    on the study's grid) is sampled again on the coarser one. Where a candidate's estimate misses the
    tolerance (a comparison outside the asymptotic range can overestimate the error), its path's
    candidates are compared with every step halved instead (``accuracy.estimated_by_halving``:
    2 |m - m_finer|, 1.5 times the error of a second-order method), the results staying the grid's."""
    from jaxflex.accuracy import estimate, estimated_by_halving
    from jaxflex.simulate import MotionSamples

    from .baselines import ruckig_samples

    ev0 = next(iter(evaluators.values()))
    grid, tf, dwell = ev0.grid, float(ev0.tf), float(ev0.dwell)
    coarser = estimate_grid(robot, grid, tf, dwell)
    if coarser is None:
        raise ValueError(f"the grid {tuple(grid)[:3]} has no coarser grid to estimate its error with")
    coarse, ratio = coarser
    out = {}
    bar = Progress("error estimate of the nominal evaluations", total=len(evaluators), unit="path", enabled=progress)
    with bar:
        for key, ev in evaluators.items():
            names = [n for n, c in candidates.items() if c.path == key]
            if not names:
                continue

            def on(g, what):
                laws = [ruckig_samples(float(ev.path.length), tf, g)[0] if isinstance(candidates[n].law, MotionSamples)
                        else candidates[n].law for n in names]
                with bar.waiting(f"{key} path on {what} (compiling unless cached)"):
                    return LawEvaluator(ev.models, ev.path, tf, dwell, g).metrics_many(laws)

            ours = [{k: np.asarray(v) for k, v in evaluations[n].items()} for n in names]
            accs = [estimate(m, {k: np.asarray(c[k]) for k in m}, grid, coarse, ratio)
                    for m, c in zip(ours, on(coarse, f"a grid {ratio:.2g}x coarser"))]
            if not all(a.met for a in accs):
                finer = {}

                def halved(g):          # the path's candidates on the finer grid, run once for all of them
                    if g not in finer:
                        finer[g] = on(g, "a grid with every step halved")
                    return finer[g]

                accs = [a if a.met else estimated_by_halving(lambda g, i=i: halved(g)[i], grid, m)[0]
                        for i, (a, m) in enumerate(zip(accs, ours))]
            out.update(zip(names, accs))
            bar.update(note=key)
    return out
