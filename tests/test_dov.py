"""DOV fields (navd.core.aiding.dov), grid files (navd.io.dov_grid), build_estimator, status."""

from __future__ import annotations

import logging
import math
import tracemalloc
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from firmware_sim.alloc import measure_steps
from firmware_sim.dov_field import AlongTrackSinusoid
from navd.config import ConfigError, DovSection, build_section, load_config
from navd.core.aiding.dov import (
    ARCSEC,
    MGAL,
    DovGrid,
    DovGridError,
    dov_status,
    predicted_effect,
)
from navd.core.earth import OMEGA_IE, radii
from navd.core.estimator import Estimator
from navd.io.dov_grid import load_dov_grid, save_dov_grid
from navd.pipeline import build_estimator

Arr = npt.NDArray[np.float64]
D2R = math.pi / 180.0


def bilinear_field(lat_rad: Arr, lon_rad: Arr, k: int) -> Arr:
    """A field that bilinear interpolation reproduces exactly (bilinear in lat, lon)."""
    a, b, c, d = (1.0, 2.0, -3.0, 5.0) if k == 0 else (-2.0, 0.5, 1.5, -4.0)
    return 1e-5 * (a + b * lat_rad + c * lon_rad + d * lat_rad * lon_rad)


def make_grid(lat_deg: Arr, lon_deg: Arr, with_dg: bool = True) -> DovGrid:
    la, lo = np.meshgrid(np.radians(lat_deg), np.radians(lon_deg), indexing="ij")
    dg = bilinear_field(la, lo, 1) * 10.0 if with_dg else None
    return DovGrid(lat_deg, lon_deg, bilinear_field(la, lo, 0), bilinear_field(la, lo, 1),
                   dg, "test")


# ------------------------------------------------------------------------ interpolation


@pytest.mark.parametrize("lat0, lon0, step", [(20.0, 110.0, 0.5), (-40.0, -75.0, 1.0 / 60.0),
                                              (60.0, 355.0, 0.25)])
def test_bilinear_fields_are_interpolated_exactly(lat0: float, lon0: float, step: float) -> None:
    """GIVEN DovGrids of fields bilinear in (lat, lon), at several origins and spacings,
    WHEN eval_into is called at 500 random points and at every node,
    THEN xi, eta and dg equal the analytic field to 1e-10 relative,
    and every node, corners and edges included, returns its own value."""
    lat = lat0 + step * np.arange(11)
    lon = lon0 + step * np.arange(9)
    g = make_grid(lat, lon)
    rng = np.random.default_rng(1)
    out = np.zeros(3)
    for _ in range(500):
        la = math.radians(rng.uniform(lat[0], lat[-1]))
        lo = math.radians(rng.uniform(lon[0], lon[-1]))
        assert g.eval_into(la, lo, out)
        want = [bilinear_field(np.array(la), np.array(lo), k) for k in (0, 1)]
        assert out[0] == pytest.approx(float(want[0]), rel=1e-10, abs=1e-16)
        assert out[1] == pytest.approx(float(want[1]), rel=1e-10, abs=1e-16)
        assert out[2] == pytest.approx(10.0 * float(want[1]), rel=1e-10, abs=1e-15)
    # every node returns its own value, corners and edges included
    for i in range(lat.size):
        for j in range(lon.size):
            assert g.eval_into(math.radians(lat[i]), math.radians(lon[j]), out)
            assert out[0] == pytest.approx(g.xi_rad[i, j], rel=1e-12, abs=1e-18)


def test_interpolation_is_continuous_across_cells() -> None:
    """GIVEN a DovGrid of random node values,
    WHEN it is evaluated 1e-12 rad either side of every interior cell edge in lat and lon,
    THEN both sides agree to within the grid's maximum slope times that offset."""
    lat = 10.0 + 0.5 * np.arange(6)
    lon = 20.0 + 0.5 * np.arange(7)
    rng = np.random.default_rng(2)
    g = DovGrid(lat, lon, rng.normal(0, 1e-4, (6, 7)), rng.normal(0, 1e-4, (6, 7)),
                rng.normal(0, 1e-4, (6, 7)))
    a = np.zeros(3)
    b = np.zeros(3)
    eps = 1e-12
    slope = 2e-4 / math.radians(0.5)  # max |difference of neighbours| / spacing
    for i in range(1, 5):  # interior cell edges along latitude
        for lo in np.linspace(lon[0], lon[-1], 13):
            la = math.radians(lat[i])
            assert g.eval_into(la - eps, math.radians(lo), a)
            assert g.eval_into(la + eps, math.radians(lo), b)
            assert np.max(np.abs(a - b)) < 10 * slope * eps + 1e-18
    for j in range(1, 6):  # interior cell edges along longitude
        for la in np.linspace(lat[0], lat[-1], 11):
            lo = math.radians(lon[j])
            assert g.eval_into(math.radians(la), lo - eps, a)
            assert g.eval_into(math.radians(la), lo + eps, b)
            assert np.max(np.abs(a - b)) < 10 * slope * eps + 1e-18


