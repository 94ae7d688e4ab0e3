"""Compiled offline EKF: a whole log's event array through :func:`~.kernels.ekf_offline`.

The run is assembled exactly as the pure-Python one (:func:`odofuse.estimators.assembly.build`:
the same models, state layout, prior, random walks and odometry-calibration states), the log's
rows become flat arrays in the order the streaming Localizer would apply them (measurements
before the odometry step ending at their time, each step split at the measurement times), the
kernel runs the filter, and the Localizer is handed the outcome (trajectory, final state,
used/rejected/dropped counts, the monitor's per-reading NIS record) to build the same
:class:`~odofuse.trajectory.EstimateResult` and findings.

Covered (else :func:`unsupported` names the reason and the caller runs the Python path):
drives with ``twist = F u`` (differential, skid-steer, increments, omni, ...) with the
Siegwart error model (no ``alphas``), every integrator, odometry calibration of the
increments/differential/skid-steer drives, and the built-in ``BeaconRange``,
``GpsPosition`` (``x``, ``y`` columns, or ``lat``, ``lon`` with a ``datum``, converted by
the model), ``CompassHeading`` and ``GyroYawRate`` models (with their calibration and clone
states, per-row ``sigma``), and robust odometry (``slip`` with a gyro). Not covered:
gyrodometry, landmark bearing and range-bearing, plug-in models, duplicated readings.
Recovery: the kernel does not re-open the filter; if the monitor says a recovery would have
been triggered, the whole run falls back to Python (so the result is always the Python one).

The streaming path: :func:`live` gives a live EKF Localizer a backend on the same kernels
(:func:`kernel_backend_class`), so online equals ``odofuse run`` bit for bit on the runs
:func:`run` covers (``docs/filters.md``, "Compiled core").
"""

from __future__ import annotations

import functools

import numpy as np

from odofuse import se2
from odofuse.declarations import INTEGRATORS
from odofuse.estimators import compiled
from odofuse.estimators.compiled.dead_reckoning import linear_terms
from odofuse.estimators.history import Track
from odofuse.status.pose_checks import record_learning_terms

_CAL_DRIVES = {"increments": 1, "differential": 2, "skid_steer": 2}
#: Stream kinds of the kernels (``kernels.RANGE`` ...; repeated here so that deciding
#: whether a run is covered does not import numba).
RANGE, GPS, COMPASS, GYRO = 0, 1, 2, 3


class _State:
    """Backend stand-in holding ``x``/``P`` for the Localizer that receives the result."""

    odo_cal = None

    def __init__(self, model, models, x0, P0, walk, options) -> None:
        self.model = model
        self.x = np.array(x0, dtype=float)
        self.P = np.array(P0, dtype=float)
        self.walk = np.asarray(walk, dtype=float)

    def mean(self) -> np.ndarray:
        return self.x

    def cov(self) -> np.ndarray:
        return self.P


def _kinds():
    from odofuse.measurements import BeaconRange, CompassHeading, GpsPosition, GyroYawRate

    return {BeaconRange: RANGE, GpsPosition: GPS, CompassHeading: COMPASS, GyroYawRate: GYRO}


def _symmetric_two_wheels(cal) -> bool:
    """One wheel a side and the track matrix of equal radii and ``y_l = -y_r``."""
    sym = np.array([[-0.5, 0.5], [0.5, -0.5]])
    return cal.wheels_per_side == 1 and np.allclose(cal.track, sym, rtol=0.0, atol=1e-12)


