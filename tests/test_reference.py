"""Fast formulation vs the full nonlinear model integrated by RK4 (the second, independent method).

Slow (about 12 min on 2 cores): run with ``pytest -m slow tests/test_reference.py``."""
import jax
import numpy as np
import pytest

from jaxflex.metrics import METRICS, metrics
from jaxflex.path import make_path
from jaxflex.profiles import make_profile
from jaxflex.reference import reference_rollout
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import Case, run_sweep

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("payload, tf", [(6.0, 0.43), (0.1, 0.3)])
def test_fast_matches_full_nonlinear_model_lame(payload, tf):
    """Paper cases, Lamé, all four laws; reference RK4 at 1e-6 s, where its numerical damping of the
    18.6 kHz axial mode stays near 1 % over the run (at 1e-5 s it wipes that mode out, which hides
    itself in the accelerations at tf). The second-order fast model (the default, with continuous
    coefficients) agrees within the SPEC 4 0.5 % on every metric (measured <= 0.13 %) except
    residual_acc, |e''| at tf with the ~18 kHz axial modes, held to the 2 % of single-instant values
    (measured -0.31 % at 6 kg, +0.95 % at 0.1 kg trap_1_4: the remainder, sampled every ~0.8 ms,
    cannot carry the second-order coupling of the deflection with the kHz accelerations). The
    first-order model's error, O(q_e^2) ~ 0.6 um, would be 3.6 % of trap_1_4's 17 um residual."""
    robot, cycle = robot_preset("default"), cycle_preset()
    fast = run_sweep(robot, cycle, [Case(payload, tf)], blends=("lame",), timed=False)
    path = make_path(cycle, "lame", 0.025)
    profiles = [make_profile(p) for p in fast.profiles]
    ref = reference_rollout(robot.replace(payload=payload), path, profiles, tf, 0.1, dt=1e-6)
    ref_m = jax.vmap(metrics)(ref)
    for k in METRICS:
        ours, theirs = fast.metrics[k][0, :, 0], np.asarray(ref_m[k])
        rel = np.abs(ours / theirs - 1)
        assert np.all(rel < (0.02 if k == "residual_acc" else 0.005)), (k, ours, theirs)
