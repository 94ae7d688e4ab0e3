"""odofuse's graph estimators on the planar datasets of the gtsam wheel, beside GTSAM itself.

Run from any directory: ``python path/to/benchmarks/bench_datasets.py [posegraphs|victoria|
goats|walk|all] [FILE ...]`` (default ``all``; ``posegraphs FILE ...`` runs only those pose
graphs). Prints figures and wall times; asserts nothing.

* ``posegraphs``: every pose graph GTSAM reads (w100, w10000, w20000, w100_30, pose2example,
  the noisy toy graphs) and ``example.graph``: odofuse's smoother (with and without marginal
  covariances) against GTSAM's LM from its reader's initial values, both scored by
  ``graph.error`` of GTSAM's graph; pose RMS between the two optima; the iterations of both
  (GTSAM / odofuse: 100 is the cap, not a minimum); iSAM2 for w100/w10000. For the files in
  ``CONVERGED_REFERENCE`` (w20000, where GTSAM's LM from the reader's values is still
  falling after 1,000 iterations) the reference is ``gtsam_reference.converged_optimum``
  from ``chordal_start`` instead, its time the whole of that (iterations: LM + Gauss-Newton).
* ``victoria``: ``victoria_park.txt`` as shipped, range-bearing SLAM with unknown trees.
  GTSAM's best: its iSAM2 incremental solve polished by LM (``gtsam_reference``); odofuse's
  smoother (``slam_init: auto`` = incremental, then LM) and isam2.
* ``goats``: both GOATS files: range-only SLAM (smoother, isam2) and range-only localisation
  against the known beacons, started from the SLAM map aligned onto them (the file's start
  pose is in another frame). Figures without ground truth: range residuals, graph error,
  outlier counts, aligned beacon mismatch.
* ``walk``: every file of the Data folder: loaded and run (the smoother with every stream,
  the config of ``gtsam_reference.dataset_config``), or refused with its one-line reason.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]  # gtsam_reference and odofuse from any cwd

import gtsam_reference as ref  # noqa: E402
import numpy as np  # noqa: E402

POSE_GRAPHS = [
    ("w100.graph", "load2D"),
    ("w10000.graph", "load2D"),
    ("w20000.txt", "load2D"),
    ("w100_30.g2o", "load2D"),
    ("pose2example.txt", "readG2o"),
    ("noisyToyGraph.txt", "readG2o"),
    ("optimizedNoisyToyGraph.txt", "readG2o"),
    ("orientationsNoisyToyGraph.txt", "readG2o"),
    ("example.graph", "load2D"),
]
#: Pose graphs whose reference is GTSAM's LM run to a standstill from the chordal start.
CONVERGED_REFERENCE = {"w20000.txt"}


def _data(name: str) -> str:
    import gtsam

    return gtsam.findExampleDataFile(name)


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _odofuse(name, estimator="smoother", log=None, **options):
    from odofuse.estimators import run_estimator
    from odofuse.io.loader import load_log

    path = _data(name)
    log = log or load_log(path)
    cfg = ref.dataset_config(log, path, estimator, **options)
    res, dt = _timed(lambda: run_estimator(estimator, log, cfg))
    return log, res, dt


def posegraphs() -> None:
    print("\n== pose graphs: odofuse smoother vs GTSAM LM (error = GTSAM graph.error) ==")
    print(
        f"{'file':30s} {'gtsam err':>12s} {'odofuse err':>12s} {'rms m':>9s} "
        f"{'gtsam s':>8s} {'odofuse s':>9s} {'+cov s':>8s} {'ratio':>6s} {'iterations':>10s}"
    )
    names = sys.argv[2:] or [n for n, _ in POSE_GRAPHS]
    for name, reader in POSE_GRAPHS:
        if name not in names:
            continue
        g, v, keys = ref.load(_data(name), reader)
        if name in CONVERGED_REFERENCE:
            (best, it_lm, gn), t_g = _timed(
                lambda g=g, v=v, k=keys: ref.converged_optimum(g, ref.chordal_start(g, v, k))
            )
            it_g = f"{it_lm}+{gn}"
        else:
            (best, it_g), t_g = _timed(lambda g=g, v=v: ref.lm_solve(g, v))
        _, res, t_o = _odofuse(name, covariances=False)
        _, res_c, t_c = _odofuse(name)
        ours = ref.odofuse_values(res, keys)
        rms = ref.position_rms(ref.poses_of(ours, keys), ref.poses_of(best, keys))
        print(
            f"{name:30s} {g.error(best):12.4f} {g.error(ours):12.4f} {rms:9.2e} "
            f"{t_g:8.2f} {t_o:9.2f} {t_c:8.2f} {t_o / max(t_g, 1e-9):6.2f} "
            f"{it_g!s:>6s}/{res.extra['iterations']:<5d}"
            + (f"  findings: {[f.line() for f in res_c.findings]}" if res_c.findings else "")
        )
    for name in [n for n in ("w100.graph", "w10000.graph") if n in names]:
        g, v, keys = ref.load(_data(name))
        best = ref.lm_optimum(g, v)
        _, res, t_o = _odofuse(name, "isam2", covariances=False)
        ours = ref.odofuse_values(res, keys)
        rms = ref.position_rms(ref.poses_of(ours, keys), ref.poses_of(best, keys))
        print(f"isam2 {name:24s} err {g.error(ours):12.4f}  rms {rms:9.2e} m  {t_o:8.2f} s")


def victoria() -> None:
    print("\n== victoria_park.txt: range-bearing SLAM, unknown trees ==")
    g, _, keys = ref.load(_data("victoria_park.txt"))
    inc, t_i = _timed(lambda: ref.isam2_incremental(g, keys))
    best, t_l = _timed(lambda: ref.lm_optimum(g, inc))
    e_best = g.error(best)
    print(
        f"GTSAM iSAM2 incremental: error {g.error(inc):.2f} in {t_i:.1f} s; + LM: "
        f"{e_best:.2f} in {t_l:.1f} s (GTSAM's best, the reference)"
    )
    for est, opts in (("smoother", {"covariances": False}), ("smoother", {}), ("isam2", {})):
        log, res, dt = _odofuse("victoria_park.txt", est, **opts)
        ours = ref.odofuse_values(res, keys)
        e = g.error(ours)
        rms = ref.position_rms(ref.poses_of(ours, keys), ref.poses_of(best, keys))
        print(
            f"odofuse {est:8s} {str(opts):22s} error {e:10.2f} ({100 * (e / e_best - 1):+.2f} %), "
            f"pose rms {rms:.4f} m, {dt:.1f} s (init {res.extra.get('init_s', 0):.1f} s), "
            f"outliers {res.extra.get('outliers')}, findings {[f.line() for f in res.findings]}"
        )


def goats() -> None:
    print("\n== GOATS (pyfg): range-only SLAM and localisation, no ground truth ==")
    for name in ("goats_15.pyfg", "goats_16.pyfg"):
        from odofuse.io.loader import load_log

        log = load_log(_data(name))
        ids = sorted(log.landmarks)
        B = np.array([log.landmarks[i] for i in ids])
        slam = None
        for est in ("smoother", "isam2"):
            _, res, dt = _odofuse(name, est, log=log, slam=True)
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
        from odofuse.estimators import run_estimator

        T, start = ref.aligned_start(slam, log)
        cfg = ref.dataset_config(log, _data(name))
        cfg = dataclasses.replace(cfg, initial={"pose": list(start), "sigma": [10.0, 10.0, 0.1]})
        loc, dt = _timed(lambda cfg=cfg, log=log: run_estimator("smoother", log, cfg))
        r = ref.range_residuals(loc, log)
        print(
            f"{name} localisation (known beacons, start {start.round(1)}) {dt:6.2f} s  range "
            f"residual median {np.median(abs(r)):.2f} rms {np.sqrt(np.mean(r**2)):.2f} m  "
            f"graph error {loc.extra['final_error']:.1f}  outliers {loc.extra.get('outliers')}"
        )


def walk() -> None:
    from odofuse.errors import OdofuseError
    from odofuse.estimators import run_estimator
    from odofuse.io.loader import load_log

    folder = os.path.dirname(_data("w100.graph"))
    print(f"\n== walk of {folder} ==")
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        try:
            log = load_log(path)
        except OdofuseError as e:
            print(f"refused  {name}: {e}")
            continue
        cfg = ref.dataset_config(log, path, covariances=False)
        try:
            res, dt = _timed(lambda cfg=cfg, log=log: run_estimator("smoother", log, cfg))
        except OdofuseError as e:
            print(f"FAILED   {name}: {e}")
            continue
        print(
            f"ran      {name}: {len(res.trajectory)} poses, used {res.used}, rejected "
            f"{res.rejected}, error {res.extra.get('final_error', float('nan')):.2f}, {dt:.1f} s"
        )


def main(argv) -> None:
    what = argv[1] if len(argv) > 1 else "all"
    parts = {"posegraphs": posegraphs, "victoria": victoria, "goats": goats, "walk": walk}
    for name, fn in parts.items():
        if what in (name, "all"):
            fn()


if __name__ == "__main__":
    main(sys.argv)
