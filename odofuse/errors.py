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
