"""The batch lane (issue 18) decodes, counts and pushes exactly as the per-sample path.

``MavlinkDecoder.feed_lane`` takes a read's worth of HIGHRES_IMU datagrams in compiled code
(navd.core.highres_batch); whatever it does not take goes through ``feed_datagram``.  Fed
the hostile streams of tests/test_io_mavlink_fastpath.py in reads of random size, a decoder
using the lane and one using only ``feed_datagram`` must return the same samples and end with
the same counters (names, values, order), source lock, agreement window, time lines and
sequence numbers.  ``Estimator.push_imu_block`` (navd.core.imu_block) must end in the state
that pushing the same samples one by one gives.
"""

from __future__ import annotations

import dataclasses
import random

import numpy as np
import numpy.typing as npt
import pytest

from navd.config import EstimatorConfig
from navd.core.estimator import Estimator
from navd.core.imu_block import ImuBlock
from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig
from navd.types import GnssSample, ImuSample, Sample
from tests.test_io_mavlink_fastpath import _frame, _stream


def _arrays(datagrams: list[bytes]) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.int64]]:
    """One read: the datagrams back to back, and where each starts (and the last ends)."""
    buf = np.frombuffer(bytearray(b"".join(datagrams)), np.uint8)
    offs = np.zeros(len(datagrams) + 1, np.int64)
    offs[1:] = np.cumsum([len(d) for d in datagrams])
    return buf, offs


def lane_feed(dec: MavlinkDecoder, datagrams: list[bytes], now: int,
              block: ImuBlock) -> tuple[list[Sample], int]:
    """What the UDP protocol does with one read: the lane while it takes datagrams, the
    per-datagram path for each one it does not; the samples in order, and how many
    datagrams the lane took."""
    buf, offs = _arrays(datagrams)
    out: list[Sample] = []
    i = taken = 0
    n = len(datagrams)
    while i < n:
        block.n = block.start = 0
        k = dec.feed_lane(buf, offs, i, n, now, block)
        if k:
            out.extend(block.samples())
            i += k
            taken += k
            continue
        out.extend(dec.feed_datagram(datagrams[i], now))
        i += 1
    return out, taken


def _reads(seed: int) -> list[tuple[int, list[bytes]]]:
    """The fast-path test's stream cut into reads of 1..32 datagrams, each read at the
    receive time of its last datagram."""
    stream = _stream(seed)
    rng = random.Random(seed + 100)
    reads = []
    i = 0
    while i < len(stream):
        k = rng.choice([1, 2, 5, 10, 10, 10, 12, 32])
        part = stream[i:i + k]
        reads.append((part[-1][0], [d for _, d in part]))
        i += k
    return reads


@pytest.mark.parametrize("relock_s", [None, 0.5])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_lane_decodes_and_counts_as_the_per_datagram_path(seed: int,
                                                              relock_s: float | None) -> None:
    cfg = MavlinkInputConfig(nominal_imu_rate_hz=1000.0, relock_s=relock_s)
    lane, slow = MavlinkDecoder(cfg), MavlinkDecoder(cfg)
    assert lane.lane
    slow._highres_fast = False
    block = ImuBlock()
    taken = 0
    for now, datagrams in _reads(seed):
        got, k = lane_feed(lane, datagrams, now, block)
        taken += k
        want = [s for d in datagrams for s in slow.feed_datagram(d, now)]
        assert got == want
        assert lane.last_junk == slow.last_junk
    assert taken > 2000
    c_lane, c_slow = lane.counters.snapshot(), slow.counters.snapshot()
    assert list(c_lane.items()) == list(c_slow.items())
    assert {k: s.last_seq for k, s in lane._sources.items()} == {
        k: s.last_seq for k, s in slow._sources.items()}
    assert lane._imu._last_t_us == slow._imu._last_t_us
    assert lane._imu._new_line == slow._imu._new_line
    if relock_s is not None:
        assert lane.source_lock is not None and slow.source_lock is not None
        assert lane.source_lock.status() == slow.source_lock.status()
        assert lane.source_lock._locked == slow.source_lock._locked
        fa, sa = lane.source_lock.imu_agreement, slow.source_lock.imu_agreement
        assert (fa.locked_mean(), fa._others, fa._start_us) == (sa.locked_mean(), sa._others,
                                                                 sa._start_us)
        assert "imu_source_refused" in c_lane


