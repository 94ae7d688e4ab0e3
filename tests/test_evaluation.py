"""ATE / RPE / NEES / alignment against hand-computed reference values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.evaluation import (
    align_se2,
    apply_alignment,
    ate,
    interpolate_poses,
    metrics,
    nees,
    nees_values,
    rpe,
)
from odofuse.io.log import SensorLog, Stream
from odofuse.trajectory import EstimateResult, Trajectory


def straight(n=11, step=1.0):
    t = np.arange(n, dtype=float)
    return Trajectory(t, np.column_stack([t * step, np.zeros(n), np.zeros(n)]))


def rot(a):
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def test_align_recovers_rigid_transform():
    rng = np.random.default_rng(3)
    est = rng.normal(size=(30, 2)) * 5
    r_true, t_true = rot(0.7), np.array([2.0, -1.0])
    gt = est @ r_true.T + t_true
    r, t, angle = align_se2(est, gt)
    np.testing.assert_allclose(r, r_true, atol=1e-12)
    np.testing.assert_allclose(t, t_true, atol=1e-12)
    assert angle == pytest.approx(0.7)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_align_never_reflects():
    est = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    gt = est * np.array([1.0, -1.0])  # a mirror image: best proper rotation is not a reflection
    r, _, _ = align_se2(est, gt)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_ate_constant_offset():
    gt = straight()
    est = Trajectory(gt.t, gt.poses + [3.0, 4.0, 0.0])
    a = ate(est, gt)
    assert a.rmse_m == pytest.approx(5.0)
    assert a.final_m == pytest.approx(5.0)
    assert a.max_m == pytest.approx(5.0)
    assert ate(est, gt, align=True).rmse_m == pytest.approx(0.0, abs=1e-12)


def test_ate_reference_values():
    gt = straight(3)
    est = Trajectory(gt.t, gt.poses + [[0, 0, 0], [0, 1, 0], [0, 2, 0.3]])
    a = ate(est, gt)
    assert a.rmse_m == pytest.approx(math.sqrt((0 + 1 + 4) / 3))
    assert a.mean_m == pytest.approx(1.0)
    assert a.rot_rmse_rad == pytest.approx(math.sqrt(0.09 / 3))


def test_interpolation_time_and_circle():
    gt = Trajectory([0.0, 1.0], [[0.0, 0.0, 3.1], [2.0, 4.0, -3.1]])
    p = interpolate_poses(gt, [0.5, 0.25])
    np.testing.assert_allclose(p[:, :2], [[1.0, 2.0], [0.5, 1.0]])
    # the short way through +-pi, not through 0
    assert abs(abs(p[0, 2]) - math.pi) < 1e-12
    assert p[1, 2] == pytest.approx(3.1 + 0.25 * (2 * math.pi - 6.2))


def test_ate_ignores_poses_outside_ground_truth():
    gt = straight(5)
    est = Trajectory([-1.0, 0.5, 2.0, 9.0], [[0, 0, 0], [0.5, 1, 0], [2, 0, 0], [9, 0, 0]])
    a = ate(est, gt)
    np.testing.assert_allclose(a.errors, [1.0, 0.0])


def test_rpe_scale_error_and_rigid_invariance():
    gt = straight(11)
    est = Trajectory(gt.t, gt.poses * [1.1, 1.0, 1.0])
    r = rpe(est, gt, delta=1.0)
    assert r.trans_rmse_m == pytest.approx(0.1)
    assert r.rot_rmse_rad == pytest.approx(0.0)
    assert r.pairs == 10
    r2 = rpe(est, gt, delta=2.0, unit="s")
    assert r2.trans_rmse_m == pytest.approx(0.2) and r2.pairs == 9
    # a rigidly moved copy has ATE > 0 but RPE = 0
    moved = apply_alignment(gt, rot(0.5), np.array([3.0, 1.0]))
    assert ate(moved, gt).rmse_m > 1.0
    r3 = rpe(moved, gt, delta=1.0)
    assert r3.trans_rmse_m == pytest.approx(0.0, abs=1e-12)
    assert r3.rot_rmse_rad == pytest.approx(0.0, abs=1e-12)


def test_rpe_rotation_error():
    gt = straight(3)
    est = Trajectory(gt.t, [[0, 0, 0], [1, 0, 0.2], [2, 0, 0.4]])
    r = rpe(est, gt, delta=1.0)
    assert r.rot_rmse_rad == pytest.approx(0.2)
    assert rpe(est, gt, delta=100.0).pairs == 0


def test_nees_reference_and_wrap():
    gt = Trajectory([0.0, 1.0, 2.0], [[0, 0, -math.pi + 0.05], [1, 0, 0], [2, 0, 0]])
    est_poses = np.array([[0, 0, math.pi - 0.05], [1.1, 0, 0], [2, 0, 0]])
    covs = np.stack([np.diag([1.0, 1.0, 0.01]), np.diag([0.01, 1.0, 1.0]), np.zeros((3, 3))])
    est = Trajectory(gt.t, est_poses, covs)
    v = nees_values(est, gt)
    np.testing.assert_allclose(v, [1.0, 1.0])  # (0.1)^2 / 0.01 twice; the P = 0 pose skipped
    assert nees(est, gt) == pytest.approx(1.0)
    assert math.isnan(nees(Trajectory(gt.t, est_poses), gt))


def test_nees_full_covariance():
    gt = Trajectory([0.0], [[0.0, 0.0, 0.0]])
    e = np.array([0.3, -0.2, 0.1])
    p = np.array([[0.5, 0.1, 0.0], [0.1, 0.4, 0.05], [0.0, 0.05, 0.2]])
    est = Trajectory([0.0], [e], p[None])
    assert nees(est, gt) == pytest.approx(e @ np.linalg.solve(p, e))
    # position only: the marginal 2x2 block, not the conditional
    assert nees(est, gt, (0, 1)) == pytest.approx(e[:2] @ np.linalg.solve(p[:2, :2], e[:2]))


def test_metrics_keys():
    gt = straight(11)
    covs = np.repeat(np.eye(3)[None] * 0.04, 11, axis=0)
    est = Trajectory(gt.t, gt.poses + [0.2, 0.0, 0.0], covs)
    res = EstimateResult("ekf", est, used={"ranges": 5, "odometry": 10}, rejected={"ranges": 1})
    log = SensorLog(
        "mem",
        {},
        {},
        Stream("groundtruth", "mem", gt.t, ("x", "y", "theta"), gt.poses),
        {"ranges.duplicate_rows": 2},
    )
    m = metrics(res, log, 0.5)
    assert m["estimator"] == "ekf" and m["poses"] == 11 and m["runtime_s"] == 0.5
    assert m["sensors"] == {
        "odometry": {"used": 10, "rejected": 0},
        "ranges": {"used": 5, "rejected": 1},
    }
    assert m["repairs"] == {"ranges.duplicate_rows": 2}
    assert m["ate_rmse_m"] == pytest.approx(0.2)
    assert m["final_error_m"] == pytest.approx(0.2)
    assert m["rpe_trans_m"] == pytest.approx(0.0, abs=1e-12)
    assert m["rpe_rot_rad"] == pytest.approx(0.0)
    assert m["nees_mean"] == pytest.approx(0.04 / 0.04)
    assert m["nees_position_mean"] == pytest.approx(0.04 / 0.04)
    m2 = metrics(res, SensorLog("mem", {}), 0.5)
    assert "ate_rmse_m" not in m2 and m2["repairs"] == {}


def test_batched_nees_equals_the_per_pose_loop():
    """One batched cholesky/solve gives the same bits as pose by pose, skipping the poses
    whose covariance is not positive definite."""
    from odofuse.evaluation import associate, nees_values
    from odofuse.se2 import wrap

    rng = np.random.default_rng(4)
    n = 300
    cov = rng.normal(size=(n, 3, 3))
    cov = cov @ np.swapaxes(cov, 1, 2) * 1e-2
    t = np.arange(n) * 0.1
    gt = Trajectory(t, rng.normal(size=(n, 3)))
    for bad in (False, True):
        c = cov.copy()
        if bad:
            c[::7] = 0.0
        est = Trajectory(t, gt.poses + rng.normal(size=(n, 3)) * 0.1, c)
        idx, g = associate(est, gt)
        e = est.poses[idx] - g
        e[:, 2] = wrap(e[:, 2])
        want = []
        for ek, pk in zip(e, c, strict=True):
            try:
                ch = np.linalg.cholesky(0.5 * (pk + pk.T))
            except np.linalg.LinAlgError:
                continue
            y = np.linalg.solve(ch, ek)
            # the sum of the squares as nees_values adds them: ``y @ y`` is BLAS's dot,
            # whose kernel fuses the multiply-adds on some CPUs (OpenBLAS on AVX-512: 21 %
            # of random triples differ in the last bit), which is no part of the batching
            want.append(float(np.sum(y * y)))
        got = nees_values(est, gt)
        assert got.shape == (n - (43 if bad else 0),)
        assert np.array_equal(got, np.asarray(want))


def _wiggly_run(n=500, seed=3):
    """A curving estimate with growing covariances (one singular) and a noisy truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    th = np.cumsum(rng.normal(0, 0.05, n))
    xy = np.cumsum(np.column_stack([np.cos(th), np.sin(th)]) * 0.2, axis=0)
    truth = Trajectory(t, np.column_stack([xy, th]))
    covs = np.tile(np.diag([0.01, 0.02, 0.003]), (n, 1, 1)) * (1 + np.arange(n))[:, None, None]
    covs[0] = 0.0  # a perfectly known start: skipped by NEES
    est = Trajectory(t, truth.poses + rng.normal(0, 0.05, (n, 3)), covs)
    return est, truth


