"""``odofuse tune``: noise parameters learned from the log itself, never from ground truth.

This module owns the tuning criterion, the optimiser loop and the tuned config file.

Criterion: the EKF's prediction-error decomposition of the likelihood. For every measurement
update with innovation ``y`` and innovation covariance ``S`` (dimension ``d``) the log-likelihood
is ``-(log det(2 pi S) + y^T S^-1 y) / 2``; their sum over the updates is exactly the
log-likelihood of the measurements given the noise parameters (Gaussian, linearised). An
update rejected by the sensor's gate contributes with its NIS capped at the gate, so that
shrinking a sigma until readings are rejected does not pay (a trimmed likelihood, robust to
the outliers the gate is for).

Each evaluation runs the compiled offline EKF when it covers the log (:func:`compiled_innovations`:
rejected probe readings give each update's ``S``), else the Python one.

The parameters (dotted config keys such as ``motion.k[0]``, ``motion.k_theta_ds``,
``sensors.ranges.sigma``) are optimised in log space by Nelder-Mead on the first part of the
log (default two thirds, by time); the held-out rest is scored with the learned and the
starting values (mean log-likelihood per update, NIS per dimension per sensor, expected 1).
The uncertainty of each learned value is the inverse of the numerical Hessian of the negative
log-likelihood in log space (central differences), i.e. a relative 1-sigma.

Ground truth never enters: :func:`tune_config` loads the log with ``groundtruth=False`` (a
log folder's ``groundtruth.csv`` is not even opened) and :func:`tune` drops it from a log it
is given before anything else runs.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import re
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from odofuse.errors import ConfigError, one_line

#: Default share of the log (by time, from its start) the parameters are fitted on.
FIT_FRACTION = 2.0 / 3.0
#: Step of the numerical Hessian, in log-parameter units (a factor e^0.1 = 1.105).
HESSIAN_STEP = 0.1
#: Each value is searched within ``start / SPAN .. start * SPAN``: a value the likelihood
#: drives to a bound (within one Hessian step of it; towards 0: the log does not want that
#: noise) is reported as such instead of wandering in log space until the time bound.
SPAN = 1.0e3
_KEY = re.compile(r"^([A-Za-z_][\w]*(?:\.[A-Za-z_][\w]*)*)(?:\[(\d+)\])?$")


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """What :func:`tune` learned.

    Attributes
    ----------
    keys : tuple of str
        Dotted config keys tuned.
    start, values : tuple of float
        Starting and learned values (the keys' units).
    log_sigma : tuple of float or None
        1-sigma of ``log(value)`` from the inverse Hessian (None: not computed or not
        identifiable); ``value * exp(+-log_sigma)`` is the 1-sigma band.
    fit_loglik, start_fit_loglik : float
        Maximised figure: total innovation log-likelihood of the fitted part (learned, start).
    fit_updates : int
        Measurement updates in the fitted part.
    t_split : float
        End of the fitted part (s, log time); the held-out part is ``t > t_split``.
    heldout : dict
        ``{"learned": {...}, "start": {...}}``, each ``{"updates", "mean_loglik", "nis": {stream:
        NIS/dim}}`` on the held-out part.
    evaluations : int
        Filter runs done by the optimiser (and the Hessian).
    seconds : float
        Wall time of the whole tuning.
    stopped : str
        ``"converged"``, ``"time bound"`` or ``"evaluation bound"``.
    raw : dict
        The config mapping with the learned values (what :func:`write_tuned` writes).
    at_bound : tuple of str
        Per key ``""``, or ``"lower"``/``"upper"`` when the learned value sits at
        ``start / SPAN`` or ``start * SPAN`` (no uncertainty then; the others' is computed
        with it held there).
    failed : int
        Candidate runs that failed (an error of the filter, e.g. a covariance that
        overflowed): skipped, as if their likelihood were zero.
    failure : str
        The first failure: the candidate values and the one-line error.
    """

    keys: tuple
    start: tuple
    values: tuple
    log_sigma: tuple
    fit_loglik: float
    start_fit_loglik: float
    fit_updates: int
    t_split: float
    heldout: dict
    evaluations: int
    seconds: float
    stopped: str
    raw: dict
    at_bound: tuple = ()
    failed: int = 0
    failure: str = ""


class _Bound(Exception):
    """The time or evaluation bound was reached inside the objective."""


# --------------------------------------------------------------------------------------------
# Config keys
# --------------------------------------------------------------------------------------------


def _locate(raw: dict, key: str):
    """``(container, index)`` of the dotted ``key`` (``a.b`` or ``a.b[i]``) in ``raw``."""
    m = _KEY.match(key)
    if m is None:
        raise ConfigError(f"'{key}' is not a dotted key such as motion.k[0]", "odofuse tune")
    parts, index = m.group(1).split("."), m.group(2)
    node = raw
    for p in parts[:-1]:
        node = node.get(p) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            raise ConfigError("no such block in the config", "odofuse tune", key)
    last = parts[-1]
    if index is None:
        return node, last
    seq = node.get(last)
    if not isinstance(seq, list) or int(index) >= len(seq):
        raise ConfigError("not a list with that many entries in the config", "odofuse tune", key)
    return seq, int(index)


def get_value(raw: dict, key: str) -> float:
    """The positive number at ``key`` in the config mapping ``raw``."""
    node, i = _locate(raw, key)
    v = node.get(i) if isinstance(node, dict) else node[i]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
        raise ConfigError(
            "needs a positive number in the config to start from (tuning is in log space)",
            "odofuse tune",
            key,
        )
    return float(v)


def set_values(raw: dict, keys, values) -> dict:
    """A deep copy of ``raw`` with ``keys`` set to ``values`` (plain floats)."""
    out = copy.deepcopy(raw)
    for key, v in zip(keys, values, strict=True):
        node, i = _locate(out, key)
        node[i] = float(v)
    return out


def default_keys(raw: dict) -> list[str]:
    """The noise keys of a config that hold positive numbers: odometry ``k`` (each entry),
    ``k_r``, ``k_l``, ``k_theta_ds``, ``var_rate``, and every sensor's scalar ``sigma*``."""
    keys = []
    motion = raw.get("motion") or {}
    for name in ("k", "k_r", "k_l", "k_theta_ds", "var_rate"):
        v = motion.get(name)
        if isinstance(v, list):
            keys += [f"motion.{name}[{i}]" for i, x in enumerate(v) if _positive(x)]
        elif _positive(v):
            keys.append(f"motion.{name}")
    for stream, block in (raw.get("sensors") or {}).items():
        for name, v in (block or {}).items():
            if name.startswith("sigma") and _positive(v):
                keys.append(f"sensors.{stream}.{name}")
    return keys


def _positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0


# --------------------------------------------------------------------------------------------
# The criterion
# --------------------------------------------------------------------------------------------


def innovations(log, config) -> list[tuple[str, float, float, float, int, bool]]:
    """Run the EKF of ``config`` over ``log`` and return every measurement update.

    The compiled EKF (:func:`compiled_innovations`) when it covers the run, else the
    pure-Python one (:func:`python_innovations`); both give the same records (to rounding).

    Returns
    -------
    list of (stream, t, logdet, nis_capped, dim, accepted)
        One entry per measurement row (the last update of a row replayed after a late
        arrival or a recovery): ``logdet = log det(2 pi S)``, ``nis_capped =
        min(y^T S^-1 y, gate)``, ``dim`` its dimension.
    """
    cfg = dataclasses.replace(config, estimator="ekf")
    rec = compiled_innovations(log, cfg)
    return rec if rec is not None else python_innovations(log, cfg)


#: Offsets of the probe readings per measurement dimension, in units of the reading's
#: sigma: ``nis(y + a) + nis(y - a) - 2 nis(y) = 2 a^T S^-1 a`` for each ``a`` gives S^-1.
_PROBES = {1: np.array([[1.0, 0.0]]), 2: np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])}


