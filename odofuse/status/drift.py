"""The calibration drift check of the EKF and the UKF: did a calibration estimate move more
than the filter's own updates explain?

A calibration state (a gyro bias, a wheel radius or track scale, a range scale) is a constant
with a random walk ``w`` per sqrt(s). A Kalman filter's estimate of the calibration states is
then a martingale: between two times its change ``d = x(t2) - x(t1)`` has mean zero and the
covariance that the updates in between explained, ``C = P(t1) - P(t2) + W (t2 - t1)`` (the
covariance it lost, each update's ``K S K^T``, plus the walk; full blocks over the calibration
states). So ``d' C^+ d`` is chi-square(rank C) on a log that matches the config, without ground
truth. When a sensor or the wheels change during the run (a gyro bias step, a tyre
that wears), the filter absorbs the change into its calibration faster than that: the
innovations stay white (the calibration followed the change), but the calibration's own path
shows it (docs/trust.md, "The calibration drift check").

The check takes a snapshot of the calibration states every ``drift_grid`` s of odometry
(:class:`Drift`), compares each snapshot ``k`` with the snapshots ``1, 2, 4, ..., 2^b`` back
(up to :data:`MAX_LAG`), and spends ``drift_alpha`` over the snapshots as the NIS windows
spend theirs (snapshot ``k`` in block ``floor(log2 k)`` gets its share of
:func:`odofuse.status.monitors.window_band`), split over its comparisons (Bonferroni). The
test is joint over the states (session 48; it was one normal test per state, Bonferroni over
them too): a gyro bias step inside a steady turn spreads over the gyro bias, the track and
radius scales and the wheels' ratio, 2-5 sigma each, which per-state tests miss and the joint
statistic sees (docs/trust.md, "The drift check, joint over the calibration states").
O(log) work per snapshot; the snapshots are a ring allocated once. Measured:
``benchmarks/bench_calibration_drift.py`` and ``bench_status.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from odofuse import chi2
from odofuse.status.findings import Finding
from odofuse.status.monitors import window_band

#: Largest lag (in snapshots) of a comparison (21 min at the default 5 s grid).
MAX_LAG = 256
#: Snapshots held (a ring, allocated once: a live filter's memory stays flat); a replay may
#: cut back up to ``_CAP - MAX_LAG - 1`` of them.
_CAP = 2 * MAX_LAG
#: Directions of a change's covariance ``C`` with an eigenvalue at most this fraction of its
#: largest carry no tested change (the updates in between explained none along them: a state
#: the sensors do not see); the statistic's degrees of freedom are the directions kept.
_RANK_TOL = 1e-10


@functools.lru_cache(maxsize=4096)
def _bound(p: float, rank: int) -> float:
    """The Mahalanobis distance a change of ``rank`` dimensions exceeds with probability
    ``p`` under the filter's model: ``sqrt(chi2.ppf(1 - p, rank))``."""
    return math.sqrt(float(chi2.ppf(1.0 - p, rank)))


def joint_distance(d, C) -> tuple[float, int]:
    """``(sqrt(d' C^+ d), rank)``: the change ``d`` (m,) in the metric of its covariance ``C``
    (m, m; its symmetric part), over the eigen-directions of ``C`` above :data:`_RANK_TOL`
    of its largest eigenvalue (a non-positive ``C`` has none: ``(0, 0)``)."""
    lam, V = np.linalg.eigh(0.5 * (C + C.T))
    top = lam[-1] if lam.size else 0.0
    if not top > 0.0:
        return 0.0, 0
    keep = lam > _RANK_TOL * top
    q = V[:, keep].T @ d
    return math.sqrt(float(np.sum(q * q / lam[keep]))), int(np.count_nonzero(keep))


