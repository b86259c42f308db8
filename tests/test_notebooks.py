"""The research notebooks (experiments/notebooks, jupytext percent scripts) run headless in quick mode.

They run in this process (``runpy.run_path``), in order, so that they share their compiled programs
with each other (their quick modes use one robot, grid and sweep shape): the first one pays the table
and rollout compilations, the optimization notebook adds its gradient. Each must finish, write its
figures and summary to the output directory, and report finite numbers."""
import json
import math
import pathlib
import runpy

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
    monkeypatch.setenv("JAXFLEX_QUICK", "1")
    monkeypatch.setenv("JAXFLEX_NB_OUT", str(tmp_path))
    ns = runpy.run_path(str(NOTEBOOKS / f"{name}.py"), run_name="__main__")
    out = tmp_path / name
    for fig in FIGURES[name]:
        path = out / fig
        assert path.is_file() and path.stat().st_size > 1000, f"{name}: missing figure {fig}"
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((out / "summary.json").read_text())
    assert summary == json.loads(json.dumps(ns["summary"]))
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
    """Each notebook script has its Jupyter twin (.ipynb: same cells, no outputs) checked in, in step
    with the script (``python experiments/notebooks/pair.py`` rewrites them), and a Jupyter kernel
    displays the figures inline (the scripts force a non-interactive backend only outside a kernel)."""
    import importlib.util
    import json

    spec = importlib.util.spec_from_file_location("pair", NOTEBOOKS / "pair.py")
    pair = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pair)
    assert set(pair.NOTEBOOKS) == set(FIGURES)
    for name in pair.NOTEBOOKS:
        script = (NOTEBOOKS / f"{name}.py").read_text()
        twin = json.loads((NOTEBOOKS / f"{name}.ipynb").read_text())
        assert twin == pair.notebook(script), f"{name}.ipynb is out of date: run python experiments/notebooks/pair.py"
        assert twin["nbformat"] == 4 and any(c["cell_type"] == "markdown" for c in twin["cells"])
        code = "".join("".join(c["source"]) for c in twin["cells"] if c["cell_type"] == "code")
        assert 'if "ipykernel" not in sys.modules' in code and "show=True" in code
