"""Accuracy and consistency of an estimate against ground truth: ATE, RPE, NEES, alignment.

Definitions follow Sturm et al. (TUM RGB-D benchmark, as implemented by evo) restricted to SE(2):

* **ATE** (absolute trajectory error): position error ``|p_est(t) - p_gt(t)|`` at each estimate
  time, ground truth interpolated in time (positions linearly, headings on the circle),
  optionally after a rigid 2-D alignment (:func:`align_se2`); reported as RMSE.
* **RPE** (relative pose error) over a distance or time ``delta``:
  ``E_ij = (gt_i^-1 gt_j)^-1 (est_i^-1 est_j)``, translation ``|E_ij.xy|`` and rotation
  ``|wrap(E_ij.theta)|``, RMSE over all pairs.
* **NEES** (normalised estimation error squared, Bar-Shalom; Thrun ch. 3 for the Gaussian):
  ``e^T P^-1 e`` with ``e = [x, y, wrap(theta)]_est - [x, y, theta]_gt`` in the world frame and
  ``P`` the world-frame covariance; for a consistent 3-D estimate its mean is 3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from odofuse.errors import InputError
from odofuse.se2 import wrap
from odofuse.trajectory import EstimateResult, Trajectory, interpolate_poses, pose_blocks


def trajectory_from_stream(stream) -> Trajectory:
    """A ``Trajectory`` from a stream with columns ``x, y, theta`` (e.g. ground truth); its
    values themselves (no copy) when they are exactly those columns in that order."""
    if tuple(stream.columns) == ("x", "y", "theta"):
        return Trajectory(stream.t, stream.values)
    return Trajectory(stream.t, np.column_stack([stream["x"], stream["y"], stream["theta"]]))


def align_se2(est_xy, gt_xy) -> tuple[np.ndarray, np.ndarray, float]:
    """Rigid 2-D alignment (Umeyama/Kabsch without scale) of ``est_xy`` onto ``gt_xy``.

    Parameters
    ----------
    est_xy, gt_xy : array_like, shape (N, 2)
        Corresponding positions (m), N >= 2.

    Returns
    -------
    R : ndarray, shape (2, 2)
        Rotation, ``det R = +1``.
    t : ndarray, shape (2,)
        Translation (m).
    angle : float
        Rotation angle of ``R`` (rad).

    ``R @ est + t`` minimises ``sum |R est_i + t - gt_i|^2`` (Umeyama 1991, eqs. 38-42 with
    ``c = 1``).
    """
    a = np.asarray(est_xy, dtype=float)
    b = np.asarray(gt_xy, dtype=float)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 2 or a.shape[0] < 2:
        raise ValueError(f"align_se2 needs two (N, 2) arrays with N >= 2; got {a.shape}, {b.shape}")
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    cov = (b - mb).T @ (a - ma)
    u, _, vt = np.linalg.svd(cov)
    s = np.diag([1.0, np.sign(np.linalg.det(u) * np.linalg.det(vt)) or 1.0])
    r = u @ s @ vt
    t = mb - r @ ma
    return r, t, math.atan2(r[1, 0], r[0, 0])


def apply_alignment(traj: Trajectory, r: np.ndarray, t: np.ndarray) -> Trajectory:
    """``traj`` moved by the rigid transform (R, t): positions ``R p + t``, headings ``+ angle``.

    Covariances are rotated as ``J P J^T`` with ``J = blockdiag(R, 1)``.
    """
    angle = math.atan2(r[1, 0], r[0, 0])
    xy = traj.xy @ r.T + t
    poses = np.column_stack([xy, wrap(traj.poses[:, 2] + angle)])
    covs = None
    if traj.covariances is not None:
        j = np.eye(3)
        j[:2, :2] = r
        covs = j @ traj.covariances @ j.T
    return Trajectory(traj.t, poses, covs)


#: Ground truth is not interpolated across a gap longer than this many median intervals.
MAX_GAP_INTERVALS = 5.0


def covered(est_t, gt_t, max_gap_intervals: float = MAX_GAP_INTERVALS) -> np.ndarray:
    """Mask (M,) of estimate times the ground truth covers without interpolating over a gap.

    A time is covered when it lies inside the ground truth's span and its two neighbouring
    ground-truth samples are at most ``max_gap_intervals`` median sampling intervals apart
    (or it coincides with a sample).
    """
    est_t, gt_t = np.asarray(est_t, dtype=float), np.asarray(gt_t, dtype=float)
    tol = 1e-9 * max(1.0, abs(float(gt_t[-1])))
    inside = (est_t >= gt_t[0] - tol) & (est_t <= gt_t[-1] + tol)
    if gt_t.size < 2:
        return inside
    dt = np.diff(gt_t)
    pos = dt[dt > 0]
    limit = max_gap_intervals * (float(np.median(pos)) if pos.size else 0.0)
    for b in pose_blocks(est_t.size):
        tb = est_t[b]
        k = np.clip(np.searchsorted(gt_t, tb, side="right") - 1, 0, gt_t.size - 2)
        on_sample = (np.abs(tb - gt_t[k]) <= tol) | (np.abs(tb - gt_t[k + 1]) <= tol)
        inside[b] &= (dt[k] <= limit) | on_sample
    return inside


def associate(est: Trajectory, gt: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Indices of estimate poses the ground truth covers (:func:`covered`) and the truth there.

    Returns ``(idx (M,), gt_poses (M, 3))``; raises ``InputError`` when they do not overlap.
    """
    idx = np.flatnonzero(covered(est.t, gt.t))
    if idx.size == 0:
        raise InputError(
            f"estimate times [{est.t[0]:.6g}, {est.t[-1]:.6g}] s do not overlap the "
            f"ground truth [{gt.t[0]:.6g}, {gt.t[-1]:.6g}] s"
        )
    t = est.t[idx]
    return idx, interpolate_poses(gt, np.clip(t, gt.t[0], gt.t[-1], out=t))  # clipped in place


