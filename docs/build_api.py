"""Build the API reference (HTML, from the docstrings) with pdoc: ``python docs/build_api.py [OUT]``
writes it to OUT (default ``docs/api``; open ``OUT/index.html``). Needs the ``docs`` extra
(``pip install -e ".[docs]"``); the test suite builds it too (tests/test_docs.py)."""
from __future__ import annotations

import importlib
import os
import pkgutil
import sys
from pathlib import Path

PACKAGES = ("jaxflex", "jaxflex.optimize", "jaxflex.experiments")


def modules() -> list[str]:
    """Every module of the three installed packages (the notebooks' scripts excepted)."""
    out = []
    for name in PACKAGES:
        pkg = importlib.import_module(name)
        out.append(name)
        out += [m.name for m in pkgutil.walk_packages(pkg.__path__, prefix=name + ".")
                if ".notebooks" not in m.name and m.name not in PACKAGES]
    return sorted(set(out))


def build(out) -> Path:
    """Write the reference to ``out``; returns its index page."""
    os.environ.setdefault("JAX_ENABLE_X64", "1")
    os.environ.setdefault("MPLBACKEND", "Agg")
    import pdoc

    # no highlighted source under each function: the reference is the docstrings (the source is in the
    # repository), and highlighting it was about half of the build's time
    pdoc.render.configure(docformat="restructuredtext", footer_text="jaxflex API reference", show_source=False)
    out = Path(out)
    pdoc.pdoc(*modules(), output_directory=out)
    return out / "index.html"


if __name__ == "__main__":
    print(build(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parent / "api"))
