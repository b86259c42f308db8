"""Batched simulation: all blend x profile combinations for several cases (payload, tf) in one jitted
call, metrics included; optional sharding of large design batches over devices.

Tables (linearization coefficients along each path, per payload) are built first; then all
rollouts (blend x profile x case) run in one jitted call, and their metrics in a small one.
"""
from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks
from jaxflex.blends import BLENDS
from jaxflex.expm import squarings_for
from jaxflex.linearized import Tables, coeffs_many, table_poses
from jaxflex.metrics import METRICS, batch_metrics
from jaxflex.path import check_path_args, make_path
from jaxflex.profiles import PROFILES, make_profile
from jaxflex.robot import Robot, check_cycle_reachable
from jaxflex.simulate import Grid, check_grid, motion_samples, rollout


class Case(NamedTuple):
    """A simulation case: payload [kg] and motion time tf [s]."""

    payload: float
    tf: float


PAPER_CASES = (Case(6.0, 0.43), Case(0.1, 0.3))


def default_grid(robot: Robot, tfs, dwell: float, dt: float | None = None) -> Grid:
    """Grid with fine step about dt (default 1e-4 s) and enough exponential squarings.

    The squaring count bounds ||A h|| <= 4 omega_max h with omega_max estimated from the highest
    assumed mode of a free link (the assembled robot's highest mode lies below twice that)."""
    dt = 1e-4 if dt is None else checks.positive("dt", dt, "s")
    dwell = checks.positive("dwell", dwell, "s")
    tf_max = max(checks.positives("tf", tfs, "s"))
    coarse = 8 * max(1, round(tf_max / 8 / 2.25e-3))         # ~2.25 ms frozen intervals (dt study)
    fine = max(1, math.ceil(tf_max / coarse / dt))
    dwell_steps = max(1, math.ceil(dwell / dt))
    c = math.sqrt(float(robot.young) / float(robot.rho))
    axial = (2 * robot.n_axial - 1) * math.pi / 2 * c / float(robot.l2)
    from jaxflex.beams import bending_roots
    bend = bending_roots(robot.n_bending)[-1] ** 2 / float(robot.l1) ** 2 * math.sqrt(
        float(robot.young) * float(robot.second_moment) / (float(robot.rho) * float(robot.area)))
    omega = 2.0 * max(axial, bend)
    h = max(tf_max / (coarse * fine), dwell / dwell_steps)
    return Grid(coarse=coarse, fine=fine, dwell_steps=dwell_steps, squarings=squarings_for(4 * omega * h))


@functools.partial(jax.jit, static_argnames=("blend",))
def _poses(robot, cycle, d, e, n, blend):
    path = make_path(cycle, blend, d, e, n)
    return table_poses(robot, path), path.length, path.breaks


def _coeffs(robot, payloads, qa, qa1, qa2):
    """Coefficients for every payload (C,) and blend: poses (B, K, 2) -> leaves (C, B, K, ...),
    through the coefficient program every table builder shares (``linearized.coeffs_many``)."""
    shape = qa.shape[:2]
    flat = [jnp.reshape(a, (-1, 2)) for a in (qa, qa1, qa2)]
    robots = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *[robot.replace(payload=m) for m in payloads])
    values = coeffs_many(robots, *flat)
    return jax.tree_util.tree_map(lambda v: v.reshape(v.shape[:1] + shape + v.shape[2:]), values)


def _rollouts(values, breaks, lengths, tfs, dwell, robots, profiles, grid):
    """All rollouts: tables (C, B, ...) -> series with leading axes (B, P, C) (their metrics come
    from ``metrics.batch_metrics``: the rollout program is the same with or without series).

    The motion samples of every law are computed first (a cheap static loop over the laws) and
    stacked, so that a single rollout body, vmapped over blend x law x case, serves all laws: one
    copy of the rollout in the compiled program however many laws there are.
    ``robots``: the robot per case (C,) for the second-order formulation, or None (first order)."""
    def samples_of(prof):
        per_case = jax.vmap(lambda L, tf: motion_samples(L, prof, tf, grid), in_axes=(None, 0))
        return jax.vmap(per_case, in_axes=(0, None))(lengths, tfs)               # (B, C, ...)

    samples = [samples_of(make_profile(name)) for name in profiles]
    samples = jax.tree_util.tree_map(lambda *a: jnp.stack(a, axis=1), *samples)   # (B, P, C, ...)

    def one(vals, br, smp, tf, robot):
        return rollout(Tables(values=vals, breaks=br), smp, tf, dwell, grid, robot)

    per_case = jax.vmap(one, in_axes=(0, None, 0, 0, 0))                           # (C)
    per_law = jax.vmap(per_case, in_axes=(None, None, 0, None, None))              # (P)
    per_blend = jax.vmap(per_law, in_axes=(1, 0, 0, None, None))                  # (B)
    return per_blend(values, breaks, samples, tfs, robots)


_rollouts_jit = jax.jit(_rollouts, static_argnames=("profiles", "grid"))


def _rollouts_and_metrics(*args, **kw):
    series = _rollouts_jit(*args, **kw)
    return batch_metrics(series), series


def _stacked_tables(robot, cycle, payloads, blends, d, e, n):
    poses = [_poses(robot, cycle, d, e, n, blend=b) for b in blends]
    qa, qa1, qa2 = (jnp.stack([p[0][k] for p in poses]) for k in range(3))
    return (_coeffs(robot, payloads, qa, qa1, qa2), jnp.stack([p[2] for p in poses]),
            jnp.stack([p[1] for p in poses]))


