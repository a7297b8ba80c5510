"""Zenith skylight-polarization sensor model (Rayleigh single-scattering sky) and its wire twin.

Truth.  The sensor looks along its boresight ``d = -z_s``.  With ``s_s`` the unit vector to
the sun in the sensor frame (``s_s = C_b^s C_n^b s_n``, true attitude and true mounting) the
single-scattering E-vector is ``d × s_s``, so the angle of polarization (from +x_s towards
+y_s, mod pi) and the degree of polarization are::

    alpha = atan2(-s_sx, s_sy) mod pi
    DoP   = dop_max sin²g / (1 + cos²g),   cos g = d · s_s = -s_sz   (g: scattering angle)

At the zenith of a level sensor the E-vector is perpendicular to the solar meridian.  Below
``dark_sun_elevation_deg`` the sky is taken as dark (DoP 0, AoP uniform noise).

Errors.  ``DoP_meas = clip(DoP + N(0, dop_sigma), 0, 1)``; ``alpha_meas = alpha + N(0,
sigma)`` with ``sigma = aop_sigma_deg * dop_max / DoP`` (AoP noise grows as the sky's
polarization fades), wrapped to [0, pi); when DoP < 1e-3 the AoP is uniform.  The sun
direction comes from :mod:`navd.core.sun` (its accuracy is tested against PyEphem).

Wire.  :func:`encode_mavlink` writes the NAVD_SKY_POLARIZATION MAVLink 2 message defined
in ``navd/io/navd_polarization.xml`` (docs/polarization.md); navd decodes it with
:func:`navd.io.pol_wire.decode`.
"""

from __future__ import annotations

import datetime as _dt
import math
import struct
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_sim.scenario import PolarizationSpec
from navd.core.aiding.polarization import pol_row
from navd.core.rotation import euler_to_mat
from navd.core.sun import sun_ned_into, utc_to_gps_s
from navd.io import pol_wire as wire
from navd.types import PolSample
from navd.units import DEG

Arr = npt.NDArray[np.float64]

_POL_STREAM = 7  # random stream id (sensors.py uses small integers per component)

POL_COLUMNS = ("t_us", "aop_rad", "dop", "utc_unix_s", "aop_true_rad", "dop_true",
               "scatter_deg", "sun_el_deg")


def parse_utc(text: str) -> float:
    """ISO 8601 date-time with an explicit offset (``Z`` or ``+08:00``) -> UTC POSIX seconds.

    Raises:
        ValueError: not ISO 8601, or no time-zone offset (local time is ambiguous).
    """
    try:
        t = _dt.datetime.fromisoformat(text)
    except (TypeError, ValueError) as e:
        raise ValueError(f"expected an ISO 8601 UTC time like 2020-06-01T10:12:00Z, got "
                         f"{text!r}") from e
    if t.tzinfo is None or t.utcoffset() is None:
        raise ValueError(f"{text!r} has no time-zone offset; write Z (UTC) or +HH:MM")
    return t.timestamp()


def rayleigh_dop(cos_g: Arr | float, dop_max: float) -> Any:
    """Single-scattering degree of polarization for a scattering angle with cosine ``cos_g``."""
    c2 = np.square(cos_g)
    return dop_max * (1.0 - c2) / (1.0 + c2)


