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


# run configs (sim-*.yaml are scenarios for `odofuse simulate`)
CONFIGS = [p for p in sorted((ROOT / "configs").glob("*.yaml")) if not p.name.startswith("sim-")]


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_every_config_loads_and_says_how_it_was_made(path):
    load_config(path)
    head = path.read_text().split("\nlog:")[0]
    assert head.startswith("#")  # a header comment
    if path.name.startswith("handtuned-"):  # a reference, never a default (docs/tune.md)
        assert head.startswith("# REFERENCE") and "ground truth" in head.lower()
    if path.name.startswith("tuned-"):
        assert "odofuse tune" in head and "ground truth was not read" in head


@pytest.mark.parametrize("estimator", ["ekf", "ukf"])
def test_plaza1_filter_config_on_plaza2_within_1_3x_of_the_plaza2_reference(estimator):
    # issue 11's judge: the one-config-per-robot file, only log: changed, against the config
    # tuned on Plaza2 with its ground truth (measured 1.15x for both, docs/tune.md)
    import dataclasses

    from odofuse.estimators import run_estimator
    from odofuse.evaluation import metrics
    from odofuse.io.loader import load_log

    log = load_log("builtin:plaza2")
    cfg = load_config(ROOT / "configs" / f"plaza1-{estimator}.yaml")
    ref = load_config(ROOT / "configs" / f"handtuned-plaza2-{estimator}.yaml")
    one = metrics(run_estimator(estimator, log, dataclasses.replace(cfg, log=ref.log)), log)
    best = metrics(run_estimator(estimator, log, ref), log)
    assert best["ate_rmse_m"] < 0.29  # the reference's own figure (0.2855 / 0.2852 m)
    assert one["ate_rmse_m"] <= 1.3 * best["ate_rmse_m"]
    assert 1.0 <= one["nees_position_mean"] <= 4.0
