"""UMBmark: measuring and correcting systematic odometry errors of a differential drive.

After Borenstein & Feng (1996), "Measurement and correction of systematic odometry errors in
mobile robots" (the "Borenstein paper" that ``002_88fc37db58155723.txt`` points to for calibrating
out systematic errors). The robot drives an L x L square, using its own odometry, ``n`` times
clockwise and ``n`` times counter-clockwise; each time the true return position is compared
with the position its odometry computed. Two dominant systematic errors explain the
centroids of these return errors:

* **type A**, a wheelbase error: every nominal 90 degree turn really turns ``90 - alpha``
  degrees, ``E_b = b_actual / b_nominal = 90 / (90 - alpha)``;
* **type B**, unequal wheel diameters: every nominally straight leg bends by ``beta`` (left
  when the right wheel is larger), an arc of radius ``R = (L/2) / sin(beta/2)``, so
  ``E_d = D_R / D_L = (R + b/2) / (R - b/2)``.

Linearising the four legs (start at a corner heading along +x; return error
``eps = p_true - p_odometry`` in the start frame) gives

``x_cw = -2L(alpha + beta)``, ``y_cw = -2L(alpha + beta)``,
``x_ccw = 2L(beta - alpha)``, ``y_ccw = -2L(beta - alpha)``,

hence Borenstein's ``alpha = (x_cw + x_ccw) / (-4L)`` and ``beta = (x_cw - x_ccw) / (-4L)``,
and from the y centroids ``alpha = (y_cw - y_ccw) / (-4L)``, ``beta = (y_cw + y_ccw) / (-4L)``;
this module averages the two. The corrected geometry keeps the mean wheel diameter:
``D_L <- 2/(E_d + 1) D_L``, ``D_R <- 2/(1/E_d + 1) D_R`` and ``b <- E_b b``.

The figure of merit is the systematic return error
``E_max,syst = max(|centroid_cw|, |centroid_ccw|)`` (m).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from odofuse import se2

__all__ = [
    "UMBmarkEstimate",
    "UMBmarkReport",
    "return_error",
    "umbmark_estimate",
    "square_return_error",
    "corrected_geometry",
    "systematic_return_error",
    "umbmark_runs",
    "calibrate_umbmark",
    "umbmark_from_logs",
]


@dataclass(frozen=True)
class UMBmarkEstimate:
    """Result of :func:`umbmark_estimate`.

    Attributes
    ----------
    alpha, beta : float
        Type A (turn) and type B (leg curvature) errors, rad.
    E_b, E_d : float
        Wheelbase ratio (actual / nominal) and wheel diameter ratio (right / left).
    R : float
        Radius of the curved legs, m (``inf`` for ``beta = 0``; negative when curving right).
    centroid_cw, centroid_ccw : ndarray (2,)
        Centroids of the return errors, m, start frame.
    """

    alpha: float
    beta: float
    E_b: float
    E_d: float
    R: float
    centroid_cw: np.ndarray
    centroid_ccw: np.ndarray


@dataclass(frozen=True)
class UMBmarkReport:
    """Result of :func:`calibrate_umbmark`: estimate, geometries and errors before and after."""

    estimate: UMBmarkEstimate
    nominal_geometry: dict
    corrected_geometry: dict
    true_geometry: dict
    errors_before: dict  # {"cw": (n, 2), "ccw": (n, 2)}
    errors_after: dict
    e_max_before: float
    e_max_after: float

    @property
    def reduction(self) -> float:
        """``E_max,syst`` before over after."""
        return self.e_max_before / self.e_max_after if self.e_max_after > 0 else math.inf

    def summary(self) -> dict:
        """Plain-number summary (JSON-serialisable)."""
        est = self.estimate
        return {
            "alpha_deg": math.degrees(est.alpha),
            "beta_deg": math.degrees(est.beta),
            "E_b": est.E_b,
            "E_d": est.E_d,
            "e_max_syst_before_m": self.e_max_before,
            "e_max_syst_after_m": self.e_max_after,
            "reduction": self.reduction,
            "corrected_geometry": dict(self.corrected_geometry),
        }


def return_error(start, true_final, odometry_final) -> np.ndarray:
    """Return position error ``eps = p_true - p_odometry`` in the start frame, m, shape (2,).

    Parameters
    ----------
    start : array_like (3,)
        Start pose (world frame); its heading defines the +x axis of the square.
    true_final, odometry_final : array_like (3,) or (2,)
        Final positions measured externally and computed by odometry (world frame).
    """
    th = float(np.asarray(start, dtype=float)[2])
    d = np.asarray(true_final, dtype=float)[:2] - np.asarray(odometry_final, dtype=float)[:2]
    return se2.rot(-th)[:2, :2] @ d


def umbmark_estimate(
    errors_cw, errors_ccw, side: float, track_width: float, method: str = "exact"
) -> UMBmarkEstimate:
    """Borenstein & Feng's estimate of ``E_b`` and ``E_d`` from square-run return errors.

    Parameters
    ----------
    errors_cw, errors_ccw : array_like (n, 2)
        Return errors ``p_true - p_odometry`` of the clockwise and counter-clockwise runs,
        start frame (the square's first leg along +x), m.
    side : float
        Side length L of the square, m.
    track_width : float
        Nominal wheelbase b, m (scaled by the estimated ``E_b`` before computing ``E_d``:
        the legs bend with the *actual* wheelbase).
    method : {"exact", "linear"}
        ``"linear"``: Borenstein & Feng's closed form (first order in alpha, beta; the leg
        radius from the chord, ``R = (L/2) / sin(beta/2)``). ``"exact"``: starts there and
        inverts the exact square geometry of :func:`square_return_error` (legs are arcs of
        length L, ``R = L / beta``), removing the second-order bias that grows with the
        errors (about 8 % of ``E_b - 1`` for ``E_d = 0.997``, ``E_b = 0.985`` on a 4 m square).

    Returns
    -------
    UMBmarkEstimate
    """
    cw = np.atleast_2d(np.asarray(errors_cw, dtype=float))
    ccw = np.atleast_2d(np.asarray(errors_ccw, dtype=float))
    if cw.shape[1] != 2 or ccw.shape[1] != 2 or not len(cw) or not len(ccw):
        raise ValueError(f"return errors must be (n, 2) arrays, got {cw.shape} and {ccw.shape}")
    if not side > 0 or not track_width > 0:
        raise ValueError(f"side and track_width must be positive, got {side}, {track_width}")
    c_cw, c_ccw = cw.mean(axis=0), ccw.mean(axis=0)
    L = float(side)
    alpha, beta = _linear_alpha_beta(c_cw, c_ccw, L)
    if method == "linear":
        R = math.inf if abs(beta) < 1e-15 else (L / 2) / math.sin(beta / 2)
    elif method == "exact":
        # Chord (simplified Newton) iterations: the linear map is the Jacobian of the square's
        # return error at alpha = beta = 0, so applying it to the residual of the exact model
        # converges to the exact inverse for the moderate errors UMBmark is used on.
        for _ in range(50):
            r_cw = c_cw - square_return_error(alpha, beta, L, "cw")
            r_ccw = c_ccw - square_return_error(alpha, beta, L, "ccw")
            d_alpha, d_beta = _linear_alpha_beta(r_cw, r_ccw, L)
            alpha, beta = alpha + d_alpha, beta + d_beta
            if abs(d_alpha) + abs(d_beta) < 1e-13:
                break
        R = math.inf if abs(beta) < 1e-15 else L / beta  # the leg is an arc of length L
    else:
        raise ValueError(f"method must be 'exact' or 'linear', got {method!r}")
    E_b = (math.pi / 2) / (math.pi / 2 - alpha)
    b = E_b * float(track_width)
    E_d = 1.0 if math.isinf(R) else (R + b / 2) / (R - b / 2)
    return UMBmarkEstimate(alpha, beta, E_b, E_d, R, c_cw, c_ccw)


def _linear_alpha_beta(c_cw, c_ccw, L: float) -> tuple[float, float]:
    """Borenstein's linear alpha, beta (rad) from the x and the y centroids, averaged."""
    (x_cw, y_cw), (x_ccw, y_ccw) = c_cw, c_ccw
    alpha = 0.5 * ((x_cw + x_ccw) / (-4 * L) + (y_cw - y_ccw) / (-4 * L))
    beta = 0.5 * ((x_cw - x_ccw) / (-4 * L) + (y_cw + y_ccw) / (-4 * L))
    return float(alpha), float(beta)


