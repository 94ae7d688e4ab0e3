"""Every file of gtsam's Data folder is loaded or refused by name; parsing checked against gtsam.

Reference readers: ``gtsam.load2D`` (TORO/iSAM line types, NoiseFormatAUTO) and ``gtsam.readG2o``
(g2o line types, information matrices), as in gtsam/slam/dataset.cpp.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from odofuse.errors import InputError, OdofuseError
from odofuse.io.loader import load_log
from odofuse.io.posegraph import COV_COLUMNS, adjoint, invert

gtsam = pytest.importorskip("gtsam")

DATA = os.path.dirname(gtsam.findExampleDataFile("w100.graph"))

#: The planar logs of the wheel: each must load.
PLANAR = {
    "victoria_park.txt",
    "victoriaPark_reduced_1k.g2o",
    "cityTrees_reduced_1k.g2o",
    "example.graph",
    "w100.graph",
    "w10000.graph",
    "w100_30.g2o",
    "w20000.txt",
    "noisyToyGraph.txt",
    "optimizedNoisyToyGraph.txt",
    "orientationsNoisyToyGraph.txt",
    "pose2example.txt",
    "goats_15.pyfg",
    "goats_16.pyfg",
    "Plaza1_DR.txt",
    "Plaza1_TD.txt",
    "Plaza2_DR.txt",
    "Plaza2_TD.txt",
    "Plaza1_.mat",
    "Plaza2_.mat",
}
#: Planar, but refused by name (the reason must appear in the message).
REFUSED_PLANAR = {"T1_city10000_04.txt": "multi-hypothesis"}


@pytest.fixture(scope="module")
def walk():
    """``{name: SensorLog or InputError}`` for every entry of the Data folder (parsed once)."""
    out = {}
    for name in sorted(os.listdir(DATA)):
        try:
            out[name] = load_log(os.path.join(DATA, name))
        except OdofuseError as e:
            out[name] = e
    return out


def test_walk_loads_planar_and_refuses_the_rest_by_name(walk):
    assert PLANAR | set(REFUSED_PLANAR) <= set(walk)
    for name, got in walk.items():
        if name in PLANAR:
            assert not isinstance(got, Exception), f"{name}: {got}"
            assert got.has("odometry") or got.has("ranges"), name
            continue
        assert isinstance(got, InputError), f"{name} loaded: {sorted(got.streams)}"
        msg = str(got)
        assert "\n" not in msg and name in msg and len(msg) < 300, msg
        if name in REFUSED_PLANAR:
            assert REFUSED_PLANAR[name] in msg and got.row == 1
        if name.startswith(("pose3", "sphere", "Klaus3", "toyExample", "edge_se3")):
            assert "3-D" in msg


def test_victoria_park_shared_id_space(walk):
    log = walk["victoria_park.txt"]
    o, lm = log.streams["odometry"], log.streams["landmarks"]
    assert len(o) + 1 == 6969 and len(lm) == 3640
    assert len(np.unique(lm["id"])) == 151
    assert "loop_closures" not in log.streams  # the steps 4 -> 6, ... are the chain
    assert 6.0 in o.t and 5.0 not in o.t and 5.0 in lm["id"]
    assert log.initial_pose is None  # no vertices in the file: the config's initial pose


def _between(graph):
    """``(i, j, x, y, theta, cov(6))`` rows of the BetweenFactorPose2 of a gtsam graph."""
    rows = []
    for k in range(graph.size()):
        f = graph.at(k)
        if isinstance(f, gtsam.BetweenFactorPose2):
            i, j = f.keys()
            m = f.measured()
            c = f.noiseModel().covariance()
            rows.append([i, j, m.x(), m.y(), m.theta(), *c[np.triu_indices(3)]])
    return np.array(rows)


def _split_like_odofuse(rows):
    ids = np.unique(rows[:, :2])
    nxt = dict(zip(ids[:-1], ids[1:], strict=True))
    lo, hi = rows[:, :2].min(axis=1), rows[:, :2].max(axis=1)
    chain = np.array([nxt.get(a) == b for a, b in zip(lo, hi, strict=True)])
    return rows[chain], rows[~chain]


def _check_against(log, rows):
    chain, loops = _split_like_odofuse(rows)
    o = log.streams["odometry"]
    assert len(o) == len(chain)
    forward = chain[:, 0] < chain[:, 1]
    idx = np.searchsorted(o.t, chain[forward, 1])
    np.testing.assert_allclose(o.values[idx][:, 2:4], chain[forward, 2:4], atol=1e-12)
    np.testing.assert_allclose(o["dtheta"][idx], chain[forward, 4], atol=1e-12)
    cov = np.column_stack([o[c] for c in COV_COLUMNS])[idx]
    np.testing.assert_allclose(cov, chain[forward, 5:], rtol=1e-9, atol=1e-15)
    if len(loops) == 0:
        assert "loop_closures" not in log.streams
        return
    lc = log.streams["loop_closures"]
    order = np.argsort(loops[:, :2].max(axis=1), kind="stable")  # odofuse: stable by t
    np.testing.assert_allclose(lc.values[:, :5], loops[order, :5], atol=1e-12)
    np.testing.assert_allclose(lc.values[:, 5:], loops[order, 5:], rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize(
    "name", ["w10000.graph", "w100.graph", "w20000.txt", "victoria_park.txt", "example.graph"]
)
def test_toro_and_isam_edges_match_load2d(walk, name):
    graph, _ = gtsam.load2D(os.path.join(DATA, name))
    rows = _between(graph)
    _check_against(walk[name], rows)
    if name == "w10000.graph":
        lc = walk[name].streams["loop_closures"]
        assert len(lc) == 54312 and len(rows) == 64311
        # first and last loop closure of the file, as stored (p_from^-1 p_to)
        _, loops = _split_like_odofuse(rows)
        for ref in (loops[0], loops[-1]):
            hit = np.flatnonzero((lc["t_from"] == ref[0]) & (lc["t_to"] == ref[1]))
            assert any(np.allclose(lc.values[h, 2:5], ref[2:5]) for h in hit)


@pytest.mark.parametrize(
    "name",
    [
        "pose2example.txt",
        "noisyToyGraph.txt",
        "victoriaPark_reduced_1k.g2o",
        "cityTrees_reduced_1k.g2o",
    ],
)
def test_g2o_edges_match_readg2o(walk, name):
    graph, _ = gtsam.readG2o(os.path.join(DATA, name), False)
    _check_against(walk[name], _between(graph))


@pytest.mark.parametrize("name", ["victoria_park.txt", "example.graph"])
def test_sightings_match_load2d_bearing_range(walk, name):
    graph, _ = gtsam.load2D(os.path.join(DATA, name))
    ref = []
    for k in range(graph.size()):
        f = graph.at(k)
        if isinstance(f, gtsam.BearingRangeFactor2D):
            i, lk = f.keys()
            br = f.measured()
            s = f.noiseModel().sigmas()
            ref.append([i, gtsam.Symbol(lk).index(), br.range(), br.bearing().theta(), s[1], s[0]])
    ref = np.array(ref)
    ref = ref[np.lexsort((ref[:, 1], ref[:, 0]))]
    lm = walk[name].streams["landmarks"]
    got = np.column_stack([lm.t, lm.values])
    np.testing.assert_allclose(got, ref, atol=1e-9)


@pytest.mark.parametrize(
    ("name", "beacons", "ranges", "steps"),
    [
        ("goats_15.pyfg", 3, 786, 472),
        ("goats_16.pyfg", 4, 572, 200),
    ],
)
def test_goats_beacons_become_the_map(walk, name, beacons, ranges, steps):
    log = walk[name]
    assert len(log.landmarks) == beacons and len(log.streams["odometry"]) == steps
    r = log.streams["ranges"]
    assert len(r) == ranges and set(np.unique(r["id"]).astype(int)) == set(log.landmarks)
    np.testing.assert_allclose(r["sigma"], 0.75)  # variance 0.5625 in the file
    with open(os.path.join(DATA, name)) as fh:
        first = fh.readline().split()  # VERTEX_XY L0 x y
    np.testing.assert_allclose(log.landmarks[int(first[1][1:])], [float(first[2]), float(first[3])])
    assert log.groundtruth is None  # the vertices are dead reckoning, not truth
    cov = np.column_stack([log.streams["odometry"][c] for c in COV_COLUMNS])
    np.testing.assert_allclose(cov[0], [4e-4, 0, 0, 4e-4, 0, 4e-6], atol=1e-15)


def test_plaza_text_equals_builtin(walk):
    text, mat = walk["Plaza1_DR.txt"], load_log("builtin:plaza1")
    for s in ("odometry", "ranges"):
        np.testing.assert_allclose(text.streams[s].t, mat.streams[s].t, rtol=1e-12)
        np.testing.assert_allclose(
            text.streams[s].values, mat.streams[s].values, rtol=1e-9, atol=1e-12
        )
    assert text.repairs == mat.repairs == {"ranges.reordered": 425, "ranges.duplicates_dropped": 2}
    assert text.landmarks == {} and text.groundtruth is None  # not shipped as text


def test_plaza_text_streams_name_the_file_they_were_read_from(walk):
    """A log named by its ``_TD.txt`` still says its odometry came from ``_DR.txt`` (the
    ``file`` of a later message about that stream); the log's source is the path named."""
    for name in ("Plaza1_DR.txt", "Plaza1_TD.txt"):
        log = walk[name]
        assert os.path.basename(log.source) == name
        assert os.path.basename(log.streams["odometry"].source) == "Plaza1_DR.txt"
        assert os.path.basename(log.streams["ranges"].source) == "Plaza1_TD.txt"


