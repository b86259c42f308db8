"""``jaxflex reproduce``: every table and figure of the paper, ours beside the paper's, in REPORT.md.

``compute`` runs the sections in order, each writing its JSON/CSV/PNG into the output directory;
``experiments.report.render`` then writes the report's text from their results, and ``run`` writes
REPORT.md atomically.
"""
from __future__ import annotations

import dataclasses
import json
import shutil
import time
from pathlib import Path

import numpy as np

from jaxflex import progress
from jaxflex.runtime.compiled import release_compiled, release_if_crowded, run_isolated, run_isolated_uncached

from . import convergence, kinematics, modes, report
from . import vibration as vibration_study
from .io import code_digest, prepare_resume, provenance, resumable, save_figure, write_json, write_text
from .report import case_label


def run(out: str = "results", quick: bool = False, vibration: bool = True, optimize: bool = True,
        closed_loop: bool = True, fresh: bool = False, refine: bool = False) -> dict:
    """``jaxflex reproduce``: ``compute`` every section into ``out``, then render REPORT.md from the
    results (``experiments.report.render``) and write it with the run's provenance. Returns the
    sections' results."""
    started = time.time()
    results = compute(out, quick, vibration, optimize, closed_loop, fresh, refine)
    out = Path(out)
    prov = provenance({"out": str(out), "quick": quick, "refine": refine}, started)
    write_text(out / "REPORT.md", report.render(results, out, quick, prov, time.time() - started))
    write_json(out / "provenance.json", prov)
    print(f"report: {out / 'REPORT.md'}")
    return results


def compute(out: str = "results", quick: bool = False, vibration: bool = True, optimize: bool = True,
            closed_loop: bool = True, fresh: bool = False, refine: bool = False) -> dict:
    """Compute every section in order, each writing its JSON/CSV/PNG into ``out``; returns the
    sections' results (``results["kinematics_default"]``, ``"modes"``, ``"vibration"``,
    ``"convergence"``, ``"optimize"``). ``vibration`` (default on) runs the simulation study of the
    paper's Section 4; without ``quick`` it is followed by the step-convergence study and the
    cross-check against the full nonlinear model. ``optimize`` (default on) adds the optimization
    studies (beyond the paper): the optimized designs against the baselines for both paper cases
    (resumable: checkpoints in DIR/optimize_*) and the cycle-time study; with ``closed_loop``
    (default on) designs refined with a servo in the loop are compared under it (``_closed_loop``:
    the designs shipped in examples/designs, or with ``refine`` the studies' designs refined again
    in this run). A section whose JSON is
    there from a run of the same code (``io.code_digest``) and mode is loaded instead of computed, and
    the optimizers resume from their checkpoints only after a run of the same code
    (``io.prepare_resume``); ``fresh``: every section is computed again."""
    with_vibration = vibration
    if not isinstance(out, (str, Path)) or not str(out):
        raise ValueError(f"out must be a directory path, got {out!r}")
    if Path(out).exists() and not Path(out).is_dir():
        raise ValueError(f"out {str(out)!r} exists and is not a directory")
    from jaxflex import __version__
    # sections computed by the same code in the same mode resume
    key = {"jaxflex_version": __version__, "code": code_digest(), "quick": quick}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    removed = prepare_resume(out, key, fresh)
    if removed:
        print(f"  {removed} earlier result file(s) and checkpoint(s) removed: "
              f"{'--fresh' if fresh else 'computed by other code or in another mode'}", flush=True)
    fig_dir = out / "figures"
    steps = 10000 if quick else 20000        # quick: the spectra's sample count (one compiled program)
    results = {}
    plan = ["kinematics", "natural frequencies"]
    plan += ["vibration study"] * with_vibration + ["full-model check"] * (with_vibration and not quick)
    closed_loop = closed_loop and not quick       # quick: no closed-loop section (its smoke test is optimize --servo's)
    plan += ["optimization studies"] * optimize + ["closed-loop study"] * (optimize and closed_loop)
    tracker = _Sections(plan, quick)

    tracker.next()
    print("== kinematics (paper Section 3: Tables 2, 5, 6; Figs. 6-8, 10, 11)", flush=True)
    for preset in ("default", "table6"):
        res = kinematics.run(preset, 1.0, out=str(fig_dir) if preset == "default" else None,
                             json_path=str(out / f"kinematics_{preset}.json"), steps=steps,
                             make_figures=preset == "default")
        results[f"kinematics_{preset}"] = res
    # between sections 1 to 4: bounded memory mappings (jaxflex.runtime.compiled); the compiled programs
    # stay while the process holds less than half its mapping limit (the later sections run many of
    # them again: the engine's rollouts, the coefficient program)
    release = release_if_crowded
    release()

    tracker.next()
    print("== natural frequencies along the path (paper Section 4)", flush=True)
    pts = 9 if quick else 41
    freq = [modes.run("default", m, pts, json_path=str(out / f"modes_{m:g}kg.json")) for m in (6.0, 0.1)]
    save_figure(modes.figure(freq), fig_dir / report.MODES_FIGURE)
    results["modes"] = freq
    release()

    if with_vibration:
        tracker.next()
        print("== vibration study (paper Section 4: Tables 7-11, Fig. 12)", flush=True)
        vib = resumable(out / "vibration.json", key, lambda: vibration_study.compute(quick=quick), "vibration")
        report.vibration_outputs(vib, fig_dir, out)
        results["vibration"] = vib
        release()
        if not quick:
            tracker.next()
            print("== step convergence and full-model cross-check", flush=True)
            conv = {"dt": resumable(out / "convergence_dt.json", key, convergence.dt_study, "dt study")}
            conv["reference"] = resumable(out / "convergence_reference.json", key, convergence.reference_study,
                                          "full-model check")
            release()
            results["convergence"] = conv

    if optimize:
        tracker.next()
        print("== optimization study (beyond the paper)", flush=True)
        if not quick:
            release_compiled()          # the studies run in processes of their own (``_optimization``)
        results["optimize"] = _optimization(out, quick, key, results.get("vibration"))
    if optimize and closed_loop:
        tracker.next()
        print("== closed-loop study (beyond the paper: a servo loop instead of the perfect controller)", flush=True)
        release_compiled()
        results["closed_loop"] = _closed_loop(out, key, results["optimize"], refine)
    tracker.next()
    return results


