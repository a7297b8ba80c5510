"""Analytic DOV field for the simulator, tests and benchmarks (a ``DovField``).

Kept out of :mod:`navd.core`: navd itself only evaluates gridded models
(:class:`navd.core.aiding.dov.DovGrid`).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.core.earth import radii
from navd.units import ARCSEC

Arr = npt.NDArray[np.float64]

TWO_PI = 2.0 * math.pi


@jit
def along_track_eval(params: Arr, lat: float, lon: float, out: Arr) -> None:
    """Kernel of :class:`AlongTrackSinusoid` (params as built there)."""
    dlon = (lon - params[1] + math.pi) % TWO_PI - math.pi
    s = params[3] * (lat - params[0]) + params[4] * dlon
    out[0] = params[5] + params[6] * math.sin(TWO_PI * s / params[7] + params[8])
    out[1] = params[9] + params[10] * math.sin(TWO_PI * s / params[11] + params[12])
    out[2] = params[13]


@jit
def _along_track_many(params: Arr, pos: Arr, out: Arr) -> None:
    for k in range(pos.shape[0]):
        along_track_eval(params, pos[k, 0], pos[k, 1], out[k])


class AlongTrackSinusoid:
    """Analytic DOV field (tests, benchmarks): sinusoids of the distance along a course.

    ``s = R_M(L0) (L - L0) cos c + R_N(L0) cos L0 (lambda - lambda0) sin c`` is the distance
    (m) from the origin projected on the course ``c`` (a local flat-earth coordinate, exact
    enough over hundreds of km for a synthetic field); then::

        xi  = xi_offset  + xi_amp  sin(2 pi s / xi_wavelength  + xi_phase)
        eta = eta_offset + eta_amp sin(2 pi s / eta_wavelength + eta_phase)
        dg  = constant

    A vehicle on that course at speed v sees sinusoids in time of period wavelength / v, as
    in seed 002's simulation.  Defined everywhere (never off grid).  Angles in rad.
    """

    def __init__(self, lat0_rad: float, lon0_rad: float, course_rad: float, *,
                 xi_amp_rad: float = 0.0, xi_wavelength_m: float = 360e3,
                 xi_phase_rad: float = 0.0, xi_offset_rad: float = 0.0,
                 eta_amp_rad: float = 0.0, eta_wavelength_m: float = 360e3,
                 eta_phase_rad: float = 0.0, eta_offset_rad: float = 0.0,
                 dg_mps2: float = 0.0) -> None:
        if not (xi_wavelength_m > 0.0 and eta_wavelength_m > 0.0):
            raise ValueError("wavelengths must be > 0 m")
        r_m, r_n = radii(lat0_rad)
        self.source = "analytic along-track sinusoid"
        self.params = np.array([
            lat0_rad, lon0_rad, course_rad, r_m * math.cos(course_rad),
            r_n * math.cos(lat0_rad) * math.sin(course_rad),
            xi_offset_rad, xi_amp_rad, xi_wavelength_m, xi_phase_rad,
            eta_offset_rad, eta_amp_rad, eta_wavelength_m, eta_phase_rad, dg_mps2])

    def eval_into(self, lat_rad: float, lon_rad: float, out: Arr) -> bool:
        along_track_eval(self.params, lat_rad, lon_rad, out)
        return True

    def eval_track(self, pos: Arr) -> Arr:
        """(N, 3) field values at positions (N, >=2) (lat_rad, lon_rad, ...) - the very
        kernel the estimator calls, so a simulated truth matches it bit for bit."""
        p = np.ascontiguousarray(pos, dtype=np.float64)
        out = np.empty((p.shape[0], 3))
        _along_track_many(self.params, p, out)
        return out

    def describe(self) -> str:
        p = self.params
        return (f"{self.source}: course {math.degrees(p[2]):.1f} deg, xi "
                f"{p[6] / ARCSEC:.3g}\" / {p[7] / 1e3:.4g} km, eta {p[10] / ARCSEC:.3g}\" / "
                f"{p[11] / 1e3:.4g} km")
