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
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from odofuse.errors import one_line
from odofuse.health import Finding, assess, status_of
from odofuse.trajectory import EstimateResult, Trajectory, pose_blocks

#: RMSE ratio to the batch smoother within which an estimator that fuses absolute sensors holds.
HOLD_RMSE_RATIO = 2.0
#: Position NEES below which an estimate holds (and the departure-NEES bound of the check).
HOLD_NEES = 10.0
#: Posterior probability of failing the judge above which ``cross_check`` fires: the
#: conventional significance level (for a calibrated posterior it bounds the fraction of
#: ``ok`` runs that fail the judge).
ALPHA = 0.05
#: Estimate times per block of the posterior's pass (temporaries ``K * block * 2`` floats).
SAMPLE_BLOCK = 2048
#: Estimators that fuse no absolute sensor: judged on their covariance alone (their drift from
#: a smoother that has the absolute sensors is expected).
UNAIDED = frozenset({"dead_reckoning"})
#: The estimators the check applies to: their estimate is of the problem the smoother solves.
CHECKED = ("dead_reckoning", "ekf", "ukf", "particle", "fixed_lag", "isam2")
#: Measurement-model kinds that observe the pose absolutely (landmarks at known positions).
ABSOLUTE_KINDS = frozenset({"gps", "compass", "range", "bearing", "range_bearing"})
#: Odometry streams, one of which a log's estimate integrates.
ODOMETRY_STREAMS = ("odometry", "wheels", "cmd_vel")


@dataclass(frozen=True)
class Reference:
    """The batch smoother's run that a cross-check compares with.

    Attributes
    ----------
    result : EstimateResult
        The smoother's estimate (poses and world-frame covariances).
    status : str
        Its own status (:func:`odofuse.health.status_of` of its findings).
    runtime_s : float
        Wall-clock time of the smoother run (s).
    config : str
        The config it ran with (its ``source``).
    """

    result: EstimateResult
    status: str
    runtime_s: float
    config: str


def reference_of(config, log) -> Reference:
    """Run the batch smoother on ``log`` with ``config`` (estimator replaced), with its
    error samples (:data:`odofuse.estimators.graph.variance.ERROR_SAMPLES`)."""
    from odofuse.estimators import run_estimator
    from odofuse.estimators.graph.variance import ERROR_SAMPLES

    cfg = dataclasses.replace(config, estimator="smoother")
    t0 = time.perf_counter()
    result = run_estimator("smoother", log, cfg, error_samples=ERROR_SAMPLES)
    return Reference(result, status_of(assess(result)), time.perf_counter() - t0, cfg.source)


def odometry_steps(log) -> int:
    """Rows of the log's odometry stream (the largest of :data:`ODOMETRY_STREAMS`)."""
    streams = getattr(log, "streams", {}) or {}
    return max((len(streams[n]) for n in ODOMETRY_STREAMS if n in streams), default=0)


def _absolute_streams(config, log) -> list[str]:
    from odofuse.declarations import stream_kind

    streams = getattr(log, "streams", {}) or {}
    out = []
    for name, opts in (config.sensors or {}).items():
        kind = getattr(opts, "model", None) or stream_kind(str(name))
        if kind in ABSOLUTE_KINDS and name in streams and len(streams[name]):
            out.append(str(name))
    return out


def _slam(config, name: str) -> bool:
    opts = config.options.get(name) if config.options else None
    return bool(getattr(opts, "slam", False))


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
    opts = config.estimator_options("cross_check")
    est = config.estimator
    if opts.smoother == "off":
        return "off (options.cross_check.smoother)"
    if est == "smoother":
        return "the estimate is the batch smoother"
    if est not in CHECKED:
        return f"estimator '{est}' is not one the batch smoother is a second opinion for"
    if _slam(config, est) or _slam(config, "smoother"):
        return "a SLAM run (landmarks unknown): not the smoother's problem"
    streams = getattr(log, "streams", {}) or {}
    if "loop_closures" in streams and len(streams["loop_closures"]):
        return "the log holds loop closures (a pose-graph problem)"
    if opts.smoother == "on":
        return None
    if not _absolute_streams(config, log):
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
    from odofuse.evaluation import associate, bracket

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


