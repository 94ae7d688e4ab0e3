"""Property-based tests (hypothesis) of the three input surfaces: CSV logs, configs, streaming.

The property is the one of shared spec section 5: any input ends in a result or in a one-line
:class:`odofuse.errors.OdofuseError`, never in another exception (a traceback). For the
streaming API also: odometry, GPS and gyro readings that arrive out of order, each at most
the late window late, give the same estimate as the same readings in time order.

The budget is bounded by example counts, not by time (``max_examples``, no deadline, so a
slow shared CI machine cannot fail a test), and the examples are derived from the test
(``derandomize``): every CI run tries the same inputs and a failure reproduces. Set
``HYPOTHESIS_PROFILE=thorough`` for a long randomised run.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from odofuse.config import config_from_dict, parse_yaml  # noqa: E402
from odofuse.errors import OdofuseError  # noqa: E402
from odofuse.io.csvlog import read_csv_log  # noqa: E402

settings.register_profile(
    "ci",
    max_examples=30,
    deadline=None,  # bounded by max_examples; wall-clock limits are flaky on shared machines
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    derandomize=True,  # the same examples on every run: a CI failure reproduces
    print_blob=True,
)
settings.register_profile("thorough", max_examples=2000, deadline=None, derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def _one_line(exc: BaseException) -> None:
    text = str(exc)
    assert "\n" not in text and len(text) < 400, text[:500]


# ------------------------------------------------------------------------------ CSV logs
_NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**20), 10**20).map(str),
    st.sampled_from(["", " ", "1_0", "0x10", "1e308", "-1e400", "nan", "inf", "abc", "1.5.2"]),
)
_CELL = st.one_of(_NUMBER, _NUMBER, st.text(max_size=12).filter(lambda s: "\n" not in s))
_HEADERS = st.sampled_from(
    ["t,ds,dtheta", "t,ds", "x,ds,dtheta", "t,ds,dtheta,extra", "t,t,ds", "", "t,,dtheta"]
)


@st.composite
def csv_bytes(draw) -> bytes:
    header = draw(_HEADERS)
    ncol = max(1, header.count(",") + 1)
    times = draw(st.lists(st.floats(-10, 1e3, allow_nan=False), max_size=30))
    lines = [header]
    for t in sorted(times) if draw(st.booleans()) else times:
        cells = [repr(t)] + [draw(_CELL) for _ in range(ncol - 1 + draw(st.integers(-1, 1)))]
        lines.append(",".join(cells))
    text = "\n".join(lines).encode("utf-8", "surrogatepass")
    if draw(st.booleans()):  # corrupt some bytes
        junk = draw(st.binary(min_size=1, max_size=4))
        at = draw(st.integers(0, len(text)))
        text = text[:at] + junk + text[at:]
    return text + (b"\n" if draw(st.booleans()) else b"")


@given(csv_bytes())
def test_any_odometry_csv_ends_in_a_log_or_an_odofuse_error(content):
    with tempfile.TemporaryDirectory() as folder:
        Path(folder, "odometry.csv").write_bytes(content)
        try:
            log = read_csv_log(folder)
        except OdofuseError as exc:
            _one_line(exc)
        else:
            data = log.streams["odometry"].data
            assert np.isfinite(data).all()


# ------------------------------------------------------------------------------- configs
_KEYS = st.sampled_from(
    [
        "log", "robot", "drive", "wheel_radius", "track_width", "encoder", "ticks_per_rev",
        "rollover", "motion", "integrator", "k", "k_r", "k_l", "estimator", "initial", "pose",
        "sigma", "sensors", "gps", "ranges", "gyro", "compass", "class", "gate", "model",
        "output", "options", "ekf", "late_window", "plugins", "description", "repair",
        "duplicates", "path", "os:system",
    ]
)  # fmt: skip
_SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(
        [
            "differential",
            "increments",
            "ekf",
            "exact",
            "builtin:plaza1",
            "os:system",
            "builtins:print",
            "subprocess:getoutput",
            "odofuse.cli:main",
            "x",
            "",
            "1e-4",
        ]
    ),  # fmt: skip
    st.text(max_size=10),
)
_VALUES = st.recursive(
    _SCALARS,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(_KEYS, inner, max_size=4),
    max_leaves=12,
)


@st.composite
def config_mappings(draw) -> dict:
    base = {
        "log": draw(st.sampled_from(["log", "builtin:plaza1", None, 3])),
        "robot": draw(
            st.one_of(
                st.just({"drive": "increments"}),
                st.just({"drive": "differential", "wheel_radius": 0.1, "track_width": 0.5}),
                st.dictionaries(_KEYS, _VALUES, max_size=4),
            )
        ),
    }
    extra = draw(st.dictionaries(_KEYS, _VALUES, max_size=5))
    base.update(extra)
    if draw(st.booleans()):
        base.pop(draw(st.sampled_from(["log", "robot"])), None)
    return base


@given(config_mappings())
def test_any_config_mapping_ends_in_a_config_or_an_odofuse_error(mapping):
    try:
        config = config_from_dict(mapping, "fuzz.yaml")
    except OdofuseError as exc:
        _one_line(exc)
        assert "fuzz.yaml" in str(exc)
    else:
        assert config.robot["drive"]


_YAML_ATOMS = st.sampled_from(
    [
        "log: x\n", "robot: {drive: increments}\n", "a: &a [1, 2]\n", "b: [*a, *a]\n", "*a",
        "[[[[", "]]", "{", "}", ": :", "- - -\n", "!!python/object:os.system {}\n",
        "estimator: ekf\n", "\t", "'", '"', "%YAML 1.1\n", "---\n", "? x\n", "<<: *a\n",
    ]
)  # fmt: skip


@given(st.lists(st.one_of(_YAML_ATOMS, st.text(max_size=8)), max_size=12).map("".join))
def test_any_yaml_text_parses_or_ends_in_a_config_error(text):
    try:
        data = parse_yaml(text, "fuzz.yaml")
    except OdofuseError as exc:
        _one_line(exc)
        return
    if isinstance(data, dict):
        try:
            config_from_dict(data, "fuzz.yaml")
        except OdofuseError as exc:
            _one_line(exc)


# ---------------------------------------------------------------------------- streaming
_READING_VALUE = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**20), 10**20),
    st.none(),
    st.text(max_size=3),
    st.lists(st.floats(), max_size=2),
)
_CALLS = st.lists(
    st.one_of(
        st.tuples(
            st.just("odometry"),
            st.one_of(st.floats(0, 5), st.floats(), st.none()),
            st.one_of(
                st.lists(st.floats(-1, 1), min_size=2, max_size=2),
                st.lists(_READING_VALUE, max_size=3),
                _READING_VALUE,
            ),
        ),
        st.tuples(
            st.sampled_from(["ranges", "ranges", "gps", "GPS", None]),
            st.dictionaries(
                st.sampled_from(["t", "id", "range", "x", "y"]), _READING_VALUE, max_size=4
            )
            | st.fixed_dictionaries(
                {"t": st.floats(0, 5), "id": st.integers(0, 3), "range": st.floats(0, 50)}
            ),
        ),
    ),
    max_size=25,
)


@pytest.fixture(scope="module")
def localizer_parts():
    from test_ekf import simulate
    from test_localizer import _cfg

    log, _ = simulate(41, steps=5)
    return log, _cfg()


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(calls=_CALLS)
def test_any_streaming_calls_end_in_a_status_or_an_input_error(localizer_parts, calls):
    from odofuse.errors import InputError
    from odofuse.estimators import ekf
    from odofuse.estimators.assembly import build

    log, cfg = localizer_parts
    loc, _, _ = build(cfg, log, "ekf", ekf.make_backend)
    statuses = {"used", "rejected", "buffered", "dropped", "duplicate"}
    for call in calls:
        try:
            if call[0] == "odometry":
                out = loc.add_odometry(call[1], call[2])
            else:
                out = loc.add_measurement(call[0], call[1])
        except InputError as exc:
            _one_line(exc)
        else:
            assert out in statuses
    loc.finish()
    result = loc.result()
    assert len(result.trajectory.t) >= 1


# ------------------------------------------------------- streaming: late and out of order
LATE_WINDOW = 0.5


def _gps_gyro_config():
    from test_localizer import _live_gps_config

    return _live_gps_config(
        sensors={
            "gps": {"sigma": 0.5, "gate": 0.9999},
            "gyro": {"sigma": 0.01, "calibrate": True, "bias_sigma": 0.02},
        },
        late_window=LATE_WINDOW,
    )


_STEP = st.tuples(st.floats(0, 0.3), st.floats(-0.1, 0.1))
_TIME = st.floats(0.01, 3.0).map(lambda v: round(v, 4))


@st.composite
def sensor_sequences(draw):
    """Odometry every 0.1 s; GPS and gyro readings at any time, each arriving up to 0.9 late
    windows after its time stamp. Returns ``(readings in time order, the arrival order)``;
    a reading is ``(t, kind, stream, row)``, odometry rows hold ``u``."""
    steps = draw(st.lists(_STEP, min_size=2, max_size=25))
    gps = draw(st.lists(st.tuples(_TIME, st.floats(-3, 3), st.floats(-3, 3)), max_size=8))
    gyro = draw(st.lists(st.tuples(_TIME, st.floats(-0.5, 0.5)), max_size=8))
    readings = {}  # one reading per (stream, t): a conflicting second one is an error
    for k, u in enumerate(steps):
        t = round(0.1 * (k + 1), 10)
        readings[("odometry", t)] = (t, 1, "odometry", {"u": u})
    for t, x, y in gps:
        readings.setdefault(("gps", t), (t, 0, "gps", {"t": t, "x": x, "y": y}))
    for t, w in gyro:
        readings.setdefault(("gyro", t), (t, 0, "gyro", {"t": t, "wz": w}))
    in_order = sorted(readings.values(), key=lambda r: (r[0], r[1]))
    late = st.floats(0.0, 0.9 * LATE_WINDOW)
    arrival = [(r[0] if r[1] else r[0] + draw(late), n, r) for n, r in enumerate(in_order)]
    return in_order, [r for _, _, r in sorted(arrival, key=lambda a: (a[0], a[1]))]


def _feed(readings):
    from odofuse.estimators.localizer import Localizer

    loc = Localizer.from_config(_gps_gyro_config(), 0.0, keep_trajectory=True)
    for t, kind, stream, row in readings:
        if kind:
            out = loc.add_odometry(t, row["u"])
        else:
            out = loc.add_measurement(stream, row)
        assert out in {"used", "rejected", "buffered", "dropped", "duplicate"}
    loc.finish()
    return loc


@given(sensor_sequences())
def test_late_and_out_of_order_readings_give_the_in_order_estimate(sequences):
    in_order, arrival = sequences
    a, b = _feed(in_order), _feed(arrival)
    ra, rb = a.result(), b.result()
    assert ra.used == rb.used and ra.rejected == rb.rejected
    assert rb.extra["dropped_late"] == ra.extra["dropped_late"]
    np.testing.assert_allclose(rb.trajectory.poses, ra.trajectory.poses, rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        rb.trajectory.covariances, ra.trajectory.covariances, rtol=0, atol=1e-9
    )
    np.testing.assert_allclose(b.state()[0], a.state()[0], rtol=0, atol=1e-9)
