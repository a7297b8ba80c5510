"""Sun position (navd.core.sun) against PyEphem, and GNSS time <-> UTC with leap seconds."""

from __future__ import annotations

import datetime as dt
import math
import re
from pathlib import Path

import ephem
import numpy as np
import pytest

from navd.core.sun import (
    GPS_EPOCH_UNIX,
    LEAP_SECONDS,
    gps_minus_utc,
    gps_to_utc_unix,
    gps_week_tow_to_utc_unix,
    sun_az_el,
    sun_ned,
    sun_ned_into,
    tai_minus_utc,
    utc_to_gps_s,
)

D2R = math.pi / 180.0


def _utc(*args: int) -> float:
    return dt.datetime(*args, tzinfo=dt.UTC).timestamp()


def _ephem_ned(u: float, lat: float, lon: float, alt: float) -> np.ndarray:
    """Second source: PyEphem (libastro, VSOP87), geometric (no refraction), topocentric."""
    o = ephem.Observer()
    o.lat = str(math.degrees(lat))
    o.lon = str(math.degrees(lon))
    o.elevation = alt
    o.pressure = 0.0  # no refraction
    o.date = ephem.Date(dt.datetime.fromtimestamp(u, dt.UTC).replace(tzinfo=None))
    s = ephem.Sun(o)
    az, el = float(s.az), float(s.alt)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])


def test_sun_direction_agrees_with_pyephem_to_0p02_deg() -> None:
    """GIVEN 400 random times from 1980 to 2099, latitudes, longitudes and altitudes,
    WHEN sun_ned and PyEphem (geometric, topocentric, no refraction) give the sun direction,
    THEN they agree within 0.02 deg at worst and 0.006 deg on average."""
    rng = np.random.default_rng(7)
    worst = 0.0
    errs = []
    for _ in range(400):
        u = float(rng.uniform(_utc(1980, 1, 6), _utc(2099, 12, 31)))
        lat = float(rng.uniform(-89.0, 89.0)) * D2R
        lon = float(rng.uniform(-180.0, 180.0)) * D2R
        alt = float(rng.uniform(-100.0, 5000.0))
        a = sun_ned(u, lat, lon, alt)
        b = _ephem_ned(u, lat, lon, alt)
        ang = math.degrees(math.acos(min(1.0, float(a @ b))))
        errs.append(ang)
        worst = max(worst, ang)
    assert worst <= 0.02
    assert float(np.mean(errs)) < 0.006  # measured: mean ~0.003 deg, max ~0.01 deg


def test_seed000_window_sun_and_sunset() -> None:
    """GIVEN the seed-000 scenario site, 20N 120E, from 18:12 to 18:53 local on 2020-06-01,
    WHEN sun_az_el and sun_ned are evaluated in that window,
    THEN the sun starts at azimuth 292 deg, elevation 4.3 deg, sets to -4.5 deg with
    azimuth increasing, and agrees with PyEphem within 0.02 deg."""
    # 20N 120E, 2020-06-01 18:12 and 18:53 local (UTC+8): the sun sets in the window
    lat, lon = 20.0 * D2R, 120.0 * D2R
    az0, el0 = sun_az_el(_utc(2020, 6, 1, 10, 12), lat, lon)
    az1, el1 = sun_az_el(_utc(2020, 6, 1, 10, 53), lat, lon)
    assert math.degrees(az0) == pytest.approx(292.0, abs=0.1)
    assert math.degrees(el0) == pytest.approx(4.3, abs=0.1)
    assert math.degrees(el1) == pytest.approx(-4.5, abs=0.1)
    assert az1 > az0
    for u in (_utc(2020, 6, 1, 10, 12), _utc(2020, 6, 1, 10, 32, 30)):
        a = sun_ned(u, lat, lon, 50.0)
        b = _ephem_ned(u, lat, lon, 50.0)
        assert math.degrees(math.acos(min(1.0, float(a @ b)))) < 0.02


def test_validity_window_and_bad_time() -> None:
    """GIVEN times in 1960, 2100, NaN, and 1972,
    WHEN sun_ned_into and sun_ned are called,
    THEN times outside the validity window or NaN return False with a zeroed output,
    1972 gives a unit vector, and sun_ned raises ValueError outside the window."""
    out = np.ones(3)
    assert not sun_ned_into(out, _utc(1960, 1, 1), 0.3, 2.0, 0.0)
    assert not out.any()
    assert not sun_ned_into(out, math.nan, 0.3, 2.0, 0.0)
    assert not sun_ned_into(out, _utc(2100, 1, 1), 0.3, 2.0, 0.0)
    assert sun_ned_into(out, _utc(1972, 1, 1), 0.3, 2.0, 0.0)
    assert np.linalg.norm(out) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="validity"):
        sun_ned(_utc(1960, 1, 1), 0.3, 2.0)


def test_gps_utc_conversion() -> None:
    """GIVEN UTC instants around the 2017 leap second, the GPS epoch and other dates,
    WHEN converting between UTC, GPS seconds and GPS week/TOW,
    THEN GPS-UTC is 0, 17 or 18 s as tabulated, week 2108 TOW maps to the right UTC,
    UTC -> GPS -> UTC round-trips exactly, and the leap second 23:59:60 maps onto the
    next day's 0 s."""
    assert gps_minus_utc(_utc(2020, 6, 1)) == 18.0
    assert gps_minus_utc(_utc(2016, 12, 31, 23, 59, 59)) == 17.0
    assert gps_minus_utc(_utc(2017, 1, 1)) == 18.0
    assert gps_minus_utc(GPS_EPOCH_UNIX) == 0.0
    # GPS week 2108 began Sunday 2020-05-31; Monday 10:12:00 UTC is TOW 86400 + 36720 + 18
    assert gps_week_tow_to_utc_unix(2108, 86400 + 36720 + 18) == _utc(2020, 6, 1, 10, 12)
    for u in (_utc(1985, 3, 1), _utc(2006, 1, 1), _utc(2016, 12, 31, 23, 59, 59),
              _utc(2017, 1, 1), _utc(2020, 6, 1, 10, 12) + 0.5, _utc(2040, 1, 1)):
        assert gps_to_utc_unix(utc_to_gps_s(u)) == u
    # the second after 2016-12-31T23:59:59 in GPS time is the leap second 23:59:60 -> next 0 s
    g = utc_to_gps_s(_utc(2016, 12, 31, 23, 59, 59))
    assert gps_to_utc_unix(g + 2.0) == _utc(2017, 1, 1)


def test_leap_second_table_matches_tzdata() -> None:
    """GIVEN the system's /usr/share/zoneinfo/leap-seconds.list (skipped if absent),
    WHEN its rows are parsed into (unix time, TAI-UTC),
    THEN they equal navd's LEAP_SECONDS table entry for entry, and tai_minus_utc after
    the last entry returns its offset."""
    path = Path("/usr/share/zoneinfo/leap-seconds.list")
    if not path.exists():
        pytest.skip("no system leap-seconds.list to compare with")
    ntp_to_unix = 2208988800
    rows = []
    for line in path.read_text().splitlines():
        m = re.match(r"^(\d+)\s+(\d+)", line)
        if m:
            rows.append((int(m.group(1)) - ntp_to_unix, int(m.group(2))))
    assert rows
    assert tuple(rows) == LEAP_SECONDS[: len(rows)]
    assert len(rows) == len(LEAP_SECONDS)
    assert tai_minus_utc(rows[-1][0] + 1.0) == rows[-1][1]
