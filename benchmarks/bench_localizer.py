"""Streaming Localizer: steps/s and memory over a long live run (issues 16 and 17).

A live EKF Localizer (``Localizer.from_config``, so it keeps only the late window) is fed
odometry at 50 Hz and a GPS fix each second, 0.3 s late (so the filter rolls back and replays
15 steps) or, for the speed table, also on time; inputs are generated on the fly (nothing of
the run is kept outside the Localizer). Printed:

* steps/s over the whole run, and the process's resident memory (RSS) at eight checkpoints:
  flat after the first window means the Localizer's memory does not grow with the run;
* with ``--check N``: the live Localizer against ``odofuse run``'s EKF (the compiled core by
  default) over ``N`` steps, bit for bit (the offline run keeps the whole log and all N poses:
  peak RSS 5.7 GiB for N = 10^7);
* with ``--against REV`` (a git revision, e.g. the merge base), the same run through that
  revision's ``odofuse/estimators/localizer.py`` and ``inputs.py`` in the same process
  (interleaved, best of three), and the ratio;
* with ``--health M``: only the cost of the live health (issue 25), ``M`` steps with the
  monitor's streaming checks off, on, and with ``health()`` asked at 1 Hz, 10 Hz and every
  step (interleaved, best of three, same process).

Run from anywhere: ``python benchmarks/bench_localizer.py [--steps N] [--check N] [--against REV]
[--health M]``
(``nice -n 10`` on a shared machine; 10^7 steps take about half an hour there).
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from odofuse.config import RunConfig  # noqa: E402
from odofuse.estimators.localizer import Localizer  # noqa: E402

RATE, GPS_EVERY = 50, 50  # odometry Hz; one fix per second


def config() -> RunConfig:
    return RunConfig(
        log="live",
        robot={"drive": "increments"},
        motion={"integrator": "exact", "k": [1e-3, 1e-4], "var_floor": 1e-8},
        estimator="ekf",
        initial={"pose": [0.0, 0.0, 0.0], "sigma": [0.1, 0.1, 0.02]},
        sensors={"gps": {"sigma": 0.5}},
        source="bench.yaml",
    )


def rss_mib() -> float:
    """Resident set size of this process, MiB (Linux /proc)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except OSError:
        return float("nan")
    import os

    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def feed(
    cls,
    n: int,
    marks=(),
    delay: float = 0.3,
    t0: float = 0.0,
    verbose: bool = False,
    ask_every: int = 0,
    checks: bool = True,
) -> tuple[object, dict]:
    """Feed ``n`` steps to a live ``cls`` Localizer, each GPS fix ``delay`` s late (negative:
    early, buffered); RSS (MiB) at the step counts ``marks`` (printed as reached when
    ``verbose``). ``ask_every`` > 0: ``loc.health()`` after every that many steps;
    ``checks=False``: the monitor's streaming checks switched off (the cost they add)."""
    loc = cls.from_config(config(), t0)
    if not checks:
        loc.monitor._advance = lambda stream, n: None
    noise = np.random.default_rng(0).normal(0.0, 0.5, (n // GPS_EVERY + 1, 2)).tolist()
    dt = 1.0 / RATE
    ds, dth = 0.5 * dt, 0.05 * dt  # 0.5 m/s, 0.05 rad/s
    u = np.array([ds, dth])
    th, x, y = 0.0, 0.0, 0.0
    rss = {}
    asked = rss.setdefault("health_s", []) if ask_every else []  # seconds per health() call
    marks = set(marks)
    for k in range(1, n + 1):
        t = k * dt
        loc.add_odometry(t, u)
        th += dth
        x += ds * math.cos(th)
        y += ds * math.sin(th)
        if k % GPS_EVERY == 0:
            ex, ey = noise[k // GPS_EVERY]
            loc.add_measurement("gps", {"t": t - delay, "x": x + ex, "y": y + ey})
        if ask_every and k % ask_every == 0:
            t_ask = time.perf_counter()
            loc.health()
            asked.append(time.perf_counter() - t_ask)
        if k in marks:
            rss[k] = rss_mib()
            if verbose:
                print(f"  step {k:,}: RSS {rss[k]:.1f} MiB", flush=True)
    return loc, rss


def offline_log(n: int, delay: float = 0.3):
    """The readings :func:`feed` sends, as a :class:`~odofuse.io.log.SensorLog` (the same
    arithmetic, so the same numbers)."""
    from odofuse.io.log import SensorLog, Stream

    noise = np.random.default_rng(0).normal(0.0, 0.5, (n // GPS_EVERY + 1, 2)).tolist()
    dt = 1.0 / RATE
    ds, dth = 0.5 * dt, 0.05 * dt
    th, x, y = 0.0, 0.0, 0.0
    gps = []
    for k in range(1, n + 1):
        th += dth
        x += ds * math.cos(th)
        y += ds * math.sin(th)
        if k % GPS_EVERY == 0:
            ex, ey = noise[k // GPS_EVERY]
            gps.append((k * dt - delay, x + ex, y + ey))
    t = np.arange(1, n + 1) * dt  # k * dt, as feed computes it
    U = np.tile([ds, dth], (n, 1))
    g = np.array(gps).reshape(-1, 3)
    streams = {
        "odometry": Stream("odometry", "bench", t, ("ds", "dtheta"), U),
        "gps": Stream("gps", "bench", g[:, 0], ("x", "y"), g[:, 1:]),
    }
    return SensorLog("bench", streams, initial_pose=np.zeros(3))


def check_offline(n: int) -> str:
    """Online (live Localizer) against ``odofuse run``'s EKF (``ekf.run``) over ``n`` steps:
    the poses and covariances of the late window and the final state, bit for bit."""
    from odofuse.estimators import ekf
    from odofuse.estimators.common import odometry_inputs
    from odofuse.motion import motion_model_from_config

    log = offline_log(n)
    t, _ = odometry_inputs(log, motion_model_from_config(config()))
    offline = ekf.run(log, config())
    loc, _ = feed(Localizer, n, t0=float(t[0]))
    online = loc.result()
    m = len(online.trajectory.t)
    same = (
        np.array_equal(online.trajectory.t, offline.trajectory.t[-m:])
        and np.array_equal(online.trajectory.poses, offline.trajectory.poses[-m:])
        and np.array_equal(online.trajectory.covariances, offline.trajectory.covariances[-m:])
        and online.used == offline.used
        and online.extra["map_to_odom"] == offline.extra["map_to_odom"]
    )
    diff = float(np.max(np.abs(online.trajectory.poses - offline.trajectory.poses[-m:])))
    return (
        f"online == odofuse run's EKF over {n:,} steps ({type(loc.backend).__name__}): "
        f"{'bit for bit' if same else f'NOT equal (max pose difference {diff:.3g})'}; "
        f"last {m} poses, final covariance, used {online.used}"
    )


def base_localizer(rev: str):
    """``Localizer`` of revision ``rev`` (its localizer.py and inputs.py), loaded beside ours."""
    folder = Path(tempfile.mkdtemp())

    def load(path: str, name: str):
        text = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{rev}:{path}"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        (folder / f"{name}.py").write_text(text)
        spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
        return mod

    inputs = load("odofuse/estimators/inputs.py", "_base_inputs")
    mod = load("odofuse/estimators/localizer.py", "_base_localizer")
    mod.inputs = inputs
    return mod.Localizer


def health_cost(m: int, reps: int = 7) -> None:
    """The live health's cost (issue 25): steps/s with the monitor's streaming checks off and
    on (best of ``reps`` interleaved runs of ``m`` steps, GPS fixes 0.3 s late); the
    streaming checks' own time per reading, timed alone; and ``health()`` timed inside the
    run at 1 Hz, 10 Hz and every step (the fastest run's mean per call). The two timed-alone
    figures hold on a loaded machine, where whole runs vary by tens of percent."""
    from odofuse.status import streaming

    best = {False: 0.0, True: 0.0}
    calls = {50: math.inf, 5: math.inf, 1: math.inf}
    for _ in range(reps):
        for checks in (False, True):
            t0 = time.perf_counter()
            feed(Localizer, m, checks=checks)
            best[checks] = max(best[checks], m / (time.perf_counter() - t0))
        for every in calls:
            asked = feed(Localizer, m, ask_every=every)[1]["health_s"]
            calls[every] = min(calls[every], sum(asked) / len(asked))
    step = 1.0 / best[True]
    loc, _ = feed(Localizer, 2000)
    opts, gate = loc.options, loc.monitor.gates["gps"]
    nis = np.random.default_rng(1).chisquare(2, 20_000).tolist()
    per = math.inf
    for _ in range(reps):
        st = streaming.StreamState()
        t0 = time.perf_counter()
        for k, v in enumerate(nis):
            st = streaming.advance(st, float(k), True, v, gate, 2, opts)
        per = min(per, (time.perf_counter() - t0) / len(nis))
    print(f"\nlive health cost, {m:,} steps, best of {reps} interleaved runs in this process")
    print(
        f"steps/s: streaming checks off {best[False]:,.0f}, on {best[True]:,.0f} "
        f"({100 * (best[False] / best[True] - 1):+.1f} %); step {1e6 * step:.1f} us"
    )
    print("| part | us per call | calls per step | share of the step |")
    print("| --- | --- | --- | --- |")
    print(
        f"| streaming checks, advance() per reading | {1e6 * per:.2f} | 1/{GPS_EVERY} | "
        f"{100 * per / GPS_EVERY / step:.2f} % |"
    )
    for every, label in ((50, "1 Hz"), (5, "10 Hz"), (1, "every step, 50 Hz")):
        print(
            f"| health() at {label} | {1e6 * calls[every]:.1f} | 1/{every} | "
            f"{100 * calls[every] / every / step:.1f} % |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200_000)
    ap.add_argument("--against", help="git revision to compare with (same process)")
    ap.add_argument("--speed-steps", type=int, default=20_000)
    ap.add_argument(
        "--check", type=int, metavar="N", help="compare online with odofuse run over N steps"
    )
    ap.add_argument(
        "--health", type=int, metavar="M", help="only the live health cost table, M steps"
    )
    args = ap.parse_args()
    if args.health:
        health_cost(args.health)
        return
    if args.check:
        print(check_offline(args.check))

    n = args.steps
    marks = [n * i // 8 for i in range(1, 9)]
    start = time.perf_counter()
    _, rss = feed(Localizer, n, marks, verbose=True)
    wall = time.perf_counter() - start
    rate = n / wall
    print(f"live EKF Localizer, odometry {RATE} Hz + GPS 1 Hz, {n:,} steps: {rate:,.0f} steps/s")
    print("RSS [MiB] at " + ", ".join(f"{k:,}: {v:.1f}" for k, v in rss.items()))
    growth = rss[marks[-1]] - rss[marks[0]]
    print(f"RSS growth from step {marks[0]:,} to {marks[-1]:,}: {growth:+.1f} MiB")
    if args.against:
        old = base_localizer(args.against)
        m = args.speed_steps
        print(f"\nsteps/s, {m:,} steps, best of 3 interleaved runs in this process")
        print(f"| GPS fixes | {args.against} | this tree | ratio | same final pose |")
        print("| --- | --- | --- | --- | --- |")
        for label, delay in (("0.3 s late (replayed)", 0.3), ("on time (buffered)", -0.01)):
            best = {"before": 0.0, "after": 0.0}
            for _ in range(3):
                for name, cls in (("before", old), ("after", Localizer)):
                    t0 = time.perf_counter()
                    feed(cls, m, delay=delay)
                    best[name] = max(best[name], m / (time.perf_counter() - t0))
            a = feed(old, 2000, delay=delay)[0].pose()
            b = feed(Localizer, 2000, delay=delay)[0].pose()
            print(
                f"| {label} | {best['before']:,.0f} | {best['after']:,.0f} | "
                f"{best['after'] / best['before']:.2f} | {bool((a == b).all())} |"
            )


if __name__ == "__main__":
    main()
