"""The compiled offline core (numba) equals the pure-Python reference paths (issue 17 item 1).

Dead reckoning against :func:`odofuse.motion.dead_reckon` for linear and non-linear drives and
every integrator; the offline EKF against the streaming Localizer (filterpy backend) on seeded
simulated logs and a Plaza1 slice, including the gate decisions, counts and findings; the
fallback without numba; metrics.json of ``odofuse run`` on Plaza1 unchanged; and what an EKF
run imports.
"""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba")

from compiled_checks import (  # noqa: E402
    SCENARIO,
    SLIP_SCENARIO,
    live_from_config,
)
from compiled_checks import assert_same_run as _same  # noqa: E402
from graph_sim import excerpt, simulated_run  # noqa: E402

from odofuse.config import RunConfig, config_from_dict  # noqa: E402
from odofuse.estimators import compiled  # noqa: E402
from odofuse.estimators.assembly import run_with  # noqa: E402
from odofuse.estimators.compiled import ekf as compiled_ekf  # noqa: E402
from odofuse.estimators.compiled.dead_reckoning import dead_reckon  # noqa: E402
from odofuse.estimators.ekf import make_backend  # noqa: E402
from odofuse.motion import dead_reckon as dead_reckon_reference  # noqa: E402
from odofuse.motion import motion_model_from_config  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
INTEGRATORS = ("euler", "rk2", "exact", "euler_end")
DRIVES = [
    ("differential", {"wheel_radius": 0.05, "track_width": 0.3}, {"k_r": 2e-4, "k_l": 3e-4}),
    ("increments", {}, {"k": [1e-3, 1e-4], "k_theta_ds": 2e-5}),
    ("mecanum4", {"wheel_radius": 0.05, "half_length": 0.2, "half_width": 0.15}, {"k": 1e-4}),
    ("ackermann", {"wheel_radius": 0.3, "wheelbase": 2.5, "track_width": 1.5}, {"k": 1e-4}),
    ("twist", {}, {"k": [1e-3, 1e-4], "alphas": [0.01, 0.001, 0.01, 0.001]}),
]


