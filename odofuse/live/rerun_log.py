"""``odofuse run CONFIG --rerun``: the run as a Rerun recording, ``trajectory.rrd`` beside
``trajectory.mcap`` (rerun-sdk; open it with ``rerun trajectory.rrd``).

Written from the finished run folder (``trajectory.csv``, ``metrics.json``) and the log, on the
timeline ``time`` (the log's seconds):

* ``world/trajectory``: the whole estimate as one line (static), ``world/estimate`` the pose
  at each time (a point and a heading arrow);
* ``world/covariance``: the 95 % position ellipse at most :data:`MAX_ELLIPSES` times;
* ``world/gps``: the raw GPS fixes (local ``x, y``, or ``lat, lon`` expressed about the run's
  datum, without the lever arm), ``world/landmarks`` the known map (static);
* ``status/degraded``: how many degrading findings cover each time, and ``status/findings``
  a text entry per finding at its start.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from odofuse.live.foxglove_view import ellipse_points

#: Ellipses drawn over a run (evenly spaced poses).
MAX_ELLIPSES = 500


def _gps_points(config, log, metrics):
    out = {}
    for name, s in log.streams.items():
        if not name.startswith("gps") or not len(s):
            continue
        if {"x", "y"} <= set(s.columns):
            out[name] = (s.t, np.column_stack([s["x"], s["y"]]))
        elif {"lat", "lon"} <= set(s.columns):
            import pymap3d

            block = config.sensors.get(name)
            datum = getattr(block, "datum", None)
            datum = datum or (metrics.get("log_defaults") or {}).get(f"sensors.{name}.datum")
            if not datum:
                continue
            h0 = float(datum[2]) if len(datum) > 2 else 0.0
            e, n, _ = pymap3d.geodetic2enu(s["lat"], s["lon"], h0, datum[0], datum[1], h0)
            out[name] = (s.t, np.column_stack([e, n]))
    return out


def write_rerun(path, traj, config, log, metrics: dict) -> Path:
    """Write the recording (see the module doc) to ``path``; returns it."""
    import rerun as rr

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")  # renamed into place when complete
    rec = rr.RecordingStream("odofuse", recording_id=f"odofuse-{path.parent.name}")
    rec.save(str(tmp))
    P = traj.covariances
    xy = np.asarray(traj.poses[:, :2], dtype=float)
    rec.log("world/trajectory", rr.LineStrips2D([xy], colors=[(30, 120, 220)]), static=True)
    if log.landmarks:
        pts = np.array([np.asarray(p, dtype=float)[:2] for p in log.landmarks.values()])
        labels = [str(k) for k in log.landmarks]
        rec.log("world/landmarks", rr.Points2D(pts, labels=labels, radii=0.2), static=True)
    every = max(1, math.ceil(len(traj) / MAX_ELLIPSES))
    findings = [f for f in metrics.get("findings", []) if f.get("t_start") is not None]
    starts = np.array([f["t_start"] for f in findings if f.get("degrades")], dtype=float)
    ends = np.array(
        [
            f["t_end"] if f.get("t_end") is not None else math.inf
            for f in findings
            if f.get("degrades")
        ],
        dtype=float,
    )
    for k in range(len(traj)):
        t = float(traj.t[k])
        rec.set_time("time", duration=t)
        x, y, th = (float(v) for v in traj.poses[k])
        rec.log("world/estimate", rr.Points2D([[x, y]], radii=0.1, colors=[(230, 60, 30)]))
        rec.log(
            "world/estimate/heading",
            rr.Arrows2D(origins=[[x, y]], vectors=[[0.5 * math.cos(th), 0.5 * math.sin(th)]]),
        )
        if P is not None and k % every == 0:
            ring = ellipse_points(traj.poses[k], P[k])
            rec.log("world/covariance", rr.LineStrips2D([np.vstack([ring, ring[:1]])]))
        active = int(np.count_nonzero((starts <= t) & (t <= ends))) if starts.size else 0
        rec.log("status/degraded", rr.Scalars([float(active)]))
    for name, (t, pts) in _gps_points(config, log, metrics).items():
        for tk, p in zip(t, pts, strict=True):
            rec.set_time("time", duration=float(tk))
            rec.log(f"world/{name}", rr.Points2D([p], radii=0.15, colors=[(255, 150, 0)]))
    for f in findings:
        rec.set_time("time", duration=float(f["t_start"]))
        level = "WARN" if f.get("degrades") else "INFO"
        text = f"[{f['check']}] {f.get('sensor') or ''}: {f['message']}"
        rec.log("status/findings", rr.TextLog(text, level=level))
    rec.flush()
    rec.disconnect()
    os.replace(tmp, path)
    return path
