"""DroneCAN adapter: simulator frames -> python-can virtual bus -> reassembly -> navd types."""

from __future__ import annotations

import asyncio
import functools
import itertools
import math
import os
import uuid
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import can
import dronecan
import pytest
from dronecan import transport
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.transport.dronecan_tx import DronecanTx
from navd.core.sun import utc_to_gps_s
from navd.io.common import Sample
from navd.io.dronecan import (
    POL_DTID,
    POL_SIGNATURE,
    DronecanConfig,
    DronecanDecoder,
    DronecanEncoder,
    DronecanLink,
    RawImuFields,
    open_bus,
    transfer_messages,
)
from navd.types import FixType, GnssSample, ImuSample, NavSolution, PolSample

ECEF = (4_331_300.125, 567_537.25, 4_633_133.5)


def virtual_cfg(**kw: object) -> DronecanConfig:
    base: dict[str, object] = {"interface": "virtual", "channel": f"t-{uuid.uuid4().hex}"}
    base.update(kw)
    return DronecanConfig(**base)  # type: ignore[arg-type]


def imu(t_us: int = 3_000_000, dt_us: int = 2500) -> ImuSample:
    dt = dt_us * 1e-6
    return ImuSample(t_us, dt_us, 0.3 * dt, -0.2 * dt, 0.05 * dt, 1.2 * dt, -0.4 * dt, -9.79 * dt)


def fix(**kw: object) -> GnssSample:
    base: dict[str, object] = dict(
        t_us=4_000_000, lat_rad=math.radians(47.3977123), lon_rad=math.radians(8.5456789),
        alt_m=488.123, vel_n=3.0, vel_e=-4.0, vel_d=0.25, h_acc_m=0.75, v_acc_m=1.5,
        vel_acc_mps=0.125, fix_type=FixType.RTK_FLOAT,
        pos_ecef_m=ECEF, vel_ecef_mps=(1.0, -2.0, 3.5),
    )
    base.update(kw)
    return GnssSample(**base)  # type: ignore[arg-type]


def feed(dec: DronecanDecoder, msgs: Iterable[can.Message], t_us: int = 0) -> list[Sample]:
    out: list[Sample] = []
    for m in msgs:
        out += dec.feed(m, t_us)
    return out


def through_bus(msgs: list[can.Message]) -> list[can.Message]:
    """Send on one virtual bus, receive on another on the same channel."""
    ch = f"t-{uuid.uuid4().hex}"
    tx = can.Bus(interface="virtual", channel=ch)
    rx = can.Bus(interface="virtual", channel=ch)
    try:
        for m in msgs:
            tx.send(m)
        got = []
        for _ in msgs:
            r = rx.recv(timeout=1.0)
            assert r is not None
            got.append(r)
        return got
    finally:
        tx.shutdown()
        rx.shutdown()


def test_raw_imu_integrated_round_trip_over_virtual_bus() -> None:
    """GIVEN an IMU sample encoded by the simulator as integrated RawIMU frames (extended IDs),
    WHEN they pass through a python-can virtual bus and the decoder,
    THEN exactly one ImuSample comes out with the same times and deltas (rel 1e-6)."""
    s = imu()
    frames = DronecanTx(node_id=21).raw_imu(s)
    assert len(frames) > 1 and all(m.is_extended_id for m in frames)
    (got,) = feed(DronecanDecoder(virtual_cfg()), through_bus(frames))
    assert isinstance(got, ImuSample)
    assert (got.t_us, got.dt_us) == (s.t_us, s.dt_us)
    for name in ("dtheta_x", "dtheta_y", "dtheta_z", "dvel_x", "dvel_y", "dvel_z"):
        assert getattr(got, name) == pytest.approx(getattr(s, name), rel=1e-6), name


