"""Behaviour snapshot for refactors (a refactor keeps every metric equal to 1e-9 relative): the paper sweep's
metrics (24 runs), a 3-step design optimization on the spanning set (its history) and every
evaluation of the study (nominal, perturbed, damped sets x 4 candidates), as JSON.

    python tests/scripts/behaviour_snapshot.py before.json       # on the old checkout (PYTHONPATH)
    python tests/scripts/behaviour_snapshot.py after.json
    python tests/scripts/behaviour_compare.py before.json after.json
"""
import json, sys
import jax, numpy as np
jax.config.update("jax_enable_x64", True)
import jaxflex
from jaxflex.robot import robot_preset, cycle_preset
from jaxflex.sweep import run_sweep, PAPER_CASES
from jaxflex.optimize import study as S
print(jaxflex.__file__, file=sys.stderr)
robot, cycle = robot_preset("default"), cycle_preset()
res = run_sweep(robot, cycle, PAPER_CASES)
out = {"sweep": {k: np.asarray(v).ravel().tolist() for k, v in res.metrics.items()}}
try:
    from jaxflex.optimize.config import StudyConfig as Nested
except ImportError:
    Nested = None
if Nested is not None:                       # the nested configuration
    import dataclasses
    from jaxflex.problem import Problem, Timing
    c = dataclasses.replace(Nested(), training_set="spanning", ruckig=False, absolute=False, box_samples=0,
                            richer_modes=0).with_optimizer(steps=3, progress=False).with_train(blend="lame", power=1.0)
    st = S.optimize_design(Problem(robot, cycle, (6.0,), Timing(0.43)), c)
elif hasattr(S, "StudyConfig"):
    from jaxflex.problem import Problem, Timing
    import dataclasses
    fields = {f.name for f in dataclasses.fields(S.StudyConfig)}
    old = dict(blend="lame", absolute=False, robust_power=1.0, box_samples=0, richer_modes=0)   # the old defaults
    st = S.optimize_design(Problem(robot, cycle, (6.0,), Timing(0.43)),
                           S.StudyConfig(steps=3, train="spanning", ruckig=False, progress=False,
                                         **{k: v for k, v in old.items() if k in fields}))
else:
    st = S.optimize_design(robot, cycle, (6.0,), 0.43, steps=3, train="spanning", ruckig=False, progress=False)
out["history"] = [list(map(float, h)) for h in st.result.history]
out["evals"] = {k: {n: {m: np.asarray(v).ravel().tolist() for m, v in d.items()} for n, d in e.items()}
                for k, e in st.evaluations.items()}
json.dump(out, open(sys.argv[1], "w"))
