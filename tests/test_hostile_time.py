"""Hostile time stamps (issue 19 item 3): a single wild stamp (0, >= 2**63, backwards,
duplicate, hours ahead) is a counted rejection; only a sustained, consistent new clock
restarts navigation, and a real sensor reboot still gets output back within ~1 s."""

from __future__ import annotations

import asyncio
import dataclasses
import random

import can
import numpy as np
import pytest

from firmware_sim import SimRun
from firmware_sim.stream import timed_samples
from firmware_sim.transport.dronecan_tx import DronecanTx
from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.config.daemon import load_daemon_config
from navd.core.clock_guard import ClockGuard
from navd.daemon.daemon import Daemon
from navd.daemon.sinks import CallbackSink
from navd.io.dronecan import DronecanConfig, DronecanDecoder
from navd.io.mavlink import MavlinkDecoder
from navd.io.mavlink.decode import MavlinkInputConfig
from navd.types import GnssSample, ImuSample, NavSolution, Sample
from tests.daemon_util import car_run

RUN_S = 30.0
HOUR_US = 3_600_000_000


@pytest.fixture(scope="module")
def drive() -> SimRun:
    return car_run(RUN_S)


def _imu(t: int, dt: int = 10_000) -> ImuSample:
    return ImuSample(t, dt, 0.0, 0.0, 0.0, 0.0, 0.0, -0.098)


def _wild(rng: random.Random, t: int, last: int) -> int:
    """One of the storm's stamps for a sample due at sensor time ``t``."""
    kind = rng.randrange(5)
    return [0, 2**63 + rng.randrange(1000), max(1, t - rng.randrange(2_000_000, 60_000_000)),
            last, t + HOUR_US * rng.randrange(1, 5)][kind]


def test_single_wild_stamps_are_counted_not_obeyed() -> None:
    """GIVEN a 100 Hz IMU stream (host time advancing with it) with a wild stamp after every
    third sample (zero, >= 2**63, seconds back, duplicate, hours ahead),
    WHEN it goes through the clock guard,
    THEN every real sample passes at once, in order; every wild one is refused or passed only
    within the estimator's own tolerance (duplicate, < 1 s back); no new clock is taken."""
    g = ClockGuard()
    rng = random.Random(3)
    out: list[int] = []
    last = 0
    for k in range(1, 3001):
        t = k * 10_000
        got = g.push(_imu(t), t + 5_000_000)
        # the first clock too needs 10 samples over 0.2 s: held, then released whole
        assert (k < 21 and not got) or got[-1].t_us == t, k
        out += [s.t_us for s in got if s.t_us <= t]
        last = t
        if k % 3 == 0:
            w = _wild(rng, t, last)
            got = g.push(_imu(w), t + 5_000_500)
            assert not got or (got[0].t_us == w and last - 1_000_000 <= w <= last), (k, w)
    assert out == [k * 10_000 for k in range(1, 3001)]
    c = g.counters
    assert c["clock_new"] == 0, dict(c)
    assert c["clock_wild"] > 300, dict(c)
    assert g.t_us == 30_000_000


def test_a_new_clock_needs_ten_consistent_samples_over_200_ms() -> None:
    """GIVEN a clock at 100 s, then a sensor reboot (new clock from 10 ms, 100 Hz),
    WHEN the new clock's samples arrive,
    THEN nothing passes until 10 samples spanning 0.2 s (sensor and host time) are in; then
    all of them come out in order, with the fixes in between, and clock_new = 1."""
    g = ClockGuard()
    for k in range(1, 101):  # the first clock: confirmed after 0.2 s, released whole
        g.push(_imu(99_000_000 + k * 10_000), k * 10_000)
    assert g.t_us == 100_000_000 and g.counters["clock_new"] == 0
    host0 = 2_000_000
    released: list[Sample] = []
    fix = GnssSample(55_000, 0.6, 1.9, 400.0, 1.0, 0.0, 0.0, 2.0, 3.0, 0.1)
    for k in range(1, 40):
        if k == 6:
            assert g.push(fix, host0 + k * 10_000) == []
        got = g.push(_imu(k * 10_000), host0 + k * 10_000)
        if k < 21:
            assert got == [], k
        elif k == 21:
            released = got
        else:
            assert [s.t_us for s in got] == [k * 10_000]
    assert [s.t_us for s in released] == [10_000 * k for k in range(1, 6)] + [55_000] + [
        10_000 * k for k in range(6, 22)]
    assert g.counters["clock_new"] == 1 and g.t_us == 390_000


def test_a_burst_of_forged_consistent_stamps_is_not_a_new_clock() -> None:
    """GIVEN a live clock and, between two of its samples, a burst of 50 forged samples an
    hour ahead that are consistent with each other (0.5 s of sensor time in 1 ms of host
    time),
    WHEN the real clock goes on,
    THEN the burst never becomes the clock (host time did not pass) and is dropped."""
    g = ClockGuard()
    for k in range(1, 101):
        g.push(_imu(k * 10_000), k * 10_000)
    for j in range(50):
        assert g.push(_imu(1_000_000 + HOUR_US + j * 10_000), 1_000_000 + j * 20) == []
    assert [s.t_us for s in g.push(_imu(1_010_000), 1_010_000)] == [1_010_000]
    assert g.counters["clock_new"] == 0 and g.counters["clock_dropped"] == 50


