"""Output helpers and plain-text tables shared by the experiments (the atomic writers live in
``jaxflex.files``)."""
from __future__ import annotations

import json
import math
import platform
import time
from pathlib import Path


from jaxflex.files import atomic_path, write_json, write_text  # noqa: F401  (the experiments' writers)


def resumable(path, key: dict, compute, label: str = ""):
    """Result of ``compute()`` cached as JSON at ``path``: a rerun with the same ``key`` (e.g. version
    and parameters) loads it instead of recomputing, so an interrupted job resumes from its last
    finished section. The file is written atomically; the value returned is always the JSON form
    (the same on a fresh and a resumed run)."""
    path = Path(path)
    if path.exists():
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError:
            data = None
        if isinstance(data, dict) and data.get("resume_key") == key:
            print(f"  {label or path.name}: resumed from {path}", flush=True)
            return data
    data = dict(compute())
    data["resume_key"] = key
    write_json(path, data)
    return json.loads(path.read_text())


def save_figure(fig, path, dpi: int = 200, show: bool = False) -> None:
    """Save a matplotlib figure atomically and close it: at ``path`` (format from its suffix; PNG at
    ``dpi``) and, beside a PNG, a vector copy with the same stem and ``.svg`` (for a paper: it
    scales without loss; no creation date in it, so the same figure gives the same file). ``show``:
    in a Jupyter kernel, also display it inline first (notebooks); elsewhere (scripts, tests, the
    CLI) nothing is shown."""
    import matplotlib.pyplot as plt

    path = Path(path)
    form = path.suffix.lstrip(".").lower() or "png"
    targets = [(path, form)] + ([(path.with_suffix(".svg"), "svg")] if form == "png" else [])
    for target, kind in targets:
        with atomic_path(target) as tmp:
            fig.savefig(tmp, dpi=dpi, format=kind, bbox_inches="tight",
                        **({"metadata": {"Date": None}} if kind == "svg" else {}))
    if show and in_notebook():
        from IPython.display import display

        display(fig)
    plt.close(fig)


def in_notebook() -> bool:
    """True inside a Jupyter (IPython) kernel."""
    import sys

    return "ipykernel" in sys.modules


def provenance(params: dict | None = None, started: float | None = None) -> dict:
    """Package version, platform, parameters and wall time of a run (recorded in every output)."""
    import jax

    from jaxflex import __version__

    out = {"jaxflex_version": __version__, "jax_version": jax.__version__,
           "python": platform.python_version(), "machine": platform.machine(),
           "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    if params is not None:
        out["parameters"] = params
    if started is not None:
        out["wall_time_s"] = round(time.time() - started, 3)
    return out


def rel_diff(ours, paper):
    """Relative difference (ours - paper) / |paper|, NaN when the paper value is missing or zero."""
    if paper is None or ours is None or paper == 0 or not math.isfinite(paper):
        return float("nan")
    return (ours - paper) / abs(paper)


def fmt(v, sig: int = 5):
    """Number formatting for tables: ``sig`` significant digits, '-' for missing/NaN."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, str):
        return v
    return f"{v:.{sig}g}"


def pct(v):
    """Percentage formatting of a relative difference."""
    return "-" if v is None or not math.isfinite(v) else f"{100 * v:+.2f}%"


def table(headers, rows) -> str:
    """A GitHub-flavoured markdown table (also readable in a terminal)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(cells[0]), sep] + [line(r) for r in cells[1:]])


def corners_design(record: dict):
    """The ``Design`` of a record's ``{"corners": [{d_m, e_m, n}, {d_m, e_m, n}], "coef": [...]}``: a
    free-path design's entry, and a closed-loop study's ``refined`` design. Imports JAX."""
    from jaxflex.designs import design

    c, coef = record["corners"], [float(v) for v in record["coef"]]
    return design(c[0]["d_m"], c[0]["e_m"], c[0]["n"], coef, d2=c[1]["d_m"], e2=c[1]["e_m"], n2=c[1]["n"])


def design_of_record(record: dict):
    """(Design, blend family, law order) of the ``design`` entry of ``jaxflex optimize``'s JSON
    (docs/conventions.md#file-formats): both corners' blend parameters (d, e [m], n; a law-only
    record: its paper path's, at both corners) and the law's coefficients. Imports JAX."""
    from jaxflex.designs import design

    p, coef = record["path"], [float(v) for v in record["coef"]]
    if p.get("free", True):
        x = corners_design({"corners": p["corners"], "coef": coef})
    else:
        x = design(p["d"], p["e"], p["n"], coef)
    return x, p["blend"], int(record.get("order", 3))


