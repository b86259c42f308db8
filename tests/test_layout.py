"""The package's layers, checked on the source (every import statement, also those inside functions).

- Imports go one way: the core library (jaxflex/) imports neither the optimizers (optimize/,
  installed as jaxflex.optimize) nor the experiment scripts and command line (experiments/,
  installed as jaxflex.experiments); optimize/ does not import experiments/. The package's
  ``__init__`` is the exception by design: the public facade over every layer, resolved lazily.
- No module imports in a circle, through any chain of imports, in jaxflex/, optimize/ or
  experiments/.
- No module uses a name it never defined or imported (pyflakes): a code path the tests do not run
  (the full ``reproduce``'s report sections, say) fails there, not in a user's run.
- The physics modules are pure functions: neither they nor anything they import reaches the
  runtime (jaxflex.runtime: compiler options, compiles, threads, memo caches, heap), and they hold
  no locks, pools or compiler options of their own.
"""
import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
FORBIDDEN = {"jaxflex": ("jaxflex.optimize", "jaxflex.experiments", "optimize", "experiments"),
             "optimize": ("jaxflex.experiments", "experiments")}
LAYERS = {"jaxflex": "jaxflex", "optimize": "jaxflex.optimize", "experiments": "jaxflex.experiments"}
PHYSICS = ("model", "beams", "linearized", "rollout", "simulate", "metrics", "rigid", "path", "blends", "profiles",
           "trajectory", "workspace", "designs")
RUNTIME = "jaxflex.runtime"


def _package(path: pathlib.Path, module: str) -> str:
    """The package a module's relative imports resolve against."""
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _from_base(node: ast.ImportFrom, package: str) -> str:
    """The absolute module of a ``from ... import`` (relative ones resolved against ``package``)."""
    if not node.level:
        return node.module or ""
    parts = package.split(".")
    parts = parts[:len(parts) - node.level + 1]
    return ".".join(parts + ([node.module] if node.module else []))


def _imports(path: pathlib.Path, module: str = ""):
    """(line, absolute module name) of every import in the file (relative ones resolved against the
    module's package), and for ``from package import name`` also ``package.name``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = _package(path, module)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            base = _from_base(node, package)
            yield node.lineno, base
            for alias in node.names:
                yield node.lineno, f"{base}.{alias.name}"


def _modules() -> dict:
    """Installed module name -> file, for every module of the three layers."""
    out = {}
    for folder, name in LAYERS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT / folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            out[".".join([name] + parts)] = path
    return out


def _graph() -> dict:
    """Module -> the package modules it imports (a ``from package import name`` counts as importing
    the submodule when ``name`` is one, else the package)."""
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        deps = set()
        for _, target in _imports(path, name):
            if target in modules and target != name:
                deps.add(target)
        graph[name] = deps
    return graph


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_imports_go_one_way(layer):
    bad = []
    for path in sorted((ROOT / layer).rglob("*.py")):
        if path == ROOT / "jaxflex" / "__init__.py":
            continue                    # the public facade (lazy): every layer's names, by design
        for line, module in _imports(path):
            if any(module == f or module.startswith(f + ".") for f in FORBIDDEN[layer]):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    assert not bad, "\n".join(bad)


def _cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan), and self-imports."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_module_imports_in_a_circle():
    cycles = _cycles(_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_cycle_check_finds_a_cycle():
    """The check above can fail: a two-module loop and a longer one are reported."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"e"}, "e": {"d"}, "f": {"a"}}
    assert sorted(_cycles(graph)) == [["a", "b", "c"], ["d", "e"]]


def _reach(graph: dict, start: str) -> set:
    seen, todo = set(), [start]
    while todo:
        v = todo.pop()
        for w in graph.get(v, ()):
            if w not in seen:
                seen.add(w)
                todo.append(w)
    return seen


