"""Loading user plug-ins named ``"package.module:Name"`` (estimators, measurement models).

A base-level helper so that every layer (models, estimators) can load a user object without
importing a layer above it.
"""

from __future__ import annotations

import importlib

from odofuse.errors import ConfigError


def load_object(spec: str, what: str = "object"):
    """Import ``"package.module:Name"`` and return the named object."""
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise ConfigError(f"{what} '{spec}' is not of the form 'package.module:Name'")
    try:
        return getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"cannot load {what} '{spec}': {exc}") from None
