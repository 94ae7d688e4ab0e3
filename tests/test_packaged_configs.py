"""Every packaged config loads, and the Plaza1 configs share one set of numbers."""

from pathlib import Path

import pytest

from odofuse.config import load_config

ROOT = Path(__file__).resolve().parent.parent
PLAZA = sorted((ROOT / "configs").glob("plaza1-*.yaml")) + sorted(
    (ROOT / "odofuse" / "default_configs").glob("plaza1-*.yaml")
)
# Configs that keep their own, tighter numbers (docs/graph.md says why).
OWN_NUMBERS = {"plaza1-slam.yaml"}


@pytest.mark.parametrize("path", PLAZA, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_plaza1_config_loads_and_shares_the_filters_numbers(path):
    cfg = load_config(path)
    assert cfg.log == "builtin:plaza1"
    if path.name in OWN_NUMBERS:
        return
    ekf = load_config(ROOT / "configs" / "plaza1-ekf.yaml")
    assert cfg.robot == ekf.robot
    assert cfg.motion == ekf.motion
    if cfg.estimator != "dead_reckoning":
        assert cfg.initial == ekf.initial
        assert cfg.sensors == ekf.sensors


def test_default_configs_are_the_repository_configs():
    # odofuse run (no CONFIG) must reproduce configs/plaza1-<estimator>.yaml
    for default in (ROOT / "odofuse" / "default_configs").glob("plaza1-*.yaml"):
        repo = ROOT / "configs" / default.name
        if repo.exists():
            a, b = load_config(default), load_config(repo)
            assert (a.robot, a.motion, a.estimator, a.initial, a.sensors, a.options) == (
                b.robot,
                b.motion,
                b.estimator,
                b.initial,
                b.sensors,
                b.options,
            )
