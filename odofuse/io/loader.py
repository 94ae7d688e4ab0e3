"""One entry point for every log format: :func:`load_log` picks the reader.

==========================================  ================================================
``spec``                                    reader
==========================================  ================================================
``builtin:NAME``                            :func:`odofuse.io.builtin.load_builtin`
folder with ``metadata.yaml``/``*.db3``/    :func:`odofuse.io.bags.read_bag` (ROS 2 bag)
``*.mcap``
any other folder                            :func:`odofuse.io.csvlog.read_csv_log`
``*.db3``, ``*.mcap``, ``*.bag`` file       :func:`odofuse.io.bags.read_bag`
``*.pyfg``, or a text file whose first      :func:`odofuse.io.pyfg.read_pyfg`
line names pyfg variables (``A0``, ``L0``)
``<prefix>_DR/TD/GT/TL.txt``                :func:`odofuse.io.plaza.read_plaza_text`
``*.mat`` (a Plaza ``<prefix>_.mat``)       :func:`odofuse.io.plaza.read_plaza_mat`
``*.g2o``, ``*.graph``, ``*.toro``, or a    :func:`odofuse.io.gtsam_text.read_gtsam_text`
text file whose first line is a pose-graph  (g2o, TORO and iSAM line types; 3-D types are
tag                                         refused by name)
==========================================  ================================================

``log.repair`` (CSV folders only, :func:`odofuse.io.csvlog.read_csv_log`) is refused for other
kinds of log rather than ignored.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from odofuse.errors import ConfigError, InputError
from odofuse.io.log import SensorLog, Stream

BAG_SUFFIXES = (".db3", ".mcap", ".bag")
GRAPH_SUFFIXES = (".g2o", ".graph", ".toro")


def log_kind(path: Path) -> str:
    """``"csv"``, ``"bag"``, ``"pyfg"``, ``"plaza"``, ``"mat"`` or ``"gtsam"`` for a path.

    Raises InputError for a path that does not exist or whose format is not recognised.
    """
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
    if suffix == ".mat":
        return "mat"
    from odofuse.io.gtsam_text import looks_like_gtsam_text
    from odofuse.io.plaza import is_plaza_text
    from odofuse.io.pyfg import looks_like_pyfg

    if looks_like_pyfg(path):
        return "pyfg"
    if is_plaza_text(path):
        return "plaza"
    if suffix in GRAPH_SUFFIXES or looks_like_gtsam_text(path):
        return "gtsam"
    raise InputError(
        "unknown log format (expected a CSV log folder, .db3/.mcap/.bag, a 2-D pose-graph "
        "text file (g2o, TORO, iSAM, pyfg) or Plaza <name>_DR/TD.txt or <name>_.mat)",
        str(path),
    )


def load_log(
    spec: str | Path,
    base_dir: str | Path | None = None,
    *,
    encoder: dict | None = None,
    topics: dict | None = None,
    repair: dict | None = None,
    joints: dict | None = None,
    groundtruth: bool = True,
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
    repair : dict, optional
        CSV repair policy ``{sort: bool, duplicates: str}`` (:data:`odofuse.io.csvlog.REPAIR`).
    joints : dict, optional
        ``{drive input: JointState joint name}`` for bags.
    groundtruth : bool
        False: the log comes without ground truth (a CSV folder's ``groundtruth.csv`` is not
        even read; other formats drop it after reading).

    Returns
    -------
    SensorLog
    """
    log = _load_log(spec, base_dir, encoder, topics, repair, joints, groundtruth)
    return log if groundtruth else dataclasses.replace(log, groundtruth=None)


def _load_log(spec, base_dir, encoder, topics, repair, joints, groundtruth) -> SensorLog:
    s = str(spec)
    if s.startswith("builtin:"):
        from odofuse.io.builtin import load_builtin

        if repair:
            raise InputError("log.repair applies to CSV log folders only", s)
        return load_builtin(s)
    path = Path(s).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    kind = log_kind(path)
    if kind == "csv":
        from odofuse.io.csvlog import read_csv_log

        return read_csv_log(path, encoder=encoder, repair=repair, groundtruth=groundtruth)
    if repair:
        raise InputError("log.repair applies to CSV log folders only", str(path))
    if kind == "bag":
        from odofuse.io.bags import read_bag

        return read_bag(path, topics=topics, joints=joints)
    if kind == "pyfg":
        from odofuse.io.pyfg import read_pyfg

        return read_pyfg(path)
    if kind == "plaza":
        from odofuse.io.plaza import read_plaza_text

        return read_plaza_text(path)
    if kind == "mat":
        from odofuse.io.plaza import read_plaza_mat

        return read_plaza_mat(path)
    from odofuse.io.gtsam_text import read_gtsam_text

    return read_gtsam_text(path)


