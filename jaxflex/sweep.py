"""The paper sweep: all blend x profile combinations for several cases (payload, tf), every rollout
through the evaluation engine's compiled programs (``jaxflex.engine``), metrics included.

Tables (linearization coefficients along each path, per payload) are built first; then every
rollout (blend x profile x case) runs, and the metrics of all of them in a small program.
"""
from __future__ import annotations

import dataclasses
import math
import time
import warnings
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks, engine, trees
from jaxflex.accuracy import (DWELL_ATOL_MM, DWELL_RTOL, Accuracy, coarser_grid, estimated, estimated_by_halving,
                              worst)
from jaxflex.blends import BLENDS
from jaxflex.expm import squarings_for
from jaxflex.linearized import Tables
from jaxflex.tables import coeffs_stacked, robot_table_poses, servo_path_tables
from jaxflex.tables import compile_ahead as coeffs_ahead
from jaxflex.metrics import METRICS
from jaxflex.path import check_path_args, make_path
from jaxflex.profiles import PROFILES, make_profile
from jaxflex.progress import stage
from jaxflex.robot import Robot, check_cycle_reachable, check_motion_loads
from jaxflex.engine import sample_motion
from jaxflex.servo import Servo, check_stable, with_rotor
from jaxflex.servo_simulate import servo_grid
from jaxflex.simulate import Grid, check_grid


class StepWarning(UserWarning):
    """Results that may miss the accuracy asked for: a user-given step that undersamples the dwell or
    outruns the frozen intervals (``step_warnings``, before anything runs), or runs whose estimated
    error misses the tolerance (``jaxflex.accuracy``, after them)."""


class Case(NamedTuple):
    """A simulation case: payload [kg] and motion time tf [s]."""

    payload: float
    tf: float


PAPER_CASES = (Case(6.0, 0.43), Case(0.1, 0.3))


def default_grid(robot: Robot, tfs, dwell: float, dt: float | None = None) -> Grid:
    """Grid with fine step about dt (default 1e-4 s) and enough exponential squarings
    (``step_squarings``)."""
    dt = DEFAULT_DT if dt is None else checks.positive("dt", dt, "s")
    dwell = checks.positive("dwell", dwell, "s")
    tf_max = max(checks.positives("tf", tfs, "s"))
    coarse = 8 * max(1, round(tf_max / 8 / 2.25e-3))         # ~2.25 ms frozen intervals (docs/performance.md)
    fine = max(1, math.ceil(tf_max / coarse / dt))
    dwell_steps = max(1, math.ceil(dwell / dt))
    grid = Grid(coarse=coarse, fine=fine, dwell_steps=dwell_steps)
    return grid._replace(squarings=step_squarings(robot, grid_step(grid, tf_max, dwell)))


def grid_step(grid: Grid, tf_max: float, dwell: float) -> float:
    """The longest step [s] of ``grid`` over a motion of ``tf_max`` [s] and a dwell of ``dwell`` [s]."""
    return max(tf_max / grid.steps, dwell / grid.dwell_steps)


def step_squarings(robot: Robot, h: float) -> int:
    """Squarings of the matrix exponential for steps up to h [s]: they bound ||A h|| <= 4 omega_max h
    with omega_max estimated from the highest assumed mode of a free link (the assembled robot's
    highest mode lies below twice that)."""
    c = math.sqrt(float(robot.young) / float(robot.rho))
    axial = (2 * robot.n_axial - 1) * math.pi / 2 * c / float(robot.l2)
    from jaxflex.beams import bending_roots
    ei_rho_a = math.sqrt(float(robot.young) * float(robot.second_moment) / (float(robot.rho) * float(robot.area)))
    bend = bending_roots(robot.n_bending)[-1] ** 2 / float(robot.l1) ** 2 * ei_rho_a
    extra = [0.0]                                       # the richer model's modes (jaxflex.model.richer)
    if robot.n_axial_proximal:
        extra.append((2 * robot.n_axial_proximal - 1) * math.pi / 2 * c / float(robot.l1))
    if robot.n_bending_distal:
        extra.append(bending_roots(robot.n_bending_distal)[-1] ** 2 / float(robot.l2) ** 2 * ei_rho_a)
    omega = 2.0 * max(axial, bend, *extra)
    return squarings_for(4 * omega * h)


