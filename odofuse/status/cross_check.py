"""A second opinion on an offline run: the batch smoother of the same log and config.

Owns the cross-check that :func:`odofuse.rundir.run_one` (``odofuse run``, ``odofuse batch``)
applies to a causal estimate, the issue-10 hold bounds (:data:`HOLD_RMSE_RATIO`,
:data:`HOLD_NEES`, declared here once and used by the judge of
:mod:`odofuse.teaching.trust_scenarios`) and the ``cross_check`` block of ``metrics.json``.

The filters' own checks see only their innovations; a consistent filter that is merely far less
accurate than the smoother passes them all. Offline, the batch smoother of the same readings
is a better estimate whose covariance says how good it is. With ``e_f``, ``e_s`` the errors of
the estimate and of the smoother and ``d = p_f - p_s`` their position difference, an optimal
smoother's error is orthogonal to ``d`` (``e_f = d + e_s``), so

* ``RMSE_f^2 ~= rms(d)^2 + RMSE_s^2`` and ``RMSE_s^2 ~= s^2``, the mean trace of the smoother's
  position covariance scaled by the smoother's own variance components (its residuals'
  verdict on the scale of its noise model, ``variance_components`` of
  :mod:`odofuse.estimators.graph.variance`; ``smoother_variance_factor``): the *predicted
  ratio* ``sqrt(1 + rms(d)^2 / s^2)`` estimates ``RMSE_f / RMSE_s`` without ground truth
  (information in the block);
* the predicted ratio plugs in ``s^2`` as if the smoother's realised error were its
  expectation; on one log it scatters widely (the smoother's error is correlated along the
  trajectory). The finding therefore asks the smoother's own posterior: given the data the
  truth is ``x_s - e``, ``e ~ N(0, P_s)`` (the linearised smoother under its variance
  components), so the judge's ratio is the random variable
  ``R^2 = mean_t |d_t + e_t|^2 / mean_t |e_t|^2``; with the smoother's joint error samples
  (:class:`odofuse.estimators.graph.variance.ErrorSamples`) the check reports
  ``p_fail = P(R > HOLD_RMSE_RATIO | data)`` and fires above :data:`ALPHA` (finding
  ``cross_check``; estimators that fuse an absolute sensor only, not :data:`UNAIDED` ones).
  Without samples it falls back to the predicted ratio above :data:`HOLD_RMSE_RATIO` and
  says so (``rule`` in the block);
* ``cov(d) = P_f - P_s <= P_f`` for a consistent estimate, so the *departure NEES*
  ``mean d^T P_f^-1 d`` is at most 2 (position) and is a lower bound of the estimate's own
  position NEES; above :data:`HOLD_NEES` (the judge's bound: the run cannot hold) the estimate
  is overconfident (finding ``cross_check_nees``, every estimator incl. dead reckoning).

The check needs the smoother's own ``status`` to be ``ok`` (a degraded yardstick measures
nothing); a check that does not apply is recorded as ``skipped: <reason>``, not as a warning.
What the smoother detected in the log carries to the run either way
(:func:`with_reference_findings`).

The estimators without a calibration drift check of their own (:data:`COMPANION`) also
carry an EKF's of the same log and config, run once per log with the reference
(:attr:`Reference.drift`, :func:`companion_applies`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from odofuse.errors import one_line
from odofuse.estimators.common import absolute_streams, sensor_kind, slam_option
from odofuse.status import latency
from odofuse.status.findings import Finding, assess, status_of
from odofuse.trajectory import EstimateResult, Trajectory, pose_blocks

#: RMSE ratio to the batch smoother within which an estimator that fuses absolute sensors holds.
HOLD_RMSE_RATIO = 2.0
#: Position NEES below which an estimate holds (and the departure-NEES bound of the check).
HOLD_NEES = 10.0
#: Posterior probability of failing the judge above which the ``advice`` line is given: the
#: conventional significance level. Advice only: it never changes ``status``.
ALPHA = 0.05
#: Ratio of the smoother's position sigma to the estimate's own above which the reference is
#: not sane: the smoother has every reading the estimate had and more, so its covariance
#: should not exceed the estimate's; beyond twice its sigma (the judge's ratio) the two runs
#: disagree about the problem itself (issue 31: a smoother sigma of 3.8e7 m passed silently).
REFERENCE_SIGMA_RATIO = 2.0
#: Estimators whose in-run checks see a drift their covariance does not cover: the filters'
#: NIS windows test each absolute sensor's innovations against the *predicted* covariance
#: (docs/trust.md, "The promise"), and so do the fixed-lag smoother's and iSAM2's
#: (:mod:`odofuse.estimators.graph.innovations`). Dead reckoning has no absolute sensor; the
#: batch smoother's residual checks test residuals against the sensor noise alone, blind to
#: an overconfident pose covariance. For every other estimator a second opinion that could
#: not judge degrades.
DRIFT_EVIDENCE = frozenset({"ekf", "ukf", "particle", "fixed_lag", "isam2"})
#: The incremental graph estimators, whose NIS checks run at :data:`NIS_OPTIONS
#: <odofuse.estimators.graph.innovations.NIS_OPTIONS>` on their sensor rows (not the gyro's, a
#: factor between poses; with ``slam: true``, iSAM2's re-sightings of landmarks in its graph).
GRAPH_NIS = frozenset({"fixed_lag", "isam2"})
#: Estimators without a calibration drift check of their own that carry an EKF's, offline
#: (:func:`companion_findings`): the batch smoother's, iSAM2's and fixed-lag's calibration
#: estimates are not martingales (they revisit past linearisations; docs/trust.md, "iSAM2 was
#: tried and not built"), the particle filter's carry Monte Carlo noise that its covariance does
#: not hold, and dead reckoning estimates none. The check tests the log against the config's
#: model (a calibration constant up to its declared walk), which every estimator of the same
#: log and config shares.
COMPANION = frozenset({"dead_reckoning", "particle", "smoother", "isam2", "fixed_lag"})
#: Estimate times per block of the posterior's pass (temporaries ``K * block * 2`` floats).
SAMPLE_BLOCK = 2048
#: Estimators that fuse no absolute sensor: judged on their covariance alone (their drift from
#: a smoother that has the absolute sensors is expected).
UNAIDED = frozenset({"dead_reckoning"})
#: The estimators the check applies to: their estimate is of the problem the smoother solves.
CHECKED = ("dead_reckoning", "ekf", "ukf", "particle", "fixed_lag", "isam2")
#: Odometry streams, one of which a log's estimate integrates.
ODOMETRY_STREAMS = ("odometry", "wheels", "cmd_vel")


#: Findings that report a fault of the log the smoother handled, not a fault of its estimate:
#: a smoother degraded by them alone is still the comparison's yardstick (a slip burst longer
#: than a second: its robust odometry widened those intervals). The finding itself carries to
#: the run it judges (:func:`with_reference_findings`): a gyro bias step fires it too, and then
#: the smoother's estimate is as far off as the run's (docs/trust.md, seed 18303).
DATA_FAULTS = ("slip_run",)
#: The reference's findings about its own solution, not about the log: they do not carry to
#: the runs it judges (:func:`with_reference_findings`).
SOLUTION_CHECKS = ("solver", "covariance", "pose")
#: How a finding of the reference starts when it is carried to a run it judges
#: (:func:`with_reference_findings`, :func:`variance_factor_findings`).
SEEN_BY_REFERENCE = "seen by the batch smoother of this log: "


@dataclass(frozen=True)
class Reference:
    """The batch smoother's run that a cross-check compares with.

    Attributes
    ----------
    result : EstimateResult
        The smoother's estimate (poses and world-frame covariances).
    status : str
        Its own status (:func:`odofuse.status.findings.status_of` of its findings).
    runtime_s : float
        Wall-clock time of the smoother run (s).
    config : str
        The config it ran with (its ``source``).
    """

    result: EstimateResult
    status: str
    runtime_s: float
    config: str
    #: Its status without the findings of :data:`DATA_FAULTS` (a fault of the log that the
    #: smoother handled leaves it a yardstick); None: ``status``.
    yardstick_status: str | None = None
    #: A function returning the companion findings of its log and config
    #: (:func:`companion_findings`), run once on its first call; None: run
    #: them with the checked run's config.
    drift: Callable[[], tuple[Finding, ...]] | None = field(default=None, compare=False)


def reference_of(config, log) -> Reference:
    """Run the batch smoother on ``log`` with ``config`` (estimator replaced), with its
    error samples (:data:`odofuse.estimators.graph.variance.ERROR_SAMPLES`)."""
    from odofuse.estimators import run_estimator
    from odofuse.estimators.graph.variance import ERROR_SAMPLES

    cfg = dataclasses.replace(config, estimator="smoother")
    t0 = time.perf_counter()
    result = run_estimator("smoother", log, cfg, error_samples=ERROR_SAMPLES)
    found = assess(result)
    yardstick = status_of([f for f in found if f.check not in DATA_FAULTS])
    runtime = time.perf_counter() - t0
    drift = functools.cache(lambda: companion_findings(cfg, log))
    return Reference(result, status_of(found), runtime, cfg.source, yardstick, drift)


def odometry_steps(log) -> int:
    """Rows of the log's odometry stream (the largest of :data:`ODOMETRY_STREAMS`)."""
    streams = getattr(log, "streams", {}) or {}
    return max((len(streams[n]) for n in ODOMETRY_STREAMS if n in streams), default=0)


