"""The calibration drift check of the EKF and the UKF: did a calibration estimate move more
than the filter's own updates explain?

A calibration state (a gyro bias, a wheel radius or track scale, a range scale) is a constant
with a random walk ``w`` per sqrt(s). A Kalman filter's estimate of it is then a martingale:
between two times its change has mean zero and the variance that the updates in between
explained, ``P(t1) - P(t2) + w^2 (t2 - t1)`` (the variance it lost, plus the walk). So ``z =
(x(t2) - x(t1)) / sqrt(that)`` is a standard normal on a log that matches the config, without
ground truth. When a sensor or the wheels change during the run (a gyro bias step, a tyre
that wears), the filter absorbs the change into its calibration faster than that: the
innovations stay white (the calibration followed the change), but the calibration's own path
shows it (docs/trust.md, "The calibration drift check").

The check takes a snapshot of the calibration states every ``drift_grid`` s of odometry
(:class:`Drift`), compares each snapshot ``k`` with the snapshots ``1, 2, 4, ..., 2^b`` back
(up to :data:`MAX_LAG`), and spends ``drift_alpha`` over the snapshots as the NIS windows
spend theirs (snapshot ``k`` in block ``floor(log2 k)`` gets its share of
:func:`odofuse.status.streaming.window_band`), split over its comparisons and states
(Bonferroni, two-sided). O(log) work per snapshot; the snapshots are a ring allocated once.
Measured: ``benchmarks/bench_calibration_drift.py`` and ``bench_status.py``.
"""

from __future__ import annotations

import dataclasses
import math
from statistics import NormalDist

import numpy as np

from odofuse.status.findings import Finding
from odofuse.status.streaming import window_band

#: Largest lag (in snapshots) of a comparison (21 min at the default 5 s grid).
MAX_LAG = 256
#: Snapshots held (a ring, allocated once: a live filter's memory stays flat); a replay may
#: cut back up to ``_CAP - MAX_LAG - 1`` of them.
_CAP = 2 * MAX_LAG
_NORMAL = NormalDist()


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
        self._var = np.empty((_CAP, m))
        # the largest comparison up to each snapshot: ratio, t_j, t_k, state, z, bound
        self._worst = np.zeros((_CAP, 6))
        self._n = 0  # snapshots taken; snapshot a (0-based) is row a % _CAP
        self._ratio = 0.0  # the newest snapshot's largest ratio (a float: health() asks)
        self.next_t = -math.inf  # odometry time of the next snapshot

    def __len__(self) -> int:
        """Snapshots taken."""
        return self._n

    def observe(self, t: float, x, variances) -> None:
        """Take the snapshot of time ``t`` from state ``x`` (n,) and the diagonal of its
        covariance ``variances`` (n,), and compare it with the earlier ones."""
        i, k = self.index, self._n + 1  # k: this snapshot, 1-based
        row = self._n % _CAP
        v, var = self._v[row], self._var[row]
        v[:] = x[i]
        var[:] = variances[i]
        self._t[row] = t
        worst = self._worst[(row - 1) % _CAP] if self._n else np.zeros(6)
        lags = [2**b for b in range(k.bit_length()) if 2**b < k and 2**b <= MAX_LAG]
        if lags:
            share = window_band(k, 1, 1, self.alpha, 1)[2]
            bound = -_NORMAL.inv_cdf(share / (2 * len(lags) * len(self.names)))
            for lag in lags:
                j = (row - lag) % _CAP
                dvar = self._var[j] - var + self.walk * (t - self._t[j])
                with np.errstate(divide="ignore", invalid="ignore"):
                    z = np.where(dvar > 0.0, np.abs(v - self._v[j]) / np.sqrt(dvar), 0.0)
                s = int(np.argmax(z))
                if z[s] / bound > worst[0]:
                    worst = (z[s] / bound, self._t[j], t, s, z[s], bound)
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
        """The largest ``|z|`` over its bound so far (above 1: the check failed)."""
        return self._ratio

    def findings(self) -> list[Finding]:
        """A ``calibration_drift`` finding when a comparison exceeded its bound."""
        if not self.ratio() > 1.0:
            return []
        ratio, tj, tk, s, z, bound = self._worst[(self._n - 1) % _CAP].tolist()
        name = self.names[int(s)]
        return [
            Finding(
                "calibration_drift",
                f"{name} moved {z:.1f} sigma of what the updates and its random walk explain "
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
#: How a companion EKF's finding starts when another estimator carries it
#: (:func:`seen_by_ekf`).
SEEN_BY_EKF = "seen by an EKF of this log and config: "


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
    return tuple(dataclasses.replace(f, message=SEEN_BY_EKF + f.message) for f in drift + mean)


def cannot_judge(why: str) -> Finding:
    """The companion EKF's note when it cannot test the calibration's drift (no degrading)."""
    msg = f"an EKF of this log could not test the calibration's drift: {why}"
    return Finding("calibration_drift", msg, degrades=False)
