"""A config is data, inputs are bounded, outputs never mix (issue 16, shared spec section 5).

Each case is one reproduction from the issue: it must end in a one-line odofuse error (or a
result), never run code the config names, never a traceback.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from test_cli import CONFIG, make_run, outputs_left, square_log

from odofuse.cli import main
from odofuse.config import load_config
from odofuse.drives import make_drive
from odofuse.errors import ConfigError

GEOMETRY = "{drive: differential, wheel_radius: 0.1, track_width: 0.5}"


def _config(tmp_path, text: str):
    path = tmp_path / "run.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def _one_line_error(capsys, *needles):
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    return err


# ------------------------------------------------------------------- 1. configs are data
@pytest.mark.parametrize(
    "text,key",
    [
        ('robot: {drive: "os:system", command: "touch pwned"}', "robot.drive"),
        ('robot: {drive: "subprocess:getoutput", cmd: "touch pwned"}', "robot.drive"),
        (f'robot: {GEOMETRY}\nestimator: "os:system"', "estimator"),
        (f'robot: {GEOMETRY}\nestimator: "builtins:print"', "estimator"),
        (f'robot: {GEOMETRY}\nsensors: {{g: {{class: "os:system"}}}}', "sensors.g.class"),
        (f'robot: {GEOMETRY}\noptions: {{"subprocess:getoutput": {{}}}}', "options.subprocess"),
        ('plugins: [os]\nrobot: {drive: "os:system", command: "touch pwned"}', "plugins[0]"),
        (f"robot: {GEOMETRY}\nplugins: os", "plugins"),
        (f'robot: {GEOMETRY}\nestimator: "kalman"', "estimator"),
        (f"robot: {GEOMETRY}\noptions: {{kalman: {{gate: 0.99}}}}", "options.kalman"),
    ],
)
def test_config_naming_code_is_refused_and_nothing_runs(tmp_path, monkeypatch, capsys, text, key):
    monkeypatch.chdir(tmp_path)
    cfg = _config(tmp_path, f"log: builtin:plaza1\n{text}\n")
    with pytest.raises(ConfigError) as info:
        load_config(cfg)
    assert info.value.key.startswith(key) and info.value.file == str(cfg)
    assert main(["run", str(cfg), "-o", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, str(cfg), key)
    assert not (tmp_path / "pwned").exists()
    assert not (tmp_path / "o").exists()


def test_unknown_builtin_dataset_names_the_config_file_and_key(tmp_path, capsys):
    # Issue 16: "unknown built-in dataset" named neither the config file nor the key.
    cfg = _config(tmp_path, f"log: builtin:plaza9\nrobot: {GEOMETRY}\n")
    with pytest.raises(ConfigError) as info:
        load_config(cfg)
    assert info.value.key == "log" and info.value.file == str(cfg)
    assert main(["run", str(cfg)]) == 2
    _one_line_error(capsys, str(cfg), "key 'log'", "builtin:plaza9", "builtin:plaza1")


def test_gate_null_is_no_gate_as_documented(tmp_path):
    # Issue 16: `gate: null` is documented as "no gate" (docs/filters.md) but was rejected.
    from odofuse.measurements import gate_threshold

    cfg = load_config(
        _config(
            tmp_path, f"log: builtin:plaza1\nrobot: {GEOMETRY}\nsensors: {{gps: {{gate: null}}}}"
        )
    )
    assert cfg.sensors["gps"].gate is None
    assert gate_threshold(cfg.sensors["gps"].gate, 2) == math.inf


def _plugin_module(tmp_path, monkeypatch, name: str, body: str):
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(body))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, name, raising=False)


def test_plugin_module_is_not_imported_without_opt_in(tmp_path, monkeypatch):
    _plugin_module(
        tmp_path,
        monkeypatch,
        "odofuse_sec_marker",
        """
        from pathlib import Path
        Path(__file__).with_name("imported").write_text("yes")
        from odofuse.drives import Differential as Drive
        """,
    )
    cfg = _config(
        tmp_path,
        "log: builtin:plaza1\n"
        "robot: {drive: 'odofuse_sec_marker:Drive', wheel_radius: 0.1, track_width: 0.5}\n",
    )
    with pytest.raises(ConfigError, match="'plugins:'") as info:
        load_config(cfg)
    assert info.value.key == "robot.drive"
    assert not (tmp_path / "imported").exists() and "odofuse_sec_marker" not in sys.modules
    opted = _config(tmp_path, "plugins: [odofuse_sec_marker]\n" + cfg.read_text())
    assert load_config(opted).plugins == ("odofuse_sec_marker",)
    assert (tmp_path / "imported").exists()


def test_opted_in_plugin_is_shape_checked_before_it_is_called(tmp_path, monkeypatch):
    _plugin_module(
        tmp_path,
        monkeypatch,
        "odofuse_sec_shapes",
        """
        from pathlib import Path
        CALLED = Path(__file__).with_name("called")

        def run(log):  # one argument: not an estimator
            CALLED.write_text("run")

        class NotADrive:
            def __init__(self, **kw):
                CALLED.write_text("init")

        class NotAModel:
            def __init__(self, **kw):
                CALLED.write_text("init")
        """,
    )
    head = "log: builtin:plaza1\nplugins: [odofuse_sec_shapes]\n"
    cases = [
        (f"robot: {GEOMETRY}\nestimator: odofuse_sec_shapes:run", "estimator", "2 positional"),
        ("robot: {drive: 'odofuse_sec_shapes:NotADrive'}", "robot.drive", "twist"),
        (
            f"robot: {GEOMETRY}\nsensors: {{s: {{class: 'odofuse_sec_shapes:NotAModel'}}}}",
            "sensors.s.class",
            "residual",
        ),
        (f"robot: {GEOMETRY}\nestimator: odofuse_sec_shapes:CALLED", "estimator", "PosixPath"),
    ]
    for text, key, needle in cases:
        with pytest.raises(ConfigError, match=needle) as info:
            load_config(_config(tmp_path, head + text + "\n"))
        assert info.value.key == key
    assert not (tmp_path / "called").exists()


def test_make_drive_refuses_a_function_without_calling_it(tmp_path):
    with pytest.raises(ConfigError, match="not a class"):
        make_drive("os:system", command=f"touch {tmp_path / 'pwned'}")
    assert not (tmp_path / "pwned").exists()


def test_docs_say_a_config_naming_plugins_is_code():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    assert "`plugins`" in text and "is code" in text


# ------------------------------------------------------------------- 2. bounded YAML
def _alias_bomb(levels: int = 9) -> str:
    text = "log: builtin:plaza1\nrobot: {drive: increments}\nsensors:\n  ranges:\n"
    text += '    a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
    prev = "a"
    for name in "bcdefghijk"[: levels - 1]:
        text += f"    {name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]\n"
        prev = name
    return text


@pytest.mark.parametrize(
    "content,needles",
    [
        (_alias_bomb().encode(), ["aliases expand", "line 9"]),
        (b"log: x\nrobot: " + b"[" * 10000 + b"]" * 10000 + b"\n", ["nested deeper", "line 2"]),
        (b"log: x\nrobot: " + b"{a: " * 5000 + b"1" + b"}" * 5000 + b"\n", ["nested deeper"]),
        (
            b"log: x\nrobot: {drive: increments}\nestimator: ekf\nestimator: ukf\n",
            ["duplicate key 'estimator'", "line 4", "first on line 3"],
        ),
        (b"log: x\nrobot: {drive: increments, drive: twist}\n", ["duplicate key 'drive'"]),
        (b"log: x\nrobot: {drive: incr\xc5ments}\n", ["not UTF-8", "0xc5", "offset 26", "line 2"]),
        (b"log: x\n#" + b"x" * (2 << 20) + b"\n", ["larger than"]),
    ],
    # Named ids: a 2 MiB config as its own id was carried by every xdist report.
    ids=[
        "alias-bomb",
        "deep-list",
        "deep-map",
        "duplicate-key",
        "duplicate-flow-key",
        "non-utf8",
        "2MiB",
    ],
)
def test_hostile_yaml_ends_in_one_line_error(tmp_path, capsys, content, needles):
    cfg = tmp_path / "run.yaml"
    cfg.write_bytes(content)
    with pytest.raises(ConfigError) as info:
        load_config(cfg)
    message = str(info.value)
    assert "\n" not in message and len(message) < 300 and str(cfg) in message
    for needle in needles:
        assert needle in message
    assert main(["run", str(cfg)]) == 2
    _one_line_error(capsys, str(cfg), needles[0])


def test_a_few_aliases_and_merge_keys_still_work(tmp_path):
    cfg = _config(
        tmp_path,
        """\
        log: builtin:plaza1
        robot: {drive: increments}
        sensors:
          gps: &base {sigma: 1.5, gate: 0.99}
          compass: {<<: *base, sigma: 0.05}
        """,
    )
    config = load_config(cfg)
    assert config.sensors["compass"].sigma == 0.05 and config.sensors["compass"].gate == 0.99


# ------------------------------------------------------------------- 3. bounded CSV logs
def _csv_run(tmp_path):
    cfg = make_run(tmp_path)
    return cfg, tmp_path / "log" / "odometry.csv"


def _set_row(path, index: int, row: bytes) -> None:
    lines = path.read_bytes().splitlines()
    lines[index] = row
    path.write_bytes(b"\n".join(lines) + b"\n")


def test_sparse_two_gigabyte_csv_ends_in_a_short_error(tmp_path, capsys):
    cfg, odo = _csv_run(tmp_path)
    with open(odo, "r+b") as fh:  # a hole of 2 GiB: no line breaks, no disk space used
        fh.seek(2 << 30)
        fh.write(b"\n30.0,0.1,0.05\n")
    assert main(["run", str(cfg)]) == 2
    err = _one_line_error(capsys, str(odo), "row 202", "line longer than")
    assert len(err) < 300
    assert outputs_left(tmp_path) == []


@pytest.mark.parametrize(
    "row,needles",
    [
        pytest.param(
            lambda: b"1.5,0.1," + b"9" * (100 << 20),
            ["row 6", "line longer than"],
            id="100MiB-line",
        ),
        pytest.param(
            b"1.5,0.1,0.\xc55", ["row 6", "column 'dtheta'", "not UTF-8", "0xc5"], id="non-utf8"
        ),
        pytest.param(b"1.5,1e308,0.05", ["row 6", "column 'ds'", "out of range"], id="overflow"),
        pytest.param(b"1.5e18,0.1,0.05", ["row 6", "column 't'", "seconds"], id="time-in-ns"),
        pytest.param(
            b"1.5,1_0,0.05", ["row 6", "column 'ds'", "not a number: '1_0'"], id="underscore"
        ),
        pytest.param(
            b"1.5,0.1," + b"x" * 5000, ["row 6", "column 'dtheta'", "not a number"], id="5000-x"
        ),
    ],
)
def test_bad_csv_row_names_file_row_and_column_with_a_short_excerpt(tmp_path, capsys, row, needles):
    # The 100 MiB row is built in the test, not at collection: as a parameter it was the test's
    # id, a 100 MB string that every xdist worker sent to the controller and every report carried.
    row = row() if callable(row) else row
    cfg, odo = _csv_run(tmp_path)
    _set_row(odo, 5, row)
    assert main(["run", str(cfg)]) == 2
    err = _one_line_error(capsys, str(odo), *needles)
    assert len(err) < 300, len(err)
    assert outputs_left(tmp_path) == []


def test_non_utf8_header_names_the_file_and_row(tmp_path, capsys):
    cfg, odo = _csv_run(tmp_path)
    _set_row(odo, 0, b"t,d\xc5s,dtheta")
    assert main(["run", str(cfg)]) == 2
    _one_line_error(capsys, str(odo), "row 1", "not UTF-8")


EKF = "estimator: ekf\n"
NON_UTF8 = {
    "gps.csv": (b"t,x,y\n2.0,0.1,0.0\n3.0,0.5,0.\xc51\n", "sensors: {gps: {sigma: 1.0}}", "y"),
    "ranges.csv": (b"t,id,range\n2.0,0,1.0\n3.0,0,1.\xc5\n", "sensors: {ranges: {}}", "range"),
    "gyro.csv": (b"t,wz\n2.0,0.1\n3.0,0.\xc5\n", "sensors: {gyro: {sigma: 0.01}}", "wz"),
    "landmarks.csv": (b"id,x,y\n0,1.0,2.0\n1,3.\xc5,1.0\n", "sensors: {ranges: {}}", "x"),
}


@pytest.mark.parametrize("name", sorted(NON_UTF8))
def test_non_utf8_byte_in_any_csv_names_file_row_and_column(tmp_path, capsys, name):
    # Issue 16: a non-UTF-8 byte in *any* CSV gave "'utf-8' codec can't decode byte 0xc5".
    cfg = make_run(tmp_path)
    body, sensors, column = NON_UTF8[name]
    (tmp_path / "log" / name).write_bytes(body)
    if name == "landmarks.csv":
        (tmp_path / "log" / "ranges.csv").write_text("t,id,range\n2.0,0,1.0\n")
    text = CONFIG.format(log="log", out="out").replace("estimator: dead_reckoning\n", EKF)
    cfg.write_text(text + sensors + "\n")
    assert main(["run", str(cfg)]) == 2
    where = str(tmp_path / "log" / name)
    _one_line_error(capsys, where, "row 3", f"column '{column}'", "not UTF-8", "0xc5")
    assert outputs_left(tmp_path) == []


# ------------------------------------------------------------------- 4. output integrity
def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def _leftovers(parent):
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


KILL_DURING_WRITE = """
import os, signal, sys
import odofuse.rundir as rundir
real = rundir.write_tum
def dying(path, traj):
    real(path, traj)
    os.kill(os.getpid(), signal.{sig})
