"""The compiled particle filter (``options.particle.compiled``) equals its numpy path.

Same seed, same draws: poses, covariances, weights' effects (resample counts, relative moves),
counts, calibration and findings to 1e-9, on simulated logs (gyro as a measurement, ranges,
GPS, compass; every integrator; odometry calibration; gyrodometry) and a Plaza1 slice; the
uncovered motion models fall back to the numpy propagation with the same result; ``on``
without numba is a one-line ConfigError; ``auto`` leaves numba unimported on a short run.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba")

from compiled_checks import SCENARIO, SLIP_SCENARIO  # noqa: E402
from compiled_checks import assert_same_run as _same  # noqa: E402
from graph_sim import excerpt, simulated_run  # noqa: E402

from odofuse.config import load_config  # noqa: E402
from odofuse.errors import ConfigError  # noqa: E402
from odofuse.estimators import compiled  # noqa: E402
from odofuse.estimators.compiled import particle as compiled_particle  # noqa: E402
from odofuse.estimators.particle import run as run_pf  # noqa: E402
from odofuse.io.loader import load_log_for  # noqa: E402
from odofuse.motion import motion_model_from_config  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
INTEGRATORS = ("euler", "rk2", "exact", "euler_end")


def _mode(cfg, mode):
    opts = dict(cfg.options)
    opts["particle"] = dataclasses.replace(cfg.estimator_options("particle"), compiled=mode)
    return dataclasses.replace(cfg, options=opts)


def _both(log, cfg):
    """``(compiled, numpy)`` results of the same seeded run."""
    return run_pf(log, _mode(cfg, "on")), run_pf(log, _mode(cfg, "off"))


def _sim(sensors, integrator="exact", seconds=20.0, **options):
    options = {"particles": 200, "seed": 3, **options}
    log, cfg = simulated_run(SCENARIO, 7, "particle", options)
    cfg = dataclasses.replace(
        cfg,
        sensors={s: o for s, o in cfg.sensors.items() if s in sensors},
        motion=dataclasses.replace(cfg.motion, integrator=integrator),
    )
    return excerpt(log, seconds), cfg


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_compiled_equals_numpy_with_a_gyro_ranges_gps_and_odometry_calibration(integrator):
    """Relative gyro updates, slip noise scales (robust odometry), ranges and GPS; the
    differential drive's calibration states; resampling happens."""
    log, cfg = _sim(("gyro", "ranges", "gps"), integrator, odometry_calibration=True)
    res, ref = _both(log, cfg)
    assert ref.extra["resamples"] > 0 and ref.extra["relative_moves"] > 100
    assert ref.used["ranges"] > 50 and ref.used["gps"] > 5
    _same(res, ref)


def test_compiled_equals_numpy_through_slip_bursts():
    """Robust odometry's factor in the filters' kernel (``ParticleBackend.slip_step``) on the
    compiled path, the reference's on the numpy path: the same slipping steps and run."""
    options = {"particles": 200, "seed": 3, "odometry_calibration": True}
    log, cfg = simulated_run(SLIP_SCENARIO, 3, "particle", options)
    res, ref = _both(excerpt(log, 25.0), cfg)
    assert ref.extra["slip_steps"] > 100
    _same(res, ref)


@pytest.mark.parametrize("sensors", [("ranges", "compass"), ("gps",)])
def test_compiled_equals_numpy_without_a_gyro(sensors):
    log, cfg = _sim(sensors, "rk2", resample_threshold=0.9)
    res, ref = _both(log, cfg)
    assert ref.extra["resamples"] > 0
    _same(res, ref)


def test_compiled_equals_numpy_with_gyrodometry():
    """The gyro's heading change in the prediction (``dtheta``, its own normal draws)."""
    log, cfg = _sim(("gyro", "ranges"))
    gyro = dataclasses.replace(cfg.sensors["gyro"], gyrodometry=True, threshold=1e-4)
    cfg = dataclasses.replace(cfg, sensors={**cfg.sensors, "gyro": gyro})
    res, ref = _both(log, cfg)
    assert ref.extra["gyrodometry_switches"] > 0
    _same(res, ref)