DEFAULT_DT = 1e-4          # [s] the default fine step (``default_grid``)
SAMPLING_TOL = 0.005       # relative: the largest miss of the dwell's peak that a step may cause unwarned


def step_warnings(robot: Robot, cycle, cases: Sequence[Case], dwell: float, dt: float, grid: Grid) -> list[str]:
    """What a step dt [s] given by the user does to the grid it gives (``default_grid``), as
    messages (empty: nothing to say):

    - the dwell residual is the largest deviation over the dwell's samples, one per dwell step
      h_d; sampled that way, the first mode's oscillation (frequency f1 at the place, motors
      locked: ``modes_at_point``) can have its peak missed by up to 1 - cos(pi f1 h_d) of its
      amplitude, and entirely once h_d is half its period or more. Above ``SAMPLING_TOL`` it says
      so, with the bound;
    - the motion's steps cannot be longer than the frozen-coefficient intervals (about 2.25 ms):
      a larger dt gives steps of one interval each, not dt, and says so.

    Only the first bound is a measured error; the motion steps' own error is not estimated here
    (docs/conventions.md#metrics: the step study)."""
    from jaxflex.frequencies import modes_at_point

    out = []
    h_d = float(dwell) / grid.dwell_steps
    for case in cases:
        f1 = float(modes_at_point(robot.replace(payload=case.payload), np.asarray(cycle.place))[0])
        phase = math.pi * f1 * h_d
        miss = 1.0 if phase >= math.pi / 2 else 1.0 - math.cos(phase)
        if miss > SAMPLING_TOL:
            bound = ("can be missed entirely" if miss >= 1.0 else f"can be missed by up to {100 * miss:.3g} %")
            out.append(f"dt {dt:g} s samples the dwell every {h_d:g} s: at payload {case.payload:g} kg the first "
                       f"mode ({f1:.3g} Hz at the place) has its peak, which the dwell residual measures, {bound}; "
                       f"use dt <= {math.acos(1 - SAMPLING_TOL) / (math.pi * f1):.3g} s (default {DEFAULT_DT:g} s)")
    h = max(c.tf for c in cases) / grid.steps
    if grid.fine == 1 and dt > 1.01 * h:
        out.append(f"dt {dt:g} s is longer than the frozen-coefficient intervals: the motion runs in steps of "
                   f"{h:.3g} s (one per interval), {h / DEFAULT_DT:.3g} times the default step, with no estimate of "
                   f"their error")
    return out


def _poses(robot, cycle, d, e, n, blend):
    """Table poses, length and breaks of a blend's path (the shared compiled pose program)."""
    path = make_path(cycle, blend, d, e, n)
    return robot_table_poses(robot, path), path.length, path.breaks


def _coeffs(robot, payloads, qa, qa1, qa2):
    """Coefficients for every payload (C,) and blend: poses (B, K, 2) -> leaves (C, B, K, ...),
    through the coefficient program every table builder shares (``tables.coeffs_stacked``)."""
    shape = qa.shape[:2]
    flat = [jnp.reshape(a, (-1, 2)) for a in (qa, qa1, qa2)]
    robots = trees.stack([robot.replace(payload=m) for m in payloads], dtype=float)
    values = coeffs_stacked(robots, *flat)
    return jax.tree_util.tree_map(lambda v: v.reshape(v.shape[:1] + shape + v.shape[2:]), values)


