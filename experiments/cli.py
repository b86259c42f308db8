"""The ``jaxflex`` command line (docs/conventions.md#file-formats), outside the core library: each
subcommand is a thin call into the experiment scripts of this package (``jaxflex.experiments``),
which call the library."""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import traceback

from jaxflex.names import DESIGN_BLENDS, PRESETS
from jaxflex.optimize.config import (ROBUST_POWER, SCENARIO_POOL, SCENARIOS, SERVO_LEARNING_RATE, SERVO_OBJECTIVES,
                                     SERVO_TRAININGS, TRAINING_SETS, StudyConfig)
from jaxflex.uncertainty import Box

STUDY = StudyConfig()       # the defaults of ``jaxflex optimize`` (this module imports no JAX)


def _add_common(p, preset=True):
    if preset:
        p.add_argument("--preset", default="default", choices=PRESETS,
                       help="robot geometry preset (docs/conventions.md#frames-and-geometry; default: %(default)s)")
    p.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")


def _add_setup(p):
    """Your own robot and move (docs/conventions.md#file-formats): files, or the pick and place points."""
    g = p.add_argument_group("robot and move", "instead of the preset's: a robot file (TOML, e.g. "
                                               "examples/paper_robot.toml) and a cycle file or the pick and place "
                                               "points; docs/conventions.md#file-formats")
    g.add_argument("--robot", metavar="FILE.toml", help="the robot (links, motors, payload, rotor, damping, servo)")
    g.add_argument("--cycle", metavar="FILE.toml", help="the Adept cycle (pick, place, lift height and direction)")
    g.add_argument("--pick", type=float, nargs=2, metavar=("X", "Y"), help="pick point [m]")
    g.add_argument("--place", type=float, nargs=2, metavar=("X", "Y"), help="place point [m]")
    g.add_argument("--lift", type=float, metavar="H", help="lift height of the cycle [m] (default: 0.025)")


def run_setup(args):
    """The robot and cycle the flags describe (``jaxflex.robot_files.setup``): the preset's name when
    no file or point is given (the experiments then build the preset), else a ``Setup``."""
    if not any(getattr(args, k, None) is not None for k in ("robot", "cycle", "pick", "place", "lift")):
        return args.preset
    from jaxflex.robot_files import setup

    return setup(args.preset, args.robot, args.cycle, args.pick, args.place, args.lift)


def file_payloads(args, setup, many: bool):
    """--payload if given, else the robot file's payload (when > 0), else 6 kg."""
    if args.payload is not None:
        return args.payload
    value = 6.0
    if not isinstance(setup, str) and getattr(args, "robot", None) is not None:
        m = float(setup.robot.payload)
        value = m if m > 0 else value
    return [value] if many else value


def _add_servo(p, feedforward="rigid"):
    """The servo loop's flags (docs/conventions.md#servo)."""
    g = p.add_argument_group("servo loop", "drive the motors with a sampled PD servo instead of prescribing them "
                                           "(the paper's perfect controller); docs/conventions.md#servo")
    g.add_argument("--servo", type=float, metavar="FC",
                   help="closed-loop bandwidth fc [Hz] of the default gain rule (Kp = J (2 pi fc)^2, "
                        "Kd = 1.4 J (2 pi fc)); omitted: perfect controller")
    g.add_argument("--servo-rate", type=float, metavar="HZ",
                   help="servo sample rate [Hz] (default: the robot file's, else 8000)")
    g.add_argument("--rotor-inertia", type=float, metavar="J",
                   help="rotor inertia of each motor [kg m^2] (default: the robot file's if > 0, else 0.01)")
    g.add_argument("--feedforward", choices=("none", "rigid", "flexible"),
                   help="feedforward torque: none, rigid inverse dynamics, or the flexible model's "
                        f"(default: the robot file's, else {feedforward})")
    g.set_defaults(feedforward_default=feedforward)
    return g