class _Sections:
    """Progress of the run on stderr, one line per section: its number, the time so far and an ETA
    from the durations of the same sections in an earlier run on this machine (remembered beside
    the compilation cache, ``jaxflex.progress.remember``; a resumed section takes far less)."""

    def __init__(self, plan: list, quick: bool):
        self.plan, self.k, self.began = plan, -1, None
        self.keys = [f"reproduce{' --quick' if quick else ''}: {name}" for name in plan]
        self.bar = progress.Progress("reproduce", total=len(plan), unit="section")

    def next(self) -> None:
        now = time.perf_counter()
        if self.k >= 0:
            progress.record(self.keys[self.k], now - self.began)
        self.k, self.began = self.k + 1, now
        if self.k >= len(self.plan):
            self.bar.done = len(self.plan)
            self.bar.close("report")
            return
        self.bar.done = self.k
        left = [progress.recorded(key) for key in self.keys[self.k:]]
        eta = f", ETA ~{progress.clock(sum(left))} (earlier run)" if all(v is not None for v in left) else ""
        self.bar.say(f"section {self.k + 1}/{len(self.plan)}: {self.plan[self.k]} "
                     f"[{progress.clock(self.bar.elapsed())}{eta}]")


# payloads [kg], tf [s], training models, motion-law coefficients: every case trains on the box grid of
# its payloads (the StudyConfig defaults; the design for both payloads on both grids).
OPT_CASES = (((6.0,), 0.43, "box", 6), ((0.1,), 0.3, "box", 6), ((0.1, 6.0), 0.43, "box", 6))