def test_raw_imu_point_samples_use_timestamps_and_float16() -> None:
    """GIVEN four IMU samples 2.5 ms apart sent as point (non-integrated) RawIMU,
    WHEN the decoder reads them,
    THEN the first only primes the decoder (counted) and the other three come out
    with their timestamps, dt 2500 us and float16 rates accurate to ~1e-3."""
    tx, dec = DronecanTx(node_id=21), DronecanDecoder(virtual_cfg())
    samples = [imu(t_us=3_000_000 + 2500 * i) for i in range(4)]
    out = feed(dec, (m for s in samples for m in tx.raw_imu(s, integrated=False)))
    assert [s.t_us for s in out] == [s.t_us for s in samples[1:]]
    assert dec.counters["imu_first_sample"] == 1
    for got, want in zip(out, samples[1:], strict=True):
        assert isinstance(got, ImuSample) and got.dt_us == 2500
        # float16 rates: ~1e-3 relative
        assert got.dvel_z == pytest.approx(want.dvel_z, rel=1e-3)
        assert got.dtheta_x == pytest.approx(want.dtheta_x, rel=1e-3)


@pytest.mark.parametrize("with_ecef", [False, True])
def test_fix2_round_trip(with_ecef: bool) -> None:
    """GIVEN an RTK-float fix sent as Fix2, with and without the ECEF fields,
    WHEN it passes through a virtual bus and the decoder,
    THEN time, fix type, position (ellipsoid height), velocity and accuracies survive,
    and ECEF position/velocity are present exactly when they were sent."""
    g = fix()
    frames = DronecanTx(node_id=30).fix2(g, with_ecef=with_ecef, geoid_sep_m=47.0)
    (got,) = feed(DronecanDecoder(virtual_cfg()), through_bus(frames))
    assert isinstance(got, GnssSample)
    assert got.t_us == g.t_us and got.fix_type == FixType.RTK_FLOAT
    assert got.lat_rad == pytest.approx(g.lat_rad, abs=1e-8 * math.pi / 180)
    assert got.lon_rad == pytest.approx(g.lon_rad, abs=1e-8 * math.pi / 180)
    assert got.alt_m == pytest.approx(g.alt_m, abs=1e-3)  # ellipsoid, not MSL
    assert (got.vel_n, got.vel_e, got.vel_d) == pytest.approx((3.0, -4.0, 0.25))
    # float16 variances: sigma to ~1e-3 relative
    assert got.h_acc_m == pytest.approx(0.75, rel=1e-3)
    assert got.v_acc_m == pytest.approx(1.5, rel=1e-3)
    assert got.vel_acc_mps == pytest.approx(0.125, rel=1e-3)
    if with_ecef:
        assert got.pos_ecef_m == pytest.approx(ECEF, abs=1e-3)
        assert got.vel_ecef_mps == pytest.approx((1.0, -2.0, 3.5))
    else:
        assert got.pos_ecef_m is None and got.vel_ecef_mps is None


def test_fix2_covariance_forms() -> None:
    """GIVEN Fix2 messages with a full 6x6, an empty, and a NaN-horizontal covariance,
    WHEN they are decoded with configured default accuracies,
    THEN sigmas come from the covariance and defaults fill the missing parts;
    a covariance that saturates float16 drops the fix and counts it."""
    tx = DronecanTx(node_id=30)
    full = [0.0] * 36
    for i, v in enumerate((4.0, 4.0, 9.0, 0.04, 0.04, 0.04)):
        full[7 * i] = v
    cfg = virtual_cfg(default_h_acc_m=11.0, default_v_acc_m=22.0, default_vel_acc_mps=0.33)
    cases = [
        (full, (2.0, 3.0, 0.2)),
        ([], (11.0, 22.0, 0.33)),
        ([math.nan, math.nan, 9.0, 0.04, 0.04, 0.04], (11.0, 3.0, 0.2)),
    ]
    for cov, want in cases:
        dec = DronecanDecoder(cfg)
        (got,) = feed(dec, tx.fix2(fix(), covariance=cov))
        assert isinstance(got, GnssSample)
        assert (got.h_acc_m, got.v_acc_m, got.vel_acc_mps) == pytest.approx(want, rel=1e-3)
    dec = DronecanDecoder(cfg)
    assert feed(dec, tx.fix2(fix(), covariance=[1e6, 1e6, 1.0, 1.0, 1.0, 1.0])) == []
    assert dec.counters["gnss_accuracy_saturated"] == 1  # float16 -> inf


