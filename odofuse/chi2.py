"""Chi-square quantiles without ``scipy.stats`` (whose import costs a second or more).

``scipy.stats.chi2.ppf(p, k)`` is ``2 * scipy.special.gammaincinv(k / 2, p)`` (that is how
scipy computes it), so this module returns the same numbers from the much lighter
``scipy.special``. Owns only that; the gates and monitors call it.
"""

from __future__ import annotations

import numpy as np


def ppf(p, dof):
    """Quantile of the chi-square law with ``dof`` degrees of freedom at probability ``p``.

    Parameters
    ----------
    p : float or array_like
        Probability in [0, 1].
    dof : int or array_like
        Degrees of freedom (> 0).

    Returns
    -------
    float or ndarray
        Same shape as the broadcast of ``p`` and ``dof``; equal to ``scipy.stats.chi2.ppf``.
    """
    from scipy.special import gammaincinv

    out = 2.0 * gammaincinv(0.5 * np.asarray(dof, dtype=float), np.asarray(p, dtype=float))
    return out[()] if np.ndim(out) == 0 else out
