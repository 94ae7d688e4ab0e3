"""One run and its output folder: the four files of spec section 3, written all or nothing.

:func:`run_one` is the single path from a config and a log to a finished run folder, shared by
``odofuse run`` and ``odofuse batch`` so that both give the same result to the last digit.

It combines the file writers of :mod:`odofuse.outputs` with the picture of
:mod:`odofuse.plotting` (which do not know each other); ``metrics.json`` comes last and marks a
complete run. The folder is written whole: claimed by one run, written beside it and swapped
in (:func:`write_outputs`). Every run's metrics go through :func:`checked_metrics`: the
batch smoother's second opinion (:mod:`odofuse.status.cross_check`) before the self-judged status.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np

from odofuse.errors import OdofuseError
from odofuse.evaluation import trajectory_from_stream
from odofuse.io.atomic import claim_folder, clean_stale, publish, temp_folder
from odofuse.outputs import (
    evo_t_max_diff,
    run_path,
    tum_name,
    write_landmarks_csv,
    write_metrics,
    write_trajectory_csv,
    write_tum,
)
from odofuse.trajectory import EstimateResult

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

    The outputs are written into a temporary folder beside ``out_dir`` and swapped in whole
    (:mod:`odofuse.io.atomic`), with ``out_dir`` claimed for this run: a failed or killed run
    leaves the previous complete outputs, a second run into the same folder is an error, and
    temporary folders a killed run left are removed first.

    Raises
    ------
    OdofuseError
        ``out_dir`` is claimed by another live run, or holds files that are not run outputs.
    """
    out = Path(out_dir)
    with claim_folder(out):
        _check_replaceable(out, result.estimator)
        clean_stale(out.parent, out.name)  # what a killed run into this folder left behind
        out.mkdir(parents=True, exist_ok=True)
        tmp = temp_folder(out.parent, out.name)
        named_tum = tum_name(result.estimator)
        gt = getattr(log, "groundtruth", None)
        written: dict[str, Path] = {}
        try:
            written["csv"] = write_trajectory_csv(tmp / "trajectory.csv", result.trajectory)
            written["tum"] = write_tum(tmp / "trajectory.tum", result.trajectory)
            if named_tum != "trajectory.tum":
                # the same content: copied, not formatted twice
                written["tum_estimator"] = Path(shutil.copyfile(written["tum"], tmp / named_tum))
            if result.extra.get("landmarks"):
                written["landmarks"] = write_landmarks_csv(
                    tmp / LANDMARKS_NAME,
                    result.extra["landmarks"],
                    result.extra.get("landmark_covariances"),
                )
            if gt is not None and len(gt):
                gt_traj = trajectory_from_stream(gt)  # the log's own arrays, not a copy
                written["groundtruth"] = write_tum(tmp / "groundtruth.tum", gt_traj)
                t_max = evo_t_max_diff(result.trajectory.t, gt.t)
                metrics = {**metrics, "evo_t_max_diff_s": t_max}
            if ros is not None:
                from odofuse.outputs_ros import write_trajectory_mcap

                written["mcap"] = write_trajectory_mcap(
                    tmp / "trajectory.mcap", result.trajectory, **ros
                )
            if plot:
                from odofuse.plotting import plot_run  # matplotlib only when a picture is wanted

                written["png"] = plot_run(tmp / "trajectory.png", result, log)
            # metrics.json last: its presence marks a complete run.
            written["metrics"] = write_metrics(tmp / "metrics.json", metrics)
            publish(tmp, out)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return {k: out / Path(p).name for k, p in written.items()}


def _check_replaceable(out: Path, estimator: str) -> None:
    """Refuse to replace a folder that holds anything but a run's outputs."""
    if out.exists() and not out.is_dir():
        raise OdofuseError(f"output folder {out} is a file")
    if out.is_dir():
        ours = (*OUTPUT_NAMES, LANDMARKS_NAME, tum_name(estimator))
        foreign = sorted(
            p.name for p in out.iterdir() if p.name not in ours and not p.name.endswith(".tum")
        )
        if foreign:
            raise OdofuseError(
                f"output folder {out} holds other files ({', '.join(foreign[:3])}); a run "
                "replaces its folder whole, so choose an empty or new folder"
            )


