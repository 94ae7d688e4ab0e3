"""Graph estimators on the datasets of the gtsam wheel, against GTSAM's own solutions (issue 12).

References are plain GTSAM (``benchmarks/gtsam_reference.py``: ``gtsam.load2D`` /
``gtsam.readG2o`` plus a prior on the first pose, ``LevenbergMarquardtOptimizer``, ``ISAM2``),
and odofuse's solution is scored in GTSAM's own graph (``graph.error``), as GTSAM scores it.
The large files (w10000, w20000, the full Victoria Park, GOATS SLAM) are in
``benchmarks/bench_datasets.py``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from odofuse.config import RunConfig  # noqa: E402
from odofuse.errors import ConfigError  # noqa: E402
from odofuse.estimators import graph, run_estimator  # noqa: E402
from odofuse.estimators.graph.landmarks import from_sighting, multilaterate  # noqa: E402
from odofuse.estimators.graph.marginals import marginal_covariances  # noqa: E402
from odofuse.io.loader import load_log  # noqa: E402
from odofuse.io.log import SensorLog, Stream  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import gtsam_reference as ref  # noqa: E402

DATA = os.path.dirname(gtsam.findExampleDataFile("w100.graph"))


def _run(name, estimator="smoother", **options):
    path = os.path.join(DATA, name)
    log = load_log(path)
    return log, run_estimator(estimator, log, ref.dataset_config(log, path, estimator, **options))


# ------------------------------------------------------------------ pose graphs = GTSAM's LM
@pytest.mark.parametrize(
    ("name", "reader"),
    [
        ("w100.graph", "load2D"),
        ("w100_30.g2o", "load2D"),  # VERTEX2/EDGE2 lines despite the extension
        ("pose2example.txt", "readG2o"),
        ("noisyToyGraph.txt", "readG2o"),
        ("optimizedNoisyToyGraph.txt", "readG2o"),
        ("orientationsNoisyToyGraph.txt", "readG2o"),
    ],
)
def test_pose_graph_equals_gtsam_lm_optimum(name, reader):
    _, res = _run(name)
    g, v, keys = ref.load(os.path.join(DATA, name), reader)
    best = ref.lm_optimum(g, v)
    ours = ref.odofuse_values(res, keys)
    assert res.used["loop_closures"] > 0 and res.rejected["loop_closures"] == 0
    assert ref.position_rms(ref.poses_of(ours, keys), ref.poses_of(best, keys)) < 0.05
    assert g.error(ours) == pytest.approx(g.error(best), rel=1e-6, abs=1e-9)
    assert res.extra["final_error"] == pytest.approx(g.error(best), rel=1e-6, abs=1e-9)
    assert res.trajectory.covariances is not None and not res.findings


def test_pose_graph_uses_the_file_covariances_and_config_sigma_overrides():
    path = os.path.join(DATA, "w100.graph")
    log = load_log(path)
    cfg = ref.dataset_config(log, path)
    base = graph.run_smoother(log, cfg)
    loops = {"sigma": [0.5, 0.5, 0.1]}
    loose = graph.run_smoother(log, replace(cfg, sensors={**cfg.sensors, "loop_closures": loops}))
    # the same factors with loop sigmas 0.5 m / 0.1 rad instead of the file's 1 m / 1 rad
    g, v, keys = ref.load(path)
    assert base.extra["final_error"] == pytest.approx(g.error(ref.odofuse_values(base, keys)))
    assert loose.extra["final_error"] > base.extra["final_error"]
    for bad, key in (({"sigma": [1, 2]}, "sigma"), ({"sigmas": 1}, "sigmas")):
        with pytest.raises(ConfigError) as exc:  # validated with the config
            graph.run_smoother(log, replace(cfg, sensors={**cfg.sensors, "loop_closures": bad}))
        assert exc.value.key == f"sensors.loop_closures.{key}"


def test_robust_loop_closures_resist_a_false_loop():
    path = os.path.join(DATA, "w100.graph")
    log = load_log(path)
    lc = log.streams["loop_closures"]
    bad = lc.values.copy()
    bad[5, 2:5] = [8.0, -6.0, 2.0]  # one wrong loop closure (place recognition failure)
    streams = dict(log.streams, loop_closures=Stream("loop_closures", "x", lc.t, lc.columns, bad))
    wrong = SensorLog(log.source, streams, {}, None, {}, log.initial_pose)
    cfg = ref.dataset_config(log, path)
    clean = graph.run_smoother(log, cfg).trajectory.poses
    plain = graph.run_smoother(wrong, cfg).trajectory.poses
    loops = {"robust": {"type": "cauchy", "k": 1.0}}
    robust_cfg = replace(cfg, sensors={**cfg.sensors, "loop_closures": loops})
    robust = graph.run_smoother(wrong, robust_cfg).trajectory.poses
    err = {k: ref.position_rms(p, clean) for k, p in (("plain", plain), ("robust", robust))}
    assert err["robust"] < 0.25 * err["plain"], err


def test_isam2_and_fixed_lag_use_loop_closures():
    g, v, keys = ref.load(os.path.join(DATA, "w100.graph"))
    best = ref.poses_of(ref.lm_optimum(g, v), keys)
    _, inc = _run("w100.graph", "isam2")
    assert ref.position_rms(inc.trajectory.poses, best) < 0.05
    log, lag = _run("w100.graph", "fixed_lag", lag=20.0)
    # loops reaching more than 20 poses (20 s) back would need a marginalised pose
    lc = log.streams["loop_closures"]
    far = int(np.sum(np.abs(lc["t_to"] - lc["t_from"]) > 20.0))
    assert lag.rejected["loop_closures"] == far > 0
    assert lag.used["loop_closures"] == len(lc) - far


def test_filters_say_they_ignore_loop_closures(tmp_path):
    path = os.path.join(DATA, "w100.graph")
    log = load_log(path)
    cfg = ref.dataset_config(log, path, "dead_reckoning")
    cfg.sensors.pop("loop_closures")
    res = run_estimator("dead_reckoning", log, cfg)
    (note,) = [f for f in res.findings if f.check == "loop_closures"]
    assert not note.degrades and note.figure == len(log.streams["loop_closures"])
    assert "201 loop closures" in note.line()


# ------------------------------------------------------------------ SLAM
def test_example_graph_equals_gtsam_optimum():
    _, res = _run("example.graph")
    g, v, keys = ref.load(os.path.join(DATA, "example.graph"))
    best = ref.lm_optimum(g, v)
    ours = ref.odofuse_values(res, keys)
    assert g.error(best) == pytest.approx(279.52, abs=0.01)  # GTSAM's optimum (issue 12)
    assert g.error(ours) == pytest.approx(g.error(best), rel=1e-6)
    assert ref.position_rms(ref.poses_of(ours, keys), ref.poses_of(best, keys)) < 0.05


@pytest.fixture(scope="module")
def victoria_head(tmp_path_factory):
    """Victoria Park up to pose 1200 (its first 1,100 poses), lines unchanged: the judged
    comparison on a graph small enough for a test (the whole file is in the benchmark)."""
    src = gtsam.findExampleDataFile("victoria_park.txt")
    path = tmp_path_factory.mktemp("vp") / "victoria_head.txt"
    with open(src) as fh, open(path, "w") as out:
        for line in fh:
            ids = line.split()[1:3]
            if max(int(ids[0]), int(ids[1]) if line.startswith("ODOMETRY") else 0) <= 1200:
                out.write(line)
    return path


@pytest.fixture(scope="module")
def victoria_head_best(victoria_head):
    """GTSAM's graph of :func:`victoria_head`, its pose keys and GTSAM's best solution of it
    (its iSAM2 incremental solve polished by LM)."""
    g, _, keys = ref.load(victoria_head)
    return g, keys, ref.lm_optimum(g, ref.isam2_incremental(g, keys))


def test_victoria_park_slam_reaches_gtsams_best(victoria_head, victoria_head_best):
    log = load_log(victoria_head)
    res = graph.run_smoother(log, ref.dataset_config(log, victoria_head, covariances=False))
    g, keys, best = victoria_head_best
    ours = ref.odofuse_values(res, keys)
    assert g.error(ours) <= 1.01 * g.error(best)
    assert ref.position_rms(ref.poses_of(ours, keys), ref.poses_of(best, keys)) < 1.0
    assert len(res.extra["landmarks"]) == len(np.unique(log.streams["landmarks"]["id"]))


def test_isam2_slam_victoria_head(victoria_head, victoria_head_best):
    log = load_log(victoria_head)
    res = graph.run_isam2(log, ref.dataset_config(log, victoria_head, "isam2"))
    g, keys, best = victoria_head_best
    ours = ref.odofuse_values(res, keys)
    # the judged bounds (issue 12): within 1 % of GTSAM's best, poses within 1 m of it;
    # before the final LM (graph.solvers.polish_isam2) the whole file was +17.5 %
    assert g.error(ours) <= 1.01 * g.error(best)
    assert ref.position_rms(ref.poses_of(ours, keys), ref.poses_of(best, keys)) < 1.0
    assert res.extra["final_error"] == pytest.approx(g.error(ours), rel=1e-3)
    assert not [f for f in res.findings if f.check == "solver"]
    assert res.used["landmarks"] == len(log.streams["landmarks"])
    cov = res.extra["landmark_covariances"]
    assert set(cov) == set(res.extra["landmarks"])
    assert all(c[0] > 0 and c[2] > 0 and c[0] * c[2] > c[1] ** 2 for c in cov.values())


def test_first_sighting_and_multilateration_reference_values():
    np.testing.assert_allclose(
        from_sighting([1.0, 2.0, math.pi / 2], 3.0, -math.pi / 2), [4.0, 2.0], atol=1e-12
    )
    rng = np.random.default_rng(4)
    P = rng.uniform(-20, 20, size=(30, 2))
    lm = np.array([7.0, -3.0])
    R = np.linalg.norm(P - lm, axis=1) + rng.normal(0, 0.1, 30)
    R[:5] += 15.0  # multipath outliers
    np.testing.assert_allclose(multilaterate(P, R, np.full(30, 0.1)), lm, atol=0.1)
    line = np.column_stack([np.linspace(0, 30, 20), np.zeros(20)])  # mirror ambiguity
    assert multilaterate(line, np.linalg.norm(line - lm, axis=1), np.full(20, 0.1)) is None


def test_goats_range_only_localisation_and_slam():
    log, slam = _run("goats_16.pyfg", "isam2", covariances=False, slam=True)
    assert slam.used["ranges"] == len(log.streams["ranges"])
    # the SLAM map is in the frame of the file's start pose: it matches the known beacons
    # after a rigid alignment (ranges 10 m .. 700 m, sigma 0.75 m)
    ids = sorted(log.landmarks)
    T, start = ref.aligned_start(slam, log)
    A = np.array([slam.extra["landmarks"][i] for i in ids])
    B = np.array([log.landmarks[i] for i in ids])
    assert np.max(np.linalg.norm(ref.apply_se2(T, A) - B, axis=1)) < 25.0
    path = os.path.join(DATA, "goats_16.pyfg")
    cfg = dataclasses.replace(
        ref.dataset_config(log, path), initial={"pose": list(start), "sigma": [10.0, 10.0, 0.1]}
    )
    loc = run_estimator("smoother", log, cfg)
    resid = ref.range_residuals(loc, log)
    # measured 6.9 m (SLAM on its own map: 1.3 m): the known beacons and the ranges disagree
    # by more than the file's 0.75 m sigma (bench_datasets.py reports both)
    assert np.median(np.abs(resid)) < 10.0 and not loc.extra.get("landmarks")
    assert loc.used["ranges"] == len(log.streams["ranges"])
    # not odofuse's model: plain GTSAM on the file's own factors (fixed beacons) starting from
    # odofuse's estimate finds nothing better, and keeps the 6.9 m residuals (docs/graph.md)
    g, values, ranges = _pyfg_localisation_graph(path, loc.trajectory, start)
    best = gtsam.LevenbergMarquardtOptimizer(g, values).optimize()
    assert g.error(best) > 0.999 * g.error(values)
    assert np.median(np.abs(ranges(best))) > 5.0
    moved = gtsam.Values(values)  # and GTSAM does solve this graph: from 5 m off, back there
    for k in range(len(loc.trajectory.t)):
        p = values.atPose2(gtsam.symbol("x", k))
        moved.update(gtsam.symbol("x", k), gtsam.Pose2(p.x() + 5.0, p.y() - 5.0, p.theta()))
    back = gtsam.LevenbergMarquardtOptimizer(g, moved).optimize()
    assert g.error(moved) > g.error(values) + 1000.0
    assert g.error(back) == pytest.approx(g.error(values), rel=1e-3)


def _pyfg_localisation_graph(path, traj, start):
    """GTSAM's graph of a pyfg file with its beacons fixed: ``(graph, values at traj, residuals)``.

    The file's EDGE_SE2 (its covariance) and EDGE_RANGE (its variance) as GTSAM factors, the
    VERTEX_XY beacons held by priors of sigma 1 um, the start prior ``start`` of sigma (10 m,
    10 m, 0.1 rad) as in odofuse's run; values: ``traj``'s poses (pose ``k`` at ``t = k``).
    """
    from gtsam.symbol_shorthand import L, X

    rows = [line.split() for line in Path(path).read_text().splitlines()]
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    fixed = gtsam.noiseModel.Isotropic.Sigma(2, 1e-6)
    for r in rows:
        if r[0] == "VERTEX_XY":
            b = gtsam.Point2(float(r[2]), float(r[3]))
            v.insert(L(int(r[1][1:])), b)
            g.add(gtsam.PriorFactorPoint2(L(int(r[1][1:])), b, fixed))
    assert np.allclose(traj.t, np.arange(len(traj.t)))
    for k, p in enumerate(traj.poses):
        v.insert(X(k), gtsam.Pose2(*p))
    sig = gtsam.noiseModel.Diagonal.Sigmas(np.array([10.0, 10.0, 0.1]))
    g.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*start), sig))
    edges = []
    for r in rows:
        if r[0] == "EDGE_SE2":
            c = [float(x) for x in r[7:13]]
            cov = np.array([[c[0], c[1], c[2]], [c[1], c[3], c[4]], [c[2], c[4], c[5]]])
            delta = gtsam.Pose2(float(r[4]), float(r[5]), float(r[6]))
            i, j = X(int(r[2][1:])), X(int(r[3][1:]))
            g.add(gtsam.BetweenFactorPose2(i, j, delta, gtsam.noiseModel.Gaussian.Covariance(cov)))
        elif r[0] == "EDGE_RANGE":
            edges.append((X(int(r[2][1:])), L(int(r[3][1:])), float(r[4])))
            noise = gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(float(r[5])))
            g.add(gtsam.RangeFactor2D(*edges[-1], noise))

    def residuals(values):
        return np.array([values.atPose2(k).range(values.atPoint2(b)) - r for k, b, r in edges])

    return g, v, residuals


# ------------------------------------------------------------------ marginals, outputs
def test_marginals_of_an_indeterminate_graph_are_regularised_not_thrown():
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    x0, lk = gtsam.symbol("x", 0), gtsam.symbol("l", 1)
    g.add(gtsam.PriorFactorPose2(x0, gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    g.add(gtsam.RangeFactor2D(x0, lk, 5.0, gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    v.insert(x0, gtsam.Pose2())
    v.insert(lk, gtsam.Point2(5.0, 0.0))  # one range: the landmark's bearing is free
    with pytest.raises(RuntimeError):
        gtsam.Marginals(g, v)
    cov, notes = marginal_covariances(g, v, [x0, lk], {x0: 3, lk: 2})
    (note,) = notes
    assert note.check == "covariance" and "indeterminate" in note.message
    np.testing.assert_allclose(cov[x0], np.eye(3) * 0.01, rtol=1e-4)
    # the free direction shows the regulariser: a prior of sigma 100, variance 1e4 (the one
    # marginals function kept; the removed duplicate used sigma 1e3, so this read > 1e5)
    assert cov[lk][1, 1] > 0.9e4


def test_cli_slam_writes_landmarks_csv(tmp_path):
    from odofuse.cli import main

    cfg = tmp_path / "run.yaml"
    cfg.write_text(
        f"log: {os.path.join(DATA, 'example.graph')}\nrobot: {{drive: increments}}\n"
        "motion: {integrator: exact, k: [1.0e-3, 1.0e-4]}\nestimator: smoother\n"
        "sensors: {landmarks: {}}\noptions: {smoother: {slam: true}}\noutput: out\n"
    )
    assert main(["run", str(cfg)]) == 0
    out = tmp_path / "out"
    lines = (out / "landmarks.csv").read_text().splitlines()
    assert lines[0] == "id,x,y,var_x,cov_xy,var_y"
    rows = np.array([[float(c) for c in r.split(",")] for r in lines[1:]])
    res = json.loads((out / "metrics.json").read_text())
    assert len(rows) == len(res["extra"]["landmarks"]) if "extra" in res else len(rows) > 0
    assert np.all(rows[:, 3] > 0) and np.all(rows[:, 5] > 0)
    assert (out / "trajectory.png").stat().st_size > 0


def test_fixed_lag_refuses_slam_by_name():
    path = os.path.join(DATA, "example.graph")
    log = load_log(path)
    with pytest.raises(ConfigError, match="smoother and isam2"):
        graph.run_fixed_lag(log, ref.dataset_config(log, path, "fixed_lag"))


def test_slam_init_option_is_validated():
    with pytest.raises(ConfigError) as exc:  # validated once, when the config is built
        RunConfig(
            log="x",
            robot={"drive": "increments"},
            options={"smoother": {"slam_init": "grid"}},
            source="f.yaml",
        )
    assert exc.value.key == "options.smoother.slam_init"


# ------------------------------------------------------------ chordal start and the LM rule
def test_chordal_poses_are_exact_on_a_noise_free_graph():
    from types import SimpleNamespace

    from odofuse import se2
    from odofuse.estimators.graph.chordal import chordal_poses
    from odofuse.estimators.graph.loops import Loop

    rng = np.random.default_rng(7)
    K = 80  # a random walk whose heading wraps past +-pi several times
    truth = np.zeros((K, 3))
    truth[0] = (2.0, -1.0, 3.0)
    for k in range(1, K):
        truth[k] = se2.compose(truth[k - 1], [rng.uniform(0.5, 1.5), 0.1, rng.normal(0, 0.6)])
    deltas = np.array([se2.between(truth[k], truth[k + 1]) for k in range(K - 1)])
    pairs = [(int(i), int(j)) for i, j in rng.integers(0, K, (40, 2)) if abs(i - j) > 3]
    cov = np.diag([0.3, 0.3, 0.05])
    loops = [
        Loop(i, j, tuple(se2.between(truth[i], truth[j])), cov, r) for r, (i, j) in enumerate(pairs)
    ]
    problem = SimpleNamespace(
        kt=np.arange(K, dtype=float),
        deltas=deltas,
        covs=np.repeat(cov[None], K - 1, 0),
        loops=loops,
        pose0=truth[0],
    )
    got = chordal_poses(problem)
    assert np.abs(got[:, :2] - truth[:, :2]).max() < 1e-9
    assert np.abs(se2.wrap(got[:, 2] - truth[:, 2])).max() < 1e-9


def test_chordal_start_agrees_with_the_independent_reference_and_lm_is_converged():
    # odofuse's relaxation (graph.chordal) and gtsam_reference's complex-number one are two
    # implementations of the same problem: equal headings. w100 stores its edges backwards
    # (1 -> 0), which odofuse turns forwards with the covariance moved to the other pose
    # (xy variances 1 and 2 instead of 1 and 1), so the position weights differ: positions
    # agree to centimetres only (on w20000, forward edges, 1.4e-8 m). The smoother ends at
    # the minimum that GTSAM's LM run to a standstill (plus Gauss-Newton) reaches.
    from odofuse.estimators.graph.chordal import chordal_poses
    from odofuse.estimators.graph.problem import build_problem

    path = os.path.join(DATA, "w100.graph")
    log = load_log(path)
    cfg = ref.dataset_config(log, path)
    g, v, keys = ref.load(path)
    ours = chordal_poses(build_problem(log, cfg, "smoother"))
    theirs = ref.poses_of(ref.chordal_start(g, v, keys), keys)
    assert np.abs(ours[:, 2] - theirs[:, 2]).max() < 1e-9
    assert ref.position_rms(ours, theirs) < 0.05
    best, _, _ = ref.converged_optimum(g, ref.chordal_start(g, v, keys))
    res = graph.run_smoother(log, cfg)
    assert set(res.extra["initial"]) == {"start", "odometry_error", "chordal_error"}
    sol = ref.odofuse_values(res, keys)
    assert g.error(sol) == pytest.approx(g.error(best), rel=1e-9, abs=1e-9)
    assert ref.position_rms(ref.poses_of(sol, keys), ref.poses_of(best, keys)) < 1e-3


def test_a_landmark_seen_again_after_the_window_is_a_loop_closure():
    """isam2_slam.resighting_loops: a landmark back in view after ``keep`` keyframes out of
    sight ties that keyframe to its previous sighting (iSAM2's window then keeps the poses in
    between); one in view all along closes nothing. loops.oldest_referenced turns the pairs
    into the window's hold."""
    from types import SimpleNamespace

    from odofuse.estimators.graph.isam2_slam import resighting_loops
    from odofuse.estimators.graph.loops import oldest_referenced

    rows = {j: [SimpleNamespace(landmark=7)] for j in (*range(3, 10), 150, 151)}
    for j in range(0, 300):
        rows.setdefault(j, []).append(SimpleNamespace(landmark=8))  # always in view
    pairs = resighting_loops(rows, keep=100)
    assert pairs == [(150, 9)]  # to the sighting before the gap
    hold = oldest_referenced(pairs + [(40, 20), (200, 120)])
    assert [hold(i) for i in (0, 39, 40, 149, 150, 199, 200)] == [9, 9, 9, 9, 120, 120, None]
