"""UMBmark (Borenstein & Feng 1996) on simulated robots with known E_d and E_b."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.teaching import simulate as S
from odofuse.teaching import umbmark as cal


def test_linearised_square_errors_match_borenstein():
    """The exact square model agrees with the first-order formulas of the module docstring."""
    L, a, b = 4.0, 2e-5, -3e-5
    cw = cal.square_return_error(a, b, L, "cw")
    ccw = cal.square_return_error(a, b, L, "ccw")
    # second-order remainder ~ L (7 beta / 2)^2 ~ 4e-8
    np.testing.assert_allclose(cw, [-2 * L * (a + b), -2 * L * (a + b)], atol=1e-7)
    np.testing.assert_allclose(ccw, [2 * L * (b - a), -2 * L * (b - a)], atol=1e-7)
    np.testing.assert_allclose(cal.square_return_error(0.0, 0.0, L, "cw"), 0.0, atol=1e-12)


def test_linear_estimate_reference_values():
    """Borenstein's closed form by hand: x_cw = -0.4, x_ccw = 0.2, L = 4 (y consistent)."""
    L, b = 4.0, 0.5
    est = cal.umbmark_estimate([[-0.4, -0.4]], [[0.2, -0.2]], L, b, method="linear")
    alpha = (-0.4 + 0.2) / (-16)  # 0.0125 rad
    beta = (-0.4 - 0.2) / (-16)  # 0.0375 rad
    assert math.isclose(est.alpha, alpha, rel_tol=1e-12)
    assert math.isclose(est.beta, beta, rel_tol=1e-12)
    E_b = 90 / (90 - math.degrees(alpha))
    assert math.isclose(est.E_b, E_b, rel_tol=1e-12)
    R = (L / 2) / math.sin(beta / 2)
    bb = E_b * b
    assert math.isclose(est.E_d, (R + bb / 2) / (R - bb / 2), rel_tol=1e-12)


@pytest.mark.parametrize("alpha,beta", [(0.02, 0.05), (-0.03, 0.01), (0.0, -0.08)])
def test_exact_estimate_inverts_the_square_model(alpha, beta):
    L = 4.0
    cw = cal.square_return_error(alpha, beta, L, "cw")
    ccw = cal.square_return_error(alpha, beta, L, "ccw")
    est = cal.umbmark_estimate([cw], [ccw], L, 0.3, method="exact")
    assert math.isclose(est.alpha, alpha, abs_tol=1e-10)
    assert math.isclose(est.beta, beta, abs_tol=1e-10)


def test_corrected_geometry_keeps_mean_radius():
    g = cal.corrected_geometry({"wheel_radius": 0.05, "track_width": 0.4}, 1.01, 0.98)
    assert math.isclose(g["wheel_radius_left"] + g["wheel_radius_right"], 0.1, rel_tol=1e-12)
    # the correction makes the model's right/left ratio equal to the measured D_R / D_L
    assert math.isclose(g["wheel_radius_right"] / g["wheel_radius_left"], 1.01, rel_tol=1e-12)
    assert math.isclose(g["track_width"], 0.392, rel_tol=1e-12)
    with pytest.raises(ValueError, match="track_width"):
        cal.corrected_geometry({"wheel_radius": 0.05}, 1.0, 1.0)


def test_return_error_is_expressed_in_the_start_frame():
    e = cal.return_error([1.0, 1.0, math.pi / 2], [1.0, 3.0], [1.0, 1.0])
    np.testing.assert_allclose(e, [2.0, 0.0], atol=1e-12)


def test_bad_input():
    with pytest.raises(ValueError, match=r"\(n, 2\)"):
        cal.umbmark_estimate([[1.0, 2.0, 3.0]], [[0.0, 0.0]], 4.0, 0.3)
    with pytest.raises(ValueError, match="positive"):
        cal.umbmark_estimate([[0.1, 0.1]], [[0.0, 0.0]], 0.0, 0.3)
    with pytest.raises(ValueError, match="method"):
        cal.umbmark_estimate([[0.1, 0.1]], [[0.0, 0.0]], 4.0, 0.3, method="magic")