@pytest.mark.parametrize("name", PHYSICS)
def test_physics_modules_do_not_reach_the_runtime(name):
    """Neither the module nor anything it imports (transitively) is the runtime; it imports no
    threads or pools and sets no compiler options."""
    graph, module = _graph(), f"jaxflex.{name}"
    assert module in graph, module
    reached = sorted(m for m in _reach(graph, module) | {module} if m == RUNTIME or m.startswith(RUNTIME + "."))
    assert not reached, f"{module} reaches {reached}"
    path = ROOT / "jaxflex" / f"{name}.py"
    own = {target for _, target in _imports(path, module)}
    assert not own & {"threading", "concurrent", "concurrent.futures", "multiprocessing"}, own
    assert "compiler_options" not in path.read_text()


def test_no_module_uses_an_undefined_name():
    """Every name a module uses is defined, imported or built in (pyflakes' check, on the three
    layers and the tests); a wrong name on a path no test runs would otherwise surface only there."""
    from pyflakes import api, messages, reporter

    class Collect(reporter.Reporter):
        def __init__(self):
            self.found = []

        def flake(self, message):
            if isinstance(message, (messages.UndefinedName, messages.UndefinedLocal, messages.UndefinedExport)):
                self.found.append(str(message))

        def unexpectedError(self, filename, msg):
            self.found.append(f"{filename}: {msg}")

        def syntaxError(self, filename, msg, lineno, offset, text):
            self.found.append(f"{filename}:{lineno}: {msg}")

    out = Collect()
    for folder in ("jaxflex", "optimize", "experiments", "tests"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            api.checkPath(str(path), out)
    assert not out.found, "\n".join(out.found)


def _module_aliases(tree: ast.Module, module: str, path: pathlib.Path, modules: dict) -> dict:
    """Local name -> module name, for every package module the file binds to a name (``import a.b
    as m``, ``from . import m``, ``from jaxflex import m``; anywhere in the file)."""
    package = _package(path, module)
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname and alias.name in modules:
                    out[alias.asname] = alias.name
        elif isinstance(node, ast.ImportFrom):
            base = _from_base(node, package)
            for alias in node.names:
                full = f"{base}.{alias.name}"
                if full in modules:
                    out[alias.asname or alias.name] = full
    return out


def _missing_attributes(path: pathlib.Path, module: str, modules: dict) -> list:
    """``m.name`` reads in the file, m one of the package's modules (``_module_aliases``), whose
    module defines no ``name`` at its top level (assignment, def, class or import)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    aliases = _module_aliases(tree, module, path, modules)
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load) and isinstance(node.value, ast.Name):
            target = aliases.get(node.value.id)
            dunder = node.attr.startswith("__") and node.attr.endswith("__")       # __file__, __name__, ...
            if target and not dunder and node.attr not in _top_level(modules[target]) \
                    and f"{target}.{node.attr}" not in modules:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno} reads {target}.{node.attr}, which it does not define")
    return bad


def _top_level(path: pathlib.Path) -> set:
    names = set()
    for node in ast.parse(path.read_text(), filename=str(path)).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for t in (node.targets if isinstance(node, ast.Assign) else [node.target]):
                names |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.If, ast.Try)):
            names |= {n.name for n in ast.walk(node) if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
            names |= {n.id for n in ast.walk(node) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)}
            names |= {(a.asname or a.name).split(".")[0] for n in ast.walk(node)
                      if isinstance(n, (ast.Import, ast.ImportFrom)) for a in n.names}
    return names


def test_no_module_reads_a_name_another_module_does_not_define():
    """``module.name`` of the package's own modules names something that module defines (pyflakes
    does not check attributes): a function renamed or removed in one module while another still
    calls it, on a path no test runs (the full ``reproduce``'s report once called a removed
    table helper of the convergence study), fails here. Modules with a lazy ``__getattr__`` (the
    public facade) are not checked."""
    modules = _modules()
    lazy = {name for name, path in modules.items() if "def __getattr__" in path.read_text()}
    checked = {k: v for k, v in modules.items() if k not in lazy}
    bad = []
    for name, path in modules.items():
        bad += _missing_attributes(path, name, checked)
    assert not bad, "\n".join(bad)