def _plaza1(seconds=300.0, motion=None):
    cfg = load_config(ROOT / "configs/plaza1-particle.yaml")
    opts = dict(cfg.options)
    opts["particle"] = dataclasses.replace(opts["particle"], particles=300)
    cfg = dataclasses.replace(cfg, options=opts)
    if motion:
        cfg = dataclasses.replace(cfg, motion=dataclasses.replace(cfg.motion, **motion))
    return excerpt(load_log_for(cfg), seconds), cfg


def test_compiled_equals_numpy_on_a_plaza1_slice():
    """The increments drive with its odometry calibration and range scale/offset states."""
    log, cfg = _plaza1()
    res, ref = _both(log, cfg)
    assert ref.extra["resamples"] > 5
    _same(res, ref)


def test_uncovered_motion_models_fall_back_to_the_numpy_propagation():
    """Thrun's quadratic terms (``alphas``) are not compiled: the numpy predict runs, the
    weighting and moments stay compiled, the result is the numpy path's."""
    log, cfg = _plaza1(120.0, {"alphas": (0.01, 0.001, 0.01, 0.001)})
    assert compiled_particle.motion_terms(motion_model_from_config(cfg), None) is None
    res, ref = _both(log, cfg)
    _same(res, ref)


def test_compiled_on_without_numba_is_a_config_error(monkeypatch):
    log, cfg = _sim(("gps",), seconds=2.0)
    monkeypatch.setitem(sys.modules, "numba", None)  # import numba -> ImportError
    monkeypatch.delitem(sys.modules, "odofuse.estimators.compiled.kernels", raising=False)
    assert compiled.load_kernels() is None
    with pytest.raises(ConfigError, match="compiled: on needs numba") as err:
        run_pf(log, _mode(cfg, "on"))
    assert "\n" not in str(err.value) and "options.particle.compiled" in str(err.value)
    auto = run_pf(log, _mode(cfg, "auto"))  # auto: the numpy path
    monkeypatch.undo()
    _same(run_pf(log, _mode(cfg, "on")), auto)


def test_auto_does_not_import_numba_for_a_short_run():
    code = (
        "import sys\n"
        "from graph_sim import excerpt, simulated_run\n"
        "from odofuse.estimators.compiled.particle import AUTO_MIN_WORK\n"
        "from odofuse.estimators.particle import run\n"
        f"log, cfg = simulated_run({SCENARIO!r}, 7, 'particle', {{'particles': 100}})\n"
        "log = excerpt(log, 5.0)\n"
        "assert 100 * sum(len(s) for s in log.streams.values()) < AUTO_MIN_WORK\n"
        "run(log, cfg)\n"
        "print('numba' in sys.modules)\n"
    )
    env = {"PYTHONPATH": f"{ROOT}:{ROOT / 'tests'}", "PATH": "/usr/bin:/bin"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    assert out.stdout.strip() == "False"


def test_auto_on_a_short_run_ignores_that_numba_is_loaded():
    """``auto`` decides by the run alone: a short run takes the numpy path even in a process
    that has imported numba (this one has), so ``odofuse run`` and an ``odofuse batch`` worker
    that ran a long log before give the same digits."""
    import numba  # noqa: F401

    log, cfg = _sim(("gyro", "ranges"), seconds=5.0, particles=50)
    assert 50 * sum(len(s) for s in log.streams.values()) < compiled_particle.AUTO_MIN_WORK
    auto, off = run_pf(log, _mode(cfg, "auto")), run_pf(log, _mode(cfg, "off"))
    assert np.array_equal(auto.trajectory.poses, off.trajectory.poses)
    assert np.array_equal(auto.trajectory.covariances, off.trajectory.covariances)
