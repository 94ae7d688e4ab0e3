"""``odofuse batch --split``: one long log cut into overlapping windows, smoothed, stitched.

This module owns the windowing (:func:`plan_windows`), the per-window run on a Dask worker
(:func:`smooth_window`) and the stitching (:func:`stitch`); :mod:`odofuse.batch.run` owns the
rest of the batch (names, resume, atomic output folders, the summary).

How a log is split and stitched (see ``docs/batch.md``):

1. The log's time span is cut into ``n`` equal *cores* ``[c_k, c_k+1]`` of at most ``split``
   seconds; window ``k`` is its core widened by ``overlap`` on each side (clipped to the log).
2. Every window runs the config's estimator on its own rows (:meth:`SensorLog.window`).
   Window 0 keeps the config's initial prior. A later window starts from the whole log's dead
   reckoning at its start with a loose prior (:data:`LOOSE_SIGMA`): it is not told where the
   previous window ended, so all windows run at once, and its own absolute sensors (GPS,
   ranges or landmarks on a known map) place it in the world frame.
3. A log without such sensors (odometry, gyro, compass only) has no world anchor inside a
   window; there each window is moved rigidly, in order, so that its pose at the seam time
   ``c_k`` equals the already stitched pose there (exact for pure odometry).
4. Stitching: each window contributes its poses inside its core; across the middle half of an
   overlap, ``[c_k - overlap/2, c_k + overlap/2]``, the pose is blended linearly from window
   ``k-1`` (weight 1 at the start) to window ``k`` (weight 1 at the end), the other window
   interpolated at the same time stamps. The stitched path is continuous at each seam, and the
   poses used stay at least ``overlap/2`` away from the edge of the window they come from,
   where a window misses the data beyond its edge. Covariances are blended with the same
   weights.
5. ``metrics.json`` gets ``extra.split``: the windows, and per seam the largest disagreement
   of the two windows over their common overlap (position, m; heading, rad) - the figure that
   says whether the overlap was long enough.
"""

from __future__ import annotations

import dataclasses
import math
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from odofuse import se2
from odofuse.trajectory import EstimateResult, Trajectory

#: Initial sigma ``[x, y, theta]`` (m, m, rad) of windows after the first: loose, so that the
#: window's own sensors, not the dead-reckoned guess, decide where it is.
LOOSE_SIGMA = (1.0e3, 1.0e3, math.pi)
#: Streams that fix a window in the world frame (with a known map for ranges/landmarks).
ANCHOR_STREAMS = ("gps", "ranges", "landmarks")
#: Default overlap as a fraction of the window duration.
DEFAULT_OVERLAP_FRACTION = 0.1


@dataclass(frozen=True)
class Window:
    """A window of a split log (s): it contributes its ``core``, it sees ``start..end``."""

    index: int
    start: float
    end: float
    core_start: float
    core_end: float


def log_span(log) -> tuple[float, float]:
    """First and last time stamp (s) over the log's streams."""
    ts = [(float(s.t[0]), float(s.t[-1])) for s in log.streams.values() if len(s)]
    if not ts:
        from odofuse.errors import InputError

        raise InputError("log has no rows", log.source)
    return min(a for a, _ in ts), max(b for _, b in ts)


def plan_windows(
    t0: float, t1: float, split: float, overlap: float, grid: float = 1.0
) -> list[Window]:
    """Equal cores of at most ``split`` s over ``[t0, t1]``, each widened by ``overlap`` s.

    Every edge lies on ``t0 + m * grid`` (whole seconds from the log's start by default), so
    that a window's keyframe-time grid (``keyframe_dt`` of the graph estimators, 1 s by
    default, from the window's first row) falls on the unsplit run's grid when the log's rows
    do; the last core ends at ``t1``.
    """
    if not (split > 0 and overlap >= 0 and grid > 0):
        raise ValueError("split and grid must be positive and overlap non-negative")
    span = (t1 - t0) / grid
    n = max(1, math.ceil((t1 - t0) / split - 1e-9))
    cuts = [round(span * k / n) for k in range(n)]
    if len(set(cuts)) < n:  # windows shorter than the grid: no split
        cuts, n = [0], 1
    o = math.ceil(overlap / grid - 1e-9)

    def at(m: float) -> float:
        return float(t0 + m * grid) if m < span else float(t1)

    return [
        Window(
            k,
            at(max(0, cuts[k] - o)),
            at(cuts[k + 1] + o) if k + 1 < n else float(t1),
            at(cuts[k]),
            at(cuts[k + 1]) if k + 1 < n else float(t1),
        )
        for k in range(n)
    ]


def is_anchored(config, log) -> bool:
    """Whether the config uses a stream that fixes a window in the world frame."""
    used = set(config.sensors or {}) & set(ANCHOR_STREAMS)
    for name in used:
        if not log.has(name):
            continue
        if name == "gps" or log.landmarks:
            return True
    return False


