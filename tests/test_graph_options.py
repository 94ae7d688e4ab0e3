"""The graph estimators' options on the declarations: the values are the ones parsed before.

Issue 9 moved ``options.<smoother|isam2|fixed_lag>`` from the graph package's own parser
(``odofuse.estimators.graph.options.parse_options``, deleted) to
:class:`odofuse.declarations.GraphOptions`. The expected values below were printed by that old
parser, on the base commit, for every packaged Plaza config (``configs/`` and
``odofuse/default_configs/``, each read by the three graph estimators) and for blocks that
use every key and every form of ``robust`` and ``calibration_freeze``. They are compared to
the letter, ``int`` and ``float`` told apart. A packaged config changed on purpose changes its
row here.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import pytest

from odofuse.config import RunConfig, load_config
from odofuse.declarations import GRAPH_ESTIMATORS, GraphOptions, catalogue
from odofuse.errors import ConfigError
from odofuse.options import explicit, to_mapping

ROOT = Path(__file__).resolve().parent.parent

#: What the old parser returned for an empty block and no sensors.
DEFAULTS = {
    "keyframe_dt": 1.0,
    "keyframe_ds": 0.0,
    "keyframe_dtheta": 0.0,
    "keyframe_every_step": False,
    "robust": {},
    "slam": False,
    "lag": 10.0,
    "max_iterations": 100,
    "relative_tolerance": 1e-06,
    "covariances": True,
    "slam_grid": 1.0,
    "known_landmark_sigma": 1e-06,
    "relinearize_threshold": 0.1,
    "relinearize_skip": 10,
    "partial_relinearization_check": True,  # new in issue 28 (GTSAM's default is off)
    "odometry_floor": 1e-08,
    "final_relinearizations": 3,
    "odometry_calibration": False,
    "calibration_freeze": None,
    "slam_init": "auto",
}
#: Keys added after the move (issue 10: robust odometry in the graph), with their defaults.
DEFAULTS.update({"slip": True, "slip_gate": 0.999})

_HUBER = ["huber", 1.345]
#: Packaged config, estimator -> the values that differ from DEFAULTS (absent: none differ).
PACKAGED = {
    "configs/plaza1-fixed_lag.yaml:fixed_lag": {
        "odometry_calibration": True,
        "robust": {"ranges": _HUBER},
    },
    "configs/plaza1-isam2.yaml:isam2": {
        "calibration_freeze": {
            "check_every": 10,
            "min_time": 0.0,
            "rel_change": 0.1,
            "window": 300.0,
        },
        "odometry_calibration": False,
        "robust": {"ranges": _HUBER},
    },
    "configs/plaza1-slam.yaml:smoother": {
        "robust": {"odometry": ["cauchy", 2.3849], "ranges": _HUBER},
        "slam": True,
    },
    "configs/plaza1-smoother.yaml:smoother": {
        "odometry_calibration": True,
        "robust": {"ranges": _HUBER},
    },
    "default_configs/plaza1-smoother.yaml:smoother": {
        "odometry_calibration": True,
        "robust": {"ranges": _HUBER},
    },
}
#: Issue 25's defaults, for a packaged config read by a graph estimator it has no block for
#: (the filter configs, or the smoother config read by isam2): the ranges (gate 0.999, no
#: loss of their own) get the gate's Tukey loss, k = sqrt(chi2_1(0.999)), and the increments
#: odometry is calibrated (``odometry_calibration: auto`` with an absolute sensor).
UNLISTED = {
    "odometry_calibration": True,
    "robust": {"ranges": ["tukey", 3.290526731491895]},
}
# the packaged copies of configs/ (`odofuse run --estimator NAME`) parse as their originals
PACKAGED.update(
    {
        "default_" + key: value
        for key, value in list(PACKAGED.items())
        if key.startswith("configs/")
        and (ROOT / "odofuse" / ("default_" + key.split(":")[0])).exists()
    }
)
PACKAGED_FILES = sorted((ROOT / "configs").glob("plaza1-*.yaml")) + sorted(
    (ROOT / "odofuse" / "default_configs").glob("plaza1-*.yaml")
)

_SENSORS = {
    "gps": {"sigma": 1.0},
    "loop_closures": {"robust": "cauchy"},
    "ranges": {"robust": "tukey", "sigma": 0.2},
}
_OWN = {"loop_closures": ["cauchy", 2.3849], "ranges": ["tukey", 4.6851]}
#: (estimator, sensors, block, values that differ from DEFAULTS), printed by the old parser.
CASES = [
    (
        "smoother",
        {},
        {
            "covariances": False,
            "final_relinearizations": 1,
            "keyframe_ds": 2,
            "keyframe_dt": 0.5,
            "keyframe_dtheta": 0.1,
            "keyframe_every_step": True,
            "known_landmark_sigma": 0.01,
            "lag": 5,
            "max_iterations": 7,
            "odometry_calibration": [0.1, 0.2, 0.01],
            "odometry_floor": 0.0,
            "relative_tolerance": 0.0001,
            "relinearize_skip": 2,
            "relinearize_threshold": 0.05,
            "slam": True,
            "slam_grid": 0.5,
            "slam_init": "dead_reckoning",
        },
        {
            "covariances": False,
            "final_relinearizations": 1,
            "keyframe_ds": 2.0,
            "keyframe_dt": 0.5,
            "keyframe_dtheta": 0.1,
            "keyframe_every_step": True,
            "known_landmark_sigma": 0.01,
            "lag": 5.0,
            "max_iterations": 7,
            "odometry_calibration": [0.1, 0.2, 0.01],
            "odometry_floor": 0.0,
            "relative_tolerance": 0.0001,
            "relinearize_skip": 2,
            "relinearize_threshold": 0.05,
            "slam": True,
            "slam_grid": 0.5,
            "slam_init": "dead_reckoning",
        },
    ),
    ("smoother", _SENSORS, {}, {"robust": _OWN}),
    (
        "smoother",
        _SENSORS,
        {"robust": "huber"},
        {"robust": {"gps": _HUBER, "loop_closures": _HUBER, "ranges": _HUBER}},
    ),
    (
        "smoother",
        _SENSORS,
        {"robust": {"k": 2, "type": "cauchy"}},
        {
            "robust": {
                "gps": ["cauchy", 2.0],
                "loop_closures": ["cauchy", 2.0],
                "ranges": ["cauchy", 2.0],
            }
        },
    ),
    (
        "smoother",
        _SENSORS,
        {"robust": {}},
        {"robust": {"gps": _HUBER, "loop_closures": _HUBER, "ranges": _HUBER}},
    ),
    (
        "smoother",
        _SENSORS,
        {"robust": None},
        {
            "robust": {
                "gps": ["none", 0.0],
                "loop_closures": ["none", 0.0],
                "ranges": ["none", 0.0],
            }
        },
    ),
    (
        "smoother",
        _SENSORS,
        {"robust": {"gps": "huber", "odometry": {"type": "tukey"}, "wheels": "none"}},
        {
            "robust": {
                "gps": _HUBER,
                "loop_closures": ["cauchy", 2.3849],
                "odometry": ["tukey", 4.6851],
                "ranges": ["tukey", 4.6851],
                "wheels": ["none", 0.0],
            }
        },
    ),
    (
        "fixed_lag",
        _SENSORS,
        {"lag": 20.0, "robust": {"ranges": {"k": 3.0}}},
        {"lag": 20.0, "robust": {"loop_closures": ["cauchy", 2.3849], "ranges": ["huber", 3.0]}},
    ),
    (
        "isam2",
        _SENSORS,
        {
            "calibration_freeze": {
                "check_every": 5,
                "sigma": {"range_offset": 0.1, "range_scale": 0.01},
            }
        },
        {
            "calibration_freeze": {
                "check_every": 5,
                "sigma": {"range_offset": 0.1, "range_scale": 0.01},
            },
            "robust": _OWN,
        },
    ),
    (
        "isam2",
        _SENSORS,
        {"calibration_freeze": {"min_time": 100, "rel_change": 0.05, "window": 60}},
        {
            "calibration_freeze": {
                "check_every": 10,
                "min_time": 100.0,
                "rel_change": 0.05,
                "window": 60.0,
            },
            "robust": _OWN,
        },
    ),
    (
        "isam2",
        {},
        {"odometry_calibration": False, "slam_init": "incremental"},
        {"slam_init": "incremental"},
    ),
]


def _plain(v):
    if isinstance(v, Mapping):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    return v


def _exact(values: dict) -> str:
    """``values`` as text in which ``2`` and ``2.0`` differ and mapping order does not count."""
    return json.dumps(_plain(values), sort_keys=True)


def _values(opts: GraphOptions) -> dict:
    return {name: _plain(v) for name, v in to_mapping(opts).items()}


def test_defaults_are_the_old_ones():
    assert GraphOptions().robust is None  # the block says nothing: the sensors' own losses
    assert _exact(_values(GraphOptions().for_run("smoother", {}, "t.yaml"))) == _exact(DEFAULTS)


@pytest.mark.parametrize("path", PACKAGED_FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
@pytest.mark.parametrize("estimator", GRAPH_ESTIMATORS)
def test_packaged_configs_parse_to_the_old_values(path, estimator):
    cfg = load_config(path)
    expected = {
        **DEFAULTS,
        **PACKAGED.get(f"{path.parent.name}/{path.name}:{estimator}", UNLISTED),
    }
    assert _exact(_values(cfg.estimator_options(estimator))) == _exact(expected)


def _issue25(sensors: dict, block: dict, changed: dict) -> dict:
    """``changed`` with issue 25's defaults: a GPS with its gate and no loss from its block or
    the estimator's gets the gate's Tukey loss (k = sqrt(chi2_2(0.999))), and the odometry
    is calibrated (auto: GPS is absolute, the drive increments) unless the block says or slam."""
    out = dict(changed)
    if "gps" in sensors:
        out["robust"] = {"gps": ["tukey", 3.7169221888498383], **out.get("robust", {})}
        if "odometry_calibration" not in block and not block.get("slam"):
            out["odometry_calibration"] = True
    return out


@pytest.mark.parametrize(("estimator", "sensors", "block", "changed"), CASES)
def test_every_key_and_form_parses_to_the_old_values(estimator, sensors, block, changed):
    cfg = RunConfig(
        log="x",
        robot={"drive": "increments"},
        estimator=estimator,
        sensors=sensors,
        options={estimator: block},
        source="t.yaml",
    )
    opts = cfg.estimator_options(estimator)
    assert _exact(_values(opts)) == _exact({**DEFAULTS, **_issue25(sensors, block, changed)})
    assert explicit(opts) == frozenset(block)  # resolving keeps what the user wrote


def test_a_robust_stream_must_be_a_sensor_and_freezing_is_isam2_only():
    with pytest.raises(ConfigError) as exc:
        RunConfig(
            log="x",
            robot={"drive": "increments"},
            options={"smoother": {"robust": {"gps": "huber"}}},
            source="t.yaml",
        )
    assert exc.value.key == "options.smoother.robust.gps" and exc.value.file == "t.yaml"
    freeze = {"calibration_freeze": {"rel_change": 0.1, "window": 30}}
    with pytest.raises(ConfigError, match="only the isam2") as exc:
        RunConfig(log="x", robot={"drive": "increments"}, options={"fixed_lag": freeze})
    assert exc.value.key == "options.fixed_lag.calibration_freeze"


def test_the_graph_block_is_listed_and_documented():
    cls, prefix = catalogue()["graph"]
    assert cls is GraphOptions and prefix == "options.<estimator>"
    text = (ROOT / "docs" / "graph.md").read_text(encoding="utf-8")
    assert "| `options.<estimator>.calibration_freeze` |" in text
