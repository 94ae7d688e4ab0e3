"""Issue 25: does the live ``Localizer.health()`` say what the offline run says?

For each log of ``bench_status.py`` (nominal seeds and injected faults, the config a user
would write) and each streaming filter, the live Localizer (``Localizer.from_config``,
memory-flat, readings fed in time order, ``health()`` asked once a second) is compared with
the offline run as ``odofuse run`` gives it (``rundir.checked_metrics``, with the batch
smoother's second opinion, shared by the filters of a log). The issue allows one difference:
"the offline run may add the smoother's consistency check", so a run whose offline status is
``degraded`` only by second-opinion findings (:data:`SECOND_OPINION`) while the live one says
``ok`` is counted apart; every other difference is a disagreement, listed with its findings.

Usage: ``python benchmarks/bench_live_status.py [--seeds N] [--first S] [--fault-seeds M]
[--faults ...] [--estimators ekf ukf particle]`` (default: 30 nominal seeds from 1000, 5
seeds per fault kind, the EKF and the particle filter: 544 s here; the UKF alone 123 s).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_status as bs  # noqa: E402

from odofuse.status.cross_check import SEEN_BY_REFERENCE  # noqa: E402
from odofuse.status.drift import SEEN_BY_EKF  # noqa: E402

#: Findings only the offline run can make: the batch smoother's second opinion and what the
#: filters take from it (docs/trust.md, section 6; ``odofuse.status`` catalog), and since
#: session 55 any finding the smoother of the log (or its companion EKF) detected, carried
#: under its own check name with a message starting with one of :data:`CARRIED`.
SECOND_OPINION = frozenset(
    {"cross_check_nees", "cross_check_skipped", "variance_factor", "latency"}
)
CARRIED = (SEEN_BY_REFERENCE, SEEN_BY_EKF)


def live_health(cfg, log, estimator: str):
    """The live Localizer's final :class:`~odofuse.status.monitors.LiveHealth` on ``log``."""
    from odofuse.estimators.assembly import events
    from odofuse.estimators.common import odometry_inputs
    from odofuse.estimators.localizer import Localizer
    from odofuse.motion import motion_model_from_config

    cfg = dataclasses.replace(cfg, estimator=estimator)
    t, U = odometry_inputs(log, motion_model_from_config(cfg))
    loc = Localizer.from_config(
        cfg, float(t[0]), landmarks=log.landmarks, initial_pose=log.initial_pose
    )
    every = max(1, round(1.0 / max(float(t[-1] - t[0]) / max(len(t) - 1, 1), 1e-9)))
    k = 0
    for te, kind, stream, i in events(log, t, U, [s for s in cfg.sensors if s in log.streams]):
        if kind == 1:
            loc.add_odometry(te, U[i])
            k += 1
            if k % every == 0:
                loc.health()
        else:
            loc.add_measurement(stream, log.streams[stream].row(i))
    loc.finish()
    return loc.health()


def compare(log, cfg, estimators) -> dict:
    """``{estimator: (verdict, live status, offline status, detail)}`` on one log; verdict
    ``equal``, ``second opinion`` (offline degraded by :data:`SECOND_OPINION` and
    :data:`CARRIED` findings alone)
    or ``differ``."""
    from odofuse.log_defaults import apply_log_defaults
    from odofuse.rundir import checked_metrics, estimate, smoother_reference

    cfg, log = apply_log_defaults(cfg, log)
    ref = smoother_reference(cfg, log)
    out = {}
    for est in estimators:
        run_cfg = dataclasses.replace(cfg, estimator=est)
        m = checked_metrics(run_cfg, log, *estimate(run_cfg, log, ref), ref)
        h = live_health(cfg, log, est)
        degrading = [f for f in m["findings"] if f.get("degrades")]
        offline = {f["check"] for f in degrading}
        live = {f.check for f in h.findings if f.degrades}
        alone = all(
            f["check"] in SECOND_OPINION or f["message"].startswith(CARRIED) for f in degrading
        )
        if h.run_status == m["status"]:
            verdict = "equal"
        elif h.run_status == "ok" and alone:
            verdict = "second opinion"
        else:
            verdict = "differ"
        detail = f"offline {sorted(offline)}, live {sorted(live)}"
        out[est] = (verdict, h.run_status, m["status"], detail)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=30, help="nominal seeds (default 30)")
    p.add_argument("--first", type=int, default=1000)
    p.add_argument("--fault-seeds", type=int, default=5, help="seeds per fault kind (5)")
    p.add_argument("--faults", nargs="*", default=list(bs.FAULTS), choices=list(bs.FAULTS))
    p.add_argument(
        "--estimators", nargs="*", default=["ekf", "particle"], choices=["ekf", "ukf", "particle"]
    )
    args = p.parse_args(argv)
    cases = [(None, s) for s in range(args.first, args.first + args.seeds)]
    cases += [(f, s) for f in args.faults for s in range(args.first, args.first + args.fault_seeds)]
    counts = {e: {"equal": 0, "second opinion": 0, "differ": 0} for e in args.estimators}
    notes = []
    t0 = time.perf_counter()
    for fault, seed in cases:
        log, cfg, what = bs.make_case(seed, fault)
        rows = compare(log, cfg, args.estimators)
        kind = fault or "nominal"
        for est, (verdict, live, offline, detail) in rows.items():
            counts[est][verdict] += 1
            if verdict != "equal":
                notes.append(f"{est} {kind} {seed} {what}: live {live}, offline {offline}")
                notes.append(f"    {detail}")
        brief = " ".join(f"{e}:{r[1][:3]}/{r[2][:3]}" for e, r in rows.items())
        print(f"  {kind} seed {seed} {what}: live/offline {brief}", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s, {len(cases)} logs")
    print(
        "| estimator | logs | live run_status = offline status "
        "| offline adds the second opinion | differ |"
    )
    print("| --- | --- | --- | --- | --- |")
    for est, c in counts.items():
        n = sum(c.values())
        print(f"| {est} | {n} | {c['equal']} | {c['second opinion']} | {c['differ']} |")
    print()
    for line in notes:
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
