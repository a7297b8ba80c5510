"""Sun direction from UTC and WGS-84 position; GNSS time <-> UTC with a leap-second table.

Algorithm (allocation-free, compiled): J. Meeus, *Astronomical Algorithms*, 2nd ed. (1998),
the same low-precision solar theory as the NOAA Solar Calculator, with its pieces written out:

* ch. 25 "low accuracy": geometric mean longitude ``L0``, mean anomaly ``M``, equation of
  the centre ``C`` (three terms), true longitude ``L0 + C``, radius ``R`` (AU) from the
  eccentricity ``e``;
* ch. 22: nutation in longitude and obliquity from the four largest terms (0.5" / 0.1"),
  mean obliquity ``eps0`` (IAU 1980 polynomial), true obliquity ``eps0 + deps``;
* aberration ``-20.4898" / R``; apparent right ascension and declination (ch. 13);
* ch. 12: Greenwich mean sidereal time from UT, plus the equation of the equinoxes;
* topocentric direction (parallax) exactly: the sun's Earth-fixed position vector
  ``R * AU * [cos d cos(a - GAST), cos d sin(a - GAST), sin d]`` minus the observer's WGS-84
  ECEF position, rotated into NED.  Polar motion (< 0.5") is ignored.

No refraction is applied: the vector is the *geometric* topocentric direction, which is what
the single-scattering skylight pattern is built on (refraction lifts only the elevation,
< 0.6 deg at the horizon, and leaves the solar meridian, hence the zenith AoP, unchanged).

Accuracy: Meeus quotes 0.01 deg for the apparent longitude of this theory; measured against
PyEphem (VSOP87, independent code; tests/test_sun.py) over 1980-2099 and all latitudes
the direction agrees to 0.003 deg on average and 0.010 deg at worst (3000 random cases):
what is left is mostly the planetary perturbations this theory omits.  Time scales: the
solar theory runs on TT (``TT = UTC + (TAI - UTC) + 32.184 s`` from the leap-second table);
sidereal time needs UT1, taken as UTC (|UT1 - UTC| < 0.9 s: <= 0.004 deg of hour angle).
Valid from 1972-01-01 (the first entry of the leap-second table: UTC in its present form)
to 2100-01-01 (UT1 - UTC stays < 0.9 s whatever leap seconds are announced, and the
theory's secular terms are good for centuries; the bound is a deliberate service limit).

GNSS time
    GPS time (and Galileo GST, BeiDou BDT + 14 s) counts SI seconds without leap seconds
    from 1980-01-06T00:00:00 UTC.  ``GPS - UTC = (TAI - UTC) - 19 s``: 18 s since
    2017-01-01.  A UTC POSIX time ``u`` (leap seconds removed) and GPS seconds ``g`` relate
    by ``g = u - 315964800 + (TAI - UTC)(u) - 19``.  Update :data:`LEAP_SECONDS` when the
    IERS announces a leap second (Bulletin C; none is scheduled as of 2025); a GNSS
    receiver's broadcast UTC parameters carry the same number.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.core.earth import geodetic_to_ecef

Arr = npt.NDArray[np.float64]

#: (UTC POSIX time at which it takes effect, TAI - UTC in s).  Source: IERS Bulletin C /
#: the IETF leap-seconds.list; tests compare it with the system's tzdata copy.
LEAP_SECONDS: tuple[tuple[int, int], ...] = (
    (63072000, 10),    # 1972-01-01
    (78796800, 11),    # 1972-07-01
    (94694400, 12),    # 1973-01-01
    (126230400, 13),   # 1974-01-01
    (157766400, 14),   # 1975-01-01
    (189302400, 15),   # 1976-01-01
    (220924800, 16),   # 1977-01-01
    (252460800, 17),   # 1978-01-01
    (283996800, 18),   # 1979-01-01
    (315532800, 19),   # 1980-01-01
    (362793600, 20),   # 1981-07-01
    (394329600, 21),   # 1982-07-01
    (425865600, 22),   # 1983-07-01
    (489024000, 23),   # 1985-07-01
    (567993600, 24),   # 1988-01-01
    (631152000, 25),   # 1990-01-01
    (662688000, 26),   # 1991-01-01
    (709948800, 27),   # 1992-07-01
    (741484800, 28),   # 1993-07-01
    (773020800, 29),   # 1994-07-01
    (820454400, 30),   # 1996-01-01
    (867715200, 31),   # 1997-07-01
    (915148800, 32),   # 1999-01-01
    (1136073600, 33),  # 2006-01-01
    (1230768000, 34),  # 2009-01-01
    (1341100800, 35),  # 2012-07-01
    (1435708800, 36),  # 2015-07-01
    (1483228800, 37),  # 2017-01-01
)
_LEAP = np.array(LEAP_SECONDS, dtype=np.float64)

GPS_EPOCH_UNIX = 315964800  # 1980-01-06T00:00:00 UTC
VALID_FROM_UNIX = 63072000.0  # 1972-01-01T00:00:00 UTC
VALID_TO_UNIX = 4102444800.0  # 2100-01-01T00:00:00 UTC

_AU_M = 149597870700.0
_D2R = math.pi / 180.0
_AS2R = _D2R / 3600.0


@jit
def tai_minus_utc(utc_unix_s: float) -> float:
    """TAI - UTC (s) at a UTC POSIX time; 10 s before 1972 (outside the table: not valid)."""
    v = 10.0
    for i in range(_LEAP.shape[0]):
        if utc_unix_s >= _LEAP[i, 0]:
            v = float(_LEAP[i, 1])
        else:
            break
    return v


def gps_minus_utc(utc_unix_s: float) -> float:
    """GPS - UTC (s), e.g. 18.0 from 2017-01-01."""
    return float(tai_minus_utc(utc_unix_s)) - 19.0


def utc_to_gps_s(utc_unix_s: float) -> float:
    """UTC POSIX seconds -> GPS seconds since the GPS epoch (continuous, no leap seconds)."""
    return utc_unix_s - GPS_EPOCH_UNIX + gps_minus_utc(utc_unix_s)


def gps_to_utc_unix(gps_s: float) -> float:
    """GPS seconds since 1980-01-06 -> UTC POSIX seconds (inverse of :func:`utc_to_gps_s`).

    The offset in force is the last table entry whose start, expressed in GPS time, is not
    after ``gps_s``.  During an inserted leap second (23:59:60) POSIX time has no name for
    the instant; it maps onto the following 00:00:00.
    """
    off = LEAP_SECONDS[0][1] - 19
    for start_unix, tai_utc in LEAP_SECONDS:
        if gps_s >= start_unix - GPS_EPOCH_UNIX + (tai_utc - 19):
            off = tai_utc - 19
        else:
            break
    return gps_s + GPS_EPOCH_UNIX - off


def gps_week_tow_to_utc_unix(week: int, tow_s: float) -> float:
    """GPS week (full, not modulo 1024) and time of week (s) -> UTC POSIX seconds."""
    return gps_to_utc_unix(week * 604800.0 + tow_s)


def sun_time_valid(utc_unix_s: float) -> bool:
    """Whether ``utc_unix_s`` lies in the algorithm's validity window (and is finite)."""
    return VALID_FROM_UNIX <= utc_unix_s < VALID_TO_UNIX