@dataclass(frozen=True)
class ATE:
    """Absolute trajectory error (positions in m, headings in rad).

    ``errors`` (M,) are the position errors at the M estimate times inside the ground truth.
    """

    rmse_m: float
    mean_m: float
    max_m: float
    final_m: float
    rot_rmse_rad: float
    errors: np.ndarray
    aligned: bool


def ate(est: Trajectory, gt: Trajectory, align: bool = False) -> ATE:
    """Absolute trajectory error of ``est`` against ``gt``.

    Parameters
    ----------
    est, gt : Trajectory
        Estimate and ground truth (same world frame unless ``align``).
    align : bool
        First align the estimate positions rigidly onto the truth (:func:`align_se2`).

    Returns
    -------
    ATE
    """
    idx, g = associate(est, gt)
    if align:
        if idx.size < 2:
            raise InputError("alignment needs at least two poses that overlap the ground truth")
        # one run of consecutive poses scored (all, or all but the start before the truth's
        # first stamp): the positions as a view, no copy
        run = idx[-1] - idx[0] + 1 == idx.size
        xy = est.poses[idx[0] : idx[-1] + 1, :2] if run else est.poses[idx, :2]
        r, t, _ = align_se2(xy, g[:, :2])
        del xy
    d, rot = np.empty(idx.size), np.empty(idx.size)
    for b in pose_blocks(idx.size):
        pb = est.poses[idx[b]]
        if align:
            pb = apply_alignment(Trajectory(est.t[idx[b]], pb), r, t).poses
        d[b] = np.linalg.norm(pb[:, :2] - g[b, :2], axis=1)
        rot[b] = wrap(pb[:, 2] - g[b, 2])
    return ATE(
        float(np.sqrt(np.mean(d**2))),
        float(d.mean()),
        float(d.max()),
        float(d[-1]),
        float(np.sqrt(np.mean(rot**2))),
        d,
        align,
    )


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 b`` for SE(2) poses (N, 3): ``b`` expressed in the frame of ``a``."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, wrap(b[:, 2] - a[:, 2])])