def initial_design(path, blend: str | None, order: int, n_coef: int | None = None):
    """The design of an earlier ``jaxflex optimize`` JSON at ``path`` to start an optimization from:
    its ``design`` entry (``design_of_record``), or, for a run with the servo in the loop that
    refined it, the refined design (``closed_loop.refined.design``, the same blend family and law
    order), so that a refinement continues from where the last run ended. ValueError, before
    anything compiles, for a file that holds none or whose blend family or law order differ from
    the run's (``blend``, ``order``; blend None: any, as a law-only run takes the law alone). With
    ``n_coef`` its law is written with that many coefficients (``profiles.elevate``: the same law,
    more freedom); fewer than it has is refused."""
    try:
        with open(path) as f:
            record = json.load(f)
        x, family, law_order = design_of_record(record["design"])
        refined = (record.get("closed_loop") or {}).get("refined")
        if refined is not None:                 # a servo run's refined design continues its refinement
            x = corners_design(refined["design"])
    except (OSError, ValueError, KeyError, TypeError, IndexError) as err:
        raise ValueError(f"--init {path}: not the JSON of a jaxflex optimize run with a design "
                         f"({type(err).__name__}: {err})") from None
    if blend is not None and family != blend:
        raise ValueError(f"--init {path}: its design has {family} blends, this run {blend} ones "
                         f"(give --blend {family})")
    if law_order != order:
        raise ValueError(f"--init {path}: its law has end-factor order {law_order}, this run {order}")
    if n_coef is not None and n_coef != len(x.coef):
        from jaxflex.profiles import elevate

        if n_coef < len(x.coef):
            raise ValueError(f"--init {path}: its law has {len(x.coef)} coefficients, which --coef {n_coef} "
                             f"cannot hold (give --coef {len(x.coef)} or more)")
        x = x._replace(coef=elevate(x.coef, n_coef))
    return x


def robot_and_cycle(preset, **overrides) -> tuple:
    """(robot, cycle) of a run: ``preset`` is a preset name (``robot_preset``, ``cycle_preset``) or a
    ``jaxflex.robot_files.Setup`` (the CLI's --robot, --cycle, --pick/--place). ``overrides``
    replace robot fields (e.g. payload)."""
    from jaxflex.robot import cycle_preset, robot_preset

    if isinstance(preset, str):
        return robot_preset(preset, **overrides), cycle_preset(preset)
    robot = preset.robot.replace(**overrides) if overrides else preset.robot
    return robot, preset.cycle


def setup_name(record) -> str:
    """The name in a record's "preset" field (``setup_record``)."""
    return record if isinstance(record, str) else record["name"]


def setup_record(preset):
    """What the records store for the robot and cycle: the preset's name, or the setup's name with
    its robot and cycle tables (``jaxflex.robot_files``), enough to rebuild them."""
    if isinstance(preset, str):
        return preset
    from jaxflex.robot_files import cycle_to_dict, robot_to_dict

    return {"name": preset.name, "robot": robot_to_dict(preset.robot), "cycle": cycle_to_dict(preset.cycle),
            "servo": preset.servo}


def code_digest() -> str:
    """A digest (16 hex digits) of the installed jaxflex sources (``jaxflex``, ``jaxflex.optimize``,
    ``jaxflex.experiments``: every ``.py`` file's path and bytes): results computed by other code
    carry another digest, so a resumable run does not take them for its own."""
    import hashlib
    import importlib

    h = hashlib.sha256()
    for name in ("jaxflex", "jaxflex.optimize", "jaxflex.experiments"):
        root = Path(importlib.import_module(name).__file__).parent
        for f in sorted(root.rglob("*.py")):
            if f.parent.name == "__pycache__":
                continue
            h.update(f"{name}/{f.relative_to(root).as_posix()}\n".encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def prepare_resume(out, key: dict, fresh: bool = False) -> int:
    """Make the resumable outputs in ``out`` safe to resume from under ``key`` (``resumable``'s key
    of every section). The sections' JSON carry their key and are recomputed when it differs; the
    optimizers' checkpoints (``checkpoint.npz``) carry none, so ``out/resume.json`` records the key
    of the run that wrote them, and when it differs (or is missing while checkpoints are there) the
    checkpoints are removed. ``fresh``: every section's JSON and every checkpoint is removed, so
    that everything is computed again. Returns the number of files removed."""
    out = Path(out)
    marker = out / "resume.json"
    try:
        old = json.loads(marker.read_text()) if marker.exists() else None
    except json.JSONDecodeError:
        old = None
    removed = 0
    checkpoints = sorted(out.rglob("checkpoint.npz"))
    if fresh or old != key and (old is not None or checkpoints):
        for f in checkpoints:
            f.unlink()
            removed += 1
    if fresh:
        for f in sorted(out.rglob("*.json")):
            try:
                data = json.loads(f.read_text())
            except (json.JSONDecodeError, UnicodeDecodeError, OSError):
                continue
            if isinstance(data, dict) and "resume_key" in data:
                f.unlink()
                removed += 1
    write_json(marker, key)
    return removed
