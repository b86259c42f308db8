"""Write the Jupyter twin (``.ipynb``) of each notebook script in this directory.

The notebooks are kept as "percent" scripts (``# %%`` code cells, ``# %% [markdown]`` text cells,
the jupytext convention): plain Python that runs with ``python file.py`` and diffs cleanly. Their
``.ipynb`` twins, with the same cells and no outputs, open in Jupyter as they are; run

    python experiments/notebooks/pair.py

after editing a script (the test suite checks that the twins match their scripts). Jupytext users
can open the scripts directly instead.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
NOTEBOOKS = ("tour", "vibration_study", "optimize_new_payload")


def cells(text: str) -> list[dict]:
    """The notebook cells of a percent script: the commented header block is dropped, markdown
    cells lose their leading ``# ``, trailing blank lines are trimmed."""
    lines = text.splitlines()
    if lines and lines[0].strip() == "# ---":                       # jupytext header
        end = next(i for i in range(1, len(lines)) if lines[i].strip() == "# ---")
        lines = lines[end + 1:]
    out, kind, body = [], None, []

    def flush():
        while body and not body[-1].strip():
            body.pop()
        while body and not body[0].strip():
            body.pop(0)
        if kind is not None and body:
            src = [ln[2:] if ln.startswith("# ") else ln[1:] if ln.startswith("#") else ln for ln in body] \
                if kind == "markdown" else list(body)
            out.append({"cell_type": kind, "source": src})

    for line in lines:
        if line.startswith("# %%"):
            flush()
            kind, body = ("markdown" if "[markdown]" in line else "code"), []
        elif kind is not None:
            body.append(line)
    flush()
    return out


def notebook(text: str) -> dict:
    """nbformat 4 JSON of a percent script (no outputs, Python 3 kernel)."""
    nb_cells = []
    for c in cells(text):
        source = [ln + "\n" for ln in c["source"][:-1]] + c["source"][-1:]
        cell = {"cell_type": c["cell_type"], "metadata": {}, "source": source}
        if c["cell_type"] == "code":
            cell.update(execution_count=None, outputs=[])
        nb_cells.append(cell)
    return {"cells": nb_cells,
            "metadata": {"kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
                         "language_info": {"name": "python"}},
            "nbformat": 4, "nbformat_minor": 4}


def main() -> int:
    for name in NOTEBOOKS:
        nb = notebook((HERE / f"{name}.py").read_text())
        (HERE / f"{name}.ipynb").write_text(json.dumps(nb, indent=1, ensure_ascii=False) + "\n")
        print(f"{name}.ipynb: {len(nb['cells'])} cells")
    return 0


if __name__ == "__main__":
    sys.exit(main())