def skip_reason(config, log) -> str | None:
    """Why the cross-check does not apply to this run, or None when it does.

    Parameters
    ----------
    config : RunConfig
        The run's config (``estimator``, ``sensors``, ``options.cross_check``).
    log : SensorLog

    Returns
    -------
    str or None
        ``off``; the estimate is the smoother itself; an estimator the smoother is not a second
        opinion for (a plug-in, SLAM, a log with loop closures: a pose-graph problem); with
        ``auto``, no absolute sensor fused or more than ``max_odometry_steps`` odometry steps.
    """
    est = config.estimator
    if config.estimator_options("cross_check").smoother == "off":
        return "off (options.cross_check.smoother)"
    if est == "smoother":
        return "the estimate is the batch smoother"
    if est not in CHECKED:
        return f"estimator '{est}' is not one the batch smoother is a second opinion for"
    return scope_reason(config, log)


def scope_reason(config, log) -> str | None:
    """The log-shape part of :func:`skip_reason` (SLAM, loop closures, ``auto``'s absolute
    sensors and length), whatever the estimator: also the scope of the smoother's own
    variance-factor test (:func:`variance_factor_findings`)."""
    opts = config.estimator_options("cross_check")
    est = config.estimator
    if slam_option(config, est) or slam_option(config, "smoother"):
        return "a SLAM run (landmarks unknown): not the smoother's problem"
    streams = getattr(log, "streams", {}) or {}
    if "loop_closures" in streams and len(streams["loop_closures"]):
        return "the log holds loop closures (a pose-graph problem)"
    if opts.smoother == "on":
        return None
    if not absolute_streams(config, log):
        return "auto: no absolute sensor fused (the smoother would be dead reckoning too)"
    n = odometry_steps(log)
    if n > opts.max_odometry_steps:
        return (
            f"auto: {n} odometry steps, above options.cross_check.max_odometry_steps "
            f"({opts.max_odometry_steps})"
        )
    return None


