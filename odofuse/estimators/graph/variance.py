"""The batch smoother's variance components: what its residuals say about its noise model.

Owns :func:`variance_components` (Förstner's iterated variance component estimation per
stream at the optimum, and the error covariance of the solution it implies), the joint
samples of the smoother's position errors under that covariance (:class:`ErrorSamples`, the
exact parametric bootstrap of the linearised smoother), the grouping of a graph's factors by
stream (:func:`factor_groups`) and the whitened sparse system of a linearised graph it works
on. :func:`odofuse.estimators.graph.solvers.run_smoother` records the components in
``extra["variance_components"]`` and the samples in ``extra["_error_samples"]`` (in memory
only: ``extra`` keys starting with ``_`` are not written); :mod:`odofuse.status.cross_check` scales
its yardstick with the first and asks the second whether the estimate holds (docs/trust.md
sections 6.2, 6.3).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

#: Redundancy (degrees of freedom) below which a variance group's factor is not estimated:
#: its relative standard deviation ``sqrt(2 / r)`` would exceed 0.32.
MIN_REDUNDANCY = 20.0
#: State dimensions above which only the global variance factor is estimated (the per-stream
#: estimation's sparse solves grow with rows times states).
MAX_VCE_DIMS = 6000
#: Bounds of a group's variance component (the stream's sigma off by 10x either way, chosen a
#: priori). Förstner's iteration has a degenerate fixed point at 0: a group whose residuals
#: the estimate absorbs (a gyro whose increments the headings follow) gets a smaller factor,
#: hence a larger weight, hence smaller residuals, pass after pass (issue 31: 1e-13 at the
#: 20-pass cap). A group that reaches a bound keeps it and is reported ``at_bound``.
VC_BOUNDS = (1e-2, 1e2)
#: Largest change of any component in a pass at convergence, in units of its own standard
#: deviation ``sqrt(2 / r_g)`` (Koch 1999, 3.6): 2 % of it, i.e. 0.2 % of a component
#: estimated from 200 degrees of freedom, 0.6 % of one from 22. A relative 0.1 % (the rule
#: before) never ended on a log whose gyro and wheel heading increments the estimate cannot
#: tell apart: their two components traded 0.35 % a pass for 20 passes (6 %, against their
#: own 30 % standard deviation) and the smoother could not judge any run on that log.
VC_TOLERANCE = 0.02
#: Largest relative change in a pass of the position variance scale (what the cross-check
#: uses) at convergence, when the components still trade: a gyro's and the wheels' heading
#: components that the log cannot separate moved 1 % a pass for 70 passes while the position
#: scale moved 0.02 % a pass (0.538 -> 0.549).
SCALE_TOLERANCE = 1e-3
#: The variance group of priors and pseudo-observations (never re-scaled).
PRIOR_GROUP = "prior"
#: Joint samples of the smoother's position errors drawn for the cross-check (docs/trust.md
#: section 6.3): a p_fail of 0.05 is resolved to a binomial standard deviation of 0.015.
ERROR_SAMPLES = 200
#: Seed of those samples: the same inputs give the same samples (``odofuse batch`` equals
#: ``odofuse run`` to the last digit).
ERROR_SAMPLES_SEED = 20261202


@dataclass(frozen=True, eq=False)
class ErrorSamples:
    """Joint samples of the batch smoother's position errors at its keyframes.

    Drawn from the smoother's linearised posterior under its variance components: the
    sandwich covariance ``N_0^-1 (sum_g c_g N_g) N_0^-1`` of :func:`variance_components`
    (``sigma0^2 N_0^-1`` on the global path). The truth is the smoother's pose minus the
    error.

    Attributes
    ----------
    xy : ndarray, shape (K, N, 2)
        Position errors (m, world frame) of the N keyframes, K samples.
    seed : int
        Seed of the numpy ``default_rng`` that drew them.
    method : str
        ``per-stream`` or ``global`` (the variance components used).
    """

    xy: np.ndarray
    seed: int
    method: str


def factor_groups(fac, graph) -> list[str]:
    """The variance group of each factor of ``graph``: its stream (a sensor, a gyro, the
    odometry) or ``"prior"`` (priors, bias-walk steps, landmark pins: pseudo-observations
    whose scale the config sets, not a sensor's). ``graph.at(j)`` returns the Python object
    the factor was added as while that object lives (pybind11 keeps one wrapper per C++
    object), so identity matches them; a factor not matched falls in ``prior`` (not
    re-scaled)."""
    label = {id(f): meas.stream for meas, f in fac.created}
    label.update({id(f): stream for stream, _n, f in fac.gyro_created})
    label.update({id(f): fac.p.odometry_stream for _i, f in fac.odometry_created})
    return [label.get(id(graph.at(j)), PRIOR_GROUP) for j in range(graph.size())]


def _whitened_system(graph, values, lin=None):
    """Whitened Jacobian ``A`` (m, n; sparse CSR), residual ``b`` (m,) and each row's factor
    index, of ``graph`` linearised at ``values`` (a robust factor with its IRLS weight, as
    the solver and the marginals see it), and the column offset and dimension of each key.

    From GTSAM's own sparse triplets of the linearised graph (``sparseJacobian_``: 1-based
    rows and columns, the keys in sorted order, ``b`` as the last column, zeros left out),
    with the rows owned by the factors in order (Plaza1's 8,991 factors: one call instead of
    a Python loop over every factor and key block, 0.53 -> 0.29 s). ``lin``: ``graph``
    linearised at ``values`` when the caller has it."""
    from scipy import sparse

    if lin is None:
        lin = graph.linearize(values)
    zero = values.zeroVectors()
    cols, n = {}, 0
    for key in values.keys():
        d = int(np.asarray(zero.at(key)).size)
        cols[int(key)] = (n, d)
        n += d
    # the linear graph's own column numbering (its keys, sorted) -> ours (every value's key)
    present = lin.keys()  # a KeySet (sorted; not iterable from Python)
    lin_keys = [k for k in cols if present.count(k)]
    remap = np.concatenate(
        [np.arange(cols[k][0], cols[k][0] + cols[k][1]) for k in lin_keys] + [np.array([n])]
    )
    rows = [_rows(lin.at(j)) for j in range(lin.size())]
    owner = np.repeat(np.arange(lin.size()), rows)
    m = int(owner.size)
    i, j, v = lin.sparseJacobian_()
    i, j = i.astype(np.int64) - 1, remap[j.astype(np.int64) - 1]
    rhs = j == n
    b = np.zeros(m)
    b[i[rhs]] = v[rhs]
    a = ~rhs
    A = sparse.csr_matrix((v[a], (i[a], j[a])), shape=(m, n))
    return A, b, owner, cols


class WhitenedSystem:
    """A linearised graph's whitened system (:func:`_whitened_system`: ``A``, ``b``,
    ``owner``, ``cols``) with the sparse factorisation of its normal matrix ``N_0 = A^T A``
    made at the first use (:attr:`lu0`), so that the variance components and the time-stamp
    test's score (:mod:`odofuse.estimators.graph.time_offset`) share one."""

    def __init__(self, graph, values, lin=None):
        self.A, self.b, self.owner, self.cols = _whitened_system(graph, values, lin)

    @functools.cached_property
    def lu0(self):
        return _factor((self.A.T @ self.A).tocsc())