def square_return_error(alpha: float, beta: float, side: float, direction: str) -> np.ndarray:
    """Exact return position of Borenstein's error model on one UMBmark square, m, shape (2,).

    Each of the four legs is an arc of length ``side`` whose heading changes by ``beta`` (rad);
    each corner turns ``+-(pi/2 - alpha)`` in place (``+`` for ``"ccw"``). The robot starts at
    the origin heading along +x, so the returned point is the return error in the start frame.
    """
    if direction not in ("cw", "ccw"):
        raise ValueError(f"direction must be 'cw' or 'ccw', got {direction!r}")
    sgn = 1.0 if direction == "ccw" else -1.0
    pose = np.zeros(3)
    leg = se2.exp(np.array([beta, side, 0.0]))
    turn = np.array([0.0, 0.0, sgn * (math.pi / 2 - alpha)])
    for _ in range(4):
        pose = se2.compose(se2.compose(pose, leg), turn)
    return pose[:2]


def corrected_geometry(geometry: Mapping, E_d: float, E_b: float) -> dict:
    """Differential-drive geometry corrected by Borenstein's factors.

    ``r_L <- 2/(E_d + 1) r_L``, ``r_R <- 2/(1/E_d + 1) r_R`` (mean radius kept) and
    ``track_width <- E_b track_width``. Returns a new dict with ``wheel_radius_left/right``.
    """
    g = dict(geometry)
    if "track_width" not in g or "wheel_radius" not in g:
        raise ValueError("UMBmark correction needs 'wheel_radius' and 'track_width'")
    r = float(g["wheel_radius"])
    g["wheel_radius_left"] = float(g.get("wheel_radius_left") or r) * 2.0 / (E_d + 1.0)
    g["wheel_radius_right"] = float(g.get("wheel_radius_right") or r) * 2.0 / (1.0 / E_d + 1.0)
    g["track_width"] = float(g["track_width"]) * E_b
    return g


