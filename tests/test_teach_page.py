"""``odofuse teach`` in a real browser: the page's JavaScript computes what the library computes.

Headless Chromium (Debian's ``chromium`` at :data:`CHROMIUM`) is driven by Playwright. The page
is loaded from a ``file://`` URL with every network request aborted; each slider is moved, the
page's numbers (``window.odofuseTeach.state()``) are compared with the Python model:

* deterministic quantities (paths, mean poses, covariances, noise-free UMBmark return errors,
  the UMBmark estimate and correction, drive inverse kinematics, the EKF replayed through
  :class:`odofuse.estimators.ekf.EkfBackend`) within 1e-9 relative (:func:`close`: the largest
  difference over the largest entry);
* the page's Monte Carlo (its own seeded generator) statistically against the linearised
  covariance and a numpy Monte Carlo of the simulator's noise model.

Each panel's screenshot must not be blank; the console must stay free of errors. The page's
speed (``odofuse teach``, a slider move of the error-growth panel) is measured by
``benchmarks/bench_teach.py``, never here. With ``ODOFUSE_TEACH_SCREENSHOTS=DIR`` the panel
screenshots are also written to ``DIR/teach-<panel>.png`` (docs/teaching.md's pictures:
``ODOFUSE_TEACH_SCREENSHOTS=docs python -m pytest -q tests/test_teach_page.py``).
"""

from __future__ import annotations

import io
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
PANELS = ("growth", "umbmark", "drives", "fusion")
REL = 1e-9