def _sweep_series(values, breaks, lengths, tfs, dwell, robots, profiles, grid, second_order, servo_inputs=None):
    """Every rollout (blend x law x case) through the evaluation engine (``jaxflex.engine``: one
    compiled program for every run, the runs side by side on the host's cores, ``engine.run_many``),
    series stacked with leading axes (B, P, C); tables (C, B, ...). ``servo_inputs``: under a servo,
    (servo, servo tables [blend][case], schedules [case])."""
    laws = [make_profile(name) for name in profiles]
    # per-run tables and lengths sliced on the host (eager jax indexing would dispatch a small
    # program per leaf and run), then passed as device arrays like every other caller's tables
    values, breaks, lengths = jax.tree_util.tree_map(np.asarray, (values, breaks, lengths))
    jobs = []
    for i in range(breaks.shape[0]):
        tables = [Tables(values=jax.tree_util.tree_map(lambda v: jnp.asarray(v[c, i]), values),
                         breaks=jnp.asarray(breaks[i])) for c in range(len(tfs))]
        extra = [None] * len(tfs)
        if servo_inputs is not None:
            servo, servo_tables, schedules = servo_inputs
            extra = [engine.ServoJob(servo, servo_tables[i][c], schedules[c]) for c in range(len(tfs))]
        jobs += [engine.Job(tables[c], sample_motion(lengths[i], law, tfs[c], grid), tfs[c], dwell, robots[c],
                            extra[c])
                 for law in laws for c in range(len(tfs))]
    series = engine.run_many(jobs, grid, second_order)
    lead = (breaks.shape[0], len(laws), len(tfs))
    return jax.tree_util.tree_map(lambda a: a.reshape(lead + a.shape[1:]), series)


def _stacked_tables(robot, cycle, payloads, blends, d, e, n):
    poses = [_poses(robot, cycle, d, e, n, blend=b) for b in blends]
    qa, qa1, qa2 = (jnp.stack([p[0][k] for p in poses]) for k in range(3))
    return (_coeffs(robot, payloads, qa, qa1, qa2), jnp.stack([p[2] for p in poses]),
            jnp.stack([p[1] for p in poses]))


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """How ``run_sweep`` builds and runs the combinations (defaults: the paper's sweep,
    docs/conventions.md#adept-cycle-and-blends and docs/conventions.md#fast-model).

    blends, profiles: the blend families (``jaxflex.blends.BLENDS``) and motion laws
    (``jaxflex.profiles.PROFILES``); every pair is simulated for every case. d, e [m], n: the corner
    blends' parameters (e None: e = d; the paper's d = e = 25 mm, n = 3). dwell [s]: the time
    simulated after tf. grid: the rollout grid (None: ``default_grid`` for the cases' tf, with the
    step ``dt`` [s] if given). second_order (default): the full model's second-order remainder is
    added (``simulate.rollout``; every metric close to the full nonlinear model, within the tolerance
    of docs/conventions.md#fast-model); False: the linearized model. with_series: keep every rollout's
    ``Series``. repeats: sweeps timed after the first (``SweepResult.run_s`` is their median);
    timed=False: none (the results only). progress: report the stages on stderr
    (``jaxflex.progress``). servo: the motors driven by this servo loop (``jaxflex.servo.Servo``, its
    rotor on every case's robot, its feedforward computed for each case's robot; the grid refined to
    its period; docs/conventions.md#servo); None: the perfect controller (the paper's). estimate: every
    run's discretization error estimated by step doubling (``jaxflex.accuracy``; the sweep run again
    on a grid about twice coarser; under a servo, whose fine steps stay within the sample period,
    on the grid with every step halved), held to the tolerance on the dwell
    residual of ``rtol`` of it or ``atol_mm`` [mm], whichever is larger; where the default grid
    misses it, every step is halved up to ``refine`` times (a grid or dt given: never). Results that
    still miss it are warned about (``StepWarning``)."""

    blends: tuple = BLENDS
    profiles: tuple = PROFILES
    d: float = 0.025
    e: float | None = None
    n: float = 3.0
    dwell: float = 0.1
    dt: float | None = None
    grid: Grid | None = None
    second_order: bool = True
    with_series: bool = False
    repeats: int = 1
    timed: bool = True
    progress: bool = False
    servo: Servo | None = None
    estimate: bool = True
    refine: int = 2
    rtol: float = DWELL_RTOL
    atol_mm: float = DWELL_ATOL_MM

    def checked(self, cycle) -> "SweepConfig":
        """The configuration with tuples, floats and e filled in; ValueError naming a bad field
        before anything compiles (docs/conventions.md#bad-input)."""
        blends, profiles = tuple(self.blends), tuple(self.profiles)
        e = self.d if self.e is None else self.e
        dwell = checks.positive("dwell", self.dwell, "s")
        dt = None if self.dt is None else checks.positive("dt", self.dt, "s")
        repeats = checks.count("repeats", self.repeats)
        refine = checks.count("refine", self.refine, minimum=0)
        rtol = checks.positive("rtol", self.rtol, "")
        atol_mm = checks.positive("atol_mm", self.atol_mm, "mm")
        if not blends or not profiles:
            raise ValueError("blends and profiles must not be empty")
        for p in profiles:
            checks.one_of("motion profile", p, PROFILES)
        for b in blends:
            check_path_args(cycle, b, self.d, e, self.n, self.d, e, self.n)
        if self.grid is not None:
            check_grid(self.grid)
        servo = None
        if self.servo is not None:
            if not isinstance(self.servo, Servo):
                raise TypeError(f"servo must be a jaxflex.servo.Servo, got {type(self.servo).__name__}")
            servo = self.servo.checked()
        return dataclasses.replace(self, blends=blends, profiles=profiles, e=e, dwell=dwell, dt=dt, repeats=repeats,
                                   servo=servo, refine=refine, rtol=rtol, atol_mm=atol_mm)


