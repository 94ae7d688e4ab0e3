"""Built-in datasets read from the installed gtsam package (never copied into odofuse).

``builtin:plaza1`` / ``builtin:plaza2``: the Plaza lawn-mower robot (Djugash et al.) shipped
in ``gtsam/Data``: odometry increments (``DR``: t, ds, dtheta), ranges to 4 surveyed beacons
(``TD``: t, -, beacon id, range), beacon positions (``TL``) and ground truth (``GT``).
"""

from __future__ import annotations

import numpy as np

from odofuse.errors import InputError
from odofuse.io.log import SensorLog
from odofuse.io.plaza import plaza_log

BUILTINS = ("plaza1", "plaza2")


def _data_file(name: str) -> str:
    """Path of a file in the installed gtsam's ``Data`` folder, found without importing gtsam
    (a filter run then never loads it); ``gtsam.findExampleDataFile`` where the folder differs.
    """
    import importlib.util
    import os

    spec = importlib.util.find_spec("gtsam")
    for folder in (spec.submodule_search_locations or []) if spec else []:
        path = os.path.join(folder, "Data", name)
        if os.path.isfile(path):
            return path
    import gtsam

    return gtsam.findExampleDataFile(name)


def load_builtin(name: str) -> SensorLog:
    """Load a built-in dataset by name (``"plaza1"``/``"plaza2"``, ``builtin:`` optional)."""
    import scipy.io

    key = name.removeprefix("builtin:").lower()
    if key not in BUILTINS:
        raise InputError(f"unknown built-in dataset '{name}'; known: {', '.join(BUILTINS)}")
    path = _data_file(f"{key.capitalize()}_.mat")
    mat = scipy.io.loadmat(path)
    dr, td, tl, gt = (np.asarray(mat[k], dtype=float) for k in ("DR", "TD", "TL", "GT"))
    source = f"builtin:{key} ({path})"
    # The dataset's dead-reckoned path (DRp) starts at the published initial pose.
    initial = np.asarray(mat["DRp"][0, 1:4], dtype=float)
    return plaza_log(dr, td, tl, gt, source, initial)
