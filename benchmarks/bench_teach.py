"""The teaching page's speed (docs/teaching.md): how long ``odofuse teach`` takes to write the
page, and how long a slider move of the error-growth panel takes in a real browser.

Run from any directory: ``python benchmarks/bench_teach.py [--repeat N]``. Needs playwright and
Debian's ``chromium`` (the browser ``tests/test_teach_page.py`` drives, with the same launch
arguments and every network request but the page's own aborted).

Prints (asserts nothing; tests never assert wall-clock times):

* ``odofuse teach -o DIR`` as a subprocess: the best of ``--repeat`` runs (default 3);
* for 500 Monte Carlo samples on the straight run (Δs = 0.05 m) and the figure eight
  (Δs = 0.05 and 0.01 m): the time of the step move that changes the path (the page draws new
  normals), and the median over seven ``k_r`` moves (the page rescales its draws) with its
  compute part; the page's own timers (``window.odofuseTeach.state().timing``).

The seconds are this machine's (2 cores, shared); the load average is printed beside them.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from test_teach_page import ARGS, CHROMIUM, set_slider, state  # noqa: E402

CASES = (("straight", 0.05), ("figure_eight", 0.05), ("figure_eight", 0.01))
K_R = (2e-6, 3e-6, 4e-6, 5e-6, 6e-6, 7e-6, 8e-6)


def write_page(folder: Path, repeat: int) -> tuple[Path, float]:
    """The page ``odofuse teach`` writes into ``folder`` and its best wall time."""
    env = {**os.environ, "PYTHONPATH": str(HERE.parent)}
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "odofuse", "teach", "-o", str(folder)],
            check=True,
            capture_output=True,
            env=env,
        )
        best = min(best, time.perf_counter() - t0)
    return folder / "odofuse-teach.html", best


def slider_moves(page_path: Path) -> list[tuple[str, float, int, float, float, float]]:
    """``(path, step, steps, step move ms, median k_r move ms, its compute ms)`` per case."""
    from playwright.sync_api import sync_playwright

    exe = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    if exe is None:
        raise SystemExit(f"no chromium at {CHROMIUM} (Debian: apt-get install chromium)")
    url, rows = page_path.as_uri(), []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=exe, args=ARGS)
        context = browser.new_context(viewport={"width": 1500, "height": 1000})
        context.route("**/*", lambda r: r.continue_() if r.request.url == url else r.abort())
        page = context.new_page()
        page.goto(url)
        page.wait_for_function("window.odofuseTeach !== undefined")
        set_slider(page, "growth", "samples", 500)
        for path, step in CASES:
            page.select_option("#growth-path", path)
            set_slider(page, "growth", "step", step)  # new steps: the page draws new normals
            first = state(page)["timing"]["growth_ms"]
            times = []
            for value in K_R:
                set_slider(page, "growth", "k_r", value)
                times.append(state(page)["timing"])
            mid = len(times) // 2
            ms = sorted(t["growth_ms"] for t in times)[mid]
            compute = sorted(t["growth_compute_ms"] for t in times)[mid]
            n = state(page)["growth"]["n_steps"]
            rows.append((path, step, n, first, ms, compute))
        browser.close()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="odofuse-teach-") as folder:
        page, seconds = write_page(Path(folder), args.repeat)
        kib = page.stat().st_size / 1024
        print(f"odofuse teach: {kib:.0f} KiB in {seconds:.2f} s (best of {args.repeat})")
        rows = slider_moves(page)
    print("error-growth panel, 500 samples (ms):")
    print("| path | step | steps | step move | k_r move, median | of it compute |")
    print("| --- | --- | --- | --- | --- | --- |")
    for path, step, n, first, ms, compute in rows:
        print(f"| {path} | {step} m | {n} | {first:.1f} | {ms:.1f} | {compute:.1f} |")
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