def simulate_polarization(t_us: npt.NDArray[np.int64], mat_nb: Arr, pos: Arr, t0_us: int,
                          imu_dt_us: int, spec: PolarizationSpec, seed: int
                          ) -> dict[str, npt.NDArray[Any]]:
    """Readings at ``rate_hz`` on the truth time grid (a reading at every truth sample whose
    time is a whole number of periods after ``t0_us``, the first IMU interval excluded).

    Args:
        t_us: (N+1,) truth times.  mat_nb: (N+1, 3, 3) true C_b^n.  pos: (N+1, 3) lat, lon,
            alt (rad, rad, m).  spec: the sensor.  seed: run seed.
    Returns:
        Columns of :data:`POL_COLUMNS`, plus ``truth_idx`` (int64) into the truth arrays.
    """
    period = round(1e6 / spec.rate_hz)
    rel = t_us - t0_us
    idx = np.nonzero((rel % period == 0) & (rel >= imu_dt_us))[0].astype(np.int64)
    n = idx.shape[0]
    utc0 = parse_utc(spec.start_utc)
    utc = utc0 + rel[idx].astype(np.float64) * 1e-6
    mat_sb = euler_to_mat(spec.mount_roll_deg * DEG, spec.mount_pitch_deg * DEG,
                          spec.mount_yaw_deg * DEG).T
    s_s = np.zeros((n, 3))
    sun_el = np.zeros(n)
    s_n = np.zeros(3)
    for i, k in enumerate(idx.tolist()):
        if not sun_ned_into(s_n, float(utc[i]), float(pos[k, 0]), float(pos[k, 1]),
                            float(pos[k, 2])):
            raise ValueError(f"polarization.start_utc: UTC {utc[i]} s is outside the sun "
                             "algorithm's validity (1972..2100)")
        s_s[i] = mat_sb @ (mat_nb[k].T @ s_n)
        sun_el[i] = math.asin(max(-1.0, min(1.0, -float(s_n[2]))))
    alpha = np.mod(np.arctan2(-s_s[:, 0], s_s[:, 1]), np.pi)
    cos_g = np.clip(-s_s[:, 2], -1.0, 1.0)
    dop = rayleigh_dop(cos_g, spec.dop_max)
    dop = np.where(sun_el < spec.dark_sun_elevation_deg * DEG, 0.0, dop)
    rng = np.random.default_rng([seed, _POL_STREAM])
    dop_meas = np.clip(dop + spec.dop_sigma * rng.standard_normal(n), 0.0, 1.0)
    sd = spec.aop_sigma_deg * DEG * spec.dop_max / np.maximum(dop, 1e-3)
    noise = sd * rng.standard_normal(n)
    uniform = rng.uniform(0.0, np.pi, n)
    a_meas = np.where(dop < 1e-3, uniform, np.mod(alpha + noise, np.pi))
    a_meas = np.where(a_meas >= np.pi, 0.0, a_meas)  # mod can round up to pi
    return {
        "t_us": t_us[idx].astype(np.int64), "aop_rad": a_meas, "dop": dop_meas,
        "utc_unix_s": utc, "aop_true_rad": alpha, "dop_true": dop,
        "scatter_deg": np.degrees(np.arccos(cos_g)), "sun_el_deg": np.degrees(sun_el),
        "truth_idx": idx,
    }


def pol_samples(pol: dict[str, npt.NDArray[Any]]) -> list[PolSample]:
    """The readings as navd samples."""
    return [PolSample(int(t), float(a), float(d), float(u)) for t, a, d, u in
            zip(pol["t_us"].tolist(), pol["aop_rad"].tolist(), pol["dop"].tolist(),
                pol["utc_unix_s"].tolist(), strict=True)]


# -------------------------------------------------------------------------------- wire
class PolMavlinkEncoder:
    """MAVLink 2 frames of NAVD_SKY_POLARIZATION (sequence number kept per encoder)."""

    def __init__(self, sysid: int = 1, compid: int = 158, sensor_id: int = 0) -> None:
        self.sysid = sysid
        self.compid = compid
        self.sensor_id = sensor_id
        self.seq = 0

    def encode(self, s: PolSample) -> bytes:
        """One frame: ``time_usec`` = sensor clock, ``time_gps_usec`` from UTC (+18 s...)."""
        gps_us = 0
        if math.isfinite(s.utc_unix_s):
            gps_us = max(0, round(utc_to_gps_s(s.utc_unix_s) * 1e6))
        frame = encode_mavlink(s.t_us, gps_us, s.aop_rad, s.dop, self.sensor_id, self.seq,
                               self.sysid, self.compid)
        self.seq = (self.seq + 1) & 0xFF
        return frame


def encode_mavlink(time_usec: int, time_gps_usec: int, aop_rad: float, dop: float,
                   sensor_id: int = 0, seq: int = 0, sysid: int = 1, compid: int = 158) -> bytes:
    """A MAVLink 2 frame (unsigned) of NAVD_SKY_POLARIZATION, byte-identical to mavgen's.

    Payload in wire order (sorted by type size, as MAVLink does): time_usec uint64,
    time_gps_usec uint64, aop float, dop float, id uint8; trailing zero bytes are trimmed
    (MAVLink 2 payload truncation, at least one byte kept).
    """
    payload = struct.pack("<QQffB", time_usec, time_gps_usec, aop_rad, dop, sensor_id)
    payload = payload.rstrip(b"\x00") or b"\x00"
    msgid = wire.MSG_ID
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, seq & 0xFF, sysid, compid,
                         msgid & 0xFFFF, msgid >> 16)
    crc = wire.crc_x25(header[1:] + payload + bytes([wire.CRC_EXTRA]))
    return header + payload + struct.pack("<H", crc)


def predict_aop(mat_nb: npt.NDArray[np.float64], mat_sb: npt.NDArray[np.float64],
                s_n: npt.NDArray[np.float64]) -> tuple[float, npt.NDArray[np.float64]]:
    """(alpha_hat rad, h (3,)): the filter's predicted AoP and its attitude row
    (:func:`navd.core.aiding.polarization.pol_row`), allocating; for tests and tools."""
    H = np.zeros((1, 15))
    alpha, _, _ = pol_row(H, 0, mat_nb, mat_sb, s_n)
    return alpha, H[0, 0:3].copy()
