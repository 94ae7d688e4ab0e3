"""One entry point for every log format: :func:`load_log` picks the reader.

==========================================  ================================================
``spec``                                    reader
==========================================  ================================================
``builtin:NAME``                            :func:`odofuse.io.builtin.load_builtin`
folder with ``metadata.yaml``/``*.db3``/    :func:`odofuse.io.bags.read_bag` (ROS 2 bag)
``*.mcap``
any other folder                            :func:`odofuse.io.csvlog.read_csv_log`
``*.db3``, ``*.mcap``, ``*.bag`` file       :func:`odofuse.io.bags.read_bag`
``*.g2o``, ``*.graph``, or a text file      :func:`odofuse.io.gtsam_text.read_gtsam_text`
whose first line is a pose-graph tag
==========================================  ================================================
"""

from __future__ import annotations

from pathlib import Path

from odofuse.errors import InputError
from odofuse.io.log import SensorLog

BAG_SUFFIXES = (".db3", ".mcap", ".bag")
GRAPH_SUFFIXES = (".g2o", ".graph")


def log_kind(path: Path) -> str:
    """``"csv"``, ``"bag"`` or ``"gtsam"`` for an existing path (raises InputError otherwise)."""
    if path.is_dir():
        if (path / "metadata.yaml").exists() or any(path.glob("*.db3")) or any(path.glob("*.mcap")):
            return "bag"
        return "csv"
    if not path.exists():
        raise InputError(
            "log not found (expected a folder, a bag, a pose-graph text file or builtin:NAME)",
            str(path),
        )
    suffix = path.suffix.lower()
    if suffix in BAG_SUFFIXES:
        return "bag"
    from odofuse.io.gtsam_text import looks_like_gtsam_text

    if suffix in GRAPH_SUFFIXES or looks_like_gtsam_text(path):
        return "gtsam"
    raise InputError(
        "unknown log format (expected a CSV log folder, .db3/.mcap/.bag, or a "
        "2-D pose-graph text file)",
        str(path),
    )


def load_log(
    spec: str | Path,
    base_dir: str | Path | None = None,
    *,
    encoder: dict | None = None,
    topics: dict | None = None,
    joints: dict | None = None,
) -> SensorLog:
    """Load a log from ``builtin:NAME``, a CSV folder, a ROS bag/MCAP or a GTSAM text file.

    Parameters
    ----------
    spec : str or Path
        The log; a relative path is taken relative to ``base_dir`` when given.
    base_dir : str or Path, optional
        Folder of the config file that named the log.
    encoder : dict, optional
        The robot's encoder block (CSV ``wheels.csv`` in ticks).
    topics : dict, optional
        ``{stream: topic or [topics]}`` for bags.
    joints : dict, optional
        ``{drive input: JointState joint name}`` for bags.

    Returns
    -------
    SensorLog
    """
    s = str(spec)
    if s.startswith("builtin:"):
        from odofuse.io.builtin import load_builtin

        return load_builtin(s)
    path = Path(s).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    kind = log_kind(path)
    if kind == "csv":
        from odofuse.io.csvlog import read_csv_log

        return read_csv_log(path, encoder=encoder)
    if kind == "bag":
        from odofuse.io.bags import read_bag

        return read_bag(path, topics=topics, joints=joints)
    from odofuse.io.gtsam_text import read_gtsam_text

    return read_gtsam_text(path)


def load_log_for(config) -> SensorLog:
    """Load the log named by a :class:`odofuse.config.RunConfig` (its encoder block and topics).

    When the robot has an ``encoder`` block without ``columns``, the encoder columns of
    ``wheels.csv`` are the drive's inputs of kind ``"wheel"`` (steering angles stay radians).
    """
    robot = dict(config.robot or {})
    encoder = robot.get("encoder")
    if encoder and not encoder.get("columns"):
        from odofuse.drives import make_drive

        geometry = {k: v for k, v in robot.items() if k not in ("drive", "encoder")}
        drive = make_drive(robot["drive"], **geometry)
        kinds = getattr(drive, "input_kinds", ("wheel",) * len(drive.input_names))
        cols = [n for n, k in zip(drive.input_names, kinds, strict=True) if k == "wheel"]
        encoder = {**encoder, "columns": cols}
    opts = config.log_options or {}
    return load_log(
        config.log, encoder=encoder, topics=opts.get("topics"), joints=opts.get("joints")
    )
