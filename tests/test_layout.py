"""The layers import one way: the core library (jaxflex/) imports neither the optimizers (optimize/,
installed as jaxflex.optimize) nor the experiment scripts and command line (experiments/, installed as
jaxflex.experiments); optimize/ does not import experiments/. Checked on the source (every import
statement, also those inside functions)."""
import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
FORBIDDEN = {"jaxflex": ("jaxflex.optimize", "jaxflex.experiments", "optimize", "experiments"),
             "optimize": ("jaxflex.experiments", "experiments")}


def _imports(path: pathlib.Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:                       # relative: resolve within the package
                continue
            yield node.lineno, node.module or ""
            if node.module == "jaxflex":         # from jaxflex import optimize / experiments
                for alias in node.names:
                    yield node.lineno, f"jaxflex.{alias.name}"


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_imports_go_one_way(layer):
    bad = []
    for path in sorted((ROOT / layer).rglob("*.py")):
        for line, module in _imports(path):
            if any(module == f or module.startswith(f + ".") for f in FORBIDDEN[layer]):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    assert not bad, "\n".join(bad)
