"""Model sweeps over two processes joined by ``jax.distributed`` (``jaxflex.model_sweep``,
``jaxflex.runtime.distributed``): two local CPU processes of one device each against one process
with two host devices, the same mesh over the same programs, so the same results bit for bit; and
both processes hold every model's result (the gather).

Three fresh interpreters each compile the small model's rollout (the two distributed ones side by
side; the cost is in docs/performance.md)."""
import json
import os
import pathlib
import socket
import subprocess
import sys

import numpy as np

SCRIPT = pathlib.Path(__file__).parent / "scripts" / "distributed_models.py"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_give_the_single_process_results_and_both_hold_all_of_them(tmp_path):
    env = dict(os.environ, JAXFLEX_CACHE_DIR="", JAXFLEX_THREADS="1")
    flags = env.get("XLA_FLAGS", "")
    port = str(_free_port())
    out = [tmp_path / f"p{i}.json" for i in range(2)] + [tmp_path / "single.json"]
    procs = [subprocess.Popen([sys.executable, str(SCRIPT), str(i), "2", port, str(out[i])], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for i in range(2)]
    single = subprocess.Popen([sys.executable, str(SCRIPT), "0", "1", "0", str(out[2])],
                              env=dict(env, XLA_FLAGS=f"{flags} --xla_force_host_platform_device_count=2"),
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    logs = [p.communicate(timeout=600)[0] for p in procs + [single]]
    for p, log in zip(procs + [single], logs):
        assert p.returncode == 0, log[-3000:]
    p0, p1, one = (json.loads(o.read_text()) for o in out)
    assert (p0["processes"], p0["devices"], p1["process"]) == (2, 2, 1)
    assert (one["processes"], one["devices"]) == (1, 2) and p0["chunk"] == one["chunk"] == 4
    for name, values in one["metrics"].items():
        a = np.asarray(values)
        assert a.shape == (5,) and np.all(np.isfinite(a)) and np.all(a > 0), name
        assert p0["metrics"][name] == values and p1["metrics"][name] == values, name    # bit for bit
    # the models differ (E, payload, damping, lengths), so must their results: no model broadcast
    assert len(set(one["metrics"]["dwell_residual_mm"])) == 5
