"""What the whole-log and the split paths of ``odofuse batch`` share: the summary records,
the per-log output folders (complete, temporary, published atomically) and gathering results
from the cluster with a progress bar.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from odofuse.errors import one_line

#: Columns of ``summary.csv`` (and keys of each record), in order.
SUMMARY_COLUMNS = (
    "log",
    "name",
    "status",
    "warnings",
    "poses",
    "runtime_s",
    "ate_rmse_m",
    "final_error_m",
    "resumed",
    "error",
)
#: Files that make a log's output folder complete (metrics.json is written last).
COMPLETE_FILES = ("trajectory.csv", "trajectory.tum", "metrics.json")
#: Times the scheduler reschedules a log whose worker died while running it.
DEFAULT_RETRIES = 3


# ------------------------------------------------------------------------------- the records
class BatchSummary(list):
    """The summary of a batch: a list of plain dict records, one per log (SUMMARY_COLUMNS).

    ``stale`` lists the complete run folders of OUT that belong to none of the batch's logs;
    ``unfused`` the note that the batch's estimator fuses none of the configured sensors
    (``RunConfig.unfused_note``: a config that forgot ``estimator:``), or None.
    """

    stale: list = []  # noqa: RUF012 - replaced per instance by run_batch, never mutated
    unfused: str | None = None

    def to_pandas(self):
        """The records as a :class:`pandas.DataFrame` (needs pandas, not a dependency)."""
        import pandas as pd

        return pd.DataFrame(list(self), columns=list(SUMMARY_COLUMNS))

    @property
    def failed(self) -> list[dict]:
        """The records of the logs that did not run."""
        return [r for r in self if r["status"] == "failed"]


def record(spec: str, name: str, metrics: dict | None, *, resumed=False, error=None) -> dict:
    if metrics is None:
        return {
            **dict.fromkeys(SUMMARY_COLUMNS),
            "log": spec,
            "name": name,
            "status": "failed",
            "resumed": False,
            "error": error,
        }
    warnings = metrics.get("warnings") or []
    return {
        "log": spec,
        "name": name,
        "status": metrics.get("status", "ok"),
        "warnings": len(warnings) if isinstance(warnings, list) else int(warnings),
        "poses": metrics.get("poses"),
        "runtime_s": metrics.get("runtime_s"),
        "ate_rmse_m": metrics.get("ate_rmse_m"),
        "final_error_m": metrics.get("final_error_m"),
        "resumed": resumed,
        "error": None,
    }


def is_complete(folder: Path) -> bool:
    """Whether ``folder`` holds a complete run (its COMPLETE_FILES, metrics.json readable)."""
    if not all((folder / f).is_file() for f in COMPLETE_FILES):
        return False
    try:
        json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return True


def _progress(total: int, desc: str, show: bool | None):
    from tqdm import tqdm

    on = sys.stderr.isatty() if show is None else show
    return tqdm(total=total, desc=desc, unit="log", file=sys.stderr, disable=not on)


def gather_records(client, futures, order: dict, desc: str, show: bool | None) -> list:
    """Results of ``futures`` as they complete (progress bar); a lost task is a failed value.

    ``order`` maps a future's key to ``(index, spec, name)``; the list is in index order.
    """
    from distributed import as_completed

    out: list = [None] * len(order)
    with _progress(len(futures), desc, show) as bar:
        for fut in as_completed(futures):
            i, spec, name = order[fut.key]
            try:
                out[i] = fut.result()
            except Exception as exc:  # e.g. KilledWorker after every retry
                out[i] = record(spec, name, None, error=one_line(exc))
            bar.update(1)
    return out
