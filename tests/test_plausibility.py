"""Plausibility of loaded logs (issue 16 item 3, :mod:`odofuse.io.plausibility`).

Each check gets a log that parses but cannot be what the config says (a reproduction from the
issue), and must end in a one-line error naming file, row and column, or a ``warnings`` line
in ``metrics.json``; the clean log of the same drive loads with no finding.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from odofuse.cli import main
from odofuse.config import load_config
from odofuse.errors import InputError
from odofuse.io.loader import load_log_for

R, B, TPR = 0.1, 0.5, 4096  # wheel radius (m), track (m), ticks per wheel revolution
DT, V, W = 0.02, 0.5, 0.2  # 50 Hz; 0.5 m/s, 0.2 rad/s


def _truth(n):
    t = 1.0 + DT * np.arange(n)
    th = W * (t - t[0])
    x = (V / W) * np.sin(th)
    y = (V / W) * (1.0 - np.cos(th))
    return t, x, y, th


def _wheels_log(folder, n=1500, ticks=True, modulus=None, gap=None, gps=None, gyro=None):
    """A differential-drive log (wheels.csv in ticks or rad) driving an arc, exact."""
    folder.mkdir(parents=True, exist_ok=True)
    t, x, y, th = _truth(n)
    s = V * (t - t[0])
    phi_r = (s + 0.5 * B * th) / R
    phi_l = (s - 0.5 * B * th) / R
    cols = np.column_stack([phi_l, phi_r])
    if ticks:
        cols = np.round(cols * TPR / (2 * math.pi))
        if modulus is not None:
            cols = np.mod(cols, modulus)
    keep = np.ones(n, dtype=bool)
    if gap is not None:
        keep[gap[0] : gap[1]] = False
    lines = [
        f"{float(t[k])!r},{float(cols[k, 0])!r},{float(cols[k, 1])!r}" for k in range(n) if keep[k]
    ]
    (folder / "wheels.csv").write_text("t,left,right\n" + "\n".join(lines) + "\n")
    if gps is not None:
        (folder / "gps.csv").write_text(gps(t, x, y))
    if gyro is not None:
        (folder / "gyro.csv").write_text(gyro(t))
    return folder


def _config(tmp_path, log="log", encoder="{ticks_per_rev: 4096, rollover: 65536}", extra=""):
    enc = f"  encoder: {encoder}\n" if encoder else ""
    text = (
        f"log: {log}\nrobot:\n  drive: differential\n  wheel_radius: {R}\n"
        f"  track_width: {B}\n{enc}estimator: dead_reckoning\n"
        "initial: {pose: [0.0, 0.0, 0.0], sigma: [0.01, 0.01, 0.01]}\noutput: out\n"
    )
    path = tmp_path / "run.yaml"
    path.write_text(text + extra)
    return path


def _load(tmp_path, **kw):
    return load_log_for(load_config(_config(tmp_path, **kw)))


def _error(tmp_path, needles, **kw):
    with pytest.raises(InputError) as err:
        _load(tmp_path, **kw)
    text = str(err.value)
    assert "\n" not in text and len(text) < 400, text
    for needle in needles:
        assert needle in text, text
    return err.value


def test_a_clean_log_has_no_finding(tmp_path):
    def gps(t, x, y):
        return "t,x,y\n" + "\n".join(
            f"{float(t[k])!r},{float(x[k])!r},{float(y[k])!r}" for k in range(0, len(t), 50)
        )

    def gyro(t):
        return "t,wz\n" + "\n".join(f"{float(v)!r},{W}" for v in t[::5])

    _wheels_log(tmp_path / "log", gps=gps, gyro=gyro)
    log = _load(tmp_path)
    assert log.findings == () and len(log.streams["wheels"]) == 1500


# -------------------------------------------------------------------------------- speed
def test_one_impossible_odometry_row_is_an_error_naming_file_and_row(tmp_path, capsys):
    # Issue 16: one ds = 1e6 row in Plaza1's odometry gave RMSE 999,482 m and status ok.
    folder = tmp_path / "log"
    folder.mkdir()
    rows = [f"{float(1.0 + 0.1 * k)!r},0.05,0.01" for k in range(100)]
    rows[40] = f"{float(1.0 + 0.1 * 40)!r},1e6,0.01"
    (folder / "odometry.csv").write_text("t,ds,dtheta\n" + "\n".join(rows) + "\n")
    cfg = tmp_path / "run.yaml"
    cfg.write_text("log: log\nrobot: {drive: increments}\nestimator: ekf\noutput: out\n")
    assert main(["run", str(cfg)]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in ("odometry.csv", "row 42", "log.max_speed", "1e+07 m/s"):
        assert needle in err, err
    assert not (tmp_path / "out").exists()
    # The limit is configurable: a (silly) 1e8 m/s robot takes the row.
    cfg.write_text("log: {path: log, max_speed: 1.0e+8}\nrobot: {drive: increments}\noutput: out\n")
    log = load_log_for(load_config(cfg))
    assert log.streams["odometry"]["ds"][40] == 1e6


def test_ticks_read_as_radians_are_an_error(tmp_path):
    # Issue 16: ticks read as radians when the encoder block is missing (5.85 m, ok).
    _wheels_log(tmp_path / "log")
    _error(tmp_path, ["wheels.csv", "ticks read as radians", "max_speed"], encoder=None)


def test_counter_wrapping_below_the_configured_rollover_is_an_error(tmp_path):
    # Issue 16: a counter wrapping at 4,096 while the config says 65,536 (7.18 m, ok).
    _wheels_log(tmp_path / "log", modulus=4096)
    exc = _error(tmp_path, ["wheels.csv", "log.max_yaw_rate", "rollover"])
    # the first wrap: the right wheel passes 4096 ticks first
    t, *_ = _truth(1500)
    phi_r = (V * (t - t[0]) + 0.5 * B * W * (t - t[0])) / R
    first = int(np.argmax(np.round(phi_r * TPR / (2 * math.pi)) >= 4096))
    assert exc.row == first + 2
    # with the right rollover the same data unwraps and loads
    log = _load(tmp_path, encoder="{ticks_per_rev: 4096, rollover: 4096}")
    assert log.repairs["wheels.rollover_unwraps"] > 0 and log.findings == ()


# ------------------------------------------------------------------------- counter gaps
def test_rollover_of_one_state_is_an_error_naming_the_column(tmp_path):
    # Issue 16: `rollover: 1` turned every step into zero motion and the run said ok.
    _wheels_log(tmp_path / "log")
    exc = _error(
        tmp_path,
        ["wheels.csv", "row 3", "wraps at 1499 of 1499 steps", "robot.encoder.rollover"],
        encoder="{ticks_per_rev: 4096, rollover: 1}",
    )
    assert exc.column == "left"


def test_a_counter_wrapping_every_other_row_still_loads(tmp_path):
    # The bound of the check above: a counter of 16 states moving 7 ticks per row (less than
    # half its range) wraps at most every other row and is unwrapped exactly.
    folder = tmp_path / "log"
    folder.mkdir()
    ticks = 7 * np.arange(200)
    rows = [f"{1.0 + DT * k!r},{float(c % 16)!r},{float(c % 16)!r}" for k, c in enumerate(ticks)]
    (folder / "wheels.csv").write_text("t,left,right\n" + "\n".join(rows) + "\n")
    log = _load(tmp_path, encoder="{ticks_per_rev: 4096, rollover: 16}")
    np.testing.assert_allclose(log.streams["wheels"]["left"], ticks * 2 * math.pi / TPR)


def test_extra_wheels_column_is_an_error(tmp_path):
    # Issue 16: an extra wheels.csv column was accepted though docs/formats.md calls it an error.
    folder = _wheels_log(tmp_path / "log")
    lines = (folder / "wheels.csv").read_text().splitlines()
    body = [lines[0] + ",spare"] + [line + ",1.0" for line in lines[1:]]
    (folder / "wheels.csv").write_text("\n".join(body) + "\n")
    exc = _error(tmp_path, ["wheels.csv", "row 1", "unexpected column", "left, right"])
    assert exc.column == "spare"


def test_gap_longer_than_half_the_counter_range_is_a_degrading_warning(tmp_path):
    # Issue 16: a wheels gap longer than half the counter range (8.58 m), reported only as
    # wheels.gaps: 1. The right wheel turns 5.5 rad/s: half of a 4096-tick counter (pi rad)
    # passes in 0.57 s; the gap is 2 s.
    _wheels_log(tmp_path / "log", modulus=4096, gap=(600, 700))
    cfg = _config(tmp_path, encoder="{ticks_per_rev: 4096, rollover: 4096}")
    assert main(["run", str(cfg)]) == 0
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["status"] == "degraded"
    lines = [w for w in m["warnings"] if w.startswith("[counter_gap]")]
    assert len(lines) == 1 and "half the counter range" in lines[0], m["warnings"]
    assert "wheels.csv" in lines[0] and "row 601" in lines[0]
    # a short gap (0.2 s, 1.1 rad < pi) is only counted as a gap
    _wheels_log(tmp_path / "log", modulus=4096, gap=(600, 610))
    log = _load(tmp_path, encoder="{ticks_per_rev: 4096, rollover: 4096}")
    assert log.findings == () and log.repairs["wheels.gaps"] == 1


# ---------------------------------------------------------------------------- time units
def test_gps_times_in_nanoseconds_are_an_error(tmp_path):
    # Issue 16: gps.csv time stamps in ns (1 fix used, 94 dropped as late).
    def gps(t, x, y):
        return "t,x,y\n" + "\n".join(
            f"{int(t[k] * 1e9)},{float(x[k])!r},{float(y[k])!r}" for k in range(0, len(t), 50)
        )

    _wheels_log(tmp_path / "log", gps=gps)
    exc = _error(tmp_path, ["gps.csv", "nanoseconds", "row 2"])
    assert exc.column == "t"


def test_a_whole_log_in_milliseconds_since_1970_is_an_error(tmp_path):
    folder = tmp_path / "log"
    folder.mkdir()
    rows = [f"{float(1.7e12 + 100.0 * k)!r},0.05,0.01" for k in range(50)]
    (folder / "odometry.csv").write_text("t,ds,dtheta\n" + "\n".join(rows) + "\n")
    cfg = tmp_path / "run.yaml"
    cfg.write_text("log: log\nrobot: {drive: increments}\n")
    with pytest.raises(InputError, match="milliseconds since 1970") as err:
        load_log_for(load_config(cfg))
    assert err.value.file.endswith("odometry.csv") and err.value.column == "t"


# ------------------------------------------------------------------------------------ GPS
def _latlon(rows):
    return lambda t, x, y: (
        "t,lat,lon\n"
        + "\n".join(
            f"{float(t[k])!r},{float(a)!r},{float(b)!r}"
            for k, (a, b) in zip(range(0, len(t), 50), rows, strict=False)
        )
    )


def test_swapped_lat_lon_against_the_datum_is_an_error(tmp_path):
    rows = [(11.5 + 1e-6 * k, 48.1) for k in range(30)]  # lon, lat written as lat, lon
    _wheels_log(tmp_path / "log", gps=_latlon(rows))
    extra = "sensors: {gps: {sigma: 2.0, datum: [48.1, 11.5]}}\n"
    _error(tmp_path, ["gps.csv", "swapped"], extra=extra)


def test_utm_fixes_without_an_origin_and_gps_jumps_are_warnings(tmp_path):
    # Issue 16: UTM offsets (0 of 95 used) said only "rejected".
    def utm(t, x, y):
        return "t,x,y\n" + "\n".join(
            f"{float(t[k])!r},{float(x[k] + 690000.0)!r},{float(y[k] + 5330000.0)!r}"
            for k in range(0, len(t), 50)
        )

    _wheels_log(tmp_path / "log", gps=utm)
    (far,) = _load(tmp_path).findings
    assert far.check == "gps_far" and far.degrades and "UTM" in far.message

    def jumpy(t, x, y):
        xs = x.copy()
        xs[500] += 80.0  # one multipath fix 80 m off, 1 s after the previous one
        return "t,x,y\n" + "\n".join(
            f"{float(t[k])!r},{float(xs[k])!r},{float(y[k])!r}" for k in range(0, len(t), 50)
        )

    _wheels_log(tmp_path / "log", gps=jumpy)
    (jump,) = _load(tmp_path).findings
    assert jump.check == "gps_jumps" and not jump.degrades and jump.figure == 2.0


# ----------------------------------------------------------------------------------- gyro
def test_gyro_in_degrees_per_second_is_an_error(tmp_path):
    # Issue 16: a gyro in deg/s (4,632 of 4,713 rejected).
    def gyro(t):
        return "t,wz\n" + "\n".join(f"{float(v)!r},{float(math.degrees(W))!r}" for v in t[::5])

    _wheels_log(tmp_path / "log", gyro=gyro)
    exc = _error(tmp_path, ["gyro.csv", "degrees per second", "rad/s"])
    assert exc.column == "wz"


def test_a_noisy_biased_gyro_beside_straight_wheels_is_no_unit_error(tmp_path):
    # A robot driving straight for 600 s (the wheels' yaw rate is 0 to rounding) with a cheap
    # gyro: bias 0.01 rad/s, white noise 0.25 rad/s per 100 Hz sample. The unit check once
    # compared samples (then 1 s windows at a fixed 0.05 rad/s) and called these wheels
    # "1.96e+299 times" too slow; nothing here says the wheels' units are wrong.
    rng = np.random.default_rng(11)
    folder = tmp_path / "log"
    folder.mkdir()
    t = 1.0 + DT * np.arange(30000)
    phi = V * (t - t[0]) / R
    (folder / "wheels.csv").write_text(
        "t,left,right\n"
        + "\n".join(f"{a:.17g},{b:.17g},{b:.17g}" for a, b in zip(t, phi, strict=True))
        + "\n"
    )
    tg = np.arange(t[0], t[-1], 0.01)
    wz = 0.01 + rng.normal(0.0, 0.25, tg.size)
    (folder / "gyro.csv").write_text(
        "t,wz\n" + "\n".join(f"{a:.17g},{b:.17g}" for a, b in zip(tg, wz, strict=True)) + "\n"
    )
    log = _load(tmp_path, encoder=None)
    assert len(log.streams["gyro"]) == tg.size


# ------------------------------------------------------------------- streams mostly unused
def test_a_stream_mostly_dropped_as_late_degrades_the_run():
    # Issue 16: gps.csv in ns had 94 of 95 fixes dropped as late, and the run said ok.
    from compiled_checks import late
    from test_ekf import simulate
    from test_localizer import _cfg, _feed_online

    log, _ = simulate(24, steps=200)
    cfg = _cfg(options={"late_window": 0.3})
    loc, _ = _feed_online(log, cfg, "ekf", order=late("ranges", 0.5))
    (found,) = [f for f in loc.result().findings if f.check == "dropped"]
    assert found.sensor == "ranges" and found.figure > 0.9 and found.degrades
    assert loc.health().status == "degraded"
    in_time, _ = _feed_online(log, cfg, "ekf")
    assert not [f for f in in_time.result().findings if f.check == "dropped"]