def _inputs(model, n, seed):
    rng = np.random.default_rng(seed)
    names = model.drive.input_names
    U = rng.normal(0.0, 0.05, (n, len(names)))
    kinds = getattr(model.drive, "input_kinds", ())
    for j, kind in enumerate(kinds):
        if kind == "wheel":
            U[:, j] = 2.0 + rng.normal(0.0, 0.4, n)  # wheels roll forward, unevenly
        elif kind == "steer":
            U[:, j] = 0.3 * np.sin(np.arange(n) / 50.0)
    return U


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("drive,geometry,motion", DRIVES, ids=[d[0] for d in DRIVES])
def test_dead_reckoning_equals_the_reference(drive, geometry, motion, integrator):
    cfg = RunConfig(
        log="x",
        robot={"drive": drive, **geometry},
        motion={"integrator": integrator, "var_floor": 1e-9, **motion},
    )
    model = motion_model_from_config(cfg)
    U = _inputs(model, 3000, 1)
    pose0 = np.array([1.0, -2.0, 3.1])
    P0 = np.diag([0.01, 0.02, 0.003])
    ref_p, ref_c = dead_reckon_reference(model, pose0, P0, U)
    got_p, got_c = dead_reckon(model, pose0, P0, U, mode="on")
    np.testing.assert_allclose(got_p, ref_p, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got_c, ref_c, rtol=0, atol=1e-9)
    only, none = dead_reckon(model, pose0, P0, U, with_cov=False, mode="on")
    assert none is None
    np.testing.assert_allclose(only, ref_p, rtol=0, atol=1e-9)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_dead_reckoning_recurrence_equals_the_reference_on_long_runs_and_sharp_turns(integrator):
    """The pose-only kernel turns ``e^{i theta}`` by angle addition and polynomial trigonometry,
    re-anchored on ``math.cos``/``math.sin`` every ``_ANCHOR`` steps and on any half-turn of
    ``_POLY_BELOW`` or more: 10^5 steps (about 400 anchors), with one step in fifty a sharp
    turn (0.3-1.5 rad per step, either way) and the heading wrapping at +-pi many times."""
    from odofuse.estimators.compiled import kernels

    geometry = {"wheel_radius": 0.05, "track_width": 0.3}
    cfg = RunConfig(
        log="x",
        robot={"drive": "differential", **geometry},
        motion={"integrator": integrator, "var_floor": 1e-9, "k_r": 2e-4, "k_l": 3e-4},
    )
    model = motion_model_from_config(cfg)
    rng = np.random.default_rng(17)
    n = 100_000
    U = 2.0 + rng.normal(0.0, 0.4, (n, 2))
    sharp = rng.random(n) < 0.02
    turn = rng.uniform(0.3, 1.5, n) * rng.choice([-1.0, 1.0], n)  # rad per step
    U[sharp, 1] = U[sharp, 0] + turn[sharp] * 0.3 / 0.05
    half = 0.5 * 0.05 * (U[:, 1] - U[:, 0]) / 0.3
    assert np.any(np.abs(half) >= kernels._POLY_BELOW) and n > 100 * kernels._ANCHOR
    pose0, P0 = np.array([1.0, -2.0, 3.1]), np.diag([0.01, 0.02, 0.003])
    ref_p, ref_c = dead_reckon_reference(model, pose0, P0, U)
    got_p, got_c = dead_reckon(model, pose0, P0, U, mode="on")
    only, _ = dead_reckon(model, pose0, P0, U, with_cov=False, mode="on")
    assert np.ptp(np.unwrap(ref_p[:, 2])) > 20 * np.pi  # many wraps
    for got in (got_p, only):
        np.testing.assert_allclose(got[:, :2], ref_p[:, :2], rtol=0, atol=1e-9)
        dth = (got[:, 2] - ref_p[:, 2] + np.pi) % (2 * np.pi) - np.pi
        np.testing.assert_allclose(dth, 0.0, rtol=0, atol=1e-9)
    # The covariance reaches 1e6 m^2 here, and its off-diagonal entries are differences of
    # large terms: to 1e-9 of each step's trace (the kernel before the recurrence, three libm
    # calls a step, was as far from the reference: 3.7e-7 relative on one cross term).
    scale = np.trace(ref_c, axis1=1, axis2=2)[:, None, None]
    assert np.all(np.abs(got_c - ref_c) <= 1e-9 * scale)


def test_dead_reckoning_auto_on_a_short_log_ignores_that_numba_is_loaded():
    """``auto`` decides by the log alone: below ``AUTO_MIN_STEPS`` the numpy path runs even in
    a process that has imported numba (this one has), bit for bit as ``compiled: off``."""
    import numba  # noqa: F401

    from odofuse.estimators.compiled.dead_reckoning import AUTO_MIN_STEPS

    cfg = RunConfig(
        log="x",
        robot={"drive": "differential", "wheel_radius": 0.05, "track_width": 0.3},
        motion={"integrator": "exact", "k_r": 2e-4, "k_l": 3e-4},
    )
    model = motion_model_from_config(cfg)
    U = _inputs(model, 5000, 2)
    assert len(U) < AUTO_MIN_STEPS
    pose0, P0 = np.zeros(3), np.diag([1e-4, 1e-4, 1e-5])
    for a, b in zip(
        dead_reckon(model, pose0, P0, U, mode="auto"),
        dead_reckon(model, pose0, P0, U, mode="off"),
        strict=True,
    ):
        assert np.array_equal(a, b)