def sweep_tables(robot: Robot, cycle, payloads: Sequence[float], blend: str,
                 config: SweepConfig = SweepConfig()) -> Tables:
    """Linearization tables of one blend's path for every payload [kg] (leaves with a leading payload
    axis K), as ``run_sweep`` with the same ``config`` builds them (its blends and d, e, n): the
    compiled table programs of that sweep are reused (no new compilation)."""
    c = config.checked(cycle)
    if blend not in c.blends:
        raise ValueError(f"blend {blend!r} is not among the sweep's blends {c.blends}")
    values, breaks, _ = _stacked_tables(robot, cycle, jnp.asarray([float(m) for m in payloads]), c.blends,
                                        *(jnp.asarray(v, dtype=float) for v in (c.d, c.e, c.n)))
    i = c.blends.index(blend)
    k = len(payloads)
    return Tables(values=jax.tree_util.tree_map(lambda v: v[:, i], values),
                  breaks=jnp.broadcast_to(breaks[i], (k,) + breaks.shape[1:]))


class SweepResult(NamedTuple):
    """Metrics dict name -> (B, P, C) arrays (blend, profile, case), optional Series with the same
    leading axes, the labels, the grid of the results, timing, and the error estimate of every
    metric (``jaxflex.accuracy.Accuracy``; None when not estimated)."""

    metrics: dict
    series: object
    blends: tuple
    profiles: tuple
    cases: tuple
    grid: Grid
    compile_s: float
    run_s: float
    tables_s: float
    accuracy: Accuracy | None = None