def test_fix2_rejections() -> None:
    """GIVEN Fix2 messages with a 2D fix, no timestamp, or a NaN velocity,
    WHEN they are decoded,
    THEN each is dropped and counted under its own reason; with use_receive_time
    a fix without timestamp is kept and stamped with the receive time."""
    tx = DronecanTx(node_id=30)
    dec = DronecanDecoder(virtual_cfg())
    assert feed(dec, tx.fix2(fix(fix_type=FixType.FIX_2D))) == []
    assert dec.counters["gnss_no_fix"] == 1
    assert feed(dec, tx.fix2(fix(t_us=0))) == []
    assert dec.counters["gnss_no_timestamp"] == 1
    assert feed(dec, tx.fix2(fix(vel_n=math.nan))) == []
    assert dec.counters["gnss_nonfinite"] == 1
    dec = DronecanDecoder(virtual_cfg(use_receive_time=True))
    (got,) = feed(dec, tx.fix2(fix(t_us=0)), t_us=777)
    assert got.t_us == 777


def test_raw_imu_absurd_and_nan_rejected() -> None:
    """GIVEN RawIMU samples with a 60 g accel, an absurd gyro delta, or a NaN,
    WHEN they are decoded,
    THEN none is emitted and each counter (absurd accel, absurd gyro, nonfinite) is 1."""
    tx, dec = DronecanTx(node_id=21), DronecanDecoder(virtual_cfg())
    dt = 0.0025
    assert feed(dec, tx.raw_imu(ImuSample(10, 2500, 0, 0, 0, 0, 0, -60 * 9.81 * dt))) == []
    assert feed(dec, tx.raw_imu(ImuSample(20, 2500, 40 * dt, 0, 0, 0, 0, 0))) == []
    assert feed(dec, tx.raw_imu(ImuSample(30, 2500, math.nan, 0, 0, 0, 0, 0))) == []
    c = dec.counters
    assert (c["imu_absurd_accel"], c["imu_absurd_gyro"], c["imu_nonfinite"]) == (1, 1, 1)


def test_interleaved_transfers_from_two_nodes_and_two_types() -> None:
    """GIVEN RawIMU and Fix2 transfers from two nodes, their frames interleaved on one bus,
    WHEN the decoder reassembles them,
    THEN all four samples come out."""
    a, b = DronecanTx(node_id=10), DronecanTx(node_id=11)
    streams = [a.raw_imu(imu(t_us=100)), b.raw_imu(imu(t_us=200)), a.fix2(fix(t_us=300)),
               b.fix2(fix(t_us=400), with_ecef=True)]
    mixed = [m for group in itertools.zip_longest(*streams) for m in group if m is not None]
    out = feed(DronecanDecoder(virtual_cfg()), through_bus(mixed))
    assert sorted(s.t_us for s in out) == [100, 200, 300, 400]


def _mangle_tail(m: can.Message, tail: int) -> can.Message:
    data = bytearray(m.data)
    data[-1] = tail
    return can.Message(arbitration_id=m.arbitration_id, data=bytes(data), is_extended_id=True)


def test_bad_tail_bytes() -> None:
    """GIVEN a multi-frame RawIMU transfer with a corrupted tail byte: toggle set on the
    start frame, a transfer ID change mid-transfer, or no end-of-transfer flag,
    WHEN it is decoded,
    THEN nothing is emitted and the matching counter rises; the unfinished transfer
    stays pending until evict_stale removes and counts it."""
    frames = DronecanTx(node_id=21).raw_imu(imu())
    first_tail = frames[0].data[-1]
    # Start frame with toggle set: the transfer never starts; the rest are orphans.
    dec = DronecanDecoder(virtual_cfg())
    assert feed(dec, [_mangle_tail(frames[0], first_tail | 0x20), *frames[1:]]) == []
    assert dec.counters["bad_toggle"] == 1
    assert dec.counters["orphan_frame"] == len(frames) - 1
    # Transfer ID changes mid-transfer.
    dec = DronecanDecoder(virtual_cfg())
    t2 = frames[2].data[-1]
    bad = [*frames[:2], _mangle_tail(frames[2], (t2 & 0xE0) | ((t2 + 1) & 0x1F)), *frames[3:]]
    assert feed(dec, bad) == []
    assert dec.counters["bad_transfer_id"] == 1
    # End-of-transfer flag missing on the last frame: never completes, evicted later.
    dec = DronecanDecoder(virtual_cfg())
    assert feed(dec, [*frames[:-1], _mangle_tail(frames[-1], frames[-1].data[-1] & ~0x40)]) == []
    assert dec.pending == 1
    assert dec.evict_stale(10**9) == 1 and dec.counters["stale_transfer"] == 1


