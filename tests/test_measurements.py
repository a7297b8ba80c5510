"""Measurement models, Euler error map and Kalman kernels against independent references.

Every H row is checked by central differences of the innovation z (computed - measured)
over the computed state, perturbed per error component with navd's conventions::

    C^ = Exp(-phi) C,  v^ = v + dv,  p^ = p + dp,  bg^ = bg - dbg  (so w^ = w + dbg),
    ba^ = ba - dba

and the innovation itself is compared with H dx when the measurement is generated from the
true state by an independent nonlinear model (ECEF geometry for the antenna position,
rigid-body velocity for the antenna velocity, atan2 for the course).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from navd.core import state as st
from navd.core.aiding import gnss_heading, gnss_position, gnss_velocity
from navd.core.kalman import gated_update, inject
from navd.core.output import euler_error_map
from navd.core.rotation import euler_to_mat

# ---------------------------------------------------------------- independent helpers
A_M = 6378137.0
FLAT = 1.0 / 298.257223563
E2 = FLAT * (2.0 - FLAT)


def sk(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def so3_exp(v: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(v))
    k = sk(v)
    if th < 1e-7:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + math.sin(th) / th * k + (1.0 - math.cos(th)) / th**2 * k @ k


def euler_mat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def euler_of(c: np.ndarray) -> np.ndarray:
    return np.array([math.atan2(c[2, 1], c[2, 2]), -math.asin(c[2, 0]),
                     math.atan2(c[1, 0], c[0, 0])])


def wrap(a: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(a) + math.pi) % (2.0 * math.pi) - math.pi


def to_ecef(p: np.ndarray) -> np.ndarray:
    lat, lon, h = p
    rn = A_M / math.sqrt(1.0 - E2 * math.sin(lat) ** 2)
    return np.array([(rn + h) * math.cos(lat) * math.cos(lon),
                     (rn + h) * math.cos(lat) * math.sin(lon),
                     (rn * (1.0 - E2) + h) * math.sin(lat)])


def from_ecef(r: np.ndarray) -> np.ndarray:
    x, y, z = r
    lon = math.atan2(y, x)
    rho = math.hypot(x, y)
    lat = math.atan2(z, rho * (1.0 - E2))
    h = 0.0
    for _ in range(12):
        rn = A_M / math.sqrt(1.0 - E2 * math.sin(lat) ** 2)
        h = rho / math.cos(lat) - rn
        lat = math.atan2(z, rho * (1.0 - E2 * rn / (rn + h)))
    return np.array([lat, lon, h])


def c_en(lat: float, lon: float) -> np.ndarray:
    """ECEF -> NED rotation."""
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])


def random_attitude(rng: np.random.Generator, max_pitch_deg: float = 30.0) -> np.ndarray:
    return euler_mat(rng.uniform(-0.8, 0.8), math.radians(rng.uniform(-max_pitch_deg,
                                                                       max_pitch_deg)),
                     rng.uniform(-math.pi, math.pi))


def perturb(state: dict, dx: np.ndarray) -> dict:
    """Computed state with error dx relative to ``state`` (navd conventions)."""
    return {
        "C": so3_exp(-dx[0:3]) @ state["C"],
        "v": state["v"] + dx[3:6],
        "p": state["p"] + dx[6:9],
        "bg": state["bg"] - dx[9:12],
        "ba": state["ba"] - dx[12:15],
    }


def unit(j: int, eps: float) -> np.ndarray:
    e = np.zeros(15)
    e[j] = eps
    return e


EPS = np.array([1e-5] * 3 + [1e-3] * 3 + [1e-8, 1e-8, 1e-2] + [1e-5] * 3 + [1e-4] * 3)
LATS_DEG = [0.0, 30.0, -45.0, 60.0, -60.0, 78.0]


def random_state(rng: np.random.Generator, lat_deg: float) -> dict:
    return {
        "C": random_attitude(rng, 30.0),
        "v": rng.normal(scale=10.0, size=3),
        "p": np.array([math.radians(lat_deg), rng.uniform(-math.pi, math.pi),
                       rng.uniform(-100.0, 3000.0)]),
        "bg": rng.normal(scale=1e-3, size=3),
        "ba": rng.normal(scale=0.05, size=3),
    }


def fd_jacobian(zfun, m: int) -> np.ndarray:  # type: ignore[no-untyped-def]
    Hn = np.zeros((m, 15))
    for j in range(15):
        Hn[:, j] = (zfun(unit(j, EPS[j])) - zfun(unit(j, -EPS[j]))) / (2.0 * EPS[j])
    return Hn


def assert_rows(H: np.ndarray, Hn: np.ndarray, rtol: float, atol: np.ndarray | float) -> None:
    bad = np.abs(H - Hn) > rtol * np.abs(Hn) + atol
    if bad.any():
        lines = [f"H[{i},{j}]: navd {H[i, j]:.9e} numerical {Hn[i, j]:.9e}"
                 for i, j in zip(*np.nonzero(bad), strict=True)]
        pytest.fail("; ".join(lines))


# ---------------------------------------------------------------- GNSS position
def pos_innovation(hat: dict, lever: np.ndarray, meas: np.ndarray) -> tuple[np.ndarray, ...]:
    H = np.full((4, 15), np.nan)
    z = np.full(4, np.nan)
    R = np.full((4, 4), np.nan)
    m = gnss_position.fill(H, z, R, np.ascontiguousarray(hat["C"]), hat["p"].copy(), lever,
                           float(meas[0]), float(meas[1]), float(meas[2]), 1.5, 3.0)
    assert m == 3
    return H[:3], z[:3].copy(), R[:3, :3]


def antenna_position(true: dict, lever: np.ndarray) -> np.ndarray:
    p = true["p"]
    return from_ecef(to_ecef(p) + c_en(p[0], p[1]).T @ (true["C"] @ lever))


@pytest.mark.parametrize("lat_deg", LATS_DEG)
def test_gnss_position_rows(lat_deg: float) -> None:
    """GIVEN random states at latitudes 0 to +-78 deg with random lever arms, and the antenna
    position measured by independent ECEF geometry,
    WHEN navd fills the GNSS position row,
    THEN the innovation is ~0 at the truth, R is diag(1.5^2, 1.5^2, 3^2), H matches central
    differences (up to the dropped second-order dD/dp), and z = H dx for a finite error."""
    rng = np.random.default_rng(int(200 + lat_deg))
    for _ in range(3):
        true = random_state(rng, lat_deg)
        lever = rng.normal(scale=1.0, size=3)
        meas = antenna_position(true, lever)
        H, z0, R = pos_innovation(true, lever, meas)
        # exact measurement of the true antenna: innovation ~ 0 (second order in |l|/R)
        assert np.all(np.abs(z0) < 1e-5), z0
        np.testing.assert_allclose(R, np.diag([1.5**2, 1.5**2, 3.0**2]), rtol=1e-14, atol=0)
        Hn = fd_jacobian(lambda dx: pos_innovation(perturb(true, dx), lever, meas)[1], 3)  # noqa: B023
        # H drops dD/dp (p^ - p_gnss), ~ |l| (1 + tan L) / R relative to D: second order
        col = np.abs(Hn).max(axis=0)
        assert_rows(H, Hn, 1e-6, 1e-6 * (1.0 + abs(math.tan(true["p"][0]))) * col + 1e-9)
        # independent model: z = H dx to second order for a finite error
        dx = np.concatenate([rng.normal(scale=2e-3, size=3), np.zeros(3),
                             rng.normal(scale=1e-6, size=2), rng.normal(scale=5.0, size=1),
                             np.zeros(6)])
        z = pos_innovation(perturb(true, dx), lever, meas)[1]
        np.testing.assert_allclose(z, H @ dx, rtol=0, atol=1e-4)


def test_gnss_position_antimeridian_and_sign() -> None:
    """GIVEN a state 2e-7 rad west of the antimeridian and a fix 4e-7 rad further east (across it),
    WHEN the position innovation is computed,
    THEN it is computed minus measured without wrapping: east component -4e-7 rad times the
    east radius, north and down 0."""
    true = {"C": euler_mat(0.1, 0.2, 3.0), "v": np.zeros(3),
            "p": np.array([0.5, math.pi - 2e-7, 100.0]), "bg": np.zeros(3),
            "ba": np.zeros(3)}
    lever = np.zeros(3)
    meas = antenna_position(true, lever)
    meas[1] = wrap(meas[1] + 4e-7)  # 4e-7 rad further east, across the antimeridian
    assert meas[1] < 0.0
    _, z, _ = pos_innovation(true, lever, meas)
    de = (A_M / math.sqrt(1 - E2 * math.sin(0.5) ** 2) + 100.0) * math.cos(0.5)
    # computed is west of measured: east component of (computed - measured) is negative
    np.testing.assert_allclose(z, [0.0, -4e-7 * de, 0.0], atol=1e-6)


# ---------------------------------------------------------------- GNSS velocity
def vel_innovation(hat: dict, w_true: np.ndarray, true_bg: np.ndarray, lever: np.ndarray,
                   meas: np.ndarray) -> tuple[np.ndarray, ...]:
    H = np.full((4, 15), np.nan)
    z = np.full(4, np.nan)
    R = np.full((4, 4), np.nan)
    rate_b = w_true + (true_bg - hat["bg"])  # compensated rate: w^ = w + dbg
    m = gnss_velocity.fill(H, z, R, np.ascontiguousarray(hat["C"]), hat["v"].copy(), rate_b,
                           lever, float(meas[0]), float(meas[1]), float(meas[2]), 0.2, 0.4)
    assert m == 3
    return H[:3], z[:3].copy(), R[:3, :3]


@pytest.mark.parametrize("lat_deg", LATS_DEG)
def test_gnss_velocity_rows(lat_deg: float) -> None:
    """GIVEN random states at latitudes 0 to +-78 deg, lever arms and body rates, and the antenna
    velocity from the rigid-body model v + C (w x l),
    WHEN navd fills the GNSS velocity row,
    THEN the innovation is 0 at the truth, R is diag(0.04, 0.04, 0.16), H matches central
    differences, and z = H dx for a finite error."""
    rng = np.random.default_rng(int(300 + lat_deg))
    for _ in range(3):
        true = random_state(rng, lat_deg)
        lever = rng.normal(scale=1.0, size=3)
        w = rng.normal(scale=0.7, size=3)
        # rigid body: the antenna moves with v + C (w x l) (earth rate x l, ~7e-5 m/s, omitted
        # by the model and here alike)
        meas = true["v"] + true["C"] @ np.cross(w, lever)
        H, z0, R = vel_innovation(true, w, true["bg"], lever, meas)
        np.testing.assert_allclose(z0, 0.0, atol=1e-12)
        np.testing.assert_allclose(R, np.diag([0.04, 0.04, 0.16]), rtol=1e-14, atol=0)

        def zf(dx: np.ndarray) -> np.ndarray:
            return vel_innovation(perturb(true, dx), w, true["bg"], lever, meas)[1]  # noqa: B023

        Hn = fd_jacobian(zf, 3)
        assert_rows(H, Hn, 1e-6, 1e-9)
        dx = np.concatenate([rng.normal(scale=2e-3, size=3), rng.normal(scale=0.3, size=3),
                             rng.normal(scale=1e-6, size=3), rng.normal(scale=2e-3, size=3),
                             rng.normal(scale=0.05, size=3)])
        np.testing.assert_allclose(zf(dx), H @ dx, rtol=0, atol=1e-4)


# ---------------------------------------------------------------- GNSS course (heading)
def course_innovation(hat_c: np.ndarray, vn: float, ve: float, row: int = 0,
                      r_v: np.ndarray | None = None, sd_h: float = 0.3,
                      sd_beta: float = 0.005) -> tuple[np.ndarray, float, np.ndarray]:
    H = np.full((4, 15), np.nan)
    z = np.full(4, np.nan)
    R = np.full((4, 4), np.nan)
    if r_v is not None:
        R[:3, :3] = r_v
    gnss_heading.course_row(H, z, R, row, np.ascontiguousarray(hat_c), np.zeros(3), np.zeros(3),
                            vn, ve, sd_h, sd_beta)
    return H[row].copy(), float(z[row]), R.copy()


@pytest.mark.parametrize("pitch_deg", [-30.0, -17.0, 0.0, 8.0, 22.0, 30.0])
def test_course_row(pitch_deg: float) -> None:
    """GIVEN attitudes pitched -30 to 30 deg at yaws around the circle, and a GNSS course within
    0.05 rad of the heading (possibly straddling +-pi),
    WHEN navd fills the course row,
    THEN the innovation is heading minus course (wrapped), H matches central differences, and its
    attitude part is the closed form of docs/design.md §4."""
    rng = np.random.default_rng(int(400 + pitch_deg))
    for yaw in [-3.1, -2.0, -0.4, 0.0, 1.1, 2.6, 3.1]:
        c = euler_mat(rng.uniform(-0.8, 0.8), math.radians(pitch_deg), yaw)
        chi = yaw + rng.uniform(-0.05, 0.05)  # course near heading, may straddle +-pi
        speed = rng.uniform(3.0, 30.0)
        vn, ve = speed * math.cos(chi), speed * math.sin(chi)
        H, z0, _ = course_innovation(c, vn, ve)
        assert abs(z0 - float(wrap(euler_of(c)[2] - math.atan2(ve, vn)))) < 1e-12
        assert abs(z0) < 0.06

        def zf(dx: np.ndarray, c: np.ndarray = c, vn: float = vn, ve: float = ve) -> np.ndarray:
            return np.array([course_innovation(so3_exp(-dx[0:3]) @ c, vn, ve)[1]])

        Hn = fd_jacobian(zf, 1)
        assert_rows(H[None, :], Hn, 1e-6, 1e-10)
        # docs/design.md §4 closed form
        tp = math.tan(math.radians(pitch_deg))
        np.testing.assert_allclose(H[:3], [-tp * math.cos(yaw), -tp * math.sin(yaw), -1.0],
                                   atol=1e-12)


def test_course_row_lever_arm_terms() -> None:
    """GIVEN an antenna on a lever arm of a rotating vehicle, so the course of
    v_gnss - C_hat (w_hat x l) depends on phi and on the gyro bias,
    WHEN navd fills the course row,
    THEN H matches finite differences through the nonlinear innovation, gyro-bias terms included."""
    rng = np.random.default_rng(77)
    for _ in range(6):
        c = euler_mat(rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-3, 3))
        lever = rng.normal(scale=1.0, size=3)
        w_true = rng.normal(scale=0.4, size=3)
        speed = rng.uniform(3.0, 12.0)
        v = c @ np.array([speed, 0.0, 0.0])
        meas = v + c @ np.cross(w_true, lever)

        def zf(dx: np.ndarray, c: np.ndarray = c, lever: np.ndarray = lever,
               w_true: np.ndarray = w_true, meas: np.ndarray = meas) -> np.ndarray:
            c_hat = so3_exp(-dx[0:3]) @ c
            w_hat = w_true + dx[9:12]
            v_c = meas - c_hat @ np.cross(w_hat, lever)
            z = np.full(4, np.nan)
            gnss_heading.course_row(np.zeros((4, 15)), z, np.zeros((4, 4)), 0,
                                    np.ascontiguousarray(c_hat), w_hat, lever,
                                    float(v_c[0]), float(v_c[1]), 0.1, 0.0)
            return np.array([z[0]])

        H = np.zeros((4, 15))
        v_c = meas - c @ np.cross(w_true, lever)
        gnss_heading.course_row(H, np.zeros(4), np.zeros((4, 4)), 0, np.ascontiguousarray(c),
                                w_true, lever, float(v_c[0]), float(v_c[1]), 0.1, 0.0)
        Hn = fd_jacobian(zf, 1)
        assert_rows(H[0:1], Hn, 1e-6, 1e-10)
        assert np.any(np.abs(H[0, 9:12]) > 1e-3)  # the bias terms are really there


def test_course_noise_matches_velocity_noise_propagation() -> None:
    """GIVEN random attitudes and velocities, a correlated GNSS velocity noise R_v and a sideslip
    sigma sb,
    WHEN the R of the joint (velocity, course) block and of a course-only row are filled,
    THEN the joint R is G R_v G^T + diag(0, 0, 0, sb^2), G the numerical Jacobian of the
    innovations in the velocity noise, and the course-only variance is sd_h^2 / v_h^2 + sb^2."""
    rng = np.random.default_rng(5)
    for _ in range(5):
        c = random_attitude(rng)
        v_true = rng.normal(scale=8.0, size=3)
        g = rng.normal(size=(3, 3))
        r_v = g @ g.T * 0.05 + 0.01 * np.eye(3)
        sd_beta = 0.004

        def innov(n: np.ndarray, c: np.ndarray = c, v_true: np.ndarray = v_true) -> np.ndarray:
            meas = v_true + n
            state = {"C": c, "v": v_true, "p": np.zeros(3), "bg": np.zeros(3),
                     "ba": np.zeros(3)}
            _, zv, _ = vel_innovation(state, np.zeros(3), np.zeros(3), np.zeros(3), meas)
            _, zc, _ = course_innovation(c, float(meas[0]), float(meas[1]))
            return np.concatenate([zv, [zc]])

        G = np.zeros((4, 3))
        for k in range(3):
            d = np.zeros(3)
            d[k] = 1e-5
            G[:, k] = (innov(d) - innov(-d)) / 2e-5
        want = G @ r_v @ G.T
        want[3, 3] += sd_beta**2
        _, _, R = course_innovation(c, float(v_true[0]), float(v_true[1]), row=3, r_v=r_v,
                                    sd_beta=sd_beta)
        np.testing.assert_allclose(R, want, rtol=1e-7, atol=1e-14)
        # course-only: isotropic horizontal sigma
        _, _, R0 = course_innovation(c, float(v_true[0]), float(v_true[1]), row=0, sd_h=0.3,
                                     sd_beta=sd_beta)
        vh2 = v_true[0] ** 2 + v_true[1] ** 2
        assert abs(R0[0, 0] - (0.09 / vh2 + sd_beta**2)) < 1e-15


# ---------------------------------------------------------------- Euler error map
def test_euler_error_map() -> None:
    """GIVEN attitudes pitched -80 to 75 deg with random roll and yaw,
    WHEN euler_error_map builds the map from the attitude error phi to the Euler-angle error,
    THEN it equals central differences of the Euler angles of Exp(-phi) C."""
    rng = np.random.default_rng(6)
    M = np.zeros((3, 3))
    for pitch_deg in [-80.0, -60.0, -30.0, 0.0, 15.0, 45.0, 75.0]:
        for _ in range(4):
            c = euler_mat(rng.uniform(-3.0, 3.0), math.radians(pitch_deg),
                          rng.uniform(-3.0, 3.0))
            euler_error_map(np.ascontiguousarray(c), M)
            Mn = np.zeros((3, 3))
            h = 1e-6
            for j in range(3):
                d = np.zeros(3)
                d[j] = h
                Mn[:, j] = wrap(euler_of(so3_exp(-d) @ c) - euler_of(so3_exp(d) @ c)) / (2 * h)
            np.testing.assert_allclose(M, Mn, rtol=1e-6, atol=1e-8)


# ---------------------------------------------------------------- Kalman kernels
def random_spd(rng: np.random.Generator, n: int, scale: np.ndarray) -> np.ndarray:
    g = rng.normal(size=(n, n))
    return (g @ g.T / n + 0.05 * np.eye(n)) * np.outer(scale, scale)


SCALE = np.array([1e-2] * 3 + [0.5] * 3 + [1e-6, 1e-6, 5.0] + [1e-3] * 3 + [0.05] * 3)


def run_update(x: np.ndarray, P: np.ndarray, H: np.ndarray, z: np.ndarray, R: np.ndarray,
               m: int, gate: float) -> tuple[float, np.ndarray, np.ndarray]:
    x2, P2 = x.copy(), P.copy()
    H4 = np.zeros((4, 15))
    H4[:m] = H
    z4 = np.zeros(4)
    z4[:m] = z
    R4 = np.eye(4)
    R4[:m, :m] = R
    nis = gated_update(x2, P2, H4, z4, R4, m, gate, np.zeros((4, 4)), np.zeros((4, 4)),
                       np.zeros(15), np.zeros(4))
    return nis, x2, P2


@pytest.mark.parametrize("m", [1, 2, 3, 4])
def test_gated_update_equals_textbook(m: int) -> None:
    """GIVEN random covariances, 1- to 4-row measurements with correlated noise, and zero or
    non-zero prior error states,
    WHEN gated_update runs ungated, then with a gate just above the NIS,
    THEN state and covariance equal the textbook Kalman update, P is exactly symmetric, the NIS
    is z^T S^-1 z (zero prior), and the gated run accepts with the same result."""
    rng = np.random.default_rng(40 + m)
    for trial in range(6):
        P = random_spd(rng, 15, SCALE)
        H = rng.normal(size=(m, 15)) / SCALE[None, :] * rng.uniform(0, 1, size=(m, 15))
        R = random_spd(rng, m, np.full(m, rng.uniform(0.1, 3.0)))  # correlated
        x = np.zeros(15) if trial % 2 == 0 else rng.normal(size=15) * SCALE * 0.1
        S = H @ P @ H.T + R
        z = rng.multivariate_normal(np.zeros(m), S)
        K = P @ H.T @ np.linalg.inv(S)
        x_want = x + K @ (z - H @ x)
        P_want = P - K @ S @ K.T
        nis, x_got, P_got = run_update(x, P, H, z, R, m, 0.0)
        if trial % 2 == 0:
            assert abs(nis - z @ np.linalg.solve(S, z)) <= 1e-9 * max(1.0, nis)
        d = 1.0 / SCALE
        np.testing.assert_allclose(x_got * d, x_want * d, rtol=0, atol=1e-9)
        np.testing.assert_allclose(P_got * np.outer(d, d), P_want * np.outer(d, d), rtol=0,
                                   atol=1e-9)
        np.testing.assert_array_equal(P_got, P_got.T)
        # accepted through a gate it passes
        nis2, x3, _ = run_update(x, P, H, z, R, m, nis + 1.0 if nis > 0 else 1.0)
        assert nis2 == nis and np.array_equal(x3, x_got)


@pytest.mark.parametrize(("hold", "more"), [(2, ()), (9, ()), (2, (0, 1, 9, 10, 11, 12, 13)),
                                          (-1, (0, 1, 12))])
def test_gated_update_with_a_held_state_is_the_schmidt_consider_update(
        hold: int, more: tuple[int, ...]) -> None:
    """GIVEN random covariances and 1-, 3- and 4-row measurements, with state 2 or 9 held, alone
    or with further states in ``hold_mask`` (the yaw bank's tilt-and-bias hold), or only those,
    WHEN gated_update runs with them held,
    THEN it is the Schmidt consider update (zero gain for every held state, the Joseph form for
    the covariance, valid for any gain), the held values and their covariance block are
    unchanged, and P stays positive definite."""
    held = sorted({hold, *more} - {-1})
    mask = sum(1 << i for i in more)
    rng = np.random.default_rng(70 + hold + mask % 7)
    for m in (1, 3, 4):
        P = random_spd(rng, 15, SCALE)
        H = rng.normal(size=(m, 15)) / SCALE[None, :] * rng.uniform(0, 1, size=(m, 15))
        R = random_spd(rng, m, np.full(m, rng.uniform(0.1, 3.0)))
        x = rng.normal(size=15) * SCALE * 0.1
        S = H @ P @ H.T + R
        z = rng.multivariate_normal(np.zeros(m), S)
        K = P @ H.T @ np.linalg.inv(S)
        K[held, :] = 0.0
        ikh = np.eye(15) - K @ H
        x_want = x + K @ (z - H @ x)
        P_want = ikh @ P @ ikh.T + K @ R @ K.T
        x2, P2 = x.copy(), P.copy()
        H4, z4, R4 = np.zeros((4, 15)), np.zeros(4), np.eye(4)
        H4[:m], z4[:m], R4[:m, :m] = H, z, R
        gated_update(x2, P2, H4, z4, R4, m, 0.0, np.zeros((4, 4)), np.zeros((4, 4)),
                     np.zeros(15), np.zeros(4), hold, mask)
        d = 1.0 / SCALE
        np.testing.assert_allclose(x2 * d, x_want * d, rtol=0, atol=1e-9)
        np.testing.assert_allclose(P2 * np.outer(d, d), P_want * np.outer(d, d), rtol=0,
                                   atol=1e-9)
        assert np.array_equal(x2[held], x[held])
        assert np.array_equal(P2[np.ix_(held, held)], P[np.ix_(held, held)])
        assert np.all(np.linalg.eigvalsh(P2) > 0.0)


def test_gated_update_rejection_leaves_state_untouched() -> None:
    """GIVEN a 4-row measurement about 10 sigma out,
    WHEN gated_update runs with the gate at half its NIS,
    THEN it returns minus the NIS and leaves x, P, H, z and R bit-for-bit untouched."""
    rng = np.random.default_rng(9)
    m = 4
    P = random_spd(rng, 15, SCALE)
    H = rng.normal(size=(m, 15)) / SCALE[None, :]
    R = random_spd(rng, m, np.ones(m))
    S = H @ P @ H.T + R
    z = 10.0 * np.linalg.cholesky(S) @ rng.normal(size=m)
    nis_true = z @ np.linalg.solve(S, z)
    x = np.zeros(15)
    H4 = np.zeros((4, 15))
    H4[:m] = H
    z4, R4 = z.copy(), R.copy()
    P2, x2 = P.copy(), x.copy()
    H5, z5, R5 = H4.copy(), z4.copy(), R4.copy()
    nis = gated_update(x2, P2, H5, z5, R5, m, 0.5 * nis_true, np.zeros((4, 4)),
                       np.zeros((4, 4)), np.zeros(15), np.zeros(4))
    assert nis < 0.0 and abs(-nis - nis_true) <= 1e-9 * nis_true
    assert np.array_equal(P2, P) and np.array_equal(x2, x)
    assert np.array_equal(H5, H4) and np.array_equal(z5, z4) and np.array_equal(R5, R4)


def test_gated_update_not_positive_definite() -> None:
    """GIVEN a zero covariance and a noise-free measurement (innovation covariance 0),
    WHEN gated_update runs,
    THEN it returns -inf and leaves the state and the covariance at zero."""
    P = np.zeros((15, 15))
    H = np.zeros((1, 15))
    H[0, 3] = 1.0
    nis, x, P2 = run_update(np.zeros(15), P, H, np.array([1.0]), np.array([[0.0]]), 1, 0.0)
    assert nis == -math.inf and not x.any() and not P2.any()


def test_inject_conventions() -> None:
    """GIVEN random true states and a computed state perturbed from each by an error state dx
    with navd's conventions,
    WHEN inject folds dx into the computed state,
    THEN dx is zeroed, the true state is recovered, and the attitude is C <- Exp(phi) C^."""
    rng = np.random.default_rng(12)
    for _ in range(5):
        true = random_state(rng, rng.uniform(-70, 70))
        dx = np.concatenate([rng.normal(scale=0.05, size=3), rng.normal(size=3),
                             rng.normal(scale=1e-5, size=2), rng.normal(scale=3.0, size=1),
                             rng.normal(scale=1e-3, size=3), rng.normal(scale=0.05, size=3)])
        hat = perturb(true, dx)
        c, v, p = hat["C"].copy(), hat["v"].copy(), hat["p"].copy()
        bg, ba = hat["bg"].copy(), hat["ba"].copy()
        x = dx.copy()
        inject(x, c, v, p, bg, ba, np.zeros((8, 3, 3)))
        assert not x.any()
        # folding in the exact error recovers the true state
        np.testing.assert_allclose(c, true["C"], atol=1e-14)
        np.testing.assert_allclose(v, true["v"], atol=1e-13)
        np.testing.assert_allclose(p, true["p"], rtol=1e-15, atol=1e-12)
        np.testing.assert_allclose(bg, true["bg"], atol=1e-16)
        np.testing.assert_allclose(ba, true["ba"], atol=1e-16)
        # and literally: C <- Exp(phi) C^
        np.testing.assert_allclose(c, so3_exp(dx[0:3]) @ hat["C"], atol=1e-15)


def test_gated_update_singular_measurement_covariance() -> None:
    """GIVEN a 2-row velocity measurement with fully correlated (singular, PSD) noise R, and a
    positive definite innovation covariance S,
    WHEN gated_update runs ungated,
    THEN the NIS, state and covariance equal the textbook Kalman update."""
    rng = np.random.default_rng(21)
    P = random_spd(rng, 15, SCALE)
    H = np.zeros((2, 15))
    H[0, 3] = 1.0
    H[1, 4] = 1.0
    R = np.array([[0.25, 0.25], [0.25, 0.25]])  # fully correlated noise: PSD, singular
    S = H @ P @ H.T + R
    assert np.linalg.eigvalsh(S)[0] > 0.0
    z = np.array([0.3, -0.2])
    K = P @ H.T @ np.linalg.inv(S)
    nis, x_got, P_got = run_update(np.zeros(15), P, H, z, R, 2, 0.0)
    assert abs(nis - z @ np.linalg.solve(S, z)) < 1e-9
    np.testing.assert_allclose(x_got / SCALE, (K @ z) / SCALE, atol=1e-9)
    np.testing.assert_allclose(P_got, P - K @ S @ K.T, atol=1e-12)


def test_a_heading_correction_turns_the_down_mismatch_with_it() -> None:
    """GIVEN a true attitude and an estimate 2 deg tilted and 40 deg off in heading,
    WHEN the estimate is turned by a heading correction d about down,
    THEN the mismatch of the estimated down direction, z - C^ C^T z (the filter's tilt
    through f x phi), turns by exactly d in navigation coordinates and stays fixed in the
    body: the frame fact behind navd.core.state.turn_tilt_cov."""
    z = np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(5)
    for _ in range(20):
        c_true = euler_mat(*rng.uniform(-0.5, 0.5, 2), rng.uniform(-math.pi, math.pi))
        tilt = np.append(rng.normal(size=2), 0.0)
        tilt *= 2 * math.pi / 180 / np.linalg.norm(tilt)
        c_hat = euler_mat(0.0, 0.0, 40 * math.pi / 180) @ so3_exp(tilt) @ c_true
        d = rng.uniform(-1.0, 1.0)
        rz = euler_mat(0.0, 0.0, d)
        m = z - c_hat @ c_true.T @ z
        m2 = z - rz @ c_hat @ c_true.T @ z
        np.testing.assert_allclose(m2, rz @ m, atol=1e-15)
        np.testing.assert_allclose(c_hat.T @ m, (rz @ c_hat).T @ m2, atol=1e-15)


def test_injection_turns_the_tilt_covariance_by_the_heading_correction() -> None:
    """GIVEN a random covariance and an error state whose heading part is d,
    WHEN the estimator's inject folds it in,
    THEN P's tilt rows and columns are turned by d about down (P <- G P G^T) and nothing
    else changes; with G = I (the common error-state reset, navd before 2026-11-27) the
    tilt / accelerometer-bias pairing stays in the old frame and later heading corrections
    separate tilt from bias with no information (tests/test_bench_info_floor.py)."""
    from navd.core import state as st

    rng = np.random.default_rng(3)
    for d in (0.0, 0.3, -1.2):
        buf = np.zeros(st.SIZE)
        buf[st.MAT:st.MAT + 9] = np.eye(3).ravel()
        buf[st.HIST_I] = -1.0
        a = rng.normal(size=(15, 15))
        p0 = a @ a.T + 15 * np.eye(15)
        buf[st.P:st.P + 225] = p0.ravel()
        buf[st.X:st.X + 3] = [0.01, -0.02, d]
        st.inject(buf)
        g = np.eye(15)
        g[0:2, 0:2] = [[math.cos(d), -math.sin(d)], [math.sin(d), math.cos(d)]]
        np.testing.assert_allclose(buf[st.P:st.P + 225].reshape(15, 15), g @ p0 @ g.T,
                                   rtol=0, atol=1e-12)
        assert not buf[st.X:st.X + 15].any()


def test_velocity_noise_of_an_uncertain_lever_arm() -> None:
    """GIVEN a body rate w, an attitude C and a lever arm whose error dl is N(0, s^2 I),
    WHEN the velocity block is filled with lever_var = s^2,
    THEN R grows by the covariance of C (w x dl): s^2 C [w x][w x]^T C^T, checked against
    the skew matrix written out and against 200,000 draws of dl (to 2 %); the course row,
    filled after it, carries J R_v J^T of the grown R; zero rate adds nothing."""
    rng = np.random.default_rng(5)
    C = euler_to_mat(0.3, -0.2, 2.1)
    w = np.array([0.4, -0.7, 1.1])
    s2 = 0.5 ** 2
    H = np.zeros((4, 15))
    z = np.zeros(4)
    R = np.zeros((4, 4))
    R0 = np.zeros((4, 4))
    args = (C, np.zeros(3), w, np.zeros(3), 1.0, 2.0, 0.5, 0.1, 0.2)
    gnss_velocity.fill(H, z, R0, *args)
    gnss_velocity.fill(H, z, R, *args, s2)
    wx = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    want = s2 * C @ wx @ wx.T @ C.T
    np.testing.assert_allclose(R[:3, :3] - R0[:3, :3], want, atol=1e-12)
    dl = rng.normal(0.0, 0.5, (200_000, 3))
    u = np.cross(w, dl) @ C.T
    np.testing.assert_allclose(np.cov(u.T), want, rtol=0.02, atol=2e-3)
    gnss_heading.course_row(H, z, R, 3, C, w, np.zeros(3), 1.0, 2.0, 0.1, 0.0)
    j = np.array([-2.0, 1.0, 0.0]) / 5.0
    assert R[3, 3] == pytest.approx(j @ R[:3, :3] @ j)
    R1 = np.zeros((4, 4))
    gnss_velocity.fill(H, z, R1, C, np.zeros(3), np.zeros(3), np.zeros(3), 1.0, 2.0, 0.5,
                       0.1, 0.2, s2)
    np.testing.assert_array_equal(R1, R0)


def _ring_of(a_of_t: list[tuple[float, np.ndarray]], t_end_s: float, dt_s: float) -> np.ndarray:
    """A state buffer whose history ring holds a level vehicle from 0 to ``t_end_s`` with
    the piecewise-constant NED acceleration ``a_of_t`` ((start s, (3,) m/s^2), ...) from
    rest at (0.5, 0.2) rad; the present state is the newest entry."""
    buf = np.zeros(st.SIZE)
    st.history_reset(buf)
    vel = np.zeros(3)
    n = round(t_end_s / dt_s) + 1
    for k in range(n):
        t = k * dt_s
        if k:
            a = [acc for t0, acc in a_of_t if t0 < t][-1]
            vel = vel + a * dt_s
        i = k % st.HIST_LEN
        o = st.HIST + i * st.HIST_W
        buf[o] = t * 1e6
        buf[o + 1:o + 10] = np.eye(3).ravel()
        buf[o + 10:o + 13] = vel
        buf[o + 13:o + 16] = (0.5, 0.2, 10.0)
        buf[st.HIST_I] = i
    buf[st.MAT:st.MAT + 9] = np.eye(3).ravel()
    buf[st.VEL:st.VEL + 3] = vel
    buf[st.POS:st.POS + 3] = (0.5, 0.2, 10.0)
    return buf


def test_gnss_noise_of_an_unknown_latency() -> None:
    """GIVEN a state history in which the vehicle accelerated at a1 until 3 s and at a2
    after (100 Hz, a ring of 5.12 s), and a fix whose latency is off by dt ~ N(0, s^2),
    WHEN the velocity and position blocks are filled with delay_var = s^2 at 4.5 s,
    THEN the velocity R grows by s^2 a2 a2^T (the covariance of the lag's error a2 dt; the
    newest second's acceleration, not the ring's mean) and the position R by s^2 v v^T (of
    v dt); a ring of less than 50 ms, and delay_var 0, add nothing."""
    a1 = np.array([0.0, 0.0, 0.0])
    a2 = np.array([1.5, -2.0, 0.3])
    buf = _ring_of([(-1.0, a1), (3.0, a2)], 4.5, 0.01)
    s2 = 0.1 ** 2
    rv = buf[st.R:st.R + 16].reshape(4, 4)
    st.fill_velocity(buf, 0.0, 0.0, 0.0, 0.2, 0.3, 0.0, 0.0)
    r0 = rv.copy()
    st.fill_velocity(buf, 0.0, 0.0, 0.0, 0.2, 0.3, 0.0, s2)
    np.testing.assert_allclose(rv[:3, :3] - r0[:3, :3], s2 * np.outer(a2, a2), rtol=1e-9,
                               atol=1e-12)
    vel = buf[st.VEL:st.VEL + 3].copy()
    st.fill_position(buf, 0.5, 0.2, 10.0, 1.0, 2.0, 0.0)
    p0 = rv.copy()
    st.fill_position(buf, 0.5, 0.2, 10.0, 1.0, 2.0, s2)
    np.testing.assert_allclose(rv[:3, :3] - p0[:3, :3], s2 * np.outer(vel, vel), rtol=1e-9,
                               atol=1e-12)
    short = _ring_of([(-1.0, a2)], 0.04, 0.01)
    st.fill_velocity(short, 0.0, 0.0, 0.0, 0.2, 0.3, 0.0, 0.0)
    r_short = short[st.R:st.R + 16].copy()
    st.fill_velocity(short, 0.0, 0.0, 0.0, 0.2, 0.3, 0.0, s2)
    np.testing.assert_array_equal(short[st.R:st.R + 16], r_short)