def compiled_innovations(log, config):
    """:func:`innovations` through the compiled offline EKF, or None when it does not cover
    the run (a gyro stream, or anything :func:`odofuse.estimators.compiled.ekf.prepare`
    refuses).

    The kernel reports each update's NIS ``y^T S^-1 y`` but not ``S``. Before every reading
    of a stream, probe readings ``z +- a`` (``a`` from :data:`_PROBES` times the reading's
    sigma) of a copy of the stream whose gate rejects everything are inserted: rejected, they
    leave the filter untouched (same state, same covariance, same calibration states), and
    their NIS gives ``S^-1`` exactly (``nis(y+a) + nis(y-a) - 2 nis(y) = 2 a^T S^-1 a``).
    """
    from odofuse.estimators.compiled import ekf as cekf

    prep = cekf.prepare(log, config)
    if prep is None:
        return None
    kern, loc, streams, args = prep
    skind, sgate, sR, mR = args["skind"], args["sgate"], args["sR"], args["mR"]
    if np.any(skind == cekf.GYRO):
        return None  # a gyro reading moves its clone state even when rejected
    S = len(streams)
    dims = np.array([loc.models[s].dim for s in streams], dtype=np.int64)
    ms = args["ms"]
    var = np.where(np.isnan(mR), sR[ms, 0, 0], mR)
    delta = np.sqrt(np.where(var > 0, var, 1.0))
    # Per reading j: its probes (+a1, -a1, +a2, -a2, ...) then the real reading, all at the
    # same time and step; idx[j] = (real row, +a1 row, -a1 row, ...) in the new arrays.
    J = len(ms)
    idx = np.full((J, 1 + 2 * len(_PROBES[2])), -1, dtype=np.int64)
    order, offs, is_probe = [], [], []
    for j in range(J):
        a = _PROBES[int(dims[ms[j]])] * delta[j]
        block = [v for p in a for v in (p, -p)]
        base = len(order)
        order += [j] * (len(block) + 1)
        offs += block + [np.zeros(2)]
        is_probe += [True] * len(block) + [False]
        idx[j, : len(block) + 1] = np.r_[base + len(block), base + np.arange(len(block))]
    order = np.asarray(order, dtype=np.int64)
    probe = np.asarray(is_probe, dtype=bool)
    for k in ("mt", "mstep", "maux", "mR"):
        args[k] = np.ascontiguousarray(args[k][order])
    args["mz"] = np.ascontiguousarray(args["mz"][order] + np.asarray(offs))
    args["ms"] = np.where(probe, ms[order] + S, ms[order]).astype(np.int64)
    for k in ("skind", "sidx", "sR"):
        args[k] = np.ascontiguousarray(np.concatenate([args[k], args[k]]))
    args["sgate"] = np.concatenate([sgate, np.full(S, -1.0)])  # probes: always rejected
    args["acc"] = np.zeros(len(order), dtype=np.int8)
    args["nis"] = np.zeros(len(order))
    args["wy"] = np.full((len(order), 2), np.nan)
    kern.ekf_offline(*args.values())
    nis, acc = args["nis"], args["acc"]
    if np.any(acc[probe] != 0):
        return None
    mt = args["mt"]
    out = []
    real = idx[:, 0]
    for si, s in enumerate(streams):  # the monitor would trigger a recovery: Python path
        sel = ms == si
        r = real[sel]
        if cekf._record(loc.monitor, s, mt[r], acc[r] == 1, nis[r], args["wy"][r]):
            return None
    for j in range(J):
        d = int(dims[ms[j]])
        n0 = nis[idx[j, 0]]
        second = [
            (nis[idx[j, 1 + 2 * q]] + nis[idx[j, 2 + 2 * q]] - 2.0 * n0) / (2.0 * delta[j] ** 2)
            for q in range(len(_PROBES[d]))
        ]
        if d == 1:
            det_inv = second[0]
        else:
            a11, a22 = second[0], second[1]
            a12 = 0.5 * (second[2] - a11 - a22)
            det_inv = a11 * a22 - a12 * a12
        logdet = d * math.log(2.0 * math.pi) - math.log(det_inv) if det_inv > 0 else math.inf
        gate = float(sgate[ms[j]])
        nis_c = min(n0, gate) if math.isfinite(n0) else gate
        out.append((streams[ms[j]], float(mt[idx[j, 0]]), logdet, nis_c, d, acc[idx[j, 0]] == 1))
    return out