def test_off_grid_is_flagged_and_zero() -> None:
    """GIVEN a small regional DovGrid,
    WHEN it is evaluated just outside each edge, 180 deg away, and at NaN lat or lon,
    THEN eval_into returns False and zeroes the output; the same point 360 deg
    east or west is on the grid."""
    g = make_grid(20.0 + 0.5 * np.arange(5), 110.0 + 0.5 * np.arange(5))
    out = np.full(3, 7.0)
    for la, lo in [(19.99, 111.0), (22.01, 111.0), (21.0, 109.99), (21.0, 112.01),
                   (21.0, 111.0 - 180.0), (math.nan, 111.0), (21.0, math.nan)]:
        out[:] = 7.0
        assert not g.eval_into(math.radians(la), math.radians(lo), out)
        assert np.all(out == 0.0)
    # the same longitude in another 360-degree window is on the grid
    assert g.eval_into(math.radians(21.0), math.radians(111.0 - 360.0), out)
    assert g.eval_into(math.radians(21.0), math.radians(111.0 + 360.0), out)


def test_global_grid_wraps_across_the_seam() -> None:
    """GIVEN a global grid with columns every 30 deg from 0 to 330 (no repeated 360 column),
    WHEN it is evaluated at longitude 345 deg and at -15 deg,
    THEN both interpolate between the 330 and 0 deg columns (5.5 arcsec)."""
    lat = np.array([-10.0, 0.0, 10.0])
    lon = np.arange(0.0, 360.0, 30.0)  # 12 columns, the 13th would repeat the first
    xi = np.tile(np.arange(12.0), (3, 1)) * ARCSEC
    g = DovGrid(lat, lon, xi, np.zeros_like(xi))
    out = np.zeros(3)
    assert g.eval_into(0.0, math.radians(345.0), out)  # between 330 (11") and 360 = 0 (0")
    assert out[0] / ARCSEC == pytest.approx(5.5)
    assert g.eval_into(0.0, math.radians(-15.0), out)
    assert out[0] / ARCSEC == pytest.approx(5.5)


def test_along_track_sinusoid() -> None:
    """GIVEN an AlongTrackSinusoid field on a 45 deg course with xi/eta sinusoids and a
    constant dg,
    WHEN it is evaluated a quarter xi wavelength along the course, 1 km across it,
    and along a track through that point and the origin,
    THEN xi is at its 20 arcsec peak, eta and dg have their phase-shifted and constant
    values, the field is constant across the course, and the origin gives xi = 0."""
    lat0, lon0, c = 22.0 * D2R, 113.0 * D2R, 45.0 * D2R
    f = AlongTrackSinusoid(lat0, lon0, c, xi_amp_rad=20 * ARCSEC, xi_wavelength_m=360e3,
                           eta_amp_rad=10 * ARCSEC, eta_wavelength_m=180e3,
                           eta_phase_rad=0.5, dg_mps2=3e-4)
    r_m, r_n = radii(lat0)
    s = 90e3  # a quarter wavelength of xi along the course
    la = lat0 + s * math.cos(c) / r_m
    lo = lon0 + s * math.sin(c) / (r_n * math.cos(lat0))
    out = np.zeros(3)
    assert f.eval_into(la, lo, out)
    assert out[0] / ARCSEC == pytest.approx(20.0, rel=1e-12)
    assert out[1] / ARCSEC == pytest.approx(10.0 * math.sin(math.pi + 0.5), rel=1e-12)
    assert out[2] == 3e-4
    # across the course the field is constant
    assert f.eval_into(la + 1e3 * math.cos(c + math.pi / 2) / r_m,
                       lo + 1e3 * math.sin(c + math.pi / 2) / (r_n * math.cos(lat0)), out)
    assert out[0] / ARCSEC == pytest.approx(20.0, rel=1e-9)
    track = f.eval_track(np.array([[la, lo, 0.0], [lat0, lon0, 0.0]]))
    assert track[0, 0] / ARCSEC == pytest.approx(20.0, rel=1e-12) and track[1, 0] == 0.0


