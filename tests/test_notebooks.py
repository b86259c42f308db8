"""The research notebooks (experiments/notebooks: jupytext percent scripts and their .ipynb twins)
run in a Jupyter kernel in quick mode, as a user opens them.

Each twin is executed by nbclient in a real kernel (ipykernel), in order. The kernels read and write
the test session's persistent compilation cache, so the programs the first notebook compiles (their
quick modes share one robot, grid and sweep shape) load in the next. Each must finish, show its
figures inline (image outputs in the executed notebook), write its figures and summary to the output
directory, and report finite numbers."""
import json
import math
import os
import pathlib

import pytest

NOTEBOOKS = pathlib.Path(__file__).resolve().parents[1] / "experiments" / "notebooks"

FIGURES = {
    "tour": ("motion_laws.png", "error.png", "error_all_laws.png", "torques.png"),
    "vibration_study": ("bars.png", "dwell_histories.png"),
    "optimize_new_payload": ("paper_sweep.png", "law.png", "history.png", "comparison.png"),
}


def _numbers(tree):
    """Every int/float leaf of a JSON-like tree (bools excluded)."""
    if isinstance(tree, dict):
        for v in tree.values():
            yield from _numbers(v)
    elif isinstance(tree, (list, tuple)):
        for v in tree:
            yield from _numbers(v)
    elif isinstance(tree, (int, float)) and not isinstance(tree, bool):
        yield tree


@pytest.mark.xdist_group("notebooks")          # one worker: the notebooks share their compiled programs
@pytest.mark.parametrize("name", list(FIGURES))
def test_notebook_runs_in_quick_mode(name, tmp_path, monkeypatch):
    import nbclient
    import nbformat

    monkeypatch.setenv("JAXFLEX_QUICK", "1")
    monkeypatch.setenv("JAXFLEX_NB_OUT", str(tmp_path))
    if os.environ.get("JAXFLEX_CACHE_DIR"):               # the session's cache (conftest), read by jax itself
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", os.environ["JAXFLEX_CACHE_DIR"])
        monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
    monkeypatch.delenv("MPLBACKEND", raising=False)       # the kernel's own: inline
    nb = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
    nbclient.NotebookClient(nb, timeout=900, kernel_name="python3",
                            resources={"metadata": {"path": str(NOTEBOOKS)}}).execute()
    images = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if "image/png" in o.get("data", {})]
    assert len(images) >= len(FIGURES[name]), f"{name}: {len(images)} inline figures"
    out = tmp_path / name
    for fig in FIGURES[name]:
        path = out / fig
        assert path.is_file() and path.stat().st_size > 1000, f"{name}: missing figure {fig}"
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["quick"] is True
    numbers = list(_numbers(summary))
    assert numbers and all(math.isfinite(v) for v in numbers), f"{name}: non-finite numbers in its summary"
    if name == "tour":
        m = summary["metrics"]
        assert m["max_torque_nm"] > 1.0 and m["dwell_residual_mm"] > 0.0
    elif name == "vibration_study":
        runs = len(summary["blends"]) * len(summary["profiles"]) * len(summary["cases"])
        assert len(summary["records"]) == runs
        assert all(r["dwell_residual_mm"] > 0 for r in summary["records"])
    else:
        assert set(summary["laws"]) >= {"optimized"} and len(summary["laws"]) >= 2
        assert summary["steps_run"] >= 1 and len(summary["coef"]) >= 2
        assert summary["laws"]["optimized"]["dwell_residual_mm"] > 0


def test_notebook_twins_match_their_scripts():
    """Each notebook script has its Jupyter twin (.ipynb: the same cells as jupytext reads from the
    script, no outputs) checked in, in step with the script (``python experiments/notebooks/pair.py``
    rewrites them), and the scripts force a non-interactive backend only outside a kernel, so that
    a kernel displays the figures inline."""
    import importlib.util

    import nbformat

    spec = importlib.util.spec_from_file_location("pair", NOTEBOOKS / "pair.py")
    pair = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pair)
    assert set(pair.NOTEBOOKS) == set(FIGURES)
    for name in pair.NOTEBOOKS:
        twin = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
        script = pair.twin(name)
        cells = lambda nb: [(c.cell_type, c.source) for c in nb.cells]
        assert cells(twin) == cells(script), f"{name}.ipynb is out of date: run python experiments/notebooks/pair.py"
        assert all(not c.get("outputs") for c in twin.cells if c.cell_type == "code")
        assert any(c.cell_type == "markdown" for c in twin.cells)
        code = "".join(c.source for c in twin.cells if c.cell_type == "code")
        assert 'if "ipykernel" not in sys.modules' in code and "show=True" in code
