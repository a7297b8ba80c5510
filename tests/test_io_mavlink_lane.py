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
import math
import random
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from navd.config import EstimatorConfig
from navd.core.estimator import Estimator
from navd.core.imu_block import ImuBlock
from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig, MavlinkUdpProtocol
from navd.io.mavlink.link import RxBatch
from navd.io.read_pacing import ReadPacer
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


@pytest.mark.parametrize(("yaw_bank", "mount"), [(False, False), (True, False), (False, True)])
def test_block_push_ends_in_the_state_per_sample_push_gives(yaw_bank: bool, mount: bool
                                                            ) -> None:
    cfg = EstimatorConfig()
    if yaw_bank:
        cfg = dataclasses.replace(cfg, yaw_bank=dataclasses.replace(cfg.yaw_bank,
                                                                    enabled="on"))
    if mount:  # an IMU turned on the vehicle: both paths turn its increments alike
        cfg = dataclasses.replace(cfg, imu=dataclasses.replace(
            cfg.imu, mount_roll=math.radians(10.0), mount_pitch=math.radians(-20.0),
            mount_yaw=math.radians(135.0)))
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


def _protocol(clock: list[int]) -> tuple[MavlinkUdpProtocol, list[Sample]]:
    """A UDP protocol (decoder with source lock, read pacer) whose samples, blocks
    expanded, land in the list returned; its clock reads ``clock[0]``."""
    dec = MavlinkDecoder(MavlinkInputConfig(nominal_imu_rate_hz=1000.0, relock_s=0.5))
    out: list[Sample] = []
    proto = MavlinkUdpProtocol(dec, out.append, lambda: clock[0])
    proto.pacer = ReadPacer([20_000, 100_000])

    def on_block(b: ImuBlock) -> None:
        out.extend(b.samples())
        b.release()

    proto.on_block = on_block
    return proto, out


def _pacer_state(p: ReadPacer) -> tuple[object, ...]:
    return tuple(getattr(p, k) for k in ReadPacer.__slots__)


@pytest.mark.parametrize("seed", [1, 2])
def test_batch_received_is_datagram_received_of_each(seed: int) -> None:
    """Reads of the hostile stream, with junk floods (muting) from another address and
    from the sender's own, and datagrams of another sender mixed in: ``batch_received``
    must leave the protocol as ``datagram_received`` of each datagram at the read's time
    does (samples, counters, useful addresses, mutings, last peer, read pacing; only the
    read's last datagram an edge of the pacer's rate window)."""
    rng = random.Random(seed)
    clock = [0]
    lane, lane_out = _protocol(clock)
    one, one_out = _protocol(clock)
    assert lane.decoder is not None and one.decoder is not None
    me, other = ("127.0.0.1", 14550), ("10.0.0.9", 5000)
    batch = RxBatch()
    blocks_used = 0
    for now, datagrams in _reads(seed):
        read = [(d, me) for d in datagrams]
        r = rng.random() if len(read) < 32 else 1.0  # a read holds at most 32
        if r < 0.05:  # junk, enough to mute its sender
            read.insert(rng.randrange(len(read) + 1), (rng.randbytes(5000), other))
        elif r < 0.08:
            read.insert(rng.randrange(len(read) + 1), (rng.randbytes(300), me))
        elif r < 0.1:
            read.insert(rng.randrange(len(read) + 1), (datagrams[0], other))
        clock[0] = now
        if rng.random() < 0.03:  # the pool is empty: the per-datagram path
            free = lane._free_blocks[:]
            lane._free_blocks.clear()
            lane.batch_received(batch.fill(read))
            lane._free_blocks.extend(free)
        else:
            n0 = len(lane_out)
            lane.batch_received(batch.fill(read))
            blocks_used += len(lane_out) > n0
        for j, (d, addr) in enumerate(read):
            # a read's samples share its last datagram's arrival: only that one may bound
            # the read pacer's rate window (ReadPacer.note's edge)
            one._datagram(d, addr, one.clock_us(), j == len(read) - 1)
        assert lane_out == one_out
    assert len(lane._free_blocks) == len(ImuBlock.pool(8))
    assert blocks_used > 100
    assert list(lane.counters.snapshot().items()) == list(one.counters.snapshot().items())
    assert "peer_muted" in lane.counters
    for attr in ("_useful", "_junk", "_junk_hosts", "_junk_all", "_muted", "_muted_hosts",
                 "_muted_all", "last_peer"):
        assert getattr(lane, attr) == getattr(one, attr), attr
    assert lane.pacer is not None and one.pacer is not None
    assert _pacer_state(lane.pacer) == _pacer_state(one.pacer)
    assert lane.decoder.source_lock is not None and one.decoder.source_lock is not None
    assert lane.decoder.source_lock.status() == one.decoder.source_lock.status()