def posterior_fail(estimate: Trajectory, smoother: Trajectory, samples: np.ndarray) -> float:
    """Posterior probability that ``estimate`` fails the judge's RMSE ratio.

    Parameters
    ----------
    estimate : Trajectory
        The run's estimate.
    smoother : Trajectory
        The batch smoother (keyframe poses, the samples' times).
    samples : ndarray, shape (K, N, 2)
        Joint samples of the smoother's position errors ``e`` at its N keyframes (m, world
        frame): the truth is the smoother's position minus ``e``.

    Returns
    -------
    float
        The fraction of the K samples whose ratio ``R^2 = mean_t |d_t + e_t|^2 /
        mean_t |e_t|^2`` exceeds ``HOLD_RMSE_RATIO^2``: ``d`` the estimate minus the smoother
        and ``e`` the sampled errors interpolated linearly between keyframes, at the
        estimate's times the smoother covers (:func:`odofuse.evaluation.associate`).
    """
    from odofuse.evaluation import associate
    from odofuse.trajectory import bracket

    idx, g = associate(estimate, smoother)
    t = np.clip(estimate.t[idx], smoother.t[0], smoother.t[-1])
    tt = smoother.t
    k_samples = samples.shape[0]
    num, den = np.zeros(k_samples), np.zeros(k_samples)
    for b in pose_blocks(idx.size, SAMPLE_BLOCK):
        d = estimate.poses[idx[b], :2] - g[b, :2]  # (B, 2)
        if tt.size == 1:
            e = np.repeat(samples[:, :1], d.shape[0], axis=1)
        else:
            k, a = bracket(tt, t[b])
            a = a[None, :, None]
            e = samples[:, k] + a * (samples[:, k + 1] - samples[:, k])  # (K, B, 2)
        num += np.sum((d[None] + e) ** 2, axis=(1, 2))
        den += np.sum(e**2, axis=(1, 2))
    return float(np.mean(num > HOLD_RMSE_RATIO**2 * den))


def _fmt(x) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.3g}"


def nees_bound(alpha: float) -> float:
    """Bound ``c`` on a mean position NEES with false-alarm probability at most ``alpha``,
    whatever the correlation of its terms along the trajectory.

    Each term ``q_t = d_t^T M_t^-1 d_t`` with ``cov(d_t) <= M_t`` is stochastically below a
    chi-square of 2 degrees of freedom (an exponential of mean 2), and the terms of one
    trajectory are strongly correlated, so the mean of N terms is *not* ``chi2(2N) / N``.
    By Jensen and that dominance ``E[(mean q - k)+] <= E[(X - k)+] = 2 exp(-k / 2)`` for
    ``X ~ chi2(2)``, hence ``P(mean q > c) <= 2 exp(-k / 2) / (c - k)`` for every ``k < c``;
    at ``k = c - 2`` this is ``exp(1 - c / 2)``, so ``c = 2 (1 + ln(1 / alpha))`` (8.2 at
    0.045; the tail of a single chi-square(2), the fully correlated case, is ``2 ln(1 /
    alpha)``).
    """
    if not alpha > 0:
        return math.inf
    return 2.0 * (1.0 + math.log(1.0 / alpha))


def _cov_at(smoother: Trajectory, t: np.ndarray) -> np.ndarray:
    """The smoother's world-frame position covariances (M, 2, 2) at times ``t`` (inside its
    span), linear between keyframes (a convex combination: positive semi-definite)."""
    from odofuse.trajectory import bracket

    C = smoother.covariances[:, :2, :2]
    if smoother.t.size == 1:
        return np.repeat(C[:1], t.size, axis=0)
    k, a = bracket(smoother.t, t)
    return C[k] + a[:, None, None] * (C[k + 1] - C[k])


def departure_nees(estimate: Trajectory, smoother: Trajectory) -> float:
    """Mean ``d^T (P_f + P_s)^-1 d`` over the estimate's poses the smoother covers (position).

    ``d`` is the estimate's position minus the smoother's (interpolated as ground truth is,
    :func:`odofuse.evaluation.associate`), ``P_f`` the estimate's position covariance and
    ``P_s`` the smoother's (interpolated; 0 when it has none). For a consistent estimate and
    smoother ``cov(d) = P_f - P_s <= P_f + P_s`` (the smoother's error is orthogonal to
    ``d``), so each term is at most chi-square(2). NaN without the estimate's covariances or
    when no combined covariance is positive definite.
    """
    from odofuse.evaluation import associate, nees

    if estimate.covariances is None:
        return math.nan
    idx, _g = associate(estimate, smoother)
    P = np.array(estimate.covariances[idx], dtype=float)
    if smoother.covariances is not None:
        t = np.clip(estimate.t[idx], smoother.t[0], smoother.t[-1])
        Ps = _cov_at(smoother, t)
        P[:, :2, :2] += np.where(np.isfinite(Ps), Ps, 0.0)
    combined = Trajectory(estimate.t[idx], estimate.poses[idx], P)
    return nees(combined, smoother, (0, 1))


