"""Every example script runs with --quick, has a narrative header and a main(argv)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


def load(path: Path):
    spec = importlib.util.spec_from_file_location(f"example_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_there_are_examples():
    assert len(EXAMPLES) >= 5


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_runs_quick(path, tmp_path, capsys):
    module = load(path)
    doc = module.__doc__ or ""
    assert "The story" in doc and "--quick" in doc, "narrative header missing"
    assert module.main(["--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.strip(), "an example prints its numbers"
    # every number it prints is finite
    assert not re.search(r"\bnan\b|\binf\b", out, flags=re.IGNORECASE)
    pngs = list(tmp_path.rglob("*.png"))
    if "picture:" in out:
        assert pngs and all(p.stat().st_size > 10_000 for p in pngs)


def test_umbmark_example_numbers(tmp_path, capsys):
    module = load(next(p for p in EXAMPLES if p.stem == "umbmark_calibration"))
    assert module.main(["--quick", "--out", str(tmp_path), "--E-d", "1.002", "--E-b", "1.01"]) == 0
    out = capsys.readouterr().out
    m = re.search(r"exact  estimate: E_d = ([\d.]+), E_b = ([\d.]+)", out)
    assert m, out
    assert abs(float(m.group(1)) - 1.002) < 0.1 * 0.002
    assert abs(float(m.group(2)) - 1.01) < 0.1 * 0.01
    factor = float(re.search(r"\(x(\d+) smaller\)", out).group(1))
    assert factor >= 10