def python_innovations(log, config) -> list[tuple[str, float, float, float, int, bool]]:
    """:func:`innovations` through the pure-Python EKF (every run the compiled one refuses)."""
    from odofuse.estimators.assembly import run_with
    from odofuse.estimators.ekf import EkfBackend
    from odofuse.measurements import gate_threshold

    records: dict = {}
    names: dict = {}

    class Recording(EkfBackend):
        def update(self, model, row):
            ok, nis = super().update(model, row)
            S = np.atleast_2d(self.last_innovation[1])
            sign, logdet = np.linalg.slogdet(2.0 * math.pi * S)
            gate = gate_threshold(getattr(model, "gate", None), model.dim)
            nis_c = min(nis, gate) if math.isfinite(nis) else gate
            key = (id(model), tuple(row.items()))
            logdet = logdet if sign > 0 else math.inf
            records[key] = (names.get(id(model), "?"), row["t"], logdet, nis_c, model.dim, ok)
            return ok, nis

    def make(model, models, x0, P0, walk, options):
        names.update({id(m): s for s, m in models.items()})
        return Recording(model, models, x0, P0, walk, options)

    run_with(log, config, "ekf", make)
    return list(records.values())


def loglik(records, t_min: float = -math.inf, t_max: float = math.inf) -> tuple[float, int]:
    """Total innovation log-likelihood and number of updates with ``t_min < t <= t_max``."""
    total, n = 0.0, 0
    for _, t, logdet, nis, _, _ in records:
        if t_min < t <= t_max:
            total -= 0.5 * (logdet + nis)
            n += 1
    return total, n


