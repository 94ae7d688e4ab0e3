"""Drawing helpers shared by the demos: figures, colours, atomic PNG saving, ellipses, markers.

Pictures are drawn on a bare :class:`matplotlib.figure.Figure` (no pyplot state, no display
needed); matplotlib is imported only when a figure is made. Also :func:`nees_bounds`, the NEES
consistency band the demos draw.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from odofuse import se2
from odofuse.io.atomic import atomic_write

_COLORS = {
    "truth": "black",
    "euler": "tab:red",
    "rk2": "tab:blue",
    "exact": "tab:green",
    "odometry": "tab:red",
    "gyro": "tab:orange",
    "gyrodometry": "tab:blue",
    "dead_reckoning": "tab:red",
    "ekf": "tab:blue",
    "smoother": "tab:green",
    "gps": "tab:gray",
}


def _figure(ncols: int = 2, nrows: int = 1, size=(6.0, 5.0)):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size[0] * ncols, size[1] * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def _save(fig, out_dir, name: str) -> str:
    """Write ``fig`` to ``out_dir/name.png`` atomically; returns the path."""
    path = Path(out_dir) / f"{name}.png"
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return str(path)


def _xy_axes(ax, title: str) -> None:
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)


def _ellipse(mean, cov, prob: float = 0.95, points: int = 90) -> np.ndarray:
    """Outline (points, 2) of the ``prob`` confidence ellipse of a 2-D Gaussian."""
    from odofuse.plotting import covariance_ellipse

    r = math.sqrt(-2.0 * math.log(1.0 - prob))  # chi-square 2 dof quantile, closed form
    return covariance_ellipse(mean, cov, n_sigma=r, points=points)


def nees_bounds(n_runs: int, dim: int = 3, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` bounds of the mean NEES of ``n_runs`` consistent samples.

    ``n_runs * mean NEES`` is chi-square with ``n_runs * dim`` degrees of freedom
    (Bar-Shalom, Li & Kirubarajan, section 5.4).
    """
    from scipy.stats import chi2

    dof = n_runs * dim
    lo = chi2.ppf(0.5 * (1 - prob), dof) / n_runs
    hi = chi2.ppf(0.5 * (1 + prob), dof) / n_runs
    return float(lo), float(hi)


def _robot_marker(ax, pose, size: float, color: str, **kw) -> None:
    x, y, th = pose
    pts = np.array([[size, 0.0], [-0.6 * size, 0.5 * size], [-0.6 * size, -0.5 * size]])
    R = se2.rot(th)[:2, :2]
    tri = pts @ R.T + [x, y]
    ax.fill(tri[:, 0], tri[:, 1], color=color, alpha=0.8, **kw)