def _optimization(out: Path, quick: bool, key: dict, vib: dict | None = None) -> dict:
    """The design optimization for both paper cases and one design robust over both payloads, then
    the cycle-time study, then the verification of the three designs (``optimize.verifications``:
    the full model and a quarter step, one process for all). Each study resumes: a finished one
    from its JSON, an interrupted optimization from its checkpoint. All share one grid (the 0.43 s
    case's; the 0.3 s case gets a finer step), so the single-payload studies and the cycle-time
    study compile their gradient once, and the training models' workspace tables (the later
    studies load them from ``DIR/optimizations/workspaces``, removed at the end).
    ``vib``: the vibration study's results (``vibration.compute``), whose paper-model residuals the
    richer-model comparison reuses instead of simulating the 12 combinations again."""
    from jaxflex.optimize.config import StudyConfig
    from jaxflex.optimize.workspaces import WORKSPACE_MEMO
    from jaxflex.robot import robot_preset
    from jaxflex.sweep import default_grid

    from . import optimize as opt

    study = StudyConfig()
    steps = 2 if quick else study.train.optimizer.steps
    # Full runs give each study a process of its own: for peak memory, no longer for the mapping limit
    # (jaxflex.runtime.compiled). The compiled programs hold most of a study's memory, and in one
    # process the studies' programs add up, whether kept or released after each study; the results are
    # the same bit for bit either way (figures in docs/performance.md). Quick runs (a smoke test of
    # every step: 2 optimizer steps, nominal models) stay in this process and share its programs.
    isolated = (lambda fn, **kw: fn(**kw)) if quick else run_isolated
    grid = default_grid(robot_preset("default"), [0.43], 0.1)
    # finished optimizations by their inputs: the cycle-time study's design at tf_ref is the 6 kg
    # study's (the same models, scales, start and steps), which it loads instead of running again
    memo = out / "optimizations"
    res = {"cases": [], "quick": quick}
    # quick: the 6 kg case only (a smoke run of every step; the design for both payloads would also
    # compile a program of its own)
    for payloads, tf, train, n_coef in (OPT_CASES[:1] if quick else OPT_CASES):
        name = "_".join(f"{m:g}" for m in payloads)
        d = out / f"optimize_{name}kg"
        rec = resumable(d / "study.json", key,
                        lambda: isolated(opt.compute, payloads=payloads, tf=tf, out=str(d), grid=grid, verify=False,
                                         config=dataclasses.replace(
                                             study.with_optimizer(steps=steps, memo=str(memo)),
                                             training_set="nominal" if quick else train, n_coef=n_coef,
                                             box_samples=4 if quick else 200, richer_modes=1 if quick else 3)),
                        f"optimization {name} kg")
        res["cases"].append({"dir": d.relative_to(out).as_posix(), "record": rec})
        if not quick:
            release_compiled()
    tfs = (0.43, 0.37) if quick else (0.43, 0.40, 0.37, 0.34, 0.31)
    ct = resumable(out / "cycle_time" / "study.json", key,
                   lambda: isolated(opt.run_cycle_time, payload=6.0, tf_ref=0.43, tfs=tfs, out=str(out / "cycle_time"),
                                    config=dataclasses.replace(study.with_optimizer(steps=steps, memo=str(memo)),
                                                               training_set="nominal" if quick else "box")),
                   "cycle-time study")
    res["cycle_time"] = {"dir": "cycle_time", "text": opt.cycle_time_text(ct), "record": ct}
    shutil.rmtree(memo / WORKSPACE_MEMO, ignore_errors=True)     # the studies' shared workspaces
    if not quick:
        # the studies' verifications (full model, quarter step) in one process after them, so that its
        # programs compile or load once, not once per study; resumed only for the same designs
        records = [case["record"] for case in res["cases"]]
        designs = [[r["payloads"], r["tf"], r["blend"], r["best_paper"], r["design"]] for r in records]
        ver = resumable(out / "verification.json", {**key, "designs": designs},
                        lambda: {"cases": isolated(opt.verifications, records=records)},
                        "verification of the optimized designs")
        for case, v in zip(res["cases"], ver["cases"]):
            case["record"]["verification"] = v
            _add_verification(out / case["dir"] / "optimize.json", v)
    for case in res["cases"]:
        case["text"] = opt.text(case["record"])
    paper = None if vib is None else paper_residuals(vib)
    res["richer"] = resumable(out / "richer_model.json", key, lambda: richer_sweep(1 if quick else 3, paper),
                              "the paper's combinations on the richer model")
    return res


CLOSED_LOOP_STEPS = 40      # optimizer steps of each design's refinement with the servo in the loop
CLOSED_LOOP_SAMPLES = 20    # random models of both boxes (besides their 32 corners) per comparison


