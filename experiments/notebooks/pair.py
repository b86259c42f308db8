"""Write the Jupyter twin (``.ipynb``) of each notebook script in this directory, with jupytext.

The notebooks are kept as jupytext "percent" scripts (``# %%`` code cells, ``# %% [markdown]`` text
cells): plain Python that runs with ``python file.py`` and diffs cleanly. Their ``.ipynb`` twins,
with the same cells and no outputs, open in Jupyter as they are. After editing a script run

    pip install -e ".[notebooks]"          # jupytext, Jupyter's kernel
    python experiments/notebooks/pair.py

(the test suite checks that the twins match their scripts, and runs the twins in a Jupyter kernel).
``jupytext --sync`` on a script does the same from the command line.
"""
from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
NOTEBOOKS = ("tour", "vibration_study", "optimize_new_payload")


def twin(name: str):
    """The notebook (nbformat 4.4) of the script ``name``.py: its cells, no outputs, no cell ids
    (random ones would change the twin at every run)."""
    import jupytext

    nb = jupytext.read(HERE / f"{name}.py")
    nb.nbformat_minor = 4
    for cell in nb.cells:
        cell.pop("id", None)
    return nb


def main() -> int:
    import jupytext

    for name in NOTEBOOKS:
        nb = twin(name)
        jupytext.write(nb, HERE / f"{name}.ipynb", fmt="ipynb")
        print(f"{name}.ipynb: {len(nb.cells)} cells")
    return 0


if __name__ == "__main__":
    sys.exit(main())