def test_the_lane_takes_a_clean_read_whole_and_stops_where_it_must() -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    cfg = MavlinkInputConfig(nominal_imu_rate_hz=1000.0, relock_s=0.5)
    dec = MavlinkDecoder(cfg)
    a = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    g, f = (0.01, -0.02, 0.03), (0.1, 0.2, -9.8)
    first = [_frame(a, 1_000_000 + 1000 * k, g, f) for k in range(3)]
    for d in first:  # the source is accepted, its time line and sequence known
        dec.feed_datagram(d, 1)
    block = ImuBlock()
    clean = [_frame(a, 1_003_000 + 1000 * k, g, f) for k in range(10)]
    got, taken = lane_feed(dec, clean, 2, block)
    assert taken == 10 and len(got) == 10
    # a read longer than the block: the lane stops when it is full
    long = [_frame(a, 1_013_000 + 1000 * k, g, f) for k in range(40)]
    buf, offs = _arrays(long)
    block.n = block.start = 0
    assert dec.feed_lane(buf, offs, 0, 40, 3, block) == len(block.t_us)
    # another instance, a frame lost, MAVLink 1: not the lane's
    t = int(block.t_us[-1])
    for bad in (_frame(a, t + 1000, g, f, imu_id=1),):
        buf, offs = _arrays([bad])
        block.n = 0
        assert dec.feed_lane(buf, offs, 0, 1, 4, block) == 0
    a.seq = (a.seq + 3) & 0xFF
    buf, offs = _arrays([_frame(a, t + 1000, g, f)])
    assert dec.feed_lane(buf, offs, 0, 1, 4, block) == 0


def _imu_stream(n: int, seed: int) -> list[Sample]:
    """A 1 kHz IMU stream with a fix every 100 ms, and some samples the block push must
    leave to the per-sample path (duplicates, disorder, a gap, absurd values)."""
    rng = random.Random(seed)
    out: list[Sample] = []
    t = 1_000_000
    for k in range(n):
        t += 1000
        dt = 1000
        r = rng.random()
        g = (rng.gauss(0, 1e-5), rng.gauss(0, 1e-5), rng.gauss(0, 1e-5))
        f = (rng.gauss(0, 1e-3), rng.gauss(0, 1e-3), -9.8e-3 + rng.gauss(0, 1e-3))
        if k > 3000 and r < 0.01:
            out.append(ImuSample(t - 1000, dt, *g, *f))  # duplicate
        elif k > 3000 and r < 0.02:
            out.append(ImuSample(t - 5000, dt, *g, *f))  # out of order
        elif k > 3000 and r < 0.025:
            g = (1.0, 0.0, 0.0)  # 1000 rad/s: absurd
        elif k > 3000 and r < 0.027:
            t += 200_000  # a gap
        out.append(ImuSample(t, dt, *g, *f))
        if k % 100 == 50:
            out.append(GnssSample(t - 20_000, 0.6, 1.9, 400.0, 0.0, 0.0, 0.0, 2.0, 3.0, 0.1))
    return out


@pytest.mark.parametrize("yaw_bank", [False, True])
def test_block_push_ends_in_the_state_per_sample_push_gives(yaw_bank: bool) -> None:
    cfg = EstimatorConfig()
    if yaw_bank:
        cfg = dataclasses.replace(cfg, yaw_bank=dataclasses.replace(cfg.yaw_bank,
                                                                    enabled="on"))
    one, blk = Estimator(cfg), Estimator(cfg)
    block = ImuBlock()
    stream = _imu_stream(8000, 3)
    rng = random.Random(4)
    i = 0
    pushed = 0
    stop = 0
    while i < len(stream):
        s = stream[i]
        if not isinstance(s, ImuSample):
            one.push(s)
            blk.push(s)
            i += 1
            continue
        run: list[ImuSample] = []
        while (i < len(stream) and isinstance(stream[i], ImuSample)
               and len(run) < rng.randint(1, 32)):
            run.append(stream[i])  # type: ignore[arg-type]
            i += 1
        for x in run:
            one.push(x)
        block.n = block.start = 0
        for k, x in enumerate(run):
            block.t_us[k], block.dt_us[k] = x.t_us, x.dt_us
            block.inc[k] = (x.dtheta_x, x.dtheta_y, x.dtheta_z, x.dvel_x, x.dvel_y, x.dvel_z)
        block.n = len(run)
        assert block.samples() == run
        while block.start < block.n:
            stop += rng.choice([0, 3000, 10_000])
            k = blk.push_imu_block(block, blk.t_us + stop % 7000, blk.t_us, 1_000_000,
                                   100_000)
            pushed += k
            if not k:
                blk.push(block.sample(block.start))
                block.start += 1
    assert pushed > 3000
    assert one.initialized and blk.initialized
    assert np.array_equal(one.buf, blk.buf)
    assert list(one.counters.items()) == list(blk.counters.items())
    assert (one.t_us, one.imu_dt_us, one.restarts) == (blk.t_us, blk.imu_dt_us, blk.restarts)
    assert np.array_equal(one.gyro_rest.acc, blk.gyro_rest.acc)
    if one.yaw_bank is not None:
        assert blk.yaw_bank is not None
        assert np.array_equal(one.yaw_bank.buf, blk.yaw_bank.buf)
