"""What the compiled-core tests share: one all-sensor figure-eight scenario, the check that
a compiled run equals its reference run (``test_compiled``, ``test_compiled_particle``), and
feeding a live Localizer a log's rows, in order or some late (also ``test_localizer``)."""

from __future__ import annotations

import numpy as np
import pytest

#: A one-lap figure eight with a biased gyro, GPS, compass and ranges to four beacons
#: (``odofuse simulate`` format; the tests pass the seed).
SCENARIO = {
    "seed": 3,
    "dt": 0.02,
    "robot": {"drive": "differential", "wheel_radius": 0.04, "track_width": 0.235},
    "path": {"kind": "figure_eight", "radius": 3.0, "speed": 0.5, "laps": 1},
    "systematic": {"E_d": 1.004, "E_b": 1.01},
    "nonsystematic": {"k": 1.0e-5},
    "sensors": {
        "gyro": {"sigma": 0.005, "bias": 0.01, "rate": 25.0},
        "gps": {"sigma": 0.3, "rate": 1.0},
        "compass": {"sigma": 0.05, "rate": 2.0},
        "ranges": {"sigma": 0.1, "rate": 5.0, "max_range": 15.0},
    },
    "beacons": [[1, 0.0, 6.0], [2, 0.0, -6.0], [3, 8.0, 0.0], [4, -8.0, 0.0]],
}
#: The same with wheel slip (the right wheel moving the robot 70 % of its count for 2 s, the
#: left 50 % for 1.5 s) and a bump: robust odometry widens steps, in runs.
SLIP_SCENARIO = {
    **SCENARIO,
    "nonsystematic": {
        "k": 1.0e-5,
        "slip_bursts": [[8.0, 10.0, "right", 0.3], [20.0, 21.5, "left", 0.5]],
        "bumps": [[30.0, "left", 0.05]],
    },
}


def assert_same_run(res, ref) -> None:
    """Poses and covariances to 1e-9; used/rejected counts and extras equal (calibration
    values and sigmas, minimal detectable errors to 1e-9, the calibration drift ratio to
    1e-6 relative); findings equal, their figures to 1e-9 relative."""
    a, b = res.trajectory, ref.trajectory
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_allclose(a.poses, b.poses, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.covariances, b.covariances, rtol=0, atol=1e-9)
    assert res.used == ref.used and res.rejected == ref.rejected
    ex, ey = dict(res.extra), dict(ref.extra)
    assert set(ex.get("calibration", {})) == set(ey.get("calibration", {}))
    for s in ey.get("calibration", {}):
        for k in ("value", "sigma"):
            assert abs(ex["calibration"][s][k] - ey["calibration"][s][k]) < 1e-9
    np.testing.assert_allclose(ex.pop("map_to_odom"), ey.pop("map_to_odom"), atol=1e-9)
    ex.pop("calibration", None), ey.pop("calibration", None)
    dx, dy = ex.pop("calibration_drift", None), ey.pop("calibration_drift", None)
    assert (dx is None) == (dy is None)
    if dy is not None:  # the same snapshots; |z| of differences of close variances: 1e-6
        assert dx["snapshots"] == dy["snapshots"] > 0
        assert dx["ratio"] == pytest.approx(dy["ratio"], rel=1e-6, abs=1e-9)
    mx, my = ex.pop("mde", {}), ey.pop("mde", {})  # figures: to 1e-9 relative
    assert {s: set(m) for s, m in mx.items()} == {s: set(m) for s, m in my.items()}
    for s, m in my.items():
        for k, v in m.items():
            assert (mx[s][k] is None) == (v is None)
            assert v is None or mx[s][k] == pytest.approx(v, rel=1e-9, abs=1e-12)
    assert ex == ey
    assert len(res.findings) == len(ref.findings)
    for f, g in zip(res.findings, ref.findings, strict=True):  # messages print figures
        assert (f.check, f.message, f.sensor, f.t_start, f.t_end, f.degrades) == (
            g.check, g.message, g.sensor, g.t_start, g.t_end, g.degrades
        )  # fmt: skip
        assert f.figure == pytest.approx(g.figure, rel=1e-9, abs=1e-12)


def feed(loc, log, t, U, streams, order=None, on_odometry=None):
    """Feed ``loc`` the odometry inputs ``U`` (at ``t``) and the rows of ``streams`` of ``log``
    in time order (``order``: a function reordering that list of
    :func:`odofuse.estimators.common.events`, e.g. :func:`late`), calling ``on_odometry(loc)``
    after each odometry step; then finish it. Returns ``loc``."""
    from odofuse.estimators.common import events

    evs = events(log, t, U, list(streams))
    for te, kind, stream, i in evs if order is None else order(evs):
        if kind == 1:
            loc.add_odometry(te, U[i])
            if on_odometry is not None:
                on_odometry(loc)
        else:
            loc.add_measurement(stream, log.streams[stream].row(i))
    loc.finish()
    return loc


def late(stream, seconds, after=-np.inf):
    """An ``order`` of :func:`feed`: the rows of ``stream`` stamped after ``after`` s arrive
    ``seconds`` after their time stamp (a Localizer replays them)."""

    def order(evs):
        keyed = [
            (te + seconds * (s == stream and te > after), kind, n)
            for n, (te, kind, s, _) in enumerate(evs)
        ]
        return [evs[n] for _, _, n in sorted(keyed)]

    return order


def live_from_config(log, cfg, make_backend, delay=0.0):
    """A Localizer built as a pipeline builds it (``Localizer.from_config``), fed the log's
    rows with the GPS fixes after the first second ``delay`` s late (replays)."""
    from odofuse.estimators.assembly import build
    from odofuse.estimators.localizer import Localizer

    _, t, U = build(cfg, log, cfg.estimator, make_backend)
    loc = Localizer.from_config(
        cfg, t0=t[0], landmarks=log.landmarks, initial_pose=log.initial_pose, keep_trajectory=True
    )
    return feed(loc, log, t, U, cfg.sensors, late("gps", delay, after=1.0))