def test_inverted_edge_covariance_is_the_adjoint():
    d = (0.7, -0.3, 2.5)
    t = gtsam.Pose2(*d)
    np.testing.assert_allclose(adjoint(d), t.AdjointMap(), atol=1e-15)
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T
    inv, cov_inv = invert(d, cov)
    ti = gtsam.Pose2(*inv)
    assert ti.equals(t.inverse(), 1e-12)
    # J = d Log(ti^-1 (t Exp(xi))^-1) / d xi by central differences; cov_inv = J cov J^T
    h, jac = 1e-6, np.zeros((3, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        plus = gtsam.Pose2.Logmap(ti.between(t.compose(gtsam.Pose2.Expmap(e)).inverse()))
        minus = gtsam.Pose2.Logmap(ti.between(t.compose(gtsam.Pose2.Expmap(-e)).inverse()))
        jac[:, k] = (plus - minus) / (2 * h)
    np.testing.assert_allclose(cov_inv, jac @ cov @ jac.T, atol=1e-8)


@pytest.mark.parametrize(
    ("suffix", "text", "row", "match"),
    [
        (".g2o", "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK2 0 5 1.0\n", 2, "at least 7"),
        (".g2o", "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2_PRIOR 0 0 0 0\n", 2, "pose priors"),
        (".g2o", "EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n", 1, "not positive definite"),
        (".g2o", "EDGE_SE2 0 1 1 0 0 1 0 0\n", 1, "0 or 6 noise entries"),
        (".graph", "EDGE2 0 1 1 0 0 1 0.5 1 1 0 0\n", 1, "load2D"),
        (".graph", "EDGE2 0 1 1 0 0 1 0 1 1 0 0\nBR 3 7 0.1 5 0.1 0.1\n", 2, "pose 3"),
        (".pyfg", "VERTEX_XY L0 1 2\nEDGE_SE2 0 A0 B1 1 0 0 1 0 0 1 0 1\n", 2, "second robot"),
        (".pyfg", "EDGE_RANGE 0 A0 A1 3.0 0.1\n", 1, "two poses"),
        (".pyfg", "VERTEX_SE2:PRIOR 0 A0 0 0 0 1 0 0 1 0 1\n", 1, "priors"),
        (
            ".pyfg",
            "EDGE_SE2 0 A0 A1 1 0 0 1 0 0 1 0 1\nEDGE_RANGE 0 A1 L4 3.0 0.1\nVERTEX_XY L0 1 2\n",
            2,
            "L4 has no VERTEX_XY",
        ),
        (".txt", "EDGE2 0 1 2 0 1 1.0 0.0 0.0\n", 1, "multi-hypothesis"),
    ],
)
def test_bad_lines_name_file_row_and_type(tmp_path, suffix, text, row, match):
    p = tmp_path / f"g{suffix}"
    p.write_text(text)
    with pytest.raises(InputError, match=match) as info:
        load_log(p)
    assert info.value.file == str(p) and info.value.row == row


def test_equiv_and_fix_are_counted(tmp_path):
    p = tmp_path / "g.graph"
    p.write_text("EDGE2 0 1 1 0 0 1 0 1 1 0 0\nEQUIV 0 1\nFIX 0\n")
    assert load_log(p).repairs == {"posegraph.equiv_ignored": 1, "posegraph.fix_ignored": 1}


# -- CSV repair policies ----------------------------------------------------------------------

ODO = "t,ds,dtheta\n0.1,0.1,0\n0.3,0.1,0\n0.2,0.1,0\n0.3,0.1,0\n0.4,0.1,0\n0.4,0.2,0\n0.5,0.1,0\n"


def _folder(tmp_path, text=ODO):
    d = tmp_path / "log"
    d.mkdir(exist_ok=True)
    (d / "odometry.csv").write_text(text)
    return d


def test_without_policy_the_clear_error_stays(tmp_path):
    with pytest.raises(InputError, match="backwards") as info:
        load_log(_folder(tmp_path))
    assert info.value.row == 4 and info.value.column == "t"
    with pytest.raises(InputError, match="duplicate time stamp") as info:
        load_log(_folder(tmp_path), repair={"sort": True})
    assert info.value.row == 7 and info.value.column == "ds"


@pytest.mark.parametrize(
    ("duplicates", "t", "repairs"),
    [
        ("drop_conflicting", [0.1, 0.2, 0.3, 0.5], {"duplicate_rows": 1, "conflicting_dropped": 2}),
        ("keep_first", [0.1, 0.2, 0.3, 0.4, 0.5], {"duplicate_rows": 1, "conflicting_dropped": 1}),
    ],
)
def test_sort_and_duplicate_policies_count_every_row(tmp_path, duplicates, t, repairs):
    log = load_log(_folder(tmp_path), repair={"sort": True, "duplicates": duplicates})
    o = log.streams["odometry"]
    np.testing.assert_allclose(o.t, t)
    if duplicates == "keep_first":
        assert o["ds"][3] == 0.1  # the first 0.4 row (line 6) is kept
    assert log.repairs == {"odometry.reordered": 2} | {
        f"odometry.{k}": v for k, v in repairs.items()
    }


def test_duplicates_error_refuses_even_exact_copies(tmp_path):
    d = _folder(tmp_path, "t,ds,dtheta\n0.1,0.1,0\n0.1,0.1,0\n")
    assert load_log(d).repairs == {"odometry.duplicate_rows": 1}
    with pytest.raises(InputError, match="same values as line 2") as info:
        load_log(d, repair={"duplicates": "error"})
    assert info.value.row == 3


def test_repair_policy_reaches_metrics_and_config_errors_name_the_key(tmp_path, capsys):
    from odofuse.cli import main

    _folder(tmp_path)
    base = (
        "robot: {drive: increments}\nmotion: {integrator: exact, k: [1.0e-4, 1.0e-4]}\n"
        "estimator: dead_reckoning\noutput: out\n"
    )
    cfg = tmp_path / "run.yaml"
    cfg.write_text("log: {path: log, repair: {sort: true, duplicates: drop_conflicting}}\n" + base)
    assert main(["run", str(cfg)]) == 0
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["repairs"] == {
        "odometry.reordered": 2,
        "odometry.duplicate_rows": 1,
        "odometry.conflicting_dropped": 2,
    }
    assert m["poses"] == 5
    for bad, key in (
        ("{sort: yes please}", "log.repair.sort"),
        ("{duplicates: newest}", "log.repair.duplicates"),
        ("{order: true}", "log.repair"),
    ):
        cfg.write_text(f"log: {{path: log, repair: {bad}}}\n" + base)
        assert main(["run", str(cfg)]) == 2
        err = capsys.readouterr().err
        assert key in err and "Traceback" not in err
    cfg.write_text("log: {path: builtin:plaza1, repair: {sort: true}}\n" + base)
    assert main(["run", str(cfg)]) == 2
    assert "CSV log folders only" in capsys.readouterr().err


def test_plaza_mat_file_equals_builtin(walk):
    mat, builtin = walk["Plaza1_.mat"], load_log("builtin:plaza1")
    assert set(mat.streams) == set(builtin.streams) == {"odometry", "ranges"}
    for s in mat.streams:
        np.testing.assert_array_equal(mat.streams[s].values, builtin.streams[s].values)
    np.testing.assert_array_equal(mat.initial_pose, builtin.initial_pose)
    assert mat.landmarks.keys() == builtin.landmarks.keys() and mat.groundtruth is not None
    assert mat.repairs == builtin.repairs and not mat.invented_times


def test_a_mat_file_that_is_not_plaza_is_refused_in_one_line(tmp_path):
    import scipy.io

    path = tmp_path / "other.mat"
    scipy.io.savemat(path, {"DR": np.zeros((3, 3))})
    with pytest.raises(InputError, match="must be a Plaza file.*missing TD") as exc:
        load_log(path)
    assert "\n" not in str(exc.value) and "other.mat" in str(exc.value)
    (tmp_path / "junk.mat").write_bytes(b"not a mat file at all")
    with pytest.raises(InputError, match="not a readable MATLAB"):
        load_log(tmp_path / "junk.mat")


def test_plausibility_judges_measured_times_only(walk, tmp_path):
    """goats_15.pyfg stamps every line 0, so pose k gets t = k s: invented, and its 32 m
    steps (row 193) are no speed. The same step with measured times is still refused."""
    from odofuse.config import RunConfig
    from odofuse.io.loader import load_log_for

    for name in ("goats_15.pyfg", "w100.graph", "victoria_park.txt"):
        log = walk[name]
        assert set(log.invented_times) == set(log.streams), name
    assert not walk["Plaza1_DR.txt"].invented_times  # the DR/TD files' own times
    path = os.path.join(DATA, "goats_15.pyfg")
    cfg = RunConfig(log=path, robot={"drive": "increments"}, source="<test>")
    log = load_log_for(cfg)
    assert np.max(np.abs(log.streams["odometry"]["ds"])) > 30.0  # > log.max_speed per "1 s"
    odo = log.streams["odometry"]
    folder = tmp_path / "measured"
    folder.mkdir()
    rows = "\n".join(
        f"{t:.1f},{float(ds)!r},{float(dth)!r}"
        for t, ds, dth in zip(odo.t, odo["ds"], odo["dtheta"], strict=True)
    )
    (folder / "odometry.csv").write_text("t,ds,dtheta\n" + rows + "\n")
    with pytest.raises(InputError, match="impossible for this robot"):
        load_log_for(RunConfig(log=str(folder), robot={"drive": "increments"}, source="<t>"))


def test_pose_graph_log_round_trips_through_csv_export(walk, tmp_path):
    from odofuse.io.csvlog import read_csv_log, write_csv_log

    log = walk["w100.graph"]
    write_csv_log(log, tmp_path / "w100")
    back = read_csv_log(tmp_path / "w100")
    for s in ("odometry", "loop_closures"):
        np.testing.assert_allclose(back.streams[s].values, log.streams[s].values, rtol=1e-15)
    assert not math.isnan(back.streams["odometry"]["cov_tt"][0])


#: Planar logs run in ``benchmarks/bench_datasets.py`` only (tens of seconds each).
RUN_IN_BENCHMARK = {"w10000.graph", "w20000.txt", "victoria_park.txt"}


@pytest.mark.parametrize("name", sorted(PLANAR - RUN_IN_BENCHMARK))
def test_walk_runs_every_small_planar_log(walk, name):
    """Loaded *and run*: the smoother with every stream the file has (loop closures, SLAM
    landmarks, ranges), or dead reckoning for the raw Plaza text (its range-only SLAM is in
    the benchmark)."""
    import dataclasses
    import sys
    from pathlib import Path

    from odofuse.estimators import run_estimator

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import gtsam_reference as ref

    log = walk[name]
    estimator = "dead_reckoning" if name.startswith("Plaza") else "smoother"
    if estimator == "dead_reckoning":  # options are validated per estimator
        cfg = ref.dataset_config(log, os.path.join(DATA, name))
        cfg = dataclasses.replace(cfg, estimator=estimator, sensors={}, options={})
    else:
        cfg = ref.dataset_config(log, os.path.join(DATA, name), estimator, covariances=False)
    res = run_estimator(estimator, log, cfg)
    assert np.all(np.isfinite(res.trajectory.poses)) and len(res.trajectory) > 3
    for stream, used in res.used.items():
        assert used + res.rejected.get(stream, 0) == len(log.streams[stream]), stream
    if estimator == "smoother":
        assert set(res.used) == set(log.streams)  # every stream of the file was used