def compare(
    estimate: Trajectory,
    smoother: Trajectory,
    fused: bool,
    variance_scale: float | None = None,
    samples: np.ndarray | None = None,
    alpha: float = ALPHA,
) -> tuple[dict, list[Finding], list[str]]:
    """The ``cross_check`` figures of ``estimate`` against ``smoother``, its consistency
    finding and its accuracy advice.

    Parameters
    ----------
    estimate : Trajectory
        The run's estimate, world-frame covariances ``(N, 3, 3)`` (or None: no NEES figure).
    smoother : Trajectory
        The batch smoother of the same log, interpolated to the estimate's times
        (:func:`odofuse.evaluation.ate`'s association: inside its span, not across its gaps).
    fused : bool
        The estimate fuses absolute sensors: the accuracy advice applies (dead reckoning's
        drift from a smoother that has them is expected).
    variance_scale : float, optional
        The smoother's own scale of its position covariance (``position_variance_scale`` of
        :func:`odofuse.estimators.graph.variance.variance_components`); ``s^2`` is the mean
        trace times it (advice only). None: 1.
    samples : ndarray, shape (K, N, 2), optional
        Joint samples of the smoother's position errors at its poses (m, world frame;
        :class:`odofuse.estimators.graph.variance.ErrorSamples`): the advice's
        :func:`posterior_fail`. None: the predicted ratio alone.
    alpha : float
        The consistency test's share of the run's false-alarm rate (:func:`alpha_budget`):
        ``cross_check_nees`` fires when the departure NEES exceeds :func:`nees_bound` of it.

    Returns
    -------
    block : dict
        ``poses_compared``, ``departure_rms_m`` (rms(d), m), ``smoother_sigma_m`` (``s``, m),
        ``smoother_sigma_model_m`` (``s`` before the variance scale, m),
        ``smoother_variance_factor``, ``predicted_ratio`` (``sqrt(1 + rms(d)^2 / s^2)``),
        ``p_fail`` (None without samples or when not ``fused``), ``samples``,
        ``departure_nees`` (:func:`departure_nees`), ``nees_alpha`` and ``nees_bound`` (the
        consistency test), ``ratio_bound`` and ``advice_alpha`` (the advice's); or
        ``skipped`` when nothing overlaps.
    findings : list of Finding
        ``cross_check_nees``: the departure NEES above its bound (the estimate's covariance
        does not cover its departure from the smoother; degrades).
    advice : list of str
        One line when a fused estimate is likely more than :data:`HOLD_RMSE_RATIO` times less
        accurate than the smoother (``p_fail`` above :data:`ALPHA`, or without samples the
        predicted ratio above :data:`HOLD_RMSE_RATIO`). Never a finding.
    """
    from odofuse.evaluation import ate, covered

    idx = np.flatnonzero(covered(estimate.t, smoother.t)) if len(estimate) and len(smoother) else []
    if len(idx) == 0:
        return {"skipped": "the smoother's poses do not overlap the estimate's"}, [], []
    rms = ate(estimate, smoother).rmse_m
    s2 = math.nan
    if smoother.covariances is not None:
        tr = smoother.covariances[:, 0, 0] + smoother.covariances[:, 1, 1]
        tr = tr[np.isfinite(tr) & (tr > 0)]
        s2 = float(tr.mean()) if tr.size else math.nan
    s2_model = s2
    if variance_scale is not None and math.isfinite(variance_scale) and variance_scale > 0:
        s2 = s2 * variance_scale
    ratio = math.sqrt(1.0 + rms**2 / s2) if s2 > 0 else None
    dn = departure_nees(estimate, smoother)
    bound = nees_bound(alpha)
    span = (float(estimate.t[idx[0]]), float(estimate.t[idx[-1]]))
    usable = samples is not None and samples.ndim == 3 and samples.shape[1] == len(smoother)
    # unaided estimates get no accuracy advice (their drift from the smoother is expected)
    p_fail = posterior_fail(estimate, smoother, samples) if usable and fused else None
    block = {
        "poses_compared": int(len(idx)),
        "departure_rms_m": rms,
        "smoother_sigma_m": math.sqrt(s2) if s2 > 0 else None,
        "smoother_sigma_model_m": math.sqrt(s2_model) if s2_model > 0 else None,
        "smoother_variance_factor": variance_scale,
        "predicted_ratio": ratio,
        "p_fail": p_fail,
        "samples": int(samples.shape[0]) if usable and fused else 0,
        "departure_nees": None if math.isnan(dn) else dn,
        "nees_alpha": alpha,
        "nees_bound": bound,
        "ratio_bound": HOLD_RMSE_RATIO if fused else None,
        "advice_alpha": ALPHA if fused else None,
    }
    advice = []
    likely = p_fail > ALPHA if p_fail is not None else ratio is not None and ratio > HOLD_RMSE_RATIO
    if fused and likely and ratio is not None:
        why = (
            f"posterior probability {p_fail:.2f} of more than {HOLD_RMSE_RATIO:g}x"
            if p_fail is not None
            else "from its covariance; no error samples"
        )
        advice.append(
            f"a batch smoother of this log is about {ratio:.2g}x more accurate ({why}; "
            f"{rms:.3g} m rms apart, smoother sigma {_fmt(s2**0.5)} m): `estimator: smoother`"
        )
    found = []
    if not math.isnan(dn) and dn > bound:
        found.append(
            Finding(
                "cross_check_nees",
                f"mean d^T (P + P_smoother)^-1 d = {dn:.3g} against the batch smoother of the "
                f"same log (consistent: at most 2; bound {bound:.3g} at false alarm "
                f"{alpha:.3g}): the covariance does not cover the estimate's departure from "
                "the smoother (overconfident)",
                t_start=span[0],
                t_end=span[1],
                figure=dn,
            )
        )
    return block, found, advice


