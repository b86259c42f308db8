"""The rollouts' error estimate (``jaxflex.accuracy``): the step-doubling formula and the grids it
compares, the refinement loop on a metric of known order, and on real rollouts: the grid refined
when the default one misses the tolerance, the warning for a ``dt`` that misses it, and the
estimate against the error measured on a grid with every step four times shorter. (The CLI's
sweep checks the default grid meets it on the paper's 6 kg case: tests/test_cli.py.)"""
import math
import warnings

import numpy as np
import pytest

from jaxflex import accuracy as ac
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.simulate import Grid
from jaxflex.sweep import DEFAULT_DT, Case, StepWarning, SweepConfig, default_grid, run_sweep


def test_coarser_and_finer_grids_scale_every_step_together():
    g = Grid(coarse=192, fine=23, dwell_steps=1000, squarings=8)
    c, r = ac.coarser_grid(g, squarings=9)
    assert (c.coarse, c.fine, c.dwell_steps, c.squarings, r) == (96, 23, 500, 9, 2.0)
    assert ac.finer_grid(c)._replace(squarings=8) == g             # a refinement undoes a coarsening
    # 136 intervals (tf 0.3 s alone): 64 of them, H and h grow by 136/64, the dwell steps by as much
    c, r = ac.coarser_grid(Grid(coarse=136, fine=22, dwell_steps=1000), squarings=9)
    assert c.coarse == 64 and r == pytest.approx(136 / 64)
    assert c.dwell_steps == round(1000 / r)
    # 8 intervals: the fine steps halve instead; one step of one interval: nothing coarser
    c, r = ac.coarser_grid(Grid(coarse=8, fine=5, dwell_steps=10), squarings=9)
    assert (c.coarse, c.fine, r) == (8, 3, pytest.approx(5 / 3))
    assert ac.coarser_grid(Grid(coarse=8, fine=1, dwell_steps=10), squarings=9) is None


def test_estimate_and_tolerance_formulas():
    m = {"dwell_residual_mm": np.array([1.0, 1e-5]), "max_torque_nm": np.array([50.0, 40.0])}
    mc = {"dwell_residual_mm": np.array([1.004, 1.3e-5]), "max_torque_nm": np.array([50.5, 39.0])}
    acc = ac.estimate(m, mc, Grid(), Grid(coarse=48), 2.0)
    np.testing.assert_allclose(acc.errors["dwell_residual_mm"], [0.004, 3e-6])
    np.testing.assert_allclose(acc.errors["max_torque_nm"], [0.5, 1.0])
    # 0.5 % of the residual or 1 nm (1e-6 mm), whichever is larger
    np.testing.assert_allclose(acc.tolerance_mm, [0.005, 1e-6])
    assert not acc.met                                       # 3e-6 mm > 1 nm in the second run
    assert ac.worst(acc)[0] == (1,)
    # a ratio other than 2: the difference over r - 1
    acc = ac.estimate(m, mc, Grid(), Grid(coarse=48), 1.5)
    np.testing.assert_allclose(acc.errors["dwell_residual_mm"], [0.008, 6e-6])


def _second_order(exact=1.0, c=8000.0, tf=0.43):
    """A 'metric' m(grid) = exact + c h^2 of the grid's fine step h [s] (a second-order method)."""
    h = lambda g: tf / (g.coarse * g.fine)
    return lambda g: {"dwell_residual_mm": np.array([exact + c * h(g) ** 2])}, lambda g: c * h(g) ** 2