def test_a_real_gap_confirmed_by_host_time_passes_at_once() -> None:
    """GIVEN a live clock, then 3 s of silence (host time passes too),
    WHEN the same clock resumes 3 s later,
    THEN its first sample passes at once (the estimator decides what a 3 s gap means)."""
    g = ClockGuard()
    for k in range(1, 101):
        g.push(_imu(k * 10_000), k * 10_000)
    assert [s.t_us for s in g.push(_imu(4_000_000), 4_000_000)] == [4_000_000]
    assert g.counters["clock_wild"] == 0


def _frames(run: SimRun, storm: bool) -> list[tuple[int, bytes]]:
    """(send time us, MAVLink frame) of ``run`` from sysid 1, with (``storm``) a hostile
    HIGHRES_IMU or GPS_INPUT from the same sysid after every second real one: zero, >= 2**63,
    seconds back, duplicate and hours-ahead stamps, plausible values."""
    tx = MavlinkTx(1, 1)
    rng = random.Random(19)
    out: list[tuple[int, bytes]] = []
    last = 0
    for k, (t, s) in enumerate(timed_samples(run)):
        if isinstance(s, ImuSample):
            out.append((t, tx.highres_imu(s)))
        elif isinstance(s, GnssSample):
            out.append((t, tx.gps_input(s)))
        if storm and k % 2 == 1 and t > 2_000_000:
            w = _wild(rng, s.t_us, last)
            fake = dataclasses.replace(s, t_us=min(w, 2**64 - 1))
            out.append((t + 100, tx.highres_imu(fake) if isinstance(fake, ImuSample)
                        else tx.gps_input(fake)))
        last = s.t_us
    return out


def _can_frames(run: SimRun, storm: bool) -> list[tuple[int, list[can.Message]]]:
    """As :func:`_frames`, over DroneCAN from node 42: RawIMU with integrals (increments
    carry their own interval, so no adapter time line stands between a stamp and the
    estimator) and Fix2."""
    tx = DronecanTx(42)
    rng = random.Random(19)
    out: list[tuple[int, list[can.Message]]] = []
    last = 0
    for k, (t, s) in enumerate(timed_samples(run)):
        if isinstance(s, ImuSample):
            out.append((t, tx.raw_imu(s)))
        elif isinstance(s, GnssSample):
            out.append((t, tx.fix2(s)))
        if storm and k % 2 == 1 and t > 2_000_000:
            # the wire's timestamp.usec has 56 bits: 2**63 cannot be sent, 2**55 can
            w = min(_wild(rng, s.t_us, last), 2**55)
            fake = dataclasses.replace(s, t_us=w)
            out.append((t + 100, tx.raw_imu(fake) if isinstance(fake, ImuSample)
                        else tx.fix2(fake)))
        last = s.t_us
    return out


def test_timestamp_storm_over_dronecan_integrals(drive: SimRun) -> None:
    """GIVEN the same storm over DroneCAN with integrated RawIMU (which passes the stamps to
    the estimator unchanged),
    WHEN it goes through the daemon's decoder and estimator task,
    THEN the clock guard counts the wild IMU stamps, navigation never restarts and outputs
    keep their 50 Hz."""
    _, clean, _ = _daemon_run(_can_frames(drive, storm=False))
    d, got, _ = _daemon_run(_can_frames(drive, storm=True))
    c = dict(d.clock_guard.counters)
    assert d.est.restarts == 0, (dict(d.est.counters), c)
    assert c.get("clock_wild", 0) > 100 and c.get("clock_new", 0) == 0, c
    t = np.array([s.t_us for s in got])
    assert np.diff(t).max() <= 100_000 and t[-1] >= clean[-1].t_us - 20_000
    assert len(got) >= len(clean) - 5


def _daemon_run(frames: list[tuple[int, bytes]] | list[tuple[int, list[can.Message]]]
                ) -> tuple[Daemon, list[NavSolution], dict[str, int]]:
    """The daemon's decoder and estimator task, in process: each frame decoded as a
    datagram (or a transfer's CAN frames), its samples queued with the send time as host
    receive time."""
    cfg = load_daemon_config(None, ["zenoh.enabled=false", "daemon.warm_up=false",
                                    f"daemon.queue_size={len(frames) * 2 + 16}"])
    d = Daemon(cfg, handle_signals=False)
    out: list[NavSolution] = []
    d.sinks = [CallbackSink(out.append, 50.0)]
    dec = MavlinkDecoder(MavlinkInputConfig(relock_s=5.0))
    can_dec = DronecanDecoder(DronecanConfig(interface="virtual", relock_s=5.0))

    async def go() -> None:
        for t, f in frames:
            if isinstance(f, bytes):
                samples = dec.feed_datagram(f, t)
            else:
                samples = [s for m in f for s in can_dec.feed(m, t)]
            for s in samples:
                d.queue.put(t * 1000 + 1, s)
        d.queue.close()
        await d._estimate()

    asyncio.run(go())
    return d, out, {**can_dec.counters.snapshot(), **dec.counters.snapshot()}