def window_config(config, window: Window, guess):
    """The config of one window: window 0 as given, a later one from ``guess`` (3,), loosely."""
    if window.index == 0:
        return config
    initial = {"pose": [float(v) for v in guess], "sigma": list(LOOSE_SIGMA)}
    return dataclasses.replace(config, initial=initial)


def smooth_window(config, log_window) -> tuple[EstimateResult | None, float, str | None]:
    """Run ``config``'s estimator on one window (on a worker): result, runtime (s), error."""
    from odofuse.estimators import run_estimator

    t0 = time.perf_counter()
    try:
        result = run_estimator(config.estimator, log_window, config)
    except Exception as exc:  # the window's log fails as one row with this message
        from odofuse.errors import one_line

        return None, time.perf_counter() - t0, one_line(exc)
    return result, time.perf_counter() - t0, None


def _transform(traj: Trajectory, T: np.ndarray) -> Trajectory:
    """``T (+) pose`` for every pose; covariances rotated by ``T``'s heading."""
    poses = se2.compose(T[None, :], traj.poses)
    covs = traj.covariances
    if covs is not None:
        R = np.eye(3)
        R[:2, :2] = se2.rot(T[2])
        covs = R @ covs @ R.T
    return Trajectory(traj.t, poses, covs)


def _interp_cov(traj: Trajectory, t: np.ndarray) -> np.ndarray | None:
    if traj.covariances is None:
        return None
    flat = traj.covariances.reshape(len(traj), 9)
    return np.stack([np.interp(t, traj.t, flat[:, j]) for j in range(9)], -1).reshape(-1, 3, 3)


def _half_zone(windows: list[Window], later: int) -> float:
    """Half width (s) of the blend zone at the seam before window ``later``: half the overlap."""
    a, b = windows[later - 1], windows[later]
    return 0.5 * min(b.core_start - b.start, a.end - a.core_end)


def stitch(
    trajs: list[Trajectory], windows: list[Window], anchored: bool
) -> tuple[Trajectory, list[dict]]:
    """One trajectory from the windows' trajectories (module docstring, steps 3 and 4).

    Returns
    -------
    trajectory : Trajectory
    seams : list of dict
        Per seam: ``t`` (s), ``max_position_diff_m`` and ``max_heading_diff_rad`` of the two
        windows over their common overlap (after the rigid move of an unanchored window).
    """
    from odofuse.trajectory import interpolate_poses

    moved = [trajs[0]]
    for k in range(1, len(trajs)):
        cur = trajs[k]
        if not anchored:
            c = np.array([windows[k].core_start])
            T = se2.compose(
                interpolate_poses(moved[-1], c)[0], se2.inverse(interpolate_poses(cur, c)[0])
            )
            cur = _transform(cur, T)
        moved.append(cur)
    has_cov = all(t.covariances is not None for t in moved)
    ts, ps, cs, seams = [], [], [], []
    last = len(moved) - 1
    for k, (traj, w) in enumerate(zip(moved, windows, strict=True)):
        keep = (traj.t >= w.core_start) & ((traj.t < w.core_end) | (k == last))
        t, p = traj.t[keep], traj.poses[keep].copy()
        c = traj.covariances[keep].copy() if has_cov else None
        for j, sign in ((k - 1, +1), (k + 1, -1)):  # blend with the neighbour across each seam
            if not 0 <= j <= last:
                continue
            seam = w.core_start if sign > 0 else w.core_end
            h = _half_zone(windows, max(j, k))
            zone = (t >= seam - h) & (t <= seam + h)
            if h <= 0 or not zone.any():
                continue
            weight_k = (t[zone] - (seam - h)) / (2 * h)  # weight of the later window
            weight_k = weight_k if sign > 0 else 1.0 - weight_k  # k is the earlier window
            other = interpolate_poses(moved[j], t[zone])
            mine = p[zone]
            p[zone] = np.column_stack(
                [
                    (1 - weight_k)[:, None] * mine[:, :2] + weight_k[:, None] * other[:, :2],
                    se2.wrap(mine[:, 2] + weight_k * se2.wrap(other[:, 2] - mine[:, 2])),
                ]
            )
            if c is not None:
                oc = _interp_cov(moved[j], t[zone])
                c[zone] = (1 - weight_k)[:, None, None] * c[zone] + weight_k[:, None, None] * oc
        ts.append(t)
        ps.append(p)
        if c is not None:
            cs.append(c)
    for k in range(1, len(moved)):
        a, b = moved[k - 1], moved[k]
        common = a.t[(a.t >= max(b.t[0], windows[k].start)) & (a.t <= min(b.t[-1], a.t[-1]))]
        if common.size:
            d = interpolate_poses(b, common) - interpolate_poses(a, common)
            pos, head = np.hypot(d[:, 0], d[:, 1]), np.abs(se2.wrap(d[:, 2]))
            seams.append(
                {
                    "t": windows[k].core_start,
                    "max_position_diff_m": float(pos.max()),
                    "max_heading_diff_rad": float(head.max()),
                }
            )
    covs = np.concatenate(cs) if has_cov else None
    return Trajectory(np.concatenate(ts), np.concatenate(ps), covs), seams


