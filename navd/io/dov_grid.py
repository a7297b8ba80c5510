"""DOV grid files: navd's ``.npz`` layout and GMT/COARDS netCDF, read into a :class:`DovGrid`.

navd ``.npz`` layout (``numpy.savez``; written by ``navd dov-grid --out FILE.npz``)::

    lat_deg     (nlat,)        strictly increasing, regularly spaced, degrees
    lon_deg     (nlon,)        strictly increasing, regularly spaced, degrees
    xi_arcsec   (nlat, nlon)   north-south deflection, + when the zenith is north of the
                               ellipsoid normal (xi = Phi - phi)
    eta_arcsec  (nlat, nlon)   east-west deflection, + east (eta = (Lambda - lambda) cos phi)
    dg_mgal     (nlat, nlon)   optional: gravity disturbance along down (g_D - gamma), mGal
    height_m    ()             optional: ellipsoidal height the values refer to
    model       ()             optional: text describing the source

GMT/COARDS netCDF (``.nc``, ``.grd``; netCDF-3 classic or netCDF-4): 1-D coordinate
variables for latitude (``lat``/``latitude``/``y`` or units ``degrees_north``) and longitude
(``lon``/``longitude``/``x`` or ``degrees_east``), in either order and either direction
(descending axes are flipped); 2-D data variables on them.  One file may hold both
components (found by name: ``xi``/``north``/..., ``eta``/``east``/..., optionally
``dg``/...; or named in config), or - as GMT grids hold one variable (``z``) each - the
north component comes from one file and the east one from a second (``eta_grid``).
Units come from each variable's ``units`` attribute (arcsec, microradian, radian; mGal,
m/s^2) or, when a file has none, from ``angle_unit``.  ``scale_factor``/``add_offset`` are
applied; ``_FillValue`` cells become NaN and the grid is refused.

Anything malformed (missing variables, NaN cells, unsorted or irregular axes, mismatched
shapes, implausible magnitudes) raises :class:`DovGridError` naming the file and the cause.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from navd.config.aiding import DovSection
from navd.core.aiding.dov import MGAL, DovGrid, DovGridError
from navd.units import ARCSEC

Arr = npt.NDArray[np.float64]

__all__ = ["DovGridError", "load_dov_grid", "load_from_settings",
           "save_dov_grid"]

NPZ_KEYS = ("lat_deg", "lon_deg", "xi_arcsec", "eta_arcsec")
NETCDF_SUFFIXES = (".nc", ".grd", ".nc4", ".cdf", ".netcdf")

_ANGLE_UNITS: dict[str, float] = {
    "arcsec": ARCSEC, "arcsecond": ARCSEC, "arcseconds": ARCSEC, "arc-second": ARCSEC,
    "arc-seconds": ARCSEC, "arc second": ARCSEC, "arc seconds": ARCSEC,
    "seconds of arc": ARCSEC, "sec": ARCSEC, '"': ARCSEC, "\u2033": ARCSEC,
    "microradian": 1e-6, "microradians": 1e-6, "micro-radian": 1e-6, "micro-radians": 1e-6,
    "microrad": 1e-6, "urad": 1e-6, "\u00b5rad": 1e-6, "\u03bcrad": 1e-6,
    "rad": 1.0, "radian": 1.0, "radians": 1.0,
}
_ANGLE_ALIASES = {"arcsec": "arcsec", "microrad": "microradian", "rad": "rad"}
_DG_UNITS: dict[str, float] = {
    "mgal": MGAL, "milligal": MGAL, "m/s^2": 1.0, "m/s2": 1.0, "m s-2": 1.0, "m s**-2": 1.0,
    "m.s-2": 1.0, "m/s**2": 1.0,
}
_XI_NAMES = ("xi", "xi_arcsec", "ksi", "north", "dov_north", "deflection_north", "dov_xi",
             "north_south", "xi_urad")
_ETA_NAMES = ("eta", "eta_arcsec", "east", "dov_east", "deflection_east", "dov_eta",
              "east_west", "eta_urad")
_DG_NAMES = ("dg", "dg_mgal", "delta_g", "gravity_disturbance", "disturbance", "dg_d")
_LAT_NAMES = ("lat", "latitude", "y", "lat_deg")
_LON_NAMES = ("lon", "longitude", "x", "lon_deg")


# ---------------------------------------------------------------------------------- config

def load_from_settings(s: DovSection) -> DovGrid:
    """Load the grid that ``[dov]`` (:class:`navd.config.aiding.DovSection`) names; raises
    :class:`DovGridError` (never exits)."""
    if not s.grid:
        raise DovGridError("[dov] enabled but no grid file given ([dov] grid)")
    g = load_dov_grid(s.grid, eta_path=s.eta_grid or None, xi_var=s.xi_var,
                      eta_var=s.eta_var, dg_var=s.dg_var, angle_unit=s.angle_unit)
    return g if s.use_dg or not g.has_dg else g.without_dg()


# ---------------------------------------------------------------------------------- loading

def load_dov_grid(path: str | Path, *, eta_path: str | Path | None = None, xi_var: str = "",
                  eta_var: str = "", dg_var: str = "", angle_unit: str = "") -> DovGrid:
    """Read a DOV grid (format from the suffix: ``.npz`` or netCDF).

    Raises:
        DovGridError: unreadable file, missing variables, bad values; the message starts
            with the file name.
    """
    p = Path(path)
    try:
        if not p.is_file():
            raise DovGridError("no such file" if not p.exists() else "not a regular file")
        if p.suffix.lower() == ".npz":
            if eta_path is not None:
                raise DovGridError("eta_grid is only for one-variable netCDF grids")
            return _load_npz(p)
        if p.suffix.lower() in NETCDF_SUFFIXES:
            return _load_netcdf(p, None if eta_path is None else Path(eta_path), xi_var,
                                eta_var, dg_var, angle_unit)
        raise DovGridError(f"unknown grid format {p.suffix!r}; expected .npz or netCDF "
                           f"({', '.join(NETCDF_SUFFIXES)})")
    except DovGridError as exc:
        msg = str(exc)
        raise DovGridError(msg if msg.startswith(str(p)) else f"{p}: {msg}") from None


def _load_npz(p: Path) -> DovGrid:
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: np.asarray(z[k]) for k in z.files}
    except (OSError, ValueError) as exc:
        raise DovGridError(f"cannot read as .npz: {exc}") from None
    missing = [k for k in NPZ_KEYS if k not in data]
    if missing:
        raise DovGridError(f"missing array(s) {missing}; the navd .npz layout has "
                           f"{list(NPZ_KEYS)} and optional dg_mgal, height_m, model")
    for k in (*NPZ_KEYS, "dg_mgal"):
        if k in data and data[k].dtype.kind not in "fiu":
            raise DovGridError(f"{k} must be numeric, got dtype {data[k].dtype}")
    dg = data.get("dg_mgal")
    src = p.name
    if "model" in data and data["model"].ndim == 0:
        src = f"{p.name} ({data['model'].item()})"
    return DovGrid(data["lat_deg"], data["lon_deg"], data["xi_arcsec"] * ARCSEC,
                   data["eta_arcsec"] * ARCSEC, None if dg is None else dg * MGAL, src)


@dataclass(frozen=True)
class _Var:
    name: str
    units: str
    values: Arr  # (nlat, nlon), NaN where masked


def _unit_factor(var: _Var, table: dict[str, float], fallback: str, what: str) -> float:
    units = var.units.strip()
    if units:
        f = table.get(units.lower())
        if f is None:
            raise DovGridError(f"variable {var.name!r} has units {units!r}; expected one of "
                               f"{sorted(set(table))}")
        return f
    if fallback:
        return table[fallback]
    raise DovGridError(f"variable {var.name!r} has no units attribute; set [dov] angle_unit "
                       f"(arcsec, microrad or rad) for {what}")


def _find_coord(ds: Any, names: tuple[str, ...], units: str) -> Any:
    lower = {n.lower(): n for n in ds.variables}
    for n in names:
        if n in lower and ds.variables[lower[n]].ndim == 1:
            return ds.variables[lower[n]]
    for v in ds.variables.values():
        if v.ndim == 1 and str(getattr(v, "units", "")).lower() == units:
            return v
    return None


def _read_file(p: Path) -> tuple[Arr, Arr, dict[str, _Var]]:
    """(lat_deg, lon_deg, {name: variable on (lat, lon) with NaN where masked})."""
    try:
        import netCDF4
    except ImportError:
        raise DovGridError("reading netCDF grids needs the netCDF4 package: "
                           "pip install 'navd[dov]'") from None
    try:
        ds = netCDF4.Dataset(str(p), "r")
    except OSError as exc:
        raise DovGridError(f"cannot open as netCDF: {exc}") from None
    try:
        ds.set_auto_maskandscale(True)
        vlat = _find_coord(ds, _LAT_NAMES, "degrees_north")
        vlon = _find_coord(ds, _LON_NAMES, "degrees_east")
        if vlat is None or vlon is None:
            raise DovGridError("no latitude/longitude coordinate variables (lat/latitude/y, "
                               "lon/longitude/x)")
        lat = np.ma.filled(np.ma.asarray(vlat[:], dtype=np.float64), np.nan)
        lon = np.ma.filled(np.ma.asarray(vlon[:], dtype=np.float64), np.nan)
        dlat, dlon = vlat.dimensions[0], vlon.dimensions[0]
        out: dict[str, _Var] = {}
        for name, v in ds.variables.items():
            if v.ndim != 2 or v is vlat or v is vlon:
                continue
            dims = tuple(v.dimensions)
            if dims not in ((dlat, dlon), (dlon, dlat)):
                continue
            a = np.ma.filled(np.ma.asarray(v[:], dtype=np.float64), np.nan)
            if dims == (dlon, dlat):
                a = a.T
            out[name] = _Var(name, str(getattr(v, "units", "")), np.array(a))
        if not out:
            raise DovGridError(f"no 2-D variable on ({dlat}, {dlon})")
    finally:
        ds.close()
    # flip descending axes (allowed by COARDS); non-monotonic ones are refused by DovGrid
    if lat.size > 1 and np.all(np.diff(lat) < 0):
        lat = lat[::-1].copy()
        out = {k: _Var(v.name, v.units, v.values[::-1, :].copy()) for k, v in out.items()}
    if lon.size > 1 and np.all(np.diff(lon) < 0):
        lon = lon[::-1].copy()
        out = {k: _Var(v.name, v.units, v.values[:, ::-1].copy()) for k, v in out.items()}
    return lat, lon, out


def _pick(found: dict[str, _Var], wanted: str, names: tuple[str, ...],
          what: str, required: bool) -> _Var | None:
    lower = {k.lower(): k for k in found}
    if wanted:
        if wanted.lower() not in lower:
            raise DovGridError(f"no variable {wanted!r} for {what}; variables: {sorted(found)}")
        return found[lower[wanted.lower()]]
    for n in names:
        if n in lower:
            return found[lower[n]]
    if required:
        raise DovGridError(f"no variable for {what} (looked for {list(names)}; variables: "
                           f"{sorted(found)}); name it in [dov] or give eta_grid")
    return None


def _load_netcdf(p: Path, eta_path: Path | None, xi_var: str, eta_var: str, dg_var: str,
                 angle_unit: str) -> DovGrid:
    fallback = _ANGLE_ALIASES.get(angle_unit, "")
    lat, lon, found = _read_file(p)
    dg: Arr | None = None
    if eta_path is None:
        if len(found) == 1 and not (xi_var or eta_var):
            raise DovGridError(f"holds one variable ({next(iter(found))}), as a GMT grid does: "
                               "give the east-west component as a second grid ([dov] eta_grid)")
        xi = _pick(found, xi_var, _XI_NAMES, "xi (north-south)", True)
        eta = _pick(found, eta_var, _ETA_NAMES, "eta (east-west)", True)
        dgv = _pick(found, dg_var, _DG_NAMES, "dg", bool(dg_var))
        if dgv is not None:
            dg = dgv.values * _unit_factor(dgv, _DG_UNITS, "", "dg")
    else:
        # GMT style: one variable per file (usually z); xi from `p`, eta from `eta_path`
        xi = (_pick(found, xi_var, (), "xi", True) if xi_var else
              _only(found, p))
        lat2, lon2, found2 = _read_file(eta_path)
        if lat2.shape != lat.shape or lon2.shape != lon.shape or not (
                np.allclose(lat2, lat, rtol=0, atol=1e-9)
                and np.allclose(lon2, lon, rtol=0, atol=1e-9)):
            raise DovGridError(f"{eta_path} (eta) is not on the same lat/lon nodes as the xi "
                               "grid")
        eta = (_pick(found2, eta_var, (), "eta", True) if eta_var else _only(found2, eta_path))
    assert xi is not None and eta is not None  # required=True picks raise instead
    xs = xi.values * _unit_factor(xi, _ANGLE_UNITS, fallback, "xi")
    es = eta.values * _unit_factor(eta, _ANGLE_UNITS, fallback, "eta")
    src = p.name if eta_path is None else f"{p.name} + {eta_path.name}"
    return DovGrid(lat, lon, xs, es, dg, src)


def _only(found: dict[str, _Var], p: Path) -> _Var:
    if len(found) != 1:
        raise DovGridError(f"{p} holds {sorted(found)}: name the variable ([dov] xi_var / "
                           "eta_var)")
    return next(iter(found.values()))


# ---------------------------------------------------------------------------------- writing

def save_dov_grid(path: str | Path, lat_deg: Arr, lon_deg: Arr, xi_rad: Arr, eta_rad: Arr,
                  dg_mps2: Arr | None = None, *, height_m: float = 0.0,
                  model: str = "", history: str = "") -> None:
    """Write a grid as navd ``.npz`` or as one COARDS/CF netCDF-4 file (xi, eta, dg)."""
    p = Path(path)
    xi_as = np.asarray(xi_rad, dtype=np.float64) / ARCSEC
    eta_as = np.asarray(eta_rad, dtype=np.float64) / ARCSEC
    if p.suffix.lower() == ".npz":
        arrays: dict[str, Any] = {
            "lat_deg": np.asarray(lat_deg, dtype=np.float64),
            "lon_deg": np.asarray(lon_deg, dtype=np.float64),
            "xi_arcsec": xi_as, "eta_arcsec": eta_as, "height_m": np.float64(height_m),
            "model": np.str_(model)}
        if dg_mps2 is not None:
            arrays["dg_mgal"] = np.asarray(dg_mps2, dtype=np.float64) / MGAL
        with open(p, "wb") as fh:
            np.savez(fh, **arrays)
        return
    if p.suffix.lower() not in NETCDF_SUFFIXES:
        raise DovGridError(f"{p}: unknown grid format {p.suffix!r}; use .npz or .nc")
    import netCDF4

    with netCDF4.Dataset(str(p), "w", format="NETCDF4") as ds:
        ds.Conventions = "COARDS, CF-1.7"
        ds.title = "Deflection of the vertical"
        ds.source = model
        ds.history = history
        ds.height_m = float(height_m)
        ds.node_offset = 0  # GMT: gridline registration
        ds.sign_convention = ("xi = Phi - phi (+ zenith north of the ellipsoid normal), "
                              "eta = (Lambda - lambda) cos phi (+ east); dg = g_D - gamma")
        ds.createDimension("lat", len(lat_deg))
        ds.createDimension("lon", len(lon_deg))
        v = ds.createVariable("lat", "f8", ("lat",))
        v.units = "degrees_north"
        v.long_name = "latitude"
        v.standard_name = "latitude"
        v[:] = lat_deg
        v = ds.createVariable("lon", "f8", ("lon",))
        v.units = "degrees_east"
        v.long_name = "longitude"
        v.standard_name = "longitude"
        v[:] = lon_deg
        for name, long_name, units, values in (
                ("xi", "deflection of the vertical, north-south component", "arcsec", xi_as),
                ("eta", "deflection of the vertical, east-west component", "arcsec", eta_as)):
            v = ds.createVariable(name, "f8", ("lat", "lon"))
            v.units = units
            v.long_name = long_name
            v[:, :] = values
        if dg_mps2 is not None:
            v = ds.createVariable("dg", "f8", ("lat", "lon"))
            v.units = "mGal"
            v.long_name = "gravity disturbance along the ellipsoid normal (down)"
            v[:, :] = np.asarray(dg_mps2, dtype=np.float64) / MGAL


def describe_values(xi_rad: Arr, eta_rad: Arr) -> str:
    """Range and RMS of a grid's deflections, arcsec (for the generator's summary)."""
    xa = np.asarray(xi_rad) / ARCSEC
    ea = np.asarray(eta_rad) / ARCSEC
    return (f"xi {xa.min():+.2f}..{xa.max():+.2f}\" (rms {math.sqrt(float(np.mean(xa**2))):.2f}), "
            f"eta {ea.min():+.2f}..{ea.max():+.2f}\" (rms {math.sqrt(float(np.mean(ea**2))):.2f})")
