"""The compiled offline core: numba kernels beside the pure-Python reference paths.

``options.ekf.compiled`` / ``options.ukf.compiled`` / ``options.dead_reckoning.compiled`` /
``options.particle.compiled`` (``auto``, ``on``, ``off``) choose it; ``auto`` uses numba when
it can be imported (dead reckoning and the particle filter only on runs long enough to pay for
loading it). This package owns that choice (:func:`enabled`), the dead-reckoning dispatch
(:mod:`.dead_reckoning`), the offline EKF over a log's event array (:mod:`.ekf`), the offline
UKF on the same arrays and coverage (:mod:`.ukf`), the particle filter's propagation,
weighting and cloud moments (:mod:`.particle`) and the kernels themselves (:mod:`.kernels`, the
only module that imports numba). The pure-Python paths stay the reference, the streaming path
and the fallback for everything the kernels do not cover (``docs/filters.md``, "Compiled
core").
"""

from __future__ import annotations

import importlib

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
    return k