def test_half_turn_polynomials_equal_libm():
    """``_sinc_cos``: Taylor polynomials of ``sin(h)/h`` and ``cos(h)`` within 2 ulp of libm
    over their whole range ``|h| < _POLY_BELOW``."""
    from odofuse.estimators.compiled import kernels

    for h in np.linspace(-kernels._POLY_BELOW, kernels._POLY_BELOW, 2001)[1:-1]:
        sinc, c = kernels._sinc_cos(h)
        assert abs(sinc * h - np.sin(h)) <= 2 * np.spacing(abs(np.sin(h))) + 1e-300
        assert abs(c - np.cos(h)) <= 2 * np.spacing(np.cos(h))


def _python(log, cfg):
    return run_with(log, cfg, "ekf", make_backend)


@pytest.mark.parametrize("odo_cal", [False, True])
@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("sensors", [("ranges", "gps", "compass", "gyro"), ("ranges",)])
def test_offline_ekf_equals_the_python_path_on_a_simulated_log(odo_cal, integrator, sensors):
    options = {"odometry_calibration": odo_cal, "slip": False, "compiled": "on"}
    log, cfg = simulated_run(SCENARIO, 3, "ekf", options)
    cfg = dataclasses.replace(
        cfg,
        sensors={s: o for s, o in cfg.sensors.items() if s in sensors},
        motion=dataclasses.replace(cfg.motion, integrator=integrator),
    )
    res = compiled_ekf.run(log, cfg)
    assert res is not None, "this run is covered by the compiled core"
    ref = _python(log, cfg)
    assert sum(ref.used.values()) > 50
    _same(res, ref)


def test_gate_rejections_are_the_same_decisions():
    """A tight gate rejects many readings: the compiled path rejects the same ones."""
    log, cfg = simulated_run(SCENARIO, 4, "ekf", {"slip": False, "recovery": False})
    sensors = {s: dataclasses.replace(o, gate=0.6) for s, o in cfg.sensors.items()}
    cfg = dataclasses.replace(cfg, sensors=sensors)
    res, ref = compiled_ekf.run(log, cfg), _python(log, cfg)
    assert res is not None and sum(ref.rejected.values()) > 20
    _same(res, ref)


def test_uncovered_runs_fall_back_to_python():
    """Gyrodometry (the gyro's heading change replacing the wheels') is not compiled: the
    EKF's ``run`` then is the Python path's."""
    from odofuse.estimators.ekf import run as run_ekf

    log, cfg = simulated_run(SCENARIO, 3, "ekf", {"compiled": "on"})
    gyro = dataclasses.replace(cfg.sensors["gyro"], gyrodometry=True, threshold=0.01)
    cfg = dataclasses.replace(cfg, sensors={**cfg.sensors, "gyro": gyro})
    assert compiled_ekf.run(log, cfg) is None
    _same(run_ekf(log, cfg), _python(log, cfg))


@pytest.mark.parametrize("odo_cal", [False, True])
def test_robust_odometry_equals_the_python_path_through_slip_bursts(odo_cal):
    """Robust odometry (on by default with a gyro) in the kernel (``kernels.step_slip``):
    the same widened steps in the same runs, the same ``slip``, ``slip_run`` and
    ``learning`` record, through two slip bursts and a bump."""
    options = {"odometry_calibration": odo_cal, "compiled": "on"}
    log, cfg = simulated_run(SLIP_SCENARIO, 3, "ekf", options)
    res = compiled_ekf.run(log, cfg)
    assert res is not None, "this run is covered by the compiled core"
    ref = _python(log, cfg)
    assert ref.extra["slip_steps"] > 100
    assert [f.t_start for f in ref.findings if f.check == "slip_run"] == [pytest.approx(8.04)]
    _same(res, ref)


