"""Built-in datasets read from the installed gtsam package (never copied into odofuse).

``builtin:plaza1`` / ``builtin:plaza2``: the Plaza lawn-mower robot (Djugash et al.) shipped
in ``gtsam/Data``: odometry increments (``DR``: t, ds, dtheta), ranges to 4 surveyed beacons
(``TD``: t, -, beacon id, range), beacon positions (``TL``) and ground truth (``GT``).
"""

from __future__ import annotations

from odofuse.errors import InputError
from odofuse.io.log import SensorLog
from odofuse.io.plaza import read_plaza_mat

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
    key = name.removeprefix("builtin:").lower()
    if key not in BUILTINS:
        raise InputError(f"unknown built-in dataset '{name}'; known: {', '.join(BUILTINS)}")
    path = _data_file(f"{key.capitalize()}_.mat")
    return read_plaza_mat(path, f"builtin:{key} ({path})")
