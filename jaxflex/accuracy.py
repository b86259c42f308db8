"""Discretization error of rollouts, estimated by step doubling, and the tolerance it is held to.

A rollout's grid (``simulate.Grid``) has three steps: the frozen-coefficient intervals H = tf /
coarse, the fine steps h = H / fine and the dwell steps h_d = dwell / dwell_steps. Every metric's
discretization error is estimated by running the same rollouts on a grid whose three steps are all
about r = 2 times longer (``coarser_grid``) and comparing:

    estimate = |m(grid) - m(coarser)| / (r - 1).

That is Richardson's estimate for a method of order one. The rollouts converge at about second
order in the three steps together (docs/conventions.md#accuracy), for which the difference
overestimates the error about threefold; the margin covers the metrics that are maxima over
samples (the dwell residual, the peak torque), whose error is not a smooth function of the step.

The tolerance (``tolerance_mm``) is on the dwell residual, the metric the designs are ranked by:
by default 0.5 % of it or 1 nm, whichever is larger. Pure functions of plain numbers and
numpy arrays: the rollouts themselves run in the caller (``jaxflex.sweep``).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxflex.simulate import Grid

DWELL_RTOL = 0.005      # relative: the default tolerance on the dwell residual ...
DWELL_ATOL_MM = 1e-6    # [mm] ... or 1 nm, whichever is larger


class Accuracy(NamedTuple):
    """The error estimate of a batch of runs (``estimate``).

    errors: metric name -> estimate, arrays shaped like the metrics, in the metric's unit;
    tolerance_mm: the dwell residual's tolerance per run [mm]; met: every run's dwell-residual
    estimate within its tolerance; grid: the grid of the results; compared_with: the coarser grid;
    ratio: its step over the results' step; rtol, atol_mm [mm]: the tolerance's two terms;
    refinements: how often the grid was refined to meet the tolerance; seconds: the wall time
    spent on the estimate and the refinements [s]."""

    errors: dict
    tolerance_mm: np.ndarray
    met: bool
    grid: Grid
    compared_with: Grid
    ratio: float
    rtol: float = DWELL_RTOL
    atol_mm: float = DWELL_ATOL_MM
    refinements: int = 0
    seconds: float = float("nan")


def tolerance_mm(dwell_residual_mm, rtol: float = DWELL_RTOL, atol_mm: float = DWELL_ATOL_MM) -> np.ndarray:
    """The dwell residual's tolerance [mm] per run: ``rtol`` of it or ``atol_mm``, whichever is larger."""
    return np.maximum(rtol * np.abs(np.asarray(dwell_residual_mm, dtype=float)), atol_mm)


def coarser_grid(grid: Grid, squarings: int) -> tuple[Grid, float] | None:
    """The grid that ``estimate`` compares ``grid`` with, and its step ratio r (>= about 1.8): the
    frozen intervals halved in number (kept a multiple of 8) and the fine steps per interval kept,
    so that H and h both grow by r, and the dwell steps divided by r; ``squarings`` are the
    exponential's for the longer steps (``sweep.step_squarings``). With fewer than 16 intervals the
    fine steps are halved instead (H then stays: that comparison misses the frozen intervals' part
    of the error). None when no coarser grid exists (8 intervals of one step)."""
    if grid.coarse >= 16:
        coarse, fine = 8 * max(1, round(grid.coarse / 16)), grid.fine
    elif grid.fine >= 2:
        coarse, fine = grid.coarse, math.ceil(grid.fine / 2)
    else:
        return None
    ratio = grid.coarse * grid.fine / (coarse * fine)
    dwell_steps = max(1, round(grid.dwell_steps / ratio))
    return grid._replace(coarse=coarse, fine=fine, dwell_steps=dwell_steps, squarings=squarings), ratio


def finer_grid(grid: Grid) -> Grid:
    """``grid`` with its frozen intervals and dwell steps doubled (every step halved): the grid a
    refinement moves to; ``coarser_grid`` of it is ``grid`` again (but for the squarings, which a
    shorter step does not need more of)."""
    return grid._replace(coarse=2 * grid.coarse, dwell_steps=2 * grid.dwell_steps)


def errors(metrics: dict, coarse_metrics: dict, ratio: float) -> dict:
    """Metric name -> |m - m_coarse| / (ratio - 1) (the module docstring's estimate), arrays."""
    return {k: np.abs(np.asarray(metrics[k]) - np.asarray(coarse_metrics[k])) / (ratio - 1.0) for k in metrics}


