"""GTSAM factors and initial values of a :class:`GraphProblem`, keyframe by keyframe.

Owns :class:`Factors`: the priors on the first pose, the calibration states and the landmarks,
the odometry between factors, each sensor row's factor with its stream's robust loss, and the
frozen-calibration variants iSAM2 switches to, the between factors of a walking gyro bias
(one bias variable per keyframe interval, :meth:`Factors.bias_segment`); and the noise
models (:func:`robust_noise`, Huber / Cauchy / Tukey, and the floored odometry covariance).
The factors GTSAM has no built-in factor for are in
:mod:`odofuse.estimators.graph.custom_factors`.
"""

from __future__ import annotations

import math

import numpy as np

from odofuse import se2
from odofuse.declarations import ROBUST_DEFAULT_K
from odofuse.estimators.graph.custom_factors import (
    calibrated_between_factor,
    frozen_calibration_factor,
    gyro_increment_factor,
)
from odofuse.estimators.graph.keys import B, L, X, model_kind
from odofuse.estimators.graph.loops import STREAM
from odofuse.estimators.graph.problem import GraphProblem, Measurement
from odofuse.measurements.landmarks import range_factor

# Variance (m^2, rad^2) added to every pre-integrated covariance so that a single step of a
# drive with a rank-deficient input covariance (e.g. increments: no lateral noise) stays
# invertible: a 0.1 mm / 0.1 mrad floor per keyframe interval, below any odometry noise.
_COV_FLOOR = 1e-8


def robust_noise(base, kind: str | None, k: float | None = None):
    """Wrap a GTSAM noise model in an M-estimator.

    Parameters
    ----------
    base : gtsam.noiseModel.Base
        The Gaussian noise model (whitening by the sensor's ``R``).
    kind : {"huber", "cauchy", "tukey"} or None
        ``None`` or ``"none"`` returns ``base`` unchanged.
    k : float, optional
        Threshold on the *whitened* residual (units of sigma); default
        :data:`ROBUST_DEFAULT_K`.
    """
    import gtsam

    if kind is None or kind == "none":
        return base
    est = {
        "huber": gtsam.noiseModel.mEstimator.Huber,
        "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
        "tukey": gtsam.noiseModel.mEstimator.Tukey,
    }[kind]
    return gtsam.noiseModel.Robust.Create(est.Create(float(k or ROBUST_DEFAULT_K[kind])), base)


def slip_scales(problem: GraphProblem) -> np.ndarray:
    """Robust odometry: the factor (>= 1) of each keyframe interval's odometry covariance.

    The graph's form of the filters' rule (:func:`odofuse.status.slip.slip_scale`,
    docs/trust.md section 2), applied to the keyframe intervals of the first fused gyro
    stream: an interval whose wheel heading change ``deltas[i, 2]`` disagrees with the gyro's
    increment (bias removed at its prior value) by ``d`` with
    ``d^2 > chi2_1(slip_gate) (var_wheels + var_gyro + (sigma_b T)^2)`` slipped, and its
    covariance is widened so that the accumulated wheel heading variance of the run of
    consecutive slipping intervals is the square of its summed disagreement. ``sigma_b`` is
    the bias prior's sigma (the graph estimates the bias, but the noise of a factor must not
    depend on the solution): a conservative test, never a looser one. A walking bias
    (``bias_walk`` > 0) has ``sigma_b^2 + bias_walk^2 (t - t_0)`` at the interval's end ``t``.

    Returns
    -------
    ndarray (K-1,)
        1 for every interval that did not slip, without a gyro, with ``slip: false`` and for
        pose-graph odometry (the file's covariance).
    """
    from odofuse.measurements import gate_threshold
    from odofuse.status.slip import slip_scale

    out = np.ones(len(problem.deltas))
    if not problem.gyro or problem.pose_graph or not problem.options.slip:
        return out
    stream = next(s for s in problem.models if s in problem.gyro)
    inc, model = problem.gyro[stream], problem.models[stream]
    if "gyro_bias" in problem.calib and "gyro_bias" in getattr(model, "calib_states", ()):
        _, bias, bias_sigma = problem.calib["gyro_bias"]
    else:
        bias, bias_sigma = 0.0, float(getattr(model, "bias_sigma", 0.0))
    i = np.asarray(inc.interval, dtype=int)
    d = se2.wrap(inc.dtheta - bias * inc.T - problem.deltas[i, 2])
    var_odo = problem.covs[i, 2, 2]
    sigma_b = bias_sigma
    if "gyro_bias" in problem.bias_walk:  # the prior of a walking bias widens with time
        sigma_b = problem.prior_sigma_at("gyro_bias", problem.kt[i + 1])
    var_ref = inc.var + (sigma_b * inc.T) ** 2
    gate = gate_threshold(problem.options.slip_gate, 1)
    run, prev = 0.0, -2
    for n in np.flatnonzero(d * d > gate * (var_odo + var_ref)):
        run = run if i[n] == prev + 1 else 0.0  # a run: consecutive slipping intervals
        out[i[n]] = slip_scale(float(d[n]), float(var_odo[n]), float(var_ref[n]), gate, run)
        run, prev = (run + float(d[n]), i[n]) if out[i[n]] > 1.0 else (0.0, -2)
    return out


