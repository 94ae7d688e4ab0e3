"""Reading one numeric CSV table with a header line: the parsing half of the CSV log reader.

:func:`read_table` is used by :mod:`odofuse.io.csvlog` (stream files, ``map.csv``); the checks
of a stream's columns and values, the repairs and the log folder are there.

Two paths give the same result. The fast path scans the file's bytes in chunks with numpy
(line length bound, comma count per line, bytes that need care) and, when the file is plain
ASCII with the same number of cells on every line, parses it with numpy's C reader
(``np.loadtxt``, which converts each cell with the same correctly rounded string-to-double
conversion as Python's ``float``): no Python string per cell, memory about the size of the
parsed array. Anything else -- a non-ASCII byte (BOM, UTF-8 text, a bad byte), an underscore
(Python's ``float`` reads ``1_0`` as 10), a line break other than ``\n``/``\r\n``, a blank line,
a row with too few/many cells, a cell the C reader refuses, a non-finite or out-of-range
value, an empty table -- goes to the exact path, which reads the file as text line by line
and raises the one-line error naming file, line and column (or accepts what it accepts).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from odofuse.errors import InputError

#: Bounds of a CSV file (shared spec section 5): a line longer than this many bytes is an
#: error (read in chunks of ``_CHUNK`` bytes, so memory stays bounded for a file without line
#: breaks), and a cell beyond this magnitude is out of range (no physical value in SI units
#: comes near; a time stamp in nanoseconds since 1970 does).
MAX_LINE_BYTES = 8192
MAX_MAGNITUDE = 1e15
#: Input quoted in a message is cut to this many characters.
EXCERPT_CHARS = 40
_CHUNK = 1 << 24


def read_table(
    path: str | Path, first_column: str | None = "t"
) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Read a numeric CSV table with a header line.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    first_column : str or None
        Required name of the first column (``"t"`` for stream files), or ``None``.

    Returns
    -------
    header : tuple of str
        Column names, stripped of surrounding white space.
    data : ndarray, shape (N, C)
        All cells as floats (finite: NaN/inf raise).
    lines : ndarray of int, shape (N,)
        1-based line number of each data row in the file (the header is line 1).

    Raises
    ------
    InputError
        Empty file, bad header, a row with too few/many cells, a non-numeric, empty or
        non-finite cell; the message names file, line and column.
    """
    path = Path(path)
    name = str(path)
    fast = _read_fast(path, name, first_column)
    if fast is not None:
        return fast
    return _read_exact(path, name, first_column)


def _read_exact(path: Path, name: str, first_column: str | None):
    """The exact path of :func:`read_table`: the file as text, line by line."""
    raw = _read_bounded(path, name)
    first = raw.split(b"\n", 1)[0]
    head_text = _decode(first, name, 1, None).removeprefix("\ufeff")
    text = _decode(raw, name, None, tuple(c.strip() for c in head_text.split(",")))
    del raw
    all_lines = text.removeprefix("\ufeff").splitlines()
    if not all_lines or not all_lines[0].strip():
        raise InputError("empty file: expected a header line", name, 1)
    header = _header(all_lines[0], name, first_column)
    ncol = len(header)
    body = all_lines[1:]
    keep = [i for i, line in enumerate(body) if line.strip()]
    if len(keep) != len(body):
        body = [body[i] for i in keep]
    lines = np.asarray(keep, dtype=np.int64) + 2
    counts = np.fromiter((line.count(",") for line in body), dtype=np.int64, count=len(body))
    bad = np.flatnonzero(counts != ncol - 1)
    if bad.size:
        i = int(bad[0])
        n = int(counts[i]) + 1
        what = "too few" if n < ncol else "too many"
        col = header[n] if n < ncol else None
        raise InputError(
            f"{what} cells: {n} instead of {ncol} ({excerpt(', '.join(header))})",
            name,
            int(lines[i]),
            col,
        )
    if not body:
        return header, np.empty((0, ncol)), lines
    joined = ",".join(body)
    try:
        if "_" in joined:  # Python's float() reads "1_0" as 10; a CSV number has no "_"
            raise ValueError("underscore in a number")
        data = np.array(joined.split(","), dtype=float).reshape(len(body), ncol)
    except ValueError:
        _raise_bad_cell(name, header, body, lines)
        raise  # pragma: no cover - _raise_bad_cell always raises
    finite = np.isfinite(data)
    if not finite.all():
        i, j = np.argwhere(~finite)[0]
        cell = excerpt(body[i].split(",")[j].strip())
        raise InputError(f"value {cell!r} is not finite", name, int(lines[i]), header[j])
    huge = np.abs(data) > MAX_MAGNITUDE
    if huge.any():
        i, j = np.argwhere(huge)[0]
        cell = excerpt(body[i].split(",")[j].strip())
        hint = " (time stamps must be in seconds)" if j == 0 and first_column == "t" else ""
        raise InputError(
            f"value {cell} is out of range (|value| > {MAX_MAGNITUDE:g}){hint}",
            name,
            int(lines[i]),
            header[j],
        )
    return header, data, lines


