"""`navd dov-grid`: the normal field, EGM96 through gravitas, and published reference values.

Reference values: GeographicLib's ``Gravity -n egm96 -p 13`` (C. Karney), as recorded in
the test suite of the ``geomodels`` package (avalentino/geomodels,
geomodels/test/test_gravity.py): gravity (-G), gravity disturbance (-D) and the spherical
deflections (-A) at the summit of Mount Everest (27:59:17N 86:55:32E, h = 8820 m) and at
four points near 17 deg at 300 m and 400 km height.  Components there are east, north, up.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from navd.cli.dov_grid import main
from navd.core.aiding.dov import ARCSEC, MGAL
from navd.core.earth import gravity
from navd.eval.gravity_model import (
    Egm96Gravitas,
    NormalField,
    classical_dov,
    disturbance_ned,
    gravity_ned,
    mechanization_dov,
    normal_j2,
)
from navd.io.dov_grid import load_dov_grid

Arr = npt.NDArray[np.float64]


def dms(d: float, m: float, s: float) -> float:
    return math.copysign(abs(d) + m / 60.0 + s / 3600.0, d)


# lat, lon (deg), h (m); -G gx gy gz (m/s^2, E N U); -D (mGal, E N U); -A Dg01, xi", eta"
GEOGRAPHICLIB_EGM96 = [
    ((dms(27, 59, 17), dms(86, 55, 32), 8820.0),
     (-0.0002103214548, 0.0008380880427, -9.7665319359240),
     (-21.0321454784042, 89.7584990506496, -199.4330543962868),
     (208.0275697808106, -18.8435137999035, 4.4428027084385)),
    ((dms(16, 46, 33), -dms(3, 0, 34), 300.0),
     (-0.0000185562383, -0.0000022160340, -9.7839489045745),
     (-1.8556238327792, -0.0864975107851, -24.6995051809167),
     (15.7255802520963, 0.0278739163708, 0.3912117252501)),
    ((-dms(16, 46, 43), dms(3, 0, 44), 400000.0),
     (0.0000171252863, 0.0016776569530, -8.6568801936947),
     (1.7125286304307, -4.2925736778895, -3.77044400298770),
     (-0.28121454847100, 1.0212161827314, -0.4080406679571)),
    ((-dms(16, 56, 33), dms(3, 10, 34), 400000.0),
     (0.0000179414111, 0.0016913972644, -8.6569658422907),
     (1.7941411100352, -4.3994466419252, -3.89353944957160),
     (-0.19222301397180, 1.0466052916775, -0.4274821365431)),
    ((dms(16, 56, 43), -dms(3, 10, 44), 300.0),
     (0.0000255265776, -0.0000471425191, -9.7840427535630),
     (2.5526577571442, -4.5779437005530, -25.6012585484130),
     (16.6326172077381, 0.9752134528843, -0.5381591725495)),
]


@pytest.fixture(scope="module")
def egm96() -> Egm96Gravitas:
    return Egm96Gravitas(360)


def _one(lat_deg: float, lon_deg: float) -> tuple[Arr, Arr]:
    return np.array([math.radians(lat_deg)]), np.array([math.radians(lon_deg)])


def test_normal_field_j2_is_the_published_wgs84_value() -> None:
    """GIVEN navd's WGS-84 normal gravity field,
    WHEN its J2 is converted to the normalized C20,
    THEN it equals NIMA TR8350.2's -0.484166774985e-3 to 1e-11 relative."""
    # NIMA TR8350.2 (WGS 84), normalized C20 of the ellipsoidal (normal) field
    assert -normal_j2() / math.sqrt(5.0) == pytest.approx(-0.484166774985e-3, rel=1e-11)