def heldout_summary(records, t_split: float) -> dict:
    """``{"updates", "mean_loglik", "nis": {stream: mean NIS/dim}}`` of updates after
    ``t_split`` (NIS capped at the gate, expected 1 per dimension). ``records`` may be the
    exception of a run that failed: then ``{"updates": 0, ..., "error": one line}``."""
    if isinstance(records, BaseException):
        return {"updates": 0, "mean_loglik": None, "nis": {}, "error": one_line(records)}
    total, n = loglik(records, t_min=t_split)
    nis: dict = {}
    for s, t, _, v, d, _ in records:
        if t > t_split:
            nis.setdefault(s, []).append(v / d)
    return {
        "updates": n,
        "mean_loglik": total / n if n else None,
        "nis": {s: float(np.mean(v)) for s, v in sorted(nis.items())},
    }


# --------------------------------------------------------------------------------------------
# Tuning
# --------------------------------------------------------------------------------------------


def tune(
    config,
    raw: dict,
    log,
    keys=None,
    fit_fraction: float = FIT_FRACTION,
    max_seconds: float = 600.0,
    max_evaluations: int = 400,
    uncertainty: bool = True,
    progress=None,
    checkpoint=None,
) -> TuneResult:
    """Learn the noise parameters ``keys`` of ``config`` from ``log`` by maximum likelihood.

    Parameters
    ----------
    config : RunConfig
        The validated config (its estimator is ignored: the likelihood is the EKF's, with
        ``options.ekf`` when given).
    raw : dict
        The same config as the parsed YAML mapping; the learned values are written into a copy.
    log : SensorLog
        The log; its ground truth is dropped before anything runs.
    keys : sequence of str, optional
        Dotted keys to tune (default :func:`default_keys`).
    fit_fraction : float
        Share of the log's time span fitted (from the start); the rest is held out.
    max_seconds, max_evaluations : float, int
        Bounds of the optimiser (the held-out scoring runs after them).
    uncertainty : bool
        Compute the numerical Hessian (about ``2 p^2`` more filter runs for ``p`` keys).
    progress : callable, optional
        Called with one status line per filter run (default: a line on stderr).
    checkpoint : callable, optional
        Called as ``checkpoint(raw, lines)`` whenever the best candidate improves: the config
        mapping with its values and a few lines saying how far the tuning got (what
        :func:`tune_config` writes, so that a crash or an interrupt keeps the best so far).

    A candidate whose filter run raises is skipped (its likelihood taken as zero), counted in
    ``failed`` and reported; when every run fails, the first failure is raised. Each value
    stays within ``start / SPAN .. start * SPAN``, so the likelihood cannot run away.
    """
    from scipy.optimize import minimize

    from odofuse.config import config_from_dict

    log = dataclasses.replace(log, groundtruth=None)  # never seen from here on
    keys = tuple(keys or default_keys(raw))
    if not keys:
        raise ConfigError(
            "no positive noise value to tune (motion k, sensor sigmas)", config.source
        )
    if not 0.0 < fit_fraction < 1.0:
        raise ConfigError("must be between 0 and 1", "odofuse tune", "--fit-fraction")
    start = np.array([get_value(raw, k) for k in keys])
    t0_log, t1_log = _time_span(log)
    t_split = t0_log + fit_fraction * (t1_log - t0_log)
    fit_log = log.window(t0_log, t_split)
    show = progress or _stderr_line
    clock = time.perf_counter()
    best = {"f": math.inf, "x": np.log(start)}
    count = {"n": 0}

    def config_for(values):
        r = set_values(raw, keys, values)
        return config_from_dict(r, config.source, Path(config.source).parent), r

    seen: dict = {}
    fails: dict = {"n": 0, "first": ""}

    def run_candidate(values):
        """The fit part's ``-loglik`` of ``values``; inf (counted) when the run fails."""
        try:
            cfg, _ = config_for(values)
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # filterpy's overflow
                total, n = loglik(innovations(fit_log, cfg))
        except Exception as exc:  # noqa: BLE001 - one failing candidate must not end the tuning
            fails["n"] += 1
            if not fails["first"]:
                where = ", ".join(f"{k} = {v:.4g}" for k, v in zip(keys, values, strict=True))
                fails["first"] = f"{where}: {one_line(exc)}"
            return math.inf, f"failed: {one_line(exc)[:80]}"
        f = -total if math.isfinite(total) and n else math.inf
        return f, f"-loglik {f:12.2f}"

    def nll(theta, bounded=True):
        key = tuple(np.asarray(theta, dtype=float).tolist())
        if key in seen:  # Nelder-Mead starts from the start values already evaluated
            return seen[key]
        if bounded and (time.perf_counter() - clock > max_seconds):
            raise _Bound("time bound")
        if bounded and count["n"] >= max_evaluations:
            raise _Bound("evaluation bound")
        count["n"] += 1
        f, text = run_candidate(np.exp(theta))
        if f < best["f"]:
            best.update(f=f, x=np.array(theta, dtype=float))
            if checkpoint is not None:
                checkpoint(
                    set_values(raw, keys, np.exp(theta)),
                    [
                        f"CHECKPOINT: best so far after {count['n']} filter runs "
                        f"({fails['n']} failed): -loglik {f:.2f} on the first part of the log "
                        f"(t <= {t_split:.2f} s); the tuning had not finished",
                    ],
                )
        seen[key] = f
        show(
            f"tune: run {count['n']:4d}  {text}  best {best['f']:12.2f}  "
            f"{time.perf_counter() - clock:6.0f} s"
        )
        return f

    f_start = nll(np.log(start), bounded=False)
    x0 = np.log(start)
    lo, hi = x0 - math.log(SPAN), x0 + math.log(SPAN)
    simplex = np.vstack([x0] + [x0 + 0.5 * e for e in np.eye(len(keys))])
    stopped = "converged"
    try:
        minimize(
            nll,
            x0,
            method="Nelder-Mead",
            bounds=list(zip(lo, hi, strict=True)),
            options={"initial_simplex": simplex, "xatol": 0.01, "fatol": 0.05, "maxfev": 10**6},
        )
    except _Bound as exc:
        stopped = str(exc)
    if not math.isfinite(best["f"]):
        first = f"; the first failure: {fails['first']}" if fails["n"] else ""
        raise ConfigError(
            f"no finite likelihood in {count['n']} candidate runs ({fails['n']} failed){first}",
            config.source,
        )
    x = best["x"]
    at_bound = tuple(
        "lower" if xi - a < HESSIAN_STEP else "upper" if b - xi < HESSIAN_STEP else ""
        for xi, a, b in zip(x, lo, hi, strict=True)
    )
    free = np.array([not b for b in at_bound])
    sig = [None] * len(keys)
    if uncertainty and stopped == "converged" and free.any():

        def f_free(th):
            full = x.copy()
            full[free] = th
            return nll(full)

        try:
            free_sig = _log_sigma(f_free, x[free], best["f"])
            for i, v in zip(np.flatnonzero(free), free_sig, strict=True):
                sig[i] = v
        except _Bound as exc:
            stopped = f"converged; Hessian cut by the {exc}"
    sig = tuple(sig)
    values = start if np.array_equal(x, np.log(start)) else np.exp(x)
    cfg, tuned_raw = config_for(values)
    learned_rec, start_rec = (_records_or_error(log, c) for c in (cfg, config_for(start)[0]))
    failed_full = isinstance(learned_rec, BaseException)
    n_fit = 0 if failed_full else loglik(learned_rec, t_max=t_split)[1]
    if progress is None:
        sys.stderr.write("\n")
    return TuneResult(
        keys=keys,
        start=tuple(float(v) for v in start),
        values=tuple(float(v) for v in values),
        log_sigma=sig,
        fit_loglik=-best["f"],
        start_fit_loglik=-f_start,
        fit_updates=n_fit,
        t_split=float(t_split),
        heldout={
            "learned": heldout_summary(learned_rec, t_split),
            "start": heldout_summary(start_rec, t_split),
        },
        failed=fails["n"],
        failure=fails["first"],
        evaluations=count["n"],
        seconds=time.perf_counter() - clock,
        stopped=stopped,
        raw=tuned_raw,
        at_bound=at_bound,
    )


