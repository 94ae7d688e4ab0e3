"""CSV log folders: parsing, every bad-input class of spec section 5, repairs, speed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.errors import InputError
from odofuse.io.csvlog import read_csv_log, read_map, read_stream, write_csv_log
from odofuse.io.loader import load_log


def write(folder, name, text):
    p = folder / name
    p.write_text(text)
    return p


def good_log(folder):
    write(folder, "odometry.csv", "t,ds,dtheta\n0.1,0.1,0.0\n0.2,0.1,0.01\n0.3,0.1,0.02\n")
    write(folder, "ranges.csv", "t,id,range\n0.1,1,5.0\n0.1,2,6.0\n0.3,1,4.9\n")
    write(folder, "map.csv", "id,x,y\n1,10.0,0.0\n2,0.0,10.0\n")
    write(folder, "groundtruth.csv", "t,x,y,theta\n0.0,0,0,0\n0.3,0.3,0.003,0.03\n")
    write(folder, "gyro.csv", "t,wz\n0.1,0.1\n0.2,0.1\n")
    write(folder, "compass.csv", "t,heading\n0.1,3.5\n")
    write(folder, "gps.csv", "t,lat,lon,sigma\n0.1,45.0,9.0,1.5\n")
    write(folder, "landmarks.csv", "t,id,range,bearing\n0.2,1,5.0,-0.5\n")
    return folder


def test_reads_every_stream(tmp_path):
    log = read_csv_log(good_log(tmp_path))
    assert set(log.streams) == {"odometry", "ranges", "gyro", "compass", "gps", "landmarks"}
    assert log.streams["odometry"].columns == ("ds", "dtheta")
    np.testing.assert_allclose(log.streams["odometry"]["dtheta"], [0.0, 0.01, 0.02])
    np.testing.assert_allclose(log.streams["ranges"]["id"], [1, 2, 1])
    np.testing.assert_allclose(log.landmarks[2], [0.0, 10.0])
    assert log.groundtruth.columns == ("x", "y", "theta")
    # absolute headings are wrapped to [-pi, pi)
    assert log.streams["compass"]["heading"][0] == pytest.approx(3.5 - 2 * math.pi)
    assert log.streams["gps"].columns == ("lat", "lon", "sigma")
    assert log.repairs == {}
    assert load_log(tmp_path.name, base_dir=tmp_path.parent).streams.keys() == log.streams.keys()


def expect(tmp_path, name, text, row, column, match, **kw):
    p = write(tmp_path, name, text)
    with pytest.raises(InputError, match=match) as info:
        read_stream(p, **kw)
    err = info.value
    assert err.file == str(p)
    assert err.row == row
    assert err.column == column
    assert str(p) in str(err)
    return err


@pytest.mark.parametrize(
    ("text", "row", "column", "match"),
    [
        ("t,ds,dtheta\n0.1,0.1,0\n0.2,nan,0\n", 3, "ds", "not finite"),
        ("t,ds,dtheta\n0.1,0.1,0\n0.2,0.1,inf\n", 3, "dtheta", "not finite"),
        ("t,ds,dtheta\n0.1,0.1,0\n0.2,abc,0\n", 3, "ds", "not a number"),
        ("t,ds,dtheta\n0.1,0.1,0\n0.2,,0\n", 3, "ds", "empty cell"),
        ("t,ds,dtheta\n0.1,0.1,0\n0.2,0.1\n", 3, "dtheta", "too few"),
        ("t,ds,dtheta\n0.1,0.1,0\n0.2,0.1,0,7\n", 3, None, "too many"),
        ("t,ds\n0.1,0.1\n", 1, "dtheta", "missing column"),
        ("t,ds,dtheta,foo\n0.1,0.1,0,1\n", 1, "foo", "unexpected column"),
        ("time,ds,dtheta\n0.1,0.1,0\n", 1, "t", "first column"),
        ("t,ds,ds\n0.1,0.1,0\n", 1, "ds", "twice"),
        ("t,ds,dtheta\n0.1,0.1,0\n0.3,0.1,0\n0.2,0.1,0\n", 4, "t", "backwards"),
        ("t,ds,dtheta\n0.1,0.1,0\n0.1,0.2,0\n", 3, "ds", "duplicate time stamp"),
        ("t,ds,dtheta\n", 2, None, "no data rows"),
        ("", 1, None, "empty file"),
        ("t,ds,dtheta\n0.1,0.1,7.0\n", 2, "dtheta", "angle"),
    ],
)
def test_bad_odometry(tmp_path, text, row, column, match):
    expect(tmp_path, "odometry.csv", text, row, column, match)


def test_blank_lines_keep_line_numbers(tmp_path):
    expect(tmp_path, "gyro.csv", "t,wz\n0.1,0.1\n\n0.3,x\n", 4, "wz", "not a number")


def test_out_of_range_values(tmp_path):
    expect(tmp_path, "ranges.csv", "t,id,range\n0.1,1,5\n0.2,1,-1\n", 3, "range", "negative")
    expect(tmp_path, "ranges.csv", "t,id,range\n0.1,1.5,5\n", 2, "id", "integer")
    expect(tmp_path, "compass.csv", "t,heading\n0.1,7.0\n", 2, "heading", "angle")
    expect(tmp_path, "gps.csv", "t,lat,lon\n0.1,91,9\n", 2, "lat", "latitude")
    expect(tmp_path, "gps.csv", "t,x,y,sigma\n0.1,1,2,0\n", 2, "sigma", "positive")
    expect(tmp_path, "gps.csv", "t,x,lat\n0.1,1,2\n", 1, "y", "t, x, y")
    expect(tmp_path, "ranges.csv", "t,id,range\n0.1,3,5\n", 2, "id", "map.csv", landmark_ids={1, 2})


def test_duplicates_dropped_and_counted(tmp_path):
    p = write(tmp_path, "odometry.csv", "t,ds,dtheta\n0.1,0.1,0\n0.1,0.1,0\n0.2,0.1,0\n0.2,0.1,0\n")
    repairs = {}
    s = read_stream(p, repairs=repairs)
    assert len(s) == 2
    assert repairs == {"odometry.duplicate_rows": 2}


def test_ranges_share_time_stamps_but_not_ids(tmp_path):
    p = write(tmp_path, "ranges.csv", "t,id,range\n0.1,1,5\n0.1,2,6\n0.1,1,5\n")
    repairs = {}
    s = read_stream(p, repairs=repairs)
    assert len(s) == 2 and repairs == {"ranges.duplicate_rows": 1}
    expect(
        tmp_path,
        "ranges.csv",
        "t,id,range\n0.1,1,5\n0.1,2,6\n0.1,1,5.5\n",
        4,
        "range",
        "time stamp and id",
    )


def test_gaps_are_counted(tmp_path):
    t = np.r_[np.arange(0, 1, 0.1), np.arange(5, 6, 0.1), np.arange(20, 21, 0.1)]
    rows = "\n".join(f"{v:.1f},0.5" for v in t)
    repairs = {}
    read_stream(write(tmp_path, "gyro.csv", "t,wz\n" + rows + "\n"), repairs=repairs)
    assert repairs == {"gyro.gaps": 2}


def test_encoder_ticks_and_rollover(tmp_path):
    # 1000 ticks per wheel revolution (250 at the encoder x gear 4), 16-bit counter that wraps.
    ticks = np.array([65000, 65400, 264, 700, 1200])  # +400, +400 (wrapped), +436, +500
    rows = "\n".join(f"{0.1 * i:.1f},{v},{v}" for i, v in enumerate(ticks))
    p = write(tmp_path, "wheels.csv", "t,left,right\n" + rows + "\n")
    repairs = {}
    s = read_stream(
        p, repairs=repairs, encoder={"ticks_per_rev": 250, "gear_ratio": 4, "rollover": 65536}
    )
    expected = (65000 + np.array([0, 400, 800, 1236, 1736])) * 2 * math.pi / 1000
    np.testing.assert_allclose(s["left"], expected, rtol=1e-12)
    np.testing.assert_allclose(s["right"], expected, rtol=1e-12)
    assert repairs == {"wheels.rollover_unwraps": 2}  # one wrap in each of two columns


def test_encoder_backwards_rollover(tmp_path):
    # 100 -> 65436 on a 16-bit counter is -200 ticks, not +65336.
    p = write(tmp_path, "wheels.csv", "t,left,right,steer\n0,100,5,0.1\n1,65436,5,0.2\n")
    repairs = {}
    s = read_stream(p, repairs=repairs, encoder={"ticks_per_rev": 100, "rollover": 65536})
    np.testing.assert_allclose(s["left"], np.array([100, -100]) * 2 * math.pi / 100, atol=1e-12)
    np.testing.assert_allclose(s["steer"], [0.1, 0.2])  # steering is radians, untouched
    assert repairs == {"wheels.rollover_unwraps": 1}


def test_map_errors(tmp_path):
    p = write(tmp_path, "map.csv", "id,x,y\n1,0,0\n1,2,2\n")
    with pytest.raises(InputError, match="twice") as info:
        read_map(p)
    assert (info.value.row, info.value.column) == (3, "id")


def test_empty_folder_and_missing_folder(tmp_path):
    with pytest.raises(InputError, match="no stream files"):
        read_csv_log(tmp_path)
    with pytest.raises(InputError, match="not found"):
        load_log(tmp_path / "nope")


def test_export_roundtrip_plaza1(tmp_path):
    log = load_log("builtin:plaza1")
    # Plaza1's TD stream jumps back in time twice; the loader sorts it, drops 2 conflicting
    # repeats and counts both, so the export has nothing left to change.
    assert log.repairs == {"ranges.reordered": 425, "ranges.duplicates_dropped": 2}
    _, changes = write_csv_log(log, tmp_path)
    assert changes == {}
    back = read_csv_log(tmp_path)
    np.testing.assert_array_equal(back.streams["odometry"].values, log.streams["odometry"].values)
    np.testing.assert_array_equal(back.groundtruth.t, log.groundtruth.t)
    np.testing.assert_array_equal(back.streams["ranges"].values, log.streams["ranges"].values)
    assert sorted(back.landmarks) == sorted(log.landmarks)


def test_million_rows_load_and_error_is_precise(tmp_path):
    n = 1_000_000
    rng = np.random.default_rng(0)
    t = np.arange(n) * 0.01
    left = np.cumsum(rng.integers(0, 50, n))
    table = np.column_stack([t, left, left + 3])
    path = tmp_path / "wheels.csv"
    np.savetxt(
        path, table, fmt=["%.2f", "%d", "%d"], delimiter=",", header="t,left,right", comments=""
    )
    log = read_csv_log(tmp_path)
    assert len(log.streams["wheels"]) == n
    lines = path.read_text().splitlines()
    lines[777_778] = lines[777_778].replace(",", ",oops", 1)  # line 777779 in the file
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as info:
        read_csv_log(tmp_path)
    assert (info.value.row, info.value.column) == (777_779, "left")


def test_encoder_columns_follow_the_drive(tmp_path):
    # tricycle inputs: ("wheel", "steer"); only the wheel column is in ticks
    from odofuse.config import config_from_dict
    from odofuse.io.loader import load_log_for

    write(tmp_path, "wheels.csv", "t,wheel,steer\n0,0,0.1\n1,500,0.2\n")
    cfg = config_from_dict(
        {
            "log": str(tmp_path),
            "robot": {
                "drive": "tricycle",
                "wheel_radius": 0.1,
                "wheelbase": 0.5,
                "encoder": {"ticks_per_rev": 1000},
            },
        },
        "cfg.yaml",
    )
    s = load_log_for(cfg).streams["wheels"]
    np.testing.assert_allclose(s["wheel"], [0.0, math.pi])
    np.testing.assert_allclose(s["steer"], [0.1, 0.2])


# the fast (numpy C reader) and exact (line by line) paths of read_table must agree on every
# input: the same arrays and line numbers, or the same one-line error
_TRICKY = [
    b"t,x\n1,2\n3,4\n",
    b"t,x\r\n1,2\r\n3,4\r\n",
    b"t,x\n1,2\n3,4",
    b"t,x\n1,2\n\n3,4\n",
    b"t,x\n1,2\n3\n",
    b"t,x\n1,2\n3,4,5\n",
    b"t,x\n1,nan\n",
    b"t,x\n1,1e16\n",
    b"t,x\n1,1_0\n",
    b"\xef\xbb\xbft,x\n1,2\n",
    b"t,x\n1,\xff\n",
    b"t,x\n1, 2 \n3,\t4\n",
    b"t,x\n1,2\r3,4\n",
    b"t,x\n",
    b"",
    b"t,t\n1,2\n",
    b"x,t\n1,2\n",
    b"t,x\n1,abc\n",
    b"t,x\n1,2\n3,4\r",
    b"t,x\n" + b"1,2\n" * 5 + b"1" * 9000 + b"\n",
    b"t,x\n1,+inf\n",
    b"t,x\n1,.5\n2,5.\n3,1E3\n",
    b"t , x \n1,2\n",
    b"t\n1\n2\n",
    b"t,x\n1,2\n   \n",
    b"t,x\n1,2\n,\n",
    b't,x\n1,"2"\n',
    b"t,x\n1,0x1\n",
    b"t,x\n1,True\n",
    b"t,x\n1,2\x0c\n",
    b"t,x\n1,2\n3,4\n\n\n",
]


@pytest.mark.parametrize("chunk", [None, 5])
def test_fast_and_exact_csv_paths_agree(tmp_path, monkeypatch, chunk):
    from odofuse.io import csvtable

    if chunk:  # chunk and block boundaries inside lines and line breaks
        monkeypatch.setattr(csvtable, "_CHUNK", chunk)
        monkeypatch.setattr(csvtable, "_BLOCK", 3)
    rng = np.random.default_rng(0)
    cells = ["1", "2.5", "-3e2", " 4 ", "", "nan", "1_0", "x", "1e20", "0.1", "7"]
    cases = list(_TRICKY)
    for _ in range(150):
        rows = [
            ",".join(rng.choice(cells) for _ in range(rng.integers(1, 4)))
            for _ in range(rng.integers(1, 6))
        ]
        sep, end = rng.choice(["\n", "\r\n"]), rng.choice(["", "\n"])
        cases.append(("t,a,b\n" + sep.join(rows) + end).encode())

    def outcome(read, *args):
        try:
            header, data, lines = read(*args)
            return header, data.shape, data.tobytes(), lines.tolist()
        except InputError as exc:
            return str(exc)

    fast = 0
    for k, raw in enumerate(cases):
        p = tmp_path / f"c{k}.csv"
        p.write_bytes(raw)
        got = outcome(csvtable.read_table, p, "t")
        assert got == outcome(csvtable._read_exact, p, str(p), "t"), raw
        if not isinstance(got, str):
            fast += csvtable._read_fast(p, str(p), "t") is not None
    assert fast >= 5  # the fast path did serve the plain files (9 of these cases)
