"""Gravity disturbance and deflection of the vertical from a gravity model (``navd dov-grid``).

Model.  The actual gravity at P = (lat, lon, h) is the gradient of the model's gravitational
potential V plus the centrifugal acceleration; the normal gravity is the gradient of the
WGS-84 normal potential U (the even zonal harmonics J2..J20 of the level ellipsoid, derived
here from a, f, GM, omega) plus the same centrifugal term, so the gravity disturbance is
the gradient of the disturbing potential T = W - U::

    dg^n = C_e^n (grad V_model - grad V_normal)          (NED, at geodetic latitude)
    xi   = -dg_N / gamma,   eta = -dg_E / gamma          (= -(1/(gamma r)) dT/dphi, ...)

On the ellipsoid (h = 0) the normal gravity is exactly along the ellipsoid normal with the
Somigliana magnitude, so these are the classical deflections (Helmert) and the grid's
``dg`` is the gravity disturbance.  The grid stores what navd's mechanization adds to its
own normal gravity ``[0, 0, gamma(L, h)]`` (Somigliana + free air)::

    xi = -g_N / gamma,  eta = -g_E / gamma,  dg = g_D - gamma

which equals the classical values at h = 0; above the ellipsoid it also carries the
curvature of the normal plumb line (about 0.17" sin 2L per km) and the free-air formula's
error, which is what the mechanization needs there.

Gravity models (``--model``):
    egm96       EGM96 to degree ``--nmax`` (<= 360) through the ``gravitas`` package,
                which embeds the coefficients (optional extra ``navd[dov]``).
    normal      the WGS-84 normal field itself: zero deflection at h = 0 (a check).
    normal-j2   J2 only: shows what the higher even zonals are worth (~1").

Example::

    navd dov-grid --lat-min 21 --lat-max 24 --lon-min 112 --lon-max 116 \\
        --step-arcmin 2 --out south_china_sea.nc
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import Protocol

import numpy as np
import numpy.typing as npt

from navd.core.earth import A_M, B_M, E2, GM, OMEGA_IE, geodetic_to_ecef, gravity, mat_ne

Arr = npt.NDArray[np.float64]

# ------------------------------------------------------------------------ normal field


def normal_j2() -> float:
    """WGS-84 dynamic form factor J2 from the defining constants (a, f, GM, omega).

    ``J2 = e^2/3 (1 - 2/15 m e' / q0)``, ``q0 = ((1 + 3/e'^2) atan e' - 3/e') / 2``,
    ``m = omega^2 a^2 b / GM`` (Heiskanen & Moritz 1967, eqs. 2-90, 2-58, 2-70).  Gives
    C20 = -J2/sqrt(5) = -0.484166774985e-3, the published WGS-84 value (NIMA TR8350.2).
    """
    e = math.sqrt(E2)
    ep = e / math.sqrt(1.0 - E2)
    m = OMEGA_IE**2 * A_M**2 * B_M / GM
    q0 = 0.5 * ((1.0 + 3.0 / ep**2) * math.atan(ep) - 3.0 / ep)
    return E2 / 3.0 * (1.0 - 2.0 / 15.0 * m * ep / q0)


def normal_j2n(n: int) -> float:
    """Even zonal J_{2n} of the normal field (Heiskanen & Moritz 1967, eq. 2-92)."""
    j2 = normal_j2()
    return ((-1.0) ** (n + 1) * 3.0 * E2**n / ((2 * n + 1) * (2 * n + 3))
            * (1.0 - n + 5.0 * n * j2 / E2))


def zonal_gravitation(xyz_m: Arr, j: dict[int, float], gm: float = GM,
                      a_m: float = A_M) -> Arr:
    """Gradient of ``V = GM/r (1 - sum_n J_n (a/r)^n P_n(z/r))`` in ECEF, m/s^2, (N, 3).

    Args:
        xyz_m: (N, 3) ECEF positions, m.
        j: unnormalized zonal coefficients {degree: J_n}.
    """
    x = np.asarray(xyz_m, dtype=np.float64)
    r = np.linalg.norm(x, axis=1)
    t = x[:, 2] / r
    v_r = -gm / r**2  # dV/dr at fixed t
    v_t = np.zeros_like(r)  # dV/dt at fixed r
    nmax = max(j) if j else 0
    p_prev, p = np.ones_like(t), t.copy()  # P_0, P_1
    dp = np.ones_like(t)  # P_1'
    for n in range(1, nmax + 1):
        if n >= 2:
            p_new = ((2 * n - 1) * t * p - (n - 1) * p_prev) / n
            dp_new = n * p + t * dp
            p_prev, p = p, p_new
            dp = dp_new
        c = -j.get(n, 0.0)
        if c == 0.0:
            continue
        q = (a_m / r) ** n
        v_r = v_r - gm / r**2 * c * (n + 1) * q * p
        v_t = v_t + gm / r * c * q * dp
    rhat = x / r[:, None]
    grad_t = (np.array([0.0, 0.0, 1.0])[None, :] - t[:, None] * rhat) / r[:, None]
    out: Arr = v_r[:, None] * rhat + v_t[:, None] * grad_t
    return out


class GravitationModel(Protocol):
    """Gravitational attraction (no centrifugal term) of an earth model in ECEF."""

    name: str

    def gravitation(self, xyz_m: Arr) -> Arr:
        """(N, 3) ECEF positions, m -> (N, 3) attraction, m/s^2."""
        ...


class NormalField:
    """The WGS-84 normal gravitational field (even zonals up to ``2 * n_zonal``)."""

    def __init__(self, n_zonal: int = 10, j2_only: bool = False) -> None:
        self.j = {2: normal_j2()} if j2_only else {2 * k: normal_j2n(k)
                                                    for k in range(1, n_zonal + 1)}
        self.name = "WGS-84 normal field (J2 only)" if j2_only else "WGS-84 normal field"

    def gravitation(self, xyz_m: Arr) -> Arr:
        return zonal_gravitation(xyz_m, self.j)


class Egm96Gravitas:
    """EGM96 (tide-free, degree <= 360) as embedded in the ``gravitas`` package."""

    def __init__(self, nmax: int = 360) -> None:
        if not 2 <= nmax <= 360:
            raise ValueError(f"EGM96 degree must be in [2, 360], got {nmax}")
        try:
            import gravitas
        except ImportError:
            raise RuntimeError("the EGM96 model needs the gravitas package: "
                               "pip install 'navd[dov]'") from None
        self._fn: Callable[[Arr, int], Arr] = gravitas.earth_acceleration
        self.nmax = nmax
        self.name = f"EGM96 to degree {nmax} (gravitas)"

    def gravitation(self, xyz_m: Arr) -> Arr:
        km = np.ascontiguousarray(np.asarray(xyz_m, dtype=np.float64) / 1000.0)
        out: Arr = np.asarray(self._fn(km, self.nmax), dtype=np.float64) * 1000.0
        return out


def make_model(name: str, nmax: int = 360) -> GravitationModel:
    if name == "egm96":
        return Egm96Gravitas(nmax)
    if name == "normal":
        return NormalField()
    if name == "normal-j2":
        return NormalField(j2_only=True)
    raise ValueError(f"unknown model {name!r}; expected egm96, normal or normal-j2")


# ------------------------------------------------------------------------ synthesis

_NORMAL = NormalField()


def _ecef(lat_rad: Arr, lon_rad: Arr, h_m: float) -> Arr:
    return np.array([geodetic_to_ecef(float(a), float(b), h_m)
                     for a, b in zip(lat_rad, lon_rad, strict=True)]).reshape(-1, 3)


def _to_ned(lat_rad: Arr, lon_rad: Arr, v_e: Arr) -> Arr:
    out = np.empty_like(v_e)
    for k in range(v_e.shape[0]):
        out[k] = mat_ne(float(lat_rad[k]), float(lon_rad[k])) @ v_e[k]
    return out


def _centrifugal(xyz: Arr) -> Arr:
    c = np.zeros_like(xyz)
    c[:, 0] = OMEGA_IE**2 * xyz[:, 0]
    c[:, 1] = OMEGA_IE**2 * xyz[:, 1]
    return c


def gravity_ned(model: GravitationModel, lat_rad: Arr, lon_rad: Arr, h_m: float) -> Arr:
    """Gravity g^n (attraction + centrifugal), NED, m/s^2, (N, 3)."""
    lat = np.atleast_1d(np.asarray(lat_rad, dtype=np.float64))
    lon = np.atleast_1d(np.asarray(lon_rad, dtype=np.float64))
    x = _ecef(lat, lon, h_m)
    return _to_ned(lat, lon, model.gravitation(x) + _centrifugal(x))


def disturbance_ned(model: GravitationModel, lat_rad: Arr, lon_rad: Arr, h_m: float,
                    spherical: bool = False) -> tuple[Arr, Arr]:
    """Gravity disturbance grad T (NED) and |normal gravity|, both at P, (N, 3) and (N,).

    ``spherical``: express grad T in the geocentric (spherical) north/east/down frame, as
    NGA's synthesis programs and GeographicLib's ``Gravity -A`` do.
    """
    lat = np.atleast_1d(np.asarray(lat_rad, dtype=np.float64))
    lon = np.atleast_1d(np.asarray(lon_rad, dtype=np.float64))
    x = _ecef(lat, lon, h_m)
    d_e = model.gravitation(x) - _NORMAL.gravitation(x)
    gam = np.linalg.norm(_NORMAL.gravitation(x) + _centrifugal(x), axis=1)
    frame_lat = np.arcsin(x[:, 2] / np.linalg.norm(x, axis=1)) if spherical else lat
    return _to_ned(frame_lat, lon, d_e), gam


def classical_dov(model: GravitationModel, lat_rad: Arr, lon_rad: Arr, h_m: float,
                  spherical: bool = False) -> tuple[Arr, Arr]:
    """(xi, eta) rad from grad T: ``xi = -dg_N / gamma``, ``eta = -dg_E / gamma``."""
    d, gam = disturbance_ned(model, lat_rad, lon_rad, h_m, spherical)
    return -d[:, 0] / gam, -d[:, 1] / gam


def mechanization_dov(model: GravitationModel, lat_rad: Arr, lon_rad: Arr,
                      h_m: float) -> tuple[Arr, Arr, Arr]:
    """(xi, eta, dg) such that ``[-xi gamma, -eta gamma, gamma + dg]`` is the gravity,
    gamma = :func:`navd.core.earth.gravity` (what the grid stores; module doc)."""
    lat = np.atleast_1d(np.asarray(lat_rad, dtype=np.float64))
    g = gravity_ned(model, lat, lon_rad, h_m)
    gam = np.array([gravity(float(b), h_m) for b in lat])
    return -g[:, 0] / gam, -g[:, 1] / gam, g[:, 2] - gam


def grid_axis(lo: float, hi: float, step: float, name: str) -> Arr:
    """Nodes lo, lo + step, ... up to the first node >= hi (deg)."""
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise ValueError(f"--{name}-max must be greater than --{name}-min")
    n = math.ceil((hi - lo) / step - 1e-9)
    return lo + step * np.arange(n + 1, dtype=np.float64)


def synthesize(model: GravitationModel, lat_deg: Arr, lon_deg: Arr, h_m: float,
               progress: bool = True) -> tuple[Arr, Arr, Arr]:
    """(xi, eta, dg) on the grid (nlat, nlon), rad and m/s^2, row by row with tqdm."""
    from tqdm import tqdm

    nlat, nlon = lat_deg.size, lon_deg.size
    xi = np.empty((nlat, nlon))
    eta = np.empty((nlat, nlon))
    dg = np.empty((nlat, nlon))
    lon = np.radians(lon_deg)
    for i in tqdm(range(nlat), desc="dov-grid", unit="row", disable=None if progress else True,
                  file=sys.stderr):
        lat = np.full(nlon, math.radians(float(lat_deg[i])))
        xi[i], eta[i], dg[i] = mechanization_dov(model, lat, lon, h_m)
    return xi, eta, dg