def _records_or_error(log, cfg):
    """:func:`innovations` over the whole log, or the exception of a run that failed."""
    try:
        return innovations(log, cfg)
    except Exception as exc:  # noqa: BLE001 - reported in the held-out summary
        return exc


def _time_span(log) -> tuple[float, float]:
    ts = [s.t for s in log.streams.values() if len(s)]
    return float(min(t[0] for t in ts)), float(max(t[-1] for t in ts))


def _stderr_line(text: str) -> None:
    sys.stderr.write("\r" + text)
    sys.stderr.flush()


def _log_sigma(f, x, f0: float, h: float = HESSIAN_STEP) -> tuple:
    """1-sigma of each log-parameter from the inverse central-difference Hessian of ``f``."""
    p = len(x)
    E = np.eye(p) * h
    H = np.empty((p, p))
    for i in range(p):
        H[i, i] = (f(x + E[i]) - 2.0 * f0 + f(x - E[i])) / h**2
        for j in range(i):
            H[i, j] = H[j, i] = (
                f(x + E[i] + E[j]) - f(x + E[i] - E[j]) - f(x - E[i] + E[j]) + f(x - E[i] - E[j])
            ) / (4.0 * h**2)
    w = np.linalg.eigvalsh(H) if np.all(np.isfinite(H)) else np.array([-1.0])
    if w.min() <= 0:
        return (None,) * p  # not a strict optimum in every direction: not identifiable
    sig = np.sqrt(np.diag(np.linalg.inv(H)))
    # a 1-sigma wider than the whole search span (x/ SPAN): the log does not inform the value
    return tuple(float(s) if s < math.log(SPAN) else None for s in sig)


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------