ROBOTS = [
    (1.002, 1.01, {"wheel_radius": 0.04, "track_width": 0.235}),
    (0.997, 0.985, {"wheel_radius": 0.04, "track_width": 0.235}),
    (1.0015, 0.99, {"wheel_radius": 0.1, "track_width": 0.5}),
    (0.999, 1.03, {"wheel_radius": 0.0825, "track_width": 0.34}),
]


@pytest.mark.parametrize("E_d,E_b,geometry", ROBOTS)
@pytest.mark.parametrize("seed", [0, 1])
def test_umbmark_recovers_E_d_E_b_and_reduces_return_error_tenfold(E_d, E_b, geometry, seed):
    sc = S.Scenario(
        geometry=geometry,
        systematic=S.SystematicErrors(E_d=E_d, E_b=E_b),
        wheel_noise=S.WheelNoise(k=1e-8),
        dt=0.05,
    )
    report = cal.calibrate_umbmark(sc, runs=5, side=4.0, seed=seed)
    est = report.estimate
    assert abs(est.E_d - E_d) <= 0.1 * abs(E_d - 1)
    assert abs(est.E_b - E_b) <= 0.1 * abs(E_b - 1)
    assert report.e_max_after * 10 <= report.e_max_before
    # the corrected nominal geometry approaches the hidden true one
    tg, cg = report.true_geometry, report.corrected_geometry
    ratio_true = tg["wheel_radius_right"] / tg["wheel_radius_left"]
    ratio_fix = cg["wheel_radius_right"] / cg["wheel_radius_left"]
    assert abs(ratio_fix - ratio_true) <= 0.1 * abs(ratio_true - 1)


def test_linear_method_is_biased_where_the_exact_one_is_not():
    """Noise-free robot with large errors: Borenstein's first-order formulas lose several per
    cent of E_b - 1 (second-order terms); the exact inversion recovers it."""
    sc = S.Scenario(systematic=S.SystematicErrors(E_d=0.997, E_b=0.985), dt=0.05)
    lin = cal.calibrate_umbmark(sc, runs=1, method="linear").estimate
    ex = cal.calibrate_umbmark(sc, runs=1, method="exact").estimate
    assert abs(lin.E_b - 0.985) > 0.05 * 0.015
    assert abs(ex.E_b - 0.985) < 0.01 * 0.015
    assert abs(ex.E_d - 0.997) < 0.01 * 0.003


def test_umbmark_from_written_logs(tmp_path):
    sc = S.Scenario(
        systematic=S.SystematicErrors(E_d=1.002, E_b=1.01),
        dt=0.05,
        encoder=S.EncoderSpec(979.2, 65536),
    )
    folders = {}
    for d in ("cw", "ccw"):
        sim = S.simulate(
            S.Scenario(**{**sc.__dict__, "path": {"kind": "square", "side": 4.0, "direction": d}})
        )
        S.write_log(sim, tmp_path / d)
        folders[d] = [tmp_path / d]
    out = cal.umbmark_from_logs(folders["cw"], folders["ccw"], 4.0)
    # encoder quantisation (979.2 ticks/rev) is the only error besides E_d, E_b
    assert abs(out["E_d"] - 1.002) < 0.1 * 0.002
    assert abs(out["E_b"] - 1.01) < 0.1 * 0.01


def test_cli_calibrate_umbmark(tmp_path, capsys):
    import json

    from odofuse.cli import main

    code = main(
        [
            "calibrate",
            "umbmark",
            "--runs",
            "2",
            "--E-d",
            "0.998",
            "--E-b",
            "1.02",
            "-o",
            str(tmp_path),
        ]
    )
    assert code == 0
    summary = json.loads((tmp_path / "umbmark.json").read_text())
    assert abs(summary["E_d"] - 0.998) < 0.1 * 0.002
    assert abs(summary["E_b"] - 1.02) < 0.1 * 0.02
    assert summary["reduction"] >= 10
    assert (tmp_path / "umbmark.png").exists()
    assert main(["calibrate", "umbmark", "--cw", str(tmp_path)]) == 2
    assert "--ccw" in capsys.readouterr().err