def test_lat_lon_fixes_are_compiled_through_the_models_conversion():
    """GPS rows of ``lat``, ``lon`` with a ``datum`` (a NavSatFix stream) are converted by
    ``GpsPosition.z`` row by row and run in the kernel: equal to the Python path."""
    import pymap3d

    from odofuse.io.log import Stream

    log, cfg = simulated_run(SCENARIO, 3, "ekf", {"compiled": "on"})
    gps = log.streams["gps"]
    datum = (45.0, 9.0, 120.0)
    lat, lon, _ = pymap3d.enu2geodetic(gps["x"], gps["y"], datum[2], *datum)
    rows = Stream("gps", gps.source, gps.t, ("lat", "lon"), np.column_stack([lat, lon]))
    log = dataclasses.replace(log, streams={**log.streams, "gps": rows})
    cfg = dataclasses.replace(
        cfg, sensors={**cfg.sensors, "gps": dataclasses.replace(cfg.sensors["gps"], datum=datum)}
    )
    res = compiled_ekf.run(log, cfg)
    assert res is not None, "lat/lon fixes with a datum are covered by the compiled core"
    ref = _python(log, cfg)
    assert ref.used["gps"] > 50
    _same(res, ref)


def test_held_rates_of_every_step_equal_the_localizers():
    """``kernels.held_rate_steps`` (the offline run's gyro heading change of each step) is
    ``history.held_rate_integral`` step by step: samples between, on and outside the step
    ends, the first one after some steps (NaN there), several in one step, none in others."""
    from odofuse.estimators.compiled import load_kernels
    from odofuse.estimators.history import held_rate_integral

    rng = np.random.default_rng(8)
    tt = np.cumsum(rng.uniform(0.0, 0.04, 400))
    ts = np.sort(np.concatenate([rng.uniform(0.3, tt[-1] + 1.0, 300), tt[[40, 41, 200]]]))
    ws = rng.normal(0.0, 0.5, ts.size)
    out = np.empty(tt.size - 1)
    load_kernels().held_rate_steps(ts, ws, tt, out)
    samples = list(zip(ts.tolist(), ws.tolist(), strict=True))
    ref = [held_rate_integral(samples, a, b) for a, b in zip(tt[:-1], tt[1:], strict=True)]
    assert np.isnan(out[0]) and ref[0] is None
    np.testing.assert_array_equal(out, [np.nan if r is None else r for r in ref])


def test_live_ekf_with_robust_odometry_equals_odofuse_run_bit_for_bit():
    """A live EKF with a gyro computes robust odometry in the offline run's kernel
    (``KernelEkfBackend.slip_step``): bit for bit, also through replays of GPS fixes 0.3 s
    late."""
    log, cfg = simulated_run(SLIP_SCENARIO, 3, "ekf", {"late_window": 0.5})
    log = excerpt(log, 32.0)
    offline = compiled_ekf.run(log, cfg)
    assert offline is not None and offline.extra["slip_steps"] > 100
    loc = live_from_config(log, cfg, make_backend, 0.3)
    assert type(loc.backend).__name__ == "KernelEkfBackend"
    online = loc.result()
    np.testing.assert_array_equal(online.trajectory.poses, offline.trajectory.poses)
    np.testing.assert_array_equal(online.trajectory.covariances, offline.trajectory.covariances)
    assert online.extra["slip_steps"] == offline.extra["slip_steps"]
    assert online.used == offline.used and online.rejected == offline.rejected


def test_without_numba_the_fallback_gives_the_same_result(monkeypatch):
    from odofuse.estimators.dead_reckoning import run as run_dr
    from odofuse.estimators.ekf import run as run_ekf

    log, cfg = simulated_run(SCENARIO, 3, "ekf", {"slip": False})
    with_numba = run_ekf(log, cfg)
    dr_cfg = dataclasses.replace(cfg, estimator="dead_reckoning")
    dr_numba = run_dr(log, dr_cfg)
    monkeypatch.setitem(sys.modules, "numba", None)  # import numba -> ImportError
    monkeypatch.delitem(sys.modules, "odofuse.estimators.compiled.kernels", raising=False)
    assert compiled.load_kernels() is None
    assert compiled_ekf.run(log, cfg) is None
    _same(run_ekf(log, cfg), with_numba)
    dr_py = run_dr(log, dr_cfg)
    np.testing.assert_allclose(dr_py.trajectory.poses, dr_numba.trajectory.poses, atol=1e-9)
    np.testing.assert_allclose(
        dr_py.trajectory.covariances, dr_numba.trajectory.covariances, atol=1e-9
    )
    from odofuse.errors import ConfigError

    with pytest.raises(ConfigError, match="needs numba"):
        compiled.enabled("on", "options.ekf.compiled")


