"""Run-config validation: every error names the dotted key and the file."""

from __future__ import annotations

from pathlib import Path

import pytest

from odofuse.config import RunConfig, config_from_dict, load_config
from odofuse.declarations import (
    EkfOptions,
    EncoderOptions,
    GpsOptions,
    InitialOptions,
    MotionOptions,
)
from odofuse.errors import ConfigError

GOOD = """\
log: ../logs/square
robot:
  drive: differential
  wheel_radius: 0.04
  track_width: 0.235
  encoder: {ticks_per_rev: 979.2, rollover: 65536}
motion:
  integrator: exact
  k_r: 1.0e-4
  k_l: 1.0e-4
estimator: ekf
initial: {pose: [0.0, 0.0, 0.0], sigma: [0.1, 0.1, 0.05]}
sensors:
  gyro:      {sigma: 0.005}
  gps:       {sigma: 1.5, gate: 0.999}
  ranges:    {sigma: 0.3, gate: 0.999}
  landmarks: {sigma_range: 0.2, sigma_bearing: 0.02}
  compass:   {sigma: 0.05}
output: out/square
options:
  ekf: {late_window: 0.5}
"""


def write(tmp_path, text, name="run.yaml"):
    d = tmp_path / "configs"
    d.mkdir(exist_ok=True)
    p = d / name
    p.write_text(text)
    return p


def test_spec_example_loads(tmp_path):
    p = write(tmp_path, GOOD)
    c = load_config(p)
    assert isinstance(c, RunConfig)
    assert Path(c.log) == p.parent / "../logs/square"  # relative to the config file
    assert Path(c.output) == p.parent / "out/square"
    assert c.robot["encoder"] == EncoderOptions(ticks_per_rev=979.2, rollover=65536)
    assert c.robot["track_width"] == 0.235
    assert c.motion == MotionOptions(integrator="exact", k_r=1e-4, k_l=1e-4)
    assert c.estimator == "ekf"
    assert c.initial == InitialOptions(pose=(0.0, 0.0, 0.0), sigma=(0.1, 0.1, 0.05))
    assert c.sensors["gps"] == GpsOptions(model="gps", sigma=1.5, gate=0.999)
    # odometry_calibration auto: the example fuses GPS, ranges, compass, so it is on
    assert c.estimator_options() == EkfOptions(late_window=0.5, odometry_calibration=True)
    assert c.source == str(p)


def test_log_mapping_with_topics_and_builtin(tmp_path):
    c = config_from_dict(
        {"log": {"path": "run.bag", "topics": {"wheels": "/js"}}, "robot": {"drive": "increments"}},
        "x.yaml",
        tmp_path,
    )
    assert c.log == str(tmp_path / "run.bag")
    assert c.log_options == {"topics": {"wheels": "/js"}}
    c = config_from_dict({"log": "builtin:plaza1", "robot": {"drive": "increments"}})
    assert c.log == "builtin:plaza1" and c.estimator == "dead_reckoning"


def bad(tmp_path, text, key, match):
    p = write(tmp_path, text)
    with pytest.raises(ConfigError, match=match) as info:
        load_config(p)
    assert info.value.key == key
    assert info.value.file == str(p)
    assert str(p) in str(info.value)
    if key:
        assert f"'{key}'" in str(info.value)