# ------------------------------------------------------------------------ bad grids

def _ok_arrays() -> tuple[Arr, Arr, Arr, Arr]:
    lat = 20.0 + 0.5 * np.arange(4)
    lon = 110.0 + 0.5 * np.arange(5)
    return lat, lon, np.full((4, 5), 5 * ARCSEC), np.full((4, 5), -3 * ARCSEC)


@pytest.mark.parametrize("mutate, needle", [
    (lambda la, lo, xi, eta: (la, lo, np.where(np.arange(20).reshape(4, 5) == 7, np.nan, xi),
                              eta), "xi has 1 NaN/fill cells of 20 (first at lat 20.5, lon 111"),
    (lambda la, lo, xi, eta: (la[[0, 2, 1, 3]], lo, xi, eta), "lat axis is not sorted"),
    (lambda la, lo, xi, eta: (la, lo[::-1], xi, eta), "lon axis is not sorted"),
    (lambda la, lo, xi, eta: (la, np.array([110.0, 110.5, 111.2, 111.5, 112.0]), xi, eta),
     "not regularly spaced"),
    (lambda la, lo, xi, eta: (la, lo, xi[:, :4], eta), "xi has shape (4, 4)"),
    (lambda la, lo, xi, eta: (la, lo, xi, eta.T), "eta has shape (5, 4)"),
    (lambda la, lo, xi, eta: (la, lo, xi / ARCSEC, eta), "wrong unit"),
    (lambda la, lo, xi, eta: (la[:1], lo, xi[:1], eta[:1]), "at least 2 points"),
    (lambda la, lo, xi, eta: (la + 80.0, lo, xi, eta), "outside [-90, 90]"),
])
def test_bad_grids_are_refused(mutate: object, needle: str) -> None:
    """GIVEN a valid grid's arrays with one defect each (NaN cell, unsorted or irregular
    axis, wrong shape, wrong unit, a single row, latitude beyond 90 deg),
    WHEN a DovGrid is built from them,
    THEN DovGridError is raised with a message naming the defect."""
    la, lo, xi, eta = mutate(*_ok_arrays())  # type: ignore[operator]
    with pytest.raises(DovGridError) as exc:
        DovGrid(la, lo, xi, eta)
    assert needle in str(exc.value)


def test_npz_round_trip_and_bad_files(tmp_path: Path) -> None:
    """GIVEN a grid saved with save_dov_grid to .npz, and broken files (missing array,
    NaN cell, unsorted axis, not a zip, absent, unknown extension),
    WHEN load_dov_grid reads them,
    THEN the good grid round-trips with its model name, and each bad one raises
    DovGridError naming the file and the cause."""
    lat, lon, xi, eta = _ok_arrays()
    dg = np.full((4, 5), 12 * MGAL)
    p = tmp_path / "g.npz"
    save_dov_grid(p, lat, lon, xi, eta, dg, model="unit test")
    g = load_dov_grid(p)
    np.testing.assert_allclose(g.xi_rad, xi, rtol=1e-15)
    np.testing.assert_allclose(g.dg_mps2, dg, rtol=1e-15)
    assert "unit test" in g.describe()
    # missing array, NaN cell, unsorted axis: refused with the file name and the cause
    np.savez(tmp_path / "miss.npz", lat_deg=lat, lon_deg=lon, xi_arcsec=xi / ARCSEC)
    xi_nan = xi / ARCSEC
    xi_nan[1, 1] = np.nan
    np.savez(tmp_path / "nan.npz", lat_deg=lat, lon_deg=lon, xi_arcsec=xi_nan,
             eta_arcsec=eta / ARCSEC)
    np.savez(tmp_path / "uns.npz", lat_deg=lat[::-1], lon_deg=lon, xi_arcsec=xi / ARCSEC,
             eta_arcsec=eta / ARCSEC)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    for name, needle in [("miss.npz", "missing array(s) ['eta_arcsec']"),
                         ("nan.npz", "NaN/fill cells"), ("uns.npz", "not sorted"),
                         ("junk.npz", "cannot read"), ("none.npz", "no such file"),
                         ("g.tif", "no such file")]:
        with pytest.raises(DovGridError) as exc:
            load_dov_grid(tmp_path / name)
        assert name in str(exc.value) and needle in str(exc.value)
    (tmp_path / "g.tif").write_bytes(b"")
    with pytest.raises(DovGridError, match="unknown grid format"):
        load_dov_grid(tmp_path / "g.tif")