def _stitched_result(
    results: list[EstimateResult], windows, anchored: bool, runtimes
) -> EstimateResult:
    traj, seams = stitch([r.trajectory for r in results], windows, anchored)
    used: dict[str, int] = {}
    rejected: dict[str, int] = {}
    for r in results:
        for name, n in r.used.items():
            used[name] = used.get(name, 0) + int(n)
        for name, n in r.rejected.items():
            rejected[name] = rejected.get(name, 0) + int(n)
    extra = {
        "split": {
            "windows": [dataclasses.asdict(w) for w in windows],
            "anchored": anchored,
            "window_runtime_s": [float(x) for x in runtimes],
            "seams": seams,
            "counts": "sensor used/rejected are summed over windows: an overlap counts twice",
        }
    }
    return EstimateResult(results[0].estimator, traj, used, rejected, extra)


def _plan_log(config, spec: str, split: float, overlap: float):
    """Load one log on the client; its windows, their logs and configs, and whether anchored."""
    from odofuse.estimators import run_estimator
    from odofuse.io.loader import load_log_for
    from odofuse.trajectory import interpolate_poses

    cfg = dataclasses.replace(config, log=spec)
    log = load_log_for(cfg)
    windows = plan_windows(*log_span(log), split, overlap)
    anchored = is_anchored(cfg, log)
    guesses = np.zeros((len(windows), 3))
    if len(windows) > 1:
        dr = run_estimator("dead_reckoning", log, cfg).trajectory
        guesses = interpolate_poses(dr, [w.start for w in windows])
    parts = [
        (window_config(cfg, w, g), log.window(w.start, w.end))
        for w, g in zip(windows, guesses, strict=True)
    ]
    return cfg, log, windows, anchored, parts


def run_split_logs(client, config, specs, names, root: Path, split, overlap, force, progress):
    """``run_batch`` with ``split``: every window of every log on the cluster; stitched records.

    A log whose complete outputs exist is reused unless ``force``; a log that cannot be
    loaded, or one of whose windows fails, is one failed record.
    """
    from odofuse.batch.common import gather_records, is_complete, record
    from odofuse.errors import one_line
    from odofuse.rundir import finish_run

    overlap = DEFAULT_OVERLAP_FRACTION * split if overlap is None else overlap
    records: list = [None] * len(specs)
    plans: dict[int, tuple] = {}
    futures, order = [], {}
    for i, (spec, name) in enumerate(zip(specs, names, strict=True)):
        final = root / name
        if not force and is_complete(final):
            import json

            metrics = json.loads((final / "metrics.json").read_text(encoding="utf-8"))
            records[i] = record(spec, name, metrics, resumed=True)
            continue
        try:
            plans[i] = _plan_log(config, spec, split, overlap)
        except Exception as exc:  # an unreadable log is one failed row
            records[i] = record(spec, name, None, error=one_line(exc))
            continue
        cfg, _, windows, _, parts = plans[i]
        for w, (wcfg, wlog) in zip(windows, parts, strict=True):
            [wlog_future] = client.scatter([wlog])
            fut = client.submit(
                smooth_window,
                wcfg,
                wlog_future,
                key=f"odofuse-window-{name}-{w.index}-{uuid.uuid4().hex[:8]}",
                pure=False,
            )
            order[fut.key] = (len(futures), spec, name)
            futures.append(fut)
    outcome = gather_records(client, futures, order, "windows", progress) if futures else []
    k = 0
    for i, plan in plans.items():
        cfg, log, windows, anchored, _ = plan
        got = outcome[k : k + len(windows)]
        k += len(windows)
        spec, name = specs[i], names[i]
        bad = [
            (w.index, g.get("error") if isinstance(g, dict) else g[2])
            for w, g in zip(windows, got, strict=True)
            if isinstance(g, dict) or g[0] is None
        ]
        if bad:
            records[i] = record(spec, name, None, error=f"window {bad[0][0]}: {bad[0][1]}")
            continue
        try:  # finish_run writes root/name whole (odofuse.io.atomic)
            result = _stitched_result([g[0] for g in got], windows, anchored, [g[1] for g in got])
            cfg_out = dataclasses.replace(cfg, output=str(root / name))
            metrics = finish_run(cfg_out, log, result, max(g[1] for g in got), root / name)
        except Exception as exc:
            records[i] = record(spec, name, None, error=one_line(exc))
            continue
        records[i] = record(spec, name, metrics)
    return records
