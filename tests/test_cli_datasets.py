"""Every planar file of gtsam's Data folder through the front door: ``odofuse run`` (issue 26).

Each file runs as a user runs it: a subprocess ``python -m odofuse run CONFIG -o OUT`` with the
documented minimal config of its format (``gtsam_reference.minimal_config``, at most five
lines; docs/formats.md), for both batch and incremental graph estimators. The run must exit 0
with the expected ``status``, and its graph error (``metrics.json`` ``extra.final_error``) must
be GTSAM's best (``gtsam_reference.best``: plain GTSAM, the converged LM optimum from the best
start; Victoria Park: iSAM2 incremental + LM) to 1e-6 relative, its poses within 0.01 m RMS of
that solution, scored again by GTSAM's own ``graph.error`` at the written ``trajectory.csv`` /
``landmarks.csv``. A second solver (g2o, ``g2opy``) confirms the pose graphs' optimum.
Files taking more than ~10 s are in the ``slow`` tier (and in ``benchmarks/bench_datasets.py``).
``Plaza1_TD.txt`` and ``Plaza2_TD.txt`` read the same log as their ``_DR.txt`` partner: that
partner's test checks it through the run's loader and runs the CLI once (:data:`SAME_LOG`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import gtsam_reference as ref  # noqa: E402

DATA = os.path.dirname(gtsam.findExampleDataFile("w100.graph"))
ESTIMATORS = ("smoother", "isam2")
#: Above ~10 s for one of the two estimators on the shared 2-core machine.
SLOW = {
    "w10000.graph",
    "w20000.txt",
    "victoria_park.txt",
    "victoriaPark_reduced_1k.g2o",
    "cityTrees_reduced_1k.g2o",
    "goats_15.pyfg",
    "Plaza1_DR.txt",
    "Plaza2_DR.txt",
    "Plaza1_.mat",
    "Plaza2_.mat",
}
#: The longest runs, s measured alone (2026-12-06, ff0b3df; in the suite of 2026-12-03 239 and
#: 85 s, before iSAM2's partial relinearisation check): collected first (tests/conftest.py).
LONGEST = {("w20000.txt", "isam2"): 150.0, ("w10000.graph", "isam2"): 47.0}
#: The runs that judge themselves ``degraded`` (every other one says ``ok``), by (file,
#: estimator) or file, and the check that says so; no ground truth is involved in either.
DEGRADED = {
    # range residuals 2.5-2.7x the file's 0.75 m sigma, with either map (docs/graph.md, GOATS)
    "goats_15.pyfg": "residuals",
    "goats_16.pyfg": "residuals",
    # the minimal config's default range sigma is too optimistic for Plaza's ranges; under the
    # default gate loss (issue 25) Plaza1's shows as 19 % of the ranges beyond the gate
    "Plaza1_.mat": "outliers",
    "Plaza2_.mat": "residuals",
    # the smoother's own check of odometry residual windows (graph.health; iSAM2 does not run
    # it): 56 windows of 2747-3456 s above their chi-square bound at GTSAM's optimum
    ("victoria_park.txt", "smoother"): "residual_windows",
    # iSAM2 SLAM's predicted landmark sightings (graph.isam2_slam): NIS windows above their
    # band over 878-2865 s (worst 7.93 of 2), the smoother's finding seen from the other side
    ("victoria_park.txt", "isam2"): "nis",
    # Plaza2's ranges at the minimal config's sigma (as its .mat says, "residuals"): mean NIS
    # of the predicted ranges 2.1 of 1 over the whole run (Plaza1's: 0.73); the smoother's
    # residuals at its optimum, fitted by the free beacons, stay in band
    ("Plaza2_DR.txt", "isam2"): "nis",
}
#: Names that read the same log as another name: naming either of ``<prefix>_DR.txt`` and
#: ``<prefix>_TD.txt`` reads both siblings (``odofuse.io.plaza``), so their runs are one
#: computation (24.5 + 10.8 s for Plaza1's pair in the suite, 9.4 + 6.3 s for Plaza2's).
#: The partner's test runs its CLI once and checks that the two configs load equal logs
#: through the run's own path (``load_log_for`` and ``apply_log_defaults``): every stream,
#: the map, ground truth, repairs, start pose and findings (each stream's ``source``, the
#: file it was read from, included); the log's ``source`` is the path named.
#: (One test, not two sharing a cache: the xdist workers would each run it.)
SAME_LOG = {"Plaza1_TD.txt": "Plaza1_DR.txt", "Plaza2_TD.txt": "Plaza2_DR.txt"}
_RUNS: dict = {}


def run_cli(name: str, estimator: str, tmp_root: Path):
    """``odofuse run`` of ``name``'s minimal config (once per module): (process, out, config)."""
    key = (name, estimator)
    if key not in _RUNS:
        folder = tmp_root / f"{name}.{estimator}"
        folder.mkdir(parents=True)
        config = ref.minimal_config(os.path.join(DATA, name), estimator)
        (folder / "run.yaml").write_text(config)
        env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
        cmd = [sys.executable, "-m", "odofuse", "run", "run.yaml", "-o", "out"]
        proc = subprocess.run(cmd, cwd=folder, env=env, capture_output=True, text=True)
        _RUNS[key] = (proc, folder / "out", config)
    return _RUNS[key]


