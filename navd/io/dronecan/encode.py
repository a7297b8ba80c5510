"""navd outputs -> DroneCAN frames.

Output
    uavcan.equipment.ahrs.Solution (1000): quaternion in x, y, z, w order (navd is w, x, y, z),
    float16; attitude 1-sigma as a diagonal roll/pitch/yaw covariance (rad²).

Frames are built here (serialised by :func:`navd.io.dronecan.transfer.transfer_messages`);
putting them on a bus is :class:`navd.io.dronecan.link.DronecanLink`'s job.
"""

from __future__ import annotations

import math

import can
import dronecan

from navd.io.dronecan.transfer import transfer_messages
from navd.types import NavSolution

__all__ = ["SOLUTION_DTID", "DronecanEncoder"]

SOLUTION_DTID = 1000


class DronecanEncoder:
    """navd outputs -> DroneCAN frames; one transfer-ID counter per data type, as required."""

    def __init__(self, node_id: int = 100, priority: int = 16) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node_id must be 1..127, got {node_id}")
        self.node_id = node_id
        self.priority = priority
        self._tid: dict[int, int] = {}

    def _next_tid(self, dtid: int) -> int:
        tid = self._tid.get(dtid, 0)
        self._tid[dtid] = (tid + 1) & 0x1F
        return tid

    def encode_solution(self, sol: NavSolution) -> list[can.Message]:
        w, x, y, z = sol.quat_nb
        m = dronecan.uavcan.equipment.ahrs.Solution()
        m.timestamp.usec = max(0, sol.t_us)
        m.orientation_xyzw = [x, y, z, w]
        m.orientation_covariance = [
            sol.att_sd_rad[0] ** 2, 0.0, 0.0,
            0.0, sol.att_sd_rad[1] ** 2, 0.0,
            0.0, 0.0, sol.att_sd_rad[2] ** 2,
        ]
        m.angular_velocity = list(sol.rate_b)
        # navd does not estimate linear acceleration; NaN says "not provided".
        m.linear_acceleration = [math.nan, math.nan, math.nan]
        return transfer_messages(m, self.node_id, self._next_tid(SOLUTION_DTID), self.priority)
