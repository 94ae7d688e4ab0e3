"""2-D pose-graph text files of the GTSAM wheel: g2o, TORO/``.graph`` and iSAM line types.

One file may mix the families (``example.graph`` has TORO ``EDGE2`` and iSAM ``BR`` lines), so
:func:`read_gtsam_text` reads every line with the union of the tables of
:mod:`odofuse.io.g2o`, :mod:`odofuse.io.toro` and :mod:`odofuse.io.isam_text`, and
:mod:`odofuse.io.posegraph` assembles the streams. Each module documents its lines; a line type
none of them reads is an error naming file, row and type (3-D types included).
"""

from __future__ import annotations

from pathlib import Path

from odofuse.io import g2o, isam_text, toro
from odofuse.io.log import SensorLog
from odofuse.io.posegraph import THREE_D_PREFIXES, GraphBuilder, read_lines

PARSERS = {**g2o.PARSERS, **toro.PARSERS, **isam_text.PARSERS}
REFUSED = {**g2o.REFUSED, **toro.REFUSED, **isam_text.REFUSED}


def first_line(path: str | Path) -> list[str] | None:
    """The words of the first non-empty, non-comment line (``None`` if unreadable)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for _ in range(100):  # bounded: a huge or binary file is not read whole
                line = fh.readline(65536)
                if not line:
                    return None
                s = line.split()
                if s and not s[0].startswith("#"):
                    return s
    except (OSError, UnicodeError):
        return None
    return None


def first_tag(path: str | Path) -> str | None:
    """The first word of :func:`first_line`."""
    cells = first_line(path)
    return cells[0] if cells else None


def looks_like_gtsam_text(path: str | Path) -> bool:
    """True when the first line starts with a pose-graph tag (2-D, or 3-D to refuse it by name)."""
    tag = first_tag(path)
    return tag is not None and (
        tag in PARSERS or tag in REFUSED or tag.startswith(THREE_D_PREFIXES)
    )


def read_gtsam_text(path: str | Path) -> SensorLog:
    """Read a 2-D pose-graph text file into a ``SensorLog`` (:mod:`odofuse.io.posegraph`).

    Raises
    ------
    InputError
        Naming the line: a short or non-numeric line, an unknown, refused or 3-D line type, a
        noise matrix that is not positive definite, two odometry edges for one step; or naming
        the file: a missing step in the odometry chain, no edges at all.
    """
    return read_lines(path, PARSERS, REFUSED, GraphBuilder(str(path))).build()