def _rows(f) -> int:
    """Rows of a linear factor in ``sparseJacobian_`` (a Hessian factor: its Jacobian's)."""
    import gtsam

    if f is None:
        return 0
    if isinstance(f, gtsam.JacobianFactor):
        return int(f.rows())
    return int(np.asarray(f.jacobian()[1]).size)


#: The gate beyond which a robust factor's reading is left out of the variance factor.
ROBUST_GATE = 0.999


def _model_factor(graph, values, b, owner, n: int):
    """``(sigma0^2, redundancy)``: the global variance factor of the noise models at the
    optimum, ``sum e^T e / (m' - n)``, for the chi-square test of :mod:`odofuse.status.cross_check`.

    A robust factor enters with its base model's whitened error ``e``, not with the IRLS
    weight it has in ``b`` (the normal equations'): ``sum w(e) e^T e`` has no chi-square law
    (Tukey's weights, below 1 for every residual, make it about 0.55 of the Gaussian sum on
    consistent 2-D readings at the 0.999 gate, so an optimistic sigma no longer shows). A
    robust factor beyond the 0.999 chi-square gate of its dimension (what the filters' gate
    rejects, and where the default Tukey loss gives no weight) is left out with its
    dimensions (``m'``): a gross reading that a robust loss already discounts would otherwise
    make the reference look optimistic (a bag's two 25 m GPS fixes under Huber: 12 against
    the band's 1.13); truncating the law at 0.999 moves the factor by about 0.1 %.
    Returns ``(None, m' - n)`` when ``m' <= n``.
    """
    import gtsam

    from odofuse.chi2 import ppf

    size = graph.size()
    sq = np.bincount(owner, weights=b * b, minlength=size)
    dims = np.bincount(owner, minlength=size)
    total, kept = float(b @ b), int(dims.sum())  # a graph without a robust loss: b^T b
    for j in np.flatnonzero(dims):
        f = graph.at(int(j))
        model = f.noiseModel() if hasattr(f, "noiseModel") else None
        if not isinstance(model, gtsam.noiseModel.Robust):
            continue
        e = np.atleast_1d(np.asarray(model.noise().whiten(f.unwhitenedError(values)), float))
        dist = float(np.linalg.norm(e))
        total -= float(sq[j])
        if dist * dist <= ppf(ROBUST_GATE, e.size):
            total += dist * dist
        else:
            kept -= int(dims[j])
    red = kept - n
    return (total / red if red > 0 else None), red


