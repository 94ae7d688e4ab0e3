"""The ``odofuse`` command (shared spec section 4).

Subcommands live in :data:`COMMANDS` (name -> ``(add_arguments, handler)``); a module
``odofuse.teaching.cli`` with a ``register(commands)`` function, if present, adds its own
(simulate, demo, calibrate). Every handler gets the parsed ``argparse.Namespace`` and returns an
exit status. Bad input (:class:`odofuse.errors.OdofuseError`, missing files) is printed as one
line ``odofuse: error: <message>`` on stderr with exit status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

from odofuse.errors import OdofuseError, one_line

#: Estimators compared by ``odofuse run`` without a config, each with its packaged config.
DEFAULT_ESTIMATORS = ("dead_reckoning", "ekf", "ukf", "smoother")
DEFAULT_DATASET = "plaza1"
DEFAULT_OUT = "odofuse-out"

Handler = Callable[[argparse.Namespace], int]
COMMANDS: dict[str, tuple[Callable[[argparse.ArgumentParser], None], Handler]] = {}


def command(name: str, add_arguments: Callable[[argparse.ArgumentParser], None]):
    """Decorator registering ``handler`` as subcommand ``name`` in :data:`COMMANDS`."""

    def deco(handler: Handler) -> Handler:
        COMMANDS[name] = (add_arguments, handler)
        return handler

    return deco


def default_config_path(estimator: str, dataset: str = DEFAULT_DATASET) -> Path:
    """Path of the packaged config ``odofuse/default_configs/<dataset>-<estimator>.yaml``."""
    from importlib.resources import files

    return Path(str(files("odofuse") / "default_configs" / f"{dataset}-{estimator}.yaml"))


def default_config(estimator: str, dataset: str = DEFAULT_DATASET):
    """The packaged default :class:`odofuse.config.RunConfig` for ``estimator``."""
    from odofuse.config import load_config

    path = default_config_path(estimator, dataset)
    if not path.exists():
        from odofuse.errors import ConfigError

        raise ConfigError(f"no packaged default config for estimator '{estimator}'", str(path))
    return load_config(path)


def progress(iterable, **kw):
    """tqdm progress bar on stderr, silent when stderr is not a terminal."""
    from tqdm import tqdm

    return tqdm(iterable, file=sys.stderr, disable=not sys.stderr.isatty(), **kw)


# --------------------------------------------------------------------------------------- run
def _run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "config",
        nargs="?",
        help="run config (YAML); omitted: the embedded default "
        f"(builtin:{DEFAULT_DATASET} with {', '.join(DEFAULT_ESTIMATORS)})",
    )
    p.add_argument(
        "-o", "--out", help=f"output folder (default: the config's output or '{DEFAULT_OUT}')"
    )
    p.add_argument("--estimator", help="override the config's estimator")
    p.add_argument(
        "--rerun", action="store_true", help="also write trajectory.rrd (a Rerun recording)"
    )


def _fmt(v) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.3f}"


def print_table(rows: list[dict], file=None) -> None:
    """Print the comparison table (estimator, position RMSE, final error, runtime, status),
    then each run's warnings and advice, one line each.

    ``runtime [s]`` is the estimator's own; a row with ``second_opinion_s`` (the batch
    smoother run of the cross-check, :mod:`odofuse.status.cross_check`) adds the column
    ``2nd opinion [s]``, so the printed times add up to the wall time of the check."""
    file = file or sys.stdout
    second = any(r.get("second_opinion_s") is not None for r in rows)
    head = ("estimator", "position RMSE [m]", "final error [m]", "runtime [s]")
    head += ("2nd opinion [s]",) * second + ("status",)
    table = [head] + [
        (
            r["estimator"],
            _fmt(r.get("ate_rmse_m")),
            _fmt(r.get("final_error_m")),
            _fmt(r.get("runtime_s")),
            *((_fmt(r.get("second_opinion_s")),) * second),
            r.get("status", "ok"),
        )
        for r in rows
    ]
    widths = [max(len(row[i]) for row in table) for i in range(len(head) - 1)]
    for row in table:
        pairs = enumerate(zip(row[:-1], widths, strict=True))
        cells = [c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in pairs]
        print("  ".join(cells + [row[-1]]), file=file)
    for r in rows:
        for line in r.get("warnings", ()):
            print(f"warning: {r['estimator']}: {line}", file=file)
    for r in rows:  # accuracy against another estimator: advice, never the status
        for line in r.get("advice", ()):
            print(f"advice: {r['estimator']}: {line}", file=file)


@command("run", _run_args)
def cmd_run(args: argparse.Namespace) -> int:
    """Run an estimator on a log (or compare the default estimators on Plaza1)."""
    from odofuse.config import load_config
    from odofuse.estimators.compiled import warm
    from odofuse.io.loader import load_log_for
    from odofuse.rundir import run_one, smoother_reference

    if args.config:
        config = load_config(args.config)
        if args.estimator:
            config = dataclasses.replace(config, estimator=args.estimator)
        log = load_log_for(config)
        out = Path(args.out or config.output or DEFAULT_OUT)
        # the smoother reuses its own run; any other estimator's second opinion is timed
        reference = smoother_reference(config, log) if config.estimator != "smoother" else None
        m = run_one(config, log, out, reference)
        if args.rerun:  # issue 27: the run viewable after the fact (odofuse.live.rerun_log)
            from odofuse.live.rerun_log import write_rerun
            from odofuse.outputs import read_trajectory_csv

            traj = read_trajectory_csv(out / "trajectory.csv")
            write_rerun(out / "trajectory.rrd", traj, config, log, m)
        row = _row(config.estimator, config, m)
        _second_opinion([row], reference)
        print_table([row])
        if row.get("note"):
            print(f"note: {row['estimator']}: {row['note']}")
        unfused = config.unfused_note()  # a config that forgot `estimator:`: dead reckoning
        if unfused:
            print(unfused)
        print(f"outputs in {out}/")
        return 0
    names = [args.estimator] if args.estimator else list(DEFAULT_ESTIMATORS)
    # NAME's packaged config (configs/plaza1-NAME.yaml; slam: the smoother with unknown
    # beacons); an estimator without one runs with the dead-reckoning config
    own = {name for name in names if default_config_path(name).exists()}
    configs = {
        name: default_config(name)
        if name in own
        else dataclasses.replace(default_config(DEFAULT_ESTIMATORS[0]), estimator=name)
        for name in names
    }
    # a fresh install: the UKF's kernels compile on the other core while the EKF runs
    background = warm.start(
        [
            (name, default_config_path(name if name in own else DEFAULT_ESTIMATORS[0]))
            for name in warm.plan(configs)
        ]
    )
    log = load_log_for(next(iter(configs.values())))
    out = Path(args.out or DEFAULT_OUT)
    rows, failed = [], 0
    # one packaged batch smoother run (when needed): the others' cross-check, the smoother's row
    reference = smoother_reference(configs.get("smoother") or default_config("smoother"), log)
    try:
        for name in progress(names, desc="estimators", unit="run"):
            cfg = configs[name]
            # a config named otherwise than its estimator (slam) is its own run, not the reference
            ref = reference if cfg.estimator == name or cfg.estimator != "smoother" else None
            if background:
                background.wait(name)
            try:
                rows.append(_row(name, cfg, run_one(cfg, log, out / name, ref)))
            except Exception as exc:  # one failing estimator must not hide the others
                failed += 1
                rows.append({"estimator": name, "status": f"failed: {one_line(exc)}"})
    finally:
        if background:
            background.stop()
    _second_opinion(rows, reference)
    print(
        f"builtin:{DEFAULT_DATASET}: {len(log.streams['odometry'])} odometry steps, "
        f"{len(log.streams['ranges'])} ranges to {len(log.landmarks)} beacons"
    )
    print_table(rows)
    for r in rows:
        if r.get("note"):
            print(f"note: {r['estimator']}: {r['note']}")
    if any(r.get("second_opinion_s") is not None for r in rows):
        print(
            "note: 2nd opinion: one batch smoother run of the same log (the cross-check), "
            "shared by the rows"
            + (" (the smoother row is that run)" if "smoother" in names else "")
        )
    print(f"outputs in {out}/<estimator>/")
    return 1 if failed else 0


def _second_opinion(rows: list[dict], reference) -> None:
    """Give each row whose cross-check ran the runtime of the smoother run it used (one run,
    shared by the rows of ``odofuse run`` without a config)."""
    if reference is None or not reference.cache_info().currsize:
        return  # never needed: no row was checked against it
    took = reference().runtime_s
    for r in rows:
        block = r.get("cross_check")
        if isinstance(block, dict) and "skipped" not in block:
            r["second_opinion_s"] = took


def _row(name: str, config, metrics: dict) -> dict:
    """The table row of ``config`` as ``name``: a SLAM run (beacons estimated, so the map
    frame is free) is named ``slam`` and shows its position RMSE after SE(2) alignment, with
    a note."""
    slam = bool(getattr(config.estimator_options(), "slam", False))
    row = {**metrics, "estimator": "slam" if slam else name}
    if slam and metrics.get("ate_aligned_rmse_m") is not None:
        row["note"] = (
            f"position RMSE after SE(2) alignment (the beacons are estimated, so the map frame "
            f"is free); unaligned {_fmt(metrics.get('ate_rmse_m'))} m (metrics.json "
            "ate_rmse_m; ate_aligned_rmse_m is the figure shown)"
        )
        row["ate_rmse_m"] = metrics["ate_aligned_rmse_m"]
    return row


# ------------------------------------------------------------------------------------- batch
def _batch_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="run config (YAML); its log: is replaced by each LOG")
    p.add_argument("logs", nargs="+", metavar="LOG", help="log folders, bags, graph files, globs")
    p.add_argument("-o", "--out", required=True, help="output folder (OUT/<log name>/, summary)")
    p.add_argument("--workers", type=int, help="local Dask workers (default: the cores)")
    p.add_argument("--scheduler", help="address of a running Dask scheduler (tcp://HOST:PORT)")
    p.add_argument("--estimator", help="override the config's estimator")
    p.add_argument("--force", action="store_true", help="redo logs whose outputs exist")
    p.add_argument("--split", help="cut each log into windows of DURATION (600s, 30m, 4h)")
    p.add_argument("--overlap", help="overlap of the --split windows (default 10%% of DURATION)")


@command("batch", _batch_args)
def cmd_batch(args: argparse.Namespace) -> int:
    """Run one config over many logs on Dask (local cluster or --scheduler), with a summary."""
    from odofuse.batch import parse_duration, print_summary, run_batch

    started = time.perf_counter()
    split = parse_duration(args.split) if args.split else None
    overlap = parse_duration(args.overlap) if args.overlap else None
    client = None
    if args.scheduler:
        from distributed import Client

        client = Client(args.scheduler, timeout="30s")
    try:
        records = run_batch(
            args.config,
            args.logs,
            args.out,
            client,
            workers=args.workers,
            estimator=args.estimator,
            force=args.force,
            split=split,
            overlap=overlap,
        )
    finally:
        if client is not None:
            client.close()
    print_summary(records, Path(args.out), started=started)
    return 1 if records.failed else 0


# ------------------------------------------------------------------------------------ export
def _export_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="builtin:NAME (plaza1, plaza2), or any readable log")
    p.add_argument("dir", help="folder to write the CSV log into")


@command("export", _export_args)
def cmd_export(args: argparse.Namespace) -> int:
    """Export a built-in dataset (or any log) as a CSV log folder."""
    from odofuse.io.csvlog import write_csv_log
    from odofuse.io.loader import load_log

    log = load_log(args.log)
    paths, changes = write_csv_log(log, args.dir)
    for p in paths:
        print(p)
    for k, v in sorted({**log.repairs, **changes}.items()):
        print(f"note: {k} = {v}")
    if log.initial_pose is not None:
        x, y, th = (float(v) for v in log.initial_pose)
        print(
            f"initial pose of the dataset: [{x:.6g}, {y:.6g}, {th:.6g}] "
            f"(put it in initial.pose of a config)"
        )
    return 0


# -------------------------------------------------------------------------------------- eval
def _eval_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("estimate", help="trajectory.csv, a run folder, or a TUM file")
    p.add_argument("groundtruth", help="groundtruth.csv, trajectory.csv or a TUM file")
    p.add_argument("--align", action="store_true", help="rigid 2-D alignment before the ATE")
    p.add_argument("--delta", type=float, default=10.0, help="RPE segment length (default 10)")
    p.add_argument("--unit", choices=("m", "s"), default="m", help="RPE delta unit (m or s)")
    p.add_argument("--json", action="store_true", help="print the numbers as JSON")


@command("eval", _eval_args)
def cmd_eval(args: argparse.Namespace) -> int:
    """Compare an estimated trajectory with ground truth (ATE, RPE, NEES)."""
    from odofuse.evaluation import ate, nees, rpe
    from odofuse.outputs import read_trajectory

    est = read_trajectory(args.estimate)
    gt = read_trajectory(args.groundtruth)
    a = ate(est, gt, align=args.align)
    r = rpe(est, gt, args.delta, args.unit)
    out = {
        "poses": int(a.errors.size),
        "aligned": a.aligned,
        "ate_rmse_m": a.rmse_m,
        "ate_mean_m": a.mean_m,
        "ate_max_m": a.max_m,
        "final_error_m": a.final_m,
        "heading_rmse_rad": a.rot_rmse_rad,
        f"rpe_trans_m_per_{args.delta:g}{args.unit}": r.trans_rmse_m,
        f"rpe_rot_rad_per_{args.delta:g}{args.unit}": r.rot_rmse_rad,
    }
    n = nees(est, gt) if not args.align else math.nan
    if not math.isnan(n):
        out["nees_mean"] = n
    if args.json:
        print(
            json.dumps(
                {
                    k: (None if isinstance(v, float) and math.isnan(v) else v)
                    for k, v in out.items()
                },
                indent=2,
            )
        )
    else:
        w = max(map(len, out))
        for k, v in out.items():
            print(f"{k.ljust(w)}  {v:.6g}" if isinstance(v, float) else f"{k.ljust(w)}  {v}")
    return 0


# -------------------------------------------------------------------------------------- plot
def _plot_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", help="a run's output folder (with trajectory.csv)")
    p.add_argument(
        "--log",
        help="log for ground truth and landmarks (default: the one named in metrics.json, "
        "relative to RUN_DIR); 'none': plot the estimate alone",
    )
    p.add_argument("-o", "--out", help="PNG to write (default RUN_DIR/trajectory.png)")


@command("plot", _plot_args)
def cmd_plot(args: argparse.Namespace) -> int:
    """Draw a run's trajectory (with ground truth and beacons when the log is known)."""
    from odofuse.io.loader import load_log
    from odofuse.outputs import read_trajectory_csv, resolve_run_path
    from odofuse.plotting import plot_run
    from odofuse.trajectory import EstimateResult

    run_dir = Path(args.run_dir)
    traj = read_trajectory_csv(run_dir / "trajectory.csv")
    meta = {}
    if (run_dir / "metrics.json").exists():
        meta = json.loads((run_dir / "metrics.json").read_text(encoding="utf-8"))
    spec = args.log or (resolve_run_path(meta["log"], run_dir) if meta.get("log") else None)
    spec = None if spec == "none" else spec
    try:
        log = load_log(spec) if spec else None
    except (OdofuseError, OSError) as exc:
        if args.log:
            raise
        raise OdofuseError(
            f"{one_line(exc).split(': ', 1)[-1]} (the log named in {run_dir / 'metrics.json'}); "
            "give it with --log LOG, or plot without it: --log none"
        ) from None
    out = plot_run(
        args.out or run_dir / "trajectory.png",
        EstimateResult(meta.get("estimator", "estimate"), traj),
        log,
    )
    print(out)
    return 0


