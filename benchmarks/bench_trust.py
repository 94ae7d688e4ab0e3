"""Issue 10's scenario set: every estimator either holds or says it is degraded.

Run from any directory: ``python benchmarks/bench_trust.py [--only NAME ...] [--estimators ...]
[--laps N] [--seed S] [--particles N]``. Prints, per scenario and estimator, the position RMSE
(m), the position NEES (expected 2), and two statuses with their verdicts of
:func:`odofuse.teaching.trust_scenarios.judge`: the estimator alone (``alone``, cross-check
off: what a live pipeline has) and as ``odofuse run`` gives it (``checked``: with the batch
smoother's second opinion, :mod:`odofuse.cross_check`, under its ``auto`` rule). A verdict is
``holds`` (RMSE within 2x of the batch smoother's and position NEES below 10), ``degraded``
(it said so) or ``SILENT`` (a silent failure: neither). ``alarm`` marks a run that holds but
that the check flags (a false alarm: the check's cost). The last lines count the silent
failures of both (target: zero checked) and the false alarms. Each checked run's cross-check
figures (departure rms, smoother sigma, predicted ratio, departure NEES, the smoother's
variance factor and its sigma before it, or why skipped) and
each degraded run's first warning are printed under the table.

One estimate per (scenario, estimator), scored twice; one smoother run per scenario, shared.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from odofuse.rundir import checked_metrics, estimate  # noqa: E402
from odofuse.teaching import trust_scenarios as ts  # noqa: E402

ESTIMATORS = ("smoother", "dead_reckoning", "ekf", "ukf", "particle")


def scenarios(names, laps, seed):
    """Yield ``(name, loader)`` with ``loader(estimator) -> (log, config)``."""
    for name in names:
        if name == "figure_eight":
            pair = ts.figure_eight()
            yield name, lambda _e, p=pair: p
        elif name == "plaza2":
            yield name, ts.plaza2
        else:
            pair = ts.simulated(name, laps, seed)
            yield name, lambda _e, p=pair: p


def _f(v) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3g}"


def _figures(block: dict) -> str:
    if "skipped" in block:
        return "skipped: " + block["skipped"]
    return (
        f"d {_f(block['departure_rms_m'])} m, s {_f(block['smoother_sigma_m'])} m, "
        f"ratio {_f(block['predicted_ratio'])}, p_fail {_f(block.get('p_fail'))}, "
        f"departure NEES {_f(block['departure_nees'])}, "
        f"smoother variance factor {_f(block.get('smoother_variance_factor'))} "
        f"(s before it {_f(block.get('smoother_sigma_model_m'))} m)"
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    names = ["figure_eight", *ts.SIMULATED, "plaza2"]
    p.add_argument("--only", nargs="*", default=names, help="scenarios to run")
    p.add_argument("--estimators", nargs="*", default=list(ESTIMATORS))
    p.add_argument("--laps", type=int, default=None, help="shorten simulated scenarios")
    p.add_argument("--seed", type=int, default=None, help="simulation seed (default 7)")
    p.add_argument("--particles", type=int, default=None, help="particle filter's particles")
    args = p.parse_args(argv)
    notes, silent, silent_checked, alarms = [], 0, 0, 0
    print(
        f"{'scenario':18} {'estimator':15} {'RMSE [m]':>9} {'NEES_pos':>9} "
        f"{'alone':9} {'verdict':9} {'checked':9} verdict"
    )
    for name, load in scenarios(args.only, args.laps, args.seed):
        refs: dict = {}  # the smoother run of each config, shared by the scenario's estimators
        ref_rmse = None
        for est in ["smoother", *[e for e in args.estimators if e != "smoother"]]:
            log, cfg = load(est)
            key = cfg.source  # the smoother of the run's own config, as odofuse run does
            opts = {"particles": args.particles} if est == "particle" and args.particles else None
            try:
                if key not in refs:
                    refs[key] = ts.smoother_reference(log, cfg)
                ref = refs[key]
                on = ts.run_config(cfg, est, opts, check=True)
                result, runtime = estimate(on, log, ref)
                m_off = checked_metrics(ts.run_config(cfg, est, opts, False), log, result, runtime)
                m_on = checked_metrics(on, log, result, runtime, ref)
            except Exception as exc:  # noqa: BLE001 - a crash is reported as such
                print(f"{name:18} {est:15} crashed: {exc}")
                silent += 1
                silent_checked += 1
                continue
            if est == "smoother":
                ref_rmse = m_off.get("ate_rmse_m")
            # The smoother is the RMSE reference; it is itself judged on its NEES alone.
            yard = ref_rmse if est != "smoother" else math.inf
            v_off, v_on = ts.judge(m_off, yard), ts.judge(m_on, yard)
            silent += v_off == "SILENT"
            silent_checked += v_on == "SILENT"
            flagged = any(f["check"].startswith("cross_check") for f in m_on["findings"])
            alarm = v_on == "holds" and flagged
            alarms += alarm
            rmse, nees = m_on.get("ate_rmse_m"), m_on.get("nees_position_mean")
            print(
                f"{name:18} {est:15} {_f(rmse):>9} {_f(nees):>9} {m_off['status']:9} "
                f"{v_off:9} {m_on['status']:9} {v_on}{'  alarm' if alarm else ''}"
            )
            sys.stdout.flush()
            notes.append(f"{name}/{est}: cross_check {_figures(m_on['cross_check'])}")
            if m_on["warnings"]:
                notes.append(f"{name}/{est}: {m_on['warnings'][0]}")
    print(f"silent failures: alone {silent}, checked {silent_checked}")
    print(f"false alarms of the check (hold, flagged only by it): {alarms}")
    for line in notes:
        print("  " + line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
