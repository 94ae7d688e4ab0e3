"""How a run judges itself: every check behind ``status``, in one package by role (issue 25).

``status: ok`` promises that the reported covariance covers the error and that no sensor or
model fault was detected; ``degraded`` means a detected inconsistency or fault, named in
``warnings``. On a log that matches its config a run says ``degraded`` with probability at
most ``options.status.alpha_run`` (5 %), split over the checks that can fire on such a log
(docs/trust.md, "The promise"; :func:`odofuse.status.cross_check.alpha_budget`).

The modules, by role (lowest import layer first; ``tests/test_layering.py``):

* :mod:`~odofuse.status.findings`: the :class:`Finding` type, ``assess`` and ``status_of``
  (the status of a list of findings), the covariance, pose and rejection checks of any
  trajectory;
* :mod:`~odofuse.status.streaming`: the streaming innovation checks of one stream (NIS
  windows with persistence and hysteresis, the run's NIS, the innovation-mean scan, rejection
  runs and counts, outages) of the filters, the fixed-lag smoother, iSAM2 and the live
  ``Localizer.health()``, with their alpha-spending bounds;
* :mod:`~odofuse.status.monitors`: the filters' monitor that feeds them, recovery after
  divergence, and a Localizer's findings;
* :mod:`~odofuse.status.mde`: the minimal detectable error of every gate, window and scan,
  and the ``inert`` note;
* :mod:`~odofuse.status.slip`: robust odometry (the wheels against the gyro) and its ``slip``
  and ``slip_run`` findings;
* :mod:`~odofuse.status.pose_checks`: the checks of a filter's track (covariance conditioning
  and growth, collapse, gyro-bias learning, dead reckoning's gyro-vs-wheels test);
* :mod:`~odofuse.status.latency`: the time-stamp test on a smoother's residuals;
* :mod:`~odofuse.status.graph_checks`: the factor graph's residual checks (scale, outliers,
  residual windows, calibration, jumps, slip, solver);
* :mod:`~odofuse.status.cross_check`: the offline second opinion (the batch smoother of the
  same log) and the run's false-alarm budget;
* :mod:`~odofuse.status.geometry`: advice, never a finding: the robot geometry (wheel radius,
  radius ratio, track) that a run's odometry calibration fits, where it is significant.

:data:`CHECKS` lists every check a run can report, where it is raised, its statistic, its
false-alarm probability on a matching log and the tests that exercise it;
``tests/test_status_catalog.py`` keeps it complete (every ``Finding`` the code makes is here,
every counted check is in the budget).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Check:
    """One check behind ``status``.

    Attributes
    ----------
    name : str
        ``Finding.check`` (the ``[name]`` of a warning line).
    raised_in : tuple of str
        Modules (paths under ``odofuse/``) that make the finding.
    estimators : str
        Who runs it.
    statistic : str
        What it tests.
    false_alarm : str
        Its false-alarm probability per run on a log that matches the config.
    budget : tuple of str
        Its keys in ``metrics.json`` ``alpha.checks`` (a per-stream key without its stream);
        empty when it is not counted (it cannot fire on a matching log, or below 1e-5).
    tests : tuple of str
        Test files that exercise it.
    """

    name: str
    raised_in: tuple[str, ...]
    estimators: str
    statistic: str
    false_alarm: str
    budget: tuple[str, ...]
    tests: tuple[str, ...]


_FILTERS = "EKF, UKF, particle filter, Localizer (live)"
_NOT = "not counted: cannot fire on a matching log"

#: Every check a run can report (docs/trust.md section 1 is the same list with the figures).
CHECKS: tuple[Check, ...] = (
    # ------------------------------------------------------------- consistency, counted
    Check(
        "nis",
        ("status/streaming.py",),
        f"{_FILTERS}; fixed-lag and iSAM2 (their predicted innovations, with slam: true the "
        "re-sightings of landmarks already mapped; estimators/graph/innovations.py)",
        "mean NIS over nis_window accepted readings against its chi-square band, alpha spent "
        "over the run's windows, health_persist windows in a row (below the band: a note)",
        "nis_alpha per fused stream (1e-3)",
        ("nis",),
        ("tests/test_live_health.py", "tests/test_graph_innovations.py"),
    ),
    Check(
        "nis_run",
        ("status/streaming.py",),
        "the same as nis",
        "mean NIS of all the stream's accepted readings against the chi-square bound of "
        "their count (from two windows' worth), never below 1 + RUN_TOLERANCE (1.1) times "
        "its expected value (streaming.run_bound)",
        "nis_alpha per fused stream (1e-3)",
        ("nis_run",),
        ("tests/test_live_health.py", "tests/test_graph_innovations.py"),
    ),
    Check(
        "innovation_mean",
        ("status/streaming.py",),
        "the same as nis, for every fused stream (a gyro's in blocks of >= 1 s)",
        "|sum|^2 / nis_window of the last nis_window whitened innovations (L^-1 y, S = L L^T; "
        "a gyro's summed over blocks of >= MEAN_BLOCK_S, over sqrt(n)), chi-square(dim), every "
        "nis_window / 4 readings or blocks and on the last window at the end of the run "
        "(streaming.end_scan), alpha spent over the evaluations (Bonferroni)",
        "nis_alpha per fused stream (1e-3); the estimators that carry an EKF's drift check "
        "(COMPANION) carry its scans too (options.ekf.nis_alpha each)",
        ("innovation_mean", "companion_innovation_mean"),
        ("tests/test_innovation_mean.py",),
    ),
    Check(
        "rejection_count",
        ("status/streaming.py", "status/graph_checks.py"),
        "the same as nis (every gated stream); the batch smoother on its residuals at the "
        "optimum (every gated sensor stream, not a gyro)",
        "rejections (the smoother: residuals beyond the gate) among the last nis_window "
        "readings against the binomial bound of the gate's own rejection probability "
        "(1 - gate) plus the gross_fraction a real sensor has (3 %), every nis_window / 4 "
        "readings and on the last window at the end of the run (streaming.end_count), alpha "
        "spent over the evaluations (Bonferroni)",
        "nis_alpha per fused gated stream (1e-3)",
        ("rejection_count",),
        ("tests/test_innovation_mean.py", "tests/test_graph_innovations.py"),
    ),
    Check(
        "calibration_drift",
        ("status/drift.py",),
        "EKF, UKF, Localizer (live), with calibration states; offline, every other estimator "
        "in the second opinion's scope carries an EKF's of the same log and config "
        "(COMPANION), and so does a live particle Localizer (Localizer.companion)",
        "a calibration estimate's change between snapshots drift_grid s apart (lags 1, 2, 4, "
        "... snapshots) over the variance its updates and random walk explain, Bonferroni "
        "over the comparisons and states, alpha spent over the run's snapshots",
        "drift_alpha (1e-3)",
        ("calibration_drift",),
        ("tests/test_drift.py",),
    ),
    Check(
        "gyro_wheels",
        ("status/pose_checks.py",),
        "dead reckoning with a gyro",
        "gyro vs wheel heading change over heading_window against the error models' "
        "chi-square bound, Bonferroni over the windows",
        "heading_alpha (1e-3)",
        ("gyro_wheels",),
        ("tests/test_status_catalog.py",),
    ),
    Check(
        "residual_windows",
        ("status/graph_checks.py",),
        "batch smoother (odometry and each gyro); carried to the runs it judges",
        "summed whitened chi-square of 20 consecutive factors at the optimum against its "
        "chi-square quantile, Bonferroni over the windows",
        "WINDOW_ALPHA per stream (1e-3)",
        ("residual_windows",),
        ("tests/test_graph_trust.py",),
    ),
    Check(
        "latency",
        ("status/latency.py",),
        "smoother, iSAM2, fixed-lag (own residuals); the others take the smoother's",
        "the residuals' score on the predicted measurement's rate (the smoother: in its own "
        "whitened system, exact variance; iSAM2, fixed-lag: a bound): a reading stamped late "
        "or early",
        "options.status.latency_alpha per fused absolute stream (1e-3, two-sided)",
        ("latency",),
        ("tests/test_latency.py",),
    ),
    Check(
        "cross_check_nees",
        ("status/cross_check.py",),
        "dead reckoning, filters, iSAM2, fixed-lag (offline, when the smoother can judge)",
        "departure NEES from the batch smoother of the same log against a bound that holds "
        "whatever the correlation along the trajectory",
        "half of what the in-run checks leave of alpha_run",
        ("cross_check_nees",),
        ("tests/test_cross_check.py",),
    ),
    Check(
        "cross_check_skipped",
        ("status/cross_check.py",),
        "the estimators of cross_check_nees",
        "the second opinion could not judge (reason given); degrades only estimators without "
        "drift evidence of their own (dead reckoning) when the reference failed. Whether it "
        "judges or not, what the reference detected in the log carries to the run under its "
        "own check name ('seen by the batch smoother of this log', with_reference_findings)",
        "the carried findings: the smoother's window and rejection-count shares, its latency "
        "shares where the run has none, the EKF companion's for the UKF (reference_status); "
        "the other half (reference_variance)",
        ("reference_status", "reference_variance"),
        ("tests/test_cross_check_skipped.py",),
    ),
    Check(
        "variance_factor",
        ("status/cross_check.py",),
        "batch smoother (own residuals); filters, fixed-lag and iSAM2 take the smoother's",
        "global variance factor v^T v / (m - n) above its chi-square band (Koch's test) and "
        "above 1 + RUN_TOLERANCE (1.1; streaming.run_bound)",
        "the reference_variance share (the smoother: half of what is left)",
        ("variance_factor", "reference_variance"),
        ("tests/test_cross_check_skipped.py", "tests/test_cross_check_variance.py"),
    ),
    # --------------------------------------------- faults that a matching log cannot show
    Check(
        "rejection_run",
        ("status/streaming.py",),
        f"{_FILTERS}; fixed-lag, iSAM2",
        "reject_run consecutive readings beyond the sensor's gate",
        f"{_NOT} ((1 - gate)^5 = 1e-15 per reading)",
        (),
        ("tests/test_live_health.py",),
    ),
    Check(
        "recovery",
        ("status/monitors.py",),
        _FILTERS,
        "a rejection run re-opened the filter (pose covariance inflated to admit the reading)",
        f"{_NOT} (follows a rejection run)",
        (),
        ("tests/test_status_catalog.py",),
    ),
    Check(
        "outage",
        ("status/streaming.py",),
        "every estimator with an absolute sensor",
        "a sensor silent for more than half of the run",
        f"{_NOT} (a fact of the log)",
        (),
        ("tests/test_cross_check_skipped.py", "tests/test_graph_trust.py"),
    ),
    Check(
        "inert",
        ("status/mde.py",),
        _FILTERS,
        "a gate that can never fire, or fires on nearly everything (minimal detectable error)",
        f"{_NOT} (a property of the config)",
        (),
        ("tests/test_live_health.py",),
    ),
    Check(
        "slip",
        ("status/slip.py", "status/graph_checks.py"),
        "filters and graph back ends with a gyro",
        "gyro and wheels disagreed on some steps; their wheel noise was widened (a note)",
        "never degrades",
        (),
        ("tests/test_graph_trust.py",),
    ),
    Check(
        "slip_run",
        ("status/slip.py",),
        "filters and graph back ends with a gyro",
        "gyro and wheels disagree on every step for more than 1 s",
        f"{_NOT} (50 tests at 1e-3 in a row)",
        (),
        ("tests/test_graph_health.py",),
    ),
    Check(
        "calibration",
        ("status/monitors.py", "status/graph_checks.py"),
        "every estimator that estimates a calibration state",
        "a calibration 5 prior sigmas from its prior, or its sigma collapsed",
        f"{_NOT} (6e-7)",
        (),
        ("tests/test_graph_health.py",),
    ),
    Check(
        "covariance",
        ("status/findings.py", "status/pose_checks.py", "status/graph_checks.py"),
        "every estimator",
        "a covariance not positive definite or ill-conditioned (correlation condition above "
        "max_condition)",
        f"{_NOT} (numerical)",
        (),
        ("tests/test_health.py",),
    ),
    Check(
        "covariance_growth",
        ("status/pose_checks.py",),
        "filters",
        "the position sigma grew growth_factor-fold over its running minimum",
        f"{_NOT} (the sensors stopped constraining the position)",
        (),
        ("tests/test_status_catalog.py",),
    ),
    Check(
        "pose",
        ("status/findings.py",),
        "every estimator",
        "a pose that is not finite",
        f"{_NOT} (numerical)",
        (),
        ("tests/test_ekf.py",),
    ),
    Check(
        "rejected",
        ("status/findings.py",),
        "every estimator",
        "a stream mostly (more than half) rejected by its gate",
        f"{_NOT} (a 0.999 gate)",
        (),
        ("tests/test_health.py",),
    ),
    Check(
        "collapse",
        ("status/pose_checks.py",),
        "filters (the particle cloud above all)",
        "the heading variance fell below 0.1 of its running maximum with no absolute "
        "reading accepted in between",
        f"{_NOT} (1e-5 for 10 particles)",
        (),
        ("tests/test_particle_collapse.py",),
    ),
    Check(
        "learning",
        ("status/pose_checks.py",),
        "filters with a gyro bias state",
        "the heading rests on a gyro bias still being learnt (a note)",
        "never degrades",
        (),
        ("tests/test_trust.py",),
    ),
    Check(
        "residuals",
        ("status/graph_checks.py",),
        "graph back ends",
        "median whitened residual of a stream above 4x its expected value",
        f"{_NOT} (a median)",
        (),
        ("tests/test_graph_health.py",),
    ),
    Check(
        "outliers",
        ("status/graph_checks.py",),
        "graph back ends",
        "more than 10 % of a stream's factors beyond their 0.999 chi-square bound",
        f"{_NOT} (0.1 % expected)",
        (),
        ("tests/test_graph.py",),
    ),
    Check(
        "jumps",
        ("status/graph_checks.py",),
        "graph back ends",
        "a keyframe moved more than the odometry allows (chi-square 1 - 1e-6 and 1 m)",
        f"{_NOT} (1e-6)",
        (),
        ("tests/test_graph_health.py",),
    ),
    Check(
        "solver",
        ("status/graph_checks.py", "estimators/graph/isam2.py"),
        "graph back ends",
        "the optimiser did not converge, or an incremental update raised",
        f"{_NOT} (numerical)",
        (),
        ("tests/test_graph.py",),
    ),
    # ------------------------------------------------------------ input and setup findings
    Check(
        "missing",
        ("io/loader.py",),
        "every run",
        "an optional configured sensor has no data in the log",
        f"{_NOT} (a fact of the log)",
        (),
        ("tests/test_newcomer.py",),
    ),
    Check(
        "unused",
        ("estimators/__init__.py",),
        "every run",
        "a configured stream that the estimator does not read",
        f"{_NOT} (a fact of the config)",
        (),
        ("tests/test_newcomer.py",),
    ),
    Check(
        "loop_closures",
        ("estimators/__init__.py",),
        "estimators that cannot use a log's loop closures",
        "the log holds loop closures that this estimator ignores",
        f"{_NOT} (a fact of the log)",
        (),
        ("tests/test_graph_datasets.py",),
    ),
    Check(
        "dropped",
        ("estimators/inputs.py",),
        "filters",
        "most of a stream dropped unused (older than late_window, or after the last "
        "odometry): its clock is not on the odometry's time base",
        f"{_NOT} (a fact of the log)",
        (),
        ("tests/test_plausibility.py",),
    ),
    Check(
        "counter_gap",
        ("io/plausibility.py",),
        "every run reading encoder counts",
        "an encoder counter jumped (wrap or lost samples)",
        f"{_NOT} (a fact of the log)",
        (),
        ("tests/test_plausibility.py",),
    ),
    Check(
        "gps_far",
        ("io/plausibility.py",),
        "every run with a GPS",
        "the fixes far from the start pose (absolute coordinates without a datum)",
        f"{_NOT} (a fact of the log)",
        (),
        ("tests/test_plausibility.py",),
    ),
    Check(
        "gps_jumps",
        ("io/plausibility.py",),
        "every run with a GPS",
        "GPS fixes that jump further than the robot can move",
        f"{_NOT} (a fact of the log)",
        (),
        ("tests/test_plausibility.py",),
    ),
    Check(
        "scoring",
        ("evaluation.py",),
        "runs scored against ground truth",
        "the score covers less than half of the estimate's span",
        f"{_NOT} (a fact of the log)",
        (),
        ("tests/test_trust.py",),
    ),
    Check(
        "timeout",
        ("live/component.py",),
        "odofuse live",
        "a stream silent for longer than its timeout",
        f"{_NOT} (a fact of the wire)",
        (),
        ("tests/test_live.py",),
    ),
    Check(
        "waiting",
        ("live/component.py",),
        "odofuse live",
        "no odometry received yet",
        f"{_NOT} (start-up)",
        (),
        ("tests/test_live.py",),
    ),
)