@dataclass(frozen=True)
class RPE:
    """Relative pose error over ``delta`` (``unit`` "m" of travelled ground-truth path or "s")."""

    trans_rmse_m: float
    rot_rmse_rad: float
    pairs: int
    delta: float
    unit: str


def rpe(est: Trajectory, gt: Trajectory, delta: float = 10.0, unit: str = "m") -> RPE:
    """Relative pose error over segments of length ``delta``.

    Parameters
    ----------
    est, gt : Trajectory
    delta : float
        Segment length: metres of travelled ground-truth path (``unit="m"``) or seconds.
    unit : {"m", "s"}

    Returns
    -------
    RPE
        NaN errors and ``pairs = 0`` when no segment is that long.

    For each estimate pose i, j is the first later pose whose travelled distance (or time) from i
    reaches ``delta``; ``E_ij = (gt_i^-1 gt_j)^-1 (est_i^-1 est_j)``.
    """
    if unit not in ("m", "s"):
        raise ValueError(f"rpe unit must be 'm' or 's', got {unit!r}")
    if not delta > 0:
        raise ValueError(f"rpe delta must be positive, got {delta!r}")
    idx, g = associate(est, gt)
    if unit == "m":
        steps = np.empty(max(idx.size - 1, 0))  # travelled ground-truth path between poses
        for b in pose_blocks(steps.size):
            steps[b] = np.linalg.norm(g[b.start + 1 : b.stop + 1, :2] - g[b, :2], axis=1)
        s = np.empty(idx.size)
        s[0] = 0.0
        np.cumsum(steps, out=s[1:])
        del steps
    else:
        s = est.t[idx]
    j = np.empty(s.size, dtype=np.intp)  # the first pose delta on from each, in blocks
    for b in pose_blocks(s.size):
        j[b] = np.searchsorted(s, s[b] + delta * (1 - 1e-12), side="left")
    pairs = int(np.count_nonzero(j < len(s)))  # j is non-decreasing: pairs start at 0..pairs-1
    del s
    if pairs == 0:
        return RPE(math.nan, math.nan, 0, float(delta), unit)
    t_err, r_err = np.empty(pairs), np.empty(pairs)
    for b in pose_blocks(pairs):
        jb = j[b]
        e_i, e_j = est.poses[idx[b]], est.poses[idx[jb]]
        err = _between(_between(g[b], g[jb]), _between(e_i, e_j))
        t_err[b] = np.linalg.norm(err[:, :2], axis=1)
        r_err[b] = np.abs(wrap(err[:, 2]))
    del idx, g, j
    return RPE(  # squared in place: the same mean as of t_err**2, without its copy
        float(np.sqrt(np.mean(np.square(t_err, out=t_err)))),
        float(np.sqrt(np.mean(np.square(r_err, out=r_err)))),
        pairs,
        float(delta),
        unit,
    )


def nees_values(est: Trajectory, gt: Trajectory, dims=(0, 1, 2)) -> np.ndarray:
    """NEES ``e^T P^-1 e`` (world frame) at every estimate pose with a positive-definite covariance.

    ``dims`` selects the pose components: ``(0, 1)`` scores the position alone (expected value
    2), for datasets whose "true" heading is not independent of the estimate (Plaza's ground
    truth heading is the odometry heading). Poses whose covariance is not positive definite
    (e.g. a perfectly known initial pose with ``P = 0``) are skipped. Returns an array of shape
    (K,), empty without covariances.
    """
    if est.covariances is None:
        return np.empty(0)
    dims = list(dims)
    idx, g = associate(est, gt)
    vals = np.empty(idx.size)
    ok = np.ones(idx.size, dtype=bool)
    for b in pose_blocks(idx.size):
        vals[b], ok[b] = _nees_block(est, idx[b], g[b], dims)
    return vals if ok.all() else vals[ok]


