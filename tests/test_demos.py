"""Every teaching demo in quick mode: it writes its PNG and its numbers say what the slide says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.cli import main as cli_main
from odofuse.teaching import demos


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    return tmp_path_factory.mktemp("demos")


def run(name, out):
    result = demos.run_demo(name, out_dir=out, quick=True, seed=0)
    png = result["png"]
    with open(png, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    return result["numbers"]


def test_integration_orders(out):
    n = run("integration", out)
    assert abs(n["slope_euler"] - 1.0) < 0.05
    assert abs(n["slope_rk2"] - 2.0) < 0.05
    assert n["max_error_exact_m"] < 1e-9  # a constant twist is integrated exactly
    assert n["error_at_dt_euler_m"] > 100 * n["error_at_dt_rk2_m"]


def test_error_growth_consistent_then_parting(out):
    n = run("error_growth", out)
    lo, hi = n["nees_bounds_95"]
    moderate, large = n["moderate"], n["large_heading_noise"]
    assert moderate["sigma_theta_end_rad"] < 0.02
    assert all(lo <= v <= hi for v in moderate["nees_rk2"])
    assert all(abs(f - 0.95) < 0.05 for f in moderate["fraction_inside_95_ellipse"])
    assert large["sigma_theta_end_rad"] > 0.5
    assert large["nees_rk2"][-1] > 10 * hi  # the banana leaves the ellipse
    assert large["fraction_inside_95_ellipse"][-1] < 0.5
    sweep = n["sweep"]
    slo, shi = sweep["nees_bounds_95"]
    assert slo <= sweep["nees_end"][0] <= shi
    assert sweep["nees_end"][-1] > 10 * shi


def test_systematic_vs_nonsystematic(out):
    n = run("systematic", out)
    assert n["e_max_syst_systematic_only_m"] > 10 * n["e_max_syst_nonsystematic_only_m"]
    u = n["umbmark"]
    assert abs(u["E_d"] - 1.002) < 0.1 * 0.002
    assert abs(u["E_b"] - 1.01) < 0.1 * 0.01
    assert u["e_max_syst_after_m"] < u["e_max_syst_before_m"] / 5


def test_gyrodometry_beats_both_sources(out):
    n = run("gyrodometry", out)
    gd = abs(n["gyrodometry_final_heading_error_deg"])
    assert gd < abs(n["odometry_final_heading_error_deg"]) / 5
    assert gd < abs(n["gyro_final_heading_error_deg"]) / 5
    assert 0 < n["steps_using_gyro"] < 0.05 * n["steps"]


def test_fusion_ekf_bridges_the_outage(out):
    n = run("fusion", out)
    assert n["ekf"]["rmse_m"] < n["dead_reckoning"]["rmse_m"] / 5
    assert n["ekf"]["max_error_in_outage_m"] < n["dead_reckoning"]["max_error_in_outage_m"]


def test_fusion_smoother(out):
    n = run("fusion", out)
    if "smoother" in n["skipped"]:
        pytest.skip(f"smoother estimator not available: {n['skipped']['smoother']}")
    assert n["smoother"]["rmse_m"] <= n["ekf"]["rmse_m"] * 1.05


def test_drive_zoo(out):
    n = run("drive_zoo", out)
    assert set(n) == {
        "differential",
        "skid_steer",
        "synchro",
        "tricycle",
        "bicycle",
        "ackermann",
        "omni3",
        "mecanum4",
        "swerve",
        "car",
        "car_ackermann",
    }
    for name, d in n.items():
        assert d["roundtrip_error"] < 1e-9, name
    assert n["differential"]["degree_of_mobility"] == 2
    assert n["omni3"]["degree_of_mobility"] == 3 and n["mecanum4"]["degree_of_mobility"] == 3
    assert n["bicycle"]["degree_of_mobility"] == 1
    # ICR of [omega, vx, vy] = [0.5, 0.25, 0] lies at R = v / omega = 0.5 m to the left
    np.testing.assert_allclose(n["differential"]["icr_body_m"], [0.0, 0.5], atol=1e-12)
    # differential inverse: wheel rates (v -+ omega b/2) / r
    assert math.isclose(n["differential"]["inverse"]["left"], (0.25 - 0.5 * 0.2) / 0.05)
    assert math.isclose(n["differential"]["inverse"]["right"], (0.25 + 0.5 * 0.2) / 0.05)


def test_gyrodometry_rule_reference():
    odo = np.array([0.0, 0.10, 0.01, -0.02])
    gyro = np.array([0.001, 0.01, 0.012, 0.05])
    dth, used = demos.gyrodometry(odo, gyro, 0.005)
    np.testing.assert_array_equal(used, [False, True, False, True])
    np.testing.assert_allclose(dth, [0.0, 0.01, 0.01, 0.05])
    with pytest.raises(ValueError, match="shape"):
        demos.gyrodometry([0.0], [0.0, 1.0], 0.1)


def test_nees_bounds_and_ellipse_reference():
    from scipy.stats import chi2

    lo, hi = demos.nees_bounds(1, 3)
    assert math.isclose(lo, 0.2157952826238981, rel_tol=1e-9)
    assert math.isclose(hi, 9.348403604496148, rel_tol=1e-9)
    lo, hi = demos.nees_bounds(100, 3)
    assert lo < 3 < hi and math.isclose(hi * 100, chi2.ppf(0.975, 300))
    ell = demos._ellipse(np.zeros(2), np.diag([4.0, 1.0]))
    r2 = ell[:, 0] ** 2 / 4 + ell[:, 1] ** 2
    np.testing.assert_allclose(r2, chi2.ppf(0.95, 2), rtol=1e-12)


def test_unknown_demo():
    with pytest.raises(ValueError, match="unknown demo"):
        demos.run_demo("nope")


def test_cli_demo_and_list(tmp_path, capsys):
    assert cli_main(["demo", "--list"]) == 0
    listing = capsys.readouterr().out
    for name in demos.DEMOS:
        assert name in listing
    assert cli_main(["demo", "integration", "--quick", "-o", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "slope_euler" in text and (tmp_path / "integration.png").exists()


@pytest.mark.slow
def test_error_growth_full_size_nees(tmp_path):
    """1000 Monte-Carlo runs: moderate noise consistent at every checkpoint, large noise not."""
    n = demos.run_demo("error_growth", out_dir=tmp_path, quick=False, seed=0)["numbers"]
    lo, hi = n["nees_bounds_95"]
    assert n["runs"] == 1000
    assert all(lo <= v <= hi for v in n["moderate"]["nees_rk2"])
    assert all(lo <= v <= hi for v in n["moderate"]["nees_exact"])
    assert n["large_heading_noise"]["nees_rk2"][-1] > 10 * hi
    # the mean NEES only grows once the heading noise does (beyond 0.03 rad it leaves the band)
    sweep = n["sweep"]
    slo, shi = sweep["nees_bounds_95"]
    for sig, v in zip(sweep["sigma_theta_end_rad"], sweep["nees_end"], strict=True):
        if sig < 0.02:
            assert slo <= v <= shi
        if sig > 0.1:
            assert v > shi
