"""Shared pieces of the option declarations: value constants and the parse hooks.

Owns the integrator and robust-loss names, the robust losses' default thresholds, the start-pose
and late-measurement defaults, the parse hooks :func:`robust_loss` and :func:`gate_probability`
(forms an annotation cannot say) and the bound shorthands the declaration modules share.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from odofuse.errors import ConfigError

INTEGRATORS = ("euler", "rk2", "exact", "euler_end")
ROBUST_KINDS = ("none", "huber", "cauchy", "tukey")
#: Default thresholds ``k`` (in sigma) of the robust losses: 95 % efficiency on Gaussian noise.
ROBUST_DEFAULT_K = {"huber": 1.345, "cauchy": 2.3849, "tukey": 4.6851}
DEFAULT_INITIAL_SIGMA = (0.1, 0.1, 0.05)
DEFAULT_LATE_WINDOW = 0.5  # s


# ------------------------------------------------------------------------------ parse hooks
def robust_loss(value, key: str, source: str) -> tuple[str, float]:
    """A robust loss ``huber | cauchy | tukey | none`` or ``{type, k}`` as ``(kind, k)``."""
    if isinstance(value, str) or value is None:
        kind, k = ("none" if value is None else value), None
    elif isinstance(value, Mapping):
        unknown = set(value) - {"type", "k"}
        if unknown:
            raise ConfigError(
                f"unknown key(s) {', '.join(sorted(unknown))}; use type and k",
                file=source,
                key=f"{key}.{sorted(unknown)[0]}",
            )
        kind, k = value.get("type", "huber"), value.get("k")
    else:
        raise ConfigError(
            f"expected a loss name or {{type, k}}, got {value!r}", file=source, key=key
        )
    if kind not in ROBUST_KINDS:
        raise ConfigError(
            f"unknown robust loss {kind!r}; use one of {', '.join(ROBUST_KINDS)}",
            file=source,
            key=key,
        )
    if kind == "none":
        return ("none", 0.0)
    if k is None:
        return (kind, ROBUST_DEFAULT_K[kind])
    if isinstance(k, bool) or not isinstance(k, int | float) or not math.isfinite(k):
        raise ConfigError(f"expected a number, got {k!r}", file=source, key=f"{key}.k")
    if not k > 0:
        raise ConfigError("robust threshold k must be positive", file=source, key=f"{key}.k")
    return (kind, float(k))


def gate_probability(value, key: str, source: str) -> float | None:
    """A chi-square acceptance probability in (0, 1); ``null`` or ``false`` disables the gate."""
    if value is None or value is False:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 < value < 1.0:
        raise ConfigError(
            f"a chi-square acceptance probability must be in (0, 1), got {value!r}", source, key
        )
    return float(value)


_POSITIVE = {"minimum": 0, "exclusive_minimum": True}
_NONNEG = {"minimum": 0}
#: A probability or fraction strictly inside (0, 1).
_OPEN_UNIT = {"minimum": 0, "maximum": 1, "exclusive_minimum": True, "exclusive_maximum": True}