def run_sweep(robot: Robot, cycle, cases: Sequence[Case] = PAPER_CASES,
              config: SweepConfig = SweepConfig()) -> SweepResult:
    """Simulate every blend x profile (``config``, ``SweepConfig``) for every case (payload [kg],
    tf [s]); validate inputs first (no compilation on bad input).

    Three compiled stages, each shared with the rest of the library: the table poses (one program per
    blend family), the linearization coefficients (``tables.coeffs_many``) and the rollouts, one
    trajectory at a time through the evaluation engine (``jaxflex.engine``, from a thread per core:
    ``jaxflex.runtime.threads``, the same results as one after another), then the metrics.
    The programs compile in the background from the start (the coefficient program while the table
    poses are computed, the rollout's programs, and those of the error estimate's grid, while the
    tables are built: ``tables.compile_ahead``, ``engine.compile_ahead``), so the two cores share
    the compilation. Timing: ``tables_s`` is the wall time of the table build (compilation
    included, the rollout's beside it; the persistent compilation cache makes it short after the
    first run on a machine); ``compile_s`` the first sweep (every rollout through the engine's
    programs, and the metrics) minus one run: what remains of the rollout's compilation; ``run_s``
    the median of ``config.repeats`` sweeps after compilation. With
    ``config.timed=False`` the timed reruns are skipped when only the results are wanted (a shorter
    run): ``compile_s`` is then the first sweep's wall time (compilation and one run) and
    ``run_s`` is nan. The linearized model alone (``second_order=False``) still takes two passes,
    the second one making the coefficients continuous; ``grid=Grid(..., continuous=False)`` makes
    it one pass. With ``config.estimate`` (default) the result carries every metric's error estimate
    (``SweepResult.accuracy``), from a second sweep on a coarser grid that is not timed, and may come
    from a refined grid (``SweepConfig``).
    """
    if not isinstance(config, SweepConfig):
        raise TypeError(f"config must be a SweepConfig, got {type(config).__name__}")
    cases = tuple(Case(*c) for c in cases)
    if not cases:
        raise ValueError("no simulation cases given")
    cases = tuple(Case(checks.nonnegative("payload", c.payload, "kg"), checks.positive("tf", c.tf, "s"))
                  for c in cases)
    c = config.checked(cycle)
    blends, profiles, dwell, repeats, timed, progress = c.blends, c.profiles, c.dwell, c.repeats, c.timed, c.progress
    check_cycle_reachable(robot, cycle)
    for case in cases:
        check_motion_loads(robot.replace(payload=case.payload), cycle, case.tf)
    if c.servo is not None:
        robot = with_rotor(robot, c.servo)
    grid = c.grid or default_grid(robot, [case.tf for case in cases], dwell, c.dt)
    if c.servo is not None:
        grid = servo_grid(grid, max(case.tf for case in cases), dwell, float(c.servo.rate))
    if c.dt is not None and c.grid is None:       # before anything compiles
        for message in step_warnings(robot, cycle, cases, dwell, c.dt, grid):
            warnings.warn(message, StepWarning, stacklevel=2)
    servo_inputs = None
    if c.servo is not None:
        paths = [make_path(cycle, b, c.d, c.e, c.n) for b in blends]
        case_robots = [robot.replace(payload=case.payload) for case in cases]
        with stage("servo loop", enabled=progress) as servo_bar, \
                servo_bar.waiting("stability along the paths and the servo tables (compiling unless cached)",
                                  key="sweep-servo"):
            for path in paths:
                for r, case in zip(case_robots, cases):
                    check_stable(r, c.servo, path, case.tf + dwell)
            servo_tables = [[servo_path_tables(r, path) for r in case_robots] for path in paths]
        servo_inputs = (c.servo, servo_tables)
    # the coefficient program compiles while the table poses are computed, and the rollout's programs
    # (and those of the error estimate's grid) while the tables are built
    coeffs_ahead(robot)
    if c.servo is None:
        coarser = estimate_grid(robot, grid, max(case.tf for case in cases), dwell) if c.estimate else None
        for g in [grid] + ([coarser[0]] if coarser is not None else []):
            engine.compile_ahead(robot.replace(payload=cases[0].payload), g, c.second_order)
    payloads = jnp.asarray([case.payload for case in cases])
    d_, e_, n_ = (jnp.asarray(v, dtype=float) for v in (c.d, c.e, c.n))
    runs_total = len(blends) * len(profiles) * len(cases)
    bar = stage(f"sweep of {runs_total} rollouts", total=1 + (repeats if timed else 0), unit="sweep",
                enabled=progress)
    t0 = time.perf_counter()
    with bar.waiting("path tables (compiling unless cached)", key="sweep-tables"):
        values, breaks, lengths = _stacked_tables(robot, cycle, payloads, blends, d_, e_, n_)
        values = jax.block_until_ready(values)
    tables_s = time.perf_counter() - t0
    robots = [robot.replace(payload=case.payload) for case in cases]
    tf_list = [case.tf for case in cases]

    schedules = {}          # per grid: where the servo's samples fall in its steps (once, not per timed sweep)

    def sweep(grid):
        inputs = None
        if servo_inputs is not None:
            if grid not in schedules:
                schedules[grid] = [engine.sample_schedule(tf, dwell, grid, c.servo.rate) for tf in tf_list]
            inputs = servo_inputs + (schedules[grid],)
        series = _sweep_series(values, breaks, lengths, tf_list, dwell, robots, profiles, grid, c.second_order,
                               inputs)
        return engine.metrics_of(series), series

    def first_sweep(grid, bar):
        t0 = time.perf_counter()
        with bar.waiting("the first sweep (compiling the rollout unless cached)", key="sweep-first"):
            mets, series = jax.block_until_ready(sweep(grid))
        bar.update(note="first sweep")
        _check_finite(mets, blends, profiles, cases)
        return mets, series, time.perf_counter() - t0

    def repeated(grid, bar, mets, series, first):
        """The timed sweeps after the first: (metrics, series, compile_s, run_s)."""
        runs = []
        for _ in range(repeats if timed else 0):
            t0 = time.perf_counter()
            mets, series = jax.block_until_ready(sweep(grid))
            runs.append(time.perf_counter() - t0)
            bar.update(note="timed sweep")
        bar.close("done")
        run_s = float(np.median(runs)) if runs else float("nan")
        return mets, series, (max(first - run_s, 0.0) if runs else first), run_s

    def timed_sweeps(grid, bar):
        return repeated(grid, bar, *first_sweep(grid, bar))

    refine = c.refine if c.dt is None and c.grid is None else 0
    accuracy = None
    if c.estimate and refine:
        # the timed sweeps wait for the grid the estimate settles on (a refined grid's are its own)
        mets, series, first = first_sweep(grid, bar)
        bar.close("first sweep")
        start = grid
        accuracy, grid, mets, series, compile_s, run_s = _estimated(
            c, robot, cases, grid, mets, series, first, float("nan"), sweep, timed_sweeps, refine=refine)
        if grid == start and timed and repeats:
            bar = stage(f"sweep of {runs_total} rollouts: timed", total=repeats, unit="sweep", enabled=progress)
            mets, series, compile_s, run_s = repeated(grid, bar, mets, series, first)
    else:
        mets, series, compile_s, run_s = timed_sweeps(grid, bar)
        if c.estimate:
            accuracy, grid, mets, series, compile_s, run_s = _estimated(
                c, robot, cases, grid, mets, series, compile_s, run_s, sweep, timed_sweeps, refine=0)
    if accuracy is not None and not accuracy.met:
        idx, err, tol = worst(accuracy)
        b_, p_, k_ = idx
        who, advice = ((f"dt {c.dt:g} s", "use a smaller dt, or none to have the grid chosen for the tolerance")
                       if c.dt is not None else
                       ("the grid given", "use a finer grid, or none to have it chosen for the tolerance")
                       if c.grid is not None else
                       (f"the default grid refined {accuracy.refinements} times", "allow more refinements"))
        warnings.warn(f"{who} misses the accuracy asked for: the estimated error of the dwell residual is "
                      f"{1e3 * err:.3g} um in run {blends[b_]}/{profiles[p_]} at {cases[k_].payload:g} kg, "
                      f"tf {cases[k_].tf:g} s, above its tolerance {1e3 * tol:.3g} um (the larger of "
                      f"{100 * c.rtol:g} % of the residual and {1e6 * c.atol_mm:g} nm); {advice}",
                      StepWarning, stacklevel=2)
    return SweepResult(mets, series if c.with_series else None, blends, profiles, cases, grid,
                       compile_s, run_s, tables_s, accuracy)


