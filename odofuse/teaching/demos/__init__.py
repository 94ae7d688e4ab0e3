"""Teaching demos: each writes one slide-ready PNG and returns its numbers.

========================  ======================================================================
``integration``           Euler vs Runge-Kutta 2 vs exact integration against the step size
                          (Politecnico slides ``003_73fced8ec7c15fe5.txt``).
``error_growth``          Siegwart's linearised covariance propagation (``004_...``)
                          against a Monte-Carlo cloud, with NEES; where the banana parts from
                          the ellipse for large heading noise.
``systematic``            Systematic vs non-systematic errors on UMBmark squares and the
                          UMBmark correction (``002_88fc37db58155723.txt``, Borenstein & Feng).
``gyrodometry``           Borenstein's gyrodometry over a bump and a slip burst (``002_...``).
``fusion``                Dead reckoning vs EKF vs smoother through a GPS outage.
``drive_zoo``             Each drive's ICR, degree of mobility and inverse kinematics.
========================  ======================================================================

Every demo is ``demo_<name>(out_dir=".", quick=False, seed=0) -> {"png": path, "numbers": dict}``;
``quick`` shrinks sample counts so the test-suite can run them in seconds. This package owns
the registry (:data:`DEMOS`, :func:`run_demo`); the demos live by group in
:mod:`~odofuse.teaching.demos.motion`, :mod:`~odofuse.teaching.demos.odometry_errors`,
:mod:`~odofuse.teaching.demos.fusion` and :mod:`~odofuse.teaching.demos.drive_zoo`, the shared
drawing helpers in :mod:`~odofuse.teaching.demos.figures`.
"""

from __future__ import annotations

from odofuse.teaching.demos.drive_zoo import demo_drive_zoo
from odofuse.teaching.demos.figures import _ellipse, nees_bounds  # noqa: F401 (_ellipse: tests)
from odofuse.teaching.demos.fusion import demo_fusion
from odofuse.teaching.demos.motion import demo_error_growth, demo_integration
from odofuse.teaching.demos.odometry_errors import (
    demo_gyrodometry,
    demo_systematic,
    gyrodometry,
    plot_umbmark,
)

__all__ = [
    "DEMOS",
    "run_demo",
    "demo_integration",
    "demo_error_growth",
    "demo_systematic",
    "demo_gyrodometry",
    "demo_fusion",
    "demo_drive_zoo",
    "gyrodometry",
    "nees_bounds",
    "plot_umbmark",
]

DEMOS = {
    "integration": demo_integration,
    "error_growth": demo_error_growth,
    "systematic": demo_systematic,
    "gyrodometry": demo_gyrodometry,
    "fusion": demo_fusion,
    "drive_zoo": demo_drive_zoo,
}


def run_demo(name: str, out_dir=".", quick: bool = False, seed: int = 0) -> dict:
    """Run demo ``name`` (a key of :data:`DEMOS`); returns ``{"png", "numbers"}``."""
    if name not in DEMOS:
        raise ValueError(f"unknown demo '{name}'; known: {', '.join(sorted(DEMOS))}")
    return DEMOS[name](out_dir=out_dir, quick=quick, seed=seed)
