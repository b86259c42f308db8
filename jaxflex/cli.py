"""The ``jaxflex`` command line (SPEC 7). Each subcommand is a thin call into ``jaxflex.experiments``."""
from __future__ import annotations

import argparse
import sys


def _add_common(p, preset=True):
    if preset:
        p.add_argument("--preset", default="default", choices=["default", "table6"],
                       help="robot geometry preset (SPEC 2; default: %(default)s)")
    p.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxflex",
        description="Differentiable elastodynamics and vibration-aware trajectory design for a "
                    "flexible five-bar pick-and-place robot (float64, JAX).")
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

    p = sub.add_parser("modes", help="natural frequencies along the path (motors locked)",
                       description="Natural frequencies and their spread along the Adept path with "
                                   "the motors locked, linearized about the static equilibrium under "
                                   "gravity (paper Section 4).")
    _add_common(p)
    p.add_argument("--payload", type=float, default=6.0, help="payload mass [kg] (default: %(default)s)")
    p.add_argument("--points", type=int, default=21,
                   help="points equally spaced in arc length (default: %(default)s)")
    p.add_argument("--out", metavar="DIR", help="write a PNG of the first three frequencies to DIR")

    p = sub.add_parser("reproduce", help="the main job: every table and figure of the paper",
                       description="Reproduce the paper's tables and figures, ours beside the "
                                   "paper's with relative differences, as REPORT.md + CSV/JSON + "
                                   "PNG figures in DIR.")
    p.add_argument("--out", metavar="DIR", default="results",
                   help="output directory (default: %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help="coarser grids and fewer points: a fast smoke run (not for publication)")
    return parser


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    args = build_parser().parse_args(argv)
    if args.command is None:
        build_parser().print_help()
        return 0
    try:
        if args.command == "kinematics":
            from jaxflex.experiments import kinematics

            kinematics.run(args.preset, args.tf, out=args.out, json_path=args.json, steps=args.steps)
        elif args.command == "modes":
            from jaxflex.experiments import modes

            modes.run(args.preset, args.payload, args.points, json_path=args.json, out=args.out)
        elif args.command == "reproduce":
            from jaxflex.experiments import reproduce

            reproduce.run(args.out, quick=args.quick)
    except ValueError as err:
        print(f"jaxflex {args.command}: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