def _largest_mahalanobis(out: Path, keys, ours, best) -> float:
    """The largest distance of a pose of ours from GTSAM's, in the reported position sigmas
    (``trajectory.csv``'s covariance): the same optimum within a thousandth of a sigma.

    An absolute tolerance (it was 1 cm) turned on rounding where the optimum is flat: on an
    AMD EPYC, iSAM2's w20000 ended at GTSAM's cost to 2.6e-10 with poses 3.1 cm RMS away
    (aligned, 3 mm and a 1.3e-4 rad turn of the whole map), 1.4e-5 of their sigmas; every
    other file and back end agreed to 3.3e-6 sigma or closer."""
    import gtsam

    traj = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    at = {int(round(t)): n for n, t in enumerate(traj[:, 0])}
    c = traj[[at[gtsam.Symbol(k).index()] for k in keys]]
    P = np.stack([c[:, [4, 5]], c[:, [5, 7]]], axis=1)  # var_x, cov_xy / cov_xy, var_y
    d = ref.poses_of(ours, keys)[:, :2] - ref.poses_of(best, keys)[:, :2]
    return float(np.sqrt(np.einsum("ni,nij,nj->n", d, np.linalg.inv(P), d)).max())


@pytest.fixture(scope="module")
def tmp_root(tmp_path_factory):
    return tmp_path_factory.mktemp("cli_datasets")


def _cases():
    for name in ref.FILES:
        if name in SAME_LOG:
            continue
        for estimator in ESTIMATORS:
            seconds = LONGEST.get((name, estimator), 0.0)
            marks = [pytest.mark.slow(seconds=seconds)] if name in SLOW else []
            yield pytest.param(name, estimator, marks=marks, id=f"{name}-{estimator}")


@pytest.mark.parametrize(("name", "estimator"), list(_cases()))
def test_odofuse_run_ends_at_gtsams_best(name, estimator, tmp_root):
    proc, out, config = run_cli(name, estimator, tmp_root)
    assert len(config.splitlines()) <= 5, config
    for alias in [a for a, partner in SAME_LOG.items() if partner == name]:
        other = ref.minimal_config(os.path.join(DATA, alias), estimator)
        assert len(other.splitlines()) <= 5, other
        _assert_same_log(other, config, tmp_root / f"same.{alias}.{estimator}")
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    warnings = metrics["warnings"]
    check = DEGRADED.get((name, estimator), DEGRADED.get(name))
    if check:
        assert metrics["status"] == "degraded"
        assert any(w.startswith(f"[{check}]") for w in warnings), warnings
    else:
        assert metrics["status"] == "ok", warnings
    assert not any(w.startswith("[solver]") for w in warnings), warnings  # LM converged
    final = metrics["extra"]["final_error"]
    assert np.isfinite(final)
    kind, reader = ref.FILES[name]
    if reader is None:  # Plaza: odofuse's motion model is the odometry noise, no plain GTSAM
        return
    _, _, keys = ref.load_file(name)
    ours = ref.run_values(out, keys)
    graph, keys, best, _ = ref.best(name, ours if kind == "range_slam" else None)
    e_best = graph.error(best)
    assert final == pytest.approx(e_best, rel=1e-6)
    assert graph.error(ours) == pytest.approx(e_best, rel=1e-6)  # the written solution
    assert _largest_mahalanobis(out, keys, ours, best) < 1e-3
    if name == "victoria_park.txt":  # the figure, whichever graph estimator (iSAM2
        # SLAM used to stop at 3,026.2, its keyframe window having marginalised 6,850 poses)
        assert final == pytest.approx(2339.2195, rel=1e-6)
        assert len((out / "landmarks.csv").read_text().splitlines()) == 1 + 151  # every tree
    if kind == "posegraph" and estimator == "smoother":  # a second solver (same run: no rerun)
        _g2o_confirms_the_optimum(graph, ours)