def close(a, b, rel: float = REL) -> None:
    """``max |a - b| <= rel * max |b|`` (relative to the quantity's scale)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (a.shape, b.shape)
    scale = float(np.max(np.abs(b))) if b.size else 0.0
    err = float(np.max(np.abs(a - b))) if b.size else 0.0
    assert err <= rel * scale, f"differ by {err:.3e} (scale {scale:.3e}):\n{a}\n{b}"


def close_poses(a, b, rel: float = REL) -> None:
    """:func:`close` for poses ``(..., 3)``: headings compared on the circle (a heading of
    exactly pi may wrap to -pi on either side)."""
    from odofuse import se2

    a, b = np.array(a, dtype=float), np.asarray(b, dtype=float)
    a[..., 2] = b[..., 2] + se2.wrap(a[..., 2] - b[..., 2])
    close(a, b, rel)


# ------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def page_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("teach")
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run(
        [sys.executable, "-m", "odofuse", "teach", "-o", str(out)],
        capture_output=True,
        text=True,
        env=env,
        cwd=root,
    )
    assert proc.returncode == 0, proc.stderr
    return out / "odofuse-teach.html"


@pytest.fixture(scope="module")
def browser():
    sync_api = pytest.importorskip(
        "playwright.sync_api",
        reason="the playwright package is not installed (pip install playwright)",
    )
    exe = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    if exe is None:
        pytest.skip(f"no chromium at {CHROMIUM} (Debian: apt-get install chromium)")
    with sync_api.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=exe, args=ARGS)
        yield b
        b.close()


@pytest.fixture()
def page(browser, page_file):
    context = browser.new_context(viewport={"width": 1500, "height": 1000})
    requests, problems = [], []

    def network_off(route):
        if route.request.url == page_file.as_uri():
            route.continue_()
        else:
            requests.append(route.request.url)
            route.abort()

    context.route("**/*", network_off)
    pg = context.new_page()
    pg.on("request", lambda r: requests.append(r.url))
    pg.on("console", lambda m: problems.append(m.text) if m.type in ("error", "warning") else None)
    pg.on("pageerror", lambda e: problems.append(str(e)))
    pg.goto(page_file.as_uri())
    pg.wait_for_function("window.odofuseTeach !== undefined")
    yield pg
    outside = [u for u in requests if u != page_file.as_uri()]
    assert not outside, f"the page requested {outside}"
    assert not problems, f"console errors: {problems}"
    context.close()


def state(pg) -> dict:
    return pg.evaluate("window.odofuseTeach.state()")


def set_slider(pg, panel: str, key: str, value: float) -> float:
    """Move a slider; returns the value the page took (a slider snaps to its step; log sliders
    step in log10 of the value)."""
    el = pg.locator(f"#{panel}-{key}")
    log = el.get_attribute("data-log") == "1"
    el.fill(repr(float(math.log10(value) if log else value)))
    got = state(pg)[panel]["params"][key]
    step = float(el.get_attribute("step"))
    if log:
        assert abs(math.log10(got) - math.log10(value)) <= 0.5 * step + 1e-12, (key, got)
    else:
        assert abs(got - value) <= 0.5 * step + 1e-12, (key, got)
    return got


# ------------------------------------------------------------------------------- references
def growth_twists(p: dict, cfg: dict) -> np.ndarray:
    from odofuse.teaching import paths

    s = p["step"]
    if p["path"] == "straight":
        return paths._straight(cfg["straight_length"], s, 1.0)
    if p["path"] == "circle":
        return paths._arc(2 * math.pi, cfg["circle_radius"], s, 1.0)
    if p["path"] == "square":
        return paths.square_twists(
            cfg["square_side"], "ccw", speed=s, turn_rate=cfg["turn_per_step_per_m"] * s, dt=1.0
        )
    return paths.figure_eight_twists(cfg["eight_radius"], speed=s, dt=1.0)


def growth_model(p: dict):
    from odofuse.drives import make_drive
    from odofuse.motion import MotionModel, OdometryErrorModel

    drive = make_drive("differential", wheel_radius=p["wheel_radius"], track_width=p["track_width"])
    errors = OdometryErrorModel((p["k_l"], p["k_r"]), (0.0, 0.0))
    return MotionModel(drive, errors, p["integrator"])


def check_growth(st: dict, cfg: dict) -> None:
    """Path, odometry poses and covariances, the noise-free truth: equal to the library."""
    from odofuse.motion import dead_reckon
    from odofuse.teaching.simulate import Scenario, SystematicErrors, simulate, true_geometry

    g = st["growth"]
    p = g["params"]
    tw = growth_twists(p, cfg)
    close(g["twists"], tw)
    model = growth_model(p)
    U = model.drive.inverse(tw)
    close(g["inputs"], U)
    poses, covs = dead_reckon(model, np.zeros(3), np.zeros((3, 3)), U)
    # poses relative to the path's size (a closed path ends near 0), covariances per matrix
    idx = [c["index"] for c in g["checkpoints"]]
    assert idx[-1] == len(U)
    close_poses([g["final_pose"]] + [c["pose"] for c in g["checkpoints"]], poses[[-1] + idx])
    close(g["final_cov"], covs[-1])
    geom = {"wheel_radius": p["wheel_radius"], "track_width": p["track_width"]}
    errors = SystematicErrors(E_d=p["E_d"], E_b=p["E_b"])
    truth = simulate(
        Scenario(
            geometry=geom, path={"kind": "twists", "values": tw.tolist()}, dt=1.0, systematic=errors
        )
    ).truth
    assert g["true_geometry"] == pytest.approx(true_geometry("differential", geom, errors), rel=REL)
    close_poses(
        [g["truth_noise_free_final"]] + [c["truth_noise_free"] for c in g["checkpoints"]],
        truth[[-1] + idx],
    )
    for c in g["checkpoints"]:
        close(c["cov"], covs[c["index"]])


def mc_reference(p: dict, cfg: dict, runs: int, seed: int) -> np.ndarray:
    """The simulator's noise model in numpy: final true poses of ``runs`` runs (runs, 3)."""
    from odofuse.drives import make_drive
    from odofuse.teaching.simulate import SystematicErrors, true_geometry

    model = growth_model(p)
    U = model.drive.inverse(growth_twists(p, cfg))
    geom = {"wheel_radius": p["wheel_radius"], "track_width": p["track_width"]}
    true = make_drive(
        "differential", **true_geometry("differential", geom, SystematicErrors(p["E_d"], p["E_b"]))
    )
    r = p["wheel_radius"]
    k = np.array([p["k_l"], p["k_r"]])
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(runs,) + U.shape) * np.sqrt(k * np.abs(U * r)) / r
    from odofuse import se2

    out = np.zeros((runs, 3))
    for i in range(runs):
        delta = se2.exp(true.twist(U + noise[i]))
        pose = np.zeros(3)
        for d in delta:
            pose = se2.compose(pose, d)
        out[i] = pose
    return out