@pytest.mark.parametrize(
    ("change", "key", "match"),
    [
        (("estimator: ekf", "estimator: ekf\ncolour: red"), "colour", "unknown key"),
        (("k_r: 1.0e-4", "k_r: lots"), "motion.k_r", "number"),
        (("k_r: 1.0e-4", "k_r: -1.0"), "motion.k_r", "negative"),
        (("integrator: exact", "integrator: magic"), "motion.integrator", "one of"),
        (("track_width: 0.235", "track_width: -0.2"), "robot.track_width", "positive"),
        (("track_width: 0.235", "track_widht: 0.235"), "robot.track_widht", "unknown"),
        (("  track_width: 0.235\n", ""), "robot.track_width", "missing"),
        (("drive: differential", "drive: hovercraft"), "robot.drive", "unknown drive"),
        (("ticks_per_rev: 979.2", "ticks_per_rev: 0"), "robot.encoder.ticks_per_rev", "positive"),
        (("rollover: 65536", "rollover: 65536, parity: odd"), "robot.encoder.parity", "unknown"),
        (("rollover: 65536", "rollover: 1.5"), "robot.encoder.rollover", "integer"),
        (("pose: [0.0, 0.0, 0.0]", "pose: [0.0, 0.0]"), "initial.pose", "3 elements"),
        (("sigma: [0.1, 0.1, 0.05]", "sigma: [0.1, x, 0.05]"), "initial.sigma[1]", "number"),
        (("sigma: 1.5, gate: 0.999", "sigma: 1.5, gate: 1.5"), "sensors.gps.gate", r"\(0, 1\)"),
        (("sigma: 0.005", "sigma: '0.005'"), "sensors.gyro.sigma", "number"),
        (("sigma: 0.005", "sigma: true"), "sensors.gyro.sigma", "number"),
        (("sigma: 0.05}", "sigma: -0.05}"), "sensors.compass.sigma", "positive"),
        (("  ekf: {late_window: 0.5}", "  ekf: 3"), "options.ekf", "mapping"),
        (("log: ../logs/square", "log: 42"), "log", "string"),
        (("log: ../logs/square\n", ""), "log", "missing"),
        (("estimator: ekf", "estimator: [ekf]"), "estimator", "string"),
        (("robot:\n  drive: differential\n", "robot:\n"), "robot.drive", "missing"),
    ],
)
def test_bad_values_name_the_key(tmp_path, change, key, match):
    old, new = change
    assert old in GOOD
    bad(tmp_path, GOOD.replace(old, new, 1), key, match)


def test_malformed_yaml_names_the_line(tmp_path):
    p = write(tmp_path, "log: x\nrobot:\n  drive: [differential\n  wheel_radius: 1\n")
    with pytest.raises(ConfigError, match=r"malformed YAML: line \d+") as info:
        load_config(p)
    assert str(p) in str(info.value)
    p = write(tmp_path, "log: x\n robot: 1\n")
    with pytest.raises(ConfigError, match="line 2"):
        load_config(p)


def test_empty_and_non_mapping(tmp_path):
    with pytest.raises(ConfigError, match="empty"):
        load_config(write(tmp_path, ""))
    with pytest.raises(ConfigError, match="mapping"):
        load_config(write(tmp_path, "- a\n- b\n"))
    with pytest.raises(ConfigError, match="mapping"):
        config_from_dict([1, 2], "x")


def test_missing_file_is_oserror(tmp_path):
    with pytest.raises(OSError):
        load_config(tmp_path / "missing.yaml")


def test_exponent_without_dot_is_a_number(tmp_path):
    # PyYAML's YAML 1.1 rules read "1e-4" as a string; we follow YAML 1.2.
    c = load_config(write(tmp_path, GOOD.replace("k_r: 1.0e-4", "k_r: 1e-4")))
    assert c.motion.k_r == 1e-4
    bad(tmp_path, GOOD.replace("k_r: 1.0e-4", "k_r: '1e-4'"), "motion.k_r", "number")


def test_motion_keys_must_fit_the_drive(tmp_path):
    inc = GOOD.replace("drive: differential", "drive: increments").replace(
        "  wheel_radius: 0.04\n  track_width: 0.235\n", ""
    )
    bad(tmp_path, inc, "motion.k_r", "left/right")
    two = GOOD.replace("k_r: 1.0e-4\n  k_l: 1.0e-4", "k: [1.0e-4, 1.0e-4, 1.0e-4]")
    bad(tmp_path, two, "motion.k", "one number per drive input")