def _nees_block(est: Trajectory, idx, g, dims) -> tuple[np.ndarray, np.ndarray]:
    """NEES (n,) of the estimate poses ``idx`` against the truth ``g`` (n, 3), and the mask of
    those with a positive-definite covariance (their values; the others' are undefined)."""
    e = est.poses[idx] - g
    e[:, 2] = wrap(e[:, 2])
    e = e[:, dims]
    covs = est.covariances[idx][:, dims][:, :, dims]
    covs = 0.5 * (covs + np.swapaxes(covs, 1, 2))
    ok = np.ones(len(covs), dtype=bool)
    try:  # every covariance positive definite: one batched factorisation and solve
        ch = np.linalg.cholesky(covs)
    except np.linalg.LinAlgError:  # find the ones that are, pose by pose
        ch = np.zeros_like(covs)
        for k, pk in enumerate(covs):
            try:
                ch[k] = np.linalg.cholesky(pk)
            except np.linalg.LinAlgError:
                ok[k] = False
                ch[k] = np.eye(len(dims))  # a placeholder: its value is masked out
    y = np.linalg.solve(ch, e[:, :, None])[:, :, 0]
    return (y * y).sum(axis=1), ok  # the same sums as y @ y per pose


def nees(est: Trajectory, gt: Trajectory, dims=(0, 1, 2)) -> float:
    """Mean NEES over the poses with a positive-definite covariance (NaN if none).

    For a consistent estimator the expected value is ``len(dims)``: 3 for the pose, 2 for the
    position alone.
    """
    v = nees_values(est, gt, dims)
    return float(v.mean()) if v.size else math.nan


#: Largest plausible ground-truth coordinate (m): beyond it squares overflow.
MAX_GT_COORDINATE = 1e12


def check_groundtruth(stream) -> None:
    """Raise ``InputError`` naming the file and row of the first non-finite ground-truth cell.

    Rows count as in the file (header = row 1). Coordinates beyond
    :data:`MAX_GT_COORDINATE` (e.g. ``1e308``) count as non-finite: their errors overflow.
    """
    for b in pose_blocks(len(stream.t)):  # the first bad cell of the first block that has one
        cells = np.column_stack([stream.t[b], stream.values[b]])
        bad = ~np.isfinite(cells) | (np.abs(cells) > MAX_GT_COORDINATE)
        if not bad.any():
            continue
        i, j = np.argwhere(bad)[0]
        column = ("t",) + tuple(stream.columns)
        raise InputError(
            f"ground truth value {cells[i, j]!r} is not finite (or beyond "
            f"{MAX_GT_COORDINATE:g}): the estimate cannot be scored",
            file=stream.source,
            row=b.start + int(i) + 2,
            column=column[j],
        )


def _coverage(out: dict, traj: Trajectory, gt: Trajectory) -> list:
    """Record what the ground truth covered; a finding when under half the estimate's span."""
    from odofuse.status.findings import Finding

    mask = covered(traj.t, gt.t)
    span = float(traj.t[-1] - traj.t[0])
    scored = int(mask.sum())
    first, last = int(np.argmax(mask)), mask.size - 1 - int(np.argmax(mask[::-1]))
    # Time covered: the estimate's steps whose both ends are scored.
    steps = np.diff(traj.t)[mask[1:] & mask[:-1]] if traj.t.size > 1 else np.empty(0)
    covered_s = float(steps.sum())
    del steps
    out["groundtruth"] = {
        "poses_scored": scored,
        "poses": len(traj),
        "t_start": float(traj.t[first]) if scored else None,
        "t_end": float(traj.t[last]) if scored else None,
        "covered_s": covered_s,
        "estimate_span_s": span,
    }
    if span > 0 and covered_s < 0.5 * span:
        return [
            Finding(
                "scoring",
                f"ground truth covers {covered_s:.3g} s of the estimate's {span:.3g} s "
                f"({scored} of {len(traj)} poses): the scores describe only that part",
                t_start=out["groundtruth"]["t_start"],
                t_end=out["groundtruth"]["t_end"],
                figure=covered_s / span,
            )
        ]
    return []