# -------------------------------------------------------------------------------------- tune
def _tune_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="run config (YAML) whose noise numbers are learned from its log")
    p.add_argument("-o", "--out", help="tuned config to write (default CONFIG-tuned.yaml)")
    p.add_argument(
        "--params", nargs="+", help="dotted keys (default: k's and sigmas), docs/tune.md"
    )
    p.add_argument("--max-seconds", type=float, default=600.0, help="time bound (default 600)")
    p.add_argument("--fit-fraction", type=float, default=2 / 3, help="share fitted (default 2/3)")


@command("tune", _tune_args)
def cmd_tune(args: argparse.Namespace) -> int:
    """Learn noise parameters from the log by innovation likelihood (never ground truth)."""
    from odofuse.tune import report_lines, tune_config

    res, out = tune_config(
        args.config,
        args.out,
        args.params,
        max_seconds=args.max_seconds,
        fit_fraction=args.fit_fraction,
    )
    print("\n".join(report_lines(res) + [f"tuned config: {out}"]))
    return 0


# ----------------------------------------------------------------------------------- options
def _options_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="?", help="a block (motion, sensors.gps, ekf, ...); omitted: all")


@command("options", _options_args)
def cmd_options(args: argparse.Namespace) -> int:
    """List the config keys: type, unit, default and meaning (from the option declarations)."""
    from odofuse.declarations import catalogue
    from odofuse.options import text_table

    blocks = catalogue()
    if args.name is None:
        for name, (cls, prefix) in blocks.items():
            doc = (cls.__doc__ or "").strip().splitlines()[0].replace("``", "")
            print(f"{name:22s} {prefix:18s} {doc}")
        return 0
    name = options_block(args.name, blocks)
    if name is None:
        raise OdofuseError(f"no options block '{args.name}'; known: {', '.join(blocks)}")
    cls, prefix = blocks[name]
    print(text_table(cls, prefix))
    return 0


def options_block(name: str, blocks) -> str | None:
    """The block of :func:`odofuse.declarations.catalogue` for ``name`` as a user writes it
    in a config: ``sensors.ranges`` (the stream; its model kind is ``range``),
    ``options.smoother``, ``smoother``/``isam2``/``fixed_lag`` (the graph block),
    ``options.ekf``."""
    from odofuse.declarations.sensors import stream_kind

    name = name.strip()
    if name in blocks:
        return name
    head, _, rest = name.partition(".")
    if head == "sensors" and rest:
        kind = stream_kind(rest)
        return f"sensors.{kind}" if kind and f"sensors.{kind}" in blocks else None
    if head == "options" and rest:
        return options_block(rest, blocks)
    if name in ("smoother", "isam2", "fixed_lag") and "graph" in blocks:
        return "graph"
    return None


# -------------------------------------------------------------------------------------- main
def _register_plugins() -> None:
    try:
        mod = importlib.import_module("odofuse.teaching.cli")
    except ModuleNotFoundError as exc:
        if exc.name != "odofuse.teaching.cli":
            raise
        return
    mod.register(COMMANDS)


# --------------------------------------------------------------------------- live (issue 27)
def _live_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="run config (YAML); its live: block, if any, names the topics")
    p.add_argument("--replay", metavar="BAG", help="play a recorded bag into the component")
    p.add_argument("--rate", type=float, help="replay at R times real time (default: as fast)")
    p.add_argument("-o", "--out", help="after a replay, write the odofuse run output folder")
    p.add_argument(
        "--foxglove",
        nargs="?",
        type=int,
        const=8765,
        metavar="PORT",
        help="serve the Foxglove WebSocket view on 127.0.0.1 (default port 8765)",
    )
    p.add_argument("--duration", type=float, help="live: stop after this many seconds")


