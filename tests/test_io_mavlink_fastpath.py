"""The HIGHRES_IMU per-sample path (issue 18) decodes and counts exactly as the general one.

``MavlinkDecoder._highres_imu_datagram`` takes the usual datagram (one unsigned HIGHRES_IMU
frame of an accepted source whose sample continues its time line) straight to its ImuSample;
everything else goes the general way.  Fed the same hostile stream, a decoder with the path
and one without it must return the same samples and end with the same counters (names,
values and their order) and the same source-lock state.
"""

from __future__ import annotations

import math
import random

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig
from navd.types import ImuSample


def _frame(mav: mavlink.MAVLink, t_us: int, gyro: tuple[float, float, float],
           accel: tuple[float, float, float], updated: int = 0xFFFF, imu_id: int = 0,
           v1: bool = False) -> bytes:
    msg = mav.highres_imu_encode(t_us, *accel, *gyro, 0.1, 0.2, 0.3, 1000.0, 0.0, 10.0, 25.0,
                                 updated, imu_id)
    buf: bytes = msg.pack(mav, force_mavlink1=v1)
    mav.seq = (mav.seq + 1) & 0xFF
    return buf


def _stream(seed: int) -> list[tuple[int, bytes]]:
    """(receive us, datagram): mostly a clean 1 kHz stream from sysid 1, with every kind of
    trouble the decoder counts mixed in."""
    rng = random.Random(seed)
    a = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    b = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    out: list[tuple[int, bytes]] = []
    t = 100_000_000
    recv = 5_000_000
    for _ in range(4000):
        t += 1000
        recv += 1000 + rng.randint(-200, 200)
        gyro = (rng.gauss(0, 0.1), rng.gauss(0, 0.1), rng.gauss(0, 0.1))
        accel = (rng.gauss(0, 1), rng.gauss(0, 1), rng.gauss(-9.8, 1))
        r = rng.random()
        if r < 0.02:
            gyro = (math.nan, gyro[1], gyro[2])
        elif r < 0.03:
            accel = (1e4, accel[1], accel[2])  # absurd
        elif r < 0.04:
            gyro = (50.0, 0.0, 0.0)  # absurd rate
        elif r < 0.05:
            out.append((recv, _frame(a, t - 1000, gyro, accel)))  # duplicate time
        elif r < 0.06:
            out.append((recv, _frame(a, t - 5000, gyro, accel)))  # out of order
        elif r < 0.065:
            t += 300_000  # a gap
        elif r < 0.067:
            t -= 3_000_000  # the clock goes back (a reboot)
        elif r < 0.08:
            out.append((recv, _frame(b, t, gyro, accel)))  # a second source
        elif r < 0.09:
            out.append((recv, _frame(a, t, gyro, accel, updated=0x0007)))  # stale fields
        elif r < 0.10:
            out.append((recv, _frame(a, t, gyro, accel, imu_id=1)))  # another instance
        elif r < 0.11:
            d = bytearray(_frame(a, t, gyro, accel))
            d[20] ^= 0x40  # bad checksum
            out.append((recv, bytes(d)))
            continue
        elif r < 0.12:
            out.append((recv, _frame(a, t, gyro, accel, v1=True)))  # MAVLink 1
            continue
        elif r < 0.125:
            a.seq = (a.seq + 5) & 0xFF  # lost frames
        elif r < 0.13:
            out.append((recv, _frame(a, 0, gyro, accel)))  # no time stamp
        elif r < 0.135:
            out.append((recv, _frame(a, t, gyro, accel) + b"\x00"))  # trailing junk
            continue
        out.append((recv, _frame(a, t, gyro, accel)))
    return out


@pytest.mark.parametrize("relock_s", [None, 0.5])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_fast_path_decodes_and_counts_as_the_general_one(seed: int,
                                                             relock_s: float | None) -> None:
    cfg = MavlinkInputConfig(nominal_imu_rate_hz=1000.0, relock_s=relock_s)
    fast, slow = MavlinkDecoder(cfg), MavlinkDecoder(cfg)
    assert fast._highres_fast
    slow._highres_fast = False
    path = fast._highres_imu_datagram
    taken = []

    def counted(data: bytes, recv_t_us: int) -> ImuSample | None:
        s = path(data, recv_t_us)
        taken.append(s is not None)
        return s

    fast._highres_imu_datagram = counted  # type: ignore[method-assign]
    for recv, d in _stream(seed):
        got, want = fast.feed_datagram(d, recv), slow.feed_datagram(d, recv)
        assert got == want
        assert fast.last_junk == slow.last_junk
    assert sum(taken) > 2000 and not all(taken)
    c_fast, c_slow = fast.counters.snapshot(), slow.counters.snapshot()
    assert list(c_fast.items()) != [] and list(c_fast.items()) == list(c_slow.items())
    if relock_s is not None:
        assert fast.source_lock is not None and slow.source_lock is not None
        assert fast.source_lock.status() == slow.source_lock.status()
        fa, sa = fast.source_lock.imu_agreement, slow.source_lock.imu_agreement
        assert (fa.locked_mean(), fa._others, fa._start_us) == (sa.locked_mean(), sa._others,
                                                                 sa._start_us)
        assert "imu_source_refused" in c_fast


def test_signed_links_and_receive_time_stamps_take_the_general_path() -> None:
    assert not MavlinkDecoder(MavlinkInputConfig(signing_key=bytes(32)))._highres_fast
    assert not MavlinkDecoder(MavlinkInputConfig(use_receive_time=True))._highres_fast
    assert not MavlinkDecoder(MavlinkInputConfig(imu_messages=frozenset({"RAW_IMU"}),
                                                 raw_gyro_rps_per_lsb=1e-3,
                                                 raw_accel_mps2_per_lsb=1e-2))._highres_fast
