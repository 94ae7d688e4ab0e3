"""Tests of odofuse.drives against the source formulas (shared/sources/*.txt)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.drives import (
    DRIVES,
    Ackermann,
    Bicycle,
    Differential,
    Generic,
    Increments,
    Mecanum4,
    Omni3,
    SkidSteer,
    Synchro,
    Tricycle,
    icr,
    make_drive,
    turn_drive_turn,
)
from odofuse.testing import numerical_jacobian

R, D, L, W = 0.05, 0.2, 0.3, 0.2  # wheel radius, MR's d, l, w (m)

ALL = {
    "differential": Differential(R, 2 * D),
    "differential_unequal": Differential(
        R, 2 * D, wheel_radius_left=0.049, wheel_radius_right=0.051
    ),
    "skid_steer": SkidSteer(R, 0.5, y_l=0.4, y_r=-0.3, x_G=0.07),
    "tricycle": Tricycle(0.1, 1.2),
    "ackermann": Ackermann(0.3, 2.5, 1.5),
    "bicycle": Bicycle(0.3, 2.5),
    "synchro": Synchro(0.04),
    "omni3": Omni3(R, D),
    "mecanum4": Mecanum4(R, L, W),
    "generic": Generic(
        0.06, [(0.3, 0.25), (0.3, -0.2), (-0.25, 0.0)], [0.3, -1.0, 2.0], [0.1, -0.4, 0.0]
    ),
    "increments": Increments(),
}


def random_inputs(drive, rng, N):
    """Random inputs: wheel increments in [-3, 3] rad, steering angles in (-1.2, 1.2) rad."""
    U = rng.uniform(-3.0, 3.0, size=(N, len(drive.input_names)))
    for j, kind in enumerate(drive.input_kinds):
        if kind == "steer":
            U[:, j] = rng.uniform(-1.2, 1.2, size=N)
    return U


def reachable_twists(drive, rng, N):
    """Random twists the drive can produce (range of its kinematics)."""
    if isinstance(drive, (Omni3, Mecanum4)) or (
        isinstance(drive, Generic) and drive.degree_of_mobility == 3
    ):
        return rng.uniform(-1.0, 1.0, size=(N, 3))
    if isinstance(drive, (Differential, SkidSteer, Generic)):
        return drive.twist(rng.uniform(-3.0, 3.0, size=(N, 2)))
    T = rng.uniform(-1.0, 1.0, size=(N, 3))
    T[:, 2] = 0.0
    if isinstance(drive, (Bicycle, Ackermann)):
        T[:, 1] = np.where(np.abs(T[:, 1]) < 0.1, 0.5, T[:, 1])  # away from steer = pi/2
    return T


# ---------------------------------------------------------------- reference matrices
def test_differential_is_mr_13_34_element_by_element():
    F = Differential(R, 2 * D).matrix()
    ref = R * np.array([[-1 / (2 * D), 1 / (2 * D)], [1 / 2, 1 / 2], [0, 0]])
    np.testing.assert_allclose(F, ref, rtol=0, atol=1e-15)
    assert F[0, 0] == pytest.approx(-0.125) and F[1, 1] == pytest.approx(0.025)
    # Politecnico slides 003: omega = (V_R - V_L) / L, V = (V_R + V_L) / 2
    t = Differential(R, 2 * D).twist([2.0, 5.0])
    assert t[0] == pytest.approx((5.0 * R - 2.0 * R) / (2 * D))
    assert t[1] == pytest.approx((5.0 * R + 2.0 * R) / 2)
    assert t[2] == 0.0


def test_omni3_is_mr_13_32_element_by_element():
    F = Omni3(R, D).matrix()
    s = 1 / (2 * math.sin(math.pi / 3))
    ref = R * np.array([[-1 / (3 * D)] * 3, [2 / 3, -1 / 3, -1 / 3], [0, -s, s]])
    np.testing.assert_allclose(F, ref, rtol=0, atol=1e-15)
    assert F[0, 0] == pytest.approx(-0.05 / 0.6)
    assert F[2, 2] == pytest.approx(0.05 / math.sqrt(3))


def test_mecanum4_is_mr_13_33_element_by_element():
    F = Mecanum4(R, L, W).matrix()
    k = 1 / (L + W)
    ref = R / 4 * np.array([[-k, k, k, -k], [1, 1, 1, 1], [-1, 1, -1, 1]])
    np.testing.assert_allclose(F, ref, rtol=0, atol=1e-15)
    assert F[0, 1] == pytest.approx(0.025)  # r / (4 (l + w)) = 0.05 / 2


def test_inverse_of_omni_and_mecanum_is_H0_of_mr_13_9_13_10():
    s3 = math.sin(math.pi / 3)
    H_omni = np.array([[-D, 1, 0], [-D, -0.5, -s3], [-D, -0.5, s3]]) / R
    H_mec = np.array([[-L - W, 1, -1], [L + W, 1, 1], [L + W, 1, -1], [-L - W, 1, 1]]) / R
    np.testing.assert_allclose(Omni3(R, D).inverse(np.eye(3)).T, H_omni, atol=1e-12)
    np.testing.assert_allclose(Mecanum4(R, L, W).inverse(np.eye(3)).T, H_mec, atol=1e-12)


# ---------------------------------------------------------------- Generic (MR 13.5 / 13.8)
def test_generic_reproduces_omni3_mecanum4_and_diff_drive():
    ang = [math.pi / 2, -math.pi / 6, 7 * math.pi / 6]  # wheel positions at angle, distance d
    omni = Generic(
        R,
        [(D * math.cos(a), D * math.sin(a)) for a in ang],
        [0.0, 4 * math.pi / 3, 2 * math.pi / 3],
        [0.0, 0.0, 0.0],
    )
    np.testing.assert_allclose(omni.matrix(), Omni3(R, D).matrix(), rtol=0, atol=1e-12)
    mec = Generic(
        R,
        [(L, W), (L, -W), (-L, -W), (-L, W)],
        [0.0] * 4,
        [-math.pi / 4, math.pi / 4, -math.pi / 4, math.pi / 4],
    )
    np.testing.assert_allclose(mec.matrix(), Mecanum4(R, L, W).matrix(), rtol=0, atol=1e-12)
    diff = Generic(R, [(0.0, D), (0.0, -D)], [0.0, 0.0], [0.0, 0.0], names=("left", "right"))
    np.testing.assert_allclose(diff.matrix(), Differential(R, 2 * D).matrix(), rtol=0, atol=1e-12)
    assert (omni.degree_of_mobility, mec.degree_of_mobility, diff.degree_of_mobility) == (3, 3, 2)
    assert diff.input_names == ("left", "right") and omni.input_names == ("w1", "w2", "w3")


def test_generic_rejects_bad_geometry():
    with pytest.raises(ValueError, match="positions"):
        Generic(R, [(0, 1, 2)], [0.0], [0.0])
    with pytest.raises(ValueError, match="roller_angles"):
        Generic(R, [(0, 1)], [0.0], [math.pi / 2])
    with pytest.raises(ValueError, match="driving_angles"):
        Generic(R, [(0, 1), (0, -1)], [0.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="wheel_radius"):
        Generic([R, -R], [(0, 1), (0, -1)], [0.0, 0.0], [0.0, 0.0])


# ---------------------------------------------------------------- Politecnico omni matrix
def test_politecnico_omni_matrix_maps_onto_mr_13_32():
    """003's omni matrix = MR 13.32 with all wheel signs flipped and the body frame rotated.

    003 gives [V_x, V_y, theta'] = F_P w. With w = -Delta theta (same numbering) and the 003
    body x axis along MR's -y axis: V_x = -v_y, V_y = v_x, theta' = omega (docs/drives.md).
    """
    r, Lp = R, D
    F_P = np.array(
        [
            [0, -r / math.sqrt(3), r / math.sqrt(3)],
            [-2 * r / 3, r / 3, r / 3],
            [r / (3 * Lp)] * 3,
        ]
    )
    F_MR = Omni3(r, D).matrix()  # rows omega, v_x, v_y
    wheel_sign = -np.eye(3)  # w = -Delta theta, same numbering
    frame = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]])  # [V_x, V_y, w]_P from [w, v_x, v_y]_MR
    np.testing.assert_allclose(F_P @ wheel_sign, frame @ F_MR, atol=1e-15)
    # a proper rotation of the components by +90 deg (the 003 frame is MR's turned by -90 deg)
    # that keeps omega
    Rp = frame[:2, 1:]
    assert np.linalg.det(Rp) == pytest.approx(1.0)
    np.testing.assert_allclose(
        Rp, [[math.cos(math.pi / 2), -math.sin(math.pi / 2)], [1, 0]], atol=1e-15
    )
    # and without the wheel sign flip no rotation of the plane fits (omega changes sign)
    assert np.allclose(F_P[2], -F_MR[0])


def test_politecnico_omni_mapping_is_unique_up_to_the_120_degree_symmetry():
    """Search all wheel renumberings and sign flips for which the 003 matrix is MR 13.32 seen
    from a rotated and/or shifted body frame (omega kept, planar block a rotation)."""
    import itertools

    r = R
    F_P = np.array(
        [[0, -r / math.sqrt(3), r / math.sqrt(3)], [-2 * r / 3, r / 3, r / 3], [r / (3 * D)] * 3]
    )
    F = Omni3(r, D).matrix()[[1, 2, 0]]  # rows v_x, v_y, omega
    found = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product([1, -1], repeat=3):
            P = np.zeros((3, 3))
            for i, j in enumerate(perm):
                P[j, i] = signs[i]  # Delta theta_MR = P w
            M = F_P @ np.linalg.inv(F @ P)
            planar = M[:2, :2]
            if (
                np.allclose(M[2], [0, 0, 1])
                and np.allclose(planar.T @ planar, np.eye(2))
                and np.linalg.det(planar) > 0
            ):
                found.append((perm, signs, math.degrees(math.atan2(planar[1, 0], planar[0, 0]))))
    assert len(found) == 3
    assert all(signs == (-1, -1, -1) for _, signs, _ in found)
    identity = [a for p, _, a in found if p == (0, 1, 2)]
    assert identity == [pytest.approx(90.0)]  # the mapping documented in docs/drives.md
    assert sorted(round(a) % 360 for *_, a in found) == [90, 210, 330]


# ---------------------------------------------------------------- skid steer (003)
def test_skid_steer_chi_1_equals_differential():
    sk, df = SkidSteer(R, 2 * D), Differential(R, 2 * D)
    assert sk.chi == 1.0
    np.testing.assert_array_equal(sk.matrix(), df.matrix())
    rng = np.random.default_rng(1)
    U = rng.normal(size=(50, 2))
    np.testing.assert_array_equal(sk.twist(U), df.twist(U))
    np.testing.assert_array_equal(SkidSteer.from_chi(R, 2 * D, 1.0).matrix(), df.matrix())


def test_skid_steer_is_the_slides_J_omega():
    yl, yr, xg, r = 0.4, -0.3, 0.07, R
    sk = SkidSteer(r, 0.5, y_l=yl, y_r=yr, x_G=xg)
    J = np.array([[-yr, yl], [xg, -xg], [-1, 1]]) / (yl - yr)  # rows v_x, v_y, omega_z
    wl, wr = 3.0, 7.0
    vx, vy, wz = J @ np.array([wl * r, wr * r])
    np.testing.assert_allclose(sk.twist([wl, wr]), [wz, vx, vy], atol=1e-15)
    # the slides' ICR definitions hold: y_l = (v_x - w_l r)/w_z, y_r = ..., x_G = -v_y / w_z
    assert (vx - wl * r) / wz == pytest.approx(yl)
    assert (vx - wr * r) / wz == pytest.approx(yr)
    np.testing.assert_allclose(sk.icr([wz, vx, vy]), [xg, vx / wz], atol=1e-15)
    assert sk.chi == pytest.approx(0.7 / 0.5)


def test_skid_steer_symmetric_case_and_from_chi():
    B, chi = 0.5, 1.6
    sk = SkidSteer.from_chi(R, B, chi)
    y0 = chi * B / 2
    assert (sk.y_l, sk.y_r, sk.chi) == pytest.approx((y0, -y0, chi))
    vl, vr = 0.2, 0.5  # slides: v_x = (v_l + v_r)/2, omega = (v_r - v_l)/(2 y0), v_y = 0
    t = sk.twist([vl / R, vr / R])
    np.testing.assert_allclose(t, [(vr - vl) / (2 * y0), (vl + vr) / 2, 0.0], atol=1e-15)
    # instantaneous radius R = lambda y0, lambda = (v_l + v_r)/(v_r - v_l)
    assert icr(t)[1] == pytest.approx((vl + vr) / (vr - vl) * y0)
    with pytest.raises(ValueError, match="chi"):
        SkidSteer.from_chi(R, B, 0.9)
    with pytest.raises(ValueError, match="y_l"):
        SkidSteer(R, B, y_l=0.2, y_r=-0.2)  # chi = 0.8 < 1


# ---------------------------------------------------------------- steered drives (003)
def test_tricycle_reference_values():
    tr = Tricycle(0.1, 1.2)
    ws, a = 4.0, 0.3
    Vs = ws * 0.1
    Rr = 1.2 * math.tan(math.pi / 2 - a)  # slides: R = d tan(pi/2 - alpha)
    t = tr.twist([ws, a])
    assert t[0] == pytest.approx(
        Vs / math.sqrt(1.2**2 + Rr**2)
    )  # slides: omega = V_s / sqrt(d^2+R^2)
    np.testing.assert_allclose(t, [Vs * math.sin(a) / 1.2, Vs * math.cos(a), 0.0], atol=1e-15)
    np.testing.assert_allclose(tr.twist([ws, 0.0]), [0, Vs, 0], atol=1e-15)  # straight
    np.testing.assert_allclose(
        tr.twist([ws, math.pi / 2]), [Vs / 1.2, 0, 0], atol=1e-15
    )  # in place
    np.testing.assert_allclose(tr.inverse([Vs / 1.2, 0, 0]), [ws, math.pi / 2], atol=1e-15)
    np.testing.assert_allclose(tr.inverse([-Vs / 1.2, 0, 0]), [ws, -math.pi / 2], atol=1e-15)
    np.testing.assert_allclose(tr.inverse([0, 0, 0]), [0, 0])


def test_bicycle_reference_and_singularity():
    bi = Bicycle(0.3, 2.5)
    t = bi.twist([2.0, 0.2])
    np.testing.assert_allclose(t, [0.6 * math.tan(0.2) / 2.5, 0.6, 0.0], atol=1e-15)
    assert icr(t)[1] == pytest.approx(2.5 / math.tan(0.2))  # slides: R = d / tan(alpha)
    with pytest.raises(ValueError, match="steer"):
        bi.twist([1.0, math.pi / 2])
    with pytest.raises(ValueError, match="spot"):
        bi.inverse([0.3, 0.0, 0.0])


def test_ackermann_inverse_matches_the_slides_per_wheel_formulas():
    """003 writes a right turn with positive magnitudes: R = d/tan(a_R) + b, etc."""
    d, b = 2.5, 0.75
    ak = Ackermann(0.3, d, 2 * b)
    omega, v = -0.2, 1.5  # right turn
    u = ak.inverse([omega, v, 0.0])
    Rs = abs(v / omega)
    w = abs(omega)
    aR, aL = abs(u[5]), abs(u[4])
    assert u[4] < 0 and u[5] < 0  # both wheels steer right
    assert Rs == pytest.approx(d / math.tan(aR) + b)
    assert aL == pytest.approx(math.atan(d / (Rs + b)))
    assert 0.3 * u[1] == pytest.approx(w * d / math.sin(aR))  # V_FR
    assert 0.3 * u[0] == pytest.approx(w * d / math.sin(aL))  # V_FL
    assert 0.3 * u[2] == pytest.approx(w * (Rs + b))  # V_BL
    assert 0.3 * u[3] == pytest.approx(w * (Rs - b))  # V_BR
    np.testing.assert_allclose(ak.twist(u), [omega, v, 0.0], atol=1e-14)


def test_ackermann_agrees_with_bicycle_for_consistent_inputs():
    ak, bi = Ackermann(0.3, 2.5, 1.5), Bicycle(0.3, 2.5)
    rng = np.random.default_rng(2)
    T = np.column_stack([rng.uniform(-0.4, 0.4, 40), rng.uniform(0.2, 3.0, 40), np.zeros(40)])
    T[::2, 1] *= -1  # reversing too
    U = ak.inverse(T)
    V = bi.inverse(T)
    np.testing.assert_allclose(ak.twist(U), bi.twist(V), atol=1e-12)
    # the bicycle's virtual wheels: mean of the rear wheels, cot(a) = mean of the cotangents
    np.testing.assert_allclose(V[:, 0], U[:, 2:4].mean(axis=1), atol=1e-12)
    cot = lambda a: np.cos(a) / np.sin(a)  # noqa: E731
    turning = np.abs(T[:, 0]) > 1e-3
    np.testing.assert_allclose(
        cot(V[turning, 1]), 0.5 * (cot(U[turning, 4]) + cot(U[turning, 5])), rtol=1e-10
    )


def test_ackermann_forward_is_least_squares_of_rolling_constraints():
    ak = Ackermann(0.3, 2.5, 1.5)
    d, b, r = 2.5, 0.75, 0.3
    rng = np.random.default_rng(3)
    for _ in range(20):
        u = random_inputs(ak, rng, 1)[0]  # inconsistent: wheels disagree
        dl, dr = u[4], u[5]
        A = np.array(
            [
                [d * math.sin(dl) - b * math.cos(dl), math.cos(dl), math.sin(dl)],
                [d * math.sin(dr) + b * math.cos(dr), math.cos(dr), math.sin(dr)],
                [-b, 1, 0],
                [b, 1, 0],
            ]
        )  # MR h_i(0) rows (gamma = 0) times r, columns omega, v_x, v_y
        z, *_ = np.linalg.lstsq(A[:, :2], r * u[:4], rcond=None)  # v_y = 0 (rear axle)
        np.testing.assert_allclose(ak.twist(u), [z[0], z[1], 0.0], atol=1e-12)


def test_ackermann_icr_lies_on_rear_axle():
    ak = Ackermann(0.3, 2.5, 1.5)
    T = np.array([[0.2, 1.0, 0.0], [-0.1, 2.0, 0.0], [0.3, -1.0, 0.0]])
    c = ak.icr(ak.twist(ak.inverse(T)))
    np.testing.assert_allclose(c[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(c[:, 1], T[:, 1] / T[:, 0], rtol=1e-12)


def test_synchro_and_increments_are_unicycles():
    sy = Synchro(0.04)
    np.testing.assert_allclose(sy.twist([10.0, 0.3]), [0.3, 0.4, 0.0], atol=1e-15)
    np.testing.assert_allclose(sy.travel([-10.0, -0.3]), [0.4, 0.3], atol=1e-15)
    inc = Increments()
    np.testing.assert_array_equal(inc.twist([1.5, -0.2]), [-0.2, 1.5, 0.0])
    np.testing.assert_array_equal(inc.travel([1.5, -0.2]), [1.5, 0.2])
    np.testing.assert_array_equal(inc.travel_scale(), [1.0, 1.0])


# ---------------------------------------------------------------- generic properties, every drive
@pytest.mark.parametrize("key", sorted(ALL))
def test_jacobian_matches_central_differences(key):
    drive = ALL[key]
    rng = np.random.default_rng(4)
    points = list(random_inputs(drive, rng, 5))
    steer = [j for j, k in enumerate(drive.input_kinds) if k == "steer"]
    special = [0.0, 1e-9, -0.7]
    if isinstance(drive, Tricycle):
        special += [math.pi / 2, -math.pi / 2]
    for s in special:  # singular / degenerate points: steering 0 (or +-pi/2), zero motion
        u = random_inputs(drive, rng, 1)[0]
        u[steer] = s
        points.append(u)
        z = u.copy()
        z[[j for j in range(len(u)) if j not in steer]] = 0.0
        points.append(z)
    for u in points:
        J = drive.J_twist_u(u)
        assert J.shape == (3, len(drive.input_names))
        np.testing.assert_allclose(J, numerical_jacobian(drive.twist, u), atol=1e-8, rtol=1e-7)


@pytest.mark.parametrize("key", sorted(ALL))
def test_inverse_round_trip(key):
    drive = ALL[key]
    rng = np.random.default_rng(5)
    T = reachable_twists(drive, rng, 30)
    U = drive.inverse(T)
    assert U.shape == (30, len(drive.input_names))
    np.testing.assert_allclose(drive.twist(U), T, atol=1e-12)
    np.testing.assert_allclose(drive.inverse(drive.twist(U)), U, atol=1e-10)


@pytest.mark.parametrize("key", sorted(ALL))
def test_batch_equals_loop(key):
    drive = ALL[key]
    rng = np.random.default_rng(6)
    U = random_inputs(drive, rng, 7)
    T = reachable_twists(drive, rng, 7)
    for fn, arg in (
        (drive.twist, U),
        (drive.J_twist_u, U),
        (drive.travel, U),
        (drive.inverse, T),
        (drive.icr, T),
    ):
        batch = fn(arg)
        loop = np.stack([fn(row) for row in arg])
        # equal up to BLAS summation order (matmul of a batch vs a row)
        np.testing.assert_allclose(batch, loop, rtol=1e-14, atol=1e-16)


@pytest.mark.parametrize("key", sorted(ALL))
def test_travel_is_metres_rolled(key):
    drive = ALL[key]
    rng = np.random.default_rng(7)
    U = random_inputs(drive, rng, 4)
    scale = drive.travel_scale()
    assert scale.shape == (len(drive.input_names),)
    np.testing.assert_allclose(drive.travel(U), np.abs(U) * scale, atol=0)
    for j, kind in enumerate(drive.input_kinds):
        assert (scale[j] == 0.0) == (kind == "steer")
        assert kind in ("wheel", "steer", "steer_increment", "increment")
    assert (drive.travel(-U) >= 0).all()


def test_travel_uses_each_wheels_radius():
    df = ALL["differential_unequal"]
    np.testing.assert_allclose(df.travel([1.0, -2.0]), [0.049, 0.102], atol=1e-15)
    np.testing.assert_allclose(
        ALL["ackermann"].travel([1, -1, 2, -2, 0.3, -0.3]), [0.3, 0.3, 0.6, 0.6, 0, 0]
    )


@pytest.mark.parametrize("key", sorted(ALL))
def test_degree_of_mobility(key):
    """Siegwart 004: delta_m = dimension of the twists reachable by changing wheel speeds
    with the steering held fixed (one ICR -> 1, a line of ICRs -> 2, anywhere -> 3)."""
    drive = ALL[key]
    rng = np.random.default_rng(8)
    u = random_inputs(drive, rng, 1)[0]
    if isinstance(drive, Ackermann):
        # four wheels on (omega, v_x, v_y): the no-side-slip constraints at Ackermann angles
        d, b = drive.wheelbase, drive.track_width / 2
        dl, dr = drive.inverse([0.3, 1.0, 0.0])[4:]
        rows = [
            [d * math.cos(dl) + b * math.sin(dl), -math.sin(dl), math.cos(dl)],
            [d * math.cos(dr) - b * math.sin(dr), -math.sin(dr), math.cos(dr)],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
        ]  # [x cos(delta) + y sin(delta), -sin(delta), cos(delta)] . (omega, v_x, v_y) = 0
        assert 3 - np.linalg.matrix_rank(np.array(rows)) == drive.degree_of_mobility == 1
        return
    wheels = [j for j, k in enumerate(drive.input_kinds) if k in ("wheel", "increment")]
    rank = np.linalg.matrix_rank(drive.J_twist_u(u)[:, wheels])
    assert rank == drive.degree_of_mobility
    steered = any(k in ("steer", "steer_increment") for k in drive.input_kinds)
    assert drive.degree_of_steerability == int(steered)


# ---------------------------------------------------------------- ICR
def test_icr_of_diff_drive_pure_rotation_is_the_centre():
    df = Differential(R, 2 * D)
    np.testing.assert_array_equal(df.icr(df.twist([-1.0, 1.0])), [0.0, 0.0])
    assert np.isinf(df.icr(df.twist([1.0, 1.0]))).all()
    assert np.isinf(icr([0.0, 0.0, 0.0])).all()
    # slides 003: ICC at R = L/2 (V_R + V_L)/(V_R - V_L) to the left
    vl, vr = 1.0 * R, 3.0 * R
    np.testing.assert_allclose(df.icr(df.twist([1.0, 3.0])), [0.0, D * (vr + vl) / (vr - vl)])


def test_icr_of_a_rigid_body_has_zero_velocity():
    rng = np.random.default_rng(9)
    T = rng.normal(size=(20, 3))
    P = icr(T)
    vel = T[:, 1:] + T[:, :1] * np.column_stack([-P[:, 1], P[:, 0]])  # v + omega e_z x p
    np.testing.assert_allclose(vel, 0.0, atol=1e-12)


# ---------------------------------------------------------------- inverse errors and input checks
@pytest.mark.parametrize(
    "key", ["differential", "skid_steer", "tricycle", "ackermann", "bicycle", "synchro"]
)
def test_nonholonomic_inverse_rejects_sideways_twist(key):
    with pytest.raises(ValueError, match="row 1"):
        drive = ALL[key]
        ok = drive.twist(random_inputs(drive, np.random.default_rng(11), 1)[0])
        drive.inverse([ok, ok + [0.0, 0.0, 0.5]])


def test_input_shape_and_finiteness_checks():
    df = Differential(R, 2 * D)
    with pytest.raises(ValueError, match=r"\(2,\)"):
        df.twist([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="row 1, column 'right'"):
        df.twist([[1.0, 2.0], [1.0, np.nan]])
    with pytest.raises(ValueError, match="track_width"):
        Differential(R, -1.0)
    with pytest.raises(ValueError, match="wheel_radius"):
        Tricycle("0.1", 1.0)


# ---------------------------------------------------------------- registry
def test_make_drive_registry_and_errors():
    assert set(DRIVES) >= {
        "differential",
        "skid_steer",
        "tricycle",
        "ackermann",
        "bicycle",
        "synchro",
        "omni3",
        "mecanum4",
        "increments",
        "generic",
    }
    for name, cls in DRIVES.items():
        assert cls.name == name
    d = make_drive("differential", wheel_radius=0.04, track_width=0.235)
    assert d == Differential(0.04, 0.235)
    assert make_drive("increments") == Increments()
    assert make_drive(
        "odofuse.drives:Mecanum4", wheel_radius=R, half_length=L, half_width=W
    ) == Mecanum4(R, L, W)
    with pytest.raises(ValueError, match="unknown drive 'hovercraft'"):
        make_drive("hovercraft")
    with pytest.raises(ValueError, match="'wheel_base'"):
        make_drive("tricycle", wheel_radius=0.1, wheel_base=1.0)
    with pytest.raises(ValueError, match="'track_width'"):
        make_drive("differential", wheel_radius=0.1)
    with pytest.raises(ValueError, match="no_such_module"):
        make_drive("no_such_module:Drive")
    with pytest.raises(ValueError, match="has no 'Nope'"):
        make_drive("odofuse.drives:Nope")


# ---------------------------------------------------------------- closed loops, integrated
def _stadium(drive, rng):
    """Reachable body twists of a closed stadium: straight, half turn, straight, half turn.

    A half turn (total rotation pi about the body-frame ICR c) moves the origin by 2c and
    reverses the heading; after the second straight and half turn the displacements cancel.
    """
    if isinstance(drive, SkidSteer):
        u_turn = np.array([1.0, 2.0])  # turning with x_G != 0 has v_y = -x_G omega
    else:
        u_turn = drive.inverse([0.2, 0.4, 0.0])
    turn = drive.twist(u_turn)
    k = 9
    turn = turn * (math.pi / k) / turn[0]  # k equal steps of pi / k
    speeds = rng.uniform(0.05, 0.5, 5)
    straight = [np.array([0.0, v, 0.0]) for v in speeds]
    return straight + [turn] * k + straight[::-1] + [turn] * k


@pytest.mark.parametrize("key", sorted(ALL))
def test_noise_free_closed_loop_returns_to_start(key):
    """Twists -> inverse kinematics -> wheel inputs -> twist -> motion.integrate(exact)."""
    from odofuse import motion, se2

    drive = ALL[key]
    rng = np.random.default_rng(12)
    twists = _stadium(drive, rng)
    if drive.degree_of_mobility == 3:  # strafe a square and spin on the spot as well
        a = 0.3
        twists += [np.array(t) for t in ([0, a, 0], [0, 0, a], [0.5, 0, 0], [-0.5, 0, 0])]
        twists += [np.array(t) for t in ([0, -a, 0], [0, 0, -a])]
    U = drive.inverse(np.array(twists))
    start = np.array([1.5, -2.0, 3.0])
    pose = start
    for u in U:
        pose = motion.integrate(pose, drive.twist(u), "exact")[0]
    assert np.hypot(*(pose[:2] - start[:2])) < 1e-9
    assert abs(se2.wrap(pose[2] - start[2])) < 1e-9
    # and the loop is not trivial: it goes somewhere in between
    mid = start
    for u in U[: len(U) // 2]:
        mid = motion.integrate(mid, drive.twist(u), "exact")[0]
    assert np.hypot(*(mid[:2] - start[:2])) > 0.5


# ---------------------------------------------------------------- turn-drive-turn
def test_turn_drive_turn_reaches_goal():
    from odofuse import motion, se2

    rng = np.random.default_rng(10)
    for _ in range(20):
        start = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-math.pi, math.pi)])
        goal = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-math.pi, math.pi)])
        segs = turn_drive_turn(start, goal)
        assert segs.shape == (3, 3)
        assert segs[0, 1:].tolist() == [0, 0] and segs[2, 1:].tolist() == [0, 0]
        assert segs[1, 0] == 0 and segs[1, 2] == 0 and segs[1, 1] >= 0
        assert (np.abs(segs[[0, 2], 0]) <= math.pi).all()
        pose = start
        for t in segs:
            pose = motion.integrate(pose, t, "exact")[0]
        np.testing.assert_allclose(pose[:2], goal[:2], atol=1e-12)
        assert abs(se2.wrap(pose[2] - goal[2])) < 1e-12
    np.testing.assert_allclose(
        turn_drive_turn([1, 1, 0.5], [1, 1, -0.5]), [[0, 0, 0], [0, 0, 0], [-1, 0, 0]]
    )


# ---------------------------------------------------------------- odofuse.testing helper
def test_numerical_jacobian_wraps_angle_rows():
    def f(x):  # heading of a point: jumps from +pi to -pi across the negative x axis
        return np.array([math.atan2(x[1], x[0]), x[0] * x[1]])

    x = np.array([-2.0, 0.0])
    J = numerical_jacobian(f, x, wrap_rows=[0])
    np.testing.assert_allclose(J, [[0.0, x[0] / (x @ x)], [x[1], x[0]]], atol=1e-9)
    assert abs(numerical_jacobian(f, x)[0, 1]) > 1e5  # unwrapped: the 2 pi jump / (2 eps)
    with pytest.raises(ValueError, match="wrap_rows"):
        numerical_jacobian(f, x, wrap_rows=[5])
    with pytest.raises(ValueError, match="shape"):
        numerical_jacobian(f, np.zeros((2, 2)))
