"""``odofuse batch``: one config over many logs on a Dask cluster, with a summary.

This module owns the fleet run: expanding the LOG arguments, naming each log's output folder,
the task a Dask worker runs per log (the same :func:`odofuse.rundir.run_one` as ``odofuse run``, so
results are identical to the last digit), failure isolation, resume, the per-log atomic output
folder, and ``OUT/summary.{csv,json,png}``. Splitting one long log into windows lives in
:mod:`odofuse.batch.split`.

The engine is ``dask.distributed``: a :class:`distributed.LocalCluster` (processes, one thread
each, a memory limit) by default, or any running scheduler through ``Client(address)``. Worker
processes live for the whole batch, so gtsam and filterpy are imported once per worker, not once
per log. A worker that dies mid-log (SIGKILL, out of memory) has its log rescheduled on another
worker by the scheduler (``distributed.scheduler.allowed-failures``); a log whose run raises is
one failed row, never a stopped batch.

Output layout::

    OUT/<name>/           trajectory.csv, trajectory.tum, trajectory.png, metrics.json
    OUT/summary.csv       one row per log (SUMMARY_COLUMNS; log paths relative to OUT)
    OUT/summary.json      the same rows as a JSON list
    OUT/summary.png       position RMSE (or final error) per log, coloured by status

Each log is written into ``OUT/.<name>.tmp-<id>/`` and renamed to ``OUT/<name>/`` when complete;
a folder ``OUT/<name>/`` therefore always holds one complete run. Temporary folders left by a
killed batch are removed when the next batch on the same OUT starts.
"""

from __future__ import annotations

import csv
import dataclasses
import glob
import io
import json
import logging
import math
import os
import sys
import time
import uuid
from pathlib import Path

from odofuse.batch.common import (
    DEFAULT_RETRIES,
    SUMMARY_COLUMNS,
    BatchSummary,
    gather_records,
    is_complete,
    record,
)
from odofuse.errors import ConfigError, InputError, one_line
from odofuse.io.atomic import clean_stale

_GLOB_CHARS = set("*?[")


# ------------------------------------------------------------------------------------ logs
def expand_logs(patterns) -> list[str]:
    """The logs named by ``patterns``: paths (folders, bags, pose-graph files) or globs.

    A glob is expanded (sorted, ``**`` allowed); a glob that matches nothing is an error. A
    plain path is kept even when it does not exist (its run is then one failed row).
    ``builtin:NAME`` passes through. Paths become absolute, so that workers with another
    working directory (on a shared file system) find them. Duplicates are dropped.
    """
    out: list[str] = []
    for pat in map(str, patterns):
        if pat.startswith("builtin:"):
            found = [pat]
        elif _GLOB_CHARS & set(pat):
            found = sorted(glob.glob(os.path.expanduser(pat), recursive=True))
            if not found:
                raise InputError("no log matches this pattern", pat)
        else:
            found = [pat]
        for f in found:
            spec = f if f.startswith("builtin:") else str(Path(f).expanduser().resolve())
            if spec not in out:
                out.append(spec)
    if not out:
        raise InputError("no logs given")
    return out


def log_names(specs: list[str]) -> list[str]:
    """Output folder names: the log's base name (without a file suffix), made unique.

    Two logs with the same base name get their parent folder's name prepended
    (``robot1-2024-05-01``); a name still taken gets ``-2``, ``-3``... in argument order.
    """

    def base(spec: str) -> str:
        if spec.startswith("builtin:"):
            return spec.split(":", 1)[1] or "builtin"
        p = Path(spec)
        return p.name if p.is_dir() or not p.suffix else p.stem

    bases = [base(s) for s in specs]
    names: list[str] = []
    for spec, b in zip(specs, bases, strict=True):
        name = b
        if bases.count(b) > 1 and not spec.startswith("builtin:"):
            name = f"{Path(spec).parent.name}-{b}"
        candidate, k = name, 2
        while candidate in names or candidate.startswith("."):
            candidate = f"{name.lstrip('.') or 'log'}-{k}"
            k += 1
        names.append(candidate)
    return names


# ------------------------------------------------------------------------------- the task
def run_log_task(config, spec: str, name: str, out: str, force: bool = False) -> dict:
    """Run ``config`` on one log into ``out/name`` (on a worker); returns its summary record.

    The log's outputs are those of ``odofuse run`` with the config's ``log:`` replaced by
    ``spec`` (the same :func:`odofuse.rundir.run_one`). A complete ``out/name`` is reused unless
    ``force``. Any error of the run becomes a failed record with its one-line message.
    """
    from odofuse.io.loader import load_log_for
    from odofuse.rundir import run_one

    root = Path(out)
    final = root / name
    if not force and is_complete(final):
        metrics = json.loads((final / "metrics.json").read_text(encoding="utf-8"))
        return record(spec, name, metrics, resumed=True)
    try:  # run_one writes out/name whole (claimed, beside it, swapped in: odofuse.io.atomic)
        cfg = dataclasses.replace(config, log=spec, output=str(final))
        metrics = run_one(cfg, load_log_for(cfg), final)
    except Exception as exc:  # one bad log is one failed row, never a stopped batch
        return record(spec, name, None, error=one_line(exc))
    return record(spec, name, metrics)


