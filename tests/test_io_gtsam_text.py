"""2-D pose-graph text files: mapping to an odometry stream, checked against gtsam's readers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.errors import InputError
from odofuse.io.gtsam_text import read_gtsam_text
from odofuse.io.loader import load_log

gtsam = pytest.importorskip("gtsam")


def test_small_graph_reference(tmp_path):
    p = tmp_path / "g.txt"
    p.write_text(
        "VERTEX_SE2 0 1.0 2.0 0.5\n"
        "VERTEX_SE2 1 2.0 2.0 0.5\n"
        "EDGE_SE2 0 1 1.0 0.0 0.2 1 0 0 1 0 1\n"
        "EDGE_SE2 2 1 0.5 0.0 0.0 1 0 0 1 0 1\n"  # stored backwards: pose 1 seen from pose 2
        "EDGE_SE2 0 2 9.0 9.0 9.0 1 0 0 1 0 1\n"  # loop closure
        "LANDMARK 1 7 3.0 4.0 0.4 0 0.4\n"
    )
    log = read_gtsam_text(p)
    o = log.streams["odometry"]
    np.testing.assert_allclose(o.t, [1.0, 2.0])
    np.testing.assert_allclose(o.values[:, :2], [[1.0, 0.2], [-0.5, 0.0]], atol=1e-12)
    np.testing.assert_allclose(log.initial_pose, [1.0, 2.0, 0.5])
    # The loop closure is kept as a stream (issue 12), no longer skipped and counted.
    assert log.repairs == {}
    lc = log.streams["loop_closures"]
    np.testing.assert_allclose(lc.values[:, :5], [[0.0, 2.0, 9.0, 9.0, 9.0 - 2 * math.pi]])
    lm = log.streams["landmarks"]
    np.testing.assert_allclose(lm.values[:, :3], [[7.0, 5.0, math.atan2(4.0, 3.0)]])
    assert load_log(p).streams.keys() == log.streams.keys()  # sniffed by content


@pytest.mark.parametrize(
    ("name", "reader"), [("pose2example.txt", "readG2o"), ("w100.graph", "load2D")]
)
def test_matches_gtsam_between_factors(name, reader):
    path = gtsam.findExampleDataFile(name)
    o = load_log(path).streams["odometry"]
    graph, _ = gtsam.readG2o(path, False) if reader == "readG2o" else gtsam.load2D(path)
    compared = 0
    for i in range(graph.size()):
        f = graph.at(i)
        if not isinstance(f, gtsam.BetweenFactorPose2):
            continue
        a, b = f.keys()
        m = f.measured()
        if abs(a - b) != 1:
            continue
        if a > b:
            m, a, b = m.inverse(), b, a
        k = int(np.flatnonzero(o.t == b)[0])
        ds = math.copysign(math.hypot(m.x(), m.y()), m.x())
        np.testing.assert_allclose(o.values[k, :2], [ds, m.theta()], atol=1e-9)
        compared += 1
    assert compared == len(o) > 5


@pytest.mark.parametrize(
    ("text", "line", "match"),
    [
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1.0 x 0 1 0 0 1 0 1\n", 2, "non-numeric"),
        ("EDGE_SE2 0 1 1.0 0\n", 1, "at least"),
        ("EDGE_SE2 0 1 1 0 0\nEDGE_SE2 1 0 1 0 0\n", 2, "second odometry edge"),
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n", 1, "3-D"),
        ("EDGE_SE2 0 1 nan 0 0\n", 1, "non-finite"),
        ("BANANA 1 2\n", 1, "unknown line type"),
    ],
)
def test_bad_lines(tmp_path, text, line, match):
    p = tmp_path / "g.g2o"
    p.write_text(text)
    with pytest.raises(InputError, match=match) as info:
        read_gtsam_text(p)
    assert info.value.row == line and info.value.file == str(p)


def test_broken_chain(tmp_path):
    p = tmp_path / "g.g2o"
    p.write_text("EDGE_SE2 0 1 1 0 0\nEDGE_SE2 2 3 1 0 0\n")
    with pytest.raises(InputError, match="between poses 1 and 2"):
        read_gtsam_text(p)
