"""Simulated DroneCAN IMU / GNSS nodes: navd.types -> python-can frames.

ImuSample -> uavcan.equipment.ahrs.RawIMU (1003): integrals = the increments,
``integration_interval`` = dt; the float16 "latest" fields get the mean rates.  With
``integrated=False`` the interval is 0 and only the point samples are meaningful, as from a
node that does not integrate.
GnssSample -> uavcan.equipment.gnss.Fix2 (1063): lat/lon 1e-8 deg, heights mm (MSL =
ellipsoid - ``geoid_sep_m``), NED velocity float32, covariance as AP_Periph sends it
(6-element diagonal: h², h², v², s², s², s²), optional ECEF position/velocity.
PolSample -> navd.equipment.SkyPolarization (20440, navd's private type,
navd/io/dsdl/navd/equipment/): encoded here by hand (the dronecan package only knows the type
after ``dronecan.load_dsdl``); tests compare the frames with the codec's, byte for byte.
Frames carry 29-bit IDs, tail bytes and (multi-frame) the transfer CRC, from the dronecan
package's transfer codec.  The transfer ID increments per data type, mod 32.
"""

from __future__ import annotations

import binascii
import math
import struct

import can
import dronecan
from dronecan import transport

from navd.core.sun import utc_to_gps_s
from navd.io.dronecan import FIX2_DTID, POL_DTID, POL_SIGNATURE, RAW_IMU_DTID
from navd.types import FixType, GnssSample, ImuSample, PolSample

_MODE = {  # FixType -> (Fix2 mode, sub_mode)
    FixType.FIX_3D: (0, 0),
    FixType.DGPS: (1, 0),
    FixType.RTK_FLOAT: (2, 0),
    FixType.RTK_FIXED: (2, 1),
}


class DronecanTx:
    """One simulated node (``node_id``) publishing RawIMU and Fix2."""

    def __init__(self, node_id: int, priority: int = 8) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node_id must be 1..127, got {node_id}")
        self.node_id = node_id
        self.priority = priority
        self._tid: dict[int, int] = {}

    def _frames(self, dtid: int, payload: object) -> list[can.Message]:
        tid = self._tid.get(dtid, 0)
        self._tid[dtid] = (tid + 1) & 0x1F
        t = transport.Transfer(
            transfer_id=tid,
            source_node_id=self.node_id,
            payload=payload,
            transfer_priority=self.priority,
        )
        return [
            can.Message(arbitration_id=f.message_id, data=bytes(f.bytes), is_extended_id=True)
            for f in t.to_frames()
        ]

    def polarization(self, s: PolSample, sensor_id: int = 0) -> list[can.Message]:
        """One SkyPolarization transfer: time stamp = sensor clock, GPS time from UTC."""
        gps_us = 0
        if math.isfinite(s.utc_unix_s):
            gps_us = max(0, round(utc_to_gps_s(s.utc_unix_s) * 1e6))
        payload = (s.t_us.to_bytes(7, "little")
                   + struct.pack("<QffB", gps_us, s.aop_rad, s.dop, sensor_id))
        crc = binascii.crc_hqx(payload, binascii.crc_hqx(struct.pack("<Q", POL_SIGNATURE),
                                                         0xFFFF))
        data = struct.pack("<H", crc) + payload
        tid = self._tid.get(POL_DTID, 0)
        self._tid[POL_DTID] = (tid + 1) & 0x1F
        cid = (self.priority << 24) | (POL_DTID << 8) | self.node_id
        chunks = [data[i:i + 7] for i in range(0, len(data), 7)]
        out = []
        for k, c in enumerate(chunks):
            tail = ((k == 0) << 7) | ((k == len(chunks) - 1) << 6) | ((k & 1) << 5) | tid
            out.append(can.Message(arbitration_id=cid, data=c + bytes([tail]),
                                   is_extended_id=True))
        return out

    def raw_imu(self, s: ImuSample, integrated: bool = True) -> list[can.Message]:
        dt_s = s.dt_us * 1e-6
        m = dronecan.uavcan.equipment.ahrs.RawIMU()
        m.timestamp.usec = s.t_us
        m.integration_interval = dt_s if integrated else 0.0
        m.rate_gyro_integral = [s.dtheta_x, s.dtheta_y, s.dtheta_z]
        m.accelerometer_integral = [s.dvel_x, s.dvel_y, s.dvel_z]
        m.rate_gyro_latest = [s.dtheta_x / dt_s, s.dtheta_y / dt_s, s.dtheta_z / dt_s]
        m.accelerometer_latest = [s.dvel_x / dt_s, s.dvel_y / dt_s, s.dvel_z / dt_s]
        return self._frames(RAW_IMU_DTID, m)

    def fix2(
        self,
        g: GnssSample,
        with_ecef: bool = False,
        geoid_sep_m: float = 0.0,
        covariance: list[float] | None = None,
    ) -> list[can.Message]:
        m = dronecan.uavcan.equipment.gnss.Fix2()
        m.timestamp.usec = g.t_us
        m.gnss_timestamp.usec = 0
        m.gnss_time_standard = 0
        m.latitude_deg_1e8 = round(math.degrees(g.lat_rad) * 1e8)
        m.longitude_deg_1e8 = round(math.degrees(g.lon_rad) * 1e8)
        m.height_ellipsoid_mm = round(g.alt_m * 1e3)
        m.height_msl_mm = round((g.alt_m - geoid_sep_m) * 1e3)
        m.ned_velocity = [g.vel_n, g.vel_e, g.vel_d]
        m.sats_used = 12
        m.status = 3 if g.fix_type >= FixType.FIX_3D else int(g.fix_type)
        m.mode, m.sub_mode = _MODE.get(g.fix_type, (0, 0))
        if covariance is None:
            h2, v2, s2 = g.h_acc_m**2, g.v_acc_m**2, g.vel_acc_mps**2
            covariance = [h2, h2, v2, s2, s2, s2]
        m.covariance = covariance
        m.pdop = 1.5
        if with_ecef:
            if g.pos_ecef_m is None or g.vel_ecef_mps is None:
                raise ValueError("with_ecef needs pos_ecef_m and vel_ecef_mps in the sample")
            e = dronecan.uavcan.equipment.gnss.ECEFPositionVelocity()
            e.velocity_xyz = list(g.vel_ecef_mps)
            e.position_xyz_mm = [round(v * 1e3) for v in g.pos_ecef_m]
            m.ecef_position_velocity = [e]
        return self._frames(FIX2_DTID, m)