def _assert_same_log(config: str, other: str, folder: Path) -> None:
    """The two minimal configs load equal logs through ``odofuse run``'s path
    (:data:`SAME_LOG`): the configs differ only in the file named, and every field of the
    loaded :class:`~odofuse.io.log.SensorLog` but its ``source`` is equal."""
    import dataclasses

    from odofuse.config import load_config
    from odofuse.io.loader import load_log_for
    from odofuse.log_defaults import apply_log_defaults

    assert other.partition("\n")[2] == config.partition("\n")[2], (config, other)
    logs = []
    folder.mkdir(parents=True)
    for n, text in enumerate((config, other)):
        (folder / f"run{n}.yaml").write_text(text)
        cfg = load_config(folder / f"run{n}.yaml")
        logs.append(apply_log_defaults(cfg, load_log_for(cfg))[1])
    a, b = logs
    assert a.source != b.source
    for f in dataclasses.fields(a):
        if f.name == "source":
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "streams":
            assert x.keys() == y.keys()
            for k in x:
                _assert_same_stream(x[k], y[k])
        elif f.name == "landmarks":
            assert x.keys() == y.keys()
            for k in x:
                np.testing.assert_array_equal(x[k], y[k])
        elif f.name == "groundtruth":
            _assert_same_stream(x, y)
        elif f.name == "initial_pose":
            assert (x is None) == (y is None)
            if x is not None:
                np.testing.assert_array_equal(x, y)
        else:
            assert x == y, f.name


def _assert_same_stream(x, y) -> None:
    """Equal streams, read from the same file (``source``)."""
    assert (x is None) == (y is None)
    if x is not None:
        assert (x.name, x.source, tuple(x.columns)) == (y.name, y.source, tuple(y.columns))
        np.testing.assert_array_equal(x.t, y.t)
        np.testing.assert_array_equal(x.values, y.values)


def _g2o_confirms_the_optimum(graph, ours) -> None:
    """g2o's LM from odofuse's optimum finds no lower chi-square (1e-6 relative), and g2o's
    chi-square there is twice GTSAM's error up to the charts' difference (g2o's residual is
    the relative pose's ``(x, y, theta)``, GTSAM's its ``Logmap``: equal to second order)."""
    at, after = ref.g2o_chi2(graph, ours)
    assert after == pytest.approx(at, rel=1e-6) and after <= at * (1 + 1e-12)
    assert at == pytest.approx(2.0 * graph.error(ours), rel=1e-3)


@pytest.mark.parametrize(
    ("name", "why"),
    [
        ("T1_city10000_04.txt", "multi-hypothesis"),  # discrete alternatives, no noise
        ("Klaus3.g2o", "3-D"),  # VERTEX_SE3:QUAT: not planar despite its place in the issue
    ],
)
def test_a_file_that_cannot_be_read_gets_one_line_saying_why(name, why, tmp_path):
    path = os.path.join(DATA, name)
    (tmp_path / "run.yaml").write_text(
        f"log: {path}\nrobot: {{drive: increments}}\nestimator: smoother\n"
        "sensors: {loop_closures: {}}\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "odofuse", "run", "run.yaml", "-o", "out"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and why in lines[0] and name in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr
