"""Marginal covariances of a solved graph that never throw (issue 12, item 4).

Owns :func:`batch_marginals`: ``gtsam.Marginals`` of the batch solution; when GTSAM refuses the
system (``IndeterminantLinearSystemException``: a gauge-free or numerically singular
information matrix), the marginals of the same graph regularised by a weak prior on every
variable (:data:`REGULARISER_SIGMA`), and when that fails too, no covariances. Each fallback
is reported as a :class:`~odofuse.health.Finding` instead of a traceback.
"""

from __future__ import annotations

from odofuse.health import Finding

#: Sigma (m, rad, or the calibration state's unit) of the weak prior put on every variable when
#: the system is indeterminate: a direction no factor determines then gets a variance of about
#: ``REGULARISER_SIGMA**2``, far above any real one, while determined directions change by a
#: relative ``sigma_real**2 / REGULARISER_SIGMA**2``.
REGULARISER_SIGMA = 1e3


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text[:160] + ("..." if len(text) > 160 else "")


def _regularised(graph, values):
    import gtsam

    g = graph.clone()
    for key in values.keys():
        kind = chr(gtsam.Symbol(key).chr())
        if kind == "x":
            nm = gtsam.noiseModel.Isotropic.Sigma(3, REGULARISER_SIGMA)
            g.add(gtsam.PriorFactorPose2(key, values.atPose2(key), nm))
        elif kind in "lb":
            nm = gtsam.noiseModel.Isotropic.Sigma(2, REGULARISER_SIGMA)
            g.add(gtsam.PriorFactorPoint2(key, values.atPoint2(key), nm))
        else:
            vec = values.atVector(key)
            nm = gtsam.noiseModel.Isotropic.Sigma(len(vec), REGULARISER_SIGMA)
            g.add(gtsam.PriorFactorVector(key, vec, nm))
    return g


def batch_marginals(graph, values):
    """Marginals of ``graph`` at ``values``, regularised or skipped rather than thrown.

    Returns
    -------
    marginal_covariance : callable or None
        ``key -> (d, d) covariance`` in GTSAM's tangent convention (``None``: skipped).
    findings : list of Finding
        Empty when ``gtsam.Marginals`` succeeded as is.
    """
    import gtsam

    try:
        return gtsam.Marginals(graph, values).marginalCovariance, []
    except RuntimeError as exc:
        first = _one_line(exc)
    try:
        m = gtsam.Marginals(_regularised(graph, values), values)
    except RuntimeError as exc:
        return None, [
            Finding(
                "covariance",
                f"marginal covariances skipped: GTSAM found the system indeterminate ({first}); "
                f"regularised: {_one_line(exc)}",
            )
        ]
    note = Finding(
        "covariance",
        f"GTSAM found the system indeterminate ({first}); covariances are of the graph with a "
        f"{REGULARISER_SIGMA:g} (m, rad) prior on every variable: a direction no factor "
        "determines shows a variance near its square",
        degrades=False,
    )
    return m.marginalCovariance, [note]