class Drift:
    """Snapshots of a filter's calibration states and the largest drift ratio so far.

    Parameters
    ----------
    names : sequence of str
        The calibration states.
    index : sequence of int
        Their indices in the filter's state vector.
    walk : ndarray (n,)
        The filter's random-walk variance per second of every state.
    owners : dict
        State -> the stream it belongs to (None: the odometry's).
    alpha, grid : float
        ``drift_alpha`` and ``drift_grid`` (:class:`odofuse.declarations.KalmanOptions`).
    """

    def __init__(self, names, index, walk, owners, alpha: float, grid: float) -> None:
        self.names = tuple(names)
        self.index = np.asarray(index, dtype=np.int64)
        self.walk = np.asarray(walk, dtype=float)[self.index]
        self.owners = dict(owners)
        self.alpha, self.grid = float(alpha), float(grid)
        m = len(self.names)
        self._t = np.empty(_CAP)
        self._v = np.empty((_CAP, m))
        self._cov = np.empty((_CAP, m, m))
        # the largest comparison up to each snapshot: ratio, t_j, t_k, the state that moved
        # most in its own sigmas and those sigmas, the distance, its bound, its degrees of
        # freedom
        self._worst = np.zeros((_CAP, 8))
        self._n = 0  # snapshots taken; snapshot a (0-based) is row a % _CAP
        self._ratio = 0.0  # the newest snapshot's largest ratio (a float: health() asks)
        self.next_t = -math.inf  # odometry time of the next snapshot

    def __len__(self) -> int:
        """Snapshots taken."""
        return self._n

    def observe(self, t: float, x, P) -> None:
        """Take the snapshot of time ``t`` from state ``x`` (n,) and its covariance ``P``
        (n, n), and compare it with the earlier ones."""
        i, k = self.index, self._n + 1  # k: this snapshot, 1-based
        row = self._n % _CAP
        v, cov = self._v[row], self._cov[row]
        v[:] = x[i]
        cov[:] = np.asarray(P)[np.ix_(i, i)]
        self._t[row] = t
        worst = self._worst[(row - 1) % _CAP] if self._n else np.zeros(8)
        lags = [2**b for b in range(k.bit_length()) if 2**b < k and 2**b <= MAX_LAG]
        if lags:
            share = window_band(k, 1, 1, self.alpha, 1)[2] / len(lags)
            for lag in lags:
                j = (row - lag) % _CAP
                d = v - self._v[j]
                C = self._cov[j] - cov + np.diag(self.walk * (t - self._t[j]))
                dist, rank = joint_distance(d, C)
                if not rank:
                    continue
                bound = _bound(share, rank)
                if dist / bound > worst[0]:
                    with np.errstate(divide="ignore", invalid="ignore"):
                        z = np.where(np.diag(C) > 0.0, np.abs(d) / np.sqrt(np.diag(C)), 0.0)
                    s = int(np.argmax(z))
                    worst = (dist / bound, self._t[j], t, s, z[s], dist, bound, rank)
        self._worst[row] = worst
        self._ratio = float(worst[0])
        self._n = k
        self.next_t = float(t) + self.grid

    def truncate(self, n: int) -> None:
        """Keep the first ``n`` snapshots, for a replay from there (at most
        ``_CAP - MAX_LAG - 1`` back: a late window is seconds, a snapshot ``grid`` s)."""
        if n < self._n - (_CAP - MAX_LAG - 1):
            raise ValueError(f"snapshot {n} is no longer held (taken: {self._n})")
        self._n = min(self._n, n)
        self.next_t = self._t[(n - 1) % _CAP] + self.grid if self._n else -math.inf
        self._ratio = float(self._worst[(self._n - 1) % _CAP, 0]) if self._n else 0.0

    def ratio(self) -> float:
        """The largest distance over its bound so far (above 1: the check failed)."""
        return self._ratio

    def findings(self) -> list[Finding]:
        """A ``calibration_drift`` finding when a comparison exceeded its bound."""
        if not self.ratio() > 1.0:
            return []
        ratio, tj, tk, s, z, dist, bound, rank = self._worst[(self._n - 1) % _CAP].tolist()
        name = self.names[int(s)]
        return [
            Finding(
                "calibration_drift",
                f"the calibration moved {dist:.1f} sigma over {int(rank)} state(s) ({name} "
                f"most, {z:.1f} sigma alone) of what the updates and the random walk explain "
                f"(bound {bound:.2f} at drift_alpha {self.alpha:g}): a sensor or the wheels "
                "changed during the run and the calibration absorbed it",
                sensor=self.owners.get(name),
                t_start=tj,
                t_end=tk,
                figure=ratio,
            )
        ]


