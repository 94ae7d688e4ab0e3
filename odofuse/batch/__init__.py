"""``odofuse batch``: one config over many logs on a Dask cluster (see :mod:`odofuse.batch.run`).

:mod:`~odofuse.batch.run` owns the fleet run and the summary; :mod:`~odofuse.batch.common` the
records and atomic per-log output folders both paths share; :mod:`~odofuse.batch.split` cutting
one long log into overlapping windows and stitching them.
"""

from odofuse.batch.common import BatchSummary, is_complete
from odofuse.batch.run import (
    expand_logs,
    local_client,
    log_names,
    parse_duration,
    print_summary,
    run_batch,
    run_log_task,
    warm_worker,
)

__all__ = [
    "BatchSummary",
    "expand_logs",
    "is_complete",
    "local_client",
    "log_names",
    "parse_duration",
    "print_summary",
    "run_batch",
    "run_log_task",
    "warm_worker",
]
