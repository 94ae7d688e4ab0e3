"""Robust odometry: the wheels against the gyro, one odometry step at a time.

:func:`slip_scale` widens a step's wheel noise when the gyro's heading change and the wheels'
disagree beyond a chi-square test (the gyrodometry switching rule of
``002_88fc37db58155723.txt``, with a statistical threshold: a heavy-tailed odometry model);
:func:`step_slip_scale` applies it in a Localizer's step (the compiled backends' kernels do the
same arithmetic); :func:`slip_note` and :func:`slip_run_findings` report the steps it widened
(``slip``, a note) and a run of them longer than :data:`SLIP_RUN_S` (``slip_run``, a wheel
fault; the graph back ends' keyframe intervals too).
"""

from __future__ import annotations

import numpy as np

from odofuse.status.findings import Finding
from odofuse.status.pose_checks import record_learning, record_learning_terms


def slip_scale(
    disagreement: float, var_odo: float, var_ref: float, gate: float, run: float = 0.0
) -> float:
    """Robust odometry: the factor that widens one step's wheel input noise.

    ``disagreement`` (rad) is the gyro heading change minus the wheels' over the step,
    ``var_odo`` the wheels' heading variance of the step (rad^2) and ``var_ref`` that of the
    gyro's change (rate noise and bias uncertainty). When the disagreement fails the
    chi-square test ``d^2 > gate (var_odo + var_ref)`` the wheels slipped (the gyrodometry
    switching rule of ``002_88fc37db58155723.txt``, with a statistical threshold) and the
    step's wheel noise is widened (a heavy-tailed odometry model). Else 1.

    A slip lasts: the steps of one burst err alike, so their wheel errors are correlated, and
    widening each step to its own disagreement (``d^2``) would give the burst's accumulated
    translation error only ``sqrt(n)`` of the ``n`` sigmas it has. ``run`` is the summed
    disagreement ``D`` of the consecutive slipping steps just before this one; the step gets
    the variance that makes the run's accumulated wheel variance ``(D + d)^2`` (the summed
    heading disagreement is a one-sigma event, and so is the translation error the same
    slip caused), at least ``d^2``: factor ``max(d^2, (D + d)^2 - D^2) / var_odo``.
    """
    if not var_odo > 0.0:
        return 1.0
    d2 = disagreement * disagreement
    if d2 <= gate * (var_odo + var_ref):
        return 1.0
    total = run + disagreement
    return max(d2, total * total - run * run) / var_odo


#: A run of consecutive slipping odometry steps longer than this (s) is a wheel fault, not a
#: slip (chosen a priori): a tyre that spins on a bump or a kerb slips for a fraction of a
#: second; for a second on end the wheels and the gyro disagree on every step only when a wheel
#: spins free, is dragged, or its encoder is stuck, and the widened wheel noise covers the
#: heading but not what the faulty wheel says of the distance (a stuck encoder for 10 s left
#: an EKF 3 m off at NEES 85, ``benchmarks/bench_status.py``). Each step's test has a false
#: alarm of ``1 - slip_gate`` (1e-3): 50 in a row at 50 Hz is beyond any nominal log.
SLIP_RUN_S = 1.0


def slip_note(loc) -> list:
    """A note of the odometry steps on which robust odometry widened the wheel noise, and a
    finding (degrading) when they ran on for more than :data:`SLIP_RUN_S`."""
    if not loc.slip_steps:
        return []
    out = [
        Finding(
            "slip",
            f"gyro and wheels disagreed on {loc.slip_steps} odometry step(s): the "
            "wheel noise of those steps was widened to cover it (robust odometry)",
            sensor=loc._slip_stream,
            figure=float(loc.slip_steps),
            degrades=False,
        )
    ]
    return out + slip_run_findings(loc._slip_stream, *loc._slip_longest, "odometry step")


def slip_run_findings(stream, a: float, b: float, unit: str) -> list:
    """The ``slip_run`` finding of a run of slipping ``unit``s from ``a`` to ``b`` (s) when it
    lasted more than :data:`SLIP_RUN_S` (the filters' steps, the graph's keyframe
    intervals)."""
    if not b - a > SLIP_RUN_S:
        return []
    return [
        Finding(
            "slip_run",
            f"gyro and wheels disagreed on every {unit} for {b - a:.2f} s (more than "
            f"{SLIP_RUN_S:g} s): a wheel spinning free or dragged, or a stuck encoder; the "
            "widened wheel noise covers the heading, not the distance that wheel reports",
            sensor=stream,
            t_start=a,
            t_end=b,
            figure=b - a,
        )
    ]


def step_slip_scale(loc, t0: float, t1: float, u) -> float:
    """Input-noise factor of one odometry step (robust odometry, :func:`slip_scale`).

    A backend on the compiled kernels computes it in its kernel (``slip_step``, None where
    it cannot: the offline run's arithmetic, so a live EKF or UKF equals ``odofuse run`` bit
    for bit); this is the reference it equals to 1e-9."""
    g = loc._gyro_increment(t0, t1)
    if g is None or t1 <= t0:
        return 1.0
    span = t1 - t0
    runs = loc._slip_runs
    run = runs.get(t0, 0.0)
    gate, sigma, var_b = loc._slip_params
    kernel = getattr(loc.backend, "slip_step", None)
    out = None
    if kernel is not None:
        learn = np.full(3, np.nan)
        out = kernel(u, span, g, run, loc._slip_params, loc._bias_idx, learn)
    if out is not None:
        scale, after = out
        if loc._bias_idx is not None:
            record_learning_terms(loc._bias_record, t0, *learn.tolist())
    else:
        delta, J = loc._increment(u)
        mm = loc.motion_model
        var_odo = float((J[2] ** 2) @ mm.errors.variances(mm.drive, u, span))
        bias = 0.0
        if loc._bias_idx is not None:
            bias = float(loc.backend.mean()[loc._bias_idx])
            cov = loc.backend.cov()
            var_b = float(cov[loc._bias_idx, loc._bias_idx])
            record_learning(loc._bias_record, t0, cov, loc._bias_idx)
        var_ref = (sigma**2 + var_b) * span**2
        d = g - bias * span - float(delta[2])
        scale = slip_scale(d, var_odo, var_ref, gate, run)
        after = run + d if scale > 1.0 else 0.0
    starts = loc._slip_starts
    if scale > 1.0:
        loc.slip_steps += 1
        begin = starts.get(t0, t0)
        starts[t1] = begin
        longest = loc._slip_longest
        if t1 - begin > longest[1] - longest[0]:
            loc._slip_longest = (begin, t1)
    runs[t1] = after
    if len(runs) > 4096:  # keep what a replay inside the late window can still ask for
        horizon = t1 - loc.late_window - 1.0
        for key in [k for k in runs if k < horizon]:
            del runs[key]
        for key in [k for k in starts if k < horizon]:
            del starts[key]
    return scale
