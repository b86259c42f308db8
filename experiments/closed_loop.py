"""The closed-loop section of ``jaxflex reproduce``: the optimized designs and the paper's combinations
under a servo loop (docs/conventions.md#servo), and the figure of residual against the bandwidth.

Thin script over ``jaxflex.optimize.closed_loop``: for an optimization study's record (its design,
law and first mode), ``case`` runs the closed-loop study and ``bandwidth_sweep`` the nominal
residual at several bandwidths; ``figure`` draws it. ``shipped_case`` evaluates the designs the
repository ships in ``examples/designs`` (refined with the servo in the loop by ``jaxflex optimize
--servo``) instead of refining the study's design again, which is what ``reproduce_case`` does.
"""
from __future__ import annotations

import json
from pathlib import Path

from jaxflex.designs import design_path
from jaxflex.optimize.closed_loop import Controller, ServoModel, Trajectory, closed_loop_study, evaluate
from jaxflex.path import make_path
from jaxflex.profiles import make_profile, shaped
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import default_grid
from jaxflex.uncertainty import ModelId

from .io import corners_design, design_of_record

FCS = (15.0, 40.0)                          # the bandwidths of the comparison [Hz]
FIGURE_FCS = (10.0, 15.0, 20.0, 25.0, 30.0, 40.0)
# the designs refined with the servo in the loop that the repository ships (one directory each, as
# ``jaxflex optimize --servo --out`` writes it); absent from an installation without the repository
DESIGNS_DIR = Path(__file__).resolve().parents[1] / "examples" / "designs"


def design_of(record: dict):
    """(Design, law, blend family) of an optimization study's record (``experiments.optimize``)."""
    x, blend, order = design_of_record(record["design"])
    return x, shaped(x.coef, order, name="optimized"), blend


def case(record: dict, controller: Controller, *, steps: int, samples: int, corners: bool, fcs=FCS,
         ruckig: bool = True, progress: bool = True) -> dict:
    """The closed-loop study (``closed_loop_study``) of a single-payload study's optimized design."""
    (payload,), tf = record["payloads"], record["tf"]
    robot, cycle = robot_preset("default"), cycle_preset("default")
    x, law, blend = design_of(record)
    grid = default_grid(robot.replace(payload=payload), [tf], 0.1)
    return closed_loop_study(robot, cycle, payload, tf, 0.1, grid, x, law, controller, fcs=fcs, steps=steps,
                             samples=samples, corners=corners, blend=blend, order=law.order,
                             first_mode_hz=record["first_mode_hz"][0], ruckig=ruckig, progress=progress)


def bandwidth_sweep(record: dict, closed: dict, fcs=FIGURE_FCS, progress: bool = True) -> dict:
    """The nominal model's closed-loop dwell residual [um] at every bandwidth of ``fcs`` [Hz] (8 kHz,
    the study's rotor) for the optimized design (the refined or shipped one if ``closed``, a record of
    ``case`` or ``shipped_case``, holds one) with its
    feedforward and with the rigid one, the best paper combination at the study's first bandwidth
    and poly7-Lamé (rigid feedforward), beside their perfect-controller values."""
    (payload,), tf = record["payloads"], record["tf"]
    robot, cycle = robot_preset("default").replace(payload=payload), cycle_preset("default")
    x, law, blend = design_of(record)
    if "refined" in closed:
        x = corners_design(closed["refined"]["design"])
        law = shaped(x.coef, law.order, name="optimized")
    elif "shipped" in closed:
        x, law, blend = shipped_trajectory(closed["shipped"])
    c = closed["controller"]
    first = next(iter(closed["paper"]))
    b, p = closed["paper"][first]["best"].split("/")
    paper_path = make_path(cycle, b, 0.025)
    opt_path = design_path(cycle, x, blend)
    trs = {"optimized": Trajectory(opt_path, law, c["feedforward"]),
           "optimized, rigid feedforward": Trajectory(opt_path, law, "rigid"),
           f"{b}/{p}": Trajectory(paper_path, make_profile(p), "rigid"),
           "lame/poly7": Trajectory(make_path(cycle, "lame", 0.025), make_profile("poly7"), "rigid")}
    grid = default_grid(robot, [tf], 0.1)
    nominal = (ServoModel(ModelId(float(payload))),)
    out = {name: [] for name in trs}
    for fc in fcs:
        res = evaluate(trs, robot, cycle, tf, 0.1, grid, fc, nominal, rate=c["rate"], rotor=c["rotor"],
                       progress=progress)
        for name in trs:
            out[name].append(float(res[name]["dwell_residual_mm"][0]) * 1e3)
    return {"fcs": list(fcs), "dwell_residual_um": out}