def test_bad_crc() -> None:
    """GIVEN a RawIMU transfer with one payload bit flipped in a middle frame,
    WHEN it is decoded,
    THEN nothing is emitted and bad_crc is counted once."""
    frames = DronecanTx(node_id=21).raw_imu(imu())
    data = bytearray(frames[3].data)
    data[2] ^= 0x10
    frames[3] = can.Message(arbitration_id=frames[3].arbitration_id, data=bytes(data),
                            is_extended_id=True)
    dec = DronecanDecoder(virtual_cfg())
    assert feed(dec, frames) == []
    assert dec.counters["bad_crc"] == 1


def test_dropped_middle_frames() -> None:
    """GIVEN a RawIMU transfer missing one middle frame, then one missing two,
    WHEN each is decoded,
    THEN nothing is emitted (toggle error, resp. CRC error counted),
    and the next intact transfer from the same node decodes."""
    frames = DronecanTx(node_id=21).raw_imu(imu())
    dec = DronecanDecoder(virtual_cfg())
    assert feed(dec, frames[:3] + frames[4:]) == []  # one lost: toggle breaks
    assert dec.counters["bad_toggle"] >= 1
    assert dec.counters.total(["bad_crc", "stale_transfer"]) + dec.pending >= 1
    dec = DronecanDecoder(virtual_cfg())
    assert feed(dec, frames[:2] + frames[4:]) == []  # two lost: toggle fine, CRC not
    assert dec.counters["bad_crc"] == 1
    # The next intact transfer from the same node decodes.
    assert len(feed(dec, DronecanTx(node_id=21).raw_imu(imu()))) == 1


def test_duplicated_frame_is_ignored_not_fatal() -> None:
    """GIVEN a RawIMU transfer in which one frame arrives twice,
    WHEN it is decoded,
    THEN the sample is still emitted once and the duplicate counts as one bad toggle."""
    frames = DronecanTx(node_id=21).raw_imu(imu())
    dec = DronecanDecoder(virtual_cfg())
    out = feed(dec, [*frames[:3], frames[2], *frames[3:]])
    assert len(out) == 1 and dec.counters["bad_toggle"] == 1


def test_transfer_received_twice_is_not_integrated_twice() -> None:
    """GIVEN every RawIMU and Fix2 transfer delivered twice (redundant CAN interfaces),
    WHEN they are decoded,
    THEN one ImuSample and one GnssSample come out and each repeat is counted."""
    # Redundant CAN interfaces deliver every transfer twice.
    tx = DronecanTx(node_id=21)
    imu_frames, fix_frames = tx.raw_imu(imu()), tx.fix2(fix())
    dec = DronecanDecoder(virtual_cfg())
    out = feed(dec, [*imu_frames, *imu_frames, *fix_frames, *fix_frames])
    assert [type(s) for s in out] == [ImuSample, GnssSample]
    assert dec.counters["imu_duplicate_time"] == 1 and dec.counters["gnss_repeat"] == 1


def test_stale_partial_transfer_is_evicted_on_next_frame() -> None:
    """GIVEN a partial RawIMU transfer left pending, with a 0.1 s transfer timeout,
    WHEN a Fix2 transfer arrives 0.2 s after the partial one began,
    THEN the fix decodes, the partial transfer is evicted and counted as stale."""
    tx = DronecanTx(node_id=21)
    first = tx.raw_imu(imu())
    dec = DronecanDecoder(virtual_cfg(transfer_timeout_s=0.1))
    assert feed(dec, first[:3], t_us=1_000_000) == [] and dec.pending == 1
    assert feed(dec, first[3:4], t_us=1_050_000) == [] and dec.pending == 1
    out = feed(dec, tx.fix2(fix()), t_us=1_200_000)  # another session, later
    assert len(out) == 1 and dec.pending == 0
    assert dec.counters["stale_transfer"] == 1


