"""Teaching and simulation subcommands: ``simulate``, ``demo``, ``calibrate``, ``teach``.

``odofuse.cli`` imports this module when present and calls :func:`register` with its
``COMMANDS`` table (name -> ``(add_arguments, handler)``). Handlers return an exit status and
raise :class:`odofuse.errors.OdofuseError` for bad input, which the CLI prints on one line.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from odofuse.errors import ConfigError, OdofuseError

__all__ = ["register", "cmd_simulate", "cmd_demo", "cmd_calibrate", "cmd_teach"]


def _as_config_error(exc: ValueError) -> OdofuseError:
    return exc if isinstance(exc, OdofuseError) else ConfigError(str(exc))


# ------------------------------------------------------------------------------- simulate
def _simulate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "scenario",
        nargs="?",
        help="scenario YAML (configs/sim-*.yaml); "
        "default: a differential robot on a 4 m counter-clockwise square",
    )
    p.add_argument("-o", "--out", required=True, help="log folder to write")
    p.add_argument("--seed", type=int, help="override the scenario's seed")
    p.add_argument(
        "--path", choices=("square", "figure_eight"), help="replace the scenario's path by this one"
    )
    p.add_argument("--direction", choices=("cw", "ccw"), help="square direction")
    p.add_argument("--E-d", dest="E_d", type=float, help="true right/left wheel diameter ratio")
    p.add_argument("--E-b", dest="E_b", type=float, help="true/nominal wheelbase ratio")


def _scenario_from_args(args):
    from dataclasses import replace

    from odofuse.teaching.simulate import Scenario, load_scenario

    sc = load_scenario(args.scenario) if args.scenario else Scenario()
    path = dict(sc.path)
    if getattr(args, "path", None):
        path = {"kind": args.path}
    if getattr(args, "direction", None):
        if path.get("kind", "square") != "square":
            raise ConfigError("--direction applies to square paths only")
        path["direction"] = args.direction
    sys_errors = sc.systematic
    if getattr(args, "E_d", None) is not None:
        sys_errors = replace(sys_errors, E_d=args.E_d)
    if getattr(args, "E_b", None) is not None:
        sys_errors = replace(sys_errors, E_b=args.E_b)
    sc = replace(sc, path=path, systematic=sys_errors)
    if getattr(args, "seed", None) is not None:
        sc = replace(sc, seed=args.seed)
    return sc


def cmd_simulate(args) -> int:
    """Simulate a robot from a scenario and write a log folder (ground truth included)."""
    from odofuse.teaching.simulate import simulate, write_log

    try:
        sim = simulate(_scenario_from_args(args))
        written = write_log(sim, args.out)
    except ValueError as exc:
        raise _as_config_error(exc) from None
    final = sim.truth[-1]
    print(
        f"simulated {len(sim.twists_cmd)} steps ({sim.t[-1]:.1f} s) of a "
        f"{sim.scenario.drive} robot, seed {sim.scenario.seed}"
    )
    print(f"true final pose: x={final[0]:.4f} m, y={final[1]:.4f} m, theta={final[2]:.4f} rad")
    for name, s in sim.streams.items():
        print(f"  {name}.csv: {len(s)} rows")
    print(f"wrote {len(written)} files to {args.out}")
    return 0


# ------------------------------------------------------------------------------- demo
#: Demo names (kept here so building the parser does not import matplotlib).
DEMO_NAMES = ("drive_zoo", "error_growth", "fusion", "gyrodometry", "integration", "systematic")


def _demo_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "name",
        nargs="?",
        choices=[*DEMO_NAMES, "all"],
        help="demo to run ('all' runs every one)",
    )
    p.add_argument("-o", "--out", default="odofuse-demos", help="folder for the PNGs")
    p.add_argument(
        "--quick", action="store_true", help="fewer samples (seconds instead of minutes)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--list", action="store_true", help="list the demos and exit")


def cmd_demo(args) -> int:
    """Run a teaching demo: writes a PNG and prints its numbers."""
    from odofuse.teaching.demos import DEMOS, run_demo

    if args.list or not args.name:
        for name, fn in sorted(DEMOS.items()):
            print(f"{name:14s} {(fn.__doc__ or '').strip().splitlines()[0]}")
        return 0
    names = sorted(DEMOS) if args.name == "all" else [args.name]
    for name in names:
        result = run_demo(name, out_dir=args.out, quick=args.quick, seed=args.seed)
        print(f"== {name}: {result['png']}")
        print(json.dumps(result["numbers"], indent=2, default=float))
    return 0


# ------------------------------------------------------------------------------- calibrate
def _calibrate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("method", choices=("umbmark",), help="calibration procedure")
    p.add_argument(
        "scenario",
        nargs="?",
        help="scenario YAML of the robot to calibrate in simulation (default: a "
        "differential robot with E_d = 1.002, E_b = 1.01)",
    )
    p.add_argument(
        "--cw",
        nargs="+",
        metavar="LOG",
        help="clockwise square log folders "
        "(with groundtruth.csv and config.yaml) instead of a simulation",
    )
    p.add_argument("--ccw", nargs="+", metavar="LOG", help="counter-clockwise square log folders")
    p.add_argument("--runs", type=int, default=5, help="runs per direction (simulation)")
    p.add_argument("--side", type=float, default=4.0, help="square side length L, m")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--E-d", dest="E_d", type=float, help="true E_d of the simulated robot")
    p.add_argument("--E-b", dest="E_b", type=float, help="true E_b of the simulated robot")
    p.add_argument(
        "--method",
        dest="estimate",
        choices=("exact", "linear"),
        default="exact",
        help="exact geometry (default) or Borenstein's linear formulas",
    )
    p.add_argument("-o", "--out", help="folder for umbmark.png and umbmark.json")


def cmd_calibrate(args) -> int:
    """Calibrate systematic odometry errors (UMBmark, Borenstein & Feng 1996)."""
    from dataclasses import replace

    from odofuse.teaching import umbmark as cal
    from odofuse.teaching.simulate import Scenario, SystematicErrors, load_scenario

    try:
        if args.cw or args.ccw:
            if not (args.cw and args.ccw):
                raise ConfigError("UMBmark needs both --cw and --ccw logs")
            res = cal.umbmark_from_logs(args.cw, args.ccw, args.side, method=args.estimate)
            summary = res
        else:
            if args.scenario:
                sc = load_scenario(args.scenario)
            else:
                sc = Scenario(systematic=SystematicErrors(E_d=1.002, E_b=1.01), dt=0.05)
            se = sc.systematic
            se = replace(
                se,
                E_d=se.E_d if args.E_d is None else args.E_d,
                E_b=se.E_b if args.E_b is None else args.E_b,
            )
            sc = replace(sc, systematic=se)
            report = cal.calibrate_umbmark(
                sc, runs=args.runs, side=args.side, seed=args.seed, method=args.estimate
            )
            summary = {"true_E_d": se.E_d, "true_E_b": se.E_b, **report.summary()}
            if args.out:
                from odofuse.teaching.demos import plot_umbmark

                Path(args.out).mkdir(parents=True, exist_ok=True)
                png = plot_umbmark(report, args.side, Path(args.out) / "umbmark.png")
                summary["png"] = str(png)
    except ValueError as exc:
        raise _as_config_error(exc) from None
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        (Path(args.out) / "umbmark.json").write_text(json.dumps(summary, indent=2, default=float))
    print(json.dumps(summary, indent=2, default=float))
    return 0


# ------------------------------------------------------------------------------- teach
def _teach_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "-o",
        "--out",
        default="odofuse-teach",
        help="folder for odofuse-teach.html (one self-contained page: open it in a browser, "
        "no server or network needed)",
    )


def cmd_teach(args) -> int:
    """Write the interactive teaching page (error growth, UMBmark, drives, fusion)."""
    from odofuse.teaching.web import write_page

    try:
        path = write_page(args.out)
    except OSError as exc:
        raise ConfigError(f"cannot write the teaching page into {args.out}: {exc}") from None
    size = path.stat().st_size
    print(f"wrote {path} ({size / 1024:.0f} KiB); open it in a browser: {path.resolve().as_uri()}")
    return 0


def register(commands) -> None:
    """Add ``simulate``, ``demo``, ``calibrate`` and ``teach`` to the CLI's ``COMMANDS`` table."""
    commands["simulate"] = (_simulate_args, cmd_simulate)
    commands["demo"] = (_demo_args, cmd_demo)
    commands["calibrate"] = (_calibrate_args, cmd_calibrate)
    commands["teach"] = (_teach_args, cmd_teach)