def _header(line: str, name: str, first_column: str | None) -> tuple[str, ...]:
    """The column names of the header line (stripped); raises on an empty or repeated name
    or a wrong first column."""
    header = tuple(c.strip() for c in line.split(","))
    for j, col in enumerate(header):
        if not col:
            raise InputError(f"empty column name in header (column {j + 1})", name, 1)
        if header.index(col) != j:
            raise InputError("column named twice in the header", name, 1, col)
    if first_column is not None and header[0] != first_column:
        raise InputError(
            f"first column must be '{first_column}', found '{header[0]}'", name, 1, first_column
        )
    return header


#: Bytes of plain numeric CSV: a file with only these goes to the fast path as it is. Any other
#: byte is looked at (:data:`_SLOW_BYTES`).
_PLAIN = b"0123456789.,-+eE\n"
#: Bytes that send a file to the exact path: non-ASCII, ``_`` and the line breaks of
#: ``str.splitlines`` other than ``\n`` and ``\r`` (a ``\r`` is allowed only in ``\r\n``).
_SLOW_BYTES = frozenset(range(128, 256)) | {ord("_"), 0x0B, 0x0C, 0x1C, 0x1D, 0x1E}
#: Every block of this many bytes holding a newline bounds each line below MAX_LINE_BYTES.
_BLOCK = MAX_LINE_BYTES // 2


def _check_line_lengths(chunk: bytes, tail: int, name: str, line: int) -> tuple[int, int]:
    """Raise the error of the first line longer than :data:`MAX_LINE_BYTES` in ``chunk``.

    ``tail`` is the number of bytes since the last newline before ``chunk`` and ``line`` the
    (1-based) line that ``chunk`` starts in. Returns ``(newlines in chunk, new tail)``.
    """
    nl = np.flatnonzero(np.frombuffer(chunk, dtype=np.uint8) == 10)
    starts = np.concatenate(([-tail - 1], nl))
    ends = np.concatenate((nl, [len(chunk)]))
    lengths = ends - starts - 1
    long = np.flatnonzero(lengths > MAX_LINE_BYTES)
    if long.size:
        raise InputError(
            f"line longer than {MAX_LINE_BYTES} bytes (binary or corrupt file?)",
            name,
            line + int(long[0]),
        )
    return nl.size, int(lengths[-1])