#: Sensor kinds whose factors lie between poses: no row of theirs is tested against a
#: prediction or counted beyond a gate in a graph back end.
BETWEEN = ("gyro", "loop_closures")


def _gated(config, stream: str) -> bool:
    """Whether ``stream``'s readings pass a gate (a stream without one cannot fire a count)."""
    return getattr(config.sensors[stream], "gate", 0.999) is not None


def alpha_budget(config, log) -> dict:
    """The run's false-alarm rate and its split over the checks that can fire on a log that
    matches its config (docs/trust.md, "The promise"; Bonferroni: the union's probability is
    at most the sum).

    The in-run statistical checks keep their declared probabilities: the filters' NIS window
    test, run NIS test and rejection count per fused stream and innovation-mean scan per
    fused stream other than a gyro (``nis_alpha`` each), dead reckoning's
    gyro-vs-wheels test (``heading_alpha``), the EKF's and UKF's calibration drift test
    (``drift_alpha``, counted whenever they fuse a sensor; the other estimators carry an
    EKF's in the second opinion's scope, :func:`companion_applies`), the batch smoother's residual
    windows per odometry and gyro stream (``WINDOW_ALPHA``) and rejection count per gated
    sensor stream that is not between poses (``nis_alpha``), the time-stamp test per fused absolute
    stream (``options.status.latency_alpha``: a graph run's own, or the reference's that a
    filter takes, :func:`with_reference_findings`). What is left of ``alpha_run`` goes to the
    second opinion when it applies, half to its consistency test (``cross_check_nees``) and
    half to the sanity of its reference (the smoother's variance factor above its chi-square
    band: a filter's ``variance_factor`` finding, the others' skip); the smoother run as the
    estimate spends half of what is left on the same test of its own residuals
    (``variance_factor``, :func:`own_test`); every estimator it judges carries the smoother's
    findings about the log (:func:`with_reference_findings`), so its residual windows and
    rejection counts count, and the time-stamp tests for an estimator without its own share
    of them (dead reckoning, whose skipped check also degrades), and the EKF companion's drift
    and scans for the UKF (``reference_status``). The
    other checks (a covariance not positive definite, a solver that did not converge, a
    stream mostly rejected or silent, a calibration 5 prior sigmas out, a slip run, ...)
    cannot fire on a matching log, or with a probability below 1e-5 (docs/trust.md); they
    are not counted.

    Returns
    -------
    dict
        ``alpha_run``; ``checks``: check (``nis:<stream>``, ``nis_run:<stream>``,
        ``innovation_mean:<stream>``, ``rejection_count:<stream>``, ``calibration_drift``,
        ``gyro_wheels``,
        ``residual_windows:<stream>``, ``latency:<stream>``, ``cross_check_nees``,
        ``reference_variance``, ``variance_factor``) ->
        false-alarm probability per run; ``total`` (their sum, at most ``alpha_run``
        unless ``overspent``); ``overspent`` (the in-run checks alone exceed it).
    """
    from odofuse.estimators.graph.innovations import NIS_OPTIONS
    from odofuse.status.graph_checks import WINDOW_ALPHA

    a = float(config.estimator_options("status").alpha_run)
    est = config.estimator
    streams = getattr(log, "streams", {}) or {}
    fused = [str(n) for n in (config.sensors or {}) if n in streams and len(streams[n])]
    checks: dict[str, float] = {}
    graph = est in GRAPH_NIS
    # the streams the innovation-mean scans test (a gyro's in blocks: streaming.MEAN_BLOCK_S)
    scanned = set(fused)
    if est in DRIFT_EVIDENCE:
        # fixed-lag and iSAM2 (also with slam: graph.isam2_slam) test their sensor rows (not
        # the gyro's or the loop closures', factors between poses) at the filters' defaults
        nis_opts = NIS_OPTIONS if graph else config.estimator_options(est)
        tested = [n for n in fused if not graph or sensor_kind(config, n) not in BETWEEN]
        nis = float(nis_opts.nis_alpha)
        checks.update({f"nis:{n}": nis for n in sorted(tested)})
        checks.update({f"nis_run:{n}": nis for n in sorted(tested)})
        checks.update({f"innovation_mean:{n}": nis for n in sorted(scanned & set(tested))})
        # the rejection count of every gated stream (a stream without a gate cannot fire it)
        checks.update({f"rejection_count:{n}": nis for n in sorted(tested) if _gated(config, n)})
        drift = float(getattr(nis_opts, "drift_alpha", 0.0))
        if drift > 0.0 and fused:  # the EKF's and UKF's calibration drift check
            checks["calibration_drift"] = drift
    elif est == "dead_reckoning" and "gyro" in streams and len(streams["gyro"]):
        checks["gyro_wheels"] = float(config.estimator_options(est).heading_alpha)
    if companion_applies(config, log):  # an EKF's, for the others (COMPANION)
        ekf = config.estimator_options("ekf")
        checks["calibration_drift"] = float(ekf.drift_alpha)
        # and its innovation-mean scans (drift.seen_by_ekf)
        checks.update(
            {f"companion_innovation_mean:{n}": float(ekf.nis_alpha) for n in sorted(scanned)}
        )
    odo = next((n for n in ODOMETRY_STREAMS if n in streams), None)
    gyros = [n for n in fused if sensor_kind(config, n) == "gyro"]
    # the smoother's residual checks: windows of its odometry and gyros, and the rejection
    # count of every gated sensor stream but the factors between poses (graph_checks)
    smoother = {f"residual_windows:{n}": WINDOW_ALPHA for n in [odo, *gyros] if n}
    counted = [n for n in fused if sensor_kind(config, n) not in BETWEEN and _gated(config, n)]
    smoother.update({f"rejection_count:{n}": float(NIS_OPTIONS.nis_alpha) for n in counted})
    if est == "smoother":
        checks.update(smoother)
    applies = skip_reason(config, log) is None
    # the time-stamp test (status.latency): a graph run's own; a filter takes the reference's
    lat_alpha = float(config.estimator_options("status").latency_alpha)
    lat = {f"latency:{n}": lat_alpha for n in latency.streams(config, log)}
    if est in latency.OWN or (applies and est in DRIFT_EVIDENCE):
        checks.update(lat)
    if applies:
        # the smoother's findings about the log carry to this run (with_reference_findings;
        # for dead reckoning its degraded status also skips the check, and that skip
        # degrades, skipped_finding): its checks' false alarms count, the time-stamp tests
        # where this run does not count them already, and the EKF companion's where this run
        # carries none of its own (the UKF; the EKF's is its own run)
        carried = sum(smoother.values())
        carried += 0.0 if est in DRIFT_EVIDENCE else sum(lat.values())
        if takes_reference_companion(config, log):
            ekf = config.estimator_options("ekf")
            carried += float(ekf.drift_alpha) + float(ekf.nis_alpha) * len(scanned)
        checks["reference_status"] = carried
    in_run = sum(checks.values())
    if applies:
        share = max(a - in_run, 0.0) / 2.0
        checks["cross_check_nees"] = share
        checks["reference_variance"] = share
    elif est == "smoother" and own_test(config, log):
        # the test that makes it unfit as a yardstick for the others, at their share
        checks["variance_factor"] = max(a - in_run, 0.0) / 2.0
    return {
        "alpha_run": a,
        "checks": checks,
        "total": sum(checks.values()),
        "overspent": in_run > a,
    }