def test_other_frames_are_ignored_and_counted() -> None:
    """GIVEN a NodeStatus, a service frame, an anonymous frame, a standard-ID frame
    and an empty frame,
    WHEN they are decoded,
    THEN nothing is emitted and each is counted once under its own reason."""
    dec = DronecanDecoder(virtual_cfg())
    node_status = can.Message(arbitration_id=(16 << 24) | (341 << 8) | 21,
                              data=b"\x00" * 7 + b"\xc0", is_extended_id=True)
    service = can.Message(arbitration_id=(16 << 24) | 0x80 | 21, data=b"\xc0", is_extended_id=True)
    anon = can.Message(arbitration_id=(16 << 24) | (1003 << 8), data=b"\xc0", is_extended_id=True)
    std = can.Message(arbitration_id=0x123, data=b"\xc0", is_extended_id=False)
    empty = can.Message(arbitration_id=(16 << 24) | (1003 << 8) | 21, data=b"", is_extended_id=True)
    assert feed(dec, [node_status, service, anon, std, empty]) == []
    c = dec.counters
    assert (c["ignored"], c["service_ignored"], c["anonymous_ignored"], c["not_extended"],
            c["bad_frame_len"]) == (1, 1, 1, 1, 1)


def test_allow_nodes() -> None:
    """GIVEN a decoder that allows only node 5,
    WHEN Fix2 arrives from node 6 and then from node 5,
    THEN node 6 is dropped and counted as not allowed, node 5 decodes."""
    dec = DronecanDecoder(virtual_cfg(allow_nodes=frozenset({5})))
    assert feed(dec, DronecanTx(node_id=6).fix2(fix())) == []
    assert dec.counters["not_allowed"] >= 1
    assert len(feed(dec, DronecanTx(node_id=5).fix2(fix()))) == 1


def test_encode_solution_quaternion_order_and_tail_bytes() -> None:
    """GIVEN a NavSolution with a known quaternion, rates and attitude sigmas,
    WHEN the encoder turns it into ahrs.Solution frames,
    THEN they carry DTID 1000 and node 77, pass the dronecan CRC, hold the quaternion
    as x, y, z, w with matching rates and variances, and the transfer ID wraps mod 32."""
    sol = NavSolution(
        t_us=55, quat_nb=(0.5, -0.5, 0.5, 0.5), roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0,
        lat_rad=0.0, lon_rad=0.0, alt_m=0.0, vel_n=(0.0, 0.0, 0.0), att_sd_rad=(0.01, 0.02, 0.1),
        gyro_bias_rps=(0.0, 0.0, 0.0), accel_bias_mps2=(0.0, 0.0, 0.0), heading_aligned=True,
        rate_b=(0.1, 0.2, 0.3),
    )
    enc = DronecanEncoder(node_id=77)
    msgs = enc.encode_solution(sol)
    assert all(m.is_extended_id and (m.arbitration_id >> 8) & 0xFFFF == 1000 for m in msgs)
    assert all(m.arbitration_id & 0x7F == 77 for m in msgs)
    t = transport.Transfer()
    t.from_frames([transport.Frame(m.arbitration_id, m.data) for m in msgs])  # checks CRC
    p = t.payload
    assert p.timestamp.usec == 55
    assert list(p.orientation_xyzw) == pytest.approx([-0.5, 0.5, 0.5, 0.5])  # x, y, z, w
    assert list(p.angular_velocity) == pytest.approx([0.1, 0.2, 0.3], rel=1e-3)
    cov = list(p.orientation_covariance)
    assert (cov[0], cov[4], cov[8]) == pytest.approx((1e-4, 4e-4, 1e-2), rel=2e-3)
    tids = [enc.encode_solution(sol)[-1].data[-1] & 0x1F for _ in range(40)]
    assert tids[:3] == [1, 2, 3] and max(tids) == 31 and 0 in tids  # mod-32 counter


_FUZZ = settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
_DTIDS = st.sampled_from([1003, 1063, 1000, 341])


@_FUZZ
@given(st.lists(st.tuples(_DTIDS, st.integers(0, 127), st.binary(max_size=8), st.booleans()),
                max_size=40))