def test_metrics_in_blocks_give_the_same_bits(monkeypatch):
    """The per-pose metrics run in blocks of BLOCK poses: tiny blocks change no bit."""
    from odofuse import trajectory

    est, truth = _wiggly_run()

    def scores():
        return (
            ate(est, truth).errors.tolist(),
            ate(est, truth, align=True).rmse_m,
            rpe(est, truth, 1.0),
            rpe(est, truth, 2.0, "s"),
            nees_values(est, truth).tolist(),
            nees_values(est, truth, (0, 1)).tolist(),
            interpolate_poses(truth, est.t[1:] - 0.03).tolist(),
        )

    whole = scores()
    monkeypatch.setattr(trajectory, "BLOCK", 7)
    assert scores() == whole
    assert len(whole[4]) == len(est) - 1  # the singular start skipped, in any block


def test_bad_groundtruth_cell_named_beyond_the_first_block(monkeypatch):
    from odofuse import evaluation, trajectory
    from odofuse.errors import InputError

    monkeypatch.setattr(trajectory, "BLOCK", 16)
    n = 100
    vals = np.zeros((n, 3))
    vals[57, 1] = np.nan
    gt = Stream("groundtruth", "gt.csv", np.arange(n, dtype=float), ("x", "y", "theta"), vals)
    with pytest.raises(InputError) as err:
        evaluation.check_groundtruth(gt)
    assert (err.value.file, err.value.row, err.value.column) == ("gt.csv", 59, "y")


def test_aligned_ate_scores_the_same_poses_with_and_without_a_gap_in_the_truth():
    """The aligned ATE aligns exactly the scored poses: one consecutive run (read as a view) or
    a run broken by a ground-truth gap (gathered), as the alignment of those poses by hand."""
    from odofuse.evaluation import associate

    est, truth = _wiggly_run()
    keep = np.ones(len(truth), dtype=bool)
    keep[20:40] = False  # a gap of 20 samples: the estimate poses inside it are not scored
    for gt in (
        Trajectory(truth.t[1:], truth.poses[1:]),
        Trajectory(truth.t[keep], truth.poses[keep]),
    ):
        idx, g = associate(est, gt)
        r, t, _ = align_se2(est.poses[idx, :2], g[:, :2])
        moved = apply_alignment(Trajectory(est.t[idx], est.poses[idx]), r, t)
        want = float(np.sqrt(np.mean(np.sum((moved.poses[:, :2] - g[:, :2]) ** 2, axis=1))))
        assert ate(est, gt, align=True).rmse_m == pytest.approx(want, rel=1e-12)
    assert idx.size < len(est) - 1  # the gap left poses unscored
