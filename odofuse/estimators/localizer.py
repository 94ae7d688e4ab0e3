"""Streaming localisation: the event loop shared by the EKF, UKF and particle filter.

A :class:`Localizer` takes one reading at a time (:meth:`Localizer.add_odometry`,
:meth:`Localizer.add_measurement`) and answers "where am I now" (:meth:`Localizer.pose`,
:meth:`Localizer.covariance`). The offline ``run(log, config)`` of every filter only feeds the
log's rows to a Localizer in time order, so the offline and the online result are the same by
construction.

Time handling
-------------
An odometry row ``(t_k, u_k)`` is the increment since the previous row (``odometry.csv``, the
Plaza ``DR`` stream) or the step between two ``wheels.csv`` rows. A measurement at ``t_m``
waits until the odometry that covers it arrives; the step ``(t_{k-1}, t_k]`` is then split at
every waiting measurement time, each part predicted with the input scaled by its time
fraction (the increment is spread uniformly over the step), and the measurement applied at
its own time. A measurement older than the filter time (late) rolls the filter back to the
stored state before the step that covers it and replays the following steps, provided it is
at most ``late_window`` seconds old; older ones are counted (``extra["dropped_late"]``) and
dropped.

Frames (ROS REP-105, as in ``001_8aaeb0868ac55f59.txt``: odometry as a sensor): ``odom_pose``
is the continuous wheel-odometry pose in the ``odom`` frame (never jumps); ``pose`` is the
filtered pose in ``map``; ``map_to_odom`` is the correction ``T_map_odom = T_map_base (+)
T_odom_base^-1`` that a ROS node would broadcast.

Gyro
----
A ``gyro`` stream is used either as a measurement (``GyroYawRate``, through a cloned heading
state) or, with ``gyrodometry: true`` and ``threshold`` (rad per odometry step) in its sensor
block, as gyrodometry (``002_88fc37db58155723.txt``): over each odometry step the gyro heading
change ``Delta_gyro`` (zero-order hold of the latest rate) replaces the wheel heading change
``Delta_odo`` when ``|Delta_gyro - Delta_odo| > threshold``.

Backends implement ``predict(u, dt, dtheta=None, var_dtheta=0.0)``,
``update(model, row) -> (accepted, nis)``, ``clone(dst, src)``, ``snapshot()``,
``restore(snap)``, ``mean() -> (n,)`` and ``cov() -> (n, n)``.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping

import numpy as np

from odofuse import se2
from odofuse.declarations import DEFAULT_LATE_WINDOW, EkfOptions
from odofuse.errors import ConfigError, InputError
from odofuse.estimators import inputs
from odofuse.estimators.common import (
    augmented_prior,
    calibration_of,
    events,  # noqa: F401 - re-exported
    gyrodometry_of,
    state_layout,
)
from odofuse.estimators.history import (
    Step,
    Steps,
    Track,
    held_rate_integral,
    keep_rate_sample,
)
from odofuse.status import findings as H
from odofuse.status import monitors
from odofuse.status.drift import drift_of, seen_by_ekf
from odofuse.status.mde import inert_findings, mde_of
from odofuse.status.pose_checks import collapse_findings, covariance_health
from odofuse.status.slip import slip_note, step_slip_scale
from odofuse.status.streaming import whiten
from odofuse.trajectory import EstimateResult, Trajectory

#: Odometry inputs composed into the ``odom`` pose at once (vectorised dead reckoning).
_ODOM_BATCH = 512
#: A live Localizer keeps this many readings per stream for its monitor (at least 4 NIS
#: windows), trimmed every ``_TRIM_EVERY`` steps, so its memory stays flat.
_KEEP_READINGS, _TRIM_EVERY = 1000, 4096


#: :meth:`Localizer.health` re-runs its checks over the kept poses every this many odometry
#: steps (poses: the steps a late reading's replay re-does are not counted again).
HEALTH_TRACK_EVERY = 1024
#: The checks over the kept poses whose episodes outlive the poses (:func:`_past_episodes`).
_TRACK_EPISODES = frozenset({"covariance", "covariance_growth", "collapse"})
#: Findings that describe the filter as it is now (the others, episodes of the run so far).
_CURRENT = frozenset({"calibration", "dropped", "rejected"})

#: Key of the odometry-calibration states in the layout (not a measurement stream).
ODOMETRY_CALIBRATION = "__odometry_calibration__"


class Localizer:
    """Streaming estimator: feed readings one at a time, ask for the pose at any moment.

    Parameters
    ----------
    backend : object
        A filter backend (``EkfBackend``, ``UkfBackend``, ``ParticleBackend``).
    models : dict
        Stream name -> bound measurement model (see :mod:`odofuse.measurements`).
    t0 : float
        Time of the initial state, s.
    late_window : float
        How old (s, behind the filter time) a measurement may be and still be applied.
    gyrodometry : tuple (stream, threshold, sigma) or None
        Use that stream's rates (rate noise ``sigma``, rad/s) for gyrodometry with the
        switching ``threshold`` (rad per odometry step) instead of as a measurement.
    name : str
        Estimator name for the result.
    options : odofuse.declarations.FilterOptions, optional
        Monitor, recovery and slip options (defaults: :class:`~odofuse.declarations.EkfOptions`).
    keep_trajectory : bool
        Keep every pose for :meth:`trajectory` and :meth:`result` (an offline run). With
        False (a live Localizer, :meth:`from_config`'s default) only the poses of the late
        window are kept, so memory stays flat however long it runs; the trajectory, the
        result and the covariance checks of :meth:`health` then cover that window.
    """

    def __init__(
        self,
        backend,
        models: Mapping[str, object],
        t0: float,
        late_window: float = DEFAULT_LATE_WINDOW,
        gyrodometry=None,
        name: str = "filter",
        motion_model=None,
        options=None,
        keep_trajectory: bool = True,
    ) -> None:
        if not late_window >= 0.0:
            raise ValueError(f"late_window must be >= 0 s, got {late_window}")
        self.backend = backend
        self.models = dict(models)
        self.name = name
        self.late_window = float(late_window)
        self.motion_model = motion_model if motion_model is not None else backend.model
        self._increment = getattr(backend, "increment", self.motion_model.increment)
        self.t = float(t0)
        self.t_start = float(t0)
        self._seq = 0
        # Readings of equal time are applied in the config's stream order (as an offline run's
        # events are), then in arrival order: a reading that arrives late takes the place it
        # would have had on time, whatever else arrived at its stamp meanwhile.
        self._rank = {s: k for k, s in enumerate(self.models)}
        self._pending: list[tuple[float, tuple[int, int], str, dict]] = []
        self._steps = Steps(self.late_window)
        self._book = None  # bookkeeping snapshot, shared by the steps while it holds
        self.used = {s: 0 for s in self.models}
        self.rejected = {s: 0 for s in self.models}
        self.dropped_late = {s: 0 for s in self.models}
        self._t_ref: dict[str, float] = {}
        gyro = gyrodometry or (None, math.inf, 0.0)
        self._gyro_stream, self._gyro_threshold, self._gyro_sigma = gyro
        self._gyro: list[tuple[float, float]] = []  # (t, wz) samples, time-sorted
        self.gyro_switches = 0
        self.options = options if options is not None else EkfOptions()
        self.monitor = monitors.FilterMonitor(self.options, self.models)
        monitors.setup_localizer(self)  # recovery indices, slip stream
        self.monitor.drift = drift_of(self)  # the calibration drift check (EKF, UKF)
        x = backend.mean()
        self._track = Track(self.t, x, backend.cov(), keep_all=keep_trajectory)
        self._odom = x[:3].copy()
        self._odom_u: list[np.ndarray] = []  # inputs not yet composed into _odom
        self._input_names = tuple(self.motion_model.drive.input_names)
        self._duplicates = inputs.Duplicates(self.late_window)
        self._x_probe = np.zeros_like(x)  # any state of the right length, for input checks
        self._watch, self._fate = None, inputs.USED
        self._last_row: dict[str, dict] = {}  # each stream's last applied reading (its MDE)
        self._last_step = None  # (u, span) of the last odometry step (a clone stream's MDE)
        self._z_span: dict[str, tuple] = {}  # each stream's reading range (min, max)
        self._slow = (-math.inf, [], None)  # health(): (pose count, findings, time), track checks
        self._version = 0  # readings applied or dropped: health() recomputes what they change
        # health(): (that version, its findings, failing streams, test and NIS ratios)
        self._fast = (None, [], [], {}, {}, {})
        #: A live particle filter's EKF of the same config, fed the same readings, whose
        #: calibration drift check it carries (:meth:`from_config`); None otherwise.
        self.companion: Localizer | None = None

    @classmethod
    def from_config(
        cls,
        config,
        t0: float,
        landmarks=None,
        estimator: str | None = None,
        initial_pose=None,
        keep_trajectory: bool = False,
    ) -> Localizer:
        """A live Localizer from a run config, without a log.

        Parameters
        ----------
        config : RunConfig
            Robot, motion, sensors, ``initial`` and ``options`` as for an offline run.
        t0 : float
            Time of the initial state, s (the first odometry row covers ``(t0, t_1]``).
        landmarks : dict, optional
            Beacon/landmark id -> ``(2,)`` world position, for range/bearing sensors.
        estimator : str, optional
            ``"ekf"``, ``"ukf"`` or ``"particle"`` (default ``config.estimator``).
        initial_pose : array_like (3,), optional
            Start pose when ``config.initial`` has none.
        keep_trajectory : bool
            Keep every pose (see the class); by default only the late window's, so a live
            Localizer's memory stays flat.
        """
        import importlib
        from types import SimpleNamespace

        name = estimator or config.estimator
        if name not in ("ekf", "ukf", "particle"):
            raise ConfigError(
                f"no streaming backend for estimator '{name}'; use ekf, ukf or particle",
                config.source,
                "estimator",
            )
        module = importlib.import_module(f"odofuse.estimators.{name}")
        pose = None if initial_pose is None else np.asarray(initial_pose, dtype=float)
        src = SimpleNamespace(landmarks=dict(landmarks or {}), initial_pose=pose, streams={})
        loc = assemble(config, name, module.make_backend, t0, src, keep_trajectory)
        if hasattr(module, "live"):  # the EKF: the compiled core's kernels, as `odofuse run`'s
            module.live(loc)
        if name == "particle" and config.estimator_options("cross_check").smoother != "off":
            # Offline a particle run carries the drift check of an EKF of its log
            # (odofuse.status.cross_check.COMPANION); live, an EKF runs beside it.
            ekf = cls.from_config(config, t0, landmarks, "ekf", initial_pose)
            loc.companion = ekf if ekf.monitor.drift is not None else None
        return loc

    # ----------------------------------------------------------------- queries
    def pose(self) -> np.ndarray:
        """Filtered pose ``[x, y, theta]`` (map frame) at :attr:`t`."""
        return self.backend.mean()[:3].copy()

    def covariance(self) -> np.ndarray:
        """Pose covariance (3, 3), world frame."""
        return self.backend.cov()[:3, :3].copy()

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Full state (pose + augmented states) and its covariance."""
        return self.backend.mean().copy(), self.backend.cov().copy()

    def odom_pose(self) -> np.ndarray:
        """Continuous wheel-odometry pose in the ``odom`` frame (REP-105), never corrected."""
        if self._odom_u:
            self._compose_odom()
        return self._odom.copy()

    def map_to_odom(self) -> np.ndarray:
        """``T_map_odom = T_map_base (+) inverse(T_odom_base)`` as ``[x, y, theta]``."""
        return se2.compose(self.pose(), se2.inverse(self.odom_pose()))

    def calibration(self) -> dict[str, dict[str, float]]:
        """Current estimate and sigma of every augmented state that is not a clone."""
        odo = getattr(self.backend, "odo_cal", None)
        return calibration_of(self.models, odo, self.backend.mean(), self.backend.cov())

    # ----------------------------------------------------------------- inputs
    def add(self, stream: str, row: Mapping[str, float]) -> str:
        """Feed one row of any measurement stream (``row`` holds ``t`` and the columns)."""
        return self.add_measurement(stream, row)

    def add_measurement(self, stream: str, row: Mapping[str, float]) -> str:
        """:meth:`_add_measurement`, and the same row to the :attr:`companion`."""
        fate = self._add_measurement(stream, row)
        if self.companion is not None:
            self.companion.add_measurement(stream, row)
        return fate

    def _add_measurement(self, stream: str, row: Mapping[str, float]) -> str:
        """Queue one measurement row; it is applied once odometry reaches its time.

        A measurement at or before the filter time triggers a replay from the step that covers
        it (within ``late_window``) or is dropped. The reading is checked first
        (:mod:`odofuse.estimators.inputs`): an unknown stream, a missing, non-numeric,
        non-finite or out-of-range value is an :class:`~odofuse.errors.InputError` naming the
        stream, the time and the field; an exact repeat of a reading (same ``t``, ``id`` and
        values) is dropped and counted (``extra["duplicates"]``), as the CSV loader does.

        Returns ``"used"``/``"rejected"`` (gate) when applied now or by a replay, ``"buffered"``
        while it waits for odometry, ``"dropped"`` when older than the late window,
        ``"duplicate"`` (see :data:`odofuse.estimators.inputs.USED` and the others).
        """
        known = set(self.models) | ({self._gyro_stream} - {None})
        t, row = inputs.check_row(stream, row, known)
        if self._duplicates.check(stream, t, row, self.t):
            return inputs.DUPLICATE
        if stream == self._gyro_stream:
            if "wz" not in row:
                raise InputError(f"stream '{stream}' at t={t:.6f}: no column 'wz'", column="wz")
            self._add_gyro_sample(row)
            return inputs.USED
        if stream == self._slip_stream and "wz" in row:
            self._store_gyro(t, row["wz"])
        z = inputs.check_measurement(stream, self.models[stream], t, row, self._x_probe)
        span = self._z_span.get(stream)
        if span is None:
            self._z_span[stream] = (z.copy(), z.copy())
        elif z.shape == span[0].shape:
            np.minimum(span[0], z, out=span[0])
            np.maximum(span[1], z, out=span[1])
        item = (t, (self._rank[stream], self._seq), stream, row)
        self._seq += 1
        if t > self.t:
            bisect.insort(self._pending, item)
            return inputs.BUFFERED
        self._watch, self._fate = item[1], inputs.USED
        try:
            steps = self._steps
            if not steps and self.t == self.t_start and t >= self.t - self.late_window:
                # Before the first odometry step: applied to the initial state as it is.
                self._apply(item)
            elif (
                t < self.t - self.late_window
                or t <= self.t_start
                or not steps
                or t <= steps.first().t0
            ):
                self.dropped_late[stream] += 1
                self._version += 1
                return inputs.DROPPED
            else:
                self._replay_with(item)
            return self._fate
        finally:
            self._watch = None

    def add_odometry(self, t: float, u) -> str:
        """Process one odometry step ``(t_prev, t]`` with drive input ``u`` (n,); returns "used".

        Checked as a reading is (one number per drive input); an exact repeat of the previous
        step is dropped (``"duplicate"``), another input at the same time is an error.
        """
        t, u = inputs.check_odometry(t, u, self._input_names)
        if not t >= self.t:
            raise InputError(
                f"odometry time {t:.6f} is before the filter time {self.t:.6f}", column="t"
            )
        if self._duplicates.odometry(t, u):
            return inputs.DUPLICATE
        if self.companion is not None:
            self.companion.add_odometry(t, u)
        due = []
        while self._pending and self._pending[0][0] <= t:
            due.append(self._pending.pop(0))
        self._last_step = (u, t - self.t)
        self._process_step(self.t, t, u, due)
        self._odom_u.append(u)
        if len(self._odom_u) >= _ODOM_BATCH:
            self._compose_odom()
        return inputs.USED

    def _compose_odom(self) -> None:
        """Dead-reckon the waiting inputs onto the ``odom`` pose (the shared motion model)."""
        from odofuse.motion import dead_reckon

        compose = getattr(self.backend, "compose_odom", None)  # the compiled core's, if any
        if compose is None:
            U = self._odom_u
            self._odom = dead_reckon(self.motion_model, self._odom, None, U, with_cov=False)[0][-1]
        else:
            self._odom = compose(self._odom, self._odom_u)
        self._odom_u.clear()

    def _store_gyro(self, t: float, wz: float) -> None:
        keep_rate_sample(self._gyro, t, wz, self.t - self.late_window - 1.0)

    def _add_gyro_sample(self, row) -> None:
        t = float(row["t"])
        self._store_gyro(t, float(row["wz"]))
        if t <= self.t and self._steps and t > self._steps.first().t0:
            self._replay_with(None, since=t)

    # ----------------------------------------------------------------- core
    def _gyro_increment(self, t0: float, t1: float) -> float | None:
        """Heading change over (t0, t1] from the gyro rates (zero-order hold), None if none."""
        return held_rate_integral(self._gyro, t0, t1)

    def _process_step(self, t0, t1, u, due) -> None:
        keep = self.late_window > 0
        if keep:
            snap = self.backend.snapshot()
            book = self._book
            if book is None:
                book = self._book = self._bookkeeping()
            n_traj = len(self._track)
        dtheta_gyro = None
        if self._gyro_stream is not None:
            g = self._gyro_increment(t0, t1)
            if g is not None:
                d_odo = float(self._increment(u)[0][2])
                if abs(g - d_odo) > self._gyro_threshold:
                    dtheta_gyro = g
                    self.gyro_switches += 1
                    self._book = None
        # Gyro heading increment variance: a rate noise sigma (rad/s) held over the step.
        var_g = (self._gyro_sigma * (t1 - t0)) ** 2 if dtheta_gyro is not None else 0.0
        scale = 1.0
        if self._slip_stream is not None:
            slips = self.slip_steps
            scale = step_slip_scale(self, t0, t1, u)
            if self.slip_steps != slips:
                self._book = None
        span = t1 - t0
        done = 0.0
        for item in due:
            tm = item[0]
            f = 1.0 if span <= 0.0 else min(max((tm - t0) / span, done), 1.0)
            if f > done:
                self._predict(
                    u * (f - done), span * (f - done), dtheta_gyro, f - done, var_g, scale
                )
                done = f
            self._apply(item)
        if not due:  # the common case: one prediction over the whole step
            self._predict(u, span, dtheta_gyro, 1.0, var_g, scale)
        elif done < 1.0:
            self._predict(
                u * (1.0 - done), span * (1.0 - done), dtheta_gyro, 1.0 - done, var_g, scale
            )
        track = self._track
        if keep:
            steps = self._steps
            steps.push(Step(t0, t1, u, snap, book, tuple(due), n_traj))
            track.forget_before(steps.first().n_traj)
        else:  # nothing can be replayed: only the newest pose matters
            track.forget_before(len(track))
        if not track.keep_all and len(track) % _TRIM_EVERY == 0:
            self._forget_readings()
        self.t = t1
        track.append(t1, self.backend.mean(), self.backend.cov())
        drift = self.monitor.drift
        if drift is not None and t1 >= drift.next_t:
            drift.observe(t1, self.backend.mean(), np.diagonal(self.backend.cov()))
            self._book = None  # the monitor's snapshot changed

    def _predict(self, u, dt, dtheta_gyro, frac, var_g, scale=1.0) -> None:
        kw = {} if scale == 1.0 else {"noise_scale": scale}
        if dtheta_gyro is not None:
            kw.update(dtheta=dtheta_gyro * frac, var_dtheta=var_g * frac)
        self.backend.predict(u, dt, **kw)

    def _apply(self, item) -> None:
        tm, _, stream, row = item
        self._version += 1
        self._book = None  # counts, clone times and the monitor change below
        model = self.models[stream]
        clones = model.clones() if hasattr(model, "clones") else {}
        if clones:
            t_ref = self._t_ref.get(stream)
            if t_ref is None or tm <= t_ref:
                self._t_ref[stream] = tm
                self._clone(model, clones)
                return
            row = dict(row)
            row["dt"] = tm - t_ref
        self._last_row[stream] = row
        accepted, nis = self.backend.update(model, row)
        white = whiten(*self.backend.last_innovation[:2]) if accepted else None
        if self.monitor.observe(stream, tm, accepted, nis, white):
            accepted, nis = monitors.recover(self, stream, model, row)
        if item[1] == self._watch:
            self._fate = inputs.USED if accepted else inputs.REJECTED
        if accepted:
            self.used[stream] += 1
        else:
            self.rejected[stream] += 1
        if clones:
            self._t_ref[stream] = tm
            self._clone(model, clones)

    def note_readings(self, stream: str, rows, t_seen, z) -> None:
        """Record readings of ``stream`` applied without :meth:`add_measurement` (the compiled
        offline EKF): the last one (its innovation covariance gives the MDE) and the span of
        the values.

        Parameters
        ----------
        rows : odofuse.io.log.Stream
            The log's stream.
        t_seen : ndarray (n,)
            Times of the stream's readings the filter saw, in order (clone-only ones too).
        z : ndarray (m, >= dim)
            The values of those it applied (the model's ``z`` in the first ``dim`` columns).
        """
        model = self.models[stream]
        z = np.asarray(z, dtype=float)[:, : int(model.dim)]
        if len(z) == 0 or len(t_seen) == 0:
            return
        self._z_span[stream] = (z.min(axis=0), z.max(axis=0))
        t_last = float(t_seen[-1])
        row = dict(rows.row(int(np.flatnonzero(rows.t == t_last)[-1])))
        if model.clones() if hasattr(model, "clones") else {}:
            if len(t_seen) < 2:
                return
            row["dt"] = t_last - float(t_seen[-2])
        self._last_row[stream] = row

    def _clone(self, model, clones) -> None:
        index = getattr(model, "calib_index", {})
        for s, src in clones.items():
            if s in index:
                self.backend.clone(index[s], src)

    def _forget_readings(self) -> None:
        """Live mode: the monitor keeps its last readings only (memory flat over a long run)."""
        keep = max(_KEEP_READINGS, 4 * int(self.options.nis_window))
        books = self._steps.books()
        tokens = monitors.forget_readings(self.monitor, keep, [b[4] for b in books])
        new = {id(b): b[:4] + (tok,) + b[5:] for b, tok in zip(books, tokens, strict=True)}
        self._steps.rebook(lambda b: new[id(b)])
        self._book = None

    def _bookkeeping(self) -> tuple:
        """What a replay restores besides the backend (never mutated once taken)."""
        return (
            dict(self.used),
            dict(self.rejected),
            dict(self._t_ref),
            self.gyro_switches,
            self.monitor.snapshot(),
            self.slip_steps,
        )

    def _restore(self, step: Step) -> None:
        used, rejected, t_ref, switches, mon, slips = step.book
        self.backend.restore(step.backend)
        self.used, self.rejected, self._t_ref = dict(used), dict(rejected), dict(t_ref)
        self.gyro_switches = switches
        self.monitor.restore(mon)
        self.slip_steps = slips
        self._book = step.book  # the state is that bookkeeping again

    def _replay_with(self, item, since: float | None = None) -> None:
        """Roll back to the step covering the late item (or time ``since``) and replay.

        Costs the steps from there to now: at most one late window (O(window)).
        """
        t = item[0] if item is not None else since
        steps = self._steps.cut(t)
        self._restore(steps[0])
        self._track.truncate(steps[0].n_traj)
        self.t = steps[0].t0
        inserted = item is None
        for s in steps:
            due = list(s.due)
            if not inserted and item[0] <= s.t1:
                bisect.insort(due, item)
                inserted = True
            self._process_step(s.t0, s.t1, s.u, due)

    # ----------------------------------------------------------------- results
    def finish(self) -> None:
        """The end of the readings: count measurements still waiting for odometry (after the
        last step) as dropped, and let the innovation-mean scans evaluate their last windows
        (:meth:`~odofuse.status.monitors.FilterMonitor.end`)."""
        for _, _, stream, _ in self._pending:
            self.dropped_late[stream] += 1
        self._pending.clear()
        self.monitor.end()
        self._version += 1
        if self.companion is not None:
            self.companion.finish()

    def trajectory(self) -> Trajectory:
        """Filtered poses at the initial time and after every odometry step.

        Without ``keep_trajectory`` only the poses of the late window (and the one before it).
        """
        return Trajectory(*self._track.arrays())

    def result(self) -> EstimateResult:
        """The run's :class:`EstimateResult` (calibration, late drops, gyro switches in extra)."""
        extra = {
            "calibration": self.calibration(),
            "dropped_late": {s: n for s, n in self.dropped_late.items() if n},
            "map_to_odom": [float(v) for v in self.map_to_odom()],
        }
        if self._duplicates.count:
            extra["duplicates"] = dict(self._duplicates.count)
        if self._gyro_stream is not None:
            extra["gyrodometry_switches"] = int(self.gyro_switches)
        if self._slip_stream is not None:
            extra["slip_steps"] = int(self.slip_steps)
        extra["recoveries"] = len(self.monitor.recoveries)
        drift = self.monitor.drift
        if drift is not None:  # the largest |z| over its bound (odofuse.status.drift)
            extra["calibration_drift"] = {"ratio": drift.ratio(), "snapshots": len(drift)}
        mde = mde_of(self)
        extra["mde"] = mde
        extra.update(getattr(self.backend, "extra", lambda: {})())
        traj = self.trajectory()
        found = self._findings(traj.t, traj.covariances) + inert_findings(self, mde)
        return EstimateResult(
            self.name, traj, dict(self.used), dict(self.rejected), extra, tuple(found)
        )

    # ----------------------------------------------------------------- health
    def health(self) -> monitors.LiveHealth:
        """The filter's self-judgement so far (no ground truth): status, findings, test ratios.

        The offline run's checks, from the same code (docs/filters.md, "Live health"): the
        streaming checks of every sensor (test ratio, NIS windows with persistence and
        hysteresis, rejection runs, outage; O(1) per reading), recoveries, calibration
        bounds, the calibration drift check (EKF, UKF: a snapshot every ``drift_grid`` s; a
        particle filter carries its :attr:`companion` EKF's), rejected and dropped
        fractions, the current pose covariance; and the checks over the kept poses
        (covariance conditioning and growth, collapse, gyro-bias learning, inert gates),
        re-run every :data:`HEALTH_TRACK_EVERY` steps (a live Localizer keeps the late
        window's poses: a fixed cost). ``status`` is degraded
        while a check is failing now, ``run_status`` when any check failed in the run.
        """
        mon = self.monitor
        span = (self.t_start, self.t)
        drift = mon.drift
        key = (self._version, self.slip_steps, len(drift) if drift is not None else 0)
        comp = self.companion
        if comp is not None:  # the companion EKF's drift (a particle filter's, live)
            key += (comp._version, comp.slip_steps, len(comp.monitor.drift))
        if key != self._fast[0]:  # what only a reading, a slip or a drift snapshot changes
            fast = mon.stream_findings(span, outage=False) + slip_note(self)
            fast += drift.findings() if drift is not None else []
            if comp is not None and _companion_saw(comp.monitor):
                fast += seen_by_ekf(comp.health().findings)
            if mon._priors:
                fast += mon._calibration_findings(self.calibration())
            fast += inputs.dropped_findings(self.used, self.rejected, self.dropped_late, span)
            fast += H.rejection_findings(self.used, self.rejected, span)
            live = mon.live
            ratios = {s: live[s].ratio for s in live}, {s: live[s].wratio for s in live}
            means = {s: live[s].mratio for s in live}
            self._fast = (key, fast, mon.failing(), *ratios, means)
        _, fast, failing, test_ratios, nis_ratios, mean_ratios = self._fast
        fast = fast + mon.outage_findings(span)
        done, slow, t_slow = self._slow
        if len(self._track) >= done + HEALTH_TRACK_EVERY:
            t, _, P = self._track.arrays()
            slow = _past_episodes(slow, float(t[0]))
            slow += covariance_health(t, P, self.options)
            slow += collapse_findings(self, t, P) + monitors.learning_of(self, t)
            slow += inert_findings(self, mde_of(self))
            t_slow = float(t[-1])
            self._slow = (len(self._track), slow, t_slow)
        x, P_now = self.backend.mean()[:3], self.backend.cov()[:3, :3]
        now = []
        if not _plainly_fine(x, P_now):  # then the exact checks say what is wrong
            here = np.array([self.t])
            now = H.pose_findings(here, x[None]) + H.covariance_findings(here, P_now[None])
        # Now: a stream failing (persistence, hysteresis), a count or state that is bad as it
        # stands, or a finding whose span reaches the newest time its check saw.
        current = (
            failing
            or now
            or any(f.degrades and (f.check in _CURRENT or f.t_end == self.t) for f in fast)
            or any(f.degrades and f.t_end == t_slow for f in slow)
        )
        found = tuple(fast + slow + now)
        return monitors.LiveHealth(
            status="degraded" if current else "ok",
            run_status=H.status_of(found),
            findings=found,
            test_ratios=dict(test_ratios),  # copies: the caller may keep or change them
            nis_ratios=dict(nis_ratios),
            mean_ratios=dict(mean_ratios),
            t=self.t,
        )

    def _findings(self, t, P) -> list:
        span = (float(t[0]), float(t[-1])) if len(t) else (None, None)
        dropped = inputs.dropped_findings(self.used, self.rejected, self.dropped_late, span)
        return monitors.localizer_findings(self, t, P) + dropped


def _companion_saw(mon) -> bool:
    """Whether the companion EKF's monitor ``mon`` has something to tell (its drift check
    over its bound, or an innovation-mean scan that fired): its ``health()`` is read then."""
    return mon.drift.ratio() > 1.0 or any(st.mhits for st in mon.live.values())


def _past_episodes(findings, t0: float) -> list:
    """The findings of earlier passes over the kept poses about poses no longer kept (their
    span ends before ``t0``, the first kept pose's time), so that ``run_status`` and
    ``findings`` keep an episode after its poses are forgotten (as the offline run, which
    keeps every pose, reports it); the first such episode of each check and sensor (memory
    stays bounded). The other checks of the pass (learning, inert) read the whole run's
    records and are re-derived each pass."""
    out: dict = {}
    for f in findings:
        if f.check in _TRACK_EPISODES and f.t_end is not None and f.t_end < t0:
            out.setdefault((f.check, f.sensor), f)
    return list(out.values())


def _plainly_fine(x, P) -> bool:
    """True when pose ``x`` (3,) is finite and covariance ``P`` (3, 3) positive definite with
    its smallest eigenvalue above :data:`odofuse.status.findings.MIN_EIGEN_RATIO` of its largest
    (leading minors > 0, and ``det > ratio * trace^3`` bounds ``l_min / l_max`` from below);
    False says nothing (the exact checks then run). Scalar arithmetic: a few microseconds."""
    (a, b, c), (_, d, e), (_, _, f) = P.tolist()
    if not all(map(math.isfinite, x.tolist())) or not math.isfinite(a + b + c + d + e + f):
        return False
    m2 = a * d - b * b
    det = a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c)
    trace = a + d + f
    return a > 0.0 and m2 > 0.0 and det > H.MIN_EIGEN_RATIO * trace**3