def tune_config(path, out=None, keys=None, **kw) -> tuple[TuneResult, Path]:
    """Tune the config file ``path`` on its own log and write the tuned config.

    The log is loaded without ground truth (:func:`odofuse.io.loader.load_log_for` with
    ``groundtruth=False``). ``out`` defaults to ``<stem>-tuned.yaml`` beside ``path``; other
    keywords go to :func:`tune`. Returns the result and the written path.
    """
    from odofuse.config import decode_utf8, load_config, parse_yaml
    from odofuse.io.loader import load_log_for

    path = Path(path)
    config = load_config(path)
    raw = parse_yaml(decode_utf8(path.read_bytes(), str(path)), str(path))
    for key in keys or default_keys(raw):
        get_value(raw, key)  # a bad key fails before the log is read
    log = load_log_for(config, groundtruth=False)
    out = Path(out) if out is not None else path.with_name(f"{path.stem}-tuned.yaml")
    saved: list = []  # the header lines of the checkpoint in ``out``
    writing: list = []  # those of the checkpoint being written

    def checkpoint(best_raw: dict, lines: list) -> None:
        writing[:] = lines
        write_config_file(best_raw, out, path, config.log, lines)
        saved[:] = lines

    try:
        res = tune(config, raw, log, keys, checkpoint=checkpoint, **kw)
    except BaseException as exc:  # a crash, Ctrl-C or SIGTERM: say where the best so far is
        if writing != saved and _holds_checkpoint(out, writing):
            saved[:] = writing  # stopped between the file's rename and the note above
        if saved:
            why = "interrupted" if isinstance(exc, KeyboardInterrupt | SystemExit) else "stopped"
            sys.stderr.write(f"\ntune: {why}; the best config so far is in {out} ({saved[0]})\n")
        raise
    write_tuned(res, out, path, config.log)
    return res, out