def systematic_return_error(errors_cw, errors_ccw) -> float:
    """``E_max,syst = max(|centroid_cw|, |centroid_ccw|)``, m."""
    c1 = np.asarray(errors_cw, dtype=float).reshape(-1, 2).mean(axis=0)
    c2 = np.asarray(errors_ccw, dtype=float).reshape(-1, 2).mean(axis=0)
    return float(max(np.hypot(*c1), np.hypot(*c2)))


def umbmark_runs(scenario, runs: int = 5, side: float = 4.0, seed: int = 0) -> dict:
    """Simulate ``runs`` clockwise and ``runs`` counter-clockwise UMBmark squares.

    The robot's controller follows the square with its nominal geometry (so its odometry
    believes it came back), the truth moves through the scenario's true geometry.

    Parameters
    ----------
    scenario : odofuse.teaching.simulate.Scenario
        A differential or skid-steer robot; its ``path`` is replaced by the squares, its
        sensors are dropped.
    runs : int
    side : float
        m.
    seed : int
        Seeds every run: the runs' own seeds are drawn from ``default_rng(seed)``.

    Returns
    -------
    dict
        ``{"cw": (runs, 2), "ccw": (runs, 2)}`` return errors (m, start frame), plus
        ``"true_geometry"`` and ``"paths"``: ``{"cw": [truth (N, 3)...], "ccw": [...]}``.
    """
    from odofuse.drives import make_drive
    from odofuse.motion import MotionModel, OdometryErrorModel, dead_reckon
    from odofuse.teaching.simulate import simulate

    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    base = replace(scenario, gyro=None, gps=None, ranges=None, landmarks=None, compass=None)
    drive = make_drive(base.drive, **dict(base.geometry))
    n = len(drive.input_names)
    model = MotionModel(drive, OdometryErrorModel((0.0,) * n, (0.0,) * n), "exact")
    out: dict = {"cw": [], "ccw": [], "paths": {"cw": [], "ccw": []}}
    path0 = dict(base.path) if dict(base.path).get("kind") == "square" else {}
    seeds = np.random.default_rng(seed).integers(0, 2**31 - 1, size=(runs, 2))
    for i in range(runs):
        for j, direction in enumerate(("cw", "ccw")):
            path = {**path0, "kind": "square", "side": side, "direction": direction, "laps": 1}
            sim = simulate(replace(base, path=path), seed=int(seeds[i, j]))
            odo, _ = dead_reckon(model, sim.truth[0], np.zeros((3, 3)), sim.u_meas, with_cov=False)
            out[direction].append(return_error(sim.truth[0], sim.truth[-1], odo[-1]))
            out["paths"][direction].append(sim.truth)
            out["true_geometry"] = sim.true_geometry
    out["cw"] = np.array(out["cw"])
    out["ccw"] = np.array(out["ccw"])
    return out