def _gmt_grid(path: Path, lat: Arr, lon: Arr, z: Arr, units: str | None,
              name: str = "z", transpose: bool = False) -> None:
    """A GMT-style one-variable COARDS grid (x = lon, y = lat)."""
    import netCDF4

    with netCDF4.Dataset(str(path), "w", format="NETCDF3_CLASSIC") as ds:
        ds.createDimension("x", lon.size)
        ds.createDimension("y", lat.size)
        vx = ds.createVariable("x", "f8", ("x",))
        vx.units = "degrees_east"
        vx[:] = lon
        vy = ds.createVariable("y", "f8", ("y",))
        vy.units = "degrees_north"
        vy[:] = lat
        dims = ("x", "y") if transpose else ("y", "x")
        vz = ds.createVariable(name, "f4", dims, fill_value=np.float32(np.nan))
        if units is not None:
            vz.units = units
        vz[:] = z.T if transpose else z


def test_netcdf_round_trip_and_gmt_layouts(tmp_path: Path) -> None:
    """GIVEN a grid saved to netCDF, and GMT-style one-variable grids (north-to-south rows,
    (x, y) storage, missing or unknown units, a fill cell, an irregular or mismatched axis),
    WHEN load_dov_grid reads them, with and without angle_unit and eta_path,
    THEN the round trip and the GMT pair load correctly once angle_unit supplies the missing
    unit, and each defect raises DovGridError with a message naming it."""
    lat, lon, xi, eta = _ok_arrays()
    rng = np.random.default_rng(3)
    xi = xi + rng.normal(0, 1e-6, xi.shape)
    p = tmp_path / "both.nc"
    save_dov_grid(p, lat, lon, xi, eta, np.full((4, 5), -7 * MGAL), model="m")
    g = load_dov_grid(p)
    np.testing.assert_allclose(g.xi_rad, xi, rtol=1e-14)
    np.testing.assert_allclose(g.dg_mps2, -7 * MGAL, rtol=1e-14)
    # two one-variable GMT grids: north (microradians, north-to-south rows) and east
    # (no units attribute, stored (x, y)); angle_unit supplies the missing unit
    north = tmp_path / "north.grd"
    east = tmp_path / "east.grd"
    _gmt_grid(north, lat[::-1], lon, (xi / 1e-6)[::-1], "microradians")
    _gmt_grid(east, lat, lon, eta / ARCSEC, None, transpose=True)
    with pytest.raises(DovGridError, match=r"no units attribute; set \[dov\] angle_unit"):
        load_dov_grid(north, eta_path=east)
    g2 = load_dov_grid(north, eta_path=east, angle_unit="arcsec")
    np.testing.assert_allclose(g2.xi_rad, xi, rtol=1e-6)  # float32 storage
    np.testing.assert_allclose(g2.eta_rad, eta, rtol=1e-6)
    assert not g2.has_dg
    # a fill (NaN) cell is refused, as are unknown units and a one-variable file alone
    z = (xi / ARCSEC).copy()
    z[2, 3] = np.nan
    _gmt_grid(tmp_path / "hole.nc", lat, lon, z, "arcsec", name="xi")
    _gmt_grid(tmp_path / "furlong.nc", lat, lon, z, "furlongs", name="xi")
    with pytest.raises(DovGridError, match=r"hole\.nc: .*NaN/fill cells"):
        load_dov_grid(tmp_path / "hole.nc", eta_path=east, angle_unit="arcsec")
    with pytest.raises(DovGridError, match="units 'furlongs'"):
        load_dov_grid(tmp_path / "furlong.nc", eta_path=east, angle_unit="arcsec")
    with pytest.raises(DovGridError, match=r"one variable \(z\).*eta_grid"):
        load_dov_grid(north, angle_unit="arcsec")
    # an irregular longitude axis is refused
    irr = np.array([110, 110.5, 111.2, 111.5, 112.0])
    _gmt_grid(tmp_path / "irr.nc", lat, irr, xi / ARCSEC, "arcsec", name="xi")
    _gmt_grid(tmp_path / "irr_e.nc", lat, irr, eta / ARCSEC, "arcsec", name="eta")
    with pytest.raises(DovGridError, match="lon axis is not regularly spaced"):
        load_dov_grid(tmp_path / "irr.nc", eta_path=tmp_path / "irr_e.nc")
    # ... and a grid whose second file sits on other nodes
    with pytest.raises(DovGridError, match="not on the same lat/lon nodes"):
        load_dov_grid(tmp_path / "irr.nc", eta_path=east)


