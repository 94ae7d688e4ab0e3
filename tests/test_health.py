"""Health as data: findings, status derivation and the checks common to every estimator."""

import numpy as np

from odofuse.evaluation import metrics
from odofuse.status.findings import (
    Finding,
    assess,
    covariance_findings,
    rejection_findings,
    status_of,
)
from odofuse.trajectory import EstimateResult, Trajectory


def _result(covs=None, used=None, rejected=None, findings=()):
    t = np.arange(5.0)
    poses = np.zeros((5, 3))
    traj = Trajectory(t, poses, covs)
    return EstimateResult("ekf", traj, used or {}, rejected or {}, findings=findings)


def test_status_is_derived_from_findings():
    assert status_of([]) == "ok"
    assert status_of([Finding("x", "note", degrades=False)]) == "ok"
    assert status_of([Finding("x", "bad")]) == "degraded"


def test_line_names_check_sensor_span_and_message():
    f = Finding("nis", "NIS 41.2 outside [0.2, 5.0]", sensor="gps", t_start=30.0, t_end=40.5)
    assert f.line() == "[nis] gps, 30.00-40.50 s: NIS 41.2 outside [0.2, 5.0]"


def test_mostly_rejected_stream_is_reported_with_its_fraction():
    out = rejection_findings({"gps": 40, "ranges": 90}, {"gps": 60, "ranges": 10})
    assert [f.sensor for f in out] == ["gps"]
    assert out[0].figure == 0.6 and "60 of 100" in out[0].message


def test_non_positive_definite_covariance_is_reported():
    covs = np.tile(np.eye(3) * 0.01, (5, 1, 1))
    assert covariance_findings(np.arange(5.0), covs) == []
    covs[2] = np.diag([1e-2, -1e-9, 1e-3])
    covs[4, 0, 0] = np.nan
    (f,) = covariance_findings(np.arange(5.0), covs)
    assert f.figure == 2 and (f.t_start, f.t_end) == (2.0, 4.0)


def test_metrics_carry_status_and_warnings():
    ok = metrics(_result(np.tile(np.eye(3), (5, 1, 1)), {"gps": 5}, {"gps": 0}))
    assert ok["status"] == "ok" and ok["warnings"] == []
    bad = metrics(_result(None, {"gps": 1}, {"gps": 4}))
    assert bad["status"] == "degraded"
    assert bad["warnings"][0].startswith("[rejected] gps, 0.00-4.00 s: 4 of 5 readings")


def test_estimator_findings_come_first_and_are_not_duplicated():
    own = Finding("rejected", "custom", sensor="gps")
    out = assess(_result(None, {"gps": 1}, {"gps": 4}, findings=(own,)))
    assert out == [own]


def test_filter_covariance_conditioning_in_blocks_equals_the_whole_run():
    from odofuse.declarations import EkfOptions
    from odofuse.status import pose_checks

    rng = np.random.default_rng(3)
    A = rng.normal(size=(1000, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)
    P[17] = np.diag([1.0, 1.0, 1e-14])  # correlation condition 1 (diagonal): healthy
    P[400] = [[1.0, 1.0 - 1e-13, 0.0], [1.0 - 1e-13, 1.0, 0.0], [0.0, 0.0, 1.0]]
    P[600, 0, 0] = np.nan
    d = np.sqrt(np.clip(np.einsum("nii->ni", P), 1e-300, None))
    finite = np.isfinite(P).all(axis=(1, 2))
    C = P[finite] / (d[finite, :, None] * d[finite, None, :])
    eig = np.linalg.eigvalsh(0.5 * (C + np.swapaxes(C, 1, 2)))
    whole = eig[:, -1] / np.maximum(eig[:, 0], 1e-300)
    in_blocks, blocks = pose_checks._correlation_condition(P, block=7)
    assert np.array_equal(in_blocks, finite) and np.array_equal(blocks, whole)
    (f,) = [
        f
        for f in pose_checks.covariance_health(np.arange(1000.0), P, EkfOptions())
        if f.check == "covariance"
    ]
    assert f.t_start == f.t_end == 400.0 and f.figure > 1e12


def test_condition_screen_is_an_upper_bound_and_exact_above_its_cap():
    """``cap``: the determinant's bound replaces the eigenvalues only where it proves the
    condition number at most ``cap``; above it the numbers are the eigenvalues' own."""
    from odofuse.status import pose_checks

    rng = np.random.default_rng(4)
    A = rng.normal(size=(3000, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + np.logspace(-14, 0, 3000)[:, None, None] * np.eye(3)
    P[5] = np.diag([1.0, 4.0, 9.0])  # correlation = identity: condition 1, bound 6.75
    _, exact = pose_checks._correlation_condition(P)
    for cap in (10.0, 1e3, 1e8):
        _, screened = pose_checks._correlation_condition(P, cap=cap)
        assert np.all(screened >= exact * (1 - 1e-9))  # an upper bound
        assert np.array_equal(screened > cap, exact > cap)  # the same verdicts
        above = exact > cap
        assert above.any() and np.array_equal(screened[above], exact[above])
    assert pose_checks._correlation_condition(P, cap=10.0)[1][5] == 6.75


def test_the_screens_determinant_is_the_correlation_matrix_one_at_every_scale():
    """``_correlation_det3`` (the screen's ``det C``, from P's six entries) equals the
    determinant of the correlation matrix, also where P's own products would overflow or
    vanish (a coordinate in units 1e150 times larger or smaller)."""
    from odofuse.status import pose_checks

    rng = np.random.default_rng(11)
    A = rng.normal(size=(500, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + np.eye(3) * rng.uniform(0.1, 2.0, (500, 1, 1))
    d = np.sqrt(np.einsum("nii->ni", P))
    expected = np.linalg.det(P / (d[:, :, None] * d[:, None, :]))
    for scale in (1.0, 1e-150, 1e150):
        D = np.diag([scale, 1.0, 1.0 / scale])  # the same correlations
        det = pose_checks._correlation_det3(D @ P @ D)
        assert np.allclose(det, expected, rtol=1e-10, atol=1e-14)
    _, cond = pose_checks._correlation_condition(D @ P @ D, cap=1e10)
    _, exact = pose_checks._correlation_condition(P)
    assert np.allclose(cond, 6.75 / expected, rtol=1e-10) and np.all(cond >= exact * (1 - 1e-9))