# --------------------------------------------------------------------- building from config
def assemble(
    config, estimator: str, make_backend, t0: float, log=None, keep_trajectory: bool = True
) -> Localizer:
    """A :class:`Localizer` for ``config`` starting at time ``t0`` (s).

    ``log`` (optional) supplies the landmark map and the dataset's own start pose; for a live
    stream pass an object with ``landmarks`` (dict id -> (2,)) and ``initial_pose`` (or None),
    or nothing.

    Parameters
    ----------
    make_backend : callable
        ``make_backend(motion_model, models, x0, P0, walk, options) -> backend``; ``options``
        is the estimator's typed options (``config.estimator_options(estimator)``).
    """
    from types import SimpleNamespace

    from odofuse.estimators.common import initial_state
    from odofuse.estimators.odocal import filter_odometry_calibration
    from odofuse.measurements import measurement_models
    from odofuse.motion import motion_model_from_config

    if log is None:
        log = SimpleNamespace(landmarks={}, initial_pose=None, streams={})
    opts = config.estimator_options(estimator)
    motion = motion_model_from_config(config)
    pose0, P0 = initial_state(config, log)
    models = measurement_models(config, log)
    gyro = gyrodometry_of(config)
    # With gyrodometry the gyro feeds the prediction and is not a measurement model.
    filt = {s: m for s, m in models.items() if gyro is None or s != gyro[0]}
    _one_gyro(filt, config.source)
    # Odometry calibration states (odofuse.estimators.odocal) are laid out after the sensors'.
    odo = filter_odometry_calibration(motion, opts, f"options.{estimator}", config.source)
    extra = {} if odo is None else {ODOMETRY_CALIBRATION: odo}
    names, index = state_layout({**filt, **extra})
    filt = {s: (m.bind(index) if hasattr(m, "bind") else m) for s, m in filt.items()}
    extra = {k: m.bind(index) for k, m in extra.items()}
    x0, Pa, walk = augmented_prior({**filt, **extra}, names, pose0, P0)
    backend = make_backend(motion, filt, x0, Pa, walk, opts)
    backend.odo_cal = extra.get(ODOMETRY_CALIBRATION)
    late = opts.late_window
    if gyro is not None:
        gyro = (gyro[0], gyro[1], float(getattr(models["gyro"], "sigma", 0.0)))
    return Localizer(backend, filt, float(t0), late, gyro, estimator, motion, opts, keep_trajectory)


def _one_gyro(models, source) -> None:
    """Refuse a second yaw-rate stream: the filters' gyro model compares the heading with a
    cloned heading (``gyro_theta_ref``) and has one ``gyro_bias``, shared by name, so a second
    gyro would read the first one's clone over its own interval (silently wrong)."""
    from odofuse.measurements import GyroYawRate

    gyros = [s for s, m in models.items() if isinstance(m, GyroYawRate)]
    if len(gyros) > 1:
        raise ConfigError(
            f"the filters fuse one gyro stream ('{gyros[0]}'), not also '{gyros[1]}': use a "
            "graph estimator (smoother, isam2, fixed_lag), which fuses each, or drop the block",
            source,
            f"sensors.{gyros[1]}",
        )
