"""Design sweeps shard their batch over devices: two forced CPU host devices.

Slow (about 2 min: two compilations of the design rollout in a subprocess): run with
``pytest -m slow tests/test_sharding.py``."""
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

SCRIPT = pathlib.Path(__file__).parent / "scripts" / "sharded_sweep.py"


@pytest.mark.slow
def test_design_sweep_shards_over_two_host_devices_and_matches_one_device():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAXFLEX_CACHE_DIR="")
    run = subprocess.run([sys.executable, str(SCRIPT)], env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["device_count"] == 2 and out["devices_used"] == [2, 1]
    for name, values in out["sharded"].items():
        a, b = np.asarray(values), np.asarray(out["single"][name])
        assert a.shape == (5,) and np.all(np.isfinite(a)), name
        # same program on different devices: equal up to reduction-order round-off
        np.testing.assert_allclose(a, b, rtol=1e-9, err_msg=name)
    # the designs differ, so the metrics must too (guards against broadcasting one design)
    assert np.ptp(np.asarray(out["sharded"]["residual_energy"])) > 0