def unsupported(loc, log, streams) -> str | None:
    """Why this run cannot take the compiled path (None when it can)."""
    from odofuse.io.csvlog import MAX_MAGNITUDE

    if loc._gyro_stream is not None:
        return "gyrodometry"
    model = loc.motion_model
    if linear_terms(model) is None:
        return f"drive '{model.drive.name}' or its error model is not linear in u"
    cal = loc.backend.odo_cal
    if cal is not None and cal.drive not in _CAL_DRIVES:
        return f"odometry calibration of '{cal.drive}'"
    if cal is not None and cal.drive != "increments" and not _symmetric_two_wheels(cal):
        # the kernel's calibrated input reads (left, right) and Borenstein's half difference
        return "odometry calibration with several wheels a side, unequal radii or offset ICRs"
    kinds = _kinds()
    for s in streams:
        m = loc.models.get(s)
        if m is None or type(m) not in kinds:
            return f"stream '{s}' ({type(m).__name__})"
        st = log.streams[s]
        v = np.concatenate([st.t[:, None], st.values], axis=1) if len(st) else st.values
        if not (np.all(np.isfinite(v)) and np.all(np.abs(v) <= MAX_MAGNITUDE)):
            return f"stream '{s}' has non-finite or out-of-range values"
        cols = set(st.columns)
        kind = kinds[type(m)]
        need = {RANGE: {"id", "range"}, GPS: {"x", "y"}, COMPASS: {"heading"}, GYRO: {"wz"}}[kind]
        if kind == GPS and not need <= cols and m.datum is not None:
            need = {"lat", "lon"}  # converted by the model (_gps_values)
        if not need <= cols:
            return f"stream '{s}' lacks columns {sorted(need - cols)}"
        if kind == GYRO and "gyro_theta_ref" not in m.calib_index:
            return f"stream '{s}': no heading clone state"
        ids = st["id"] if "id" in cols else np.zeros(len(st))
        order = np.lexsort((ids, st.t))
        if len(st) > 1 and np.any((np.diff(st.t[order]) == 0) & (np.diff(ids[order]) == 0)):
            return f"stream '{s}' has repeated readings (same t and id)"
        if kind == RANGE:
            beacons = m._beacons
            if not all(int(round(i)) in beacons for i in np.unique(ids)):
                return f"stream '{s}' names a beacon that is not in the map"
    return None


def _measurements(loc, log, streams, t, kinds):
    """Flat measurement arrays in the Localizer's order, and the per-stream tables."""
    S = len(streams)
    skind = np.zeros(S, dtype=np.int64)
    sidx = np.full((S, 2), -1, dtype=np.int64)
    sgate = np.zeros(S)
    sR = np.zeros((S, 2, 2))
    mt, ms, mz, maux, mR = [], [], [], [], []
    for si, s in enumerate(streams):
        m = loc.models[s]
        st = log.streams[s]
        kind = kinds[type(m)]
        skind[si] = kind
        sgate[si] = loc.monitor.gates[s]
        d = m.dim
        sR[si, :d, :d] = m.R(None)
        ci = m.calib_index
        n = len(st)
        z = np.zeros((n, 2))
        aux = np.zeros((n, 2))
        if kind == RANGE:
            z[:, 0] = st["range"]
            b = m._beacons
            keys = np.array(sorted(b), dtype=np.int64)
            pos = np.array([b[i] for i in keys.tolist()], dtype=float).reshape(-1, 2)
            ids = np.rint(st["id"]).astype(np.int64)  # round(): half to even, as np.rint
            aux[:] = pos[np.searchsorted(keys, ids)] if n else aux
            sidx[si] = ci.get("range_scale", -1), ci.get("range_offset", -1)
        elif kind == GPS:
            z[:] = _gps_values(m, st)
            aux[:] = m.lever_arm
        elif kind == COMPASS:
            z[:, 0] = se2.wrap(st["heading"])
            sidx[si, 0] = ci.get("compass_offset", -1)
        else:
            z[:, 0] = st["wz"]
            sidx[si] = ci["gyro_theta_ref"], ci.get("gyro_bias", -1)
        r = np.square(st["sigma"]) if "sigma" in st.columns else np.full(n, np.nan)
        mt.append(st.t)
        ms.append(np.full(n, si, dtype=np.int64))
        mz.append(z)
        maux.append(aux)
        mR.append(r)
    cat = np.concatenate
    mt = cat(mt) if mt else np.zeros(0)
    order = np.argsort(mt, kind="stable")  # events(): by time, then stream order, then row
    ms, mz, maux, mR = (cat(a)[order] if a else np.zeros((0,)) for a in (ms, mz, maux, mR))
    mt = mt[order]
    return (
        mt,
        ms.astype(np.int64),
        mz.reshape(-1, 2),
        maux.reshape(-1, 2),
        mR,
        (skind, sidx, sgate, sR),
    )