def test_timestamp_storm_does_not_reset_navigation(drive: SimRun) -> None:
    """GIVEN a 30 s drive over MAVLink with, from 2 s on, a hostile frame from the same sysid
    after every second real one (zero, >= 2**63, seconds back, duplicate and hours-ahead
    stamps on plausible IMU and GNSS values),
    WHEN it goes through the daemon's decoder and estimator task,
    THEN navigation never restarts, outputs keep their 50 Hz (no gap > 100 ms of sensor
    time after the first), and the attitude equals the clean run's to 0.5 deg."""
    _, clean, _ = _daemon_run(_frames(drive, storm=False))
    d, got, dec_counts = _daemon_run(_frames(drive, storm=True))
    assert d.est.restarts == 0, (dict(d.est.counters), dict(d.clock_guard.counters))
    t = np.array([s.t_us for s in got])
    assert np.diff(t).max() <= 100_000 and t[-1] >= clean[-1].t_us - 20_000
    # rate-type HIGHRES_IMU: the adapter's time line already drops a lone wild stamp
    assert dec_counts["imu_gap"] + dec_counts["imu_time_backwards"] > 300, dec_counts
    assert d.clock_guard.counters["clock_new"] == 0
    a = {s.t_us: (s.roll_rad, s.pitch_rad, s.yaw_rad) for s in clean}
    diff = [np.degrees(np.abs(np.subtract(a[s.t_us], (s.roll_rad, s.pitch_rad, s.yaw_rad))))
            for s in got if s.t_us in a]
    d_deg = np.array(diff)
    d_deg[:, 2] = np.minimum(d_deg[:, 2], 360.0 - d_deg[:, 2])
    assert len(diff) >= len(clean) - 5 and d_deg.max() < 0.5, d_deg.max(0)
    assert dec_counts["imu_time_out_of_range"] > 50  # >= 2**53 refused by the adapter


def test_reboot_in_the_daemon_still_restarts_once(drive: SimRun) -> None:
    """GIVEN the drive's frames, then the same frames again (a reboot: the clock restarts
    near 0; host time goes on),
    WHEN they go through the daemon in process,
    THEN navigation restarts exactly once and outputs resume within 1.1 s of the new
    clock."""
    frames = _frames(drive, storm=False)
    end = frames[-1][0] + 500_000
    d, got, _ = _daemon_run(frames + [(t + end, f) for t, f in frames])
    assert d.est.restarts == 1 and d.clock_guard.counters["clock_new"] == 1
    t = np.array([s.t_us for s in got])
    k = int(np.flatnonzero(np.diff(t) < 0)[0]) + 1
    assert t[k] < 1_100_000


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_the_guards_usual_case_shortcut_changes_nothing(seed: int) -> None:
    """ClockGuard.on_clock (the daemon's per-sample shortcut, issue 18) either does what
    push would for that sample, or nothing: a guard asked on_clock first and push only when
    it says False hands out the same samples and ends in the same state as one asked push
    alone, over stamps that jump, repeat, go back, leave the range and restart."""
    rng = random.Random(seed)
    plain, short = ClockGuard(), ClockGuard()
    t, host = 5_000_000, 1_000_000
    took = 0
    for _ in range(20_000):
        r = rng.random()
        host += rng.choice([1000, 1000, 1000, 0, 50_000, 3_000_000])
        if r < 0.90:
            t += 1000
            stamp = t
        elif r < 0.93:
            stamp = t  # repeated
        elif r < 0.95:
            stamp = t - rng.randint(1, 2_000_000)  # back, small or large
        elif r < 0.97:
            stamp = t + rng.randint(100_001, 10_000_000)  # a wild jump ahead
        elif r < 0.98:
            stamp = rng.choice([0, -5, 1 << 53, 1 << 60])  # out of range
        elif r < 0.99:
            t = rng.randint(1, 1_000_000)  # a new clock that goes on
            stamp = t
        else:
            s = GnssSample(t - 20_000, 0.8, 0.1, 100.0, 1.0, 0.0, 0.0, 1.0, 2.0, 0.1)
            assert plain.push(s, host) == short.push(s, host)
            continue
        h = host if rng.random() < 0.9 else None
        imu = ImuSample(stamp, 1000, 0.0, 0.0, 0.0, 0.0, 0.0, -0.0098)
        want = plain.push(imu, h)
        if short.on_clock(stamp, h):
            took += 1
            got: list[Sample] = [imu]
        else:
            got = short.push(imu, h)
        assert got == want
        assert (short.t_us, short._host_at_t, short.pending, dict(short.counters),
                short.last_change) == (plain.t_us, plain._host_at_t, plain.pending,
                                       dict(plain.counters), plain.last_change)
    assert 1_000 < took < 20_000  # both ways taken, often
    assert plain.counters["clock_wild"] and plain.counters["clock_out_of_range"]
