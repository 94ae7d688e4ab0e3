"""The fixed-lag smoother reports, for each pose, the estimate and covariance of lag-L smoothing.

A pose leaves the window in the update of the first keyframe more than ``lag`` s after it, and
``run_fixed_lag`` reports the estimate and marginal covariance held just before that update:
those of the graph of every keyframe added so far. The batch smoother run on the log cut at the
last of those keyframes computes the same marginal from scratch (at its optimum, its robust
weights at the optimum, the calibration variables' uncertainty included), so the two must agree.
Before the fixed-lag smoother relinearised its calibration vectors, the range scale (true 1.05)
stayed linearised at 1.0, every range's Huber weight was computed 1 m (5 sigma) off and the
reported covariance was 1.0-3.6x the batch marginal (eigenvalues of Q^-1 P; 0.93-1.03 after).
"""

from __future__ import annotations

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from test_graph import _config, _simulate  # noqa: E402

from odofuse.estimators import graph  # noqa: E402

LAG = 5.0  # s
SENSORS = {"ranges": {"sigma": 0.2, "calibrate": True, "scale_sigma": 0.1, "offset_sigma": 0.5}}
ROBUST = {"ranges": "huber"}


@pytest.fixture(scope="module")
def run():
    # 90 s loop, 2 Hz ranges to beacons 15-25 m away with a 5 % scale error (1 m, 5 sigma)
    log = _simulate(seed=3, T=90.0, scale=1.05, sigma=0.2)
    res = graph.run_fixed_lag(log, _config("fixed_lag", SENSORS, {"lag": LAG, "robust": ROBUST}))
    return log, res


@pytest.mark.parametrize("t_pose", [20.0, 40.0, 60.0, 80.0])
def test_fixed_lag_pose_is_the_batch_marginal_of_the_data_before_it_left(run, t_pose):
    log, res = run
    kt = res.trajectory.t
    j = int(np.searchsorted(kt, t_pose))
    i = int(np.searchsorted(kt, kt[j] + LAG, side="right"))  # the update that marginalises j
    batch = graph.run_smoother(
        log.window(float(kt[0]), float(kt[i - 1])), _config("smoother", SENSORS, {"robust": ROBUST})
    )
    jb = int(np.flatnonzero(np.abs(batch.trajectory.t - kt[j]) < 1e-9)[0])
    P, Q = res.trajectory.covariances[j], batch.trajectory.covariances[jb]
    ratios = np.linalg.eigvals(np.linalg.solve(Q, P)).real  # 1 where the two agree
    assert 0.85 < ratios.min() and ratios.max() < 1.15, ratios
    # the same estimate, up to the relinearisation threshold (0.1): well inside one sigma
    d = res.trajectory.poses[j, :2] - batch.trajectory.poses[jb, :2]
    assert d @ np.linalg.solve(Q[:2, :2], d) < 0.5**2


# ------------------------------------------------ the filters' gate on fixed-lag's rows
def _with_gross_fixes(clean_cfg, folder, offset):
    """A copy of the log of ``clean_cfg`` whose GPS fixes 30, 50 and 70 are ``offset`` (m,
    x and y) off: gross fixes, far beyond any gate."""
    import csv
    import shutil

    shutil.copytree(clean_cfg.parent, folder)
    gps = folder / "gps.csv"
    rows = list(csv.reader(gps.open(encoding="utf-8")))
    for j in (30, 50, 70):
        rows[1 + j][1] = repr(float(rows[1 + j][1]) + offset[0])
        rows[1 + j][2] = repr(float(rows[1 + j][2]) + offset[1])
    with gps.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows(rows)
    return folder / "config.yaml"


def test_fixed_lag_leaves_out_a_gross_fix_as_the_filters_gate_does(tmp_path):
    """Issue 25: fixed-lag gave a gross GNSS fix Huber's loss, a bounded pull that never
    vanishes, and said ``ok`` over Sokal's NEES bound on 5 of 40 real-robot logs (1.15x).
    Now a row beyond its gate by its predicted NIS is left out, as a filter leaves it out:
    fixes 60 m off in x and 60 m off in y leave the same estimate, to rounding (with Huber's
    loss each pulls its own way), and each is counted as rejected."""
    import csv

    from test_cross_check_skipped import _run, _simulated_log

    clean = _simulated_log(tmp_path / "clean")
    runs = {
        name: _run(
            _with_gross_fixes(clean, tmp_path / name, off), "fixed_lag", tmp_path / f"o{name}"
        )
        for name, off in {"x": (60.0, 0.0), "y": (0.0, -60.0)}.items()
    }
    clean_run = _run(clean, "fixed_lag", tmp_path / "oclean")
    poses = {}
    for name in runs:
        with (tmp_path / f"o{name}" / "trajectory.csv").open(encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
        poses[name] = np.array([[float(r["x"]), float(r["y"])] for r in rows])
    assert np.abs(poses["x"] - poses["y"]).max() < 1e-9
    gps = {name: m["sensors"]["gps"] for name, m in runs.items()}
    base = clean_run["sensors"]["gps"]
    for name in runs:
        assert gps[name]["rejected"] == base["rejected"] + 3, (gps[name], base)
        assert gps[name]["used"] == base["used"] - 3
        assert runs[name]["status"] == "ok", runs[name]["warnings"]
    assert runs["x"]["ate_rmse_m"] < 1.5 * clean_run["ate_rmse_m"]


def test_the_gate_reopens_after_reject_run_rejections_in_a_row():
    """:func:`innovations.gated_out`: a row beyond its gate is left out; from the
    ``reject_run``-th in a row on, the stream's rows go in until one is within the gate again
    (a filter re-opens); a stream that is not gated is never left out."""
    from types import SimpleNamespace

    from odofuse.estimators.graph import innovations

    gps, ranges = SimpleNamespace(stream="gps"), SimpleNamespace(stream="ranges")
    runs = {"gps": 0}
    oks = [False, False, True, False, False, False, False, False, True, False]
    out = [innovations.gated_out([(j, gps, ok)], runs, 3) for j, ok in enumerate(oks)]
    assert out == [{0}, {1}, set(), {3}, {4}, set(), set(), set(), set(), {9}]
    assert innovations.gated_out([(0, ranges, False)], runs, 3) == set()
    assert runs == {"gps": 1}


def test_a_row_that_alone_holds_a_new_variable_stays_in():
    """:func:`innovations.without` leaves a row in when nothing else holds a variable it adds
    (iSAM2 would meet an undetermined system), and the others out."""
    from odofuse.estimators.graph import innovations
    from odofuse.estimators.graph.keys import X

    noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.BetweenFactorPose2(X(0), X(1), gtsam.Pose2(), noise))  # 0: odometry
    g.add(gtsam.PriorFactorPose2(X(1), gtsam.Pose2(), noise))  # 1: a row on the new pose
    g.add(gtsam.PriorFactorPose2(X(2), gtsam.Pose2(), noise))  # 2: the only one on X(2)
    v = gtsam.Values()
    v.insert(X(1), gtsam.Pose2())
    v.insert(X(2), gtsam.Pose2())
    kept, left = innovations.without(g, {1, 2}, v)
    assert left == {1} and kept.size() == 2
    assert [kept.at(j).keys() for j in range(2)] == [g.at(0).keys(), g.at(2).keys()]
    same, none = innovations.without(g, set(), v)
    assert none == set() and same.size() == 3