def _gps_values(model, st) -> np.ndarray:
    """A GPS stream's east/north values (n, 2): its ``x``, ``y``, or each row's ``lat``,
    ``lon`` through the model's own conversion (``GpsPosition.z``), as the Python path reads
    them."""
    if {"x", "y"} <= set(st.columns):
        return np.column_stack([st["x"], st["y"]])
    return np.array([model.z(st.row(i)) for i in range(len(st))]).reshape(-1, 2)


def _record(mon, stream: str, t, ok, nis, white) -> bool:
    """Feed one stream's gated updates to the monitor, as ``FilterMonitor.observe`` would one
    by one; True when a recovery would have been triggered (a run of ``reject_run``
    rejections with recovery on). ``white`` (n, 2): each accepted reading's whitened
    innovation (the kernels' ``_whiten``; its first ``dim`` columns are the stream's). Fills
    the monitor's record arrays directly when they are the ``array`` buffers it keeps (the
    equality tests compare the findings), else calls ``observe`` per reading."""
    from array import array

    opts = mon.options
    k = int(opts.reject_run)
    if opts.recovery and k >= 1 and ok.size >= k:
        bad = np.concatenate([[0], np.cumsum(~ok)])
        if np.any(bad[k:] - bad[:-k] == k):
            return True
    bufs = (getattr(mon, "_t", {}).get(stream), getattr(mon, "_nis", {}).get(stream))
    oks = getattr(mon, "_ok", {}).get(stream)
    if all(isinstance(b, array) and b.typecode == "d" for b in bufs) and isinstance(oks, array):
        bufs[0].frombytes(np.ascontiguousarray(t, dtype=float).tobytes())
        v = np.where(np.isfinite(nis), nis, 1e300)
        bufs[1].frombytes(v.astype(float).tobytes())
        oks.frombytes(ok.astype(np.int8).tobytes())
        wy = getattr(mon, "_white", {}).get(stream)
        if wy is not None:
            wy.frombytes(np.ascontiguousarray(white[:, : mon.dims[stream]]).tobytes())
        return False
    d = mon.dims[stream]
    for tj, okj, nj, wj in zip(t.tolist(), ok.tolist(), nis.tolist(), white, strict=True):
        if mon.observe(stream, tj, okj, nj, tuple(wj[:d].tolist())):
            return True
    return False


def _motion_args(model, cal) -> tuple:
    """The kernels' motion model: ``(integrator code, M, K, floor, rate, odometry-calibration
    drive code, its state indices)`` of ``model`` (:func:`linear_terms`) and ``cal`` (the
    filter's odometry calibration, or None), shared by :func:`run` and :func:`live`."""
    M, K, floor, rate = (np.ascontiguousarray(a, dtype=float) for a in linear_terms(model))
    code = 0 if cal is None else _CAL_DRIVES[cal.drive]
    cidx = np.asarray(cal.index if cal is not None else (), dtype=np.int64)
    return INTEGRATORS.index(model.integrator), M, K, floor, rate, code, cidx