def reference_problems(ref: Reference, estimate: Trajectory, alpha: float) -> list[str]:
    """Why the smoother cannot serve as a yardstick for ``estimate``: [] when it can.

    Checked before it is used (issue 31): its variance components failed (a singular
    factorisation) or stopped at their iteration cap; its global variance factor
    ``v^T v / (m - n)`` above the ``1 - alpha`` quantile of ``chi2(m - n) / (m - n)`` (its
    residuals say its noise model is optimistic, so its covariance claims too much; below the
    band it is pessimistic and the consistency test only conservative); none at all; or its
    mean position sigma more than :data:`REFERENCE_SIGMA_RATIO` times the estimate's own.
    """
    vc = (ref.result.extra or {}).get("variance_components")
    out = []
    if not vc:
        out.append("the smoother has no variance components: its scale cannot be checked")
    elif "skipped" in vc:
        out.append(f"the smoother's variance components failed ({vc['skipped']})")
    else:
        if vc.get("converged") is False:
            out.append(
                f"the smoother's variance components did not converge in "
                f"{vc.get('iterations')} passes"
            )
        excess = variance_factor_excess(vc, alpha)
        if excess:
            out.append(
                f"the smoother's {excess}: its noise model is optimistic, its covariance "
                "claims too much"
            )
    sm = ref.result.trajectory
    if sm.covariances is not None and estimate.covariances is not None and len(estimate):
        ts = sm.covariances[:, 0, 0] + sm.covariances[:, 1, 1]
        te = estimate.covariances[:, 0, 0] + estimate.covariances[:, 1, 1]
        ts, te = ts[np.isfinite(ts)], te[np.isfinite(te)]
        if ts.size and te.size and te.mean() > 0:
            q = math.sqrt(float(ts.mean()) / float(te.mean()))
            if not q <= REFERENCE_SIGMA_RATIO:
                out.append(
                    f"the smoother's position sigma is {q:.3g}x the estimate's own (more "
                    f"than {REFERENCE_SIGMA_RATIO:g}x: it has every reading the estimate had)"
                )
    return out


def variance_factor_excess(vc: dict, alpha: float) -> str | None:
    """``"variance factor ... above its chi-square band (...)"`` when the global variance
    factor of ``vc`` (``extra["variance_components"]``: ``v^T v / (m - n)`` of the noise
    models at the optimum, Koch's global test) is above the ``1 - alpha`` quantile of
    ``chi2(m - n) / (m - n)`` and above ``1 + RUN_TOLERANCE`` (a whole-run test:
    :func:`odofuse.status.streaming.run_bound`); None when it is inside, or not available."""
    from odofuse import chi2
    from odofuse.status.streaming import RUN_TOLERANCE, run_bound

    f, r = vc.get("variance_factor"), vc.get("redundancy")
    if f is None or not r or r <= 0:
        return None
    hi = run_bound(chi2.ppf(1.0 - alpha, r) / r) if alpha > 0 else math.inf
    if math.isfinite(f) and f <= hi:
        return None
    return (
        f"variance factor {f:.3g} is above its chi-square band ({hi:.3g} at {r} degrees of "
        f"freedom, false alarm {alpha:.2g}; never below 1 + {RUN_TOLERANCE:g})"
    )


def own_test(config, log) -> bool:
    """Whether the batch smoother run as the estimate tests its own variance factor: where it
    is the others' second opinion (:func:`scope_reason`, the check not switched off)."""
    off = config.estimator_options("cross_check").smoother == "off"
    return config.estimator == "smoother" and not off and scope_reason(config, log) is None