def run_one(config, log, out_dir: Path, reference=None) -> dict:
    """Run one estimator on ``log`` and write its outputs into ``out_dir``; returns metrics.

    ``reference`` (an :class:`odofuse.status.cross_check.Reference` or a function returning one) is
    the batch smoother run of the cross-check, shared by several runs on one log; None: run
    when the check applies. A smoother run given its own reference reuses it.
    """
    from odofuse.log_defaults import apply_log_defaults

    config, log = apply_log_defaults(config, log)  # what a bag says where the config is silent
    with claim_folder(out_dir):  # a second run into out_dir fails now, not after its estimate
        result, runtime = estimate(config, log, reference)
        return finish_run(config, log, result, runtime, out_dir, reference)


def smoother_reference(config, log):
    """A function returning the batch smoother run of ``config`` on ``log``, run once on its
    first call (:class:`odofuse.status.cross_check.Reference`): ``reference`` of :func:`run_one` for
    several runs on one log."""
    import functools

    from odofuse.log_defaults import apply_log_defaults
    from odofuse.status.cross_check import reference_of

    return functools.cache(lambda: reference_of(*apply_log_defaults(config, log)))


def estimate(config, log, reference=None) -> tuple[EstimateResult, float]:
    """``(result, runtime_s)`` of ``config.estimator`` on ``log``; the smoother reuses a
    given ``reference`` (its result and runtime) instead of running twice."""
    from odofuse.estimators import run_estimator

    if config.estimator == "smoother" and reference is not None:
        ref = reference() if callable(reference) else reference
        return ref.result, ref.runtime_s
    t0 = time.perf_counter()
    result = run_estimator(config.estimator, log, config)
    return result, time.perf_counter() - t0


def checked_metrics(config, log, result, runtime: float, reference=None) -> dict:
    """Metrics of ``result`` on ``log`` after the batch smoother's second opinion.

    The one path from an estimate to its ``metrics.json`` content, shared by
    :func:`finish_run` and the trust scenarios' runs
    (:func:`odofuse.teaching.trust_scenarios.run`): :func:`odofuse.status.cross_check.cross_check`
    adds its findings (so ``status`` and ``warnings`` follow), the ``cross_check`` block, the
    ``advice`` list (accuracy against the smoother, and the robot geometry the odometry
    calibration fits: :func:`odofuse.status.geometry.geometry_advice`; never a finding, never
    the status) and the run's false-alarm budget ``alpha``
    (:func:`odofuse.status.cross_check.alpha_budget`).
    """
    from odofuse.evaluation import metrics
    from odofuse.status.cross_check import alpha_budget, cross_check
    from odofuse.status.geometry import geometry_advice

    result, block, advice = cross_check(config, log, result, reference)
    m = metrics(result, log, runtime)
    m["cross_check"] = block
    m["advice"] = list(advice) + geometry_advice(config.robot, result.extra or {})
    m["alpha"] = alpha_budget(config, log)
    return m


def finish_run(config, log, result, runtime: float, out_dir: Path, reference=None) -> dict:
    """Metrics of ``result`` on ``log`` and the run's outputs in ``out_dir``; returns metrics."""
    from odofuse.outputs_ros import mcap_options

    m = checked_metrics(config, log, result, runtime, reference)
    m["log"] = run_path(config.log, out_dir)  # relative to the run folder (outputs.run_path)
    m["config"] = run_path(config.source, out_dir)
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
    from odofuse.trajectory import interpolate_poses

    dr = run_estimator("dead_reckoning", log, config).trajectory
    return interpolate_poses(dr, np.asarray(t, dtype=float))
