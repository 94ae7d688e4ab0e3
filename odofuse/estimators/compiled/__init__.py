"""The compiled offline core: numba kernels beside the pure-Python reference paths.

``options.ekf.compiled`` / ``options.ukf.compiled`` / ``options.dead_reckoning.compiled`` /
``options.particle.compiled`` (``auto``, ``on``, ``off``) choose it; ``auto`` uses numba when
it can be imported (dead reckoning and the particle filter only on runs long enough to pay for
loading it). This package owns that choice (:func:`enabled`, which also says on a terminal
when a one-time compile is about to happen: :func:`announce`), the dead-reckoning dispatch
(:mod:`.dead_reckoning`), the offline EKF over a log's event array (:mod:`.ekf`), the offline
UKF on the same arrays and coverage (:mod:`.ukf`), the particle filter's propagation,
weighting and cloud moments (:mod:`.particle`) and the kernels themselves (:mod:`.kernels`, the
only module that imports numba). The pure-Python paths stay the reference, the streaming path
and the fallback for everything the kernels do not cover (``docs/filters.md``, "Compiled
core").
"""

from __future__ import annotations

import importlib
import sys

#: Values of the ``compiled`` option.
COMPILED_MODES = ("auto", "on", "off")


def load_kernels():
    """The :mod:`.kernels` module, or None when numba cannot be imported."""
    try:
        return importlib.import_module("odofuse.estimators.compiled.kernels")
    except ImportError:
        return None


def enabled(mode: str, what: str = "compiled", worth_it: bool = True):
    """The kernels module when ``mode`` asks for it and numba is importable, else None.

    ``on`` without numba is an error (the user asked for it explicitly). ``auto`` also needs
    ``worth_it``: the caller's judgement that the run is long enough to pay for importing
    numba and loading the cached machine code (dead reckoning:
    :data:`.dead_reckoning.AUTO_MIN_STEPS`).
    """
    if mode == "off" or (mode == "auto" and not worth_it):
        return None
    k = load_kernels()
    if k is None and mode == "on":
        from odofuse.errors import ConfigError

        raise ConfigError("compiled: on needs numba (pip install 'numba>=0.60,<0.69')", key=what)
    if k is not None:
        announce(k, what)
    return k


#: The kernel each compiled path calls first, by estimator: its cache says whether the run
#: will compile (numba compiles lazily, at a kernel's first call in a process).
FIRST_KERNEL = {
    "ekf": "filter_offline",
    "ukf": "filter_offline",
    "dead_reckoning": "dr_linear",
    "particle": "pf_mean",
}
_announced: set[str] = set()


def cold(dispatcher) -> bool:
    """Whether numba's on-disk cache holds no machine code of ``dispatcher`` for its current
    source (no index, or one written for another version of the file: numba then compiles).
    False when that cannot be told (numba's cache layout is not public API)."""
    try:
        return not dispatcher._cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - a guess for a message, never a reason to fail a run
        return False


def announce(k, what: str, stream=None) -> bool:
    """Say on the terminal, once per process, that a one-time compile of the kernels is about
    to happen (issue 28: a line, not silence), when the first kernel of ``what``'s estimator
    has no cached machine code. Only when ``stream`` (standard error) is a terminal: piped
    and captured output stays the run's own. Returns whether it printed.

    One line for the whole run: numba compiles each kernel lazily at its first call, for the
    argument types of that call, so a later estimator (the UKF after the EKF, sharing
    ``filter_offline``) may compile again under the same line; no progress bar, since numba
    reports no progress."""
    stream = sys.stderr if stream is None else stream
    est = what.split(".")[1] if what.count(".") >= 2 else what
    name = FIRST_KERNEL.get(est)
    if name is None or _announced or not getattr(stream, "isatty", lambda: False)():
        return False
    if not cold(getattr(k, name)):
        return False
    _announced.add(est)
    print(
        "odofuse: compiling the numba kernels once for this machine and version (10-20 s per "
        "estimator on the compiled core); later runs load them from the cache",
        file=stream,
        flush=True,
    )
    return True
