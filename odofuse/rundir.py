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

import numpy as np

from odofuse.outputs import (
    evo_t_max_diff,
    tum_name,
    write_landmarks_csv,
    write_metrics,
    write_trajectory_csv,
    write_tum,
)
from odofuse.trajectory import EstimateResult, Trajectory

OUTPUT_NAMES = (
    "trajectory.csv",
    "trajectory.tum",
    "trajectory.png",
    "metrics.json",
    "groundtruth.tum",
    "trajectory.mcap",
)
#: Written besides when the estimator estimated landmarks (SLAM): ``id,x,y,var_x,cov_xy,var_y``.
LANDMARKS_NAME = "landmarks.csv"


def write_outputs(
    out_dir: str | Path,
    result: EstimateResult,
    metrics: dict,
    log=None,
    plot: bool = True,
    ros: dict | None = None,
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
    ros : dict, optional
        Keyword arguments of :func:`odofuse.outputs_ros.write_trajectory_mcap` (``odom_poses``,
        frames, topic): also write ``trajectory.mcap``.

    Returns
    -------
    dict
        ``{"csv", "tum", "tum_estimator", "metrics"}`` paths, and ``"png"``, ``"groundtruth"``
        (``groundtruth.tum``, with ``metrics["evo_t_max_diff_s"]`` set) and ``"mcap"`` when
        written, and ``"landmarks"`` (``landmarks.csv``) when ``result.extra`` holds estimated
        landmarks.

    If any writer fails, files written by this call are removed again and the error propagates.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    # Outputs of an earlier run in this folder go first, so that a run failing half-way
    # cannot leave a mix of old and new files.
    named_tum = tum_name(result.estimator)
    for name in (*OUTPUT_NAMES, LANDMARKS_NAME, named_tum):
        (out / name).unlink(missing_ok=True)
    written: dict[str, Path] = {}
    gt = getattr(log, "groundtruth", None)
    try:
        written["csv"] = write_trajectory_csv(out / "trajectory.csv", result.trajectory)
        written["tum"] = write_tum(out / "trajectory.tum", result.trajectory)
        if named_tum != "trajectory.tum":
            written["tum_estimator"] = write_tum(out / named_tum, result.trajectory)
        if result.extra.get("landmarks"):
            written["landmarks"] = write_landmarks_csv(
                out / LANDMARKS_NAME,
                result.extra["landmarks"],
                result.extra.get("landmark_covariances"),
            )
        if gt is not None and len(gt):
            gt_traj = Trajectory(gt.t, np.column_stack([gt["x"], gt["y"], gt["theta"]]))
            written["groundtruth"] = write_tum(out / "groundtruth.tum", gt_traj)
            metrics = {**metrics, "evo_t_max_diff_s": evo_t_max_diff(result.trajectory.t, gt.t)}
        if ros is not None:
            from odofuse.outputs_ros import write_trajectory_mcap

            written["mcap"] = write_trajectory_mcap(
                out / "trajectory.mcap", result.trajectory, **ros
            )
        if plot:
            from odofuse.plotting import plot_run

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
    from odofuse.log_defaults import apply_log_defaults

    config, log = apply_log_defaults(config, log)  # what a bag says where the config is silent
    t0 = time.perf_counter()
    result = run_estimator(config.estimator, log, config)
    return finish_run(config, log, result, time.perf_counter() - t0, out_dir)


def finish_run(config, log, result, runtime: float, out_dir: Path) -> dict:
    """Metrics of ``result`` on ``log`` and the run's outputs in ``out_dir``; returns metrics."""
    from odofuse.evaluation import metrics
    from odofuse.outputs_ros import mcap_options

    m = metrics(result, log, runtime)
    m["log"] = config.log
    m["config"] = config.source
    if log.ros.get("defaults"):
        m["log_defaults"] = log.ros["defaults"]
    ros = mcap_options(config, log)
    if ros is not None:
        ros["odom_poses"] = dead_reckoning_at(config, log, result.trajectory.t)
    write_outputs(out_dir, result, m, log, ros=ros)
    return m


def dead_reckoning_at(config, log, t) -> np.ndarray:
    """The run's dead-reckoned base pose in the odom frame at times ``t``, shape ``(N, 3)``."""
    from odofuse.estimators import run_estimator
    from odofuse.evaluation import interpolate_poses

    dr = run_estimator("dead_reckoning", log, config).trajectory
    return interpolate_poses(dr, np.asarray(t, dtype=float))
