"""The drive registry: name -> class (:data:`DRIVES`) and :func:`make_drive`.

A user plug-in is named ``"package.module:Class"``; nothing else is needed to add a drive.
"""

from __future__ import annotations

import dataclasses

from odofuse.drives.car import Car, CarAckermann
from odofuse.drives.differential import Differential, SkidSteer
from odofuse.drives.offset import Offset
from odofuse.drives.omni import Generic, Mecanum4, Omni3
from odofuse.drives.steered import Ackermann, Bicycle, Synchro, Tricycle
from odofuse.drives.swerve import Swerve
from odofuse.drives.twist import Increments, Twist
from odofuse.errors import ConfigError
from odofuse.plugins import DRIVE_METHODS, load_class

DRIVES: dict[str, type] = {
    cls.name: cls
    for cls in (
        Differential,
        SkidSteer,
        Tricycle,
        Ackermann,
        Bicycle,
        Synchro,
        Omni3,
        Mecanum4,
        Generic,
        Increments,
        Swerve,
        Car,
        CarAckermann,
        Twist,
    )
}


def _load_class(spec: str) -> type:
    """The plug-in drive class ``spec``, checked to be a class with the drive methods."""
    try:
        return load_class(spec, "drive", DRIVE_METHODS)
    except ConfigError as exc:
        raise ConfigError(str(exc), key="drive") from None


def make_drive(name: str, **geometry):
    """Build a drive model from its registry name (or ``"package.module:Class"``) and geometry.

    Parameters
    ----------
    name : str
        A key of :data:`DRIVES` or ``"package.module:Class"`` for a user plug-in.
    **geometry
        The class's constructor arguments (e.g. ``wheel_radius=0.04, track_width=0.235``).
        ``base_frame_offset=[x, y, theta]`` (any drive) reports the twist at a base frame with
        that pose in the drive's kinematic-centre frame (:class:`odofuse.drives.offset.Offset`).

    Returns
    -------
    DriveModel

    Raises
    ------
    ValueError (:class:`odofuse.errors.ConfigError`)
        For an unknown drive name, an unknown or missing geometry key (the message names the
        key), or an invalid value.
    """
    if not isinstance(name, str):
        raise ConfigError(f"drive name must be a string, got {name!r}", key="drive")
    if "base_frame_offset" in geometry:
        geometry = dict(geometry)
        offset = geometry.pop("base_frame_offset")
        return Offset(make_drive(name, **geometry), offset)
    if ":" in name:
        cls = _load_class(name)
    elif name in DRIVES:
        cls = DRIVES[name]
    else:
        raise ConfigError(
            f"unknown drive '{name}'; known: {', '.join(sorted(DRIVES))}", key="drive"
        )
    if dataclasses.is_dataclass(cls):
        fields = [f for f in dataclasses.fields(cls) if f.init]
        known = {f.name for f in fields}
        for key in geometry:
            if key not in known:
                raise ConfigError(
                    f"drive '{name}': unknown geometry key '{key}'; accepted: "
                    f"{', '.join(sorted(known)) or 'none'}",
                    key=key,
                )
        for f in fields:
            no_default = (
                f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
            )
            if no_default and f.name not in geometry:
                raise ConfigError(f"drive '{name}': missing geometry key '{f.name}'", key=f.name)
        return cls(**geometry)
    try:
        return cls(**geometry)
    except TypeError as exc:
        raise ConfigError(f"drive '{name}': bad geometry ({exc})", key="drive") from None