@pytest.mark.parametrize("h_m", [0.0])
def test_normal_field_has_zero_deflection_on_the_ellipsoid(h_m: float) -> None:
    """The DOV of the pure normal field (even zonals J2..J20 of WGS-84) is zero with respect
    to the ellipsoid normal, and its magnitude is Somigliana's, everywhere."""
    lat = np.radians(np.linspace(-89.0, 89.0, 37))
    lon = np.radians(np.linspace(-180.0, 170.0, 37))
    g = gravity_ned(NormalField(), lat, lon, h_m)
    gam = np.array([gravity(float(a), h_m) for a in lat])
    assert np.max(np.abs(g[:, :2])) / gam.min() < 1e-6 * ARCSEC
    np.testing.assert_allclose(g[:, 2], gam, rtol=0, atol=1e-9)


def test_j2_alone_leaves_an_arcsecond() -> None:
    """J2 alone is not the level ellipsoid's field: the missing J4, J6... tilt gravity by
    up to ~1" (so the generator subtracts the full normal field, not J2)."""
    lat = np.radians(np.linspace(-80.0, 80.0, 33))
    xi, eta, _ = mechanization_dov(NormalField(j2_only=True), lat, np.zeros_like(lat), 0.0)
    assert 0.3 < np.max(np.abs(xi)) / ARCSEC < 2.0
    assert np.max(np.abs(eta)) / ARCSEC < 1e-9


def test_normal_plumb_line_curvature_above_the_ellipsoid() -> None:
    """Above the ellipsoid normal gravity leans poleward by ~0.17" sin(2L) per km
    (Heiskanen & Moritz 1967, sec. 5-2); the mechanization-consistent grid carries it."""
    for lat_deg in (20.0, 45.0, 70.0):
        lat, lon = _one(lat_deg, 10.0)
        xi, _, _ = mechanization_dov(NormalField(), lat, lon, 10_000.0)
        want = 0.17 * 10.0 * math.sin(2 * math.radians(lat_deg))
        assert float(xi[0]) / ARCSEC == pytest.approx(want, rel=0.05)


@pytest.mark.parametrize("point", GEOGRAPHICLIB_EGM96, ids=lambda p: f"{p[0][0]:.2f}")
def test_egm96_matches_geographiclib(egm96: Egm96Gravitas, point: tuple) -> None:  # type: ignore[type-arg]
    """GIVEN EGM96 to degree 360 and GeographicLib's published values at Mount Everest and
    four points near 17 deg at 300 m and 400 km,
    WHEN gravity, the gravity disturbance and the deflections are computed,
    THEN gravity and disturbance match (horizontal 1e-4 mGal, vertical 0.01 mGal), the
    spherical xi/eta match to 1e-4 arcsec, and the geodetic eta matches with xi within the
    geodetic-geocentric latitude effect."""
    (lat_deg, lon_deg, h), g_enu, d_enu, (_, xi_a, eta_a) = point
    lat, lon = _one(lat_deg, lon_deg)
    g = gravity_ned(egm96, lat, lon, h)[0]
    # gravity: horizontal to 0.0001 mGal, vertical to 0.01 mGal (the models' GM differ by
    # 3e5 m^3/s^2 and GeographicLib's degree 0 uses WGS-84's)
    assert g[1] == pytest.approx(g_enu[0], abs=1e-9)
    assert g[0] == pytest.approx(g_enu[1], abs=1e-9)
    assert -g[2] == pytest.approx(g_enu[2], abs=1e-7)
    # gravity disturbance grad T: tests the normal field subtracted (J2..J20 of WGS-84)
    d, _ = disturbance_ned(egm96, lat, lon, h)
    assert d[0, 1] / MGAL == pytest.approx(d_enu[0], abs=1e-4)
    assert d[0, 0] / MGAL == pytest.approx(d_enu[1], abs=1e-4)
    assert -d[0, 2] / MGAL == pytest.approx(d_enu[2], abs=1e-2)
    # deflections, spherical approximation as GeographicLib's -A (and NGA's programs)
    xi, eta = classical_dov(egm96, lat, lon, h, spherical=True)
    assert float(xi[0]) / ARCSEC == pytest.approx(xi_a, abs=1e-4)
    assert float(eta[0]) / ARCSEC == pytest.approx(eta_a, abs=1e-4)
    # in the geodetic frame eta is unchanged and xi differs by the large vertical
    # disturbance seen through the geodetic-geocentric latitude difference (<= 0.19 deg)
    xg, eg = classical_dov(egm96, lat, lon, h)
    assert float(eg[0]) / ARCSEC == pytest.approx(eta_a, abs=1e-4)
    assert abs(float(xg[0]) - float(xi[0])) <= abs(d[0, 2]) / 9.7 * math.radians(0.2)