def prepare(log, config, estimator: str = "ekf"):
    """``(kernels, loc, streams, args)`` of the compiled offline EKF (or UKF, ``estimator``,
    :mod:`.ukf`), or None when the run is not covered: ``args`` are the arguments of
    :func:`~.kernels.ekf_offline` by name (in its order), the Localizer ``loc`` receives the
    outcome (:func:`finish`). Also used by :mod:`odofuse.tune`, which adds rejected probe
    readings to the measurement arrays to read each update's innovation covariance."""
    from odofuse.estimators.assembly import build

    opts = config.estimator_options(estimator)
    key = f"options.{estimator}.compiled"
    kern = compiled.enabled(getattr(opts, "compiled", "auto"), key)
    if kern is None:
        return None
    loc, t, U = build(config, log, estimator, _State)
    streams = [s for s in config.sensors if s in log.streams]
    t = np.asarray(t, dtype=float)
    U = np.ascontiguousarray(U, dtype=float)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(U))) or np.any(np.diff(t) < 0):
        return None
    if len(t) > 2 and np.any(t[2:] == t[1:-1]):
        return None  # repeated odometry times: the Localizer's duplicate rules apply
    if unsupported(loc, log, streams) is not None:
        return None
    kinds = _kinds()
    mt, ms, mz, maux, mR, (skind, sidx, sgate, sR) = _measurements(loc, log, streams, t, kinds)
    t0 = t[0]
    late = loc.late_window
    # The step that applies each reading: the first step ending at or after it; readings at
    # or before the start are applied to the initial state when inside the late window.
    mstep = np.searchsorted(t[1:], mt, side="left").astype(np.int64)
    at_start = mt <= t0
    mstep[at_start] = -1
    keep = ~(at_start & (mt < t0 - late)) & (mstep < len(U))
    dropped = ~keep
    for si, s in enumerate(streams):
        loc.dropped_late[s] += int(np.count_nonzero(dropped & (ms == si)))
    mt, ms, mstep, mz, maux, mR = (a[keep] for a in (mt, ms, mstep, mz, maux, mR))
    integ, M, K, floor, rate, cal_code, cidx = _motion_args(loc.motion_model, loc.backend.odo_cal)
    x, P = loc.backend.x.copy(), loc.backend.P.copy()
    N = len(U)
    traj_x, traj_P = np.empty((N + 1, 3)), np.empty((N + 1, 3, 3))
    odom = loc._odom.copy()
    acc = np.zeros(len(mt), dtype=np.int8)
    nis = np.zeros(len(mt))
    wy = np.full((len(mt), 2), np.nan)
    snap_k = snapshot_steps(t, loc.monitor.drift)
    snap_x, snap_v = np.empty((len(snap_k), len(x))), np.empty((len(snap_k), len(x)))
    args = dict(
        x=x, P=P, walk=loc.backend.walk, tt=t, U=U, integ=integ,
        M=M, K=K, floor=floor, rate=rate,
        cal=cal_code, cidx=cidx, mt=mt, ms=ms, mstep=mstep, mz=np.ascontiguousarray(mz),
        maux=np.ascontiguousarray(maux), mR=mR, skind=skind, sidx=sidx, sgate=sgate, sR=sR,
        traj_x=traj_x, traj_P=traj_P, odom=odom, acc=acc, nis=nis, wy=wy,
        snap_k=snap_k, snap_x=snap_x, snap_v=snap_v, **_slip_args(kern, loc, log, t),
    )  # fmt: skip
    return kern, loc, streams, args


def _slip_args(kern, loc, log, t) -> dict:
    """Robust odometry's arguments of the kernel (``slip_g`` ... ``learn`` of
    :func:`~.kernels.filter_offline`): each step's gyro heading change from the slip stream's
    rates held as the Localizer holds them (``history.held_rate_integral``: every reading of
    the stream, in time order, is known when the step ending at or after it runs); ``slip_g``
    None when robust odometry is off."""
    N = len(t) - 1
    stream = loc._slip_stream
    if stream is None:
        return dict(
            slip_g=None, slip=np.zeros(3), bias_idx=-1,
            slip_out=np.zeros(0), learn=np.zeros((0, 3)),
        )  # fmt: skip
    st = log.streams[stream]
    order = np.argsort(st.t, kind="stable")
    g = np.empty(N)
    kern.held_rate_steps(st.t[order], np.ascontiguousarray(st["wz"][order]), t, g)
    return dict(
        slip_g=g,
        slip=loc._slip_params,
        bias_idx=-1 if loc._bias_idx is None else int(loc._bias_idx),
        slip_out=np.ones(N),
        learn=np.full((N, 3), np.nan),
    )