def _plaza_config():
    from odofuse.config import load_config

    return load_config(ROOT / "odofuse" / "default_configs" / "plaza1-ekf.yaml")


def test_plaza1_slice_equals_the_python_path():
    from odofuse.io.builtin import load_builtin

    log = excerpt(load_builtin("builtin:plaza1"), 600.0)
    cfg = _plaza_config()
    for odo_cal in (True, False):
        opts = dataclasses.replace(cfg.estimator_options("ekf"), odometry_calibration=odo_cal)
        c = dataclasses.replace(cfg, options={**cfg.options, "ekf": opts})
        res = compiled_ekf.run(log, c)
        assert res is not None
        ref = _python(log, c)
        assert ref.used["ranges"] > 100
        _same(res, ref)


def _metrics(tmp_path, mode):
    text = (ROOT / "odofuse" / "default_configs" / "plaza1-ekf.yaml").read_text()
    text = text.replace("  ekf:\n", f"  ekf:\n    compiled: {mode}\n", 1)
    (tmp_path / f"{mode}.yaml").write_text(text)
    out = tmp_path / f"out-{mode}"
    env = {"PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"}
    cmd = [sys.executable, "-m", "odofuse", "run", str(tmp_path / f"{mode}.yaml"), "-o", str(out)]
    run = subprocess.run(cmd, check=True, env=env, cwd=tmp_path, capture_output=True, text=True)
    m = json.loads((out / "metrics.json").read_text())
    for key in ("runtime_s", "config"):
        m.pop(key)
    # The summary table without its wall-time columns (``runtime [s]`` and, since issue 30
    # point 8, ``2nd opinion [s]``, the cross-check's smoother run): every other cell, the
    # figures and the status, is compared.
    head, *rows = run.stdout.splitlines()[:2]
    columns = re.split(r"\s{2,}", head.strip())
    timed = {i for i, c in enumerate(columns) if c.endswith("[s]")}
    assert columns[0] == "estimator" and columns[-1] == "status" and timed, columns
    table = [head]
    for line in rows:
        cells = line.split()
        assert len(cells) == len(columns), (columns, line)
        table.append(" ".join(c for i, c in enumerate(cells) if i not in timed))
    return m, table


