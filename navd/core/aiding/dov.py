"""Deflection of the vertical (DOV): gravity models evaluated along the track.

Model (docs/design.md §6).  The mechanization's gravity in NED is::

    g^n = [-xi gamma, -eta gamma, gamma + dg_D]                                   (1)

with gamma the WGS-84 normal gravity (Somigliana + free air, :func:`navd.core.earth.gravity`,
along the ellipsoid normal), xi the north-south and eta the east-west component of the
deflection (rad), and dg_D the gravity disturbance along down (m/s^2).  Signs are the
astronomic ones: ``xi = Phi - phi`` is positive when the plumb-line zenith lies north of the
ellipsoid normal, ``eta = (Lambda - lambda) cos phi`` positive when it lies east; i.e. with
the disturbing potential T = W - U (spherical approximation)::

    xi = -(1 / (gamma r)) dT/dphi,    eta = -(1 / (gamma r cos phi)) dT/dlambda       (2)

A field is a regular latitude/longitude grid of (xi, eta, dg) interpolated bilinearly at
the current position (cell (i, j), fractions t along latitude and s along longitude)::

    f(L, lambda) = (1-t)(1-s) f[i,j] + (1-t) s f[i,j+1] + t (1-s) f[i+1,j] + t s f[i+1,j+1]

Outside the grid the field reports False and writes zeros: the estimator then runs on normal
gravity and counts ``dov_off_grid``.  Evaluation is compiled and allocation-free.

Uncompensated DOV (seed 002, mapped to navd's conventions: NED, errors computed - true,
``C_hat = Exp(-phi) C``).  With GNSS damping velocity and rotation modulation making the
horizontal accelerometer biases observable, the steady-state tilt error balances the
unmodelled horizontal gravity (``f^n x phi = -(g_hat - g)``)::

    phi_N = eta,        phi_E = -xi                                                    (3)

(the seed writes dphi_E = xi, dphi_N = -eta in ENU with errors true - computed).  The tilt
leaks into heading through ``phi_E' = phi_D Omega cos L + phi_N Omega sin L`` (transport
rate neglected, ``eps_E = 0``), so early on the yaw error (``dpsi = -phi_D``) is::

    dpsi = eta tan L + xi' sec L / omega_ie                                            (4)

with xi' the rate of change of xi along the track; the filter attenuates it later.
:func:`dov_status` reports (1)-(4) for the status topic, in arcseconds.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.core.earth import OMEGA_IE, radii
from navd.types import GnssSample
from navd.units import ARCSEC

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

Arr = npt.NDArray[np.float64]

MGAL = 1e-5  # m/s^2 per mGal
TWO_PI = 2.0 * math.pi

#: |xi|, |eta| above this are refused as a unit mistake (real DOV stay below ~2 arcmin)
MAX_DEFLECTION_RAD = 600.0 * ARCSEC
#: |dg| above this is refused as a unit mistake (real disturbances stay below ~600 mGal)
MAX_DG_MPS2 = 2000.0 * MGAL
#: cells above this are refused (memory: 3 float64 per cell); crop the grid first
MAX_CELLS = 50_000_000

# grid parameter vector layout (one float64 array, so the kernel takes few arguments)
_P_LAT0, _P_DLAT, _P_NLAT, _P_LON0, _P_DLON, _P_NLON, _P_SPAN, _P_PERIODIC = range(8)


class DovGridError(ValueError):
    """A DOV grid (or its file) is malformed; the message says what and where."""


@jit
def grid_eval(params: Arr, data: Arr, lat: float, lon: float, out: Arr) -> bool:
    """Bilinear (xi, eta, dg) at (lat, lon) rad into ``out``; False (zeros) off the grid.

    Args:
        params: see ``_P_*``: lat0, dlat, nlat, lon0, dlon, nlon (rad, counts), lon span
            (rad), periodic flag (1.0 when the columns close the full circle).
        data: (3, nlat, nlon) xi (rad), eta (rad), dg (m/s^2).
    """
    nlat = int(params[_P_NLAT])
    nlon = int(params[_P_NLON])
    u = (lat - params[_P_LAT0]) / params[_P_DLAT]
    # written so that NaN positions fall off the grid too; edges count with a round-off margin
    if not (u >= -1e-9 and u <= nlat - 1.0 + 1e-9):
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        return False
    if u < 0.0:
        u = 0.0
    if u > nlat - 1.0:
        u = nlat - 1.0
    i = int(u)
    if i > nlat - 2:
        i = nlat - 2  # the northern edge row belongs to the last cell
    d = (lon - params[_P_LON0]) % TWO_PI  # in [0, 2 pi)
    span = params[_P_SPAN]
    if not (d >= 0.0):  # NaN longitude
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        return False
    if params[_P_PERIODIC] > 0.5:
        # the columns close the circle: the cell east of the last column wraps to the first
        v = d / params[_P_DLON]
        j = int(v)
        if j > nlon - 1:
            j = nlon - 1
        j1 = j + 1 if j + 1 < nlon else 0
    else:
        if d > span:
            if d >= TWO_PI - 1e-12:
                d = 0.0  # a hair west of the first column
            elif d <= span * (1.0 + 1e-12) + 1e-12:
                d = span
            else:
                out[0] = 0.0
                out[1] = 0.0
                out[2] = 0.0
                return False
        v = d / params[_P_DLON]
        j = int(v)
        if j > nlon - 2:
            j = nlon - 2  # the eastern edge column belongs to the last cell
        j1 = j + 1
    t = u - i
    s = v - j
    w00 = (1.0 - t) * (1.0 - s)
    w01 = (1.0 - t) * s
    w10 = t * (1.0 - s)
    w11 = t * s
    for k in range(3):
        out[k] = (w00 * data[k, i, j] + w01 * data[k, i, j1] + w10 * data[k, i + 1, j]
                  + w11 * data[k, i + 1, j1])
    return True


def _check_axis(name: str, axis: npt.ArrayLike, lo: float, hi: float) -> Arr:
    a = np.asarray(axis, dtype=np.float64)
    if a.ndim != 1 or a.size < 2:
        raise DovGridError(f"{name} axis must be 1-D with at least 2 points, got shape "
                           f"{a.shape}")
    if not np.all(np.isfinite(a)):
        raise DovGridError(f"{name} axis has non-finite values")
    d = np.diff(a)
    if not np.all(d > 0.0):
        k = int(np.argmax(d <= 0.0))
        raise DovGridError(f"{name} axis is not sorted (strictly increasing): "
                           f"{name}[{k + 1}] = {a[k + 1]:.9g} after {name}[{k}] = {a[k]:.9g}")
    step = (a[-1] - a[0]) / (a.size - 1)
    dev = float(np.max(np.abs(d - step)))
    if dev > 1e-4 * step:
        raise DovGridError(f"{name} axis is not regularly spaced: steps range from "
                           f"{d.min():.9g} to {d.max():.9g} deg; bilinear interpolation "
                           "here needs a regular grid (resample it, e.g. gmt grdsample)")
    if a[0] < lo - 1e-9 or a[-1] > hi + 1e-9:
        raise DovGridError(f"{name} axis runs from {a[0]:.9g} to {a[-1]:.9g} deg, outside "
                           f"[{lo:g}, {hi:g}]")
    return a


def _check_values(name: str, v: npt.ArrayLike, shape: tuple[int, int], lat: Arr, lon: Arr,
                  limit: float, unit: str, scale: float) -> Arr:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != shape:
        raise DovGridError(f"{name} has shape {a.shape} but the axes give (nlat, nlon) = "
                           f"{shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        i, j = (int(x) for x in np.argwhere(bad)[0])
        raise DovGridError(f"{name} has {int(bad.sum())} NaN/fill cells of {a.size} (first at "
                           f"lat {lat[i]:.6g}, lon {lon[j]:.6g} deg); fill or crop the grid")
    big = float(np.max(np.abs(a)))
    if big > limit:
        raise DovGridError(f"|{name}| reaches {big / scale:.6g} {unit}, above the plausible "
                           f"{limit / scale:g} {unit}: wrong unit?")
    return a


class DovGrid:
    """(xi, eta[, dg]) on a regular latitude/longitude grid, bilinear; a ``DovField``.

    Args:
        lat_deg: (nlat,) strictly increasing, regularly spaced latitudes, deg.
        lon_deg: (nlon,) strictly increasing, regularly spaced longitudes, deg (any
            360-degree window; a grid whose columns close the circle wraps across the seam).
        xi_rad, eta_rad: (nlat, nlon) deflection components, rad (signs in the module doc).
        dg_mps2: (nlat, nlon) gravity disturbance along down, m/s^2; None: zeros.
        source: text for status and logs (file name, model).

    Raises:
        DovGridError: unsorted or irregular axes, mismatched shapes, NaN cells, values
            beyond physical plausibility (a unit mistake).
    """

    def __init__(self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, xi_rad: npt.ArrayLike,
                 eta_rad: npt.ArrayLike, dg_mps2: npt.ArrayLike | None = None,
                 source: str = "") -> None:
        lat = _check_axis("lat", lat_deg, -90.0, 90.0)
        lon = _check_axis("lon", lon_deg, -720.0, 720.0)
        step_lon = (lon[-1] - lon[0]) / (lon.size - 1)
        if lon[-1] - lon[0] > 360.0 + 1e-9:
            raise DovGridError(f"lon axis spans {lon[-1] - lon[0]:.9g} deg, more than 360")
        shape = (lat.size, lon.size)
        if lat.size * lon.size > MAX_CELLS:
            raise DovGridError(f"grid has {lat.size * lon.size} cells, more than {MAX_CELLS}; "
                               "crop it to the operating region (e.g. gmt grdcut)")
        xi = _check_values("xi", xi_rad, shape, lat, lon, MAX_DEFLECTION_RAD, "arcsec", ARCSEC)
        eta = _check_values("eta", eta_rad, shape, lat, lon, MAX_DEFLECTION_RAD, "arcsec",
                            ARCSEC)
        dg = (np.zeros(shape) if dg_mps2 is None else
              _check_values("dg", dg_mps2, shape, lat, lon, MAX_DG_MPS2, "mGal", MGAL))
        self.lat_deg = lat
        self.lon_deg = lon
        self.has_dg = dg_mps2 is not None
        self.source = source
        self.data = np.ascontiguousarray(np.stack([xi, eta, dg]))
        span = math.radians(lon[-1] - lon[0])
        periodic = abs((lon[-1] - lon[0]) + step_lon - 360.0) < 1e-6 * step_lon
        self.params = np.array([
            math.radians(lat[0]), math.radians((lat[-1] - lat[0]) / (lat.size - 1)),
            float(lat.size), math.radians(lon[0]), math.radians(step_lon), float(lon.size),
            span, 1.0 if periodic else 0.0])

    @property
    def xi_rad(self) -> Arr:
        out: Arr = self.data[0]
        return out

    @property
    def eta_rad(self) -> Arr:
        out: Arr = self.data[1]
        return out

    @property
    def dg_mps2(self) -> Arr:
        out: Arr = self.data[2]
        return out

    def without_dg(self) -> DovGrid:
        """The same deflections with the gravity disturbance left out (zeros)."""
        return DovGrid(self.lat_deg, self.lon_deg, self.data[0], self.data[1], None,
                       self.source + " (dg not applied)")

    def eval_into(self, lat_rad: float, lon_rad: float, out: Arr) -> bool:
        """Write (xi_rad, eta_rad, dg_d_mps2) at the position into ``out`` (3,); False
        (and zeros) off the grid.  Allocation-free."""
        return bool(grid_eval(self.params, self.data, lat_rad, lon_rad, out))

    def describe(self) -> str:
        """One line for logs and status: source, extent and spacing."""
        p = self.params
        return (f"{self.source or 'grid'}: lat {self.lat_deg[0]:.4f}..{self.lat_deg[-1]:.4f}, "
                f"lon {self.lon_deg[0]:.4f}..{self.lon_deg[-1]:.4f} deg, "
                f"step {math.degrees(p[_P_DLAT]) * 60:.4g}' x {math.degrees(p[_P_DLON]) * 60:.4g}'"
                f"{', with dg' if self.has_dg else ''}")


# ------------------------------------------------------------------------------ the aid

class DovField(Protocol):
    """A deflection-of-the-vertical model evaluated along the track (:class:`DovGrid`)."""

    def eval_into(self, lat_rad: float, lon_rad: float, out: Arr) -> bool:
        """Write (xi_rad, eta_rad, dg_d_mps2) into ``out`` (3,); False when off the model's
        area (``out`` is then zeroed: normal gravity)."""
        ...


class DovAid:
    """The estimator's gravity model: evaluates the DOV field into ``est.dov`` at every GNSS
    epoch (and at the start), so the mechanization uses the deflection of the present
    position.  Always present; with no field (off, or refused) it does nothing.

    Attributes:
        field: the model, or None (normal gravity).
        refused: why a configured model was refused (set by ``build_estimator``), or None.
        on_grid: the last evaluation was inside the model's area.
    """

    name = "dov"
    consumes = GnssSample

    def __init__(self, field: DovField | None, refused: str | None = None) -> None:
        self.field = field
        self.refused = refused
        self.on_grid = False

    def reset(self) -> None:
        pass

    def start(self, est: Estimator, fix: GnssSample) -> None:
        if self.field is not None:
            self.on_grid = self.field.eval_into(fix.lat_rad, fix.lon_rad, est.dov)

    def fuse(self, est: Estimator, g: GnssSample) -> bool:
        """Re-evaluate at the present position (not a measurement: never corrects)."""
        if self.field is not None:
            self.on_grid = self.field.eval_into(float(est.pos[0]), float(est.pos[1]), est.dov)
            if not self.on_grid:
                est.counters["dov_off_grid"] += 1
        return False

    def status(self, est: Estimator) -> dict[str, object]:
        return {"dov_model": ("off" if self.field is None else
                              "on grid" if self.on_grid else "off grid: normal gravity")}


def predicted_effect(xi_rad: float, eta_rad: float, xi_rate_rps: float,
                     lat_rad: float) -> tuple[float, float, float]:
    """Attitude error (rad) that this DOV causes when left out of the mechanization.

    Returns ``(phi_N, phi_E, dpsi)``: the tilt (3) and the early yaw error (4) of the
    module doc; ``phi_D = -dpsi``.  ``xi_rate_rps``: d xi / dt along the track, rad/s.
    """
    c = math.cos(lat_rad)
    dpsi = eta_rad * math.tan(lat_rad) + (xi_rate_rps / (c * OMEGA_IE) if c > 1e-6 else 0.0)
    return eta_rad, -xi_rad, dpsi


def _xi_rate(field: Any, pos: Arr, vel_n: Arr, tau_s: float) -> float | None:
    """d xi / dt along the track by a central difference over +-tau_s of motion."""
    r_m, r_n = radii(float(pos[0]))
    lat, lon, h = float(pos[0]), float(pos[1]), float(pos[2])
    dlat = float(vel_n[0]) * tau_s / (r_m + h)
    dlon = float(vel_n[1]) * tau_s / ((r_n + h) * max(math.cos(lat), 1e-9))
    if dlat == 0.0 and dlon == 0.0:
        return 0.0
    a = np.zeros(3)
    b = np.zeros(3)
    if not (field.eval_into(lat + dlat, lon + dlon, a) and field.eval_into(lat - dlat,
                                                                           lon - dlon, b)):
        return None
    return float(a[0] - b[0]) / (2.0 * tau_s)


def dov_status(est: Estimator, rate_window_s: float = 60.0) -> dict[str, object]:
    """DOV part of the status record (angles in arcsec); merge with ``status.update(...)``.

    Keys:
        dov_model: "off" | "refused: <why>; normal gravity" | "on grid: <source>" |
            "off grid: normal gravity (<source>)" | "waiting for the first GNSS epoch".
        dov_xi_arcsec, dov_eta_arcsec, dov_dg_mgal: the values the mechanization uses now.
        dov_xi_rate_arcsec_per_h: d xi / dt along the track (+-``rate_window_s`` of motion).
        dov_uncomp_tilt_arcsec: [phi_N, phi_E] = [eta, -xi] that leaving this DOV out of
            the mechanization would cause (seed 002, eq. (3) of the module doc).
        dov_uncomp_heading_arcsec: the early yaw error eta tan L + xi' sec L / omega_ie.
        Predictions are None while no DOV value is known (model off, refused, off grid).
    """
    field = est.dov_aid.field
    xi, eta, dg = (float(v) for v in est.dov)
    reason = est.dov_aid.refused
    out: dict[str, object] = {
        "dov_xi_arcsec": xi / ARCSEC, "dov_eta_arcsec": eta / ARCSEC, "dov_dg_mgal": dg / MGAL,
        "dov_xi_rate_arcsec_per_h": None, "dov_uncomp_tilt_arcsec": None,
        "dov_uncomp_heading_arcsec": None,
    }
    if field is None:
        out["dov_model"] = (f"refused: {reason}; normal gravity" if reason is not None
                            else "off")
        return out
    src_fn = getattr(field, "describe", None)
    src = str(src_fn()) if callable(src_fn) else type(field).__name__
    if not est.dov_aid.on_grid:
        out["dov_model"] = (f"off grid: normal gravity ({src})"
                            if est.counters.get("dov_off_grid", 0) > 0
                            else f"waiting for the first GNSS epoch ({src})")
        return out
    out["dov_model"] = f"on grid: {src}"
    rate = _xi_rate(field, est.pos, est.vel_n, rate_window_s)
    lat = float(est.pos[0])
    phi_n, phi_e, dpsi = predicted_effect(xi, eta, rate if rate is not None else 0.0, lat)
    out["dov_uncomp_tilt_arcsec"] = [phi_n / ARCSEC, phi_e / ARCSEC]
    if rate is not None:
        out["dov_xi_rate_arcsec_per_h"] = rate / ARCSEC * 3600.0
        out["dov_uncomp_heading_arcsec"] = dpsi / ARCSEC
    return out
