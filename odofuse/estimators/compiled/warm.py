"""A run's second filter compiled in another process while the first one runs (issue 28).

``odofuse run`` with no config runs the EKF and then the UKF. On a fresh install each
compiles its own specialisation of the event-loop kernel (:func:`.kernels.filter_offline`)
at its first call: here 14 and 16 s, one after the other, since numba compiles on one core.
:func:`start` gives the later filter's compile to a child process on the other core: the
child (``python -m odofuse.estimators.compiled.warm CONFIG ESTIMATOR``) runs that estimator
on the same config and log and discards the result, which fills numba's on-disk cache with
exactly the signatures the run will ask for. The run waits for the child
(:meth:`Background.wait`) before that estimator starts and then loads the machine code. A
child that fails or is killed costs nothing but time: the estimator compiles in the run as
before. Two processes compiling one kernel at once is safe because the kernels' cache saves
are serialised (:data:`.kernels.CACHE_SAVES_LOCKED`).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

#: The estimators on the event-loop kernel; a run's first compiles it in the run itself.
FILTERS = ("ekf", "ukf")


class Background:
    """The child compiling ``estimators`` (:func:`start`)."""

    def __init__(self, proc: subprocess.Popen, estimators: tuple[str, ...]):
        self.proc = proc
        self.estimators = estimators

    def wait(self, estimator: str) -> None:
        """Return when ``estimator``'s kernels are in the cache (or the child has ended)."""
        if estimator in self.estimators:
            self.proc.wait()

    def stop(self) -> None:
        """End the child now if it still runs (the run failed or was interrupted)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def plan(configs: dict) -> list[str]:
    """The estimators of ``configs`` (estimator name: its config, in run order) to compile
    in the background: every filter of :data:`FILTERS` after the first, when its
    ``compiled`` option is not ``off``, numba is importable, the cache holds no machine code
    of the event-loop kernel yet and two processes may compile at once."""
    from odofuse.estimators import compiled

    filters = [
        name
        for name, cfg in configs.items()
        if name in FILTERS and getattr(cfg.estimator_options(name), "compiled", "auto") != "off"
    ]
    if len(filters) < 2:
        return []
    k = compiled.load_kernels()
    if k is None or not k.CACHE_SAVES_LOCKED or not compiled.cold(k.filter_offline):
        return []
    return filters[1:]


def start(jobs: list[tuple[str, Path]]) -> Background | None:
    """Start the child compiling each ``(estimator, config file)`` of ``jobs``; None when
    there is nothing to compile."""
    if not jobs:
        return None
    argv = [sys.executable, "-m", __name__]
    for name, path in jobs:
        argv += [str(path), name]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return Background(proc, tuple(name for name, _ in jobs))


def main(argv: list[str]) -> int:
    """The child: run each ``CONFIG ESTIMATOR`` pair of ``argv`` and discard its result."""
    import dataclasses

    from odofuse.config import load_config
    from odofuse.estimators import run_estimator
    from odofuse.io.loader import load_log_for
    from odofuse.log_defaults import apply_log_defaults

    for path, name in zip(argv[::2], argv[1::2], strict=True):
        config = dataclasses.replace(load_config(path), estimator=name)
        config, log = apply_log_defaults(config, load_log_for(config))
        run_estimator(name, log, config)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
