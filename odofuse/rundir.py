"""The output folder of one run: the four files of spec section 3, written all or nothing.

It combines the file writers of :mod:`odofuse.outputs` with the picture of
:mod:`odofuse.plotting` (which do not know each other); ``metrics.json`` comes last and marks a
complete run.
"""

from __future__ import annotations

from pathlib import Path

from odofuse.outputs import write_landmarks_csv, write_metrics, write_trajectory_csv, write_tum
from odofuse.trajectory import EstimateResult

OUTPUT_NAMES = ("trajectory.csv", "trajectory.tum", "trajectory.png", "metrics.json")
#: Written besides when the estimator estimated landmarks (SLAM): ``id,x,y,var_x,cov_xy,var_y``.
LANDMARKS_NAME = "landmarks.csv"


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
        ``{"csv": path, "tum": path, "metrics": path, "png": path}``, and ``"landmarks"``
        (``landmarks.csv``) when ``result.extra`` holds estimated landmarks.

    If any writer fails, files written by this call are removed again and the error propagates.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    # Outputs of an earlier run in this folder go first, so that a run failing half-way
    # cannot leave a mix of old and new files.
    for name in (*OUTPUT_NAMES, LANDMARKS_NAME):
        (out / name).unlink(missing_ok=True)
    written: dict[str, Path] = {}
    try:
        written["csv"] = write_trajectory_csv(out / "trajectory.csv", result.trajectory)
        written["tum"] = write_tum(out / "trajectory.tum", result.trajectory)
        if result.extra.get("landmarks"):
            written["landmarks"] = write_landmarks_csv(
                out / LANDMARKS_NAME,
                result.extra["landmarks"],
                result.extra.get("landmark_covariances"),
            )
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