def estimate_grid(robot: Robot, grid: Grid, tf: float, dwell: float):
    """The coarser grid the error estimate compares ``grid`` with, and its step ratio
    (``accuracy.coarser_grid``, the exponential's squarings set by ``robot`` for the longer steps),
    or None; tf the (longest) motion time and dwell the dwell [s]."""
    return coarser_grid(grid, step_squarings(robot, 2 * grid_step(grid, tf, dwell)))


def _estimated(c, robot, cases, grid, mets, series, compile_s, run_s, sweep, timed_sweeps, refine):
    """The error estimate of a sweep's metrics (``jaxflex.accuracy.estimated``): the same sweep on the
    coarser grid and, where the dwell residual misses its tolerance and ``refine`` allows, timed
    sweeps on refined grids; under a servo (``accuracy.estimated_by_halving``) the same sweep on the
    grid with every step halved, whose results are taken where the first grid's miss the tolerance.
    Returns the accuracy and the final grid's results."""
    t_start = time.perf_counter()
    if c.servo is not None:
        # the fine and dwell steps stay within the sample period: compared with every step halved
        outs = {}

        def halved(g):
            with stage("error estimate", enabled=c.progress) as bar, \
                    bar.waiting("the sweep on a grid with every step halved (compiling unless cached)",
                                key="sweep-estimate"):
                outs[g] = jax.block_until_ready(sweep(g))
            _check_finite(outs[g][0], c.blends, c.profiles, cases)
            return outs[g][0]

        acc, _ = estimated_by_halving(halved, grid, mets, refine=refine, rtol=c.rtol, atol_mm=c.atol_mm)
        if acc.grid != grid:        # the results of a finer grid: timed as the first grid's were
            bar = stage("refined grid: every step halved to meet the tolerance",
                        total=1 + (c.repeats if c.timed else 0), unit="sweep", enabled=c.progress)
            out = timed_sweeps(acc.grid, bar) if c.timed else outs[acc.grid] + (compile_s, float("nan"))
            grid, (mets, series, compile_s, run_s) = acc.grid, out
        return (acc._replace(seconds=time.perf_counter() - t_start), grid, mets, series, compile_s, run_s)
    coarser = estimate_grid(robot, grid, max(case.tf for case in cases), c.dwell)
    if coarser is None:
        raise ValueError(f"the grid {tuple(grid)[:3]} has no coarser grid to estimate its error with; "
                         "use a finer grid or SweepConfig(estimate=False)")
    last = {"grid": grid, "out": (mets, series, compile_s, run_s)}

    def evaluate(g):
        with stage("error estimate", enabled=c.progress) as bar, \
                bar.waiting(f"the sweep on a grid {coarser[1]:.2g}x coarser (compiling unless cached)",
                            key="sweep-estimate"):
            m, _ = jax.block_until_ready(sweep(g))
        _check_finite(m, c.blends, c.profiles, cases)
        return m

    def refined(g):
        bar = stage("refined grid: every step halved to meet the tolerance", total=1 + (c.repeats if c.timed else 0),
                    unit="sweep", enabled=c.progress)
        last["grid"], last["out"] = g, timed_sweeps(g, bar)
        return last["out"][0]

    acc, _ = estimated(evaluate, grid, mets, coarser, refine=refine, rtol=c.rtol, atol_mm=c.atol_mm, refined=refined)
    return (acc._replace(seconds=time.perf_counter() - t_start), last["grid"]) + last["out"]


