"""One run and its output folder: the four files of spec section 3, written all or nothing.

:func:`run_one` is the single path from a config and a log to a finished run folder, shared by
``odofuse run`` and ``odofuse batch`` so that both give the same result to the last digit.

It combines the file writers of :mod:`odofuse.outputs` with the picture of
:mod:`odofuse.plotting` (which do not know each other); ``metrics.json`` comes last and marks a
complete run.
"""

from __future__ import annotations

import time
from pathlib import Path

from odofuse.outputs import write_metrics, write_trajectory_csv, write_tum
from odofuse.trajectory import EstimateResult

OUTPUT_NAMES = ("trajectory.csv", "trajectory.tum", "trajectory.png", "metrics.json")


def write_outputs(
    out_dir: str | Path, result: EstimateResult, metrics: dict, log=None, plot: bool = True
) -> dict[str, Path]:
    """Write the four outputs of a run (spec section 3) into ``out_dir``.

    Parameters
    ----------
    out_dir : str or Path
        Output folder (created if needed).
    result : EstimateResult
        The estimate.
    metrics : dict
        The metrics, see :func:`odofuse.evaluation.metrics`.
    log : SensorLog, optional
        For ground truth and landmarks in the picture.
    plot : bool
        Also write ``trajectory.png``.

    Returns
    -------
    dict
        ``{"csv": path, "tum": path, "metrics": path, "png": path}``.

    If any writer fails, files written by this call are removed again and the error propagates.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    # Outputs of an earlier run in this folder go first, so that a run failing half-way
    # cannot leave a mix of old and new files.
    for name in OUTPUT_NAMES:
        (out / name).unlink(missing_ok=True)
    written: dict[str, Path] = {}
    try:
        written["csv"] = write_trajectory_csv(out / "trajectory.csv", result.trajectory)
        written["tum"] = write_tum(out / "trajectory.tum", result.trajectory)
        if plot:
            from odofuse.plotting import plot_run  # matplotlib only when a picture is wanted

            written["png"] = plot_run(out / "trajectory.png", result, log)
        # metrics.json last: its presence marks a complete run.
        written["metrics"] = write_metrics(out / "metrics.json", metrics)
    except BaseException:
        for p in written.values():
            Path(p).unlink(missing_ok=True)
        raise
    return written


def run_one(config, log, out_dir: Path) -> dict:
    """Run one estimator on ``log`` and write its outputs into ``out_dir``; returns metrics."""
    from odofuse.estimators import run_estimator

    t0 = time.perf_counter()
    result = run_estimator(config.estimator, log, config)
    return finish_run(config, log, result, time.perf_counter() - t0, out_dir)


def finish_run(config, log, result, runtime: float, out_dir: Path) -> dict:
    """Metrics of ``result`` on ``log`` and the run's outputs in ``out_dir``; returns metrics."""
    from odofuse.evaluation import metrics

    m = metrics(result, log, runtime)
    m["log"] = config.log
    m["config"] = config.source
    write_outputs(out_dir, result, m, log)
    return m
