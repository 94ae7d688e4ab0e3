"""Suite-wide collection order for the parallel run (issue 28).

The README's test command runs the suite on every core (``-n auto --dist worksteal`` in
pyproject.toml's ``addopts``, pytest-xdist). The tests marked ``slow`` (each needs more than
10 s on the 2-core machine, and says why beside its mark) are collected first, the longest
first where the mark gives its measured ``seconds``: worksteal hands each worker a contiguous
share of the collection and an idle worker steals from the end of another's, so a long test
collected late would run alone at the end of the run (the million-step particle test did: the
suite took 14 min with its 4 min at the end; longest first, 14 min 31 s: the other slow
tests then wait in that worker's share). The order is otherwise the files' own.

GTSAM's reference optima (``benchmarks/gtsam_reference.best``, 47 s for all files) are shared
between the workers through a folder of the run (:func:`pytest_configure`). On an empty numba
cache (a clean clone, or after an edit of ``kernels.py``) the compiled core is compiled once,
in two processes, before the workers start (``tests/prewarm.py``), instead of by every worker
and CLI subprocess that reaches a kernel first.
"""

from __future__ import annotations


def _order(item) -> tuple[bool, float]:
    slow = item.get_closest_marker("slow")
    return (slow is None, -float(slow.kwargs.get("seconds", 0.0)) if slow else 0.0)


def pytest_collection_modifyitems(config, items):
    items.sort(key=_order)


def pytest_configure(config):
    """One folder per test run where ``benchmarks/gtsam_reference.best`` shares GTSAM's
    reference optima between the xdist workers (set before they start, so they inherit it):
    a file's reference is then computed once per run, not once per worker that asks. Also
    lets the run write Python's bytecode caches (below)."""
    import os
    import sys
    import tempfile

    if hasattr(config, "workerinput"):  # a worker: the controller has set it
        return
    # A machine with PYTHONDONTWRITEBYTECODE set (this one's shell) has every worker and every
    # `odofuse` subprocess compile odofuse and re-rewrite the test modules' asserts from source:
    # the suite writes its bytecode caches (__pycache__, ignored by git) like any default
    # Python, so that only the first process compiles.
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    sys.dont_write_bytecode = False
    folder = tempfile.mkdtemp(prefix="odofuse-gtsam-best-")
    os.environ["ODOFUSE_GTSAM_BEST_DIR"] = folder
    config._gtsam_best_dir = folder
    if config.getoption("numprocesses", None):  # xdist's workers are about to start
        _prewarm()


def _prewarm() -> None:
    """Compile the compiled core into numba's cache (``tests/prewarm.py``) when it is cold."""
    import sys

    import prewarm  # tests/ is on sys.path: pytest put it there to import this file

    if prewarm.cold():
        for job, proc in zip(prewarm.JOBS, prewarm.start(), strict=True):
            if proc.wait():  # costs only time: the tests compile what it did not
                print(f"tests/prewarm.py {job} failed (exit {proc.returncode})", file=sys.stderr)


def pytest_unconfigure(config):
    import shutil

    folder = getattr(config, "_gtsam_best_dir", None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)