def warm_worker(estimator: str) -> str:
    """Import odofuse and ``estimator``'s back end once on a worker (gtsam, filterpy)."""
    from odofuse.estimators import get_estimator

    get_estimator(estimator)
    return estimator


# ------------------------------------------------------------------------------ the cluster
def local_client(workers: int | None = None, memory_limit: int | str | None = None):
    """A :class:`distributed.Client` on a new LocalCluster: processes, one thread each.

    ``memory_limit`` (bytes or ``"4GiB"``) defaults to 80 % of the machine's memory shared
    between the workers; a worker past it is restarted by its nanny and its log rescheduled.
    """
    import dask
    import psutil
    from distributed import Client, LocalCluster

    n = max(1, int(workers or os.cpu_count() or 1))
    if memory_limit is None:
        memory_limit = int(0.8 * psutil.virtual_memory().total / n)
    with dask.config.set({"distributed.scheduler.allowed-failures": DEFAULT_RETRIES}):
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            memory_limit=memory_limit,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            silence_logs=logging.ERROR,
        )
    return Client(cluster)


def _load_config(config, estimator: str | None):
    from odofuse.config import RunConfig, load_config

    cfg = config if isinstance(config, RunConfig) else load_config(config)
    if estimator:
        cfg = dataclasses.replace(cfg, estimator=estimator)
    return cfg


def run_batch(
    config,
    logs,
    out: str | Path = "odofuse-batch",
    client=None,
    *,
    workers: int | None = None,
    estimator: str | None = None,
    force: bool = False,
    split: float | None = None,
    overlap: float | None = None,
    progress: bool | None = None,
) -> BatchSummary:
    """Run ``config`` over ``logs`` on Dask and write ``out``'s summary; returns the records.

    Parameters
    ----------
    config : RunConfig or path
        The run config; its ``log:`` is replaced by each log.
    logs : iterable of str or Path
        Log folders, bags, pose-graph files or globs (see :func:`expand_logs`).
    out : str or Path
        Output folder: ``out/<name>/`` per log and ``out/summary.{csv,json,png}``.
    client : distributed.Client, optional
        Run on this client's cluster; default a new LocalCluster of ``workers`` processes,
        closed at the end.
    workers : int, optional
        Workers of the LocalCluster (default: the machine's cores).
    estimator : str, optional
        Overrides the config's estimator.
    force : bool
        Redo logs whose complete outputs exist (default: reuse them).
    split, overlap : float, optional
        s; cut each log into windows of ``split`` overlapping by ``overlap`` (default 10 % of
        ``split``), smooth them in parallel and stitch them (:mod:`odofuse.batch.split`).
    progress : bool, optional
        Progress bar on stderr; default only when stderr is a terminal.

    Returns
    -------
    BatchSummary
        One record per log, in argument order.
    """
    cfg = _load_config(config, estimator)
    specs = expand_logs(logs)
    names = log_names(specs)
    root = Path(out).expanduser().resolve()
    root.mkdir(parents=True, exist_ok=True)
    clean_stale(root)
    own = client is None
    if own:
        client = local_client(workers)
    try:
        client.run(warm_worker, cfg.estimator)
        if split:
            from odofuse.batch.split import run_split_logs

            records = run_split_logs(
                client, cfg, specs, names, root, split, overlap, force, progress
            )
        else:
            futures = client.map(
                run_log_task,
                [cfg] * len(specs),
                specs,
                names,
                [str(root)] * len(specs),
                [force] * len(specs),
                key=[f"odofuse-log-{n}-{uuid.uuid4().hex[:8]}" for n in names],
                pure=False,
            )
            order = {
                f.key: (i, s, n)
                for i, (f, s, n) in enumerate(zip(futures, specs, names, strict=True))
            }
            records = gather_records(client, futures, order, "logs", progress)
    finally:
        if own:
            cluster = client.cluster
            client.close()
            cluster.close()
    clean_stale(root)  # what a worker killed mid-log left behind; its log ran again elsewhere
    summary = BatchSummary(records)
    write_summary(root, summary)
    summary.stale = stale_folders(root, names)
    summary.unfused = cfg.unfused_note()  # a config that forgot `estimator:`
    return summary


def stale_folders(root: Path, names) -> list[str]:
    """Complete run folders in ``root`` that belong to none of this batch's logs (an earlier
    batch over other logs): listed by :func:`print_summary`, never deleted (they may be the
    only copy of a run)."""
    keep = set(names)
    return sorted(
        p.name
        for p in root.iterdir()
        if p.is_dir() and not p.name.startswith(".") and p.name not in keep and is_complete(p)
    )


