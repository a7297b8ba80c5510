"""WGS-84 and SO(3) helpers against known values (published constants, closed forms)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from navd.core import earth, rotation

DEG = math.pi / 180.0


def test_wgs84_derived_constants() -> None:
    """GIVEN the WGS-84 defining constants in navd.core.earth,
    WHEN the derived semi-minor axis b and eccentricity squared e^2 are read,
    THEN they match NIMA TR8350.2 (b = 6356752.3142 m, e^2 = 6.69437999014e-3)."""
    # NIMA TR8350.2: b = 6356752.3142 m, e^2 = 6.69437999014e-3
    b, e2 = earth.B_M, earth.E2
    assert b == pytest.approx(6356752.3142, abs=1e-4)
    assert e2 == pytest.approx(6.69437999014e-3, rel=1e-11)


def test_radii_at_equator_and_pole() -> None:
    """GIVEN the equator (latitude 0) and the pole (latitude 90 deg),
    WHEN earth.radii computes the meridian and prime-vertical radii,
    THEN at the equator R_N = a and R_M = a (1 - e^2), and at the pole both equal a^2 / b."""
    r_m, r_n = earth.radii(0.0)
    assert r_n == pytest.approx(earth.A_M, abs=1e-6)
    assert r_m == pytest.approx(earth.A_M * (1 - earth.E2), abs=1e-6)  # 6335439.327 m
    r_m, r_n = earth.radii(math.pi / 2)
    # at the pole both equal a^2 / b = 6399593.626 m
    assert r_m == pytest.approx(6399593.6258, abs=1e-3)
    assert r_n == pytest.approx(6399593.6258, abs=1e-3)


def test_normal_gravity_known_values() -> None:
    """GIVEN points on the ellipsoid at the equator, the pole and 45 deg latitude,
    WHEN earth.gravity and earth.gravity_derivs evaluate normal gravity and its derivatives,
    THEN the values match TR8350.2 (Somigliana), the height gradient is the free-air
    -3.086e-6 s^-2, and the latitude derivative is positive and matches a central difference."""
    # Somigliana on the ellipsoid: equator and pole values of TR8350.2
    assert earth.gravity(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-9)
    assert earth.gravity(math.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-9)
    # 45 deg: 9.806199203 m/s^2 (TR8350.2 table)
    assert earth.gravity(45 * DEG, 0.0) == pytest.approx(9.806199, abs=2e-6)
    # free-air gradient near the surface ~ -3.086e-6 s^-2
    dg_dl, dg_dh = earth.gravity_derivs(45 * DEG, 0.0)
    assert dg_dh == pytest.approx(-3.086e-6, rel=3e-3)
    h = 1e-3
    num = (earth.gravity(45 * DEG + h, 100.0) - earth.gravity(45 * DEG - h, 100.0)) / (2 * h)
    assert earth.gravity_derivs(45 * DEG, 100.0)[0] == pytest.approx(num, rel=1e-6)
    assert dg_dl > 0


def test_geodetic_ecef_known_points() -> None:
    """GIVEN known geodetic points (equator/prime meridian, pole, 90E at 100 m, 45N 45E),
    WHEN earth.geodetic_to_ecef converts them,
    THEN the ECEF coordinates equal the closed-form / textbook values."""
    assert earth.geodetic_to_ecef(0.0, 0.0, 0.0) == pytest.approx((earth.A_M, 0.0, 0.0))
    x, y, z = earth.geodetic_to_ecef(math.pi / 2, 0.0, 0.0)
    assert (x, y, z) == pytest.approx((0.0, 0.0, earth.B_M), abs=1e-6)
    x, y, z = earth.geodetic_to_ecef(0.0, math.pi / 2, 100.0)
    assert (x, y, z) == pytest.approx((0.0, earth.A_M + 100.0, 0.0), abs=1e-6)
    # the textbook case 45N 45E on the ellipsoid: (3194419.145, 3194419.145, 4487348.409) m
    x, y, z = earth.geodetic_to_ecef(45 * DEG, 45 * DEG, 0.0)
    assert (x, y, z) == pytest.approx((3194419.145, 3194419.145, 4487348.409), abs=2e-3)


@settings(max_examples=300, deadline=None)
@given(st.floats(-89.9, 89.9), st.floats(-180.0, 180.0), st.floats(-500.0, 1e5))
def test_ecef_round_trip(lat: float, lon: float, h: float) -> None:
    """GIVEN any latitude in +-89.9 deg, longitude and height from -500 m to 100 km,
    WHEN the point is converted to ECEF and back with earth.ecef_to_geodetic,
    THEN latitude and (wrapped) longitude return within 1e-11 rad and height within 1e-6 m."""
    x, y, z = earth.geodetic_to_ecef(lat * DEG, lon * DEG, h)
    la, lo, hh = earth.ecef_to_geodetic(x, y, z)
    assert la == pytest.approx(lat * DEG, abs=1e-11)
    assert ((lo - lon * DEG + math.pi) % (2 * math.pi) - math.pi) == pytest.approx(0, abs=1e-11)
    assert hh == pytest.approx(h, abs=1e-6)


def test_mat_ne_maps_known_directions() -> None:
    """GIVEN the ECEF-to-NED matrix earth.mat_ne at 30N 60E,
    WHEN it is applied to the ellipsoid normal, the earth's axis and NED east,
    THEN it is orthonormal, the normal maps to -D, the axis maps to (cos L, 0, -sin L),
    and the east direction has no ECEF z component."""
    lat, lon = 30 * DEG, 60 * DEG
    c = earth.mat_ne(lat, lon)
    np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-15)
    # the ECEF direction of the ellipsoid normal (up) maps to -D
    up_e = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon),
                     math.sin(lat)])
    np.testing.assert_allclose(c @ up_e, [0, 0, -1], atol=1e-15)
    # the earth's axis maps to (cos L, 0, -sin L): north and up components
    np.testing.assert_allclose(c @ [0, 0, 1], [math.cos(lat), 0, -math.sin(lat)], atol=1e-15)
    # an eastward displacement changes only the longitude
    e_e = c.T @ np.array([0.0, 1.0, 0.0])
    assert e_e[2] == pytest.approx(0.0, abs=1e-15)


def test_euler_known_matrices() -> None:
    """GIVEN single 90 deg rotations in yaw, pitch and roll,
    WHEN rotation.euler_to_mat builds the body-to-NED matrix,
    THEN body x points east (yaw), body x points up (pitch) and body y points down (roll)."""
    # yaw 90 deg: body x points east
    c = rotation.euler_to_mat(0.0, 0.0, math.pi / 2)
    np.testing.assert_allclose(c @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    # pitch 90 deg nose up: body x points up (-D)
    c = rotation.euler_to_mat(0.0, math.pi / 2, 0.0)
    np.testing.assert_allclose(c @ [1, 0, 0], [0, 0, -1], atol=1e-15)
    # roll 90 deg right wing down: body y points down
    c = rotation.euler_to_mat(math.pi / 2, 0.0, 0.0)
    np.testing.assert_allclose(c @ [0, 1, 0], [0, 0, 1], atol=1e-15)


@settings(max_examples=300, deadline=None)
@given(st.floats(-3.1, 3.1), st.floats(-1.55, 1.55), st.floats(-3.14, 3.14))
def test_euler_quaternion_dcm_round_trips(r: float, p: float, y: float) -> None:
    """GIVEN any roll, pitch (away from +-90 deg) and yaw,
    WHEN the Euler angles go to a DCM, back to Euler, and the DCM to a quaternion and back,
    THEN the angles and the DCM are recovered and the quaternion is unit norm with q0 >= 0."""
    c = rotation.euler_to_mat(r, p, y)
    np.testing.assert_allclose(rotation.mat_to_euler(c), (r, p, y), atol=1e-9)
    q = rotation.mat_to_quat(c)
    assert q[0] >= 0.0 and sum(v * v for v in q) == pytest.approx(1.0)
    np.testing.assert_allclose(rotation.quat_to_mat(q), c, atol=1e-14)


def test_quaternion_of_known_rotation() -> None:
    """GIVEN a 90 deg yaw rotation (about down),
    WHEN rotation.mat_to_quat converts its DCM,
    THEN the quaternion is (cos 45 deg, 0, 0, sin 45 deg)."""
    # 90 deg about down (yaw): q = (cos 45, 0, 0, sin 45)
    q = rotation.mat_to_quat(rotation.euler_to_mat(0.0, 0.0, math.pi / 2))
    assert q == pytest.approx((math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3), st.floats(0.0, 3.1))
def test_exp_log_inverse(axis: list[float], angle: float) -> None:
    """GIVEN any rotation vector with angle in [0, 3.1] rad (near-zero axes skipped),
    WHEN rotation.exp_so3 maps it to a matrix and rotation.log_vec maps it back,
    THEN the matrix is a proper rotation and the log returns the original vector."""
    a = np.array(axis)
    n = np.linalg.norm(a)
    if n < 1e-3:
        return
    v = a / n * angle
    m = rotation.exp_so3(v)
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(m) == pytest.approx(1.0)
    np.testing.assert_allclose(rotation.log_vec(m), v, atol=1e-9)


def test_exp_small_angle_and_skew() -> None:
    """GIVEN a nano-radian rotation vector and a 90 deg rotation about z,
    WHEN rotation.exp_so3 and rotation.skew are evaluated,
    THEN the small-angle exp equals I + skew(v), skew(v) @ w equals v x w,
    and the 90 deg case equals the Rodrigues matrix."""
    v = np.array([1e-9, -2e-9, 3e-9])
    np.testing.assert_allclose(rotation.exp_so3(v), np.eye(3) + rotation.skew(v), atol=1e-24)
    w = np.array([0.3, -0.1, 2.0])
    np.testing.assert_allclose(rotation.skew(v) @ w, np.cross(v, w), atol=1e-24)
    # Rodrigues at a known angle: 90 deg about z
    np.testing.assert_allclose(rotation.exp_so3(np.array([0, 0, math.pi / 2])),
                               [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)


def test_log_near_pi() -> None:
    """GIVEN a rotation of pi - 1e-9 rad about z,
    WHEN it is mapped through exp_so3 and back through log_vec,
    THEN the recovered angle about z has the same magnitude (sign free) within 1e-6."""
    v = np.array([0.0, 0.0, math.pi - 1e-9])
    out = rotation.log_vec(rotation.exp_so3(v))
    assert abs(abs(out[2]) - v[2]) < 1e-6


def test_wrap_pi() -> None:
    """GIVEN angles 3 pi, -pi and 0.5 rad,
    WHEN rotation.wrap_pi wraps them,
    THEN they map to pi, pi and 0.5: the range is (-pi, pi]."""
    assert rotation.wrap_pi(3 * math.pi) == pytest.approx(math.pi)
    assert rotation.wrap_pi(-math.pi) == pytest.approx(math.pi)
    assert rotation.wrap_pi(0.5) == pytest.approx(0.5)


@settings(max_examples=200, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-1.4, 1.4), st.floats(-math.pi, math.pi),
       st.lists(st.floats(-1.0, 1.0, allow_subnormal=False), min_size=3, max_size=3))
def test_zyx_yaw_error_is_azimuth_misalignment_plus_tan_pitch_tilt(
        r: float, p: float, y: float, axis: list[float]) -> None:
    """ZYX yaw is the nose's azimuth, so an attitude error phi (C_hat = Exp(-phi) C, NED)
    moves it by -(phi_D + tan(pitch) * phi . h), h the horizontal unit vector along the nose:
    the heading misalignment phi_D plus a tilt about h amplified by tan(pitch).  This is
    why benchmarks/polarization.py scores heading as phi_D and prints ZYX yaw beside it."""
    v = np.array(axis)
    if np.linalg.norm(v) < 1e-3:
        return
    phi = 1e-6 * v / np.linalg.norm(v)
    c = rotation.euler_to_mat(r, p, y)
    c_hat = rotation.exp_so3(-phi) @ c
    d_yaw = rotation.wrap_pi(rotation.mat_to_euler(c_hat)[2] - y)
    h = np.array([math.cos(y), math.sin(y), 0.0])
    predicted = -(phi[2] + math.tan(p) * float(phi @ h))
    assert d_yaw == pytest.approx(predicted, rel=1e-3, abs=1e-11)