rundir.write_tum = dying
from odofuse.cli import main
sys.argv = ["odofuse", "run", {cfg!r}]
sys.exit(main())
"""


@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_killed_run_keeps_the_previous_result_and_the_next_run_cleans_up(tmp_path, sig):
    cfg = make_run(tmp_path)
    assert main(["run", str(cfg)]) == 0
    out = tmp_path / "out"
    before = _snapshot(out)
    script = KILL_DURING_WRITE.format(sig=sig, cfg=str(cfg))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    assert _snapshot(out) == before  # the previous complete result, untouched
    if sig == "SIGTERM":  # cleanup ran: no temporary folder, no lock
        assert _leftovers(tmp_path) == []
    else:  # SIGKILL: nothing can run, the next run cleans up
        assert any(".out.tmp-" in n for n in _leftovers(tmp_path))
        assert ".out.lock" in _leftovers(tmp_path)
    assert main(["run", str(cfg)]) == 0
    assert _leftovers(tmp_path) == []
    assert _snapshot(out).keys() == before.keys()


def test_second_run_into_a_claimed_folder_is_a_clear_error(tmp_path, capsys):
    cfg = make_run(tmp_path)
    assert main(["run", str(cfg)]) == 0
    before = _snapshot(tmp_path / "out")
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (tmp_path / ".out.lock").write_text(f"{holder.pid}\n")
        capsys.readouterr()
        assert main(["run", str(cfg)]) == 2
        _one_line_error(capsys, "in use by another run", f"pid {holder.pid}")
        assert _snapshot(tmp_path / "out") == before
    finally:
        holder.kill()
        holder.wait()
    # the holder is gone: its lock is stale and taken over
    assert main(["run", str(cfg)]) == 0
    assert _leftovers(tmp_path) == []


def test_two_concurrent_runs_never_leave_a_mixed_folder(tmp_path):
    short = make_run(tmp_path / "a")
    long_dir = tmp_path / "b"
    square_log(long_dir / "log", n=3000)
    long = long_dir / "run.yaml"
    long.write_text(CONFIG.format(log="log", out="out"))
    out = tmp_path / "shared"
    cmd = [sys.executable, "-m", "odofuse", "run"]
    procs = [
        subprocess.Popen([*cmd, str(c), "-o", str(out)], stderr=subprocess.PIPE)
        for c in (long, short)
    ]
    codes = [(p.wait(), p.stderr.read().decode()) for p in procs]
    for rc, err in codes:
        assert rc == 0 or (rc == 2 and "in use by another run" in err), err
    metrics = json.loads((out / "metrics.json").read_text())
    rows = len((out / "trajectory.csv").read_text().splitlines()) - 1
    assert metrics["poses"] == rows
    assert _leftovers(tmp_path) == []


CLAIM_AND_HOLD = """
import os, sys, time
from odofuse.errors import OdofuseError
from odofuse.io.atomic import claim_folder
folder, journal, go = sys.argv[1:4]
while not os.path.exists(go):  # spin, so that all start within microseconds
    pass
