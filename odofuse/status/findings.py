"""Self-judgement of a run, without ground truth: findings, and the status derived from them.

A :class:`Finding` is one thing a run noticed about itself (a stream mostly rejected by its
gate, innovations outside their chi-square band, a covariance that stopped being positive
definite, a solver that hit its iteration cap, ...). Estimators and monitors *append*
findings; ``status`` is derived from them by :func:`status_of` and never set by hand
(shared spec section 3: a run whose estimate cannot be trusted never says ``ok``).

:func:`assess` holds the checks that apply to every estimator's result alike (covariance
health of the trajectory, per-stream rejection fractions); estimator-specific monitors live
with their estimator and return :class:`Finding` records too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from odofuse.trajectory import pose_blocks

#: A stream whose gate rejected more than this fraction of its readings is reported.
MOSTLY_REJECTED = 0.5
#: Smallest eigenvalue (relative to the largest) below which a covariance is not usable.
MIN_EIGEN_RATIO = 1e-14


@dataclass(frozen=True)
class Finding:
    """One self-check that failed.

    Attributes
    ----------
    check : str
        What was checked, e.g. ``"rejected"``, ``"nis"``, ``"covariance"``, ``"solver"``.
    message : str
        What was found, for a person (one line, no trailing period).
    sensor : str or None
        The stream concerned (``None`` for the estimate as a whole).
    t_start, t_end : float or None
        Log-time span (s) the finding covers.
    figure : float or None
        The measured figure the finding is about (fraction, NIS, iterations, ...).
    degrades : bool
        Whether the finding makes the run ``degraded`` (informational notes do not).
    """

    check: str
    message: str
    sensor: str | None = None
    t_start: float | None = None
    t_end: float | None = None
    figure: float | None = None
    degrades: bool = True

    def line(self) -> str:
        """The ``warnings`` line: ``[check] sensor, t0-t1 s: message``."""
        where = []
        if self.sensor:
            where.append(self.sensor)
        if self.t_start is not None and self.t_end is not None:
            where.append(f"{self.t_start:.2f}-{self.t_end:.2f} s")
        elif self.t_start is not None:
            where.append(f"from {self.t_start:.2f} s")
        prefix = f"[{self.check}] " + (", ".join(where) + ": " if where else "")
        return prefix + self.message

    def as_dict(self) -> dict:
        """JSON-ready form (``metrics.json`` ``findings``)."""
        return {
            "check": self.check,
            "sensor": self.sensor,
            "t_start": self.t_start,
            "t_end": self.t_end,
            "figure": self.figure,
            "degrades": self.degrades,
            "message": self.message,
        }


def status_of(findings) -> str:
    """``"degraded"`` if any finding degrades the run, else ``"ok"``."""
    return "degraded" if any(f.degrades for f in findings) else "ok"


def rejection_findings(used: dict, rejected: dict, span=(None, None)) -> list[Finding]:
    """A finding per stream whose gate rejected more than :data:`MOSTLY_REJECTED` of it."""
    out = []
    for name in sorted(set(used) | set(rejected)):
        u, r = int(used.get(name, 0)), int(rejected.get(name, 0))
        if u + r and r / (u + r) > MOSTLY_REJECTED:
            frac = r / (u + r)
            out.append(
                Finding(
                    "rejected",
                    f"{r} of {u + r} readings ({100 * frac:.0f} %) rejected by the gate: "
                    "the estimate and this sensor disagree",
                    sensor=name,
                    t_start=span[0],
                    t_end=span[1],
                    figure=frac,
                )
            )
    return out


def covariance_findings(t, covariances) -> list[Finding]:
    """Findings for non-finite or non-positive-definite pose covariances of a trajectory.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Pose times (s).
    covariances : ndarray, shape (N, 3, 3) or None
        World-frame pose covariances.
    """
    if covariances is None or len(t) == 0:
        return []
    C = np.asarray(covariances, dtype=float)
    bad = np.zeros(len(C), dtype=bool)
    for b in pose_blocks(len(C)):  # in blocks: temporaries of a few MB on any run
        Cb = C[b]
        finite = np.isfinite(Cb).all(axis=(1, 2))
        bad[b] = ~finite
        if finite.any():
            sym = 0.5 * (Cb[finite] + np.swapaxes(Cb[finite], 1, 2))
            eig = np.linalg.eigvalsh(sym)
            top = np.maximum(np.abs(eig[:, -1]), np.finfo(float).tiny)
            bad_f = eig[:, 0] <= MIN_EIGEN_RATIO * top
            bad[b.start + np.flatnonzero(finite)[bad_f]] = True
    if not bad.any():
        return []
    idx = np.flatnonzero(bad)
    return [
        Finding(
            "covariance",
            f"{idx.size} of {len(t)} pose covariances not positive definite or not finite",
            t_start=float(t[idx[0]]),
            t_end=float(t[idx[-1]]),
            figure=float(idx.size),
        )
    ]


def pose_findings(t, poses) -> list[Finding]:
    """A finding when any estimated pose is not finite."""
    P = np.asarray(poses, dtype=float)
    bad = ~np.isfinite(P).all(axis=1)
    if not bad.any():
        return []
    idx = np.flatnonzero(bad)
    return [
        Finding(
            "pose",
            f"{idx.size} of {len(t)} poses not finite",
            t_start=float(t[idx[0]]),
            t_end=float(t[idx[-1]]),
            figure=float(idx.size),
        )
    ]


def assess(result) -> list[Finding]:
    """The estimator's own findings plus the checks common to every estimator.

    Parameters
    ----------
    result : odofuse.trajectory.EstimateResult

    Returns
    -------
    list of Finding
        ``result.findings`` first, then rejection fractions, pose and covariance health.
    """
    traj = result.trajectory
    span = (
        (float(traj.t[0]), float(traj.t[-1]))
        if len(traj) and math.isfinite(traj.t[0])
        else (None, None)
    )
    own = list(getattr(result, "findings", ()) or ())
    reported = {(f.check, f.sensor) for f in own}
    common = [
        f
        for f in rejection_findings(result.used, result.rejected, span)
        if (f.check, f.sensor) not in reported
    ]
    common += pose_findings(traj.t, traj.poses)
    common += covariance_findings(traj.t, traj.covariances)
    return own + common