def _close(a, b, where=""):
    """Equal structure; integers, strings and flags identical; floats to 1e-9 relative."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _close(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12), where
    else:
        assert a == b and type(a) is type(b), where


@pytest.mark.slow  # two odofuse run subprocesses on Plaza1 (compiled on and off): 17 s
def test_plaza1_metrics_json_unchanged_to_the_printed_digit(tmp_path):
    """Counts, findings and status identical; every figure the run prints identical (the
    summary table without its runtime column); metrics.json floats to 1e-9 relative."""
    (on, table_on), (off, table_off) = _metrics(tmp_path, "on"), _metrics(tmp_path, "off")
    assert table_on == table_off
    # Counts identical; the sensors' minimal detectable errors are figures (_close below).
    counts = {n: (v["used"], v["rejected"]) for n, v in on["sensors"].items()}
    assert counts == {n: (v["used"], v["rejected"]) for n, v in off["sensors"].items()}
    # Findings identical to the printed digit (their figures, floats, in _close below).
    said = [(f["check"], f["sensor"], f["degrades"], f["message"]) for f in on["findings"]]
    assert said == [(f["check"], f["sensor"], f["degrades"], f["message"]) for f in off["findings"]]
    assert on["status"] == off["status"] and on["warnings"] == off["warnings"]
    _close(on, off)


def test_an_ekf_run_imports_only_what_it_needs(tmp_path):
    """No scipy.stats, pyplot, gtsam, dask or filterpy for a (compiled) EKF run on Plaza1."""
    code = (
        "import sys\n"
        "from odofuse.config import load_config\n"
        "from odofuse.estimators import run_estimator\n"
        "from odofuse.io.loader import load_log_for\n"
        f"cfg = load_config({str(ROOT / 'odofuse/default_configs/plaza1-ekf.yaml')!r})\n"
        "run_estimator('ekf', load_log_for(cfg), cfg)\n"
        "bad = ['scipy.stats', 'matplotlib.pyplot', 'gtsam', 'dask', 'filterpy']\n"
        "print([m for m in bad if m in sys.modules])\n"
    )
    env = {"PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_chi2_quantiles_equal_scipy_stats():
    from scipy.stats import chi2 as reference

    from odofuse import chi2

    for p in (1e-6, 0.05, 0.5, 0.999, 1 - 1e-9):
        for k in (1, 2, 3, 40, 100):
            assert chi2.ppf(p, k) == reference.ppf(p, k)
    np.testing.assert_array_equal(chi2.ppf([0.1, 0.9], 3), reference.ppf([0.1, 0.9], 3))


def test_config_accepts_the_compiled_option():
    cfg = config_from_dict(
        {
            "log": "x",
            "robot": {"drive": "increments"},
            "estimator": "ekf",
            "options": {"ekf": {"compiled": "off"}, "dead_reckoning": {"compiled": "on"}},
        }
    )
    assert cfg.estimator_options("ekf").compiled == "off"
    assert cfg.estimator_options("dead_reckoning").compiled == "on"
    with pytest.raises(ValueError, match="compiled"):
        config_from_dict(
            {"log": "x", "robot": {"drive": "increments"}, "options": {"ekf": {"compiled": "x"}}}
        )


def test_stream_kind_codes_agree_with_the_kernels():
    from odofuse.estimators.compiled import kernels

    codes = (compiled_ekf.RANGE, compiled_ekf.GPS, compiled_ekf.COMPASS, compiled_ekf.GYRO)
    assert codes == (kernels.RANGE, kernels.GPS, kernels.COMPASS, kernels.GYRO)


class _Terminal:
    """A standard error that says it is a terminal, and keeps what is written to it."""

    def __init__(self, tty=True):
        self.tty, self.text = tty, ""

    def isatty(self):
        return self.tty

    def write(self, s):
        self.text += s

    def flush(self):
        pass


def test_a_one_time_compile_is_announced_on_a_terminal_only(monkeypatch):
    from odofuse.estimators import compiled

    k = compiled.load_kernels()
    if k is None:
        pytest.skip("numba not installed")
    monkeypatch.setattr(compiled, "_announced", set())
    monkeypatch.setattr(compiled, "cold", lambda dispatcher: True)  # an empty numba cache
    piped = _Terminal(tty=False)
    assert not compiled.announce(k, "options.ekf.compiled", piped) and piped.text == ""
    term = _Terminal()
    assert compiled.announce(k, "options.ekf.compiled", term)
    assert term.text.startswith("odofuse: compiling the numba kernels once")
    assert not compiled.announce(k, "options.ukf.compiled", term)  # once per process
    monkeypatch.setattr(compiled, "_announced", set())
    monkeypatch.setattr(compiled, "cold", lambda dispatcher: False)  # the cache has them
    assert not compiled.announce(k, "options.ukf.compiled", _Terminal())


def test_the_cold_cache_test_reads_numbas_index():
    from odofuse.estimators import compiled

    k = compiled.load_kernels()
    if k is None:
        pytest.skip("numba not installed")
    k.pf_mean(np.zeros((2, 3)), np.full(2, 0.5), np.array([2]), np.empty(3))  # cached now
    assert compiled.cold(k.pf_mean) is False
    assert compiled.cold(object()) is False  # not a dispatcher: cannot tell, no message
