"""Estimators: each is ``run(log, config) -> EstimateResult``, looked up by name.

The table maps a config name to ``"module:function"`` so that importing odofuse does not import
gtsam or filterpy until an estimator that needs them runs. Users may name their own estimator
as ``"package.module:function"``.
"""

from __future__ import annotations

import importlib

from odofuse.errors import ConfigError

ESTIMATORS: dict[str, str] = {
    "dead_reckoning": "odofuse.estimators.dead_reckoning:run",
    "ekf": "odofuse.estimators.ekf:run",
    "ukf": "odofuse.estimators.ukf:run",
    "particle": "odofuse.estimators.particle:run",
    "smoother": "odofuse.estimators.graph:run_smoother",
    "isam2": "odofuse.estimators.graph:run_isam2",
    "fixed_lag": "odofuse.estimators.graph:run_fixed_lag",
}


def load_object(spec: str, what: str = "object"):
    """Import ``"package.module:Name"`` and return the named object."""
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise ConfigError(f"{what} '{spec}' is not of the form 'package.module:Name'")
    try:
        return getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"cannot load {what} '{spec}': {exc}") from None


def get_estimator(name: str):
    """The ``run(log, config)`` of estimator ``name`` (a table key or ``module:function``)."""
    spec = ESTIMATORS.get(name, name)
    if ":" not in spec:
        raise ConfigError(
            f"unknown estimator '{name}'; known: {', '.join(ESTIMATORS)}", key="estimator"
        )
    return load_object(spec, "estimator")


def run_estimator(name: str, log, config):
    """Run estimator ``name`` on ``log`` with ``config``; returns an ``EstimateResult``."""
    return get_estimator(name)(log, config)