def test_refinement_halves_every_step_until_the_estimate_meets_the_tolerance():
    evaluate, error = _second_order()
    g = Grid(coarse=96, fine=4, dwell_steps=100)
    coarser = ac.coarser_grid(g, g.squarings)
    acc, final = ac.estimated(evaluate, g, evaluate(g), coarser, refine=5)
    assert acc.met and acc.refinements >= 1
    assert acc.grid.coarse == g.coarse * 2 ** acc.refinements and acc.compared_with.coarse == acc.grid.coarse // 2
    assert final["dwell_residual_mm"][0] == evaluate(acc.grid)["dwell_residual_mm"][0]
    # a second-order error: the estimate is 3x the error at a ratio of 2 (covers it, not 10x more)
    assert acc.errors["dwell_residual_mm"][0] == pytest.approx(3 * error(acc.grid), rel=1e-6)
    # the grid before the last refinement missed the tolerance (no refinement beyond need)
    prev = acc.grid._replace(coarse=acc.grid.coarse // 2)
    assert 3 * error(prev) > 0.005 * evaluate(prev)["dwell_residual_mm"][0]
    # no refinement allowed: reported as missed, on the grid given
    acc0, final0 = ac.estimated(evaluate, g, evaluate(g), coarser, refine=0)
    assert not acc0.met and acc0.refinements == 0 and acc0.grid == g


def test_halving_bounds_the_error_of_the_grid_given_and_takes_the_finer_results_where_it_misses():
    """The comparison under a servo (no uniformly coarser grid): the same runs with every step halved.
    On a second-order metric 2 |m - m_finer| is 1.5 times the error of m; where it misses the
    tolerance the finer grid's results are taken, with step doubling's estimate against the grid
    given (3 times their error), and no run beyond what each refinement needs."""
    evaluate, error = _second_order()
    calls = []
    counted = lambda g: calls.append(g) or evaluate(g)
    g = Grid(coarse=96, fine=4, dwell_steps=100)
    acc, final = ac.estimated_by_halving(counted, g, evaluate(g), refine=0)
    assert acc.grid == g and acc.compared_with == ac.finer_grid(g) and acc.ratio == 0.5 and calls == [ac.finer_grid(g)]
    assert acc.errors["dwell_residual_mm"][0] == pytest.approx(1.5 * error(g), rel=1e-9)
    assert not acc.met and final["dwell_residual_mm"][0] == evaluate(g)["dwell_residual_mm"][0]
    calls.clear()
    acc, final = ac.estimated_by_halving(counted, g, evaluate(g), refine=5)
    assert acc.met and acc.refinements >= 1 and len(calls) == acc.refinements       # one run per refinement
    assert acc.grid.coarse == g.coarse * 2 ** acc.refinements and acc.compared_with.coarse == acc.grid.coarse // 2
    assert acc.errors["dwell_residual_mm"][0] == pytest.approx(3 * error(acc.grid), rel=1e-6)
    assert final["dwell_residual_mm"][0] == evaluate(acc.grid)["dwell_residual_mm"][0]


@pytest.mark.xdist_group("commands")
def test_the_default_grid_refines_until_the_tolerance_is_met_and_a_given_dt_that_misses_it_is_warned():
    """The linearized model (one program per grid), Lamé/poly7 at 0.1 kg, 0.3 s, a tolerance of
    0.1 % of the dwell residual (five times tighter than the default; the default grid's estimate is
    about 0.24 %, one refinement's about a quarter of that). Without dt the default grid misses it, so every step is halved until the estimate meets it; the results come from the
    refined grid. The same step given as dt: no refinement, the results on that grid, and a
    StepWarning stating the estimate and the tolerance (the same grids: nothing compiles again).
    That estimate covers the error measured against every step quartered. (The 24 paper runs of the
    second-order model against the quartered grid: ``reproduce``'s convergence study.)"""
    robot, cycle = robot_preset("default"), cycle_preset()
    cfg = dict(blends=("lame",), profiles=("poly7",), second_order=False, timed=False, rtol=1e-3)
    res = run_sweep(robot, cycle, [Case(0.1, 0.3)], SweepConfig(refine=3, **cfg))
    acc = res.accuracy
    base = default_grid(robot, [0.3], 0.1)
    assert acc.met and acc.refinements >= 1 and res.grid.coarse == base.coarse * 2 ** acc.refinements
    assert res.grid == acc.grid and acc.errors["dwell_residual_mm"][0, 0, 0] <= acc.tolerance_mm[0, 0, 0]
    assert math.isclose(acc.rtol, 1e-3)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always", StepWarning)
        res = run_sweep(robot, cycle, [Case(0.1, 0.3)], SweepConfig(dt=DEFAULT_DT, **cfg))
    text = [str(w.message) for w in said if "misses the accuracy" in str(w.message)]
    acc = res.accuracy
    assert res.grid == base and not acc.met and acc.refinements == 0 and len(text) == 1, [str(w.message) for w in said]
    idx, err, tol = ac.worst(acc)
    assert err > tol and f"{1e3 * err:.3g} um" in text[0] and f"{1e3 * tol:.3g} um" in text[0], text
    # the estimate against the error measured on a grid with every step 4x shorter (its own error
    # about 1/16 of the default grid's): it covers it, and by a margin that is not absurd
    quarter = base._replace(coarse=4 * base.coarse, dwell_steps=4 * base.dwell_steps)
    ref = run_sweep(robot, cycle, [Case(0.1, 0.3)], SweepConfig(grid=quarter, estimate=False, **cfg))
    m = "dwell_residual_mm"
    measured = abs(res.metrics[m][0, 0, 0] - ref.metrics[m][0, 0, 0])
    estimate = acc.errors[m][0, 0, 0]
    assert measured <= estimate <= 30 * measured, (measured, estimate)


def test_the_reports_convergence_section_renders_its_tables():
    """``reproduce``'s step-convergence section (only the full run has it; ``--quick`` skips it) from
    records shaped as ``convergence.dt_study`` and ``reference_study`` write them: the dt table with
    each metric's change against its limit, the estimate's table, and the fast-against-full table.
    The full run once failed here, after hours of sections, on a removed table helper."""
    from jaxflex.experiments.report import convergence_section
    from jaxflex.metrics import METRICS

    grid = {"coarse": 192, "fine": 23, "dwell_steps": 1000}
    rows = [{"metric": m, "max_rel_change": 0.001 * (k + 1), "limit": 0.02, "worst_run": "lame/poly7/6 kg"}
            for k, m in enumerate(METRICS)]
    runs = [{"run": "lame/poly7", "payload": 6.0, "tf": 0.43, "value_mm": 0.03, "estimate_mm": 2e-5,
             "error_mm": 1e-5, "tolerance_mm": 1.5e-4}]
    estimate = {"ratio": 2.0, "met": True, "same_ranking": True, "dwell_runs": runs,
                "rows": [{"metric": m, "covered": 24, "runs": 24, "max_estimate_rel": 1e-3, "max_error_rel": 5e-4}
                         for m in METRICS]}
    dt = {"grids": {"base": grid, "quarter": {**grid, "coarse": 768, "dwell_steps": 4000}}, "rows": rows,
          "estimate": estimate}
    case = {"payload": 6.0, "tf": 0.43, "profiles": ["poly7", "bang_bang"], "reference_s": 100.0,
            "metrics": {m: {"fast": [1.0, 2.0], "full": [1.001, 2.0]} for m in METRICS}}
    reference = {"method": "exprb3", "dt": 2e-5, "cases": [case]}
    text = convergence_section({"dt": dt, "reference": reference}, {})
    assert "192 frozen intervals x 23 steps" in text and "| dwell_residual_mm |" in text
    assert "Every metric is within its limit." in text
    assert "runs with estimate >= error" in text and "Fast minus full, relative [%], 6 kg" in text
    assert "every metric within the 0.5 %" in text
