"""Marginal covariances of a solved graph that never throw.

Owns :func:`marginal_covariances`: ``gtsam.Marginals`` of the solution; when GTSAM refuses the
system (``IndeterminantLinearSystemException``: a gauge-free or numerically singular
information matrix), the same marginals by QR (:func:`qr_marginals`), then those of the same
graph linearised with a weak prior on every variable, and when that fails too, no
covariances. Each fallback that changes the covariances is reported as a
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

    ``gtsam.Marginals`` (multifrontal Cholesky) is tried first. If the system is
    indeterminate, by QR (:func:`qr_marginals`: the same covariances, no finding), which
    works on the Jacobian instead of the information matrix, whose condition number is the
    square of the Jacobian's: Plaza2's range-only SLAM with odometry calibration (smallest
    eigenvalue of the information 8e-5 against 4e8: the lanes' poses sliding along
    themselves) had its covariances omitted, and has them this way. If QR also finds the
    system singular (a direction no factor determines), again on the graph
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
    exact = qr_marginals(graph, values, keys)
    if exact is not None:
        return exact, []
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


def qr_marginals(graph, values, keys) -> dict | None:
    """``key -> marginal covariance`` of the nonlinear ``graph`` linearised at ``values``,
    eliminated by QR: a fresh ``gtsam.ISAM2`` (QR factorisation) updated once with the whole
    graph there, as :func:`optimum_marginals` does (``gtsam.Marginals`` offers Cholesky only
    in the Python wrapper). None when QR too finds the system indeterminate (GTSAM raises for
    a direction no factor determines) or a covariance is not finite and positive definite."""
    import gtsam

    params = gtsam.ISAM2Params()
    params.setFactorization("QR")
    try:
        isam = gtsam.ISAM2(params)
        isam.update(graph, values)
        cov = {k: isam.marginalCovariance(k) for k in keys}
    except RuntimeError:
        return None
    for c in cov.values():
        if not np.all(np.isfinite(c)) or np.linalg.eigvalsh(0.5 * (c + c.T))[0] <= 0.0:
            return None
    return cov


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
