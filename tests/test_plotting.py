"""Plots: the ellipse geometry and a PNG that exists, decodes and is written atomically."""

from __future__ import annotations

import os

import numpy as np
import pytest

from odofuse.io.log import SensorLog, Stream
from odofuse.plotting import covariance_ellipse, plot_run
from odofuse.trajectory import EstimateResult, Trajectory


def test_ellipse_is_the_two_sigma_contour():
    cov = np.array([[4.0, 1.2], [1.2, 1.0]])
    pts = covariance_ellipse([1.0, -2.0], cov, n_sigma=2.0, points=100)
    d = pts - [1.0, -2.0]
    mahal = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
    np.testing.assert_allclose(mahal, 4.0, rtol=1e-12)
    # axis-aligned case: half-axes 2 sigma_x = 4 and 2 sigma_y = 2
    pts = covariance_ellipse([0.0, 0.0], np.diag([4.0, 1.0]), points=401)
    assert np.abs(pts[:, 0]).max() == pytest.approx(4.0)
    assert np.abs(pts[:, 1]).max() == pytest.approx(2.0, rel=1e-4)


def test_plot_run_writes_png(tmp_path):
    import matplotlib.image

    n = 60
    t = np.arange(n, dtype=float)
    poses = np.column_stack([np.cos(t / 10) * 10, np.sin(t / 10) * 10, t / 10 + np.pi / 2])
    covs = np.repeat(np.diag([0.2, 0.1, 0.01])[None], n, axis=0)
    res = EstimateResult("ekf", Trajectory(t, poses, covs))
    gt = Stream("groundtruth", "mem", t, ("x", "y", "theta"), poses * [1.02, 1.02, 1])
    log = SensorLog("mem", {}, {1: np.array([0.0, 0.0]), 2: np.array([5.0, 5.0])}, gt)
    out = plot_run(tmp_path / "p.png", res, log)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = matplotlib.image.imread(out)
    assert img.shape[0] > 400 and img.shape[1] > 400
    assert os.listdir(tmp_path) == ["p.png"]  # no temporary file left
    # a bare trajectory without covariance or log also plots
    plot_run(tmp_path / "q.png", Trajectory(t, poses))
    assert (tmp_path / "q.png").stat().st_size > 1000