def _scan(path: Path, name: str) -> tuple[int, bool]:
    """One pass over the file's bytes in chunks of ``_CHUNK``.

    Raises the error of a line longer than :data:`MAX_LINE_BYTES` (as the exact path does,
    before anything else). Returns ``(lines, plain)``: the number of lines, and whether the
    fast path may parse the file -- only ASCII without :data:`_SLOW_BYTES` and ``\r`` only in
    ``\r\n``. (Rows of unequal length, blank lines and bad cells are caught by the parser and
    the row count.)
    """
    line, tail = 1, 0  # tail: bytes since the last newline
    plain, cr_pending = True, False
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            first = chunk.find(b"\n")
            short = first >= 0 and tail + first <= MAX_LINE_BYTES
            # each block holding a newline: no line inside the chunk reaches 2 * _BLOCK bytes
            short = short and all(
                chunk.find(b"\n", k, k + _BLOCK) >= 0 for k in range(0, len(chunk), _BLOCK)
            )
            if short:
                nl_count = chunk.count(b"\n")
                last = chunk.rfind(b"\n")
                new_tail = len(chunk) - last - 1
            else:
                nl_count, new_tail = _check_line_lengths(chunk, tail, name, line)
            line += nl_count
            tail = new_tail
            if not plain:
                continue
            odd = set(chunk.translate(None, _PLAIN))
            if odd & _SLOW_BYTES or (cr_pending and chunk[:1] != b"\n"):
                plain = False
            elif 13 in odd:
                crlf = chunk.count(b"\r\n")
                cr_pending = chunk.endswith(b"\r")
                plain = chunk.count(b"\r") == crlf + cr_pending
            else:
                cr_pending = False
    return line - (tail == 0), plain and not cr_pending


def _read_fast(path: Path, name: str, first_column: str | None):
    """The fast path of :func:`read_table`, or ``None`` where the exact path must decide."""
    lines, uniform = _scan(path, name)
    if not uniform or lines < 2:
        return None
    with open(path, encoding="ascii", newline="") as fh:
        head = fh.readline().rstrip("\r\n")
    header = _header(head, name, first_column)
    try:
        data = np.loadtxt(
            path, delimiter=",", skiprows=1, comments=None, dtype=float, ndmin=2, encoding="ascii"
        )
    except ValueError:
        return None
    n = lines - 1
    if data.shape != (n, len(header)):
        return None
    if not np.isfinite(data).all() or (np.abs(data) > MAX_MAGNITUDE).any():
        return None
    return header, data, np.arange(2, n + 2, dtype=np.int64)


def excerpt(text: str, limit: int = EXCERPT_CHARS) -> str:
    """``text`` cut to ``limit`` characters (with ``...``), for quoting input in a message."""
    return text if len(text) <= limit else text[:limit] + "..."


def _read_bounded(path: Path, name: str) -> bytes:
    """The file's bytes, refusing a line longer than :data:`MAX_LINE_BYTES` while reading.

    Reads in chunks, so a multi-gigabyte file without line breaks (a sparse file, a binary
    file) ends after the first chunk instead of being read into memory.
    """
    chunks, line, tail = [], 1, 0  # tail: bytes since the last newline
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            nl_count, tail = _check_line_lengths(chunk, tail, name, line)
            line += nl_count
            chunks.append(chunk)
    return b"".join(chunks)


def _decode(raw: bytes, name: str, row: int | None, header) -> str:
    """Decode UTF-8 (BOM allowed); a bad byte raises InputError naming row and column."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        at = exc.start
        start = raw.rfind(b"\n", 0, at) + 1
        line = row if row is not None else raw.count(b"\n", 0, at) + 1
        j = raw.count(b",", start, at)
        col = header[j] if header is not None and line > 1 and j < len(header) else None
        raise InputError(
            f"not UTF-8: byte 0x{raw[at]:02x} at byte {at - start + 1} of the line",
            name,
            line,
            col,
        ) from None


def _raise_bad_cell(name: str, header, body, lines) -> None:
    for i, line in enumerate(body):
        for j, cell in enumerate(line.split(",")):
            try:
                if "_" in cell:
                    raise ValueError(cell)
                float(cell)
            except ValueError:
                what = (
                    "empty cell" if not cell.strip() else f"not a number: {excerpt(cell.strip())!r}"
                )
                raise InputError(what, name, int(lines[i]), header[j]) from None
    raise InputError("unreadable numeric data", name)  # pragma: no cover
