"""The later filter's kernels compiled in a second process (``compiled/warm.py``, issue 28),
and the cache saves that make two compiling processes safe (``kernels._lock_cache_saves``)
and the compile of a signature by one process at a time (``kernels._share_compiles``)."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("numba")

from numba.core.caching import IndexDataCacheFile  # noqa: E402

from odofuse.cli import default_config  # noqa: E402
from odofuse.estimators import compiled  # noqa: E402
from odofuse.estimators.compiled import kernels, warm  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _slow_index(tmp_path) -> IndexDataCacheFile:
    """A numba cache file whose index write waits 0.2 s after reading the old index: the
    window in which a second process reads the same old index."""
    f = IndexDataCacheFile(str(tmp_path), "kernels.f-1.py311", "stamp")
    write = f._save_index

    def slow(overloads):
        time.sleep(0.2)
        write(overloads)

    f._save_index = slow
    return f


def _save_both(f, save) -> dict:
    threads = [threading.Thread(target=save, args=(k, f"code of {k}")) for k in ("sig_a", "sig_b")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return {k: f.load(k) for k in ("sig_a", "sig_b")}


def test_two_saves_at_once_keep_both_signatures_under_the_lock(tmp_path):
    import fcntl

    (tmp_path / "raw").mkdir()
    raw = _slow_index(tmp_path / "raw")
    loaded = _save_both(raw, raw.save)
    # numba's own save: both read the empty index and take data file 1; one signature is
    # lost, or loads the other one's code
    assert loaded != {"sig_a": "code of sig_a", "sig_b": "code of sig_b"}
    (tmp_path / "locked").mkdir()
    f = _slow_index(tmp_path / "locked")
    locked = kernels._locked(f.save, str(tmp_path / "locked" / "odofuse-kernels.lock"), fcntl)
    assert _save_both(f, locked) == {"sig_a": "code of sig_a", "sig_b": "code of sig_b"}


def test_every_kernel_saves_under_the_lock():
    assert kernels.CACHE_SAVES_LOCKED
    assert kernels.filter_offline._cache._cache_file.save.__name__ == "save_locked"
    assert kernels.pf_cov._cache._cache_file.save.__name__ == "save_locked"


def test_the_plan_gives_the_later_filter_to_the_background(monkeypatch):
    configs = {name: default_config(name) for name in ("dead_reckoning", "ekf", "ukf", "smoother")}
    monkeypatch.setattr(compiled, "cold", lambda dispatcher: True)
    assert warm.plan(configs) == ["ukf"]
    assert warm.plan({"ekf": configs["ekf"]}) == []  # one filter: it compiles in the run
    ukf = configs["ukf"]
    off = dataclasses.replace(ukf, options={**ukf.options, "ukf": {"compiled": "off"}})
    assert warm.plan({**configs, "ukf": off}) == []
    monkeypatch.setattr(compiled, "cold", lambda dispatcher: False)
    assert warm.plan(configs) == []  # a warm cache: no second process


# The run's own steps (cli.cmd_run): the UKF compiles in the background process while this
# process compiles the EKF, both into one empty cache; then the UKF loads, and a third process
# finds both filters' machine code there.
_RUN = """
from odofuse.cli import default_config, default_config_path
from odofuse.estimators import run_estimator
from odofuse.estimators.compiled import kernels, warm
from odofuse.io.loader import load_log_for
from odofuse.log_defaults import apply_log_defaults

configs = {name: default_config(name) for name in ("ekf", "ukf")}
background = warm.start([(name, default_config_path(name)) for name in warm.plan(configs)])
for name, config in configs.items():
    config, log = apply_log_defaults(config, load_log_for(config))
    if background:
        background.wait(name)
    run_estimator(name, log, config)
for kernel in (kernels.ekf_offline, kernels.filter_offline):  # the EKF's, the UKF's
    print(len(kernel.stats.cache_hits), len(kernel.stats.cache_misses))
"""


@pytest.mark.slow(seconds=40)  # the EKF's and the UKF's kernels compiled once, on 2 cores
def test_the_background_compile_fills_the_cache_the_run_then_loads(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)}

    def run():
        cmd = [sys.executable, "-c", _RUN]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
        return [int(v) for v in proc.stdout.split()[-4:]]  # hits and misses of each

    # the EKF compiled here (its event loop a miss of filter_offline too), the UKF loaded
    assert run() == [0, 1, 1, 1]
    assert run() == [1, 0, 1, 0]  # neither signature was lost from the cache's index


_PF_COV = """
import numpy as np
from odofuse.estimators.compiled import kernels
X, w, P = np.zeros((5, 3)), np.full(5, 0.2), np.empty((3, 3))
kernels.pf_cov(X, w, np.array([2], dtype=np.int64), np.array([False, False, True]), P)
k = kernels.pf_cov
print(sum(k.stats.cache_hits.values()), sum(k.stats.cache_misses.values()))
"""


def test_processes_started_together_compile_a_signature_once(tmp_path):
    # Three processes on an empty cache ask for the same signature at once (the workers of a
    # batch or of this suite on a fresh install): one compiles it, the others wait and load it.
    assert kernels.COMPILES_SHARED
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-c", _PF_COV]
    procs = [subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True) for _ in range(3)]
    counts = sorted(tuple(int(v) for v in p.communicate()[0].split()[-2:]) for p in procs)
    assert [p.returncode for p in procs] == [0, 0, 0]
    assert counts == [(0, 1), (1, 0), (1, 0)]  # (hits, misses) of each process