def figure(sweep: dict, closed: dict, label: str):
    """Dwell residual [um] on the nominal model against the servo's bandwidth fc [Hz] (log scale), one
    line per trajectory (a marker of its own each), its perfect-controller value dashed where the
    study has it; one column wide, the legend below."""
    import matplotlib.pyplot as plt

    from jaxflex.names import display_name
    from jaxflex.plotting import COLUMN_WIDTH, MARKERS, legend_below

    names = list(sweep["dwell_residual_um"])
    fig, ax = plt.subplots(figsize=(COLUMN_WIDTH, 3.3 + 0.3 + 0.17 * len(names)), layout="constrained")
    perfect = next(iter(closed["fcs"].values()))
    for i, (name, values) in enumerate(sweep["dwell_residual_um"].items()):
        ax.semilogy(sweep["fcs"], values, "-", marker=MARKERS[i % len(MARKERS)], ms=4, color=f"C{i}",
                    label=display_name(name), lw=1.6 if name == "optimized" else 1.0)
        key = next((k for k in perfect if k == name or k.startswith(name + " ")), None)
        if key is not None and not name.endswith("rigid feedforward"):
            ax.axhline(perfect[key]["perfect_um"], color=f"C{i}", ls="--", lw=0.8)
    ax.set(xlabel="servo bandwidth fc [Hz]", ylabel="dwell residual [µm]")
    ax.set_title(f"{label}: under the servo (solid)\nand the perfect controller (dashed)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    legend_below(fig, ncol=1)
    return fig


def reproduce_case(record: dict, out_dir: str, steps: int, samples: int, fcs=FCS, figure_fcs=FIGURE_FCS,
                   corners: bool = True) -> dict:
    """One case of reproduce's closed-loop section (a module-level function: reproduce runs it in a
    process of its own): at each bandwidth of ``fcs`` [Hz] the study's design refined with that
    servo in the loop (``steps``) and compared on ``samples`` random models and (``corners``) the
    32 corners (``case``); then the nominal residual at ``figure_fcs`` and its figure, written to
    ``out_dir/residual_vs_fc.png``. Returns {"studies": fc -> record, "sweep": ``bandwidth_sweep``}."""
    from pathlib import Path

    from jaxflex.runtime.compiled import release_compiled

    from .io import save_figure
    from .report import case_label

    studies = {}
    for fc in fcs:
        release_compiled()      # the last bandwidth's gradient (tens of thousands of mappings) is done with
        studies[f"{fc:g}"] = case(record, Controller(fc), steps=steps, samples=samples, corners=corners, fcs=(fc,))
    first = studies[f"{fcs[0]:g}"]
    sweep = bandwidth_sweep(record, first, figure_fcs)
    save_figure(figure(sweep, first, case_label(record["payloads"][0], record["tf"])),
                Path(out_dir) / "residual_vs_fc.png")
    return {"studies": studies, "sweep": sweep}


def shipped_designs(payload: float, tf: float, designs_dir=DESIGNS_DIR) -> dict:
    """The shipped designs for ``payload`` [kg] and cycle time ``tf`` [s]: the bandwidth fc [Hz] each
    was refined at -> its directory under ``designs_dir`` (each holds the ``optimize.json`` of a
    single-payload ``jaxflex optimize --servo`` run whose design was refined); {} when there are
    none or no such directory (an installation without the repository)."""
    out = {}
    root = Path(designs_dir)
    for d in sorted(root.iterdir()) if root.is_dir() else ():
        f = d / "optimize.json"
        if not f.is_file():
            continue
        rec = json.loads(f.read_text())
        cl = rec.get("closed_loop") or {}
        if "refined" in cl and rec.get("payloads") == [payload] and abs(float(rec.get("tf", -1.0)) - tf) < 1e-9:
            out[float(cl["controller"]["fc"])] = d
    return out


def shipped_design(directory) -> dict:
    """The refined design of a shipped design's ``optimize.json``, JSON-ready: its directory's name,
    the bandwidth fc [Hz] and controller it was refined for, its blend family, law order and
    ``{"corners", "coef"}`` (the form ``io.corners_design`` reads)."""
    directory = Path(directory)
    rec = json.loads((directory / "optimize.json").read_text())
    _, blend, order = design_of_record(rec["design"])
    cl = rec["closed_loop"]
    return {"name": directory.name, "trained_at_hz": float(cl["controller"]["fc"]), "controller": cl["controller"],
            "blend": blend, "order": order, "design": cl["refined"]["design"]}


def shipped_trajectory(shipped: dict):
    """(Design, shaped law, blend family) of a ``shipped_design`` record."""
    x = corners_design(shipped["design"])
    return x, shaped(x.coef, shipped["order"], name="optimized"), shipped["blend"]


def shipped_case(record: dict, out_dir: str, samples: int, designs: dict, fcs=FCS, figure_fcs=FIGURE_FCS,
                 corners: bool = True) -> dict:
    """One case of reproduce's closed-loop section with the shipped designs (a module-level function:
    reproduce runs it in a process of its own): at each bandwidth of ``fcs`` [Hz] the shipped design
    refined at that bandwidth, or else the one refined at the nearest, evaluated with the closed-loop
    study (``closed_loop_study``, no refinement: its controller's rate, rotor and feedforward at that
    bandwidth) beside the paper's combinations and the baselines on ``samples`` random models and
    (``corners``) the 32 corners of the boxes; then the nominal residual at ``figure_fcs`` and its
    figure, written to ``out_dir/residual_vs_fc.png``. ``record``: the optimization study's record of
    the same payload and cycle time (its first mode shapes the ZV/ZVD baselines); ``designs``: the
    ``shipped_design`` records of that case's ``shipped_designs`` (fc [Hz] -> record). Returns
    {"studies": fc -> record, each with its design under "shipped", "sweep": ``bandwidth_sweep``}."""
    from .io import save_figure
    from .report import case_label

    if not designs:
        raise ValueError(f"no shipped design for {record['payloads'][0]:g} kg, tf {record['tf']:g} s")
    (payload,), tf = record["payloads"], record["tf"]
    robot, cycle = robot_preset("default"), cycle_preset("default")
    grid = default_grid(robot.replace(payload=payload), [tf], 0.1)
    studies = {}
    for fc in fcs:
        shipped = designs[min(designs, key=lambda f: (abs(f - fc), f))]    # refined at fc, else the nearest
        x, law, blend = shipped_trajectory(shipped)
        c = shipped["controller"]
        st = closed_loop_study(robot, cycle, payload, tf, 0.1, grid, x, law,
                               Controller(fc, c["rate"], c["rotor"], c["feedforward"]), fcs=(fc,), steps=0,
                               samples=samples, corners=corners, blend=blend, order=shipped["order"],
                               first_mode_hz=record["first_mode_hz"][0], progress=True)
        studies[f"{fc:g}"] = {**st, "shipped": shipped}
    first = studies[f"{fcs[0]:g}"]
    sweep = bandwidth_sweep(record, first, figure_fcs)
    save_figure(figure(sweep, first, case_label(payload, tf)), Path(out_dir) / "residual_vs_fc.png")
    return {"studies": studies, "sweep": sweep}