def _factor(N):
    """Sparse LU of the symmetric positive-definite ``N`` with a symmetric fill-reducing
    ordering and diagonal pivots (a Cholesky in effect: no pivoting that destroys sparsity)."""
    from scipy.sparse.linalg import splu

    return splu(
        N, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )


def _hat_traces(A, N, rows, scale, lu, chunk) -> dict:
    """Per group ``tr(N^-1 A_g^T A_g / c_g)`` (the hat matrix's diagonal summed over the
    group's rows; the largest group by difference: the traces sum to ``n``)."""
    largest = max(rows, key=lambda g: rows[g].size)
    out = {}
    for g, idx in rows.items():
        if g == largest:
            continue
        t = 0.0
        for k in range(0, idx.size, chunk):
            a = A[idx[k : k + chunk]]
            t += float(np.sum(a.toarray().T * lu.solve(a.T.toarray()))) / scale[g]
        out[g] = t
    out[largest] = A.shape[1] - sum(out.values())
    return out


def _error_samples(A, lu0, row_scale, cols, values, position_keys, k, seed, method):
    """``k`` joint samples ``e = N_0^-1 A^T (sqrt(c_row) z)``, ``z ~ N(0, I)`` over the
    whitened residual rows (``c_row`` each row's variance component), of the position errors
    at ``position_keys``, rotated from the Pose2 tangent (body frame) to world positions."""
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((A.shape[0], k))
    z *= np.sqrt(row_scale)[:, None]
    e = lu0.solve(np.asarray((A.T @ z), dtype=float))
    del z
    off = np.array([cols[int(key)][0] for key in position_keys])
    theta = np.array([values.atPose2(key).theta() for key in position_keys])
    c, s = np.cos(theta), np.sin(theta)
    dx, dy = e[off].T, e[off + 1].T  # (k, N) body-frame tangent errors
    xy = np.stack((c * dx - s * dy, s * dx + c * dy), axis=-1)
    return ErrorSamples(xy, int(seed), method)