def test_random_frames_never_raise(frames: list[tuple[int, int, bytes, bool]]) -> None:
    """GIVEN random frames (any known DTID, node, payload, extended or not),
    WHEN they are fed to the decoder,
    THEN it never raises and yields only ImuSample or GnssSample."""
    dec = DronecanDecoder(virtual_cfg())
    for i, (dtid, node, data, ext) in enumerate(frames):
        cid = (16 << 24) | (dtid << 8) | node if ext else node
        for s in dec.feed(can.Message(arbitration_id=cid, data=data, is_extended_id=ext), i):
            assert isinstance(s, ImuSample | GnssSample)


@_FUZZ
@given(st.integers(0, 200), st.integers(1, 255), st.booleans())
def test_corrupted_transfer_never_yields_a_wrong_sample(pos: int, xor: int, gnss: bool) -> None:
    """GIVEN a RawIMU or Fix2 transfer with one byte XOR-corrupted anywhere,
    WHEN it is decoded,
    THEN the output is either nothing or exactly the clean transfer's samples."""
    tx = DronecanTx(node_id=9)
    frames = tx.fix2(fix(), with_ecef=True) if gnss else tx.raw_imu(imu())
    clean = feed(DronecanDecoder(virtual_cfg()), frames)
    flat = [(i, j) for i, m in enumerate(frames) for j in range(len(m.data))]
    i, j = flat[pos % len(flat)]
    data = bytearray(frames[i].data)
    data[j] ^= xor
    frames = list(frames)
    frames[i] = can.Message(arbitration_id=frames[i].arbitration_id, data=bytes(data),
                            is_extended_id=True)
    out = feed(DronecanDecoder(virtual_cfg()), frames)
    assert out in ([], clean)


def test_link_delivers_on_the_event_loop() -> None:
    """GIVEN an open DronecanLink and a simulator bus on the same virtual channel,
    WHEN the simulator sends RawIMU and Fix2 and the link sends Solution frames,
    THEN the IMU and GNSS samples reach the callback on the event loop thread,
    and the simulator receives the Solution frames byte for byte."""
    async def main() -> None:
        cfg = virtual_cfg()
        got: list[Sample] = []
        loop_thread: list[bool] = []
        loop = asyncio.get_running_loop()

        def on_sample(s: Sample) -> None:
            loop_thread.append(asyncio.get_running_loop() is loop)
            got.append(s)

        link = await DronecanLink.open(cfg, on_sample=on_sample)
        sim_bus = open_bus(cfg, dtids=(1000,))  # sees only Solution frames
        try:
            tx = DronecanTx(node_id=12)
            for m in [*tx.raw_imu(imu()), *tx.fix2(fix(), with_ecef=True)]:
                sim_bus.send(m)
            async with asyncio.timeout(3):
                while len(got) < 2:
                    await asyncio.sleep(0.005)
            assert [type(s) for s in got] == [ImuSample, GnssSample] and all(loop_thread)
            sol_frames = DronecanEncoder(node_id=100).encode_solution(
                NavSolution(1, (1.0, 0.0, 0.0, 0.0), 0, 0, 0, 0, 0, 0, (0, 0, 0), (0, 0, 0),
                            (0, 0, 0), (0, 0, 0), True, (0, 0, 0)))
            assert link.send(sol_frames)
            rx = [sim_bus.recv(timeout=1.0) for _ in sol_frames]
            want = [bytes(m.data) for m in sol_frames]
            assert [bytes(m.data) for m in rx if m is not None] == want
        finally:
            link.close()
            sim_bus.shutdown()

    asyncio.run(main())


@pytest.mark.skipif(not os.path.exists("/sys/class/net/vcan0"), reason="no vcan0 interface")
def test_socketcan_vcan0_round_trip() -> None:
    """GIVEN a vcan0 interface (skipped otherwise),
    WHEN a RawIMU transfer is sent over SocketCAN and decoded,
    THEN exactly one sample with the sent timestamp comes out."""
    cfg = DronecanConfig(interface="socketcan", channel="vcan0")
    rx = open_bus(cfg)
    tx = can.Bus(interface="socketcan", channel="vcan0")
    try:
        frames = DronecanTx(node_id=33).raw_imu(imu())
        for m in frames:
            tx.send(m)
        dec = DronecanDecoder(cfg)
        out: list[Sample] = []
        for _ in frames:
            m = rx.recv(timeout=1.0)
            assert m is not None
            out += dec.feed(m, 0)
        assert len(out) == 1 and out[0].t_us == imu().t_us
    finally:
        rx.shutdown()
        tx.shutdown()


