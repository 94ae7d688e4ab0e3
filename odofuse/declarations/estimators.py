"""The estimator registry of the declarations: :data:`ESTIMATOR_OPTIONS` and the lookup of an
estimator's options class (a built-in's, or a user estimator's own ``Options``)."""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping
from dataclasses import dataclass

from odofuse.declarations.filters import (
    DeadReckoningOptions,
    EkfOptions,
    ParticleOptions,
    UkfOptions,
)
from odofuse.declarations.graph import GraphOptions
from odofuse.declarations.run import RUN_OPTIONS
from odofuse.errors import ConfigError
from odofuse.options import coerce


@dataclass(frozen=True)
class UncheckedOptions:
    """The block of a user estimator without ``Options``: its keys are the estimator's to
    validate; ``values`` is the block, read-only."""

    values: Mapping = dataclasses.field(default_factory=lambda: types.MappingProxyType({}))

    @classmethod
    def from_block(cls, mapping, key_prefix: str, source: str) -> UncheckedOptions:
        if mapping is None:
            mapping = {}
        if not isinstance(mapping, Mapping):
            raise ConfigError(
                f"must be a mapping, got {type(mapping).__name__} {mapping!r}", source, key_prefix
            )
        return cls(types.MappingProxyType(dict(mapping)))


#: Estimator name -> options class (``options.<name>``).
ESTIMATOR_OPTIONS: dict[str, type] = {
    "dead_reckoning": DeadReckoningOptions,
    "ekf": EkfOptions,
    "ukf": UkfOptions,
    "particle": ParticleOptions,
    "smoother": GraphOptions,
    "isam2": GraphOptions,
    "fixed_lag": GraphOptions,
}


def estimator_options_class(name: str, source: str = "<config>") -> type:
    """The options class of estimator ``name``: registered, or a user function's ``Options``."""
    if name in ESTIMATOR_OPTIONS:
        return ESTIMATOR_OPTIONS[name]
    if name in RUN_OPTIONS:
        return RUN_OPTIONS[name]
    if ":" not in name:
        raise ConfigError(
            f"unknown estimator '{name}'; known: {', '.join(ESTIMATOR_OPTIONS)}",
            source,
            f"options.{name}",
        )
    from odofuse.plugins import load_function

    try:
        run = load_function(name, "estimator")
    except ConfigError as exc:
        raise ConfigError(str(exc), source, f"options.{name}") from None
    return getattr(run, "Options", UncheckedOptions)


def estimator_options(name: str, block=None, source: str = "<config>"):
    """``options.<name>`` validated into its class (``block`` may already be an instance)."""
    return coerce(estimator_options_class(name, source), block, f"options.{name}", source)