@jit
def _wrap360(x: float) -> float:
    return x - 360.0 * math.floor(x / 360.0)


@jit
def sun_ned_into(out: Arr, utc_unix_s: float, lat_rad: float, lon_rad: float,
                 alt_m: float) -> bool:
    """Unit vector from the observer to the sun, local NED, written into ``out`` (3,).

    Returns False (``out`` zeroed) when the time is outside the validity window or not
    finite.  Allocates nothing.
    """
    if not (utc_unix_s >= VALID_FROM_UNIX and utc_unix_s < VALID_TO_UNIX):
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        return False
    jd_ut = utc_unix_s / 86400.0 + 2440587.5
    jde = jd_ut + (tai_minus_utc(utc_unix_s) + 32.184) / 86400.0
    T = (jde - 2451545.0) / 36525.0
    # Meeus ch. 25 (low accuracy), degrees
    L0 = _wrap360(280.46646 + T * (36000.76983 + T * 0.0003032))
    M = _wrap360(357.52911 + T * (35999.05029 - T * 0.0001537))
    e = 0.016708634 - T * (0.000042037 + T * 0.0000001267)
    Mr = M * _D2R
    C = ((1.914602 - T * (0.004817 + T * 0.000014)) * math.sin(Mr)
         + (0.019993 - T * 0.000101) * math.sin(2.0 * Mr)
         + 0.000289 * math.sin(3.0 * Mr))
    true_lon = L0 + C
    nu = (M + C) * _D2R
    R = 1.000001018 * (1.0 - e * e) / (1.0 + e * math.cos(nu))
    # Meeus ch. 22: nutation (largest terms) and obliquity
    om = (125.04452 - T * (1934.136261 - T * (0.0020708 + T / 450000.0))) * _D2R
    Ls = (280.4665 + 36000.7698 * T) * _D2R
    Lm = (218.3165 + 481267.8813 * T) * _D2R
    dpsi = (-17.20 * math.sin(om) - 1.32 * math.sin(2.0 * Ls) - 0.23 * math.sin(2.0 * Lm)
            + 0.21 * math.sin(2.0 * om)) * _AS2R
    deps = (9.20 * math.cos(om) + 0.57 * math.cos(2.0 * Ls) + 0.10 * math.cos(2.0 * Lm)
            - 0.09 * math.cos(2.0 * om)) * _AS2R
    eps0 = (23.0 + 26.0 / 60.0 + 21.448 / 3600.0) * _D2R + (
        T * (-46.8150 + T * (-0.00059 + T * 0.001813))) * _AS2R
    eps = eps0 + deps
    # apparent longitude: + nutation, + aberration
    lam = true_lon * _D2R + dpsi - 20.4898 * _AS2R / R
    ra = math.atan2(math.cos(eps) * math.sin(lam), math.cos(lam))
    dec = math.asin(math.sin(eps) * math.sin(lam))
    # Meeus ch. 12: GMST from UT (UT1 ~ UTC), + equation of the equinoxes
    d_ut = jd_ut - 2451545.0
    Tu = d_ut / 36525.0
    gmst = (280.46061837 + 360.98564736629 * d_ut
            + Tu * Tu * (0.000387933 - Tu / 38710000.0))
    gast = _wrap360(gmst) * _D2R + dpsi * math.cos(eps)
    # Earth-fixed sun position minus observer, m
    h = ra - gast
    rs = R * _AU_M
    sx = rs * math.cos(dec) * math.cos(h)
    sy = rs * math.cos(dec) * math.sin(h)
    sz = rs * math.sin(dec)
    ox, oy, oz = geodetic_to_ecef(lat_rad, lon_rad, alt_m)
    dx = sx - ox
    dy = sy - oy
    dz = sz - oz
    # C_e^n
    sl = math.sin(lat_rad)
    cl = math.cos(lat_rad)
    so = math.sin(lon_rad)
    co = math.cos(lon_rad)
    n = -sl * co * dx - sl * so * dy + cl * dz
    ea = -so * dx + co * dy
    d = -cl * co * dx - cl * so * dy - sl * dz
    norm = math.sqrt(n * n + ea * ea + d * d)
    out[0] = n / norm
    out[1] = ea / norm
    out[2] = d / norm
    return True


def sun_ned(utc_unix_s: float, lat_rad: float, lon_rad: float, alt_m: float = 0.0) -> Arr:
    """Convenience (allocates): the NED unit vector to the sun.

    Raises:
        ValueError: time outside 1972-01-01 .. 2100-01-01 UTC or not finite.
    """
    out = np.zeros(3)
    if not sun_ned_into(out, float(utc_unix_s), float(lat_rad), float(lon_rad),
                        float(alt_m)):
        raise ValueError(f"UTC {utc_unix_s!r} s is outside the sun algorithm's validity "
                         f"(1972-01-01 .. 2100-01-01 UTC)")
    return out


def sun_az_el(utc_unix_s: float, lat_rad: float, lon_rad: float,
              alt_m: float = 0.0) -> tuple[float, float]:
    """(azimuth clockwise from north, elevation above the local horizon), rad; geometric."""
    s = sun_ned(utc_unix_s, lat_rad, lon_rad, alt_m)
    return (math.atan2(s[1], s[0]) % (2.0 * math.pi),
            math.asin(max(-1.0, min(1.0, -float(s[2])))))
