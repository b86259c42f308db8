"""Natural frequencies with the motors locked along the Adept path (paper Section 4, "Vibrational
domain"); ``jaxflex modes`` calls ``run``."""
from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks
from jaxflex.frequencies import modes_at_point
from jaxflex.path import make_path, path_frame
from jaxflex.robot import check_cycle_reachable

from . import paper_data
from .io import fmt, provenance, robot_and_cycle, save_figure, setup_name, setup_record, table, write_json


@jax.jit
@jax.jit
def _positions(path, s):
    return jax.vmap(lambda si: path_frame(path, si).pos)(s)


def _along(robot, path, s):
    """Positions (N, 2) [m] and locked frequencies (N, ne) [Hz] at the arc lengths s (N,): one pose at
    a time through the compiled program every frequency computation shares (``modes_at_point``)."""
    x = np.asarray(_positions(path, s))
    return x, np.stack([np.asarray(modes_at_point(robot, xi)) for xi in x])


def compute(preset: str = "default", payload: float = 6.0, points: int = 21, blend: str = "lame",
            d: float = 0.025) -> dict:
    """Locked-motor frequencies [Hz] at ``points`` equally spaced arc lengths of the blended path."""
    points = checks.count("points", points, 2)
    payload = checks.nonnegative("payload", payload, "kg")
    started = time.time()
    robot, cycle = robot_and_cycle(preset, payload=payload)
    check_cycle_reachable(robot, cycle)
    path = make_path(cycle, blend, d)
    s = jnp.linspace(0.0, path.length, int(points))
    x, freqs = _along(robot, path, s)
    x, freqs, s = np.asarray(x), np.asarray(freqs), np.asarray(s)
    if not np.all(np.isfinite(freqs)):
        raise ValueError(f"non-finite natural frequencies (payload {payload} kg, {setup_name(setup_record(preset))})")
    pts = [{"s": float(si), "x": float(xi[0]), "y": float(xi[1]), "freqs_hz": [float(f) for f in fr]}
           for si, xi, fr in zip(s, x, freqs)]
    summary = {f"mode_{k + 1}": {"min": float(freqs[:, k].min()), "max": float(freqs[:, k].max()),
                                 "mean": float(freqs[:, k].mean())} for k in range(3)}
    return {"payload": float(payload), "preset": setup_record(preset), "blend": blend, "points": pts,
            "summary": summary,
            # the paper's frequencies belong to the paper's robot: none beside a robot of your own
            "paper": paper_data.FREQUENCIES_HZ.get(float(payload)) if isinstance(preset, str) else None,
            "provenance": provenance({"preset": setup_record(preset), "payload": payload, "points": points,
                                      "blend": blend, "d": d}, started)}


def text(res: dict) -> str:
    """Readable table: frequencies of the first modes at each point, then a paper comparison."""
    rows = [[f"{p['s'] * 1e3:.2f}", f"{p['x'] * 1e3:.2f}", f"{p['y'] * 1e3:.2f}"]
            + [fmt(f, 5) for f in p["freqs_hz"][:4]] for p in res["points"]]
    out = [f"Locked-motor natural frequencies along the {res['blend']} path, payload {res['payload']:g} kg, "
           f"`{setup_name(res['preset'])}`", "",
           table(["s [mm]", "x [mm]", "y [mm]", "f1 [Hz]", "f2 [Hz]", "f3 [Hz]", "f4 [Hz]"], rows), ""]
    paper = res.get("paper") or {}
    rows = []
    for key, k in (("first", 1), ("third", 3)):
        s = res["summary"][f"mode_{k}"]
        mid, half = 0.5 * (s["max"] + s["min"]), 0.5 * (s["max"] - s["min"])
        ref = paper.get(key)
        rows.append([f"mode {k}", f"{mid:.1f} +- {half:.1f}",
                     f"{ref[0]:g} +- {ref[1]:g}" if ref else "-",
                     f"{100 * (mid / ref[0] - 1):+.2f}%" if ref else "-"])
    out += [table(["", "ours [Hz]", "paper [Hz]", "diff (centre)"], rows), ""]
    return "\n".join(out)


def figure(results: list[dict]):
    """First three frequencies along the path for each payload (one panel per mode, two columns
    wide, one legend below)."""
    import matplotlib.pyplot as plt

    from jaxflex.plotting import MARKERS, PAGE_WIDTH, legend_below, suptitle

    fig, axes = plt.subplots(1, 3, figsize=(PAGE_WIDTH, 3.2), layout="constrained")
    for i, res in enumerate(results):
        s = np.array([p["s"] for p in res["points"]]) * 1e3
        f = np.array([p["freqs_hz"] for p in res["points"]])
        for k, ax in enumerate(axes):
            ax.plot(s, f[:, k], "-", marker=MARKERS[i % len(MARKERS)], ms=3, label=f"{res['payload']:g} kg")
    for k, ax in enumerate(axes):
        ax.set_title(f"mode {k + 1}")
        ax.set_xlabel("arc length [mm]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("frequency [Hz]")
    legend_below(fig, title="payload")
    suptitle(fig, "Natural frequencies with the motors locked, along the Adept path (Lamé, d = e = 25 mm)")
    return fig


def run(preset="default", payload=6.0, points=21, json_path=None, out=None) -> dict:
    """``jaxflex modes``: natural frequencies along the path for ``payload`` [kg] at ``points`` poses; prints
    the table, optional JSON and figure."""
    res = compute(preset, payload, points)
    print(text(res))
    if json_path:
        write_json(json_path, res)
    if out:
        path = Path(out) / f"modes_{payload:g}kg.png"
        save_figure(figure([res]), path)
        res["figure"] = str(path)
        print(f"figure: {path}")
    return res
