"""Every planar file of the gtsam wheel through ``odofuse run``, beside GTSAM itself (issue 26).

Run from any directory: ``python path/to/benchmarks/bench_datasets.py [table|goats|all]
[FILE ...]`` (default ``all``; ``table FILE ...`` runs only those files). Prints figures and
wall times; asserts nothing (tests/test_cli_datasets.py asserts).

* ``table``: for each file of ``gtsam_reference.FILES`` and each graph estimator (``smoother``,
  ``isam2``), the documented minimal config (``gtsam_reference.minimal_config``) run as a user
  runs it (``python -m odofuse run CONFIG -o OUT``, a subprocess), and per run: odofuse's
  graph error (``metrics.json`` ``extra.final_error``), GTSAM's best
  (``gtsam_reference.best``: the converged LM optimum from the best start; Victoria Park and
  the other range-bearing SLAM files: GTSAM's iSAM2 incremental solve + LM; GOATS: LM from
  odofuse's solution, GTSAM having no range-only initialiser), the pose RMS between the two,
  g2o's chi-square at odofuse's solution and after g2o's own LM from it (pose graphs), the
  status, and the time ratio odofuse / plain GTSAM on the same graph with the same solver:
  odofuse's estimator wall time (``runtime_s``: start, solve, marginal covariances, checks)
  and, for the smoother, its solve alone (``extra.solve_s``), over GTSAM's time for the same
  solve: LM from the same start (smoother on a pose graph; chordal or the reader's values),
  or iSAM2 incremental + LM (isam2, and the SLAM smoother, whose start is an incremental
  pass). The Plaza files have no plain-GTSAM reference (their odometry noise is odofuse's
  motion model): status and graph error only.
* ``goats``: both GOATS files: range-only SLAM and range-only localisation against the known
  beacons, started from the SLAM map aligned onto them (the file's start pose is in another
  frame). Figures without ground truth: range residuals, graph error, outlier counts, aligned
  beacon mismatch.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]  # gtsam_reference and odofuse from any cwd

import gtsam_reference as ref  # noqa: E402
import numpy as np  # noqa: E402

ESTIMATORS = ("smoother", "isam2")


def _data(name: str) -> str:
    import gtsam

    return gtsam.findExampleDataFile(name)


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def cli_run(name: str, estimator: str, folder: Path):
    """``odofuse run`` of the minimal config in ``folder``: (metrics or None, stderr, wall s)."""
    config = ref.minimal_config(_data(name), estimator)
    (folder / "run.yaml").write_text(config)
    env = {**os.environ, "PYTHONPATH": str(HERE.parent), "MPLBACKEND": "Agg"}
    cmd = [sys.executable, "-m", "odofuse", "run", "run.yaml", "-o", "out"]
    proc, wall = _timed(
        lambda: subprocess.run(cmd, cwd=folder, env=env, capture_output=True, text=True)
    )
    if proc.returncode:
        return None, proc.stderr.strip(), wall
    return json.loads((folder / "out" / "metrics.json").read_text()), "", wall


def gtsam_times(name: str, graph, keys):
    """Plain GTSAM's solves of a file: ``{"lm": (values, s), "isam2": (values, s)}``.

    ``lm``: the best start of a pose graph (:func:`gtsam_reference.best`) + converged LM;
    ``isam2``: :func:`gtsam_reference.isam2_incremental` + converged LM (every kind but
    range-only SLAM). Times include the start, not the file reading.
    """
    _, v, _ = ref.load_file(name)
    kind = ref.FILES[name][0]
    out = {}
    if kind == "posegraph":

        def lm():
            chordal = ref.chordal_start(graph, v, keys)
            start = chordal if graph.error(chordal) < graph.error(v) else v
            return ref.converged_optimum(graph, start)[0]

        out["lm"] = _timed(lm)
    if kind in ("posegraph", "slam"):
        try:  # plain iSAM2 (Cholesky) refuses w20000: an indeterminate system at pose 1190
            out["isam2"] = _timed(
                lambda: ref.converged_optimum(graph, ref.isam2_incremental(graph, keys))[0]
            )
        except RuntimeError as exc:
            print(f"   plain GTSAM iSAM2 failed: {str(exc).strip().splitlines()[0]}")
    return out


def table(names) -> None:
    print("\n== every planar file through `odofuse run` (minimal config) vs plain GTSAM ==")
    print(
        f"{'file':30s} {'estimator':9s} {'odofuse error':>16s} {'GTSAM best':>16s} "
        f"{'rel':>9s} {'rms m':>8s} {'g2o chi2 at -> after LM':>27s} {'status':8s} "
        f"{'odofuse s':>9s} {'solve s':>8s} {'GTSAM s':>8s} {'ratio':>6s} {'solve':>6s}"
    )
    for name in names:
        kind, reader = ref.FILES[name]
        print(f"-- {name}: minimal config\n" + ref.minimal_config(_data(name), "<estimator>"))
        graph = keys = times = None
        if reader is not None and kind != "range_slam":
            graph, _, keys = ref.load_file(name)
            times = gtsam_times(name, graph, keys)
        for est in ESTIMATORS:
            with tempfile.TemporaryDirectory() as tmp:
                m, err, wall = cli_run(name, est, Path(tmp))
                if m is None:
                    print(f"{name:30s} {est:9s} FAILED: {err}")
                    continue
                e = float(m["extra"]["final_error"])
                cols = {"best": "-", "rel": "-", "rms": "-", "g2o": "-", "gt": "-", "r": "-"}
                t_g = None
                if reader is not None:
                    _, _, k = ref.load_file(name)
                    ours = ref.run_values(Path(tmp) / "out", k)
                    start = ours if kind == "range_slam" else None
                    g, k, best, _ = ref.best(name, start)
                    e_best = g.error(best)
                    rms = ref.position_rms(ref.poses_of(ours, k), ref.poses_of(best, k))
                    cols.update(best=f"{e_best:.6f}", rel=f"{e / e_best - 1:+.1e}")
                    cols["rms"] = f"{rms:.1e}"
                    if kind == "posegraph":
                        at, after = ref.g2o_chi2(g, ours)
                        cols["g2o"] = f"{at:.6f} -> {after:.6f}"
                    which = "lm" if est == "smoother" and kind == "posegraph" else "isam2"
                    if times and which in times:  # not GOATS (GTSAM's LM from odofuse's
                        # solution is no run), nor a plain GTSAM solve that failed
                        t_g = times[which][1]
                        cols["gt"] = f"{t_g:.3g}"
                        cols["r"] = f"{m['runtime_s'] / t_g:.2f}" if t_g > 0 else "-"
                solve = m["extra"].get("solve_s")
                solve_txt = f"{solve:.2f}" if solve is not None else "-"
                solve_ratio = "-"
                if solve is not None and t_g:  # a timer that read 0 gives no ratio
                    solve_ratio = f"{solve / t_g:.2f}"
                print(
                    f"{name:30s} {est:9s} {e:16.6f} {cols['best']:>16s} {cols['rel']:>9s} "
                    f"{cols['rms']:>8s} {cols['g2o']:>27s} {m['status']:8s} "
                    f"{m['runtime_s']:9.2f} {solve_txt:>8s} {cols['gt']:>8s} {cols['r']:>6s} "
                    f"{solve_ratio:>6s}  (wall {wall:.1f} s)",
                    flush=True,
                )


def goats() -> None:
    from odofuse.estimators import run_estimator
    from odofuse.io.loader import load_log

    print("\n== GOATS (pyfg): range-only SLAM and localisation, no ground truth ==")
    for name in ("goats_15.pyfg", "goats_16.pyfg"):
        path = _data(name)
        log = load_log(path)
        ids = sorted(log.landmarks)
        B = np.array([log.landmarks[i] for i in ids])
        slam = None
        for est in ESTIMATORS:
            cfg = ref.dataset_config(log, path, est, slam=True)
            res, dt = _timed(lambda cfg=cfg, est=est, log=log: run_estimator(est, log, cfg))
            r = ref.range_residuals(res, log)
            T, start = ref.aligned_start(res, log)
            A = np.array([res.extra["landmarks"][i] for i in ids])
            mis = np.linalg.norm(ref.apply_se2(T, A) - B, axis=1)
            print(
                f"{name} SLAM {est:8s} {dt:6.2f} s  range residual median {np.median(abs(r)):.2f} "
                f"rms {np.sqrt(np.mean(r**2)):.2f} m  graph error "
                f"{res.extra.get('final_error', float('nan')):.1f}  outliers "
                f"{res.extra.get('outliers')}  beacons vs map after alignment {mis.round(1)} m"
            )
            slam = slam or res
        T, start = ref.aligned_start(slam, log)
        cfg = ref.dataset_config(log, path)
        cfg = dataclasses.replace(cfg, initial={"pose": list(start), "sigma": [10.0, 10.0, 0.1]})
        loc, dt = _timed(lambda cfg=cfg, log=log: run_estimator("smoother", log, cfg))
        r = ref.range_residuals(loc, log)
        print(
            f"{name} localisation (known beacons, start {start.round(1)}) {dt:6.2f} s  range "
            f"residual median {np.median(abs(r)):.2f} rms {np.sqrt(np.mean(r**2)):.2f} m  "
            f"graph error {loc.extra['final_error']:.1f}  outliers {loc.extra.get('outliers')}"
        )


def main(argv) -> None:
    what = argv[1] if len(argv) > 1 else "all"
    if what in ("table", "all"):
        names = argv[2:] if what == "table" and len(argv) > 2 else list(ref.FILES)
        table(names)
    if what in ("goats", "all"):
        goats()


if __name__ == "__main__":
    main(sys.argv)