# ------------------------------------------------------------------------------ the summary
def _cell(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.17g}"
    return str(v)


def summary_csv_text(records) -> str:
    """``summary.csv``: a header of SUMMARY_COLUMNS and one row per record."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SUMMARY_COLUMNS)
    for r in records:
        w.writerow([_cell(r.get(c)) for c in SUMMARY_COLUMNS])
    return buf.getvalue()


def write_summary(out: Path, records) -> dict[str, Path]:
    """Write ``summary.csv``, ``summary.json`` and ``summary.png`` into ``out`` atomically.

    The files give each log relative to ``out`` (:func:`odofuse.outputs.run_path`); the
    records returned by :func:`run_batch` keep the absolute paths.
    """
    from odofuse.io.atomic import atomic_write, atomic_write_text
    from odofuse.outputs import json_ready, run_path

    # the files name each log relative to OUT (outputs.run_path): relocatable with it
    rows = [{**r, "log": run_path(r["log"], out)} for r in records]
    paths = {
        "csv": atomic_write_text(out / "summary.csv", summary_csv_text(rows)),
        "json": atomic_write_text(
            out / "summary.json", json.dumps(json_ready(rows), indent=2) + "\n"
        ),
    }
    paths["png"] = atomic_write(out / "summary.png", lambda tmp: plot_summary(records, tmp))
    return paths


STATUS_COLOURS = {"ok": "tab:green", "degraded": "tab:orange", "failed": "tab:red"}


def plot_summary(records, path) -> None:
    """Bar chart: position RMSE per log (final error where RMSE is missing), by status.

    A failed log (or one without ground truth) gets a short bar-less label in its colour.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    names = [r["name"] for r in records]
    heights, kinds = [], set()
    for r in records:
        v = r.get("ate_rmse_m")
        kinds.add("position RMSE" if v is not None else "final error")
        v = r.get("final_error_m") if v is None else v
        heights.append(v if v is not None and math.isfinite(v) else 0.0)
    colours = [STATUS_COLOURS.get(r["status"], "tab:gray") for r in records]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.5 * len(records) + 2), 4.0))
    x = range(len(records))
    ax.bar(x, heights, color=colours)
    for i, r in enumerate(records):
        if r["status"] == "failed":
            ax.text(i, 0, "failed", rotation=90, ha="center", va="bottom", color="tab:red")
        elif r.get("ate_rmse_m") is None and r.get("final_error_m") is None:
            ax.text(i, 0, "no ground truth", rotation=90, ha="center", va="bottom", fontsize=8)
    ax.set_xticks(list(x), names, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel(" / ".join(sorted(kinds)) + " [m]")
    ax.set_title(f"odofuse batch: {len(records)} logs")
    # beside the axes, never over a bar
    ax.legend(
        handles=[Patch(color=c, label=s) for s, c in STATUS_COLOURS.items()],
        fontsize=8,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        borderaxespad=0.0,
    )
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=100)
    plt.close(fig)


def parse_duration(text: str) -> float:
    """Seconds from ``"600"``, ``"600s"``, ``"30m"``, ``"4h"`` or ``"1d"`` (positive)."""
    s = str(text).strip().lower()
    scale = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}.get(s[-1:], None)
    number = s[:-1] if scale else s
    try:
        value = float(number) * (scale or 1.0)
    except ValueError:
        raise ConfigError(f"not a duration: {text!r} (e.g. 600, 600s, 30m, 4h)") from None
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"a duration must be positive: {text!r}")
    return value


def print_summary(records, out: Path, file=None, started: float | None = None) -> None:
    """The summary as a short table on ``file`` (stdout)."""
    file = file or sys.stdout
    head = ("log", "status", "warnings", "poses", "RMSE [m]", "final [m]", "runtime [s]")

    def f(v):
        return "-" if v is None else f"{v:.3f}"

    rows = [head] + [
        (
            r["name"],
            r["status"] + (" (resumed)" if r.get("resumed") else ""),
            "-" if r.get("warnings") is None else str(r["warnings"]),
            "-" if r.get("poses") is None else str(r["poses"]),
            f(r.get("ate_rmse_m")),
            f(r.get("final_error_m")),
            f(r.get("runtime_s")),
        )
        for r in records
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(head))]
    for row in rows:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip(), file=file)
    for r in records:
        if r["status"] == "failed":
            print(f"{r['name']}: {r['error']}", file=file)
    took = "" if started is None else f" in {time.perf_counter() - started:.1f} s"
    print(f"{len(records)} logs{took}; summary in {out}/summary.csv", file=file)
    if getattr(records, "unfused", None):
        print(records.unfused, file=file)
    stale = getattr(records, "stale", None) or []
    if stale:
        shown = ", ".join(stale[:5]) + (f" and {len(stale) - 5} more" if len(stale) > 5 else "")
        print(
            f"note: {len(stale)} output folder(s) in {out}/ belong to no log of this batch "
            f"(an earlier batch; not in summary.csv): {shown}",
            file=file,
        )