def variance_factor_findings(
    smoother: EstimateResult, alpha: float, seen_by_reference: bool = False
) -> list[Finding]:
    """The ``variance_factor`` finding (degrading) of a batch smoother's run: its residuals
    say that the config's noise model is optimistic for this log, so a covariance computed
    with it claims too much, the smoother's and any other estimator's of the same log and
    config (``seen_by_reference``: the finding of a filter that the smoother checks, as the
    time-stamp test's; for the others the skipped check degrades, :func:`skipped_finding`).
    The same test (:func:`variance_factor_excess`) makes the smoother unable to judge the
    others (:func:`reference_problems`); without this finding a smoother or a filter pulled
    by a fault their other checks do not see (a gyro bias step, docs/trust.md) said ``ok``
    at a position NEES of 100."""
    vc = (smoother.extra or {}).get("variance_components") or {}
    excess = variance_factor_excess(vc, alpha)
    if not excess:
        return []
    by = SEEN_BY_REFERENCE if seen_by_reference else ""
    return [
        Finding(
            "variance_factor",
            f"{by}the residuals' {excess}: the noise model is optimistic for this log, a "
            "covariance computed with it claims more than the readings support",
            figure=float(vc["variance_factor"]),
        )
    ]


def skipped_finding(estimator: str, reason: str, failed: bool) -> Finding:
    """The ``cross_check_skipped`` finding: the second opinion did not judge the run.

    It degrades when the reference *failed* (``failed``: the smoother raised, is itself
    degraded, or could not serve as a yardstick, :func:`reference_problems`) and the
    estimator has no other evidence of a drift its covariance does not cover (not in
    :data:`DRIFT_EVIDENCE`): then nothing vouches for the covariance, and a skipped check must
    not read as ``ok`` (issue 31). A check that did not run for a reason of the log's shape
    (no absolute sensor: nothing could judge a drift; a log above ``max_odometry_steps``) is
    a note: on a log that matches the config the run must not say ``degraded`` for it.
    """
    alone = estimator not in DRIFT_EVIDENCE
    if alone:
        tail = f"; {estimator}'s own checks cannot see a drift its covariance does not cover"
        tail += ", so nothing vouches for its covariance" if failed else ""
    else:
        tail = "; the status rests on the run's own checks"
    return Finding(
        "cross_check_skipped",
        f"the batch smoother could not judge: {reason}{tail}",
        degrades=alone and failed,
    )


#: Skip reasons that mean the check does not apply (the user's choice, or another problem):
#: no finding. Any other skip of an estimator in :data:`CHECKED` is a ``cross_check_skipped``.
NOT_APPLICABLE = (
    "off (",
    "the estimate is the batch smoother",
    "estimator '",
    "a SLAM run",
    "the log holds loop closures",
)


def cross_check(config, log, result: EstimateResult, reference=None):
    """``result`` with the cross-check's findings added, the ``cross_check`` block and the
    advice.

    Parameters
    ----------
    config, log
        The run's config and log (after :func:`odofuse.log_defaults.apply_log_defaults`).
    result : EstimateResult
        The run's estimate.
    reference : Reference or callable, optional
        The smoother run to compare with, or a function returning it (called only when the
        check applies: ``odofuse run`` without a config shares one smoother run between its
        estimators); None: :func:`reference_of` ``(config, log)``.

    Returns
    -------
    result : EstimateResult
        With the findings of :func:`compare` appended to ``findings``, or a
        ``cross_check_skipped`` finding (:func:`skipped_finding`) when the check should have
        judged and could not: the log has no absolute sensor or is too long (``auto``), holds
        loop closures, the smoother raised, is itself degraded, or fails
        :func:`reference_problems`.
    block : dict
        ``metrics.json``'s ``cross_check``: the figures, ``smoother_status`` (and
        ``smoother_config`` when the reference ran with another config than the run's), or
        ``skipped: <reason>``.
    advice : list of str
        :func:`compare`'s advice (never a finding).
    """
    budget = alpha_budget(config, log)
    reason = skip_reason(config, log)
    if "variance_factor" in budget["checks"]:  # the smoother as the estimate (own_test)
        found = variance_factor_findings(result, budget["checks"]["variance_factor"])
        result = dataclasses.replace(result, findings=(*result.findings, *found))
    companion = companion_applies(config, log)  # an EKF's drift check (COMPANION)
    if companion and config.estimator == "smoother":
        # the run is the reference's own estimate when one is given (rundir.estimate)
        own = None if reference is None else reference() if callable(reference) else reference
        result = _with_companion(config, log, result, own)
    if reason is not None:
        return _skipped(result, reason, {"skipped": reason}, failed=False)
    try:  # a smoother that cannot run this log must not fail the run it only checks
        if reference is None:
            ref = reference_of(config, log)
        else:
            ref = reference() if callable(reference) else reference
    except Exception as exc:
        why = f"the batch smoother failed: {one_line(exc)}"
        if companion:
            result = _with_companion(config, log, result)
        return _skipped(result, why, {"skipped": why})
    if companion:
        result = _with_companion(config, log, result, ref)
    # no wall-clock time here: metrics.json is the same for the same inputs (odofuse batch
    # equals odofuse run to the last digit); the config only when it is not the run's own
    about = {"smoother_status": ref.status}
    if ref.config != config.source:
        about["smoother_config"] = ref.config
    result = with_reference_findings(config, log, result, ref)
    if (ref.status if ref.yardstick_status is None else ref.yardstick_status) != "ok":
        why = f"the batch smoother's own status is {ref.status}"
        return _skipped(result, why, {"skipped": why, **about})
    share = budget["checks"]["reference_variance"]
    if result.estimator in DRIFT_EVIDENCE:  # the others' skip below degrades for the same cause
        found = variance_factor_findings(ref.result, share, seen_by_reference=True)
        result = dataclasses.replace(result, findings=(*result.findings, *found))
    problems = reference_problems(ref, result.trajectory, share)
    if problems:
        why = "unable to judge: " + "; ".join(problems)
        return _skipped(result, why, {"skipped": why, **about})
    fused = result.estimator not in UNAIDED
    vc = (ref.result.extra or {}).get("variance_components") or {}
    scale = vc.get("position_variance_scale")
    es = (ref.result.extra or {}).get("_error_samples")
    samples = getattr(es, "xy", None)
    alpha = budget["checks"]["cross_check_nees"]
    block, found, advice = compare(
        result.trajectory, ref.result.trajectory, fused, scale, samples, alpha
    )
    if "skipped" in block:
        return _skipped(result, block["skipped"], {**block, **about})
    if found:
        result = dataclasses.replace(result, findings=(*result.findings, *found))
    return result, {**block, **about}, advice