def servo_options(args, setup=None) -> dict | None:
    """The servo flags as keyword arguments of ``servo.cycle_servo`` (fc, rate, rotor_inertia,
    feedforward, and the robot file's other settings); a flag given wins over the robot file's
    ``[servo]`` table (``setup``: ``run_setup``'s), which wins over the defaults. None when neither
    --servo nor the file sets fc."""
    own = setup is not None and not isinstance(setup, str)
    file = dict(setup.servo) if own and setup.servo is not None else {}
    given = lambda flag, default: flag if flag is not None else default
    fc = given(getattr(args, "servo", None), file.get("fc"))
    if fc is None:
        return None
    rotor = float(setup.robot.rotor_inertia) if own else 0.0
    return {**file, "fc": fc, "rate": given(args.servo_rate, file.get("rate", 8000.0)),
            "rotor_inertia": given(args.rotor_inertia, rotor if rotor > 0 else 0.01),
            "feedforward": args.feedforward or file.get("feedforward") or args.feedforward_default}


def build_parser() -> argparse.ArgumentParser:
    """The ``jaxflex`` argument parser (one subparser per command)."""
    parser = argparse.ArgumentParser(
        prog="jaxflex",
        description="Differentiable elastodynamics and vibration-aware trajectory design for a "
                    "flexible five-bar pick-and-place robot (float64, JAX).")
    from jaxflex import __version__

    parser.add_argument("--version", action="version", version=f"jaxflex {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("kinematics", help="Tables 2, 5, 6 and Figs. 6-8, 10, 11 (paper Section 3)",
                       description="Blend lengths (Table 2), max task acceleration (Table 5) and max "
                                   "joint acceleration (Table 6) of the 12 path-profile combinations, "
                                   "ours beside the paper's; optional figures.")
    _add_common(p)
    p.add_argument("--tf", type=float, default=1.0, help="motion time [s] (default: %(default)s)")
    p.add_argument("--steps", type=int, default=20000,
                   help="time steps over [0, tf] for the maxima (default: %(default)s)")
    p.add_argument("--out", metavar="DIR", help="write Figs. 6, 7, 8, 10, 11 (PNG) to DIR")
    _add_setup(p)

    p = sub.add_parser("modes", help="natural frequencies along the path (motors locked)",
                       description="Natural frequencies and their spread along the Adept path with "
                                   "the motors locked, linearized about the static equilibrium under "
                                   "gravity (paper Section 4).")
    _add_common(p)
    p.add_argument("--payload", type=float, help="payload mass [kg] (default: the robot file's, else 6)")
    p.add_argument("--points", type=int, default=21,
                   help="points equally spaced in arc length (default: %(default)s)")
    p.add_argument("--out", metavar="DIR", help="write a PNG of the first three frequencies to DIR")
    _add_setup(p)

    p = sub.add_parser("sweep", help="simulate the 12 path-profile combinations (paper Section 4)",
                       description="Inverse elastodynamic simulation (perfect controller) of the 12 "
                                   "blend x motion-law combinations for one payload and motion time, "
                                   "then a dwell at the place pose; every metric of docs/conventions.md#metrics "
                                   "per run.")
    _add_common(p)
    p.add_argument("--payload", type=float, help="payload mass [kg] (default: the robot file's, else 6)")
    p.add_argument("--tf", type=float, default=0.43, help="motion time [s] (default: %(default)s)")
    p.add_argument("--dt", type=float, default=None,
                   help="integration step [s] (default: 1e-4, converged; see REPORT.md)")
    p.add_argument("--dwell", type=float, default=0.1,
                   help="dwell after the motion, motors holding the place pose [s] (default: %(default)s)")
    p.add_argument("--repeats", type=int, default=3,
                   help="sweeps timed after the first, compiling, one; the run time printed is their median "
                        "(default: %(default)s; 0: the results only, no timing)")
    _add_servo(p)
    _add_setup(p)

    p = sub.add_parser("optimize", help="optimize the trajectory against the paper and industrial baselines",
                       description="Gradient-based optimization (reverse mode through the table build and "
                                   "the whole rollout, Adam) of a design - the blend parameters of both "
                                   "corners (default family: smoothstep, G4 joins) and a monotone motion "
                                   "law - minimizing the worst absolute residual vibration at the place "
                                   "point over a grid of models of the uncertainty box "
                                   "(docs/conventions.md#uncertainty-box); compared "
                                   "with the best of the 12 paper combinations, its ZV/ZVD input shaping "
                                   "and a Ruckig jerk-limited profile at equal time, on the nominal, "
                                   "perturbed (E +-5 %%, payload +-10 %%) and damped models and on random "
                                   "models of the box.")
    _add_common(p)
    p.add_argument("--payload", type=float, nargs="+",
                   help="payload mass(es) [kg]; several give one design robust over them (default: the robot "
                        "file's, else 6)")
    p.add_argument("--tf", type=float, default=0.43, help="motion time [s] (default: %(default)s)")
    p.add_argument("--steps", type=int, default=STUDY.train.optimizer.steps,
                   help="optimizer steps (default: %(default)s)")
    p.add_argument("--coef", type=int, metavar="N",
                   help=f"motion-law coefficients (default: {STUDY.n_coef}, or the --init design's; with --init, "
                        "more than its design has write its law with N coefficients: the same law, more "
                        "freedom to optimize)")
    p.add_argument("--lr", type=float, default=STUDY.train.optimizer.learning_rate,
                   help="Adam learning rate (linear warm-up over the first 10 %% of the steps, then "
                        "a cosine decay to a tenth; default: %(default)s)")
    p.add_argument("--train", default=STUDY.training_set, choices=TRAINING_SETS,
                   help="training models per payload: box (default: a --box-points^2 grid over E and the "
                        "payload mass of the uncertainty box); nominal; spanning (nominal plus the 4 "
                        "corners E x0.95/1.05, payload x0.9/1.1); perturbed (all 9: E x0.95/1/1.05, "
                        "payload x0.9/1/1.1)")
    p.add_argument("--blend", default=STUDY.train.blend, choices=DESIGN_BLENDS,
                   help="blend family of the optimized path (default: %(default)s, G4 joins)")
    p.add_argument("--objective", default="worst", choices=["worst", "relative"],
                   help="worst (default): smooth worst case (power mean of order 8) of the absolute "
                        "residuals over the training models; relative: weighted mean of each model's "
                        "residual divided by the best paper combination's on that model (the old objective)")
    p.add_argument("--box-young", type=float, default=STUDY.box.young, metavar="REL",
                   help="uncertainty box: Young's modulus half-width, relative (default: %(default)s)")
    p.add_argument("--box-payload", type=float, default=STUDY.box.payload, metavar="REL",
                   help="uncertainty box: payload half-width, relative (default: %(default)s)")
    p.add_argument("--box-damping", type=float, nargs=2, default=list(STUDY.box.damping), metavar=("LOW", "HIGH"),
                   help="uncertainty box: range of the damping ratio at the first mode (default: %(default)s)")
    p.add_argument("--box-length", type=float, default=STUDY.box.length, metavar="M",
                   help="uncertainty box: link-length half-width [m] (default: %(default)s)")
    p.add_argument("--box-rotor", type=float, default=STUDY.box.rotor, metavar="REL",
                   help="uncertainty box: rotor-inertia half-width, relative (default: %(default)s)")
    p.add_argument("--box-points", type=int, default=STUDY.box_points,
                   help="training grid points per axis (E, payload) of the box, odd (default: %(default)s)")
    p.add_argument("--box-samples", type=int, default=STUDY.box_samples,
                   help="random models of the box every trajectory is evaluated on after training "
                        "(0: none; default: %(default)s)")
    p.add_argument("--richer-modes", type=int, default=STUDY.richer_modes,
                   help="modes of each kind added to every link of the richer validation model (every "
                        "link in bending and tension) every trajectory is evaluated on (0: none; "
                        "default: %(default)s)")
    p.add_argument("--law-only", dest="free_path", action="store_false",
                   help="optimize the motion law only, on the best paper combination's path")
    p.add_argument("--init", metavar="FILE",
                   help="start from the design in FILE, the JSON of an earlier jaxflex optimize run (its "
                        "perfect-controller design: blends and law; of a --servo run that refined it, the refined "
                        "design, so a refinement continues where it ended; with --law-only its law); with "
                        "--steps 0 that design is evaluated, exported and, with --servo, refined as it is")
    p.add_argument("--verify", action="store_true",
                   help="re-simulate the best paper combination and the optimized trajectory at a quarter "
                        "step and with the full nonlinear model (exponential integrator, step 2e-5 s; this adds to the "
                        "run time)")
    p.add_argument("--out", metavar="DIR",
                   help="write optimize.json, trajectory.csv (t,x,y,q1,q2 at 10 kHz), figures and a "
                        "checkpoint to DIR; rerunning with the same DIR resumes")
    p.add_argument("--export-rate", type=float, default=10_000.0, metavar="HZ",
                   help="sample rate of trajectory.csv [Hz] (default: %(default)s)")
    _add_setup(p)
    g = _add_servo(p, feedforward="flexible")
    g.description = ("then judge the designs under a sampled PD servo of bandwidth FC: refine the design with "
                     "the servo in the loop (the feedforward given to the design: --feedforward, default "
                     "flexible; the paper's combinations and the baselines get the rigid one) and compare "
                     "them at FC and the --servo-fcs bandwidths on the nominal model and the boxes of "
                     "the robot and the controller (fc +-20 %, rate 4-16 kHz, rotor +-10 %); "
                     "docs/conventions.md#servo")
    g.add_argument("--servo-steps", type=int, default=20, metavar="N",
                   help="optimizer steps with the servo in the loop (0: the perfect controller's design "
                        "as is; default: %(default)s)")
    g.add_argument("--servo-scenarios", type=int, default=SCENARIOS, metavar="N",
                   help="models added to the refinement's training set: those on which the design does worst "
                        f"among {SCENARIO_POOL} random models of both boxes (apart from the evaluation's) and the 32 "
                        "corners (0: the fixed training models only, --servo-training; default: %(default)s)")
    g.add_argument("--servo-training", choices=SERVO_TRAININGS, default="fixed",
                   help="the refinement's fixed training models: 'fixed', the nominal model and eight corners "
                        "of the boxes; 'corners', the nominal model and all 32 corners (about four times the "
                        "rollouts per step; default: %(default)s)")
    g.add_argument("--servo-power", type=float, default=ROBUST_POWER, metavar="P",
                   help="order of the power mean over the training models (larger: closer to the worst "
                        "model; default: %(default)s)")
    g.add_argument("--servo-objective", choices=SERVO_OBJECTIVES, default="dwell",
                   help="what the refinement minimizes on each model: 'dwell', the dwell residual's mean "
                        "square; 'peak', a smooth maximum of it over the dwell, closer to the reported residual; "
                        "'energy+dwell', the mean square with the vibration energy at tf beside it, as the "
                        "perfect controller's optimizer (misleading under a servo, which keeps acting after tf: "
                        "docs/conventions.md#servo; default: %(default)s)")
    g.add_argument("--servo-lr", type=float, default=SERVO_LEARNING_RATE, metavar="LR",
                   help="Adam learning rate of the refinement (default: %(default)s)")
    g.add_argument("--servo-rounds", type=int, default=1, metavar="N",
                   help="refinements in a row, each from the last one's design with its scenarios picked "
                        "again (default: %(default)s)")
    g.add_argument("--servo-samples", type=int, default=200, metavar="N",
                   help="random models of both boxes each trajectory is evaluated on under the servo "
                        "(default: %(default)s)")
    g.add_argument("--servo-fcs", type=float, nargs="*", default=[15.0, 40.0], metavar="FC",
                   help="bandwidths [Hz] of the closed-loop comparison besides FC (default: 15 40)")
    g.add_argument("--no-servo-corners", dest="servo_corners", action="store_false",
                   help="skip the 32 corners of the boxes in the closed-loop comparison")
    p.add_argument("--cycle-time", nargs="*", type=float, metavar="TF",
                   help="instead: the cycle-time study for the first payload: optimize a design at each "
                        "motion time TF [s] (default: 0.43 0.40 0.37 0.34 0.31) and report the shortest one "
                        "whose residual is no worse than the best paper combination at --tf, with the peak "
                        "torque bounded by poly7-Lame's at --tf; with --out, cycle_time.json and the "
                        "Pareto figure cycle_time.png")

    p = sub.add_parser("bench", help="compile and run times of the batched sweep and of a gradient",
                       description="Benchmarks: compile time and median run time of the 24-rollout "
                                   "sweep (12 combinations x 2 paper cases) and of one gradient of the "
                                   "residual objective; steps per second and peak memory.")
    p.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")
    p.add_argument("--repeats", type=int, default=5, help="timed repeats (default: %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help="the sweep and the design gradient only (no forward-only or law timings)")
    p.add_argument("--servo", type=float, metavar="FC",
                   help="also time the 24 rollouts under a sampled PD servo of bandwidth FC [Hz] (8 kHz, "
                        "0.01 kg m^2 rotor, rigid feedforward, each payload's default gains; "
                        "docs/conventions.md#servo)")

    p = sub.add_parser("reproduce", help="the main job: every table and figure of the paper",
                       description="Reproduce the paper's tables and figures, ours beside the "
                                   "paper's with relative differences, as REPORT.md + CSV/JSON + "
                                   "PNG figures in DIR.")
    p.add_argument("--out", metavar="DIR", default="results",
                   help="output directory (default: %(default)s)")
    p.add_argument("--no-vibration", dest="vibration", action="store_false",
                   help="skip the vibration study (Tables 7-11, Fig. 12, convergence checks)")
    p.add_argument("--no-optimize", dest="optimize", action="store_false",
                   help="skip the optimization study (beyond the paper: optimized trajectories vs the "
                        "baselines, cycle-time study)")
    p.add_argument("--no-closed-loop", dest="closed_loop", action="store_false",
                   help="skip the closed-loop study (designs refined with a servo in the loop, compared under it "
                        "at 15 and 40 Hz)")
    p.add_argument("--refine", action="store_true",
                   help="in the closed-loop study, refine the optimization studies' designs with the servo in the "
                        "loop in this run (40 steps per payload and bandwidth, about an hour on 2 cores) instead "
                        "of evaluating the designs shipped in examples/designs")
    p.add_argument("--quick", action="store_true",
                   help="coarser grids and fewer points, no convergence or full-model checks: a fast "
                        "smoke run (not for publication)")
    p.add_argument("--fresh", action="store_true",
                   help="compute every section again instead of resuming; without it a rerun into the same DIR "
                        "reuses the sections computed by the same code (a digest of its sources) in the same mode")
    return parser


def _enable_compilation_cache(jax) -> None:
    """Persistent XLA compilation cache (JAXFLEX_CACHE_DIR, default ~/.cache/jaxflex/jax; set it to
    an empty string to disable): repeated CLI runs skip most compilation. The durations of earlier
    compilations and reproduce sections are kept beside it (jaxflex-timings.json) for the ETAs."""
    import os

    cache = os.environ.get("JAXFLEX_CACHE_DIR",
                           os.path.join(os.path.expanduser("~"), ".cache", "jaxflex", "jax"))
    if cache:
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
        from jaxflex import progress

        progress.remember(os.path.join(cache, "jaxflex-timings.json"))    # ETAs of compilations


def main(argv=None) -> int:
    """Console entry point: parse ``argv`` (default: sys.argv), enable float64, the persistent
    compilation cache and the heap trimming (``jaxflex.runtime.heap``), run the command; returns the exit
    status (2 on bad input)."""
    import jax

    from jaxflex.runtime import heap

    heap.start_trimming()
    if "MPLBACKEND" not in os.environ:          # the commands only write figure files: no window
        import matplotlib

        matplotlib.use("Agg")
    jax.config.update("jax_enable_x64", True)
    _enable_compilation_cache(jax)
    args = build_parser().parse_args(argv)
    if args.command is None:
        build_parser().print_help()
        return 0
    try:
        if args.command == "kinematics":
            from jaxflex.experiments import kinematics

            kinematics.run(run_setup(args), args.tf, out=args.out, json_path=args.json, steps=args.steps)
        elif args.command == "modes":
            from jaxflex.experiments import modes

            setup = run_setup(args)
            modes.run(setup, file_payloads(args, setup, False), args.points, json_path=args.json, out=args.out)
        elif args.command == "sweep":
            from jaxflex.experiments import sweep

            setup = run_setup(args)
            sweep.run(setup, file_payloads(args, setup, False), args.tf, args.dt, args.dwell, json_path=args.json,
                      servo=servo_options(args, setup), repeats=args.repeats)
        elif args.command == "optimize":
            from jaxflex.experiments import optimize

            setup = run_setup(args)
            payloads = file_payloads(args, setup, True)
            config = study_config(args)
            if args.cycle_time is not None:
                tfs = tuple(args.cycle_time) or (0.43, 0.40, 0.37, 0.34, 0.31)
                optimize.run_cycle_time(setup, payloads[0], args.tf, tfs, out=args.out,
                                        json_path=args.json, config=config)
            else:
                closed = None
                options = servo_options(args, setup)
                if options is not None:
                    closed = {**options, "steps": args.servo_steps, "samples": args.servo_samples,
                              "fcs": tuple(args.servo_fcs), "corners": args.servo_corners,
                              "scenarios": args.servo_scenarios, "training": args.servo_training,
                              "power": args.servo_power, "learning_rate": args.servo_lr,
                              "objective": args.servo_objective,
                              "rounds": args.servo_rounds}
                optimize.run(setup, tuple(payloads), args.tf, out=args.out, json_path=args.json,
                             verify=args.verify, config=dataclasses.replace(config, free_path=args.free_path),
                             export_rate=args.export_rate, closed_loop=closed)
        elif args.command == "bench":
            from jaxflex.experiments import bench

            bench.run(repeats=args.repeats, json_path=args.json, quick=args.quick, servo=args.servo)
        elif args.command == "reproduce":
            from jaxflex.experiments import reproduce

            reproduce.run(args.out, quick=args.quick, vibration=args.vibration, optimize=args.optimize,
                          closed_loop=args.closed_loop, fresh=args.fresh, refine=args.refine)
    except ValueError as err:
        print(f"jaxflex {args.command}: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\njaxflex {args.command}: interrupted. Outputs are written atomically (no half-written "
              "files); rerun the same command to resume from the finished sections and checkpoints.",
              file=sys.stderr)
        return 130
    except Exception as err:        # noqa: BLE001 - an unexpected failure: one line, not a traceback
        if os.environ.get("JAXFLEX_TRACEBACK"):
            traceback.print_exc()
        print(f"jaxflex {args.command}: failed: {type(err).__name__}: {_one_line(err)} (set "
              "JAXFLEX_TRACEBACK=1 for the traceback)", file=sys.stderr)
        return 1
    return 0


def study_config(args) -> StudyConfig:
    """The ``StudyConfig`` of ``jaxflex optimize``'s arguments (validated when the study starts)."""
    worst = args.objective == "worst"
    init = None
    if getattr(args, "init", None):
        from jaxflex.experiments.io import initial_design

        init = initial_design(args.init, args.blend if args.free_path else None, STUDY.train.order, args.coef)
    return dataclasses.replace(
        STUDY.with_optimizer(steps=args.steps, learning_rate=args.lr).with_train(
            blend=args.blend, power=ROBUST_POWER if worst else 1.0),
        n_coef=(len(init.coef) if init is not None else STUDY.n_coef) if args.coef is None else args.coef,
        training_set=args.train, absolute=worst,
        box=Box(args.box_young, args.box_payload, tuple(args.box_damping), args.box_length, args.box_rotor).checked(),
        box_points=args.box_points, box_samples=args.box_samples, richer_modes=args.richer_modes, init=init)


HUGEPAGES = "glibc.malloc.hugetlb=1"


def hugepages_env() -> dict | None:
    """The environment to re-run the command in with glibc's malloc on transparent huge pages, or
    None when that does not apply: JAXFLEX_HUGEPAGES=0, not Linux with glibc, huge pages off
    (``/sys/kernel/mm/transparent_hugepage/enabled`` is "never"), or already set in GLIBC_TUNABLES.

    Why: XLA:CPU allocates and frees large buffers at every run of a program, and with 4 KiB pages
    every new buffer costs page faults, so an optimization spends a large share of its CPU time in
    the kernel. Huge pages take far fewer page faults and shorten the run; the results are the same
    (memory placement only; figures in docs/performance.md). glibc reads the tunable only at
    start-up, hence the re-execution."""
    import platform

    tunables = os.environ.get("GLIBC_TUNABLES", "")
    if os.environ.get("JAXFLEX_HUGEPAGES", "1") == "0" or "glibc.malloc.hugetlb" in tunables:
        return None
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return None
    try:
        with open("/sys/kernel/mm/transparent_hugepage/enabled") as f:
            if "[never]" in f.read():
                return None
    except OSError:
        return None
    return dict(os.environ, GLIBC_TUNABLES=f"{tunables}:{HUGEPAGES}" if tunables else HUGEPAGES)


def entry() -> None:  # pragma: no cover - the console script; tests call main() and hugepages_env()
    """The ``jaxflex`` console script: ``main`` on sys.argv, re-executed once with huge pages for
    malloc where that applies (``hugepages_env``)."""
    env = hugepages_env()
    if env is not None:
        try:
            os.execve(sys.executable, [sys.executable, "-m", "jaxflex.experiments.cli", *sys.argv[1:]], env)
        except OSError:
            pass                                    # run as we are
    sys.exit(main())


def _one_line(err: BaseException) -> str:
    """The exception's message on one line (XLA and numpy messages can span many)."""
    text = " ".join(str(err).split())
    return text if len(text) <= 500 else text[:497] + "..."


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
