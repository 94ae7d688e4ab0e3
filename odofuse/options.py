"""Options declared once: the mechanism that turns a config block into a frozen dataclass.

An options class is a frozen dataclass whose fields are made with :func:`option` (a default, a
unit and a one-line meaning, optional bounds, choices or a ``parse`` hook). :func:`from_mapping`
validates a YAML mapping against the field annotations and returns the instance;
:func:`markdown_table` and :func:`describe` render the same fields for the docs and for
``odofuse options``. The built-in declarations and their registries live in
:mod:`odofuse.declarations`; ``python -m odofuse.declarations --write-docs`` regenerates the tables
between ``<!-- options:NAME -->`` and ``<!-- /options:NAME -->`` in ``docs/*.md``.

Supported annotations: ``bool``, ``int``, ``float``, ``str``, ``tuple[float, ...]`` (any
length) or ``tuple[float, float]`` (fixed length; element type any of these), ``dict[str, X]``,
a nested options dataclass, unions of those with ``None`` and with each other (the branch is
chosen by the YAML value's kind: ``k: 0.01`` or ``k: [0.01, 0.001]``).
An options class may define ``check(self)`` raising :class:`ConfigError` with a key relative
to the block (cross-field rules), or a classmethod ``from_block(mapping, key_prefix, source)``
that replaces :func:`from_mapping` for that class entirely.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import MISSING

from odofuse.errors import ConfigError

__all__ = ["option", "from_mapping", "coerce", "to_mapping", "describe", "markdown_table"]


def option(
    default=MISSING,
    *,
    unit: str,
    doc: str,
    minimum: float | None = None,
    maximum: float | None = None,
    exclusive_minimum: bool = False,
    exclusive_maximum: bool = False,
    choices: tuple | None = None,
    parse: Callable | None = None,
    type_name: str | None = None,
    default_factory=MISSING,
):
    """A dataclass field of an options class, with the metadata that validates and documents it.

    Parameters
    ----------
    default : object
        Value when the key is absent (omit both ``default`` and ``default_factory`` for a
        required key). Use tuples, not lists, so that the frozen instance stays immutable.
    unit : str
        SI unit of the value (``"m"``, ``"rad/s"``, ``"s"``), ``"-"`` for a pure number or flag.
    doc : str
        One-line meaning (the docs table and ``odofuse options`` print it).
    minimum, maximum : float, optional
        Bounds, checked on a number and on every element of a list or mapping of numbers.
    exclusive_minimum, exclusive_maximum : bool
        Make the bound strict (``minimum=0, exclusive_minimum=True``: positive).
    choices : tuple, optional
        The allowed values.
    parse : callable, optional
        ``parse(value, key, source) -> value`` for a form the annotation cannot say (a loss name
        or ``{type, k}``); it replaces the type check and raises :class:`ConfigError` itself.
    type_name : str, optional
        How the docs name the type (default: derived from the annotation).
    """
    meta = {
        "unit": unit,
        "doc": doc,
        "minimum": minimum,
        "maximum": maximum,
        "exclusive_minimum": exclusive_minimum,
        "exclusive_maximum": exclusive_maximum,
        "choices": tuple(choices) if choices is not None else None,
        "parse": parse,
        "type_name": type_name,
    }
    return dataclasses.field(default=default, default_factory=default_factory, metadata=meta)


def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def _fields(cls) -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(cls) if f.init]


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _fmt(x) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def _check_bounds(v: float, meta: Mapping, key: str, src: str) -> None:
    lo, hi = meta.get("minimum"), meta.get("maximum")
    lo_x, hi_x = meta.get("exclusive_minimum"), meta.get("exclusive_maximum")
    low_bad = lo is not None and (v <= lo if lo_x else v < lo)
    high_bad = hi is not None and (v >= hi if hi_x else v > hi)
    if not (low_bad or high_bad):
        return
    if lo is not None and hi is not None:
        what = f"in {'(' if lo_x else '['}{_fmt(lo)}, {_fmt(hi)}{')' if hi_x else ']'}"
    elif lo == 0:
        what = "positive" if lo_x else "not negative"
    elif lo is not None:
        what = f"{'>' if lo_x else '>='} {_fmt(lo)}"
    else:
        what = f"{'<' if hi_x else '<='} {_fmt(hi)}"
    raise ConfigError(f"must be {what}, got {v!r}", src, key)


def _kind_matches(tp, v) -> bool:
    """Whether YAML value ``v`` is of the kind that branch ``tp`` of a union reads."""
    origin = typing.get_origin(tp)
    if tp is type(None):
        return v is None
    if tp is bool:
        return isinstance(v, bool)
    if tp in (int, float):
        return _is_number(v)
    if tp is str:
        return isinstance(v, str)
    if origin in (tuple, list):
        return isinstance(v, list | tuple)
    if origin in (dict, Mapping) or dataclasses.is_dataclass(tp):
        return isinstance(v, Mapping)
    return False


def _type_label(tp) -> str:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is type(None):
        return "null"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_label(a) for a in args)
    if origin in (tuple, list):
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_label(args[0])}"
        return f"{len(args)} {_type_label(args[0]) if args else 'value'}s"
    if origin in (dict, Mapping):
        return f"mapping of {_type_label(args[1])}" if args else "mapping"
    if dataclasses.is_dataclass(tp):
        return "mapping"
    return {bool: "bool", int: "int", float: "float", str: "string"}.get(tp, str(tp))


def _phrase(tp) -> str:
    """``tp`` as the words of an error message: ``a number or null``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_phrase(a) for a in args)
    if origin in (tuple, list):
        n = "" if len(args) == 2 and args[1] is Ellipsis else f"{len(args)} "
        return f"a list of {n}{_phrase(args[0]).split(' ', 1)[-1]}s"
    if origin in (dict, Mapping) or dataclasses.is_dataclass(tp):
        return "a mapping"
    names = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
    return names.get(tp, "null" if tp is type(None) else str(tp))