def companion_findings(config, log) -> tuple[Finding, ...]:
    """The ``calibration_drift`` findings of an EKF of ``log`` with ``config`` (its estimator
    replaced; the EKF's options are the config's ``options.ekf``) and its ``innovation_mean``
    findings, each saying that the EKF saw it (:func:`odofuse.status.drift.seen_by_ekf`); ()
    when the EKF finds nothing.

    The EKF's calibration path is the model's martingale only while the EKF itself holds the
    track: an EKF degraded by a check of its own failure (recoveries, rejection runs, ...; not
    its NIS tests, which test the log against the config's model as the scan does:
    :data:`odofuse.status.drift.MODEL`) cannot judge the drift (its failure moves the
    calibration), and neither can an EKF that does not run; both leave a note that does not
    degrade (the run's other checks stand)."""
    from odofuse.estimators import run_estimator
    from odofuse.status.drift import cannot_judge, seen_by_ekf

    try:
        result = run_estimator("ekf", log, dataclasses.replace(config, estimator="ekf"))
    except Exception as exc:  # noqa: BLE001 - a check that cannot run is a note, never a crash
        return (cannot_judge(one_line(exc)),)
    return seen_by_ekf(assess(result))


def companion_applies(config, log) -> bool:
    """Whether the run carries the calibration drift check of an EKF of its log
    (:func:`companion_findings`): an estimator of :data:`COMPANION`, in the second opinion's
    scope (:func:`scope_reason`, not switched off), with the EKF's ``drift_alpha`` above 0."""
    return (
        config.estimator in COMPANION
        and config.estimator_options("cross_check").smoother != "off"
        and float(config.estimator_options("ekf").drift_alpha) > 0.0
        and scope_reason(config, log) is None
    )


def takes_reference_companion(config, log) -> bool:
    """Whether the run takes the EKF companion's findings that its reference carries
    (:func:`with_reference_findings`, counted in ``reference_status``): the UKF, which has
    drift and scan checks of its own, where the smoother carries a companion
    (:func:`companion_applies`). The EKF's companion is its own run, and the estimators of
    :data:`COMPANION` carry the same findings themselves (:func:`_with_companion`)."""
    smoother = dataclasses.replace(config, estimator="smoother")
    return config.estimator == "ukf" and companion_applies(smoother, log)


def _with_companion(config, log, result: EstimateResult, ref: Reference | None = None):
    """``result`` with the companion findings: the reference's (shared by the runs on one
    log) when given, else those of an EKF of ``config``."""
    drift = ref.drift if ref is not None and ref.drift is not None else None
    found = drift() if drift is not None else companion_findings(config, log)
    return dataclasses.replace(result, findings=(*result.findings, *found)) if found else result


def with_reference_findings(config, log, result: EstimateResult, ref: Reference):
    """``result`` with the reference's degrading findings about the log, each said to be
    seen by the batch smoother of this log: its residual windows, rejection counts, time-stamp
    tests, slip runs, outages, ... (every check but those about its own solution,
    :data:`SOLUTION_CHECKS`) and, where it carries one (:func:`companion_applies`), an EKF's
    drift and innovation-mean findings. They test the log's readings against the config's
    model, which every estimator of the same log shares: offline, a fault the second opinion
    detected is a detected fault (shared spec section 3), whatever the run's own checks saw
    (docs/trust.md, "What the second opinion detected carries": a gyro bias step that the
    filters' checks missed at a position NEES of 86 while the smoother's ``slip_run`` fired).
    A finding of the same check and stream that the run made itself is not repeated; the
    companion's findings go to the UKF alone (:func:`takes_reference_companion`)."""
    if result is ref.result:
        return result
    by = SEEN_BY_REFERENCE
    theirs = [
        dataclasses.replace(f, message=by + f.message)
        for f in ref.result.findings
        if f.degrades and f.check not in SOLUTION_CHECKS
    ]
    if ref.drift is not None and takes_reference_companion(config, log):
        theirs += [f for f in ref.drift() if f.degrades]  # they say that an EKF saw them
    fused = set(result.used) | set(result.rejected)
    found, seen = [], {(f.check, f.sensor) for f in result.findings if f.degrades}
    for f in theirs:
        key = (f.check, f.sensor)
        if key in seen or (f.sensor is not None and f.sensor not in fused):
            continue
        seen.add(key)
        found.append(f)
    return dataclasses.replace(result, findings=(*result.findings, *found)) if found else result


def _skipped(result: EstimateResult, reason: str, block: dict, failed: bool = True):
    if result.estimator not in CHECKED or reason.startswith(NOT_APPLICABLE):
        return result, block, []
    found = skipped_finding(result.estimator, reason, failed)
    return dataclasses.replace(result, findings=(*result.findings, found)), block, []