# ------------------------------------------------------------------------------- tests
def test_page_is_one_small_self_contained_file(page_file):
    html = page_file.read_text(encoding="utf-8")
    assert len(html.encode()) < 1_000_000
    for needle in ("http://", "https://", "<link", " src="):
        assert needle not in html, f"the page references {needle!r}"
    assert "default-src 'none'" in html  # the page's CSP forbids any fetch


def test_teach_into_a_file_is_a_one_line_error(tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x")
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run(
        [sys.executable, "-m", "odofuse", "teach", "-o", str(blocker)],
        capture_output=True,
        text=True,
        env=env,
        cwd=root,
    )
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(blocker) in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


def test_page_config_comes_from_the_library():
    from odofuse.drives import make_drive
    from odofuse.teaching.demos.drive_zoo import _ZOO
    from odofuse.teaching.simulate import Scenario
    from odofuse.teaching.web import page_config

    cfg = page_config()
    geom = dict(Scenario().geometry)
    assert cfg["umbmark"]["geometry"] == geom
    assert cfg["growth"]["wheel_radius"]["value"] == geom["wheel_radius"]
    zoo = {d["name"]: d for d in cfg["drives"]["zoo"]}
    assert list(zoo) == [name for name, _, _ in _ZOO]
    for name, geometry, _ in _ZOO:
        drive = make_drive(name, **geometry)
        if zoo[name]["kind"] == "linear":
            close(zoo[name]["pinv"], np.linalg.pinv(drive.matrix()))


def test_the_harness_sees_a_fetch_attempt(browser, page_file):
    """Negative control of the ``page`` fixture's checks: a request the page's own code might
    make is refused by its Content-Security-Policy and reported on the console."""
    context = browser.new_context()
    pg = context.new_page()
    pg.goto(page_file.as_uri())
    with pg.expect_console_message(lambda m: m.type == "error", timeout=30_000) as msg:
        pg.evaluate("fetch('https://example.invalid/x.json').catch(() => null)")
    text = msg.value.text
    context.close()
    assert "Content Security Policy" in text, text


def test_error_growth_equals_the_library_for_every_slider(page):
    cfg = page.evaluate("window.odofuseTeach.config()")["growth"]
    check_growth(state(page), cfg)
    moves = [
        ("k_r", 2e-5),
        ("k_l", 4e-6),
        ("wheel_radius", 0.05),
        ("track_width", 0.3),
        ("E_d", 1.004),
        ("E_b", 0.99),
        ("step", 0.1),
        ("samples", 200),
    ]
    for key, value in moves:
        set_slider(page, "growth", key, value)
        check_growth(state(page), cfg)
    for integrator in ("euler", "exact", "rk2"):
        page.select_option("#growth-integrator", integrator)
        for path in ("circle", "square", "figure_eight", "straight"):
            page.select_option("#growth-path", path)
            st = state(page)
            assert st["growth"]["params"]["path"] == path
            assert st["growth"]["params"]["integrator"] == integrator
            check_growth(st, cfg)


def test_error_growth_cloud_matches_the_linearised_covariance_where_it_should(page):
    from odofuse.teaching.demos import nees_bounds

    cfg = page.evaluate("window.odofuseTeach.config()")["growth"]
    set_slider(page, "growth", "samples", 1000)
    g = state(page)["growth"]
    n = g["samples"]
    # the page's chi-square bounds (Wilson-Hilferty) against scipy's
    assert g["nees_bounds_95"] == pytest.approx(list(nees_bounds(n)), rel=1e-3)
    lo, hi = nees_bounds(n, prob=0.999)
    # default: small noise (sigma_theta = 0.013 rad at the end of the 5 m run, below the
    # ~0.03 rad where demo error_growth's sweep sees cloud and ellipse part), no systematic
    # error: the ellipse describes the cloud
    for c in g["checkpoints"]:
        assert lo <= c["nees"] <= hi, c
        assert 0.92 <= c["inside_95"] <= 0.98, c
        var = np.diag(c["cov"])
        cov_mc = np.asarray(c["mc_cov_error"])
        assert np.diag(cov_mc) / var == pytest.approx(np.ones(3), abs=6 * math.sqrt(2 / n))
    # the same process in numpy: the final clouds agree in mean and spread
    ref = mc_reference(g["params"], cfg, n, seed=7)
    last = g["checkpoints"][-1]
    est = np.asarray(last["pose"])
    ref_err = ref - est
    sd = ref_err.std(axis=0, ddof=1)
    mean_js = np.asarray(last["mc_mean_error"])
    assert np.all(np.abs(mean_js - ref_err.mean(axis=0)) <= 5 * sd * math.sqrt(2 / n))
    sd_js = np.sqrt(np.diag(last["mc_cov_error"]))
    assert sd_js / sd == pytest.approx(np.ones(3), abs=6 / math.sqrt(2 * n))
    # large heading noise: the banana leaves the ellipse (NEES above the bound)
    set_slider(page, "growth", "k_r", 2e-3)
    set_slider(page, "growth", "k_l", 2e-3)
    g = state(page)["growth"]
    assert g["checkpoints"][-1]["nees"] > hi
    assert not g["consistent_end"]
    # a systematic error (unequal wheels bend the straight run) moves the cloud off the
    # ellipse by the noise-free truth's offset (same seed, so the same draws as before)
    set_slider(page, "growth", "k_r", 1e-6)
    set_slider(page, "growth", "k_l", 1e-6)
    before = state(page)["growth"]["checkpoints"][-1]
    set_slider(page, "growth", "E_d", 1.004)
    last = state(page)["growth"]["checkpoints"][-1]
    offset = np.subtract(last["truth_noise_free"], last["pose"])
    assert abs(offset[1]) > 0.05  # metres: the bend is large against sigma_y
    shift = np.subtract(last["mc_mean_error"], before["mc_mean_error"])
    sd_js = np.sqrt(np.diag(last["mc_cov_error"]))
    assert np.all(np.abs(shift - offset) <= 0.05 * np.abs(offset) + 5 * sd_js / math.sqrt(n))
    assert last["nees"] > hi


def check_umbmark(st: dict) -> None:
    from dataclasses import replace

    from odofuse.teaching import umbmark as um
    from odofuse.teaching.simulate import Scenario, SystematicErrors, WheelNoise, true_geometry

    u = st["umbmark"]
    p = u["params"]
    geom = u["nominal_geometry"]
    errors = SystematicErrors(E_d=p["E_d"], E_b=p["E_b"])
    sc = Scenario(geometry=geom, dt=0.05, systematic=errors, wheel_noise=WheelNoise(k=0.0))
    det = um.umbmark_runs(sc, runs=1, side=p["side"], seed=0)
    close(u["noise_free_cw"], det["cw"][0])
    close(u["noise_free_ccw"], det["ccw"][0])
    true_geom = true_geometry("differential", geom, errors)
    assert u["true_geometry"] == pytest.approx(true_geom, rel=REL)
    for key, cw, ccw in (
        ("estimate", u["errors_cw"], u["errors_ccw"]),
        ("estimate_noise_free", [u["noise_free_cw"]], [u["noise_free_ccw"]]),
    ):
        est = um.umbmark_estimate(cw, ccw, p["side"], geom["track_width"], p["method"])
        js = u[key]
        for name in ("alpha", "beta", "E_b", "E_d"):
            close(js[name], getattr(est, name))
        close(js["E_d"] - 1.0, est.E_d - 1.0, rel=1e-7)
        close(js["E_b"] - 1.0, est.E_b - 1.0, rel=1e-7)
        close(js["centroid_cw"], est.centroid_cw)
        close(js["centroid_ccw"], est.centroid_ccw)
    est = um.umbmark_estimate(
        u["errors_cw"], u["errors_ccw"], p["side"], geom["track_width"], p["method"]
    )
    fixed = um.corrected_geometry(geom, est.E_d, est.E_b)
    assert u["corrected_geometry"] == pytest.approx(fixed, rel=REL)
    close(u["e_max_before"], um.systematic_return_error(u["errors_cw"], u["errors_ccw"]))
    close(u["e_max_after"], um.systematic_return_error(u["errors_after_cw"], u["errors_after_ccw"]))
    after = um.umbmark_runs(
        replace(sc, geometry=u["corrected_geometry"], actual_geometry=true_geom), 1, p["side"], 0
    )
    close(u["after_noise_free_cw"], after["cw"][0])
    close(u["after_noise_free_ccw"], after["ccw"][0])


def test_umbmark_equals_the_library_for_every_slider(page):
    check_umbmark(state(page))
    for key, value in (("E_d", 0.997), ("E_b", 0.985), ("k", 1e-6), ("runs", 8), ("side", 3.0)):
        set_slider(page, "umbmark", key, value)
        check_umbmark(state(page))
    page.select_option("#umbmark-method", "linear")
    check_umbmark(state(page))
    # the correction works: the corrected squares return far closer to the start
    u = state(page)["umbmark"]
    assert u["e_max_after"] < 0.2 * u["e_max_before"]


def check_drives(st: dict) -> None:
    from odofuse.drives import make_drive
    from odofuse.teaching.demos.drive_zoo import _ZOO

    d = st["drives"]
    tw = np.asarray(d["twist"])
    assert set(d["drives"]) == {name for name, _, _ in _ZOO}
    for name, geometry, _ in _ZOO:
        drive = make_drive(name, **geometry)
        js = d["drives"][name]
        assert js["names"] == list(drive.input_names)
        try:
            u = drive.inverse(tw)
        except ValueError:
            assert js["unreachable"], f"{name}: the library refuses {tw}, the page does not"
            continue
        assert not js["unreachable"], f"{name}: {js['unreachable']}"
        close(js["inputs"], u)
        icr = drive.icr(tw)
        if np.all(np.isfinite(icr)):
            close(js["icr_m"], icr)
        else:
            assert js["icr_m"] is None
        for unit, kind in zip(js["units"], drive.input_kinds, strict=True):
            assert unit == {"wheel": "rad/s", "steer": "rad", "steer_increment": "rad/s"}[kind]


def test_drive_zoo_inverse_kinematics_equal_the_library(page):
    check_drives(state(page))
    for key, value in (("omega", -0.35), ("vx", 0.8), ("vy", 0.3), ("vx", 0.0), ("omega", 0.0)):
        set_slider(page, "drives", key, value)
        check_drives(state(page))
    set_slider(page, "drives", "vy", 0.0)
    set_slider(page, "drives", "omega", 0.6)
    check_drives(state(page))  # turning on the spot


def replay_ekf(st: dict):
    """The page's fusion run through the library's EKF backend, step by step."""
    from odofuse.estimators.ekf import EkfBackend
    from odofuse.measurements.absolute import GpsPosition
    from odofuse.measurements.gyro import GyroYawRate

    f, g = st["fusion"], st["growth"]
    p = {**g["params"], "path": f["params"]["path"]}
    cfg = st["_cfg"]
    model = growth_model(p)
    U = model.drive.inverse(growth_twists(p, cfg))
    gyro = GyroYawRate(
        name="gyro", sigma=f["params"]["gyro_sigma"], gate=None, calibrate=False
    ).bind({"gyro_theta_ref": 3})
    gps = GpsPosition(name="gps", sigma=f["params"]["gps_sigma"], gate=None)
    be = EkfBackend(model, {"gyro": gyro, "gps": gps}, np.zeros(4), np.zeros((4, 4)), np.zeros(4))
    fixes = {fx["k"]: fx["z"] for fx in f["gps"]}
    seen = []
    for k, u in enumerate(U):
        be.predict(u, f["dt"])
        if f["params"]["gyro"]:
            accepted, _ = be.update(gyro, {"wz": f["gyro_wz"][k], "dt": f["dt"]})
            assert accepted
            be.clone(3, 2)
        if f["params"]["gps"] and (k + 1) in fixes:
            before = be.cov()[:2, :2].copy()
            z = fixes[k + 1]
            accepted, _ = be.update(gps, {"x": z[0], "y": z[1]})
            assert accepted
            seen.append((k + 1, before, be.cov()[:2, :2].copy()))
    return be, seen


def check_fusion(st: dict) -> None:
    be, seen = replay_ekf(st)
    f = st["fusion"]
    close(f["final_x"], be.mean())
    close(f["final_P"], be.cov())
    assert len(f["fixes"]) == len(seen)
    for js, (k, before, after) in zip(f["fixes"], seen, strict=True):
        assert js["k"] == k
        close(js["before"]["P"], before)
        close(js["after"]["P"], after)
        assert np.trace(after) < np.trace(before)  # the ellipse shrinks at each fix


def test_fusion_equals_the_library_ekf(page):
    cfg = page.evaluate("window.odofuseTeach.config()")["growth"]

    def st():
        s = state(page)
        s["_cfg"] = cfg
        return s

    check_fusion(st())
    page.check("#fusion-gyro")
    check_fusion(st())
    for key, value in (("gyro_sigma", 0.01), ("gps_sigma", 0.2), ("gps_period", 6.0)):
        set_slider(page, "fusion", key, value)
        check_fusion(st())
    page.uncheck("#fusion-gps")
    s = st()
    assert s["fusion"]["fixes"] == []
    check_fusion(s)
    page.select_option("#fusion-path", "square")
    page.check("#fusion-gps")
    check_fusion(st())


def test_panels_render(page):
    from PIL import Image

    def shoot(save: bool) -> None:
        shots = os.environ.get("ODOFUSE_TEACH_SCREENSHOTS")
        for name in PANELS:
            png = page.locator(f"#panel-{name}").screenshot()
            img = np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=float)
            assert img.std() > 20, f"panel {name} looks blank (pixel std {img.std():.1f})"
            for canvas in page.locator(f"#panel-{name} canvas").all():
                c = np.asarray(Image.open(io.BytesIO(canvas.screenshot())).convert("L"), float)
                assert np.mean(c < 200) > 0.01, f"a canvas of panel {name} is empty"
            if shots and save:
                path = Path(shots) / f"teach-{name}.png"
                path.parent.mkdir(parents=True, exist_ok=True)
                Image.open(io.BytesIO(png)).convert("P", palette=Image.ADAPTIVE).save(
                    path, optimize=True
                )

    shoot(save=False)  # the defaults
    # the pictures of docs/teaching.md: the banana leaving the ellipse (large wheel noise on
    # the straight run), UMBmark's and the drives' defaults, the fusion panel with the gyro on
    set_slider(page, "growth", "k_r", 1e-3)
    set_slider(page, "growth", "k_l", 1e-3)
    page.check("#fusion-gyro")
    set_slider(page, "growth", "samples", 1000)  # last: the shown update time is a warm one
    shoot(save=True)