def load_log_for(config, groundtruth: bool = True) -> SensorLog:
    """Load the log named by a :class:`odofuse.config.RunConfig` (its encoder block and topics).

    When the robot has an ``encoder`` block without ``columns``, the encoder columns of
    ``wheels.csv`` are the drive's inputs of kind ``"wheel"`` (steering angles stay radians).
    With ``log.wheel_inputs: velocity`` those columns hold wheel speeds (rad/s; ticks/s with
    an encoder block; JointState ``velocity`` in a bag) and are integrated once here into
    cumulative angles, see :func:`integrate_wheel_velocities`. ``groundtruth=False``: see
    :func:`load_log`.
    """
    robot = dict(config.robot or {})
    options = config.log_options or {}
    encoder = robot.get("encoder")
    if encoder is not None:  # the typed robot.encoder block as the mapping the readers take
        encoder = {**dataclasses.asdict(encoder), "columns": list(encoder.columns or [])}
    velocity = options.get("wheel_inputs") == "velocity"
    cols = None
    if (encoder and not encoder.get("columns")) or velocity:
        from odofuse.drives import make_drive

        geometry = {k: v for k, v in robot.items() if k not in ("drive", "encoder")}
        drive = make_drive(robot["drive"], **geometry)
        kinds = getattr(drive, "input_kinds", ("wheel",) * len(drive.input_names))
        cols = [n for n, k in zip(drive.input_names, kinds, strict=True) if k == "wheel"]
    if encoder and not encoder.get("columns"):
        encoder = {**encoder, "columns": cols}
    if velocity and not config.log.startswith("builtin:") and log_kind(Path(config.log)) == "bag":
        raise ConfigError(
            "bags: JointState velocity is read (and integrated) by itself when position is "
            "empty; leave log.wheel_inputs out",
            config.source,
            "log.wheel_inputs",
        )
    if velocity and encoder and encoder.get("rollover"):
        raise ConfigError(
            "encoder.rollover unwraps counter positions; wheel speeds cannot roll over",
            config.source,
            "log.wheel_inputs",
        )
    log = load_log(
        config.log,
        encoder=encoder,
        topics=options.get("topics"),
        repair=options.get("repair"),
        joints=options.get("joints"),
        groundtruth=groundtruth,
    )
    if velocity and "wheels" in log.streams:
        wheels = integrate_wheel_velocities(log.streams["wheels"], cols)
        log = dataclasses.replace(log, streams={**log.streams, "wheels": wheels})
    from odofuse.io.plausibility import check_log

    log = configured_streams(log, config)
    return check_log(log, config, **options.get("limits", {}))


#: Model kinds that fix the pose in the world (what the run has left when one goes missing).
ABSOLUTE_KINDS = ("gps", "compass", "range", "bearing", "range_bearing")


def configured_streams(log: SensorLog, config) -> SensorLog:
    """A sensor the config names is used or explained: one without data in ``log`` is an error.

    The error names the key (``sensors.gps``) and what was looked for (``LOG/gps.csv``, a
    topic, a stream of a built-in dataset). A block with ``optional: true`` makes it a
    finding in ``log.findings`` instead, which degrades the run when no other absolute
    sensor (:data:`ABSOLUTE_KINDS`) of the config has data.
    """
    from odofuse.status.findings import Finding

    missing = [s for s in config.sensors if not (log.has(s) and len(log.streams[s]))]
    if not missing:
        return log
    notes = []
    for stream in missing:
        looked = _looked_for(log, config, stream)
        opts = config.sensors[stream]
        if not getattr(opts, "optional", False):
            have = ", ".join(sorted(log.streams)) or "none"
            raise ConfigError(
                f"configured, but the log has no data for it: {looked} (streams in the log: "
                f"{have}); add the data, remove the block, or mark it optional: true",
                config.source,
                f"sensors.{stream}",
            )
        left = [
            s
            for s, o in config.sensors.items()
            if s not in missing and getattr(o, "kind", "") in ABSOLUTE_KINDS
        ]
        absolute = getattr(opts, "kind", "") in ABSOLUTE_KINDS
        alone = absolute and not left
        notes.append(
            Finding(
                "missing",
                f"sensors.{stream} is optional and not in the log ({looked}): not used"
                + ("; no other absolute sensor is left, the position drifts" if alone else ""),
                sensor=stream,
                degrades=alone,
            )
        )
    old = tuple(getattr(log, "findings", ()) or ())
    return dataclasses.replace(log, findings=old + tuple(notes))


def _looked_for(log: SensorLog, config, stream: str) -> str:
    """Where the data of ``stream`` would have come from, for the messages."""
    spec = str(config.log)
    if spec.startswith("builtin:"):
        return f"{spec} has no stream '{stream}'"
    path = Path(spec)
    if path.is_dir() and log_kind(path) == "csv":
        return f"{path / (stream + '.csv')} not found"
    topics = (config.log_options or {}).get("topics") or {}
    if stream in topics:
        return f"no messages on topic {topics[stream]} in {spec}"
    return f"no '{stream}' stream in {spec}"


def integrate_wheel_velocities(stream: Stream, columns) -> Stream:
    """Wheel speeds -> cumulative wheel angles, one backward rectangle per row interval.

    Row ``k+1``'s speed is taken as the speed during the step from ``t_k`` to ``t_{k+1}``
    (the convention of the steering columns, and ros2_controllers' ``update_from_velocity``,
    which multiplies the latest measured speed by the period):
    ``theta_{k+1} = theta_k + omega_{k+1} (t_{k+1} - t_k)``, ``theta_0 = 0``. The first row's
    speed is therefore unused. Other columns (steering angles) are unchanged.

    Parameters
    ----------
    stream : Stream
        ``wheels`` with speeds in rad/s in ``columns``.
    columns : sequence of str
        The wheel columns (the drive's inputs of kind ``"wheel"``); missing ones are left to
        the estimators' column check.

    Returns
    -------
    Stream
        A new stream; the same times and columns.
    """
    values = stream.values.copy()
    dt = np.diff(stream.t)
    for name in columns:
        if name in stream.columns:
            j = stream.columns.index(name)
            values[0, j] = 0.0
            values[1:, j] = np.cumsum(stream.values[1:, j] * dt)
    return Stream(stream.name, stream.source, stream.t, stream.columns, values)