def _record_slip(loc, t, scale, learn) -> None:
    """The Localizer's robust-odometry record after the kernel (``slip.step_slip_scale``
    step by step): the slipping steps, the longest run of consecutive ones (the first of
    equal length) and the ``learning`` check's heading and bias covariance terms."""
    slipping = scale > 1.0
    loc.slip_steps += int(np.count_nonzero(slipping))
    if slipping.any():
        d = np.diff(np.concatenate([[0], slipping.astype(np.int8), [0]]))
        first, end = np.flatnonzero(d == 1), np.flatnonzero(d == -1)  # steps [first, end)
        length = t[end] - t[first]
        k = int(np.argmax(length))
        a, b = loc._slip_longest
        if length[k] > b - a:
            loc._slip_longest = (float(t[first[k]]), float(t[end[k]]))
    if loc._bias_idx is not None:
        for k in np.flatnonzero(~np.isnan(learn[:, 0])).tolist():
            record_learning_terms(loc._bias_record, float(t[k]), *learn[k].tolist())


def snapshot_steps(t, drift) -> np.ndarray:
    """The steps (indices into the ``t[1:]`` step ends) after which the streaming Localizer
    takes a snapshot of the calibration states for ``drift``
    (:class:`odofuse.status.drift.Drift`: the first step, then the first ending at least
    ``drift.grid`` s after the last snapshot); empty without a drift check."""
    if drift is None or len(t) < 2:
        return np.zeros(0, dtype=np.int64)
    ends = np.asarray(t[1:], dtype=float)
    out, k = [], 0
    while k < len(ends):
        out.append(k)
        k = max(int(np.searchsorted(ends, ends[k] + drift.grid, side="left")), k + 1)
    return np.asarray(out, dtype=np.int64)


def run(log, config):
    """The compiled offline EKF, or None when the run is not covered (see module doc)."""
    prep = prepare(log, config)
    if prep is None:
        return None
    kern, loc, streams, args = prep
    kern.ekf_offline(*args.values())
    return finish(loc, log, streams, args)


def finish(loc, log, streams, args):
    """The Localizer ``loc`` of :func:`prepare` handed the kernel's outcome ``args``: the
    monitor's record, counts, readings, final state, trajectory and odometry pose; its
    result, or None when a recovery would have re-opened the filter (the Python path then
    runs)."""
    t, mt, ms, acc, nis = (args[k] for k in ("tt", "mt", "ms", "acc", "nis"))
    for si, s in enumerate(streams):
        mine = ms == si
        sel = mine & (acc != 2)  # clone-only first gyro readings are not counted
        ok = acc[sel] == 1
        if _record(loc.monitor, s, mt[sel], ok, nis[sel], args["wy"][sel]):
            return None  # a recovery would re-open the filter: the Python path does that
        loc.used[s] += int(np.count_nonzero(ok))
        loc.rejected[s] += int(ok.size - np.count_nonzero(ok))
        loc.note_readings(s, log.streams[s], mt[mine], args["mz"][sel])  # its MDE (metrics)
    loc.backend.x, loc.backend.P = args["x"], args["P"]
    if len(args["U"]):  # the last step, as Localizer.add_odometry keeps it (a gyro's MDE)
        loc._last_step = (args["U"][-1], float(t[-1] - t[-2]))
    drift = loc.monitor.drift
    for k, xs, vs in zip(args["snap_k"], args["snap_x"], args["snap_v"], strict=True):
        drift.observe(float(t[k + 1]), xs, vs)
    if loc._slip_stream is not None:
        _record_slip(loc, t, args["slip_out"], args["learn"])
    loc._track = Track.from_arrays(t, args["traj_x"], args["traj_P"])
    loc._odom = args["odom"]
    loc.t = float(t[-1])
    loc.finish()  # the end of the readings, as for a fed Localizer (the scans' last windows)
    return loc.result()