def _squarem(step, settled, c, moving, iterations: int):
    """Fixed point of ``step`` (dict -> dict of positive components) from ``c``, accelerated
    by SQUAREM's scheme S3 (Varadhan & Roland, "Simple and globally convergent methods for
    accelerating the convergence of any EM algorithm", Scand. J. Statist. 35 (2008)): two
    passes ``c1 = step(c0)``, ``c2 = step(c1)``, then a pass from their extrapolation
    (:func:`_extrapolate`) over the components ``moving()`` names. Ends when
    ``settled(before, after, passes)`` holds for a pass or after ``iterations`` passes;
    returns the components, whether they settled, and the passes."""
    passes = 0

    def advance(c0):
        nonlocal passes
        passes += 1
        c1 = step(c0)
        return c1, settled(c0, c1, passes)

    while passes < iterations:
        c1, done = advance(c)
        if done or passes >= iterations:
            return c1, done, passes
        c2, done = advance(c1)
        if done or passes >= iterations:
            return c2, done, passes
        c, done = advance(_extrapolate(c, c1, c2, sorted(moving())))
        if done:
            return c, True, passes
    return c, False, passes


def _extrapolate(c0: dict, c1: dict, c2: dict, gs) -> dict:
    """SQUAREM's S3 point from three successive components, in the logarithms of those named
    by ``gs`` (so it stays positive), clamped to :data:`VC_BOUNDS`; the others as in ``c2``:
    ``r = l1 - l0``, ``d = l2 - 2 l1 + l0``, ``alpha = -max(|r| / |d|, 1)``,
    ``l = l0 - 2 alpha r + alpha^2 d`` (``alpha = -1`` gives ``l2``, the plain iteration)."""
    lo, hi = math.log(VC_BOUNDS[0]), math.log(VC_BOUNDS[1])
    l0 = np.array([math.log(c0[g]) for g in gs])
    r = np.array([math.log(c1[g] / c0[g]) for g in gs])
    d = np.array([math.log(c2[g] / c1[g]) for g in gs]) - r
    norm_r, norm_d = float(np.linalg.norm(r)), float(np.linalg.norm(d))
    alpha = -max(norm_r / norm_d, 1.0) if norm_d > 0.0 else -1.0
    out = dict(c2)
    for g, lg in zip(gs, l0 - 2.0 * alpha * r + alpha * alpha * d, strict=True):
        out[g] = math.exp(min(max(float(lg), lo), hi))
    return out


def one_blas_thread(fn):
    """Run ``fn`` with BLAS on one thread: OpenBLAS's dot products and SuperLU's
    multi-right-hand-side solves sum in an order set by its thread count, so the last digit of
    these components moved between a process with two threads and a Dask worker with one
    (``odofuse batch`` must equal ``odofuse run`` to the last digit, docs/batch.md)."""

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapped


@one_blas_thread
def variance_components(
    graph,
    values,
    groups,
    position_keys,
    chunk: int = 256,
    iterations: int = 20,
    samples: int = 0,
    seed: int = ERROR_SAMPLES_SEED,
    lin=None,
    system: WhitenedSystem | None = None,
):
    """Variance components of a least-squares solution and the error covariance they imply.

    Förstner's iterated variance component estimation on the system linearised at the
    optimum: the noise of group ``g`` (:func:`factor_groups`) is ``c_g`` times what its
    model says; with weights ``1 / c_g`` (start: 1), the weighted solution's whitened
    residuals ``v_g`` (a robust factor with its IRLS weight, as it enters the normal
    equations) and the group's redundancy ``r_g = m_g - tr(N^-1 N_g) / c_g`` (``N = sum_g
    N_g / c_g``, ``N_g = A_g^T A_g`` the group's whitened normal matrix, ``m_g`` its residual
    dimensions, ``sum_g r_g = m - n``) give ``c_g <- v_g^T v_g / r_g``, until no ``c_g``
    moves by more than :data:`VC_TOLERANCE` of its standard deviation ``sqrt(2 / r_g)``, or
    the position variance scale below by more than :data:`SCALE_TOLERANCE` (at
    most ``iterations`` passes, ``converged`` says whether it got there; a single pass is
    biased when the groups' relative weights are off). Each
    component is bounded to :data:`VC_BOUNDS` (a group that reaches a bound keeps it,
    ``at_bound``: no factor is driven to zero). A group whose redundancy is below
    :data:`MIN_REDUNDANCY` keeps ``c_g = 1`` (too few degrees of freedom: relative standard
    deviation ``sqrt(2 / r_g)`` above 0.32), and so does the ``prior`` group. The solution
    itself (computed with the model's weights) is not changed; its error covariance under
    those components is the sandwich ``N_0^-1 (sum_g c_g N_g) N_0^-1`` (``N_0 = sum_g N_g``,
    whose inverse is the marginals' covariance). Förstner, "Ein Verfahren zur Schätzung von
    Varianz- und Kovarianzkomponenten", AVN 86 (1979); Koch, *Parameter Estimation and
    Hypothesis Testing in Linear Models* (1999), section 3.6.

    Each pass costs one sparse solve per residual row outside the largest group; above
    :data:`MAX_VCE_DIMS` state dimensions (Plaza1's 16,400: 610 s on the loaded 2 shared
    cores, against 78 s for the smoother itself) only the global factor ``sigma0^2`` is
    estimated (``method: global``, one group: the covariance scales by ``sigma0^2``, no solve).

    Parameters
    ----------
    graph : gtsam.NonlinearFactorGraph
    values : gtsam.Values
        The optimum.
    groups : list of str
        Group of each factor of ``graph``.
    position_keys : list of int
        Pose2 keys whose position covariance is scaled.
    chunk : int
        Right-hand sides per sparse solve (memory ``n * chunk`` floats).
    iterations : int
        Most passes of the estimation.
    samples : int
        Joint samples of the position errors at ``position_keys`` to draw as well (0: none,
        the dict alone is returned); they cost one factorisation of ``N_0`` on the global
        path and one solve with ``samples`` right-hand sides.
    seed : int
        Seed of those samples.
    lin : gtsam.GaussianFactorGraph, optional
        ``graph`` linearised at ``values``, when the caller has it (else linearised here).
    system : WhitenedSystem, optional
        That linearisation's whitened system, when the caller shares it (and its
        factorisation of ``N_0``) with another computation; ``lin`` is then not used.

    Returns
    -------
    dict
        ``method`` (``per-stream`` or ``global``), ``variance_factor`` (global
        ``sum v^T v / (m - n)`` at the optimum, None when ``m <= n``), ``redundancy``
        (``m - n``), ``iterations``, ``converged`` (no component moved by more than
        :data:`VC_TOLERANCE` of its standard deviation in the last pass, or the position
        variance scale by more than :data:`SCALE_TOLERANCE`; True on the global path),
        ``groups``: group ->
        ``{"variance_factor" (c_g), "redundancy" (r_g), "dims" (m_g), "estimated",
        "at_bound"}`` (per stream only), and
        ``position_variance_scale``: mean trace of the sandwich's position blocks over the
        mean trace of ``N_0^-1``'s (1 when no group was estimated).
    ErrorSamples
        Only with ``samples > 0``: the samples (:class:`ErrorSamples`); the dict is then the
        first item of a pair.
    """
    from scipy import sparse

    system = system or WhitenedSystem(graph, values, lin)
    A, b, owner, cols = system.A, system.b, system.owner, system.cols
    m, n = A.shape
    redundancy = m - n
    weighted = float(b @ b / redundancy) if redundancy > 0 else None
    sigma0, model_redundancy = _model_factor(graph, values, b, owner, n)
    if n > MAX_VCE_DIMS:  # the global factor: no solve (the covariance scales as one)
        c0 = weighted if weighted is not None and weighted > 0 else 1.0
        out = {
            "method": "global",
            "variance_factor": sigma0,
            "redundancy": int(model_redundancy),
            "converged": True,  # one closed-form factor, no iteration
            "position_variance_scale": c0,
        }
        if samples <= 0:
            return out
        lu0 = system.lu0
        rs = np.full(m, c0)
        return out, _error_samples(A, lu0, rs, cols, values, position_keys, samples, seed, "global")
    label = np.array(groups, dtype=object)[owner]
    rows = {g: np.flatnonzero(label == g) for g in sorted(set(label))}
    scale = dict.fromkeys(rows, 1.0)
    free = {g for g in rows if g != PRIOR_GROUP}
    # the sandwich's position traces: sum_g c_g ||A_g y||^2 over tr(E^T N_0^-1 E), with
    # y = N_0^-1 E independent of the components (computed once, re-weighted each pass)
    lu0 = system.lu0
    pos = np.concatenate([np.arange(cols[int(k)][0], cols[int(k)][0] + 2) for k in position_keys])
    model, per_group = 0.0, dict.fromkeys(rows, 0.0)
    for k in range(0, pos.size, chunk):
        sel = pos[k : k + chunk]
        e = np.zeros((n, sel.size))
        e[sel, np.arange(sel.size)] = 1.0
        y = lu0.solve(e)
        model += float(np.sum(y[sel, np.arange(sel.size)]))
        ay = A @ y
        for g in rows:
            per_group[g] += float(np.sum(ay[rows[g]] ** 2))

    def position_scale(c: dict) -> float:
        return sum(c[g] * per_group[g] for g in rows) / model if model > 0 else 1.0

    red, bounded = {}, set()

    def step(c: dict) -> dict:
        """One Förstner pass from components ``c``: the components its residuals give."""
        nonlocal red
        weight = np.empty(m)
        for g, idx in rows.items():
            weight[idx] = 1.0 / c[g]
        w = sparse.diags(weight)
        N = (A.T @ w @ A).tocsc()
        lu = _factor(N)
        v = b - A @ lu.solve(A.T @ (w @ b))
        trace = _hat_traces(A, N, rows, c, lu, chunk)
        red = {g: rows[g].size - trace[g] for g in rows}
        new = dict(c)
        for g in list(free):
            if red[g] < MIN_REDUNDANCY:
                free.discard(g)
                new[g] = 1.0
            elif g not in bounded:
                raw = float(v[rows[g]] @ v[rows[g]] / red[g])
                new[g] = min(max(raw, VC_BOUNDS[0]), VC_BOUNDS[1])
                if new[g] != raw:
                    bounded.add(g)  # kept at its bound from now on
        return new

    def settled(c: dict, new: dict, passes: int) -> bool:
        """No component moved by :data:`VC_TOLERANCE` of its sd, or (after the first pass)
        the position scale by :data:`SCALE_TOLERANCE`, in the pass from ``c`` to ``new``."""
        moved = max(
            (abs(new[g] / c[g] - 1.0) / math.sqrt(2.0 / max(red[g], MIN_REDUNDANCY)) for g in rows),
            default=0.0,
        )
        shift = abs(position_scale(new) / position_scale(c) - 1.0)
        return moved < VC_TOLERANCE or (passes > 1 and shift < SCALE_TOLERANCE)

    # SQUAREM (Varadhan & Roland 2008): two passes, a step along their squared extrapolation
    # in log components, and a pass from there; a log whose gyro and wheel heading increments
    # the estimate cannot tell apart moves 2 % a pass toward its fixed point, over 300 passes
    scale, converged, passes = _squarem(step, settled, scale, lambda: free - bounded, iterations)
    out_groups = {
        g: {
            "variance_factor": float(scale[g]),
            "redundancy": float(red[g]),
            "dims": int(rows[g].size),
            "estimated": g in free,
            "at_bound": g in bounded,
        }
        for g in rows
    }
    out = {
        "method": "per-stream",
        "variance_factor": sigma0,
        "redundancy": int(model_redundancy),
        "iterations": passes,
        "converged": converged,
        "groups": out_groups,
        "position_variance_scale": position_scale(scale),
    }
    if samples <= 0:
        return out
    rs = np.empty(m)
    for g, idx in rows.items():
        rs[idx] = scale[g]
    return out, _error_samples(A, lu0, rs, cols, values, position_keys, samples, seed, "per-stream")