try:
    with claim_folder(folder):
        with open(journal, "a") as fh:
            fh.write("in\\n")
        time.sleep(0.05)
        with open(journal, "a") as fh:
            fh.write("out\\n")
except OdofuseError:
    pass
"""


def test_runs_started_together_never_both_hold_a_folder(tmp_path):
    """Six processes claim one folder at the same instant: never two inside at once.

    A lock created empty and filled after used to be read as stale by a second run, which
    removed it, so both held the folder and one deleted the other's temporary folder (CI,
    session 26: ``test_two_concurrent_runs_never_leave_a_mixed_folder``). The old code
    overlapped in 20 of 20 such rounds, this one in 0 of 20.
    """
    go, journal = tmp_path / "go", tmp_path / "journal"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", CLAIM_AND_HOLD, str(tmp_path / "out"), str(journal), str(go)]
        )
        for _ in range(6)
    ]
    time.sleep(0.5)
    go.touch()
    assert [p.wait() for p in procs] == [0] * 6
    depth = deepest = 0
    for word in journal.read_text().split():
        depth += 1 if word == "in" else -1
        deepest = max(deepest, depth)
    assert deepest == 1
    assert _leftovers(tmp_path) == []


def test_output_folder_with_other_files_is_not_replaced(tmp_path, capsys):
    cfg = make_run(tmp_path)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "notes.txt").write_text("mine")
    assert main(["run", str(cfg)]) == 2
    _one_line_error(capsys, "holds other files (notes.txt)")
    assert sorted(os.listdir(tmp_path / "out")) == ["notes.txt"]


# ------------------------------------------------------------------- 5. streaming API
def _localizer(steps=20):
    from test_ekf import simulate
    from test_localizer import _cfg

    from odofuse.estimators import ekf
    from odofuse.estimators.assembly import build

    log, _ = simulate(31, steps=steps)
    loc, t, U = build(_cfg(), log, "ekf", ekf.make_backend)
    return log, loc, t, U


@pytest.mark.parametrize(
    "stream,row,needles",
    [
        ("GPS", {"t": 1.0, "x": 0.0, "y": 0.0}, ["unknown stream 'GPS'", "ranges"]),
        (None, {"t": 1.0}, ["unknown stream None"]),
        ("ranges", None, ["mapping", "NoneType"]),
        ("ranges", 3.0, ["mapping", "float"]),
        ("ranges", {"t": None, "id": 0, "range": 3.0}, ["'t' must be a number"]),
        ("ranges", {"t": "1.0", "id": 0, "range": 3.0}, ["'t' must be a number"]),
        ("ranges", {"t": 1.0, "id": 0, "range": None}, ["t=1.000000", "'range'"]),
        ("ranges", {"t": 1.0, "id": 0, "range": [3.0, 4.0]}, ["'range' must be a number"]),
        ("ranges", {"t": 1.0, "id": 0, "range": 1e308}, ["'range'", "out of range"]),
        ("ranges", {"t": math.inf, "id": 0, "range": 3.0}, ["'t' is non-finite"]),
    ],
)
def test_streaming_bad_readings_name_stream_time_and_field(stream, row, needles):
    from odofuse.errors import InputError

    _, loc, _, _ = _localizer()
    with pytest.raises(InputError) as info:
        loc.add_measurement(stream, row)
    message = str(info.value)
    assert "\n" not in message and len(message) < 300
    for needle in needles:
        assert needle in message, message


@pytest.mark.parametrize(
    "u,needles",
    [
        ([0.1, 0.2, 0.3], ["shape (2,)", "got (3,)"]),
        (0.1, ["shape (2,)", "got ()"]),
        (None, ["NoneType"]),
        ([0.1, None], ["'dtheta'", "non-finite"]),
        ([1e308, 0.0], ["out of range"]),
        ([0.1, math.nan], ["non-finite"]),
        ("ab", ["str"]),
    ],
)
def test_streaming_bad_odometry_names_time_and_field(u, needles):
    from odofuse.errors import InputError

    _, loc, t, _ = _localizer()
    before = loc.pose()
    with pytest.raises(InputError) as info:
        loc.add_odometry(t[1], u)
    for needle in needles:
        assert needle in str(info.value), str(info.value)
    np.testing.assert_array_equal(loc.pose(), before)
    assert np.all(np.isfinite(loc.covariance()))
    with pytest.raises(InputError, match="'t' must be a number"):
        loc.add_odometry(None, [0.1, 0.0])


def test_streaming_zero_dt_step_with_another_input_is_an_error():
    # Issue 16: zero dt with a 100x input was accepted (the CLI drops exact duplicates only).
    from odofuse.errors import InputError

    _, loc, t, U = _localizer()
    assert loc.add_odometry(t[1], U[0]) == "used"
    before = loc.state()
    with pytest.raises(InputError, match="a second step at this time") as info:
        loc.add_odometry(t[1], 100.0 * U[0])
    assert "\n" not in str(info.value) and "t=" in str(info.value)
    np.testing.assert_array_equal(loc.state()[1], before[1])
    assert loc.add_odometry(t[1], U[0]) == "duplicate"


def test_streaming_add_returns_what_happened_to_the_reading():
    from odofuse.estimators.localizer import events

    log, loc, t, U = _localizer(steps=60)
    ranges = log.streams["ranges"]
    evs = events(log, t, U, ["ranges"])
    held = None
    for te, kind, stream, i in evs:
        if kind == 1:
            assert loc.add_odometry(te, U[i]) == "used"
        elif held is None and i >= 3:
            held = ranges.row(i)  # fed later, while still inside the late window
        else:
            fate = loc.add_measurement(stream, ranges.row(i))
            assert fate in ("used", "rejected") if te <= loc.t else fate == "buffered"
        if held is not None and loc.t >= held["t"] and loc.t - held["t"] < loc.late_window / 2:
            break
    assert held is not None and loc.t >= held["t"]
    assert loc.add_measurement("ranges", held) == "used"  # applied by a replay
    assert loc.add_measurement("ranges", held) == "duplicate"
    outlier = {**held, "t": held["t"] - 1e-4, "range": held["range"] + 500.0}
    assert loc.add_measurement("ranges", outlier) == "rejected"
    future = {**held, "t": loc.t + 1.0}
    assert loc.add_measurement("ranges", future) == "buffered"
    old = {**held, "t": loc.t - loc.late_window - 1.0}
    assert loc.add_measurement("ranges", old) == "dropped"
    conflict = {**held, "range": held["range"] + 0.1}
    from odofuse.errors import InputError

    with pytest.raises(InputError, match="different values"):
        loc.add_measurement("ranges", conflict)


def test_streaming_exact_duplicates_match_the_offline_run():
    from test_localizer import _cfg

    from odofuse.estimators import ekf
    from odofuse.estimators.localizer import events

    log, loc, t, U = _localizer(steps=60)
    offline = ekf.run(log, _cfg())
    for te, kind, stream, i in events(log, t, U, ["ranges"]):
        if kind == 1:
            loc.add_odometry(te, U[i])
            assert loc.add_odometry(te, U[i]) == "duplicate"
        else:
            row = log.streams[stream].row(i)
            loc.add_measurement(stream, row)
            for _ in range(50):  # a burst of identical fixes counts once, as offline
                assert loc.add_measurement(stream, row) == "duplicate"
    loc.finish()
    online = loc.result()
    np.testing.assert_array_equal(online.trajectory.poses, offline.trajectory.poses)
    np.testing.assert_array_equal(online.trajectory.covariances, offline.trajectory.covariances)
    assert online.used == offline.used
    assert online.extra["duplicates"]["ranges"] == 50 * len(log.streams["ranges"])
    assert online.extra["duplicates"]["odometry"] == len(U)