def test_dsdl_ids_match_the_spec() -> None:
    """GIVEN the dronecan package's DSDL definitions,
    WHEN the default DTIDs of RawIMU, Fix2 and Solution are read,
    THEN they are 1003, 1063 and 1000."""
    assert dronecan.uavcan.equipment.ahrs.RawIMU.default_dtid == 1003
    assert dronecan.uavcan.equipment.gnss.Fix2.default_dtid == 1063
    assert dronecan.uavcan.equipment.ahrs.Solution.default_dtid == 1000


_f32 = st.floats(-1048576.0, 1048576.0, width=32, allow_subnormal=False)
_f16 = st.floats(-32768.0, 32768.0, width=16, allow_subnormal=False)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(usec=st.integers(1, 2**56 - 1),
       interval=st.floats(0.0009765625, 1.0, width=32, allow_subnormal=False),
       g_latest=st.lists(_f16, min_size=3, max_size=3),
       g_int=st.lists(_f32, min_size=3, max_size=3),
       a_latest=st.lists(_f16, min_size=3, max_size=3),
       a_int=st.lists(_f32, min_size=3, max_size=3),
       cov=st.lists(_f16, max_size=36), tid=st.integers(0, 31))
def test_raw_imu_unpacker_agrees_with_the_dronecan_codec(
        usec: int, interval: float, g_latest: list[float], g_int: list[float],
        a_latest: list[float], a_int: list[float], cov: list[float], tid: int) -> None:
    """GIVEN any RawIMU message (any fields, covariance tail of any length, any transfer
    ID) encoded into frames; navd unpacks RawIMU itself for speed,
    WHEN navd reassembles them and the dronecan codec decodes the same frames,
    THEN navd yields one transfer with no counters and the same fields as the codec."""
    m = dronecan.uavcan.equipment.ahrs.RawIMU()
    m.timestamp.usec = usec
    m.integration_interval = interval
    m.rate_gyro_latest, m.rate_gyro_integral = g_latest, g_int
    m.accelerometer_latest, m.accelerometer_integral = a_latest, a_int
    m.covariance = cov
    msgs = transfer_messages(m, 9, tid, 16)
    ref = transport.Transfer()
    ref.from_frames([transport.Frame(message_id=x.arbitration_id, data=bytes(x.data))
                     for x in msgs])
    p = ref.payload
    dec = DronecanDecoder(virtual_cfg())
    sess: list[object] = []
    for x in msgs:
        got = dec._reassemble(x, 0)
        if got is not None:
            sess.append(got[3])
    assert len(sess) == 1 and dec.counters.total() == 0
    f = sess[0]
    assert isinstance(f, RawImuFields)
    assert f.usec == int(p.timestamp.usec)
    assert f.integration_interval == float(p.integration_interval)
    assert f.rate_gyro_latest == tuple(float(v) for v in p.rate_gyro_latest)
    assert f.rate_gyro_integral == tuple(float(v) for v in p.rate_gyro_integral)
    assert f.accelerometer_latest == tuple(float(v) for v in p.accelerometer_latest)
    assert f.accelerometer_integral == tuple(float(v) for v in p.accelerometer_integral)


# -- navd's private polarization message -------------------------------------------------------

_DSDL_NAVD = Path(__file__).resolve().parents[1] / "navd" / "io" / "dsdl" / "navd"


@functools.cache
def _codec_pol_type() -> Any:
    """The dronecan package's own parse of navd's .uavcan file, registered with its codec."""
    dronecan.load_dsdl(str(_DSDL_NAVD))
    return dronecan.TYPENAMES["navd.equipment.SkyPolarization"]


def _pol(t_us: int = 5_000_000, aop: float = 1.25, dop: float = 0.42) -> PolSample:
    return PolSample(t_us=t_us, aop_rad=aop, dop=dop, utc_unix_s=1_590_999_000.25)


