"""User plug-ins named ``"package.module:Name"``: the opt-in gate and the shape checks.

A base-level module so that every layer (drives, models, estimators, config) can load a user
object without importing a layer above it. A config is data (shared spec section 5): a plug-in
is code, so a config may name one only when its top-level ``plugins:`` list names the module
(:func:`check_allowed`, called by :mod:`odofuse.config` before anything is imported). Whatever
path loads a plug-in, the object is checked to have the plug-in's shape (a class with the
drive's or measurement model's methods, a ``run(log, config)`` function for an estimator)
before anything is called or constructed: ``os:system`` or ``builtins:print`` is refused, never
run.
"""

from __future__ import annotations

import importlib
import inspect
import re
import sys

from odofuse.errors import ConfigError

_MODULE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")

#: The methods (callables on the class) each plug-in kind must have.
DRIVE_METHODS = ("twist", "J_twist_u", "travel")
SENSOR_METHODS = ("z", "h", "H", "R", "residual")


def split_spec(spec, what: str = "plug-in") -> tuple[str, str]:
    """``"package.module:Name"`` -> ``("package.module", "Name")``, without importing."""
    module_name, sep, attr = str(spec).partition(":")
    if not sep or not _MODULE.fullmatch(module_name) or not attr.isidentifier():
        raise ConfigError(f"{what} '{_short(spec)}' is not of the form 'package.module:Name'")
    return module_name, attr


def _short(value, limit: int = 80) -> str:
    text = str(value)
    return text if len(text) <= limit else text[:limit] + "..."


def is_stdlib(module_name: str) -> bool:
    """Whether ``module_name`` belongs to Python's standard library (never a plug-in)."""
    top = module_name.partition(".")[0]
    return top in sys.stdlib_module_names or top in sys.builtin_module_names


def check_module_name(name, what: str = "plug-in module") -> str:
    """Validate one entry of a config's ``plugins:`` list (a dotted name, not the stdlib)."""
    if not isinstance(name, str) or not _MODULE.fullmatch(name):
        raise ConfigError(f"{what} must be a dotted module name, got {_short(repr(name))}")
    if is_stdlib(name):
        raise ConfigError(f"{what} '{name}' is part of the Python standard library, not a plug-in")
    return name


def check_allowed(spec, allowed, what: str = "plug-in") -> None:
    """Refuse ``spec`` unless its module is (in) one of the ``allowed`` modules; never imports."""
    module_name, _ = split_spec(spec, what)
    if is_stdlib(module_name):
        raise ConfigError(
            f"{what} '{_short(spec)}' names the standard library module '{module_name}'; "
            "a plug-in must be a class or function of your own"
        )
    if not any(module_name == m or module_name.startswith(m + ".") for m in allowed):
        raise ConfigError(
            f"{what} '{_short(spec)}' is code: list its module '{module_name}' under the "
            "top-level 'plugins:' key to allow it"
        )


def load_object(spec: str, what: str = "object"):
    """Import ``"package.module:Name"`` and return the named object (no shape check)."""
    module_name, attr = split_spec(spec, what)
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"cannot load {what} '{spec}': {exc}") from None
    try:
        return getattr(module, attr)
    except AttributeError:
        raise ConfigError(
            f"cannot load {what} '{spec}': module '{module_name}' has no '{attr}'"
        ) from None


def load_class(spec: str, what: str, methods: tuple[str, ...]) -> type:
    """Load ``spec`` and check it is a class with the callable ``methods``; never instantiates."""
    obj = load_object(spec, what)
    if not inspect.isclass(obj):
        raise ConfigError(f"{what} '{spec}' is a {type(obj).__name__}, not a class")
    missing = [m for m in methods if not callable(inspect.getattr_static(obj, m, None))]
    if missing:
        raise ConfigError(
            f"{what} '{spec}' lacks the method(s) {', '.join(missing)} of its interface"
        )
    return obj


def load_function(spec: str, what: str = "estimator", nargs: int = 2):
    """Load ``spec`` and check it is a Python function taking ``nargs`` positional arguments."""
    obj = load_object(spec, what)
    if not inspect.isfunction(obj):
        raise ConfigError(f"{what} '{spec}' is a {type(obj).__name__}, not a Python function")
    try:
        inspect.signature(obj).bind(*range(nargs))
    except TypeError:
        raise ConfigError(
            f"{what} '{spec}' must take {nargs} positional arguments (log, config)"
        ) from None
    return obj