def _value(tp, v, meta: Mapping, key: str, src: str):
    """Validate ``v`` against annotation ``tp``; returns the typed (immutable) value."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        for branch in args:
            if _kind_matches(branch, v):
                return _value(branch, v, meta, key, src)
        raise ConfigError(f"must be {_phrase(tp)}, got {v!r}", src, key)
    if tp is type(None):
        if v is not None:
            raise ConfigError(f"must be null, got {v!r}", src, key)
        return None
    if tp is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"expected true or false, got {v!r}", src, key)
        return v
    if tp is int:
        if not _is_number(v):
            raise ConfigError(f"must be an integer, got {type(v).__name__} {v!r}", src, key)
        if not math.isfinite(float(v)) or v != int(v):
            raise ConfigError(f"must be an integer, got {v!r}", src, key)
        _check_bounds(int(v), meta, key, src)
        return int(v)
    if tp is float:
        if not _is_number(v):
            raise ConfigError(f"must be a number, got {type(v).__name__} {v!r}", src, key)
        if not math.isfinite(float(v)):
            raise ConfigError(f"must be finite, got {v!r}", src, key)
        _check_bounds(float(v), meta, key, src)
        return float(v)
    if tp is str:
        choices = meta.get("choices") or ()
        if isinstance(v, bool) and {"on", "off"} <= set(choices):
            v = "on" if v else "off"  # YAML 1.1 reads an unquoted on/off as a boolean
        if not isinstance(v, str) or not v.strip():
            raise ConfigError(f"must be a non-empty string, got {v!r}", src, key)
        if meta.get("choices") and v not in meta["choices"]:
            raise ConfigError(f"must be one of {', '.join(meta['choices'])}, got '{v}'", src, key)
        return v.strip()
    if origin in (tuple, list):
        if not isinstance(v, list | tuple):
            raise ConfigError(f"must be {_phrase(tp)}, got {v!r}", src, key)
        variadic = len(args) == 2 and args[1] is Ellipsis
        if not variadic and len(v) != len(args):
            raise ConfigError(f"must have {len(args)} elements, got {len(v)}", src, key)
        elems = [args[0]] * len(v) if variadic else list(args)
        pairs = enumerate(zip(elems, v, strict=True))
        return tuple(_value(t, x, meta, f"{key}[{i}]", src) for i, (t, x) in pairs)
    if origin in (dict, Mapping):
        block = _mapping(v, key, src)
        inner = args[1] if args else object
        return types.MappingProxyType(
            {k: _value(inner, x, meta, f"{key}.{k}", src) for k, x in block.items()}
        )
    if dataclasses.is_dataclass(tp):
        return from_mapping(tp, v, key, src)
    raise TypeError(f"options annotation {tp!r} of '{key}' is not supported")


def _mapping(v, key: str, src: str) -> dict:
    if v is None:
        return {}
    if not isinstance(v, Mapping):
        raise ConfigError(f"must be a mapping, got {type(v).__name__} {v!r}", src, key)
    for k in v:
        if not isinstance(k, str):
            raise ConfigError(f"keys must be strings, got {k!r}", src, key)
    return dict(v)


def from_mapping(cls, mapping, key_prefix: str, source: str = "<config>"):
    """Validate ``mapping`` (a YAML block, ``None`` = empty) into the frozen ``cls`` instance.

    Parameters
    ----------
    cls : type
        A frozen options dataclass whose fields were made with :func:`option`.
    mapping : Mapping or None
        The block as parsed from YAML.
    key_prefix : str
        Dotted key of the block (``"sensors.gps"``), named in every error.
    source : str
        The config file, named in every error.

    Raises
    ------
    ConfigError
        Unknown key (listing the allowed ones), wrong type, out of bounds, missing required
        value, each naming ``key_prefix.key`` and ``source``.
    """
    hook = getattr(cls, "from_block", None)
    if hook is not None:
        return hook(mapping, key_prefix, source)
    block = _mapping(mapping, key_prefix, source)
    fields = _fields(cls)
    names = [f.name for f in fields]
    for k in block:
        if k not in names:
            raise ConfigError(
                f"unknown key (allowed: {', '.join(names)})", source, _join(key_prefix, k)
            )
    hints = _hints(cls)
    kwargs = {}
    for f in fields:
        key = _join(key_prefix, f.name)
        if f.name not in block:
            if f.default is MISSING and f.default_factory is MISSING:
                raise ConfigError("missing required value", source, key)
            continue
        v, parse = block[f.name], f.metadata.get("parse")
        kwargs[f.name] = (
            parse(v, key, source) if parse else _value(hints[f.name], v, f.metadata, key, source)
        )
    obj = cls(**kwargs)
    # Which keys the user wrote (a default and an explicit value can be equal): see explicit().
    object.__setattr__(obj, "_explicit", frozenset(kwargs))
    check = getattr(obj, "check", None)
    if check is not None:
        try:
            check()
        except ConfigError as exc:
            raise ConfigError(_bare(exc), source, _join(key_prefix, exc.key or "")) from None
    return obj


def explicit(obj) -> frozenset[str]:
    """The keys the config gave for the options instance ``obj`` (not filled by defaults).

    Where the config is silent some values come from the data instead (a ROS message's
    covariance where a sensor block gives no ``sigma``); this is how a reader tells the two
    apart. An instance not made by :func:`from_mapping` has every field explicit.
    """
    given = getattr(obj, "_explicit", None)
    return given if given is not None else frozenset(f.name for f in _fields(type(obj)))


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix and key else prefix or key


def _bare(exc: ConfigError) -> str:
    """The message of ``exc`` without its ``file, key '...':`` prefix."""
    msg = str(exc)
    return msg.split(": ", 1)[1] if (exc.file or exc.key) and ": " in msg else msg


def coerce(cls, value, key_prefix: str, source: str = "<config>"):
    """``value`` as a ``cls`` instance: an instance passes, a mapping or ``None`` is validated."""
    if isinstance(value, cls):
        return value
    return from_mapping(cls, value, key_prefix, source)


def to_mapping(obj) -> dict:
    """A plain YAML/JSON-ready dict of an options instance (tuples become lists)."""

    def plain(v):
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return to_mapping(v)
        if isinstance(v, Mapping):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [plain(x) for x in v]
        return v

    return {f.name: plain(getattr(obj, f.name)) for f in _fields(type(obj))}


def describe(cls, key_prefix: str = "") -> list[dict]:
    """One row per key of ``cls``: ``key, type, unit, default, meaning`` (nested flattened)."""
    rows, hints = [], _hints(cls)
    for f in _fields(cls):
        key, meta, tp = _join(key_prefix, f.name), f.metadata, hints[f.name]
        default = (
            "required"
            if f.default is MISSING and f.default_factory is MISSING
            else _show(f.default if f.default is not MISSING else f.default_factory())
        )
        type_name = meta.get("type_name") or _type_label(tp)
        if meta.get("choices"):
            type_name = " \\| ".join(map(str, meta["choices"]))
        bounds = _bounds_text(meta)
        rows.append(
            {
                "key": key,
                "type": f"{type_name}{', ' + bounds if bounds else ''}",
                "unit": meta.get("unit", ""),
                "default": default,
                "meaning": meta.get("doc", ""),
            }
        )
        nested = [a for a in (tp, *typing.get_args(tp)) if dataclasses.is_dataclass(a)]
        for sub in nested:
            rows.extend(describe(sub, key))
    return rows


def _bounds_text(meta: Mapping) -> str:
    lo, hi = meta.get("minimum"), meta.get("maximum")
    if lo is not None and hi is not None:
        lb, rb = (
            "(" if meta.get("exclusive_minimum") else "[",
            ")" if meta.get("exclusive_maximum") else "]",
        )
        return f"in {lb}{_fmt(lo)}, {_fmt(hi)}{rb}"
    if lo is not None:
        return f"{'>' if meta.get('exclusive_minimum') else '>='} {_fmt(lo)}"
    if hi is not None:
        return f"{'<' if meta.get('exclusive_maximum') else '<='} {_fmt(hi)}"
    return ""


def _show(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, tuple | list):
        return "[" + ", ".join(_show(x) for x in v) + "]"
    if dataclasses.is_dataclass(v):
        return "(block)"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k}: {_show(x)}" for k, x in v.items()) + "}" if v else "{}"
    return _fmt(v)


def markdown_table(cls, key_prefix: str = "") -> str:
    """The docs table of ``cls``: ``| key | type | unit | default | meaning |``."""
    lines = ["| key | type | unit | default | meaning |", "| --- | --- | --- | --- | --- |"]
    for r in describe(cls, key_prefix):
        lines.append(
            f"| `{r['key']}` | {r['type']} | {r['unit']} | `{r['default']}` | {r['meaning']} |"
        )
    return "\n".join(lines)


def text_table(cls, key_prefix: str = "") -> str:
    """The listing of ``odofuse options NAME``: one aligned line per key."""
    rows = describe(cls, key_prefix)
    head = {
        "key": "key",
        "type": "type",
        "unit": "unit",
        "default": "default",
        "meaning": "meaning",
    }
    cols = ("key", "type", "unit", "default")
    width = {c: max(len(str(r[c])) for r in [head, *rows]) for c in cols}
    return "\n".join(
        "  ".join(str(r[c]).replace("\\|", "|").ljust(width[c]) for c in cols) + "  " + r["meaning"]
        for r in [head, *rows]
    )


# ------------------------------------------------------------------------------- docs writer
def _marker(name: str) -> tuple[str, str]:
    return f"<!-- options:{name} -->", f"<!-- /options:{name} -->"


def render_docs(text: str, tables: Mapping[str, str]) -> str:
    """``text`` with every ``<!-- options:NAME -->`` ... ``<!-- /options:NAME -->`` refilled."""
    out = text
    for name, table in tables.items():
        start, end = _marker(name)
        i = out.find(start)
        if i < 0:
            continue
        j = out.find(end, i)
        if j < 0:
            raise ValueError(f"{start} has no closing {end}")
        out = out[: i + len(start)] + "\n" + table + "\n" + out[j:]
    return out