def calibrate_umbmark(
    scenario, runs: int = 5, side: float = 4.0, seed: int = 0, method: str = "exact"
) -> UMBmarkReport:
    """The whole UMBmark procedure on a simulated robot: measure, estimate, correct, re-measure.

    Parameters
    ----------
    scenario : odofuse.teaching.simulate.Scenario
        Nominal geometry plus the robot's (hidden) systematic errors.
    runs, side, seed
        See :func:`umbmark_runs`; the runs after the correction use ``seed + 1``.
    method : {"exact", "linear"}
        See :func:`umbmark_estimate`.

    Returns
    -------
    UMBmarkReport
    """
    before = umbmark_runs(scenario, runs, side, seed)
    nominal = dict(scenario.geometry)
    est = umbmark_estimate(before["cw"], before["ccw"], side, float(nominal["track_width"]), method)
    fixed = corrected_geometry(nominal, est.E_d, est.E_b)
    after_scenario = replace(scenario, geometry=fixed, actual_geometry=before["true_geometry"])
    after = umbmark_runs(after_scenario, runs, side, seed + 1)
    return UMBmarkReport(
        estimate=est,
        nominal_geometry=nominal,
        corrected_geometry=fixed,
        true_geometry=dict(before["true_geometry"]),
        errors_before={"cw": before["cw"], "ccw": before["ccw"]},
        errors_after={"cw": after["cw"], "ccw": after["ccw"]},
        e_max_before=systematic_return_error(before["cw"], before["ccw"]),
        e_max_after=systematic_return_error(after["cw"], after["ccw"]),
    )


def _log_return_error(folder) -> tuple[np.ndarray, dict]:
    from pathlib import Path

    from odofuse.config import load_config
    from odofuse.errors import InputError
    from odofuse.estimators.common import odometry_inputs
    from odofuse.io.loader import load_log_for
    from odofuse.motion import dead_reckon, motion_model_from_config

    cfg_path = Path(folder) / "config.yaml"
    if not cfg_path.exists():
        raise InputError("UMBmark log folder needs a config.yaml naming the robot", str(folder))
    config = load_config(cfg_path)
    log = load_log_for(config)
    if log.groundtruth is None or len(log.groundtruth) < 2:
        raise InputError(
            "UMBmark needs groundtruth.csv (the externally measured poses)", str(folder)
        )
    model = motion_model_from_config(config)
    _, U = odometry_inputs(log, model)
    gt = log.groundtruth.values
    odo, _ = dead_reckon(model, gt[0], np.zeros((3, 3)), U, with_cov=False)
    return return_error(gt[0], gt[-1], odo[-1]), dict(config.robot)


def umbmark_from_logs(cw_folders, ccw_folders, side: float, method: str = "exact") -> dict:
    """UMBmark from recorded square runs (log folders with ``config.yaml`` and ground truth).

    Each folder's odometry is dead-reckoned with its config's nominal robot from the first
    ground-truth pose; the return error is the last ground-truth position minus the odometry's.

    Returns
    -------
    dict
        ``alpha_deg``, ``beta_deg``, ``E_b``, ``E_d``, ``e_max_syst_m``, ``corrected_geometry``.
    """
    cw = [_log_return_error(f) for f in cw_folders]
    ccw = [_log_return_error(f) for f in ccw_folders]
    robot = cw[0][1]
    geometry = {k: v for k, v in robot.items() if k not in ("drive", "encoder")}
    est = umbmark_estimate(
        [e for e, _ in cw], [e for e, _ in ccw], side, float(geometry["track_width"]), method
    )
    return {
        "alpha_deg": math.degrees(est.alpha),
        "beta_deg": math.degrees(est.beta),
        "E_b": est.E_b,
        "E_d": est.E_d,
        "e_max_syst_m": systematic_return_error([e for e, _ in cw], [e for e, _ in ccw]),
        "corrected_geometry": corrected_geometry(geometry, est.E_d, est.E_b),
    }