def _closed_loop(out: Path, key: dict, opt: dict, refine: bool = False) -> dict:
    """The single-payload studies' cases under the servo (``experiments.closed_loop``): at each
    bandwidth of ``closed_loop.FCS`` a design refined with that servo in the loop is compared with the
    paper's combinations and the baselines on the robot's and the controller's boxes, then the
    figure of the nominal residual against the bandwidth. The design is the one the repository ships
    for that payload, cycle time and bandwidth (``closed_loop.shipped_case``; refined at the nearest
    bandwidth where none was refined at it), or with ``refine``, or for a case without a shipped
    design, the study's design refined in this run (``closed_loop.reproduce_case``:
    ``CLOSED_LOOP_STEPS`` steps at each bandwidth, about a quarter of an hour each on 2 cores). Each
    case resumes from its JSON (only for the same designs); each case runs in a process of its own,
    with the persistent compilation cache for the shipped designs (the programs the cases share, and
    those earlier sections compiled, are loaded instead of compiled again; docs/performance.md),
    without it for a refinement (its gradient's program is too large to serialize,
    ``run_isolated_uncached``)."""
    from . import closed_loop as cl

    res = {"cases": []}
    for case in opt["cases"]:
        rec = case["record"]
        if len(rec["payloads"]) != 1:
            continue
        name = f"{rec['payloads'][0]:g}"
        d = out / f"closed_loop_{name}kg"
        designs = {} if refine else cl.shipped_designs(rec["payloads"][0], rec["tf"])
        if designs:
            shipped = {fc: cl.shipped_design(p) for fc, p in designs.items()}
            r = resumable(d / "closed_loop.json", {**key, "shipped": {f"{fc:g}": v for fc, v in shipped.items()}},
                          lambda: run_isolated(cl.shipped_case, record=rec, out_dir=str(d),
                                               samples=CLOSED_LOOP_SAMPLES, designs=shipped),
                          f"closed loop {name} kg (shipped designs)")
        else:
            if not refine:
                print(f"  no shipped design for {name} kg (examples/designs): the study's design is refined "
                      "with the servo in the loop", flush=True)
            r = resumable(d / "closed_loop.json", {**key, "refined": CLOSED_LOOP_STEPS},
                          lambda: run_isolated_uncached(cl.reproduce_case, record=rec, out_dir=str(d),
                                                        steps=CLOSED_LOOP_STEPS, samples=CLOSED_LOOP_SAMPLES),
                          f"closed loop {name} kg")
        res["cases"].append({"dir": d.relative_to(out).as_posix(), "payload": rec["payloads"][0], "tf": rec["tf"],
                             **r})
        release_compiled()
    return res


def _add_verification(path: Path, verification: dict) -> None:
    """Write the verification into a study's ``optimize.json`` (``optimize.compute`` wrote it
    without: ``reproduce`` verifies the studies together after them)."""
    if path.exists():
        rec = json.loads(path.read_text())
        if rec.get("verification") != verification:
            write_json(path, {**rec, "verification": verification})


def paper_residuals(vib: dict) -> dict:
    """The dwell residuals [mm] of the vibration study (``vibration.compute``: the 12 combinations in
    both paper cases, paper model, default grid) in ``richer_sweep``'s layout: case label ->
    'blend/profile' -> value."""
    return {case_label(c["payload"], c["tf"]): {f"{b}/{p}": float(v) for b, row in
                                                  vib[f"case{k}"]["dwell_residual_mm"].items() for p, v in row.items()}
            for k, c in enumerate(vib["cases"])}


def richer_sweep(n_modes: int = 3, paper: dict | None = None) -> dict:
    """The 12 paper combinations in both paper cases on the paper's model and on the richer
    validation model (``jaxflex.model.richer``, ``n_modes`` extra modes of each kind per link):
    dwell residual [mm] per model, case ('6 kg, 0.43 s', ...) and combination ('lame/poly7', ...),
    and the first locked frequencies at the place pose [Hz]. ``paper``: the paper model's residuals
    in that layout when they are already computed (``paper_residuals``: the same sweep), else they
    are simulated here."""
    from jaxflex.frequencies import modes_at_point
    from jaxflex.model import richer
    from jaxflex.robot import cycle_preset, robot_preset
    from jaxflex.sweep import PAPER_CASES, SweepConfig, run_sweep

    robot, cycle = robot_preset("default"), cycle_preset()
    out = {"n_modes": n_modes, "dwell_residual_mm": {}, "place_freqs_hz": {}}
    for label, r in (("paper model", robot), ("richer model", richer(robot, n_modes))):
        if label == "paper model" and paper is not None:
            out["dwell_residual_mm"][label] = paper
        else:
            res = run_sweep(r, cycle, PAPER_CASES, SweepConfig(timed=False, estimate=False))
            dw = res.metrics["dwell_residual_mm"]
            out["dwell_residual_mm"][label] = {
                case_label(c.payload, c.tf): {f"{b}/{p}": float(dw[i, j, k]) for i, b in enumerate(res.blends)
                                               for j, p in enumerate(res.profiles)}
                for k, c in enumerate(res.cases)}
        out["place_freqs_hz"][label] = {
            f"{c.payload:g} kg": np.asarray(modes_at_point(r.replace(payload=c.payload), np.asarray(cycle.place)))[:4]
            .tolist() for c in PAPER_CASES}
    return out


