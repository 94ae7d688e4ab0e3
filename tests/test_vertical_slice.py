"""End to end: log folder -> drive model -> dead reckoning -> trajectory.csv, for every drive
whose geometry keys the spec fixes, on noise-free simulated wheel readings."""

import csv

import numpy as np
import pytest
import yaml

from odofuse import se2
from odofuse.cli import main
from odofuse.drives import make_drive
from odofuse.motion import integrate

GEOMETRY = {
    "differential": {"wheel_radius": 0.04, "track_width": 0.235},
    "skid_steer": {"wheel_radius": 0.1, "track_width": 0.5},
    "omni3": {"wheel_radius": 0.05, "wheel_distance": 0.2},
    "mecanum4": {"wheel_radius": 0.05, "half_length": 0.3, "half_width": 0.2},
}
HEADER = "t,x,y,theta,var_x,cov_xy,cov_xtheta,var_y,cov_ytheta,var_theta"


def twists(holonomic: bool, n: int = 400) -> np.ndarray:
    """A smooth tour: curves both ways, straight parts, and sideways motion when holonomic."""
    k = np.arange(n)
    omega = 0.03 * np.sin(2 * np.pi * k / 150)
    omega[100:140] = 0.0  # exactly straight
    vx = 0.05 + 0.02 * np.cos(2 * np.pi * k / 90)
    vy = 0.02 * np.sin(2 * np.pi * k / 70) if holonomic else np.zeros(n)
    return np.column_stack([omega, vx, vy])


def truth(pose0, tw):
    poses = [np.asarray(pose0, float)]
    for step in tw:
        poses.append(integrate(poses[-1], step, "exact")[0])
    return np.array(poses)


def write_csv(path, header, rows):
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(rows)


def run_cli(tmp_path, robot, stream, columns, t, values, pose0):
    logdir = tmp_path / "log"
    logdir.mkdir()
    write_csv(logdir / f"{stream}.csv", ["t", *columns], np.column_stack([t, values]).tolist())
    config = {
        "log": "log",
        "robot": robot,
        "motion": {"integrator": "exact", "k": 1e-4},
        "estimator": "dead_reckoning",
        "initial": {"pose": [float(v) for v in pose0], "sigma": [0.01, 0.01, 0.01]},
        "output": "out",
    }
    cfg = tmp_path / "run.yaml"
    cfg.write_text(yaml.safe_dump(config))
    assert main(["run", str(cfg)]) == 0
    out = tmp_path / "out" / "trajectory.csv"
    assert out.read_text().splitlines()[0] == HEADER
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    return data


@pytest.mark.parametrize("drive_name", sorted(GEOMETRY))
def test_wheels_log_dead_reckons_to_the_true_pose(tmp_path, drive_name):
    drive = make_drive(drive_name, **GEOMETRY[drive_name])
    tw = twists(holonomic=drive_name in ("omni3", "mecanum4"))
    U = drive.inverse(tw)
    cumulative = np.vstack([np.zeros(U.shape[1]), np.cumsum(U, axis=0)])  # wheel angles, rad
    t = 100.0 + 0.1 * np.arange(len(cumulative))
    pose0 = np.array([1.0, -2.0, 3.0])
    data = run_cli(
        tmp_path,
        {"drive": drive_name, **GEOMETRY[drive_name]},
        "wheels",
        drive.input_names,
        t,
        cumulative,
        pose0,
    )
    expected = truth(pose0, tw)
    np.testing.assert_allclose(data[:, 0], t)
    assert np.abs(data[:, 1:3] - expected[:, :2]).max() < 1e-9
    assert np.abs(se2.wrap(data[:, 3] - expected[:, 2])).max() < 1e-9
    # covariance columns: a symmetric positive semi-definite matrix that grows with travel
    P = data[:, [4, 5, 6, 5, 7, 8, 6, 8, 9]].reshape(-1, 3, 3)
    assert np.all(np.linalg.eigvalsh(P) > -1e-12)
    assert P[-1, 0, 0] + P[-1, 1, 1] > P[0, 0, 0] + P[0, 1, 1]


def test_odometry_increments_log_dead_reckons_to_the_true_pose(tmp_path):
    tw = twists(holonomic=False)
    t = 5.0 + 0.2 * np.arange(1, len(tw) + 1)
    pose0 = np.array([0.0, 0.0, 4.2])
    data = run_cli(
        tmp_path,
        {"drive": "increments"},
        "odometry",
        ("ds", "dtheta"),
        t,
        np.column_stack([tw[:, 1], tw[:, 0]]),
        pose0,
    )
    expected = truth(pose0, tw)
    assert data.shape[0] == len(tw) + 1  # the initial pose, one period before the first row
    assert np.abs(data[:, 1:3] - expected[:, :2]).max() < 1e-9


@pytest.mark.parametrize(
    "robot",
    [
        {"drive": "tricycle", "wheel_radius": 0.1, "wheelbase": 0.8},
        {"drive": "bicycle", "wheel_radius": 0.3, "wheelbase": 2.5},
        {"drive": "ackermann", "wheel_radius": 0.3, "wheelbase": 2.5, "track_width": 1.5},
        {"drive": "synchro", "wheel_radius": 0.05},
    ],
    ids=lambda r: r["drive"],
)
def test_noise_free_simulated_steered_drives_dead_reckon_exactly(tmp_path, robot):
    # Steering columns: the row at t_{k+1} holds the angle held during step k, as written by the
    # simulator and read by the estimators; a noise-free log then dead-reckons to the truth.
    from odofuse.teaching.simulate import scenario_from_dict, simulate, write_log

    scenario = scenario_from_dict(
        {
            "seed": 1,
            "dt": 0.05,
            "robot": robot,
            "path": {"kind": "figure_eight", "radius": 4.0, "speed": 1.0, "laps": 1},
        },
        "<test>",
    )
    write_log(simulate(scenario), tmp_path / "log")
    config = yaml.safe_load((tmp_path / "log" / "config.yaml").read_text())
    config.update(log="log", estimator="dead_reckoning", output="out")
    (tmp_path / "run.yaml").write_text(yaml.safe_dump(config))
    assert main(["run", str(tmp_path / "run.yaml")]) == 0
    est = np.loadtxt(tmp_path / "out" / "trajectory.csv", delimiter=",", skiprows=1)
    gt = np.loadtxt(tmp_path / "log" / "groundtruth.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(est[:, 0], gt[:, 0])
    assert np.abs(est[:, 1:3] - gt[:, 1:3]).max() < 1e-9
