"""Simulated logs for the graph tests (the one place that imports the simulator).

The simulator lives in ``odofuse.teaching``; this module is the only place the graph tests
name its path.
"""

from __future__ import annotations

import dataclasses

from odofuse.config import config_from_dict
from odofuse.teaching.scenario import scenario_from_dict
from odofuse.teaching.simlog import run_config, to_sensor_log
from odofuse.teaching.simulate import simulate


def simulated_run(scenario: dict, seed: int, estimator: str, options=None, sensors=None):
    """``(log, config)`` of a scenario (``odofuse simulate`` format), seeded.

    The config is the one the simulator writes for the log (nominal geometry and noise),
    with ``options`` as ``options.<estimator>`` and ``sensors`` blocks merged over its own.
    """
    sim = simulate(scenario_from_dict(scenario, "<test scenario>"), seed=seed)
    log = to_sensor_log(sim)
    cfg = run_config(sim, estimator)
    for name, block in (sensors or {}).items():
        cfg["sensors"][name] = {**cfg["sensors"].get(name, {}), **block}
    cfg["options"] = {estimator: dict(options or {})}
    config = config_from_dict(cfg, source="<test config>")
    return log, dataclasses.replace(config, log="<memory>")


def excerpt(log, seconds: float):
    """The first ``seconds`` of a log (every stream and the ground truth cut alike)."""
    from odofuse.io.log import Stream

    t0 = min(float(s.t.min()) for s in log.streams.values() if len(s))
    t1 = t0 + seconds

    def cut(s):
        keep = s.t <= t1
        return Stream(s.name, s.source, s.t[keep], s.columns, s.values[keep])

    gt = None if log.groundtruth is None else cut(log.groundtruth)
    streams = {n: cut(s) for n, s in log.streams.items()}
    return dataclasses.replace(log, streams=streams, groundtruth=gt)