def test_sign_convention_at_mount_everest(egm96: Egm96Gravitas) -> None:
    """Gravity at the summit pulls north (towards the Tibetan plateau): the plumb-line
    zenith lies south of the ellipsoid normal, so xi = Phi - phi < 0 - GeographicLib's
    -A gives xi = -18.84", eta = +4.44"; navd's mechanization sees g_N = -xi gamma > 0."""
    lat, lon = _one(dms(27, 59, 17), dms(86, 55, 32))
    xi, eta, _ = mechanization_dov(egm96, lat, lon, 8820.0)
    g = gravity_ned(egm96, lat, lon, 8820.0)[0]
    assert float(xi[0]) < 0.0 < float(eta[0]) and g[0] > 0.0 > g[1]
    # at 8.8 km the grid value (relative to navd's normal gravity along the ellipsoid normal)
    # adds the normal plumb-line curvature, 1.26" here, to the classical -18.96"
    xc, _ = classical_dov(egm96, lat, lon, 8820.0)
    xn, _, _ = mechanization_dov(NormalField(), lat, lon, 8820.0)
    assert float(xi[0]) == pytest.approx(float(xc[0]) + float(xn[0]), abs=0.01 * ARCSEC)
    assert float(xi[0]) / ARCSEC == pytest.approx(-17.70, abs=0.01)


def test_cli_writes_loadable_grids(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN `navd dov-grid` run over a South China Sea box with EGM96, over a wide box
    with --model normal, and with a reversed latitude range or a .txt output,
    WHEN the written grids are loaded,
    THEN the EGM96 grid is 5x5 with dg, holds the model's values at its nodes and has
    deflections of 0.5-30 arcsec; the normal-field grid is zero; the bad arguments exit."""
    out = tmp_path / "scs.nc"
    assert main(["--lat-min", "21", "--lat-max", "22", "--lon-min", "113", "--lon-max", "114",
                 "--step-arcmin", "15", "--out", str(out), "--quiet"]) == 0
    assert "wrote" in capsys.readouterr().out
    g = load_dov_grid(out)
    assert g.xi_rad.shape == (5, 5) and g.has_dg
    # the grid holds what the model gives at its nodes
    xi, eta, dg = mechanization_dov(Egm96Gravitas(), np.radians([21.25]), np.radians([113.5]),
                                    0.0)
    o = np.zeros(3)
    assert g.eval_into(math.radians(21.25), math.radians(113.5), o)
    np.testing.assert_allclose(o, [xi[0], eta[0], dg[0]], rtol=1e-12, atol=1e-18)
    # magnitudes of a few arcsec at sea level, as EGM96 has in the South China Sea
    assert 0.5 * ARCSEC < np.max(np.abs(g.data[:2])) < 30 * ARCSEC
    # the normal field gives a zero grid, J2 alone does not
    npz = tmp_path / "normal.npz"
    assert main(["--lat-min", "-60", "--lat-max", "60", "--lon-min", "0", "--lon-max", "30",
                 "--step-arcmin", "1200", "--out", str(npz), "--model", "normal",
                 "--quiet"]) == 0
    assert np.max(np.abs(load_dov_grid(npz).data)) < 1e-9
    with pytest.raises(SystemExit):
        main(["--lat-min", "10", "--lat-max", "5", "--lon-min", "0", "--lon-max", "1",
              "--step-arcmin", "5", "--out", str(npz)])
    with pytest.raises(SystemExit):
        main(["--lat-min", "1", "--lat-max", "5", "--lon-min", "0", "--lon-max", "1",
              "--step-arcmin", "5", "--out", str(tmp_path / "x.txt")])