def _check_finite(mets, blends, profiles, cases):
    for name, v in mets.items():
        bad = np.argwhere(~np.isfinite(v))
        if bad.size:
            b, p, c = bad[0]
            raise FloatingPointError(
                f"non-finite {name} in run blend={blends[b]}, profile={profiles[p]}, payload="
                f"{cases[c].payload:g} kg, tf={cases[c].tf:g} s")


def results_table(res: SweepResult, case_index: int) -> list[dict]:
    """Per-run records (the 'results' entries of ``jaxflex sweep --json``, docs/conventions.md#file-formats)
    for one case: the metrics and, when estimated, their error estimates (``error_estimate``, in the
    metrics' units) and the dwell residual's tolerance [mm]."""
    out = []
    for i, b in enumerate(res.blends):
        for j, p in enumerate(res.profiles):
            rec = {"blend": b, "profile": p}
            rec.update({k: float(res.metrics[k][i, j, case_index]) for k in METRICS})
            if res.accuracy is not None:
                rec["error_estimate"] = {k: float(res.accuracy.errors[k][i, j, case_index]) for k in METRICS}
                rec["dwell_residual_tolerance_mm"] = float(res.accuracy.tolerance_mm[i, j, case_index])
            out.append(rec)
    return out


def accuracy_record(acc: Accuracy | None) -> dict | None:
    """The sweep's accuracy as a JSON-ready dict (``jaxflex sweep --json``'s ``accuracy``), None if
    not estimated."""
    if acc is None:
        return None
    method = ("step doubling: |m - m_coarser| / (r - 1)" if acc.ratio > 1 else
              "step halving: |m - m_finer| / (1 - r), every step of the comparison r = 1/2 of the results'")
    return {"method": method, "rtol": acc.rtol, "atol_mm": acc.atol_mm,
            "met": acc.met, "ratio": acc.ratio, "refinements": acc.refinements, "seconds": acc.seconds,
            "grid": acc.grid._asdict(), "compared_with": acc.compared_with._asdict(),
            "max_estimate_over_tolerance": float(np.max(acc.errors["dwell_residual_mm"] / acc.tolerance_mm))}