# --------------------------------------------------------------------- the streaming path
def slip_step(self, u, span, g, run, slip, bias_idx, learn) -> tuple[float, float]:
    """A kernel backend's ``slip_step``: ``slip.step_slip_scale``'s factor and run of one
    step in the kernel :func:`run` uses (:func:`~.kernels.step_slip`), on the backend's
    state; ``learn`` (3,) receives the ``learning`` terms when ``bias_idx`` is not None."""
    _, M, K, floor, rate = self._motion_args[:5]
    b = -1 if bias_idx is None else int(bias_idx)
    u = np.ascontiguousarray(u, dtype=float)
    kf = self.kf
    return self._kern.step_slip(kf.x, kf.P, u, span, g, M, K, floor, rate, slip, b, run, learn)


def compose_odom(self, odom, U) -> np.ndarray:
    """A kernel backend's ``compose_odom``: the ``odom`` pose (3,) after the steps ``U``
    (N, m), as :func:`run` composes it."""
    integ, M = self._motion_args[:2]
    odom = np.array(odom, dtype=float)
    self._kern.odom_steps(odom, np.ascontiguousarray(U, dtype=float), integ, M)
    return odom


@functools.cache
def kernel_backend_class(base):
    """:class:`KernelEkfBackend` over ``base`` (``EkfBackend``, the Python backend it stands in
    for; passed in so that this module imports neither it nor filterpy)."""

    class KernelEkfBackend(base):
        """:class:`~odofuse.estimators.ekf.EkfBackend` whose odometry predictions and gated
        updates run the kernels of :func:`run` (:func:`.kernels.ekf_predict_step`,
        :func:`.kernels.ekf_update_row`), in place on ``kf.x`` (n,) and ``kf.P`` (n, n).

        A live Localizer on it (:func:`live`) computes what ``odofuse run`` computes with the
        compiled core, bit for bit, on every run that :func:`run` covers. What the kernels do
        not cover runs the Python methods: a prediction with a gyro heading (gyrodometry),
        a row without the kernel's columns (a range without ``id``), the
        innovation a recovery reads.
        """

        def predict(self, u, dt, dtheta=None, var_dtheta=0.0, noise_scale=1.0) -> None:
            if dtheta is not None:
                super().predict(u, dt, dtheta, var_dtheta, noise_scale)
                return
            kf, (integ, M, K, floor, rate, cal, cidx) = self.kf, self._motion_args
            self._kern.ekf_predict_step(
                kf.x, kf.P, u, dt, integ, M, K, floor, rate, cal, cidx, self.walk,
                float(noise_scale),
            )  # fmt: skip

        def update(self, model, row) -> tuple[bool, float]:
            args = _update_args(self._kinds.get(type(model)), model, row)
            gate = self._gates.get(id(model))
            if args is None or gate is None:
                return super().update(model, row)
            self._pending = (model, row)
            kf = self.kf
            nis, ok = self._kern.ekf_update_row(kf.x, kf.P, *args, gate, self._out)
            return bool(ok), float(nis)

        compose_odom = compose_odom
        slip_step = slip_step

        last_innovation = kernel_innovation

    return KernelEkfBackend


def _kernel_innovation(self):
    """``(y, S, R)`` of a kernel backend's last update: the kernel's (``self._out``: ``y0, y1,
    s00, s10, s11``), or the Python method's when it ran; read by a recovery and by the
    innovation-mean scan."""
    if self._pending is None:
        return self._innovation
    model, row = self._pending
    y0, y1, s00, s10, s11 = self._out.tolist()
    R = np.atleast_2d(model.R(row))
    if model.dim == 1:
        return np.array([y0]), np.array([[s00]]), R
    return np.array([y0, y1]), np.array([[s00, s10], [s10, s11]]), R