# ------------------------------------------------------------------------ config, estimator


def _dov(table: object) -> DovSection:
    return build_section(DovSection, "dov", table)


def test_settings_validation() -> None:
    """GIVEN [dov] config tables,
    WHEN the section is built,
    THEN an empty table gives the defaults, and an unknown key, a non-boolean enabled or a
    bad angle_unit raise ConfigError naming the problem."""
    assert _dov({}) == DovSection()
    with pytest.raises(ConfigError, match="unknown key 'gird'"):
        _dov({"gird": "x.nc"})
    with pytest.raises(ConfigError, match="enabled must be true or false"):
        _dov({"enabled": "yes"})
    with pytest.raises(ConfigError, match="angle_unit"):
        _dov({"angle_unit": "deg"})


def test_build_estimator_keeps_normal_gravity_on_a_bad_grid(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN dov enabled with a grid file containing a NaN cell, with no grid, disabled,
    with a misspelt key, and with use_dg=false on a good grid,
    WHEN build_estimator builds the estimator,
    THEN the bad grid is refused with a warning and normal gravity is kept (status says so),
    a missing grid and "off" are reported, the typo raises ConfigError, and use_dg=false
    keeps the deflections but zeroes the gravity disturbance."""
    lat, lon, xi, eta = _ok_arrays()
    xi[0, 0] = np.nan
    np.savez(tmp_path / "bad.npz", lat_deg=lat, lon_deg=lon, xi_arcsec=xi / ARCSEC,
             eta_arcsec=eta / ARCSEC)
    with caplog.at_level(logging.WARNING, logger="navd.dov"):
        est = build_estimator(load_config(None, ["dov.enabled=true",
                                                 f"dov.grid=\"{tmp_path / 'bad.npz'}\""]))
    assert est.dov_field is None
    assert "bad.npz" in caplog.text and "NaN" in caplog.text and "normal gravity" in caplog.text
    st = dov_status(est)
    assert str(st["dov_model"]).startswith("refused: ") and "normal gravity" in str(
        st["dov_model"])
    assert st["dov_uncomp_tilt_arcsec"] is None
    # no grid configured at all
    est = build_estimator(load_config(None, ["dov.enabled=true"]))
    assert "no grid file" in str(dov_status(est)["dov_model"])
    # disabled, and a syntax error in [dov]
    assert dov_status(build_estimator({}))["dov_model"] == "off"
    with pytest.raises(ConfigError):
        build_estimator(load_config(None, ["dov.enable=true"]))
    # use_dg = false drops the disturbance but keeps the deflections
    lat, lon, xi, eta = _ok_arrays()
    save_dov_grid(tmp_path / "ok.npz", lat, lon, xi, eta, np.full((4, 5), 9 * MGAL))
    est = build_estimator(load_config(None, [
        "dov.enabled=true", f"dov.grid=\"{tmp_path / 'ok.npz'}\"", "dov.use_dg=false"]))
    assert isinstance(est.dov_field, DovGrid)
    assert not est.dov_field.has_dg and np.all(est.dov_field.dg_mps2 == 0.0)


def test_status_predicts_the_seed_002_effect() -> None:
    """GIVEN an estimator at 10 m/s on a 30 deg course in an along-track sinusoid DOV field,
    WHEN dov_status is read,
    THEN it reports "on grid", the uncompensated tilt (eta, 0), the heading effect
    eta tan L + xi_dot / (cos L Omega_ie) and the xi rate; predicted_effect maps (xi, eta)
    to (eta, -xi, 0)."""
    lat0, lon0, c = 22.0 * D2R, 113.0 * D2R, 30.0 * D2R
    amp, lam = 20 * ARCSEC, 360e3
    f = AlongTrackSinusoid(lat0, lon0, c, xi_amp_rad=amp, xi_wavelength_m=lam,
                           eta_amp_rad=amp, eta_wavelength_m=lam, eta_phase_rad=1.0)
    est = Estimator(dov_field=f)
    speed = 10.0
    est.pos[:] = (lat0, lon0, 0.0)
    est.vel_n[:] = (speed * math.cos(c), speed * math.sin(c), 0.0)
    f.eval_into(lat0, lon0, est.dov)
    est.dov_on_grid = True
    st = dov_status(est)
    assert str(st["dov_model"]).startswith("on grid: analytic")
    eta = amp * math.sin(1.0)
    assert st["dov_uncomp_tilt_arcsec"] == pytest.approx([eta / ARCSEC, -0.0])
    xi_dot = amp * 2 * math.pi / lam * speed  # d/dt of amp sin(2 pi v t / lam) at t = 0
    want = (eta * math.tan(lat0) + xi_dot / (math.cos(lat0) * OMEGA_IE)) / ARCSEC
    assert st["dov_uncomp_heading_arcsec"] == pytest.approx(want, rel=1e-3)
    assert st["dov_xi_rate_arcsec_per_h"] == pytest.approx(xi_dot / ARCSEC * 3600, rel=1e-3)
    assert predicted_effect(1e-4, 2e-4, 0.0, 0.0) == (2e-4, -1e-4, 0.0)


def _car_grid(run_pos: Arr, margin_deg: float) -> DovGrid:
    lat = np.degrees(run_pos[:, 0])
    lon = np.degrees(run_pos[:, 1])
    la = np.linspace(lat.min() - margin_deg, lat.max() + margin_deg, 12)
    lo = np.linspace(lon.min() - margin_deg, lon.max() + margin_deg, 14)
    rng = np.random.default_rng(5)
    return DovGrid(la, lo, rng.normal(0, 10 * ARCSEC, (12, 14)),
                   rng.normal(0, 10 * ARCSEC, (12, 14)), rng.normal(0, 20 * MGAL, (12, 14)))


def test_estimator_flags_off_grid_and_uses_the_grid_on_it() -> None:
    """GIVEN a car480 run with a grid covering the whole track, then a tiny grid around its start,
    WHEN the estimator processes the run,
    THEN with full coverage it stays on grid with nonzero DOV and no off-grid count;
    with the tiny grid it counts off-grid epochs, zeroes the DOV and reports
    "off grid: normal gravity"."""
    from firmware_sim import generate, load_scenario

    run = generate(load_scenario("car480", {"duration_s": 120.0}), seed=1)
    full = _car_grid(run.truth_pos, 0.01)
    est = Estimator(dov_field=full)
    for s in run.samples():
        est.push(s)
    assert est.dov_on_grid and est.counters.get("dov_off_grid", 0) == 0
    out = np.zeros(3)
    full.eval_into(float(est.pos[0]), float(est.pos[1]), out)
    assert np.all(est.dov != 0.0)
    assert str(dov_status(est)["dov_model"]).startswith("on grid")
    # a grid that ends halfway along the track
    lat = np.degrees(run.truth_pos[:, 0])
    lon = np.degrees(run.truth_pos[:, 1])
    k = lat.size // 2
    part = DovGrid(np.linspace(lat[0] - 1e-3, lat[0] + 1e-3, 3),
                   np.linspace(lon[0] - 1e-3, lon[0] + 1e-3, 3), np.full((3, 3), 1e-5),
                   np.full((3, 3), 1e-5))
    assert abs(lat[k] - lat[0]) > 1e-3 or abs(lon[k] - lon[0]) > 1e-3
    est = Estimator(dov_field=part)
    for s in run.samples():
        est.push(s)
    assert est.counters["dov_off_grid"] > 0 and not est.dov_on_grid
    assert np.all(est.dov == 0.0)
    assert est.status()["dov_model"] == "off grid: normal gravity"
    assert str(dov_status(est)["dov_model"]).startswith("off grid: normal gravity")


@pytest.mark.alloc
def test_gnss_updates_with_a_grid_do_not_allocate() -> None:
    """GIVEN a car480 run and a DovGrid covering the track,
    WHEN the estimator steps through the samples (over 100 GNSS updates, on grid),
    THEN no numpy memory is traced, peak Python allocation is under 4 KiB and growth under 1 KiB."""
    from firmware_sim import generate, load_scenario

    run = generate(load_scenario("car480", {"duration_s": 150.0}), seed=2)
    est = Estimator(dov_field=_car_grid(run.truth_pos, 0.01))
    a = measure_steps(est, list(run.samples()))
    assert est.counters["gnss"] > 100 and est.dov_on_grid
    numpy_domain = a.snapshot.filter_traces([tracemalloc.DomainFilter(
        True, np.lib.tracemalloc_domain)])
    assert sum(s.size for s in numpy_domain.statistics("filename")) == 0
    assert a.peak < 4096
    assert a.grew < 1024