def test_pol_type_signature_and_frames_match_the_dronecan_codec() -> None:
    """GIVEN the dronecan codec's parse of navd's SkyPolarization .uavcan file,
    WHEN its DTID, signature and size are read and a reading is encoded by both sides,
    THEN they match navd's constants (24 bytes) and the frames are identical."""
    t = _codec_pol_type()
    assert t.default_dtid == POL_DTID
    assert t.get_data_type_signature() == POL_SIGNATURE
    assert (t.get_min_bitlen() + 7) // 8 == 24
    s = _pol()
    tx = DronecanTx(node_id=33)
    ours = tx.polarization(s, sensor_id=2)
    m = t()
    m.timestamp.usec = s.t_us
    m.time_gps_usec = round(utc_to_gps_s(s.utc_unix_s) * 1e6)
    m.aop, m.dop, m.sensor_id = s.aop_rad, s.dop, 2
    ref = transfer_messages(m, 33, 0, tx.priority)
    assert [(x.arbitration_id, bytes(x.data)) for x in ours] == [
        (x.arbitration_id, bytes(x.data)) for x in ref]


def test_pol_readings_decode_and_bad_ones_are_counted() -> None:
    """GIVEN a valid polarization reading, its repeat, five bad readings
    (NaN/out-of-range AoP, DoP > 1, no UTC, no timestamp) and a CRC-corrupted one,
    WHEN they are decoded,
    THEN only the valid one becomes a PolSample (values kept) and each bad one is
    dropped and counted under its reason."""
    tx = DronecanTx(node_id=33)
    dec = DronecanDecoder(virtual_cfg())
    s = _pol()
    out = feed(dec, tx.polarization(s))
    assert len(out) == 1 and isinstance(out[0], PolSample)
    p = out[0]
    assert p.t_us == s.t_us and p.aop_rad == pytest.approx(s.aop_rad, abs=1e-7)
    assert p.dop == pytest.approx(s.dop, abs=1e-7)
    assert p.utc_unix_s == pytest.approx(s.utc_unix_s, abs=1e-6)
    assert dec.counters["pol_ok"] == 1
    assert feed(dec, tx.polarization(s)) == [] and dec.counters["pol_repeat"] == 1
    bad = [_pol(t_us=6_000_000, aop=math.nan), _pol(t_us=6_100_000, aop=3.5),
           _pol(t_us=6_200_000, dop=1.5),
           PolSample(t_us=6_300_000, aop_rad=1.0, dop=0.4, utc_unix_s=math.nan),
           _pol(t_us=0)]
    for b in bad:
        assert feed(dec, tx.polarization(b)) == []
    c = dec.counters
    assert c["pol_wire_bad_value"] == 3 and c["pol_wire_no_gps_time"] == 1
    assert c["pol_no_timestamp"] == 1
    frames = tx.polarization(_pol(t_us=7_000_000))
    data = bytearray(frames[1].data)
    data[0] ^= 0x01
    frames[1] = can.Message(arbitration_id=frames[1].arbitration_id, data=bytes(data),
                            is_extended_id=True)
    assert feed(dec, frames) == [] and dec.counters["bad_crc"] == 1


def test_pol_readings_decode_in_order_over_a_virtual_bus() -> None:
    """GIVEN a simulated polarization node sending five readings on a virtual bus,
    WHEN navd's bus receives them and the decoder reads them,
    THEN all five come out in order with their timestamps."""
    cfg = virtual_cfg()
    tx_bus = can.Bus(interface="virtual", channel=cfg.channel)
    rx_bus = open_bus(cfg)
    try:
        tx = DronecanTx(node_id=33)
        for k in range(5):
            for f in tx.polarization(_pol(t_us=1_000_000 + 100_000 * k)):
                tx_bus.send(f)
        dec = DronecanDecoder(cfg)
        got: list[Sample] = []
        while (m := rx_bus.recv(0.2)) is not None:
            got += dec.feed(m, 0)
        assert [s.t_us for s in got] == [1_000_000 + 100_000 * k for k in range(5)]
    finally:
        tx_bus.shutdown()
        rx_bus.shutdown()
