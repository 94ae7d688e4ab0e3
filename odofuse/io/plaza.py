"""The Plaza lawn-mower datasets (Djugash et al.): raw ``*_DR/TD/GT/TL.txt`` files and the streams.

The raw files are whitespace-separated numbers, one row per line:

==========  ==============================  ====================================================
file        columns                         becomes
==========  ==============================  ====================================================
``*_DR``    ``t ds dtheta``                 ``odometry`` (increments, m and rad)
``*_TD``    ``t - id range``                ``ranges`` (sorted by time, repeated (t, id) rows
                                            dropped, both counted as ``ranges.reordered`` and
                                            ``ranges.duplicates_dropped``)
``*_GT``    ``t x y theta``                 ground truth
``*_TL``    ``id x y``                      the beacon map
==========  ==============================  ====================================================

``Plaza1_.mat`` / ``Plaza2_.mat`` hold the same arrays (``DR``, ``TD``, ``TL``, ``GT``) and the
dead-reckoned path ``DRp``, whose first row is the published start pose
(:func:`read_plaza_mat`; ``builtin:plaza1`` reads the file of the installed gtsam).

Naming any one of ``Plaza1_DR.txt`` / ``Plaza1_TD.txt`` / ... reads every sibling with the same
prefix that exists. The gtsam wheel ships only ``DR`` and ``TD`` as text (ground truth and beacons
are in ``Plaza1_.mat``, read by ``builtin:plaza1``), so a log from the text files has odometry
and ranges but no map and no ground truth.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from odofuse.errors import InputError
from odofuse.io.log import SensorLog, Stream, time_ordered

NAME = re.compile(r"^(?P<prefix>.+)_(?P<kind>DR|TD|GT|TL)\.txt$", re.IGNORECASE)
COLUMNS = {"DR": 3, "TD": 4, "GT": 4, "TL": 3}


def plaza_log(dr, td, tl, gt, source: str, initial=None, files=None) -> SensorLog:
    """The SensorLog of Plaza arrays (``dr`` or ``td``, ``tl``, ``gt`` may be ``None``).

    ``source`` names the log (the path the config gave); ``files`` maps ``"DR"``, ``"TD"``,
    ``"GT"`` to the file each array was read from, the ``source`` of its stream (default
    ``source``: a ``.mat`` holds them all), so that a message about the odometry of a log
    named by its ``_TD.txt`` names ``_DR.txt``."""
    files = files or {}
    src = {kind: files.get(kind, source) for kind in ("DR", "TD", "GT")}
    streams, repairs = {}, {}
    if dr is not None:
        streams["odometry"] = Stream("odometry", src["DR"], dr[:, 0], ("ds", "dtheta"), dr[:, 1:3])
    if td is not None:
        # The raw TD ranges of Plaza1 jump back in time twice (425 rows out of order) and repeat
        # two (t, beacon) pairs with different ranges: sorted and deduplicated here, and counted.
        ranges, moved, dropped = time_ordered(
            Stream("ranges", src["TD"], td[:, 0], ("id", "range"), td[:, 2:4]), ("id",)
        )
        streams["ranges"] = ranges
        pairs = (("ranges.reordered", moved), ("ranges.duplicates_dropped", dropped))
        repairs = {k: v for k, v in pairs if v}
    landmarks = {} if tl is None else {int(row[0]): row[1:3].copy() for row in tl}
    groundtruth = None
    if gt is not None:
        groundtruth = Stream("groundtruth", src["GT"], gt[:, 0], ("x", "y", "theta"), gt[:, 1:4])
    return SensorLog(source, streams, landmarks, groundtruth, repairs, initial)


def is_plaza_text(path: str | Path) -> bool:
    return NAME.match(Path(path).name) is not None


def _read_table(path: Path, ncol: int) -> np.ndarray:
    name = str(path)
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for row, line in enumerate(fh, start=1):
            cells = line.split()
            if not cells:
                continue
            if len(cells) != ncol:
                raise InputError(f"expected {ncol} numbers, got {len(cells)}", name, row)
            try:
                vals = [float(c) for c in cells]
            except ValueError:
                raise InputError("non-numeric value", name, row) from None
            if not np.all(np.isfinite(vals)):
                raise InputError("non-finite value", name, row)
            rows.append(vals)
    if not rows:
        raise InputError("empty file", name)
    return np.array(rows)


def read_plaza_text(path: str | Path) -> SensorLog:
    """Read ``<prefix>_DR/TD/GT/TL.txt`` (whichever exist beside ``path``) into a SensorLog."""
    path = Path(path)
    m = NAME.match(path.name)
    if m is None:
        raise InputError("not a Plaza text file (expected <prefix>_DR/TD/GT/TL.txt)", str(path))
    found, files = {}, {}
    for kind, ncol in COLUMNS.items():
        sibling = path.with_name(f"{m['prefix']}_{kind}.txt")
        if sibling.exists():
            found[kind], files[kind] = _read_table(sibling, ncol), str(sibling)
    if "TD" not in found and "DR" not in found:
        raise InputError(f"neither {m['prefix']}_DR.txt nor {m['prefix']}_TD.txt exists", str(path))
    arrays = (found.get(kind) for kind in ("DR", "TD", "TL", "GT"))
    return plaza_log(*arrays, str(path), files=files)


#: The arrays a Plaza ``.mat`` file must hold.
MAT_KEYS = ("DR", "TD", "TL", "GT", "DRp")


def read_plaza_mat(path: str | Path, source: str | None = None) -> SensorLog:
    """Read a Plaza ``*_.mat`` file (module docstring) into a SensorLog.

    Raises
    ------
    InputError
        A file MATLAB's format reader refuses, or one without the Plaza arrays.
    """
    import scipy.io

    name = str(path)
    try:
        mat = scipy.io.loadmat(name)
    except Exception as exc:  # noqa: BLE001 - scipy raises IndexError, ValueError ... on junk
        raise InputError(f"not a readable MATLAB .mat file ({exc})"[:200], name) from None
    missing = [k for k in MAT_KEYS if k not in mat]
    if missing:
        raise InputError(
            f"a .mat log must be a Plaza file (arrays {', '.join(MAT_KEYS)}); missing "
            f"{', '.join(missing)}",
            name,
        )
    dr, td, tl, gt = (np.asarray(mat[k], dtype=float) for k in ("DR", "TD", "TL", "GT"))
    # The dataset's dead-reckoned path (DRp) starts at the published initial pose.
    initial = np.asarray(mat["DRp"][0, 1:4], dtype=float)
    return plaza_log(dr, td, tl, gt, source or name, initial)
