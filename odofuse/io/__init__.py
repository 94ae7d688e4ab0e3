"""Reading logs (CSV folders, built-in datasets, ROS 2 bags, GTSAM text) into a SensorLog."""

from odofuse.io.log import SensorLog, Stream

__all__ = ["SensorLog", "Stream"]