def compare(
    estimate: Trajectory,
    smoother: Trajectory,
    fused: bool,
    variance_scale: float | None = None,
    samples: np.ndarray | None = None,
) -> tuple[dict, list[Finding]]:
    """The ``cross_check`` figures of ``estimate`` against ``smoother`` and their findings.

    Parameters
    ----------
    estimate : Trajectory
        The run's estimate, world-frame covariances ``(N, 3, 3)`` (or None: no NEES figure).
    smoother : Trajectory
        The batch smoother of the same log, interpolated to the estimate's times
        (:func:`odofuse.evaluation.ate`'s association: inside its span, not across its gaps).
    fused : bool
        The estimate fuses absolute sensors: the predicted-ratio finding applies.
    variance_scale : float, optional
        The smoother's own scale of its position covariance (``position_variance_scale`` of
        :func:`odofuse.estimators.graph.variance.variance_components`: the error covariance its
        residuals' variance components imply over the one its noise model implies); ``s^2``
        is the mean trace times it. None: 1 (not available).
    samples : ndarray, shape (K, N, 2), optional
        Joint samples of the smoother's position errors at its poses (m, world frame;
        :class:`odofuse.estimators.graph.variance.ErrorSamples`): the ``cross_check`` finding
        fires when :func:`posterior_fail` exceeds :data:`ALPHA`. None: the fallback rule
        (predicted ratio above :data:`HOLD_RMSE_RATIO`).

    Returns
    -------
    block : dict
        ``poses_compared``, ``departure_rms_m`` (rms(d), m), ``smoother_sigma_m`` (``s``, m),
        ``smoother_sigma_model_m`` (``s`` before the variance scale, m),
        ``smoother_variance_factor`` (the scale, None when not available),
        ``predicted_ratio`` (``sqrt(1 + rms(d)^2 / s^2)``), ``p_fail`` (None without
        samples or when not ``fused``), ``samples`` (K, 0 without), ``rule``
        (``posterior p_fail > ALPHA`` or the fallback and why), ``alpha``, ``departure_nees`` (mean
        ``d^T P_f^-1 d`` over the positive-definite ``P_f``, expected <= 2), the bounds; or
        ``skipped`` when nothing overlaps.
    findings : list of Finding
        ``cross_check`` (fused, ``p_fail`` above :data:`ALPHA`; without samples the predicted
        ratio above :data:`HOLD_RMSE_RATIO`) and
        ``cross_check_nees`` (departure NEES above :data:`HOLD_NEES`).
    """
    from odofuse.evaluation import ate, covered, nees

    idx = np.flatnonzero(covered(estimate.t, smoother.t)) if len(estimate) and len(smoother) else []
    if len(idx) == 0:
        return {"skipped": "the smoother's poses do not overlap the estimate's"}, []
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
    dn = nees(estimate, smoother, (0, 1)) if estimate.covariances is not None else math.nan
    span = (float(estimate.t[idx[0]]), float(estimate.t[idx[-1]]))
    usable = samples is not None and samples.ndim == 3 and samples.shape[1] == len(smoother)
    # unaided estimates are judged on their covariance alone: no p_fail (its drift is expected)
    p_fail = posterior_fail(estimate, smoother, samples) if usable and fused else None
    if usable:
        rule = f"posterior p_fail > {ALPHA:g}"
    else:
        why = "none" if samples is None else "not one per smoother pose"
        rule = f"predicted ratio > {HOLD_RMSE_RATIO:g} (fallback: smoother error samples {why})"
    block = {
        "poses_compared": int(len(idx)),
        "departure_rms_m": rms,
        "smoother_sigma_m": math.sqrt(s2) if s2 > 0 else None,
        "smoother_sigma_model_m": math.sqrt(s2_model) if s2_model > 0 else None,
        "smoother_variance_factor": variance_scale,
        "predicted_ratio": ratio,
        "p_fail": p_fail,
        "samples": int(samples.shape[0]) if usable and fused else 0,
        "alpha": ALPHA if fused else None,
        "rule": rule if fused else None,
        "departure_nees": None if math.isnan(dn) else dn,
        "ratio_bound": HOLD_RMSE_RATIO if fused else None,
        "nees_bound": HOLD_NEES,
    }
    found, text = [], None
    if fused and p_fail is not None and p_fail > ALPHA:
        text, figure = (
            f"{rms:.3g} m rms from the batch smoother of the same log: posterior "
            f"probability {p_fail:.2f} (> {ALPHA:g}) of more than {HOLD_RMSE_RATIO:g}x its "
            f"error (predicted ratio {_fmt(ratio)}x, smoother sigma {_fmt(s2**0.5)} m)",
            p_fail,
        )
    elif fused and p_fail is None and ratio is not None and ratio > HOLD_RMSE_RATIO:
        text, figure = (
            f"{rms:.3g} m rms from the batch smoother of the same log, whose own sigma is "
            f"{math.sqrt(s2):.3g} m: likely more than {HOLD_RMSE_RATIO:g}x its error "
            f"(predicted {ratio:.2f}x; no error samples: fallback rule)",
            ratio,
        )
    if text is not None:
        found.append(Finding("cross_check", text, t_start=span[0], t_end=span[1], figure=figure))
    if not math.isnan(dn) and dn > HOLD_NEES:
        found.append(
            Finding(
                "cross_check_nees",
                f"mean d^T P^-1 d = {dn:.3g} against the batch smoother of the same log "
                f"(consistent: at most 2; bound {HOLD_NEES:g}): overconfident against the "
                "smoother",
                t_start=span[0],
                t_end=span[1],
                figure=dn,
            )
        )
    return block, found


def cross_check(config, log, result: EstimateResult, reference=None):
    """``result`` with the cross-check's findings added, and the ``cross_check`` block.

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
        With the findings of :func:`compare` appended to ``findings``.
    block : dict
        ``metrics.json``'s ``cross_check``: the figures and ``smoother_status`` (and
        ``smoother_config`` when the reference ran with another config than the run's), or
        ``skipped: <reason>`` (also when the smoother raised: the run it only checks goes on).
    """
    reason = skip_reason(config, log)
    if reason is not None:
        return result, {"skipped": reason}
    try:  # a smoother that cannot run this log must not fail the run it only checks
        if reference is None:
            ref = reference_of(config, log)
        else:
            ref = reference() if callable(reference) else reference
    except Exception as exc:
        return result, {"skipped": f"the batch smoother failed: {one_line(exc)}"}
    # no wall-clock time here: metrics.json is the same for the same inputs (odofuse batch
    # equals odofuse run to the last digit); the config only when it is not the run's own
    about = {"smoother_status": ref.status}
    if ref.config != config.source:
        about["smoother_config"] = ref.config
    if ref.status != "ok":
        return result, {"skipped": f"the batch smoother's own status is {ref.status}", **about}
    fused = result.estimator not in UNAIDED
    vc = (ref.result.extra or {}).get("variance_components") or {}
    scale = vc.get("position_variance_scale")
    es = (ref.result.extra or {}).get("_error_samples")
    samples = getattr(es, "xy", None)
    block, found = compare(result.trajectory, ref.result.trajectory, fused, scale, samples)
    if found:
        result = dataclasses.replace(result, findings=(*result.findings, *found))
    return result, {**block, **about}
