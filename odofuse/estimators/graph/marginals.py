"""Marginal covariances of a solved graph that never throw.

Owns :func:`marginal_covariances`: ``gtsam.Marginals`` of the solution; when GTSAM refuses the
system (``IndeterminantLinearSystemException``: a gauge-free or numerically singular
information matrix), the marginals of the same graph linearised with a weak prior on every
variable, and when that fails too, no covariances. Each fallback is reported as a
:class:`~odofuse.status.findings.Finding` (:func:`~odofuse.status.graph_checks.marginals_finding`)
instead of a traceback. The batch smoother uses it; iSAM2 takes the marginals at its polished
optimum from :func:`optimum_marginals` (the fixed-lag smoother reads its own Bayes tree's).
"""

from __future__ import annotations

import numpy as np

from odofuse.status.graph_checks import marginals_finding


def marginal_covariances(graph, values, keys, dims, lin=None) -> tuple[dict, list]:
    """Marginal covariances (GTSAM tangent) of ``keys``, and the findings of a failure.

    ``dims`` maps every variable's key to its tangent dimension; ``lin`` (optional) is
    ``graph`` linearised at ``values`` when the caller has it (the batch smoother shares one
    with the variance components: on Plaza1 a linearisation of its Python factors is 0.24 s).

    ``gtsam.Marginals`` is tried first; if the system is indeterminate, again on the graph
    linearised at ``values`` with a prior of sigma 100 (m, rad, units of the variable) on
    every variable: a covariance the data determine to sigma ``s`` changes by the fraction
    ``~(s / 100)^2`` (1e-8 for decimetres), the directions they do not determine get the
    prior's size instead of an exception (a weaker prior trips GTSAM's own conditioning check).
    If that fails too, no covariances are returned.
    """
    import gtsam

    try:
        marginals = gtsam.Marginals(graph if lin is None else lin, values)
        return {k: marginals.marginalCovariance(k) for k in keys}, []
    except RuntimeError as exc:
        detail = str(exc).strip().splitlines()[0][:160]
    lin = graph.linearize(values)  # a fresh one: the prior factors are added to it
    sig = 1e2
    for key, dim in dims.items():
        lin.add(
            gtsam.JacobianFactor(
                key, np.eye(dim) / sig, np.zeros(dim), gtsam.noiseModel.Unit.Create(dim)
            )
        )
    try:
        marginals = gtsam.Marginals(lin, values)
        return {k: marginals.marginalCovariance(k) for k in keys}, [marginals_finding(detail, True)]
    except RuntimeError:
        return {}, [marginals_finding(detail, False)]


def optimum_marginals(graph, values, params):
    """``key -> marginal covariance`` (GTSAM tangent) of ``graph`` linearised at ``values``
    (an iSAM2 run's polished optimum): GTSAM's batch ``Marginals`` (multifrontal Cholesky,
    as :func:`marginal_covariances`), or, when that elimination is indeterminate, a fresh
    ``gtsam.ISAM2(params)`` updated once with the whole graph there (QR unless ``params``
    say otherwise: the exact covariances, where :func:`marginal_covariances` adds a weak
    prior). The fresh iSAM2 was the only way until session 32: the same covariances to 3e-8
    relative on Plaza1's ``.mat``, but 8.5 s of its 33 s ``odofuse run`` against 0.4 s
    (docs/speed.md)."""
    import gtsam

    try:
        return gtsam.Marginals(graph, values).marginalCovariance
    except RuntimeError:
        fresh = gtsam.ISAM2(params)
        fresh.update(graph, values)
        return fresh.marginalCovariance