def _odometry_noise(cov, floor: float = _COV_FLOOR):
    import gtsam

    cov = 0.5 * (cov + cov.T)
    cov[0, 0] += floor
    cov[1, 1] += floor
    cov[2, 2] += floor
    return gtsam.noiseModel.Gaussian.Covariance(cov)


class Factors:
    """Turns a :class:`GraphProblem` into GTSAM factors and initial values, keyframe by keyframe."""

    def __init__(
        self,
        problem: GraphProblem,
        odometry_robust: bool = True,
        odometry_fixed=None,
        odometry_weights=None,
        final_robust=None,
    ) -> None:
        """``odometry_robust=False`` drops the odometry stream's robust loss;
        ``odometry_fixed`` (m,) holds the odometry calibration at these values (no variable);
        ``odometry_weights`` (K-1,) are frozen robust weights: each odometry factor is
        Gaussian with its covariance divided by its weight (no loss). The stages of
        :func:`odofuse.estimators.graph.solvers.run_smoother`.

        ``final_robust`` (stream -> (kind, k)): :attr:`final` collects every factor that
        :meth:`static` and :meth:`keyframe` make, a sensor row's with the loss given here for
        its stream instead of ``problem.robust``'s (:meth:`with_loss`): iSAM2 is updated
        online with convex losses and solves :attr:`final`, the configured ones, at the end
        (:func:`odofuse.estimators.graph.problem.convex_problem`)."""
        import gtsam

        self.p = problem
        self.final_robust = dict(final_robust) if final_robust is not None else None
        self.final = gtsam.NonlinearFactorGraph() if final_robust is not None else None
        self.odometry_robust = odometry_robust and odometry_weights is None
        self.odometry_fixed = None if odometry_fixed is None else np.asarray(odometry_fixed)
        self.odometry_weights = odometry_weights
        self.gtsam = gtsam
        self.dims: dict[int, int] = {}
        self.python_factors = 0
        self.used: dict[str, int] = {problem.odometry_stream: problem.odometry_rows}
        for s in problem.models:
            self.used.setdefault(s, 0)
        self.created: list = []  # (measurement, factor) in the order added
        # the last keyframe's sensor rows: (position among its factors, measurement, factor)
        self.rows: list = []
        self.by_kf: dict[int, list[Measurement]] = {}
        for meas in problem.measurements:
            added = meas.keyframe if meas.added_at is None else meas.added_at
            self.by_kf.setdefault(added, []).append(meas)
        self.loops_by_kf: dict[int, list] = {}  # graph.loops.Loop records by later keyframe
        for loop in problem.loops:
            self.loops_by_kf.setdefault(loop.later, []).append(loop)
        if problem.loops:
            self.used[STREAM] = 0
        self.landmark_keys: dict[int, int] = {}
        needs_landmarks = {m.landmark for m in problem.measurements if m.landmark is not None}
        for lid in sorted(needs_landmarks):
            if self._landmark_variable_needed(lid):
                self.landmark_keys[lid] = L(lid)
        self.calib_keys = {name: key for name, (key, _, _) in problem.calib.items()}
        # calibration state -> constant used by new factors once frozen (iSAM2 only)
        self.frozen: dict[str, float] = {}
        # frozen beacon ranges: (factor, private beacon key, beacon position) to add with
        # the next keyframe, and the factor -> range scale its unwhitened error is divided by
        self._pending: list = []
        self.error_scale: dict[int, float] = {}
        # keyframe interval -> [(gyro stream, n)] of its pre-integrated gyro increments, and
        # the factors made of them: (stream, n, factor)
        self.gyro_by_interval: dict[int, list[tuple[str, int]]] = {}
        for stream, inc in problem.gyro.items():
            for n, i in enumerate(inc.interval):
                self.gyro_by_interval.setdefault(int(i), []).append((stream, n))
        self.gyro_created: list = []
        self.odometry_created: list = []  # (keyframe i, factor from i-1 to i)
        self.slip = slip_scales(problem)  # (K-1,) odometry covariance factors (wheel slip)
        # walking gyro bias (calib name) -> key of its newest segment (the fixed-lag window
        # keeps that one; older segments leave the window with their keyframes)
        self.bias_current: dict[str, int] = {n: problem.calib[n][0] for n in problem.bias_walk}
        self._theta_guess: dict[int, float] = {}

    def _landmark_variable_needed(self, lid) -> bool:
        if self.p.options.slam:
            return True
        # Known landmarks become pinned variables only for factors without calibration keys.
        return any(
            m.landmark == lid and not self.model_calib(self.p.models[m.stream])
            for m in self.p.measurements
        )

    def model_calib(self, model) -> dict:
        """Model state name -> GTSAM key of the model's estimated calibration states."""
        clones = set(getattr(model, "clones", lambda: {})())
        stream = getattr(model, "name", "")
        names = {s: self.p.state_name(stream, s) for s in getattr(model, "calib_states", ())}
        return {
            s: self.p.calib[n][0] for s, n in names.items() if n in self.p.calib and s not in clones
        }

    def static(self):
        """Priors on the first pose, calibration states and landmarks, with their values."""
        gtsam = self.gtsam
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        p = self.p
        pose0 = gtsam.Pose2(*p.pose0)
        g.add(
            gtsam.PriorFactorPose2(
                X(0),
                pose0,
                gtsam.noiseModel.Gaussian.Covariance(se2.cov_world_to_body(p.pose0, p.P0)),
            )
        )
        v.insert(X(0), pose0)
        self.dims[X(0)] = 3
        for _name, (key, value, sigma) in p.calib.items():
            v.insert(key, np.array([value]))
            g.add(
                gtsam.PriorFactorVector(
                    key, np.array([value]), gtsam.noiseModel.Isotropic.Sigma(1, sigma)
                )
            )
            self.dims[key] = 1
        if p.odometry_calibration is not None and self.odometry_fixed is None:
            oc = p.odometry_calibration
            v.insert(p.odometry_key, np.array(oc.nominal))
            prior = gtsam.noiseModel.Diagonal.Sigmas(np.array(oc.sigma))
            g.add(gtsam.PriorFactorVector(p.odometry_key, np.array(oc.nominal), prior))
            self.dims[p.odometry_key] = len(oc.nominal)
        for lid, key in self.landmark_keys.items():
            pos = p.landmarks.get(lid)
            v.insert(key, gtsam.Point2(*pos))
            self.dims[key] = 2
            if not p.options.slam:
                g.add(
                    gtsam.PriorFactorPoint2(
                        key,
                        gtsam.Point2(*pos),
                        gtsam.noiseModel.Isotropic.Sigma(2, p.options.known_landmark_sigma),
                    )
                )
        if self.final is not None:  # no sensor rows here
            self.final.push_back(g)
        return g, v

    def odometry(self, i: int):
        """``BetweenFactorPose2`` from keyframe ``i-1`` to ``i``."""
        d = self.p.deltas[i - 1]
        loss, k = self.p.robust.get(self.p.odometry_stream, ("none", 0.0))
        if not self.odometry_robust:
            loss = "none"
        cov = self.p.covs[i - 1] * self.slip[i - 1]
        if self.odometry_weights is not None:
            cov = cov / self.odometry_weights[i - 1]
        floor = 0.0 if self.p.pose_graph else self.p.options.odometry_floor  # the file's noise
        nm = robust_noise(_odometry_noise(cov, floor), loss, k)
        oc = self.p.odometry_calibration
        if oc is not None and self.odometry_fixed is not None:
            # m(p) = delta0 Exp(G (p - p0)) at the fixed p (calibrated_between_factor's model)
            xi = self.p.G[i - 1] @ (self.odometry_fixed - np.asarray(oc.nominal))
            m = self.gtsam.Pose2(*d).compose(self.gtsam.Pose2.Expmap(xi))
            return self.gtsam.BetweenFactorPose2(X(i - 1), X(i), m, nm)
        if oc is not None:
            self.python_factors += 1
            return calibrated_between_factor(
                X(i - 1), X(i), self.p.odometry_key, d, self.p.G[i - 1], oc.nominal, nm
            )
        return self.gtsam.BetweenFactorPose2(X(i - 1), X(i), self.gtsam.Pose2(*d), nm)

    def loop(self, loop):
        """``BetweenFactorPose2`` of a :class:`~odofuse.estimators.graph.loops.Loop`, with the
        robust loss of ``sensors.loop_closures.robust``."""
        loss, k = self.p.robust.get(STREAM, ("none", 0.0))
        nm = robust_noise(self.gtsam.noiseModel.Gaussian.Covariance(loop.cov), loss, k)
        return self.gtsam.BetweenFactorPose2(
            X(loop.i), X(loop.j), self.gtsam.Pose2(*loop.delta), nm
        )

    def measurement(self, meas: Measurement, loss: tuple[str, float] | None = None):
        """The factor of one sensor row (robust loss of its stream applied).

        ``loss`` (kind, k) replaces the stream's loss: a twin for another graph
        (:meth:`with_loss`), not counted in :attr:`python_factors`.
        """
        gtsam = self.gtsam
        m = self.p.models[meas.stream]
        kind = model_kind(m)
        calib = self.model_calib(m)
        count = int(loss is None)  # python_factors counts the factors of this graph only
        loss, k = loss or self.p.robust.get(meas.stream, ("none", 0.0))
        key = X(meas.keyframe)
        if kind == "LandmarkRangeBearing" and meas.landmark in self.landmark_keys:
            # GTSAM's BearingRange measurement is ordered (bearing, range).
            R = m.R(meas.row)
            base = gtsam.noiseModel.Diagonal.Sigmas(np.sqrt([R[1, 1], R[0, 0]]))
            return m.factor(
                key,
                meas.row,
                None,
                robust_noise(base, loss, k),
                landmark_key=self.landmark_keys[meas.landmark],
            )
        base = m.noise(meas.row)
        nm = robust_noise(base, loss, k)
        if kind == "BeaconRange" and meas.landmark in self.landmark_keys:
            lkey = self.landmark_keys[meas.landmark]
            if calib:
                self.python_factors += count
                return range_factor(
                    key,
                    meas.row["range"],
                    nm,
                    landmark_key=lkey,
                    scale_key=calib.get("range_scale"),
                    offset_key=calib.get("range_offset"),
                )
            return gtsam.RangeFactor2D(key, lkey, float(meas.row["range"]), nm)
        if kind == "LandmarkBearing" and meas.landmark in self.landmark_keys:
            return m.factor(key, meas.row, None, nm, landmark_key=self.landmark_keys[meas.landmark])
        if calib and all(s in self.frozen for s in calib) and kind == "BeaconRange":
            if not count:  # a twin: with_loss clones the built-in factor (same private beacon)
                raise ValueError("a frozen beacon range's twin is a clone (Factors.with_loss)")
            return self._frozen_beacon_range(m, meas, loss, k)
        if calib and all(s in self.frozen for s in calib):
            self.python_factors += count
            consts = {s: self.frozen[s] for s in calib}
            return frozen_calibration_factor(m, key, meas.row, consts, nm)
        f = m.factor(key, meas.row, calib, nm)
        if isinstance(f, gtsam.CustomFactor):
            self.python_factors += count
        return f

    def with_loss(self, meas: Measurement, f, loss: tuple[str, float]):
        """The factor ``f`` that :meth:`measurement` made of ``meas`` (with the calibration
        frozen or not as it was then), with the robust ``loss`` (kind, k) on the same Gaussian
        noise instead of its stream's: a built-in factor is cloned with the new noise model, a
        Python factor (which GTSAM cannot clone) is made again. Not counted in
        :attr:`python_factors`.
        """
        if isinstance(f, self.gtsam.CustomFactor):
            return self.measurement(meas, loss)
        nm = f.noiseModel()
        base = nm.noise() if hasattr(nm, "robust") else nm
        return f.cloneWithNewNoiseModel(robust_noise(base, *loss))

    def gyro(self, stream: str, n: int, i: int):
        """The heading-increment factor of the ``n``-th gyro increment, keyframes ``i-1, i``.

        Without a bias variable a ``BetweenFactorPose2`` whose noise has zero precision on
        the translation: its error is exactly ``wrap(theta_i - theta_{i-1} - dtheta)`` (the
        rotation part of Pose2's ``Logmap``) and it takes the stream's robust loss. With the
        ``gyro_bias`` variable the error ``theta_i - theta_{i-1} + b T - dtheta`` is linear in
        the tangent coordinates of the three variables, so a ``LinearContainerFactor``
        (linearised at the keyframes' initial headings) is that factor exactly, in C++, as
        long as no heading moves by more than pi from its initial value; with a robust loss
        it is :func:`gyro_increment_factor` (Python). A walking bias
        (:attr:`GraphProblem.bias_walk`) enters through its segment of interval ``i-1``.
        """
        gtsam = self.gtsam
        inc = self.p.gyro[stream]
        dtheta, var, T = float(inc.dtheta[n]), float(inc.var[n]), float(inc.T[n])
        bias_key = self.model_calib(self.p.models[stream]).get("gyro_bias")
        if bias_key is not None:  # the segment of interval i-1 when the bias walks
            bias_key = self.p.bias_key(self.p.state_name(stream, "gyro_bias"), i - 1)
        loss, k = self.p.robust.get(stream, ("none", 0.0))
        if bias_key is None:
            nm = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0, 0.0, 1.0 / var]))
            return gtsam.BetweenFactorPose2(
                X(i - 1), X(i), gtsam.Pose2(0.0, 0.0, dtheta), robust_noise(nm, loss, k)
            )
        sigma = math.sqrt(var)
        nm = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
        if loss != "none":
            self.python_factors += 1
            return gyro_increment_factor(
                X(i - 1), X(i), bias_key, dtheta, T, robust_noise(nm, loss, k)
            )
        b0 = float(self.p.calib[self.p.state_name(stream, "gyro_bias")][1])
        th0, th1 = self._theta_guess[i - 1], self._theta_guess[i]
        e0 = float(se2.wrap(th1 - th0 + b0 * T - dtheta))
        jf = gtsam.JacobianFactor(
            X(i - 1),
            np.array([[0.0, 0.0, -1.0]]),
            X(i),
            np.array([[0.0, 0.0, 1.0]]),
            bias_key,
            np.array([[T]]),
            np.array([-e0]),
            nm,
        )
        lin = gtsam.Values()
        lin.insert(X(i - 1), gtsam.Pose2(0.0, 0.0, th0))
        lin.insert(X(i), gtsam.Pose2(0.0, 0.0, th1))
        lin.insert(bias_key, np.array([b0]))
        return gtsam.LinearContainerFactor(jf, lin)

    def bias_segment(self, name: str, i: int, g, v) -> None:
        """Adds segment ``i-1`` of the walking bias ``name`` to ``g``/``v`` (keyframe ``i >= 2``).

        A new variable (initial value: the prior's) tied to segment ``i-2`` by GTSAM's
        ``BetweenFactorVector`` with zero mean and sigma
        :meth:`GraphProblem.bias_step_sigma`: the random walk, discretised per keyframe
        interval.
        """
        gtsam = self.gtsam
        j = i - 1
        key, prev = self.p.bias_key(name, j), self.p.bias_key(name, j - 1)
        v.insert(key, np.array([self.p.calib[name][1]]))
        nm = gtsam.noiseModel.Isotropic.Sigma(1, self.p.bias_step_sigma(name, j))
        g.add(gtsam.BetweenFactorVector(prev, key, np.zeros(1), nm))
        self.dims[key] = 1
        self.bias_current[name] = key

    def _frozen_beacon_range(self, m, meas, loss, k):
        """A frozen ``s ||p - b|| + o = z`` range as built-in GTSAM factors.

        ``(s d + o - z) / sigma = (d - z') / sigma'`` with ``z' = (z - o) / s`` and
        ``sigma' = sigma / s``: the same whitened error (and robust weight, whose threshold
        is in sigma), so ``RangeFactor2D(x, b_n, z', sigma')`` to a *private* copy ``b_n``
        of the beacon, pinned by a ``known_landmark_sigma`` prior, is the calibrated factor
        with constant ``s, o``. A private copy per factor keeps the factor local (a shared
        beacon variable would tie all range factors together again) and built-in (a Python
        ``CustomFactor`` linearised inside iSAM2 costs a copy of all the values).
        """
        gtsam = self.gtsam
        scale = self.frozen.get("range_scale", 1.0)
        offset = self.frozen.get("range_offset", 0.0)
        sigma = math.sqrt(float(m.R(meas.row)[0, 0])) / scale
        nm = robust_noise(gtsam.noiseModel.Isotropic.Sigma(1, sigma), loss, k)
        z = (float(meas.row["range"]) - offset) / scale
        bkey = B(len(self.error_scale))
        f = gtsam.RangeFactor2D(X(meas.keyframe), bkey, z, nm)
        pos = np.asarray(self.p.landmarks[meas.landmark], dtype=float)
        self._pending.append((bkey, gtsam.Point2(*pos)))
        self.error_scale[id(f)] = 1.0 / scale
        self.dims[bkey] = 2
        return f

    def keyframe(self, i: int, values_guess, g=None, v=None):
        """Factors and new values of keyframe ``i`` (odometry from ``i-1`` and its sensors),
        added to ``g``/``v`` (new containers when omitted)."""
        gtsam = self.gtsam
        if g is None:
            g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        first = g.size()  # this keyframe's factors are g's from here on
        twins: dict[int, object] = {}  # position in g -> the factor for self.final
        self.rows = []
        self._theta_guess[i] = float(values_guess.theta())
        if i > 0:
            f = self.odometry(i)
            g.add(f)
            self.odometry_created.append((i, f))
            v.insert(X(i), values_guess)
            self.dims[X(i)] = 3
            if i > 1:
                for name in self.p.bias_walk:
                    self.bias_segment(name, i, g, v)
            for stream, n in self.gyro_by_interval.get(i - 1, ()):
                f = self.gyro(stream, n, i)
                g.add(f)
                self.gyro_created.append((stream, n, f))
                self.used[stream] = self.used.get(stream, 0) + int(self.p.gyro[stream].samples[n])
        for loop in self.loops_by_kf.get(i, ()):
            g.add(self.loop(loop))
            self.used[STREAM] += 1
        for meas in self.by_kf.get(i, ()):
            f = self.measurement(meas)
            final = (self.final_robust or {}).get(meas.stream)
            if final is not None and final != self.p.robust.get(meas.stream):
                twins[g.size()] = self.with_loss(meas, f, final)
            self.rows.append((g.size() - first, meas, f))
            g.add(f)
            self.created.append((meas, f))
            self.used[meas.stream] = self.used.get(meas.stream, 0) + meas.rows
        pin = gtsam.noiseModel.Isotropic.Sigma(2, self.p.options.known_landmark_sigma)
        for bkey, pos in self._pending:
            v.insert(bkey, pos)
            g.add(gtsam.PriorFactorPoint2(bkey, pos, pin))
        self._pending.clear()
        if self.final is not None:
            for j in range(first, g.size()):
                self.final.add(twins[j] if j in twins else g.at(j))
        return g, v
