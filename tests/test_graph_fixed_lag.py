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