def estimate(metrics: dict, coarse_metrics: dict, grid: Grid, compared_with: Grid, ratio: float,
             rtol: float = DWELL_RTOL, atol_mm: float = DWELL_ATOL_MM, refinements: int = 0,
             seconds: float = float("nan")) -> Accuracy:
    """The ``Accuracy`` of ``metrics`` (run on ``grid``) from the same runs on ``compared_with``
    (``coarser_grid``, step ratio ``ratio``)."""
    errs = errors(metrics, coarse_metrics, ratio)
    tol = tolerance_mm(metrics["dwell_residual_mm"], rtol, atol_mm)
    return Accuracy(errs, tol, bool(np.all(errs["dwell_residual_mm"] <= tol)), grid, compared_with, ratio,
                    rtol, atol_mm, refinements, seconds)


def worst(acc: Accuracy) -> tuple[tuple, float, float]:
    """The run whose dwell-residual estimate is largest against its tolerance: (index, estimate
    [mm], tolerance [mm])."""
    e = np.asarray(acc.errors["dwell_residual_mm"])
    idx = np.unravel_index(int(np.argmax(e / acc.tolerance_mm)), e.shape)
    return idx, float(e[idx]), float(acc.tolerance_mm[idx])


def estimated(evaluate, grid: Grid, metrics: dict, coarser: tuple[Grid, float], *, refine: int = 0,
              rtol: float = DWELL_RTOL, atol_mm: float = DWELL_ATOL_MM, refined=None) -> tuple[Accuracy, dict]:
    """The ``Accuracy`` of ``metrics`` (runs on ``grid``) and the metrics it ends with.

    ``evaluate(grid) -> metrics`` runs the same runs on another grid; ``coarser``: (grid, step
    ratio) of ``coarser_grid``. While the dwell residual misses its tolerance and ``refine``
    allows, every step is halved (``finer_grid``) and the runs repeated there by ``refined(grid)``
    (default ``evaluate``), the previous results becoming the comparison: a comparison with a
    shorter step certifies what a too pessimistic one, outside the asymptotic range, could not."""
    refined = evaluate if refined is None else refined
    compared_with, ratio = coarser
    acc = estimate(metrics, evaluate(compared_with), grid, compared_with, ratio, rtol, atol_mm)
    refinements = 0
    while not acc.met and refinements < refine:
        refinements += 1
        previous, grid = metrics, finer_grid(grid)
        metrics = refined(grid)
        acc = estimate(metrics, previous, grid, acc.grid, 2.0, rtol, atol_mm, refinements)
    return acc, metrics


def estimated_by_halving(evaluate, grid: Grid, metrics: dict, *, refine: int = 0, rtol: float = DWELL_RTOL,
                         atol_mm: float = DWELL_ATOL_MM) -> tuple[Accuracy, dict]:
    """The ``Accuracy`` of ``metrics`` (runs on ``grid``) where no uniformly coarser grid exists, and
    the metrics it ends with: under a servo the fine and dwell steps stay within the sample period,
    so a coarser grid could lengthen the frozen intervals only and would miss the fine steps' part of
    the error. The runs are repeated on the grid with every step halved (``finer_grid``; ``evaluate(grid)
    -> metrics``), and the error of ``metrics`` is bounded by

        estimate = |m - m_finer| r / (r - 1),  r = 2,

    exact for a method of order one and 1.5 times the error of one of order two (the ``Accuracy``'s
    ``compared_with`` is the finer grid, its ``ratio`` 1/2). While that misses the tolerance and
    ``refine`` allows, the finer grid's results are taken, with ``estimate``'s |m_finer - m| / (r - 1)
    against the grid before (no further runs for that step), and so on."""
    finer = finer_grid(grid)
    fine = evaluate(finer)
    errs = {k: 2.0 * np.abs(np.asarray(metrics[k]) - np.asarray(fine[k])) for k in metrics}
    tol = tolerance_mm(metrics["dwell_residual_mm"], rtol, atol_mm)
    acc = Accuracy(errs, tol, bool(np.all(errs["dwell_residual_mm"] <= tol)), grid, finer, 0.5, rtol, atol_mm)
    refinements = 0
    while not acc.met and refinements < refine:
        refinements += 1
        if refinements > 1:
            finer = finer_grid(grid)
            fine = evaluate(finer)
        acc = estimate(fine, metrics, finer, grid, 2.0, rtol, atol_mm, refinements)
        grid, metrics = finer, fine
    return acc, metrics
