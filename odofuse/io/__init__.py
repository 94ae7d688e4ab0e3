"""Reading logs (CSV folders, built-in datasets, ROS 2 bags, g2o/TORO/iSAM/pyfg pose graphs, raw
Plaza text) into a SensorLog; :mod:`odofuse.io.loader` picks the reader."""

from odofuse.io.loader import load_log, load_log_for
from odofuse.io.log import SensorLog, Stream

__all__ = [
    "SensorLog",
    "Stream",
    "load_log",
    "load_log_for",
    "read_csv_log",
    "write_csv_log",
    "read_bag",
    "read_gtsam_text",
    "load_builtin",
]


def __getattr__(name):
    # Lazy: importing odofuse.io must not import rosbags or gtsam.
    if name in ("read_csv_log", "write_csv_log"):
        from odofuse.io import csvlog

        return getattr(csvlog, name)
    if name == "read_bag":
        from odofuse.io.bags import read_bag

        return read_bag
    if name == "read_gtsam_text":
        from odofuse.io.gtsam_text import read_gtsam_text

        return read_gtsam_text
    if name == "load_builtin":
        from odofuse.io.builtin import load_builtin

        return load_builtin
    raise AttributeError(name)
