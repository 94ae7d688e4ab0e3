"""Issue 25 item 2: ``advice`` in metrics.json, printed under the CLI table, never the status."""

from __future__ import annotations

import io

from odofuse.cli import print_table


def test_the_table_prints_warnings_then_advice_and_the_status_column_is_the_runs():
    rows = [
        {
            "estimator": "ekf",
            "ate_rmse_m": 0.3,
            "final_error_m": 0.5,
            "runtime_s": 1.0,
            "status": "ok",
            "warnings": ["[slip] gyro: a note"],
            "advice": [
                "a batch smoother of this log is about 2.5x more accurate: `estimator: smoother`"
            ],
        },
        {"estimator": "smoother", "ate_rmse_m": 0.1, "status": "ok", "warnings": [], "advice": []},
    ]
    out = io.StringIO()
    print_table(rows, out)
    lines = out.getvalue().splitlines()
    assert lines[1].split()[-1] == "ok" and lines[2].split()[-1] == "ok"
    assert lines[3] == "warning: ekf: [slip] gyro: a note"
    assert lines[4] == (
        "advice: ekf: a batch smoother of this log is about 2.5x more accurate: "
        "`estimator: smoother`"
    )
    assert len(lines) == 5


def test_rows_without_advice_print_as_before():
    out = io.StringIO()
    print_table([{"estimator": "dead_reckoning", "status": "degraded"}], out)
    assert not any(line.startswith("advice") for line in out.getvalue().splitlines())
