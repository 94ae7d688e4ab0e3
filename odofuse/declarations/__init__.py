"""Built-in option declarations: one frozen dataclass per config block, sensor kind, estimator.

Every key a run config may carry outside ``robot``'s drive geometry is declared here once, with
its type, unit, default and meaning (:func:`odofuse.options.option`); :mod:`odofuse.config`
validates the YAML blocks into these classes, the estimators and models read the instances, and
the docs tables and ``odofuse options`` are generated from them. The registries:

- :data:`BLOCK_OPTIONS`: ``motion``, ``initial``, ``robot.encoder``, ``log``, ``live``;
- :data:`SENSOR_OPTIONS`: measurement-model kind (a sensor block's ``model``, by default
  :data:`STREAM_DEFAULTS` of its stream name) -> options class;
- :data:`ESTIMATOR_OPTIONS`: estimator name -> options class.

A user estimator ``package.module:function`` or measurement model ``class: package.module:Class``
declares its own options the same way, as an attribute ``Options`` (a frozen dataclass of
:func:`~odofuse.options.option` fields) on the function or class.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from odofuse.declarations.common import (
    DEFAULT_INITIAL_SIGMA,
    DEFAULT_LATE_WINDOW,
    INTEGRATORS,
    ROBUST_DEFAULT_K,
    ROBUST_KINDS,
    gate_probability,
    robust_loss,
)
from odofuse.declarations.estimators import (
    ESTIMATOR_OPTIONS,
    UncheckedOptions,
    estimator_options,
    estimator_options_class,
)
from odofuse.declarations.filters import (
    DeadReckoningOptions,
    EkfOptions,
    FilterOptions,
    KalmanOptions,
    ParticleOptions,
    UkfOptions,
)
from odofuse.declarations.graph import (
    GRAPH_ESTIMATORS,
    SLAM_INITS,
    FreezeConvergence,
    FreezeThresholds,
    GraphOptions,
)
from odofuse.declarations.run import (
    BLOCK_OPTIONS,
    CROSS_CHECK_MODES,
    RUN_OPTIONS,
    CrossCheckOptions,
    EncoderOptions,
    InitialOptions,
    LogOptions,
    MotionOptions,
    OutputOptions,
    RepairOptions,
    StatusOptions,
)
from odofuse.declarations.sensors import (
    GRAPH_STREAM_OPTIONS,
    SENSOR_OPTIONS,
    STREAM_DEFAULTS,
    BearingOptions,
    CompassOptions,
    GpsOptions,
    GyroOptions,
    LoopClosureOptions,
    PluginSensorOptions,
    RangeBearingOptions,
    RangeOptions,
    SensorOptions,
    sensor_options,
    stream_kind,
)
from odofuse.options import markdown_table, render_docs

__all__ = [
    "BLOCK_OPTIONS",
    "CROSS_CHECK_MODES",
    "DEFAULT_INITIAL_SIGMA",
    "DEFAULT_LATE_WINDOW",
    "DOC_FILES",
    "ESTIMATOR_OPTIONS",
    "GRAPH_ESTIMATORS",
    "GRAPH_STREAM_OPTIONS",
    "INTEGRATORS",
    "ROBUST_DEFAULT_K",
    "ROBUST_KINDS",
    "RUN_OPTIONS",
    "SENSOR_OPTIONS",
    "SLAM_INITS",
    "STREAM_DEFAULTS",
    "BearingOptions",
    "CompassOptions",
    "CrossCheckOptions",
    "DeadReckoningOptions",
    "EkfOptions",
    "KalmanOptions",
    "EncoderOptions",
    "FilterOptions",
    "FreezeConvergence",
    "FreezeThresholds",
    "GpsOptions",
    "GraphOptions",
    "GyroOptions",
    "InitialOptions",
    "LogOptions",
    "LoopClosureOptions",
    "MotionOptions",
    "OutputOptions",
    "ParticleOptions",
    "PluginSensorOptions",
    "RangeBearingOptions",
    "RangeOptions",
    "RepairOptions",
    "SensorOptions",
    "StatusOptions",
    "UkfOptions",
    "UncheckedOptions",
    "catalogue",
    "doc_tables",
    "estimator_options",
    "estimator_options_class",
    "gate_probability",
    "main",
    "robust_loss",
    "sensor_options",
    "stream_kind",
]


#: The docs files whose ``<!-- options:NAME -->`` tables are generated.
DOC_FILES = (
    "docs/filters.md",
    "docs/formats.md",
    "docs/graph.md",
    "docs/trust.md",
    "docs/ros2.md",
)


def catalogue() -> dict[str, tuple[type, str]]:
    """Every declared block: name -> (class, dotted key prefix), for the docs and the CLI."""
    out = {name: (cls, name) for name, cls in BLOCK_OPTIONS.items()}
    for kind, cls in SENSOR_OPTIONS.items():
        out[f"sensors.{kind}"] = (cls, "sensors.<stream>")
    for stream, cls in GRAPH_STREAM_OPTIONS.items():
        out[f"sensors.{stream}"] = (cls, f"sensors.{stream}")
    for name, cls in ESTIMATOR_OPTIONS.items():
        if name in GRAPH_ESTIMATORS:
            continue  # one block for the three: "graph" below
        if cls is not UncheckedOptions and dataclasses.fields(cls):
            out[name] = (cls, f"options.{name}")
    out["graph"] = (GraphOptions, "options.<estimator>")
    freeze = "options.isam2.calibration_freeze"
    out["graph.freeze_convergence"] = (FreezeConvergence, freeze)
    out["graph.freeze_thresholds"] = (FreezeThresholds, freeze)
    for name, cls in RUN_OPTIONS.items():
        out[name] = (cls, f"options.{name}")
    return out


def doc_tables() -> dict[str, str]:
    """Marker name -> generated markdown table."""
    return {name: markdown_table(cls, prefix) for name, (cls, prefix) in catalogue().items()}


def main(argv: list[str] | None = None) -> int:
    """``python -m odofuse.declarations --write-docs [--check]``: regenerate docs tables."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m odofuse.declarations")
    p.add_argument("--write-docs", action="store_true", help="rewrite the tables in docs/*.md")
    p.add_argument("--check", action="store_true", help="exit 1 if a docs table is out of date")
    args = p.parse_args(argv)
    root = Path(__file__).resolve().parents[2]
    stale = []
    for rel in DOC_FILES:
        path = root / rel
        text = path.read_text(encoding="utf-8")
        new = render_docs(text, doc_tables())
        if new != text:
            stale.append(rel)
            if args.write_docs:
                path.write_text(new, encoding="utf-8")
    for rel in stale:
        print(f"{'rewrote' if args.write_docs else 'out of date'}: {rel}")
    return 1 if stale and args.check else 0