def _set_innovation(self, value) -> None:
    self._innovation, self._pending = value, None


#: ``last_innovation`` of the kernel backends (EKF, UKF).
kernel_innovation = property(_kernel_innovation, _set_innovation)


def _update_args(kind, model, row):
    """``ekf_update_row``'s arguments for one row, as :func:`_measurements` and
    ``kernels._apply`` build them, or None when the kernel does not cover the row."""
    ci = model.calib_index
    s = row.get("sigma")
    if s is None:  # the stream's R, as _measurements' sR
        R = model.R(None)
        r00, r01, r11 = float(R[0, 0]), 0.0, 0.0
        if R.shape[0] == 2:
            r01, r11 = float(R[0, 1]), float(R[1, 1])
    else:
        r00 = r11 = float(s) * float(s)
        r01 = 0.0
    if kind == RANGE and "id" in row and "range" in row:
        b = model._beacons.get(int(round(float(row["id"]))))
        if b is None:
            return None
        i0, i1 = ci.get("range_scale", -1), ci.get("range_offset", -1)
        return RANGE, float(row["range"]), 0.0, b[0], b[1], r00, r01, r11, i0, i1, 0.0
    if kind == GPS and (("x" in row and "y" in row) or ("lat" in row and "lon" in row)):
        lx, ly = model.lever_arm
        e, n = model.z(row).tolist()
        return GPS, e, n, lx, ly, r00, r01, r11, -1, -1, 0.0
    if kind == COMPASS and "heading" in row:
        z = float(se2.wrap(float(row["heading"])))
        i0 = ci.get("compass_offset", -1)
        return COMPASS, z, 0.0, 0.0, 0.0, r00, r01, r11, i0, -1, 0.0
    if kind == GYRO and "wz" in row and "dt" in row:
        i0, i1 = ci["gyro_theta_ref"], ci.get("gyro_bias", -1)
        return GYRO, float(row["wz"]), 0.0, 0.0, 0.0, r00, r01, r11, i0, i1, float(row["dt"])
    return None


def live(loc) -> None:
    """Give the EKF Localizer ``loc`` the compiled step kernels when ``odofuse run`` would
    use the compiled core for its sensors (``options.ekf.compiled``, numba importable, the
    drive, error model, calibration and models covered: :func:`unsupported`); else leave its
    Python backend. Equal to the offline run bit for bit on the runs :func:`run` covers."""
    swap_backend(loc, "ekf", "EkfBackend", kernel_backend_class)


def swap_backend(loc, estimator: str, base: str, make_class):
    """Replace the Python backend (class named ``base``) of the live ``estimator`` Localizer
    ``loc`` by ``make_class(its class)``, holding the same state, when the compiled core
    covers its config (:func:`live`); returns the new backend, or None when it is kept."""
    mode = getattr(loc.options, "compiled", "off")
    if loc.name != estimator or type(loc.backend).__name__ != base or mode == "off":
        return None
    kinds = _kinds()
    models = loc.models.values()
    if unsupported(loc, None, []) is not None or any(type(m) not in kinds for m in models):
        return None
    if any(kinds[type(m)] == GYRO and "gyro_theta_ref" not in m.calib_index for m in models):
        return None
    kern = compiled.enabled(mode, f"options.{estimator}.compiled")
    if kern is None:
        return None
    backend = object.__new__(make_class(type(loc.backend)))
    backend.__dict__.update(loc.backend.__dict__)
    backend._motion_args = _motion_args(loc.motion_model, backend.odo_cal)
    backend._kern, backend._kinds, backend._pending = kern, kinds, None
    backend._innovation, backend._out = None, np.zeros(5)
    backend.kf.x = np.ascontiguousarray(backend.kf.x, dtype=float)
    backend.kf.P = np.ascontiguousarray(backend.kf.P, dtype=float)
    loc.backend = backend
    return backend