def sweep_tables(robot: Robot, cycle, payloads: Sequence[float], blend: str, *, blends=BLENDS, d=0.025,
                 e=None, n=3.0) -> Tables:
    """Linearization tables of one blend's path for every payload [kg] (leaves with a leading payload
    axis K), as ``run_sweep(..., blends=blends)`` builds them: with the same ``blends`` the compiled
    table programs of a sweep are reused (no new compilation). ``d``, ``e`` [m], ``n``: the blend."""
    e = d if e is None else e
    blends = tuple(blends)
    if blend not in blends:
        raise ValueError(f"blend {blend!r} is not among the sweep's blends {blends}")
    for b in blends:
        check_path_args(cycle, b, d, e, n, d, e, n)
    values, breaks, _ = _stacked_tables(robot, cycle, jnp.asarray([float(m) for m in payloads]), blends,
                                        *(jnp.asarray(v, dtype=float) for v in (d, e, n)))
    i = blends.index(blend)
    k = len(payloads)
    return Tables(values=jax.tree_util.tree_map(lambda v: v[:, i], values),
                  breaks=jnp.broadcast_to(breaks[i], (k,) + breaks.shape[1:]))


class SweepResult(NamedTuple):
    """Metrics dict name -> (B, P, C) arrays (blend, profile, case), optional Series with the same
    leading axes, the labels, and timing."""

    metrics: dict
    series: object
    blends: tuple
    profiles: tuple
    cases: tuple
    grid: Grid
    compile_s: float
    run_s: float
    tables_s: float


def run_sweep(robot: Robot, cycle, cases: Sequence[Case] = PAPER_CASES, *, d=0.025, e=None, n=3.0,
              dwell: float = 0.1, dt: float | None = None, blends=BLENDS, profiles=PROFILES,
              grid: Grid | None = None, with_series: bool = False, repeats: int = 1,
              second_order: bool = True) -> SweepResult:
    """Simulate every blend x profile x case; validate inputs first (no compilation on bad input).

    Three jitted stages: the table poses per blend family, the linearization coefficients for every
    blend and payload (one compiled function shared by all blends), and one program with every
    rollout (vmapped over blend, law, case), then the metrics (``metrics.batch_metrics``).
    Timing: ``tables_s`` is the wall time of the first two stages (compilation included; the
    persistent compilation cache makes it short after the first run on a machine); ``compile_s``
    the rollout program's first call minus one run; ``run_s`` the median of ``repeats`` runs of
    the rollout program after compilation. ``second_order`` (default) adds the full model's
    second-order remainder (``simulate.rollout``): agreement with the full nonlinear model within
    about 0.3 % on every metric; False gives the linearized model (still two passes, the second one
    making the coefficients continuous; ``grid=Grid(..., continuous=False)`` makes it one pass).
    """
    e = d if e is None else e
    blends, profiles, cases = tuple(blends), tuple(profiles), tuple(Case(*c) for c in cases)
    if not cases:
        raise ValueError("no simulation cases given")
    cases = tuple(Case(checks.nonnegative("payload", c.payload, "kg"), checks.positive("tf", c.tf, "s"))
                  for c in cases)
    dwell = checks.positive("dwell", dwell, "s")
    if dt is not None:
        dt = checks.positive("dt", dt, "s")
    repeats = checks.count("repeats", repeats)
    if not blends or not profiles:
        raise ValueError("blends and profiles must not be empty")
    for p in profiles:
        checks.one_of("motion profile", p, PROFILES)
    for b in blends:
        check_path_args(cycle, b, d, e, n, d, e, n)
    check_cycle_reachable(robot, cycle)
    grid = grid or default_grid(robot, [c.tf for c in cases], dwell, dt)
    check_grid(grid)
    payloads = jnp.asarray([c.payload for c in cases])
    tfs = jnp.asarray([c.tf for c in cases])
    d_, e_, n_ = (jnp.asarray(v, dtype=float) for v in (d, e, n))
    t0 = time.perf_counter()
    values, breaks, lengths = _stacked_tables(robot, cycle, payloads, blends, d_, e_, n_)
    values = jax.block_until_ready(values)
    tables_s = time.perf_counter() - t0
    robots = None
    if second_order:
        robots = jax.vmap(lambda m: robot.replace(payload=m))(payloads)
    args = (values, breaks, lengths, tfs, jnp.asarray(dwell, dtype=float), robots)
    kw = dict(profiles=profiles, grid=grid)
    t0 = time.perf_counter()
    out = jax.block_until_ready(_rollouts_and_metrics(*args, **kw))
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(_rollouts_and_metrics(*args, **kw))
        runs.append(time.perf_counter() - t0)
    run_s = float(np.median(runs))
    mets = {k: np.asarray(v) for k, v in out[0].items()}
    _check_finite(mets, blends, profiles, cases)
    return SweepResult(mets, out[1] if with_series else None, blends, profiles, cases, grid, max(first - run_s, 0.0),
                       run_s, tables_s)


def _check_finite(mets, blends, profiles, cases):
    for name, v in mets.items():
        bad = np.argwhere(~np.isfinite(v))
        if bad.size:
            b, p, c = bad[0]
            raise FloatingPointError(
                f"non-finite {name} in run blend={blends[b]}, profile={profiles[p]}, payload="
                f"{cases[c].payload:g} kg, tf={cases[c].tf:g} s")


def results_table(res: SweepResult, case_index: int) -> list[dict]:
    """Per-run records (SPEC 7 'results' entries) for one case."""
    out = []
    for i, b in enumerate(res.blends):
        for j, p in enumerate(res.profiles):
            rec = {"blend": b, "profile": p}
            rec.update({k: float(res.metrics[k][i, j, case_index]) for k in METRICS})
            out.append(rec)
    return out