def drift_of(loc) -> Drift | None:
    """The :class:`Drift` of a Localizer ``loc`` (an EKF or UKF with calibration states and
    ``drift_alpha > 0``), else None."""
    from odofuse.declarations import KalmanOptions
    from odofuse.estimators.common import calibration_index

    opts = loc.options
    if not isinstance(opts, KalmanOptions) or not opts.drift_alpha > 0.0:
        return None
    odo = getattr(loc.backend, "odo_cal", None)
    index = calibration_index(loc.models, odo)
    walk = getattr(loc.backend, "walk", None)
    if not index or walk is None:
        return None
    owners = {}
    for stream, m in loc.models.items():
        for s in getattr(m, "calib_states", ()):
            owners.setdefault(s, stream)
    return Drift(list(index), list(index.values()), walk, owners, opts.drift_alpha, opts.drift_grid)


#: The companion EKF's checks that test its innovations against the config's model (the
#: log's departure from it, which another estimator of the log shares), not its own failure.
MODEL = ("nis", "nis_run")


def seen_by_ekf(found) -> tuple[Finding, ...]:
    """What an EKF of the same log and config, with findings ``found``, tells another
    estimator about the log (the companion of :data:`odofuse.status.cross_check.COMPANION`,
    offline and live): its ``calibration_drift`` and ``innovation_mean`` findings, each
    saying the EKF saw them. Both say the log departs from the config's model (a
    calibration that moved more than its walk allows, innovations whose mean is off zero),
    which the other estimator runs too; dead reckoning, which fuses no absolute sensor, takes
    both as it takes the batch smoother's findings about the log (a gyro bias step at a
    turn's reversal is invisible to its own gyro-against-wheels windows: docs/trust.md,
    "Dead reckoning carries the companion EKF's scan").

    The EKF's calibration path and innovations are the model's only while the EKF itself
    holds the track: an EKF that is also degraded by a check of its own failure (recoveries,
    rejection runs, a covariance or calibration out of bounds, ...) cannot judge (its failure
    moved them), and says so in a note that does not degrade. Its NIS tests (:data:`MODEL`)
    are not such a check: like the scan, they test its innovations against the config's
    model, which the other estimator shares (a gyro bias step raises the run's NIS beside
    the scan and the drift: docs/trust.md, "The companion EKF's NIS tests")."""
    own = ("calibration_drift", "innovation_mean")
    drift = [f for f in found if f.check == "calibration_drift" and f.degrades]
    mean = [f for f in found if f.check == "innovation_mean" and f.degrades]
    other = sorted({f.check for f in found if f.degrades and f.check not in own + MODEL})
    if drift and other:
        return (
            cannot_judge(
                f"it is degraded by {', '.join(other)} itself, so its calibration's path is "
                "no evidence about the log"
            ),
        )
    if other:
        return ()
    return tuple(
        dataclasses.replace(f, message=f"seen by an EKF of this log and config: {f.message}")
        for f in drift + mean
    )


def cannot_judge(why: str) -> Finding:
    """The companion EKF's note when it cannot test the calibration's drift (no degrading)."""
    msg = f"an EKF of this log could not test the calibration's drift: {why}"
    return Finding("calibration_drift", msg, degrades=False)
