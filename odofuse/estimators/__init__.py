"""Estimators: each is ``run(log, config) -> EstimateResult``, looked up by name.

The table maps a config name to ``"module:function"`` so that importing odofuse does not import
gtsam or filterpy until an estimator that needs them runs. Users may name their own estimator
as ``"package.module:function"``.
"""

from __future__ import annotations

from odofuse.errors import ConfigError
from odofuse.plugins import load_function

ESTIMATORS: dict[str, str] = {
    "dead_reckoning": "odofuse.estimators.dead_reckoning:run",
    "ekf": "odofuse.estimators.ekf:run",
    "ukf": "odofuse.estimators.ukf:run",
    "particle": "odofuse.estimators.particle:run",
    "smoother": "odofuse.estimators.graph:run_smoother",
    "isam2": "odofuse.estimators.graph:run_isam2",
    "fixed_lag": "odofuse.estimators.graph:run_fixed_lag",
}


def get_estimator(name: str):
    """The ``run(log, config)`` of estimator ``name`` (a table key or ``module:function``)."""
    spec = ESTIMATORS.get(name, name)
    if ":" not in spec:
        raise ConfigError(
            f"unknown estimator '{name}'; known: {', '.join(ESTIMATORS)}", key="estimator"
        )
    return load_function(spec, "estimator")


def run_estimator(name: str, log, config, **options):
    """Run estimator ``name`` on ``log`` with ``config``; returns an ``EstimateResult``.

    ``options`` are keyword arguments of that estimator's ``run`` beyond the config (the
    cross-check asks the batch smoother for its error samples: ``error_samples=K``).

    The log's plausibility findings (``log.findings``) join the result's. A log with loop
    closures (``loop_closures`` stream) that the estimator did not use gets
    a non-degrading finding saying so (only the graph estimators use them, with
    ``sensors: {loop_closures: {}}``).
    """
    result = get_estimator(name)(log, config, **options)
    noted = tuple(getattr(log, "findings", ()) or ())  # the log's plausibility findings
    if noted:
        import dataclasses

        result = dataclasses.replace(result, findings=tuple(result.findings) + noted)
    streams = getattr(log, "streams", {}) or {}
    n = len(streams["loop_closures"]) if "loop_closures" in streams else 0
    if n and "loop_closures" not in result.used:
        import dataclasses

        from odofuse.health import Finding

        note = Finding(
            "loop_closures",
            f"{n} loop closures in the log are not used by '{name}' (the graph estimators use "
            "them with sensors: {loop_closures: {}})",
            sensor="loop_closures",
            figure=float(n),
            degrades=False,
        )
        result = dataclasses.replace(result, findings=tuple(result.findings) + (note,))
    return result
