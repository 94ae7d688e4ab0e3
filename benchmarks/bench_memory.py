"""Where a run's memory peaks: resident memory per phase of ``odofuse run CONFIG -o OUT``.

Run from any directory: ``python benchmarks/bench_memory.py CONFIG -o OUT [other run args]``
(e.g. the configs ``benchmarks/bench_io.py`` writes into ``/tmp/odofuse-bench-io-10h``).

A thread samples the process's resident set (``/proc/self/statm``, Linux) every 2 ms; the
phases are labelled by wrapping the functions ``odofuse run`` calls (load, estimate, the metrics
and their passes, each output writer, the picture), the innermost label winning; time outside
them is ``cli``. Prints, per phase, the resident memory when it was first seen and the largest
seen in it (MiB), then ``ru_maxrss``, the true peak. A numba kernel holds the GIL, so a peak
inside one is seen only by ``ru_maxrss`` and by the next sample after it. Asserts nothing.
"""

from __future__ import annotations

import functools
import importlib
import os
import resource
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # the repo

PAGE = os.sysconf("SC_PAGE_SIZE")
#: (module, function, label) wrapped; ``odofuse.rundir`` imports some of them by name.
PHASES = (
    ("odofuse.io.loader", "load_log_for", "load"),
    ("odofuse.estimators", "run_estimator", "estimate"),
    ("odofuse.evaluation", "metrics", "metrics"),
    ("odofuse.evaluation", "check_groundtruth", "metrics: check truth"),
    ("odofuse.evaluation", "_coverage", "metrics: coverage"),
    ("odofuse.evaluation", "associate", "metrics: associate"),
    ("odofuse.evaluation", "ate", "metrics: ate"),
    ("odofuse.evaluation", "align_se2", "metrics: align"),
    ("odofuse.evaluation", "rpe", "metrics: rpe"),
    ("odofuse.evaluation", "nees", "metrics: nees"),
    ("odofuse.status.findings", "assess", "metrics: assess"),
    ("odofuse.rundir", "write_outputs", "outputs (truth tum, evo)"),
    ("odofuse.outputs", "write_trajectory_csv", "write csv"),
    ("odofuse.outputs", "write_tum", "write tum"),
    ("odofuse.outputs", "write_metrics", "write json"),
    ("odofuse.plotting", "plot_run", "plot"),
)


def _rss_mib() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * PAGE / 2**20


def main(argv: list[str]) -> None:
    stack, seen = ["cli"], {}

    def sample() -> None:
        while True:
            r, label = _rss_mib(), stack[-1]
            first, top = seen.get(label, (r, r))
            seen[label] = (first, max(top, r))
            time.sleep(0.002)

    for mod, name, label in PHASES:
        m = importlib.import_module(mod)
        real = getattr(m, name)

        def wrapped(*a, _real=real, _label=label, **k):
            stack.append(_label)
            try:
                return _real(*a, **k)
            finally:
                stack.pop()

        functools.update_wrapper(wrapped, real)
        setattr(m, name, wrapped)
        rundir = importlib.import_module("odofuse.rundir")
        if getattr(rundir, name, None) is real:
            setattr(rundir, name, wrapped)
    threading.Thread(target=sample, daemon=True).start()
    from odofuse.cli import main as cli

    rc = cli(["run", *argv])
    time.sleep(0.01)
    print(f"{'phase':26s} {'RSS first seen':>14s} {'largest':>8s}  (MiB)")
    for label, (first, top) in seen.items():
        print(f"{label:26s} {first:14.0f} {top:8.0f}")
    print(
        f"ru_maxrss (the peak): {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB"
    )
    sys.exit(rc)


if __name__ == "__main__":
    main(sys.argv[1:])