@command("live", _live_args)
def cmd_live(args: argparse.Namespace) -> int:
    """The streaming estimator as a ROS 2 component over Zenoh (rmw_zenoh's wire format)."""
    from odofuse.config import load_config
    from odofuse.live.run import run_live

    config = load_config(args.config)
    summary = run_live(
        config, args.replay, args.rate, args.out, args.foxglove, duration_s=args.duration
    )
    bad = ", ".join(f"{k} {v}" for k, v in sorted(summary["bad"].items())) or "none"
    print(
        f"live: {summary['handled']} messages, {summary['steps']} odometry steps, "
        f"{summary['published']} estimates published, status {summary['status']}, "
        f"skipped messages: {bad}"
    )
    if args.out:
        print(f"wrote {args.out}")
    return 0


def _exit_on_sigterm() -> None:
    """SIGTERM ends the command like Ctrl-C: cleanup runs (temporary outputs, the folder lock)."""
    import signal
    import threading

    def stop(signum, frame):
        raise SystemExit(128 + signum)

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, stop)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand of :data:`COMMANDS`."""
    from odofuse import __version__

    parser = argparse.ArgumentParser(
        prog="odofuse",
        description="Probabilistic state estimation for wheeled mobile robots. "
        "Run `odofuse run` for a comparison on a real dataset.",
    )
    parser.add_argument("--version", action="version", version=f"odofuse {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (add_arguments, handler) in COMMANDS.items():
        doc = (handler.__doc__ or "").strip().splitlines()
        p = sub.add_parser(name, help=doc[0] if doc else None, description=doc[0] if doc else None)
        add_arguments(p)
        p.set_defaults(_handler=handler)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``odofuse`` console script; returns the exit status."""
    if argv is None:  # the console script (not a caller's own process): SIGTERM cleans up
        _exit_on_sigterm()
    _register_plugins()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_handler", None):
        parser.print_help()
        return 2
    try:
        return int(args._handler(args) or 0)
    except OdofuseError as exc:
        print(f"odofuse: error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:  # bad values found below the config layer (e.g. a drive's limits)
        print(f"odofuse: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"odofuse: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("odofuse: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
