"""Error types for bad input: each names the file and the row/column or the config key."""

from __future__ import annotations


def one_line(exc: BaseException) -> str:
    """``"Type: first line of the message"``: an exception as one line of a table or a log."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


class OdofuseError(ValueError):
    """Base class of every error odofuse raises for bad input; the CLI prints it on one line."""


class InputError(OdofuseError):
    """Bad data in a log: names the file, and the row (1-based, header = row 1) and column."""

    def __init__(
        self,
        message: str,
        file: str | None = None,
        row: int | None = None,
        column: str | None = None,
    ) -> None:
        self.file, self.row, self.column = file, row, column
        where = []
        if file is not None:
            where.append(str(file))
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)


class ConfigError(OdofuseError):
    """Bad run configuration: names the key (dotted path) and the file."""

    def __init__(self, message: str, file: str | None = None, key: str | None = None) -> None:
        self.file, self.key = file, key
        where = []
        if file is not None:
            where.append(str(file))
        if key is not None:
            where.append(f"key '{key}'")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)


class NumericError(OdofuseError):
    """An estimator's state or covariance stopped being finite: names the estimator, the time,
    the stream being processed and the most likely cause that could be tested."""

    def __init__(self, message: str, estimator: str, t: float, stream: str) -> None:
        self.estimator, self.t, self.stream = estimator, t, stream
        super().__init__(f"{estimator}: at t={t:.3f} s ({stream}): {message}")


def check_array(value, name: str, shape: tuple, expected: str | None = None):
    """``value`` as a float array of ``shape`` (``None`` entries: any length), else InputError.

    A one-line check for the Python API (the CLI's inputs are checked by the loaders):
    ``check_array(U, "U", (None, 2), "(N, 2): one row per step, columns left, right")``.
    Refuses other numbers of dimensions, other lengths, non-numeric dtypes (strings, objects,
    booleans) and non-finite values. Returns a new float64 array.
    """
    import numpy as np

    want = expected or "(" + ", ".join("N" if n is None else str(n) for n in shape) + ")"
    try:
        raw = np.asarray(value)
    except Exception as exc:  # noqa: BLE001 - ragged lists and the like
        raise InputError(f"argument '{name}': expected shape {want}, got {one_line(exc)}") from None
    if raw.dtype.kind not in "iuf":
        raise InputError(
            f"argument '{name}': expected numbers of shape {want}, got dtype {raw.dtype}"
        )
    ok = raw.ndim == len(shape) and all(
        n is None or m == n for m, n in zip(raw.shape, shape, strict=True)
    )
    if not ok:
        raise InputError(f"argument '{name}': expected shape {want}, got shape {raw.shape}")
    arr = raw.astype(float)
    if not np.isfinite(arr).all():
        raise InputError(f"argument '{name}': values must be finite (shape {want})")
    return arr