def _holds_checkpoint(out: Path, lines: list) -> bool:
    """Whether ``out`` is the checkpoint whose header holds ``lines`` (its rename done)."""
    try:
        return bool(lines) and f"# {lines[0]}\n" in out.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return False


def report_lines(res: TuneResult) -> list[str]:
    """The human-readable summary (also the tuned file's header)."""
    lines = [
        f"maximised: EKF innovation log-likelihood of the first part of the log (t <= "
        f"{res.t_split:.2f} s, {res.fit_updates} updates): {res.start_fit_loglik:.2f} at the "
        f"start values -> {res.fit_loglik:.2f} learned",
        f"{res.evaluations} filter runs, {res.seconds:.1f} s, stopped: {res.stopped}; each "
        f"value bounded to start x/ {SPAN:g}",
    ]
    if res.failed:
        lines.append(
            f"{res.failed} of {res.evaluations} candidate runs failed and were skipped; the "
            f"first: {res.failure}"
        )
    bounds = res.at_bound or ("",) * len(res.keys)
    for k, s, v, sg, b in zip(res.keys, res.start, res.values, res.log_sigma, bounds, strict=True):
        band = "uncertainty not computed" if sg is None else f"1-sigma x/ {math.exp(sg):.3f}"
        if b:
            band = f"at the {b} bound start {'/' if b == 'lower' else '*'} {SPAN:g}: " + (
                "the log does not want this noise" if b == "lower" else "not informed"
            )
        lines.append(f"  {k}: {v:.4g} ({band}; start {s:.4g})")
    for name in ("start", "learned"):
        h = res.heldout[name]
        if h.get("error"):
            lines.append(f"held-out, {name} values: the run failed: {h['error']}")
            continue
        ml = "n/a" if h["mean_loglik"] is None else f"{h['mean_loglik']:.4f}"
        nis = ", ".join(f"{s} {v:.2f}" for s, v in h["nis"].items()) or "-"
        lines.append(
            f"held-out (t > {res.t_split:.2f} s, {h['updates']} updates), {name} values: "
            f"mean log-likelihood per update {ml}, NIS per dimension {nis} (expected 1)"
        )
    return lines


def write_tuned(res: TuneResult, out, source, log: str) -> Path:
    """Write the tuned config: a header saying how it was made, then the config mapping.

    ``log`` is written resolved (the tuned file may live in another folder).
    """
    raw = copy.deepcopy(res.raw)
    raw["description"] = (
        f"Tuned by `odofuse tune {source}` from the log itself (no ground truth): "
        + "; ".join(
            f"{k} = {v:.4g}" + ("" if s is None else f" (x/ {math.exp(s):.3f})")
            for k, v, s in zip(res.keys, res.values, res.log_sigma, strict=True)
        )
    )
    return write_config_file(raw, out, source, log, report_lines(res))


def write_config_file(raw: dict, out, source, log: str, lines) -> Path:
    """Write the config mapping ``raw`` to ``out`` (atomically) under a header of ``lines``.

    ``log`` is written resolved (the tuned file may live in another folder).
    """
    import yaml

    from odofuse.io.atomic import atomic_write_text

    raw = copy.deepcopy(raw)
    if isinstance(raw.get("log"), dict):
        raw["log"]["path"] = log
    else:
        raw["log"] = log
    header = [f"Made by `odofuse tune {source}` on {log}; ground truth was not read.", *lines]
    text = "".join(f"# {h}\n" for h in header) + yaml.safe_dump(raw, sort_keys=False)
    return atomic_write_text(out, text)
