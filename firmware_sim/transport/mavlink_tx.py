"""Simulated autopilot / GNSS receiver: navd.types -> MAVLink 2 frames.

ImuSample (increments) -> HIGHRES_IMU (rates = dtheta/dt, specific force = dv/dt, SI),
SCALED_IMU (mG, mrad/s, int16, time_boot_ms) or RAW_IMU (counts with a given scale).
GnssSample -> GPS_INPUT (alt MSL m float, vn/ve/vd m/s), GPS_RAW_INT (alt MSL mm plus
alt_ellipsoid, ground speed cm/s + course cdeg, accuracies mm), HIL_GPS (vn/ve/vd cm/s).
MSL heights are ellipsoid heights minus ``geoid_sep_m`` (the geoid undulation N).
Integer fields saturate instead of wrapping, as a real sender's would.
"""

from __future__ import annotations

import math
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from navd.types import GnssSample, ImuSample
from navd.units import G0 as G0_MPS2

UINT16_MAX = 0xFFFF
_I16 = (-(2**15), 2**15 - 1)
_I32 = (-(2**31), 2**31 - 1)
_U16 = (0, 2**16 - 2)  # UINT16_MAX means "unknown" in most fields
_U32 = (0, 2**32 - 1)


def _sat(x: float, lim: tuple[int, int]) -> int:
    return max(lim[0], min(lim[1], round(x)))


class MavlinkTx:
    """Encodes simulator samples as one MAVLink source (sysid/compid, own sequence)."""

    def __init__(self, sysid: int = 1, compid: int = 1) -> None:
        self._mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)

    def _pack(self, msg: Any, force_mavlink1: bool = False) -> bytes:
        buf: bytes = msg.pack(self._mav, force_mavlink1=force_mavlink1)
        self._mav.seq = (self._mav.seq + 1) & 0xFF
        return buf

    @staticmethod
    def _rates(s: ImuSample) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        dt_s = s.dt_us * 1e-6
        return (
            (s.dtheta_x / dt_s, s.dtheta_y / dt_s, s.dtheta_z / dt_s),
            (s.dvel_x / dt_s, s.dvel_y / dt_s, s.dvel_z / dt_s),
        )

    # -- IMU ------------------------------------------------------------------------------------

    def highres_imu(self, s: ImuSample, imu_id: int = 0, fields_updated: int = 0x1FFF) -> bytes:
        (gx, gy, gz), (ax, ay, az) = self._rates(s)
        return self._pack(
            self._mav.highres_imu_encode(
                s.t_us, ax, ay, az, gx, gy, gz,
                0.0, 0.0, 0.0,  # mag (gauss): not simulated
                1013.25, 0.0, 0.0, 20.0,  # abs/diff pressure hPa, pressure alt, temperature
                fields_updated, imu_id,
            )
        )

    def scaled_imu(self, s: ImuSample) -> bytes:
        (gx, gy, gz), (ax, ay, az) = self._rates(s)
        mg = 1e3 / G0_MPS2
        return self._pack(
            self._mav.scaled_imu_encode(
                (s.t_us // 1000) & 0xFFFFFFFF,
                _sat(ax * mg, _I16), _sat(ay * mg, _I16), _sat(az * mg, _I16),
                _sat(gx * 1e3, _I16), _sat(gy * 1e3, _I16), _sat(gz * 1e3, _I16),
                0, 0, 0, 2000,
            )
        )

    def raw_imu(
        self, s: ImuSample, gyro_rps_per_lsb: float, accel_mps2_per_lsb: float, imu_id: int = 0
    ) -> bytes:
        (gx, gy, gz), (ax, ay, az) = self._rates(s)
        g, a = gyro_rps_per_lsb, accel_mps2_per_lsb
        return self._pack(
            self._mav.raw_imu_encode(
                s.t_us,
                _sat(ax / a, _I16), _sat(ay / a, _I16), _sat(az / a, _I16),
                _sat(gx / g, _I16), _sat(gy / g, _I16), _sat(gz / g, _I16),
                0, 0, 0, imu_id, 2000,
            )
        )

    # -- GNSS -----------------------------------------------------------------------------------

    def gps_input(
        self,
        g: GnssSample,
        geoid_sep_m: float = 0.0,
        gps_id: int = 0,
        ignore_flags: int = 0,
        hdop: float = 0.8,
        vdop: float = 1.2,
    ) -> bytes:
        return self._pack(
            self._mav.gps_input_encode(
                g.t_us, gps_id, ignore_flags,
                0, 0,  # GPS week time: not used by navd
                int(g.fix_type),
                _sat(math.degrees(g.lat_rad) * 1e7, _I32),
                _sat(math.degrees(g.lon_rad) * 1e7, _I32),
                g.alt_m - geoid_sep_m,
                hdop, vdop,
                g.vel_n, g.vel_e, g.vel_d,
                g.vel_acc_mps, g.h_acc_m, g.v_acc_m,
                12, 0,
            )
        )

    def gps_raw_int(
        self,
        g: GnssSample,
        geoid_sep_m: float = 0.0,
        with_ellipsoid: bool = True,
        eph: int = 80,
        epv: int = 120,
    ) -> bytes:
        speed = math.hypot(g.vel_n, g.vel_e)
        cog_cdeg = round(math.degrees(math.atan2(g.vel_e, g.vel_n)) * 100.0) % 36000
        return self._pack(
            self._mav.gps_raw_int_encode(
                g.t_us,
                int(g.fix_type),
                _sat(math.degrees(g.lat_rad) * 1e7, _I32),
                _sat(math.degrees(g.lon_rad) * 1e7, _I32),
                _sat((g.alt_m - geoid_sep_m) * 1e3, _I32),
                eph, epv,
                _sat(speed * 100.0, _U16),
                cog_cdeg,
                12,
                _sat(g.alt_m * 1e3, _I32) if with_ellipsoid else 0,
                _sat(g.h_acc_m * 1e3, _U32),
                _sat(g.v_acc_m * 1e3, _U32),
                _sat(g.vel_acc_mps * 1e3, _U32),
                0, 0,
            )
        )

    def hil_gps(self, g: GnssSample, geoid_sep_m: float = 0.0, gps_id: int = 0,
                eph: int = 80, epv: int = 120) -> bytes:
        speed = math.hypot(g.vel_n, g.vel_e)
        cog_cdeg = round(math.degrees(math.atan2(g.vel_e, g.vel_n)) * 100.0) % 36000
        return self._pack(
            self._mav.hil_gps_encode(
                g.t_us,
                int(g.fix_type),
                _sat(math.degrees(g.lat_rad) * 1e7, _I32),
                _sat(math.degrees(g.lon_rad) * 1e7, _I32),
                _sat((g.alt_m - geoid_sep_m) * 1e3, _I32),
                eph, epv,
                _sat(speed * 100.0, _U16),
                _sat(g.vel_n * 100.0, _I16),
                _sat(g.vel_e * 100.0, _I16),
                _sat(g.vel_d * 100.0, _I16),
                cog_cdeg,
                12,
                gps_id,
                0,
            )
        )