def test_a_queue_dropping_a_block_returns_it_to_its_pool() -> None:
    import logging

    from navd.daemon.sources import SampleQueue
    from navd.diag import RateLimitedLog

    q = SampleQueue(16, RateLimitedLog(logging.getLogger("test"), 5.0))
    free = ImuBlock.pool(2)
    b = free.pop()
    b.n = 5
    q.put(1, b)
    for k in range(16):
        q.put(2, ImuSample(k + 1, 1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    assert q.drops == 5 and len(free) == 2 and b.n == 0


def _daemon_outputs(items: list[tuple[int, Sample | ImuBlock]]
                    ) -> tuple[bytes, list[object], int]:
    """The estimator task of a daemon (a 50 Hz capturing sink) fed ``items``: its final
    state buffer, the solutions it published and how many samples it pushed in blocks."""
    import asyncio

    from navd.config.daemon import load_daemon_config
    from navd.daemon.daemon import Daemon
    from navd.daemon.sinks import CallbackSink

    captured: list[object] = []
    d = Daemon(load_daemon_config(None, []), handle_signals=False,
               extra_sinks=[CallbackSink(captured.append, 50.0, "capture")])
    d.sinks = list(d._extra)
    block_push = d.est.push_imu_block
    in_blocks = [0]

    def counted(*args: Any) -> int:
        k = block_push(*args)
        in_blocks[0] += k
        return k

    d.est.push_imu_block = counted  # type: ignore[method-assign]

    async def run() -> None:
        task = asyncio.get_running_loop().create_task(d._estimate())
        for recv_ns, s in items:
            d.queue.put(recv_ns, s)
            await asyncio.sleep(0)
        d.queue.close()
        await task

    asyncio.run(run())
    return d.est.buf.tobytes(), captured, in_blocks[0]


def test_the_estimator_task_outputs_the_same_from_blocks() -> None:
    """The daemon's estimator task fed a car run's samples one by one, and fed its IMU
    samples in blocks of 1..32 (some with a stamp off the clock, which the guard holds):
    the same state and the same published solutions, at the same samples."""
    from tests.daemon_util import car_run

    run = car_run(30.0)
    samples = list(run.samples())
    rng = random.Random(7)
    free = ImuBlock.pool(4096 // 2)
    one: list[tuple[int, Sample | ImuBlock]] = []
    blocks: list[tuple[int, Sample | ImuBlock]] = []
    i = 0
    while i < len(samples):
        s = samples[i]
        recv_ns = 10**12 + s.t_us * 1000
        if not isinstance(s, ImuSample):
            one.append((recv_ns, s))
            blocks.append((recv_ns, s))
            i += 1
            continue
        b = free.pop()
        take = rng.randint(1, 32)
        while i < len(samples) and isinstance(samples[i], ImuSample) and b.n < take:
            x = samples[i]
            assert isinstance(x, ImuSample)
            if rng.random() < 0.002:  # a wild stamp: the clock guard's, not the block run's
                x = dataclasses.replace(x, t_us=x.t_us + 50_000_000)
            b.t_us[b.n], b.dt_us[b.n] = x.t_us, x.dt_us
            b.inc[b.n] = (x.dtheta_x, x.dtheta_y, x.dtheta_z, x.dvel_x, x.dvel_y, x.dvel_z)
            b.n += 1
            one.append((recv_ns, x))
            i += 1
        blocks.append((recv_ns, b))
    state_one, out_one, _ = _daemon_outputs(one)
    state_blk, out_blk, in_blocks = _daemon_outputs(blocks)
    assert len(out_one) > 1000 and in_blocks > 0.9 * sum(isinstance(s, ImuSample)
                                                         for _, s in one)
    assert out_blk == out_one
    assert state_blk == state_one
