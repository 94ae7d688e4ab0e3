"""Numerical differentiation helpers for tests.

Never used by library code paths (docs/architecture.md); analytic Jacobians in the
library are checked against :func:`numerical_jacobian` in the test-suite.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

__all__ = ["numerical_jacobian"]


def _wrap(a: np.ndarray) -> np.ndarray:
    """Wrap angles to ``[-pi, pi)`` (local copy so this module needs only numpy)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def numerical_jacobian(
    f: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    eps: float = 1e-6,
    wrap_rows: Iterable[int] | None = None,
) -> np.ndarray:
    """Central-difference Jacobian of ``f`` at ``x``.

    Parameters
    ----------
    f : callable
        Function mapping an ``(n,)`` float array to an ``(m,)`` array (a scalar output
        is treated as ``m = 1``).
    x : array_like, shape (n,)
        Point of linearisation (not modified).
    eps : float, optional
        Step of the central difference, in the units of ``x``; default ``1e-6``.
    wrap_rows : iterable of int, optional
        Indices of output rows that are angles: their difference
        ``f(x + h) - f(x - h)`` is wrapped to ``[-pi, pi)`` before dividing by ``2 eps``,
        so a jump across ``+-pi`` does not produce a spurious ``2 pi / (2 eps)``.

    Returns
    -------
    ndarray, shape (m, n)
        ``J[i, j] ~= d f_i / d x_j`` with truncation error ``O(eps**2)``.

    Raises
    ------
    ValueError
        If ``x`` is not one-dimensional, ``eps`` is not positive, or a row index in
        ``wrap_rows`` is out of range.
    """
    x = np.array(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"numerical_jacobian: x must have shape (n,), got {x.shape}")
    if not eps > 0.0:
        raise ValueError(f"numerical_jacobian: eps must be positive, got {eps}")
    m = np.atleast_1d(np.asarray(f(x.copy()), dtype=float)).reshape(-1).size
    rows = [] if wrap_rows is None else [int(r) for r in wrap_rows]
    for r in rows:
        if not -m <= r < m:
            raise ValueError(f"numerical_jacobian: wrap_rows index {r} out of range for m={m}")
    J = np.empty((m, x.size))
    for j in range(x.size):
        xp = x.copy()
        xm = x.copy()
        xp[j] += eps
        xm[j] -= eps
        d = np.atleast_1d(np.asarray(f(xp), dtype=float)).reshape(-1) - np.atleast_1d(
            np.asarray(f(xm), dtype=float)
        ).reshape(-1)
        if rows:
            d[rows] = _wrap(d[rows])
        J[:, j] = d / (2.0 * eps)
    return J