def metrics(
    result: EstimateResult, log=None, runtime_s: float | None = None, rpe_delta_m: float = 10.0
) -> dict:
    """The ``metrics.json`` content of a run (shared spec section 3).

    Parameters
    ----------
    result : EstimateResult
    log : SensorLog, optional
        Supplies ``repairs`` and ground truth.
    runtime_s : float, optional
        Wall-clock time of the estimator (s).
    rpe_delta_m : float
        Segment length of the RPE (m of travelled ground-truth path).

    Returns
    -------
    dict
        Always ``estimator, poses, runtime_s, sensors {name: {used, rejected, mde}}, repairs``
        (``mde``: a filter's minimal detectable errors, docs/filters.md); with
        ground truth also ``ate_rmse_m, ate_aligned_rmse_m, final_error_m, rpe_trans_m,
        rpe_rot_rad, rpe_delta_m, nees_mean, nees_position_mean`` (3-D pose NEES, expected 3,
        and position-only NEES, expected 2; None without covariances). ``status`` (``ok`` or
        ``degraded``), ``warnings`` (one line per finding) and ``findings`` (the records) come
        from :func:`odofuse.status.findings.assess`, never from ground truth.
    """
    from odofuse.status.findings import assess, status_of

    traj = result.trajectory
    names = sorted(set(result.used) | set(result.rejected))
    out: dict = {
        "estimator": result.estimator,
        "poses": len(traj),
        "runtime_s": None if runtime_s is None else float(runtime_s),
        "sensors": {
            n: {"used": int(result.used.get(n, 0)), "rejected": int(result.rejected.get(n, 0))}
            for n in names
        },
        "repairs": dict(getattr(log, "repairs", {}) or {}),
    }
    for n, mde in ((result.extra or {}).get("mde") or {}).items():  # docs/filters.md
        if n in out["sensors"]:
            out["sensors"][n]["mde"] = mde
    gt_stream = getattr(log, "groundtruth", None)
    scoring = []
    if gt_stream is not None and len(gt_stream) and len(traj):
        check_groundtruth(gt_stream)
        gt = trajectory_from_stream(gt_stream)
        scoring = _coverage(out, traj, gt)
        a = ate(traj, gt)
        out["ate_rmse_m"] = a.rmse_m
        out["final_error_m"] = a.final_m
        del a  # its per-pose errors: not held through the passes below
        if np.count_nonzero((traj.t >= gt.t[0]) & (traj.t <= gt.t[-1])) >= 2:
            out["ate_aligned_rmse_m"] = ate(traj, gt, align=True).rmse_m
        r = rpe(traj, gt, rpe_delta_m, "m")
        out["rpe_trans_m"] = r.trans_rmse_m
        out["rpe_rot_rad"] = r.rot_rmse_rad
        out["rpe_delta_m"] = r.delta
        for key, dims in (("nees_mean", (0, 1, 2)), ("nees_position_mean", (0, 1))):
            n = nees(traj, gt, dims)
            out[key] = None if math.isnan(n) else n
    extra = {
        k: v
        for k, v in (result.extra or {}).items()
        if not str(k).startswith("_") and k != "mde"  # mde: under "sensors" above
    }
    if extra:  # keys starting with "_" are in memory only (the cross-check's error samples)
        out["extra"] = extra
    findings = assess(result) + scoring
    out["status"] = status_of(findings)
    out["warnings"] = [f.line() for f in findings]
    out["findings"] = [f.as_dict() for f in findings]
    return out
