"""HIGHRES_IMU datagrams of one read, decoded in compiled code (issue 18, the batch lane).

:func:`decode_run` is ``MavlinkDecoder._highres_imu_datagram`` for a run of datagrams that
lie one after the other in a receive buffer: for each that is exactly one unsigned MAVLink 2
HIGHRES_IMU frame (CRC-16/MCRF4XX with its CRC_EXTRA) of the one locked, accepted source,
whose sequence number continues, and whose sample passes every check of that path (IMU
instance, updated-fields mask, time range, plausibility) and continues the source's time
line (``RateIntegrator.advance``), it writes the sample into an
:class:`navd.core.imu_block.ImuBlock`'s arrays, bit for bit the ImuSample that path makes.
It stops at the first datagram it cannot take; the decoder then feeds that one through the
per-datagram path (which decodes, refuses and counts whatever is unusual) and calls it again
for the rest.  The Python side (``MavlinkDecoder.feed_lane``) checks the source and the
lock once per run and writes back what the run changed: counters, the time line, the
sequence number, the lock's last-seen time and the IMU agreement's window sums.

It lives in ``navd.core`` only so that the install-time kernel build (numpy and numba, no
pymavlink) compiles it with the estimator's kernels; it knows nothing of sockets.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit

__all__ = ["LANE_STATE", "decode_run"]

# decode_run's ``lane`` array (int64): the source (sysid, compid), the wanted IMU instance,
# the updated-fields mask, HIGHRES_IMU's CRC_EXTRA, the largest interval of the time line
# (us); then what a run changes: the source's last sequence number (-1: none) and the time
# line's last stamp (us, -1: none)
L_SYS, L_COMP, L_ID, L_MASK, L_EXTRA, L_MAX_GAP, L_SEQ, L_LAST_T = range(8)
LANE_STATE = 8

_STX_V2 = 0xFD
_HIGHRES_ID = 105
_HEADER = 10
_PAYLOAD = 63  # "<Q13fHB"
_MAX_T_US = np.uint64(1 << 53)

U8 = npt.NDArray[np.uint8]
I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]


@jit
def decode_run(buf: U8, offs: I64, i0: int, n: int, lane: I64, lim: F64, scratch: U8,
               sums: F64, t_out: I64, dt_out: I64, inc_out: F64, o: int) -> int:
    """Decode datagrams ``i0..n-1`` (datagram i is ``buf[offs[i]:offs[i + 1]]``) while each
    is a lane datagram (module docstring); return how many were taken.

    Sample j of the run goes to ``t_out[o + j]``, ``dt_out[o + j]``, ``inc_out[o + j]``
    (dtheta xyz rad, dvel xyz m/s), at most ``len(t_out) - o`` of them.  ``lane``: see
    ``L_*``, its sequence number and last stamp are advanced.  ``lim``: max angular rate
    (rad/s), max specific force (m/s^2).  ``scratch``: 64 zeroed bytes or more (the
    payload, zero-padded as MAVLink 2 trims it; 8-byte aligned for the views).  ``sums``:
    the locked stream's IMU agreement sums (rate xyz rad/s, specific force xyz m/s^2), each
    sample added in order as ``ImuAgreement.add_locked`` adds them.
    """
    sysid = lane[L_SYS]
    compid = lane[L_COMP]
    want_id = lane[L_ID]
    mask = lane[L_MASK]
    extra = lane[L_EXTRA]
    max_gap = lane[L_MAX_GAP]
    seq_last = lane[L_SEQ]
    last_t = lane[L_LAST_T]
    mg = lim[0]
    ma = lim[1]
    room = len(t_out) - o
    k = 0
    for i in range(i0, n):
        if k >= room or seq_last < 0 or last_t < 0:
            break
        p = offs[i]
        size = offs[i + 1] - p
        # FrameScanner.is_unsigned_v2: one unsigned v2 frame filling the datagram
        if (size < 12 or buf[p] != _STX_V2 or buf[p + 2] != 0
                or size != buf[p + 1] + _HEADER + 2):
            break
        if buf[p + 7] != _HIGHRES_ID or buf[p + 8] != 0 or buf[p + 9] != 0:
            break
        if buf[p + 5] != sysid or buf[p + 6] != compid:
            break
        seq = np.int64(buf[p + 4])
        if (seq - seq_last - 1) & 0xFF:  # a frame lost: _track counts it (Python)
            break
        body_end = p + size - 2
        crc = 0xFFFF
        for q in range(p + 1, body_end + 1):
            b = int(buf[q]) if q < body_end else int(extra)
            tmp = (b ^ (crc & 0xFF)) & 0xFF
            tmp = (tmp ^ (tmp << 4)) & 0xFF
            crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
        if crc != (int(buf[body_end]) | int(buf[body_end + 1]) << 8):
            break
        # the payload, zero-padded to its full length
        plen = size - _HEADER - 2
        for q in range(_PAYLOAD):
            scratch[q] = buf[p + _HEADER + q] if q < plen else 0
        t_raw = scratch[0:8].view(np.uint64)[0]
        f = scratch[8:32].view(np.float32)
        updated = np.int64(scratch[60]) | np.int64(scratch[61]) << 8
        if np.int64(scratch[62]) != want_id or (updated & mask) != mask:
            break
        if t_raw == 0 or t_raw > _MAX_T_US:
            break
        ax = np.float64(f[0])
        ay = np.float64(f[1])
        az = np.float64(f[2])
        gx = np.float64(f[3])
        gy = np.float64(f[4])
        gz = np.float64(f[5])
        if not (gx * gx + gy * gy + gz * gz <= mg * mg
                and ax * ax + ay * ay + az * az <= ma * ma):
            break
        t = np.int64(t_raw)
        dt_us = t - last_t
        if not (dt_us > 0 and dt_us <= max_gap):  # RateIntegrator.advance
            break
        last_t = t
        seq_last = seq
        dt_s = dt_us * 1e-6
        j = o + k
        t_out[j] = t
        dt_out[j] = dt_us
        inc_out[j, 0] = gx * dt_s
        inc_out[j, 1] = gy * dt_s
        inc_out[j, 2] = gz * dt_s
        inc_out[j, 3] = ax * dt_s
        inc_out[j, 4] = ay * dt_s
        inc_out[j, 5] = az * dt_s
        sums[0] += gx
        sums[1] += gy
        sums[2] += gz
        sums[3] += ax
        sums[4] += ay
        sums[5] += az
        k += 1
    lane[L_SEQ] = seq_last
    lane[L_LAST_T] = last_t
    return k
