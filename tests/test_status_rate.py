"""Issue 25 item 5, short form of ``benchmarks/bench_status.py``: on nominal logs the status says
``degraded`` no more often than ``alpha_run`` allows (the binomial 99 % bound for the small
count), injected faults are detected (the same bound on the misses), and no run that says
``ok`` has a position NEES above the chi-square 99.9 % bound of its run.

Seeds 504, 507, 510 (the differential robot with gyro and GPS, gyro and ranges, wheels only;
low noise) and faults on 504-506 were not used to choose defaults (the benchmark's seed sets
are 1000-1017 and 2000 on). They were run once before the benchmark's last change: seed 510's
wheels-only log then had drawn systematic errors its config cannot know (dead reckoning `ok`
at NEES 10.7), which is why wheels-only logs now have the exact geometry their config states.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_status as bs  # noqa: E402

ESTIMATORS = ("ekf", "smoother")
NOMINAL_SEEDS = (504, 507, 510)
FAULT_SEEDS = (504, 505, 506)
FAULTS = ("stuck_encoder", "gps_multipath")


def test_binomial_bound_and_effective_count():
    # 100 runs at a true 5 %: more than 11 degraded has probability below 1 %
    assert bs.binomial_bound(100) == 11
    assert bs.binomial_bound(3) == 1  # the wide bound of a small count
    rng = np.random.default_rng(0)
    white = rng.chisquare(2, 4000)
    assert bs.n_eff(white) > 2500  # independent values: n_eff near n
    slow = np.repeat(rng.chisquare(2, 40), 100)  # 40 independent values, each held 100 times
    assert 10 < bs.n_eff(slow) < 120
    bound, ne = bs.nees_bound(white)
    assert 2.0 < bound < 2.3 and ne > 2500


def test_generalised_chi_square_quantile_reference_values():
    from scipy.stats import chi2

    # equal weights: a scaled chi-square (5 independent positions: chi-square(10) / 5)
    assert bs.generalised_chi2_ppf(np.full(10, 0.2)) == pytest.approx(chi2.ppf(0.999, 10) / 5)
    # one position (two equal weights, an exponential) and a single chi-square(1) value
    assert bs.generalised_chi2_ppf(np.ones(2)) == pytest.approx(chi2.ppf(0.999, 2), rel=1e-7)
    assert bs.generalised_chi2_ppf(np.array([3.0])) == pytest.approx(3 * chi2.ppf(0.999, 1))
    many = np.full(400, 0.005)  # 200 independent positions
    assert bs.generalised_chi2_ppf(many) == pytest.approx(chi2.ppf(0.999, 400) / 200)
    # unequal weights against a seeded Monte Carlo of 2e6 draws (its 99.9 % point to ~1 %)
    lam = np.array([1.2, 0.5, 0.2, 0.05, 0.05])
    rng = np.random.default_rng(7)
    draws = (rng.standard_normal((2_000_000, lam.size)) ** 2) @ lam
    assert bs.generalised_chi2_ppf(lam) == pytest.approx(np.quantile(draws, 0.999), rel=0.02)


def test_the_model_bound_reads_the_solutions_own_joint_covariance():
    # a SLAM log of bench_slam_status (seed 2002, nominal): run_log checks that the mean NEES
    # of the joint covariance's blocks is the run's; the solution says its positions' errors
    # hold about two independent values (the map's common drift; 9.97 is the 99.9 % point of
    # a mean of 2.1), which Sokal's window on the NEES series overstated (bound 3.22)
    import bench_slam_status as bss
    from scipy.stats import chi2

    from odofuse.estimators.graph import solvers

    log, cfg, _ = bss.make_case(2002)
    status, mean, bound, _w, _rmse, model = bs.run_log(log, cfg, ["isam2"])["isam2"]
    assert status == "ok" and solvers.on_solution is None
    assert 0 < mean < bound < model
    # between two and three independent positions' bound and a single one's
    assert chi2.ppf(0.999, 6) / 3 < model < chi2.ppf(0.999, 2)


@pytest.mark.parametrize("seed", [504, 510])
def test_dead_reckonings_model_bound_follows_its_own_propagation(seed):
    # seed 504: differential with gyro and GPS (odometry calibration on: the prior of the
    # systematic errors is in the covariance); 510: wheels only (off)
    import dataclasses

    from scipy.stats import chi2

    from odofuse.estimators import dead_reckoning as dr
    from odofuse.estimators.common import initial_state, odometry_inputs
    from odofuse.estimators.compiled.dead_reckoning import dead_reckon
    from odofuse.estimators.odocal import filter_odometry_calibration
    from odofuse.evaluation import trajectory_from_stream
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.motion import motion_model_from_config

    log, cfg, _ = bs.make_case(seed)
    cfg, log = apply_log_defaults(cfg, log)
    cfg = dataclasses.replace(cfg, estimator="dead_reckoning")
    traj = dr.run(log, cfg).trajectory
    model = motion_model_from_config(cfg)
    opts = cfg.estimator_options("dead_reckoning")
    cal = filter_odometry_calibration(model, opts, "options.dead_reckoning", cfg.source)
    assert (cal is not None) == (seed == 504)
    t, U = odometry_inputs(log, model)
    idx = np.linspace(1, len(traj.t) - 1, 12).astype(int)
    m = len(idx)
    S = bs.dead_reckoning_joint_covariance(log, cfg, traj, idx)
    # its diagonal is the run's own covariances
    diag = S.reshape(m, 2, m, 2)[np.arange(m), :, np.arange(m), :]
    assert np.allclose(diag, traj.covariances[idx, :2, :2], rtol=1e-9, atol=0.0)
    # Phi(k, j) = I + c e_theta^T is the derivative of the pose at k with respect to the pose
    # at j: dead-reckoned again from j, moved by 1e-6 in x and in heading
    j, k = idx[2], idx[7]
    again = dead_reckon(model, traj.poses[j], np.zeros((3, 3)), U[j:k], False)[0][-1]
    assert np.allclose(again, traj.poses[k], atol=1e-9)
    c = np.array([-(traj.poses[k, 1] - traj.poses[j, 1]), traj.poses[k, 0] - traj.poses[j, 0]])
    for col, expected in ((0, [1.0, 0.0]), (2, c)):
        moved = traj.poses[j] + 1e-6 * np.eye(3)[col]
        d = (dead_reckon(model, moved, np.zeros((3, 3)), U[j:k], False)[0][-1] - again) / 1e-6
        assert np.allclose(d[:2], expected, rtol=1e-4, atol=1e-6), (col, d, expected)
    # between two poses the white part's covariance grows by what the motion adds, never less
    white = traj.covariances
    if cal is not None:
        pose0, _ = initial_state(cfg, log)
        white = white - dr.calibration_covariances(model, cal, pose0, t, U, traj.poses)
    for j, k in zip(idx[:-1], idx[1:], strict=True):
        Phi = np.eye(3)
        Phi[:2, 2] = [-(traj.poses[k, 1] - traj.poses[j, 1]), traj.poses[k, 0] - traj.poses[j, 0]]
        added = white[k] - Phi @ white[j] @ Phi.T
        assert np.linalg.eigvalsh(added)[0] > -1e-9 * np.abs(white[k]).max()
    # the bound: dead reckoning's error is mostly one growing mode, between one position's
    # bound and that of m independent ones
    gt = trajectory_from_stream(log.groundtruth)
    bound, sub_mean = bs.dead_reckoning_nees_bound(log, cfg, traj, gt)
    n = min(bs.FILTER_BOUND_POSES, len(traj.t))
    assert chi2.ppf(0.999, 2 * n) / n < bound < chi2.ppf(0.999, 2)
    assert 0.0 < sub_mean < bound


def test_a_filters_model_bound_follows_its_own_closed_loop():
    # the EKF on the nominal log of seed 504 (differential, gyro and GPS, low noise), on its
    # Python path with its operations recorded (benchmarks/filter_joint.py): between two poses
    # the filter's covariance grows by what its closed loop adds, Q and K R K^T, never less
    import dataclasses

    import filter_joint
    from scipy.stats import chi2

    from odofuse.evaluation import nees_values, trajectory_from_stream
    from odofuse.log_defaults import apply_log_defaults

    log, cfg, _ = bs.make_case(504)
    cfg, log = apply_log_defaults(cfg, log)
    cfg = dataclasses.replace(cfg, estimator="ekf")
    traj, steps = filter_joint.run_recorded(log, cfg, "ekf")
    assert len(steps) == len(traj.t)
    assert filter_joint.worst_added_noise(steps) > -1e-9
    # without the closed loop (every Phi the identity) an update's shrinking shows at once
    frozen = [(None, P) for _, P in steps]
    assert filter_joint.worst_added_noise(frozen) < -0.1
    # the joint covariance holds the run's own covariances on its diagonal
    idx = np.arange(1, len(steps), 50)
    S = filter_joint.joint_position_covariance(steps, idx).reshape(len(idx), 2, len(idx), 2)
    diag = S[np.arange(len(idx)), :, np.arange(len(idx)), :]
    assert np.allclose(diag, traj.covariances[idx, :2, :2], rtol=1e-12, atol=0.0)
    assert np.linalg.eigvalsh(S.reshape(2 * len(idx), -1))[0] > -1e-12 * np.abs(S).max()
    # the run's bound on its scored poses: the filter's errors are correlated over a run, so
    # between that of independent positions and that of a single one
    gt = trajectory_from_stream(log.groundtruth)
    bound, sub_mean = bs.recorded_nees_bound(traj, steps, gt)
    m = min(bs.FILTER_BOUND_POSES, nees_values(traj, gt, (0, 1)).size)
    assert chi2.ppf(0.999, 2 * m) / m < bound < chi2.ppf(0.999, 2)
    assert 0.0 < sub_mean < bound


def test_the_particle_filters_model_bound_is_the_ekfs_correlation_at_its_own_covariances():
    # the particle filter's bound takes the EKF's closed loop on the same log and config (the
    # same model) for the correlation of the errors and keeps its own covariances: given the
    # EKF's own trajectory it is the EKF's bound, and it does not move when the covariances
    # are scaled (the run's mean NEES does)
    import dataclasses

    import filter_joint

    from odofuse.evaluation import trajectory_from_stream
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.trajectory import Trajectory

    log, cfg, _ = bs.make_case(504)
    cfg, log = apply_log_defaults(cfg, log)
    cfg = dataclasses.replace(cfg, estimator="particle")
    gt = trajectory_from_stream(log.groundtruth)
    ekf, steps = filter_joint.run_recorded(log, dataclasses.replace(cfg, estimator="ekf"), "ekf")
    expected = bs.recorded_nees_bound(ekf, steps, gt)
    assert np.allclose(bs.particle_nees_bound(log, cfg, ekf, gt), expected, rtol=1e-9)
    wide = Trajectory(ekf.t, ekf.poses, 4.0 * ekf.covariances)
    bound, mean = bs.particle_nees_bound(log, cfg, wide, gt, (ekf, steps))
    assert bound == pytest.approx(expected[0], rel=1e-9)
    assert mean == pytest.approx(expected[1] / 4.0, rel=1e-9)
    with pytest.raises(AssertionError, match="not the particle filter's"):
        late = Trajectory(ekf.t + 1.0, ekf.poses, ekf.covariances)
        bs.particle_nees_bound(log, cfg, late, gt, (ekf, steps))


def test_lag_prefixes_are_the_keyframes_held_when_each_pose_left_the_window():
    # run_fixed_lag takes pose j's estimate before adding the first keyframe i with
    # kt[i] - lag > kt[j], so with the keyframes 0..i-1 in it; the last poses take all
    kt = np.arange(11.0)
    assert bs.lag_prefixes(kt, 2.5).tolist() == [2, 3, 4, 5, 6, 7, 8, 9, 10, 10, 10]
    assert bs.lag_prefixes(kt, 2.0).tolist() == [2, 3, 4, 5, 6, 7, 8, 9, 10, 10, 10]
    assert bs.lag_prefixes(kt, 1.5).tolist() == [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 10]
    assert bs.lag_prefixes(kt, 20.0).tolist() == [10] * 11


def test_the_fixed_lag_model_bound_is_the_covariance_of_its_stitched_estimates():
    # the fixed-lag smoother on the nominal log of seed 504 (differential, gyro and GPS): each
    # stitched estimate is a linear map of the whitened noise of the factors it held, e_j =
    # (H_p^-1 A_p^T n_p)[j], so their joint covariance is the product of those maps, which
    # the benchmark reads from each prefix's information matrix alone
    import dataclasses

    from scipy.stats import chi2

    from odofuse import se2
    from odofuse.estimators.graph import solvers
    from odofuse.estimators.graph.isam2 import run_fixed_lag
    from odofuse.estimators.graph.keys import X
    from odofuse.evaluation import trajectory_from_stream
    from odofuse.log_defaults import apply_log_defaults

    log, cfg, _ = bs.make_case(504)
    cfg, log = apply_log_defaults(cfg, log)
    got = []
    solvers.on_solution = lambda *args: got.append(args)
    try:
        res = run_fixed_lag(log, dataclasses.replace(cfg, estimator="fixed_lag"))
    finally:
        solvers.on_solution = None
    ((problem, graph, values, estimator),) = got
    assert estimator == "fixed_lag" and graph.size() > len(problem.kt)
    kt = problem.kt
    idx = np.arange(0, len(kt), 7)
    S = bs.fixed_lag_joint_covariance(problem, graph, values, idx)
    A, row_tag, key_tags, key_end, col = bs.prefix_system(graph, values)
    A = A.toarray()
    prefix = bs.lag_prefixes(kt, problem.options.lag)
    assert len(set(prefix[idx])) > 10  # many windows, not one solution
    M = np.zeros((2 * len(idx), A.shape[0]))
    for a, j in enumerate(idx):
        q = prefix[j]
        m_q, n_q = int((row_tag <= q).sum()), int(key_end[key_tags <= q].max())
        Aq = A[:m_q, :n_q]
        c = col[X(int(j))]
        M[2 * a : 2 * a + 2, :m_q] = np.linalg.solve(Aq.T @ Aq, Aq.T)[c : c + 2]
    theta = np.array([values.atPose2(X(int(j))).theta() for j in idx])
    R = np.kron(np.eye(len(idx)), np.eye(2))
    for a, r in enumerate(se2.rot(theta)):
        R[2 * a : 2 * a + 2, 2 * a : 2 * a + 2] = r
    brute = R @ (M @ M.T) @ R.T
    assert np.allclose(S, brute, rtol=1e-6, atol=1e-9 * np.abs(S).max())
    # its diagonal is the run's own covariances, up to the linearisation point
    m = len(idx)
    Q = S.reshape(m, 2, m, 2)[np.arange(m), :, np.arange(m), :]
    P = res.trajectory.covariances[idx][:, :2, :2]
    ratios = np.concatenate([np.linalg.eigvals(np.linalg.solve(Q[i], P[i])).real for i in range(m)])
    assert 0.9 < ratios.min() and ratios.max() < 1.1, (ratios.min(), ratios.max())
    # errors across windows are correlated: more than one value, fewer than m independent ones
    gt = trajectory_from_stream(log.groundtruth)
    bound, sub_mean, worst = bs.fixed_lag_nees_bound(problem, graph, values, res.trajectory, gt)
    n = min(bs.FILTER_BOUND_POSES, len(kt))
    assert chi2.ppf(0.999, 2 * n) / n < bound < chi2.ppf(0.999, 2)
    assert 0.0 < sub_mean < bound and worst < bs.FIXED_LAG_COVARIANCE_TOLERANCE


@pytest.fixture(scope="module")
def table():
    # Sokal's bound is what the tests judge; the model bounds are the benchmark's column
    return bs.measure(
        NOMINAL_SEEDS,
        ESTIMATORS,
        FAULTS,
        FAULT_SEEDS,
        log_lines=lambda _l: None,
        model_bounds=False,
    )


#: The EKF's nominal rate was a strict xfail on the defaults branch: its consistent runs on 504
#: (NEES 2.28, bound 4.84) and 507 (NEES 1.48, bound 4.38) were degraded by the cross-check's
#: accuracy ratio to the smoother (``p_fail`` 0.73 and 0.97). Issue 25 item 2 (merged from the
#: status branch) turned that ratio into advice: the same runs, with the same NEES, now say
#: ``ok`` (0/3 degraded, bound 1), so the mark is gone.
@pytest.mark.slow
@pytest.mark.parametrize("est", ESTIMATORS)
def test_nominal_degraded_rate_is_within_the_binomial_bound(table, est):
    rows = table["nominal"][est]
    degraded = [r for r in rows if r[2] != "ok"]
    assert len(degraded) <= bs.binomial_bound(len(rows)), degraded


@pytest.mark.slow
@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("est", ESTIMATORS)
def test_injected_faults_are_detected(table, fault, est):
    rows = table[fault][est]
    missed = [r for r in rows if r[2] == "ok"]
    assert len(missed) <= bs.binomial_bound(len(rows), 1 - bs.DETECTION), missed


@pytest.mark.slow
@pytest.mark.parametrize("est", ESTIMATORS)
def test_ok_runs_are_consistent(table, est):
    over = [
        (kind, r)
        for kind in table
        for r in table[kind][est]
        if r[2] == "ok" and np.isfinite(r[3]) and r[3] > r[4]
    ]
    assert not over, over
