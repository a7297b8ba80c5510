"""Hostile input to the running daemon: thousands of bad datagrams (random bytes, truncated
and CRC-corrupted frames, NaN/Inf fields, |accel| > 50 g, 1000 km GNSS jumps, sources
outside the allowlist) interleaved with a real drive.  The daemon must refuse and count
them, log at a limited rate, keep running, and keep its attitude output finite and right.
"""

from __future__ import annotations

import dataclasses
import json
import math
import random
import signal
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from daemon_util import (
    STARTUP_TIMEOUT_S,
    NotifySocket,
    car_run,
    free_port,
    heading_errors_deg,
    start_daemon,
    stop_daemon,
    write_config,
)
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from firmware_sim.stream import timed_samples
from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.types import GnssSample, ImuSample

DURATION_S = 30.0
RATE_FACTOR = 5.0
FUZZ_FROM_US = 3_000_000  # after initialisation (a bad first fix is the estimator's problem)


def _fuzz_for(rng: random.Random, t: int, s: ImuSample | GnssSample, good: bytes,
              tx: MavlinkTx, stranger: MavlinkTx) -> list[bytes]:
    """A few hostile datagrams to send next to the real frame ``good`` of sample ``s``."""
    out: list[bytes] = [rng.randbytes(rng.randint(1, 280))]
    framed = bytes([0xFD, rng.randint(0, 255)]) + rng.randbytes(rng.randint(0, 270))
    out.append(framed)
    out.append(good[: rng.randint(1, len(good) - 1)])  # truncated
    bad = bytearray(good)
    bad[rng.randrange(10, len(bad))] ^= 1 << rng.randrange(8)  # CRC no longer matches
    out.append(bytes(bad))
    if isinstance(s, ImuSample):
        dt = s.dt_us * 1e-6
        between = dataclasses.replace(s, t_us=t + 3000)  # between two real samples
        nan = rng.choice([math.nan, math.inf, -math.inf])
        out.append(tx.highres_imu(dataclasses.replace(between, dtheta_y=nan)))
        out.append(tx.highres_imu(dataclasses.replace(between, dvel_z=-60.0 * 9.81 * dt)))
        out.append(stranger.highres_imu(between))  # valid, but not an allowed source
        # several good and bad frames in one datagram with junk between them
        out.append(good[:7] + rng.randbytes(5) + tx.highres_imu(
            dataclasses.replace(between, dvel_x=math.nan)))
    else:
        between = dataclasses.replace(s, t_us=s.t_us + 50_000)
        out.append(tx.gps_input(dataclasses.replace(
            between, lat_rad=s.lat_rad + math.radians(9.0))))  # ~1000 km away
        out.append(tx.gps_input(dataclasses.replace(between, alt_m=math.nan)))
        out.append(tx.gps_input(dataclasses.replace(
            between, t_us=s.t_us + 60_000, lon_rad=s.lon_rad + math.radians(12.0))))
    return out


def _attitude_listener(port: int, got: list[tuple[float, Any]], stop: threading.Event
                       ) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.settimeout(0.1)
    mav = mavlink.MAVLink(None)
    try:
        while not stop.is_set():
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            for m in mav.parse_buffer(data) or []:
                if m.get_type() == "ATTITUDE":
                    got.append((time.monotonic(), m))
    finally:
        sock.close()


def test_daemon_survives_fuzz_and_counts_it(tmp_path: Path) -> None:
    """GIVEN navd with an allowlist fed a 30 s drive over MAVLink UDP, from 3 s with hostile
    datagrams after every real frame (junk, truncated, corrupted, NaN/Inf, > 50 g, ~1000 km
    GNSS jumps, a stranger source), WHEN it is stopped with SIGTERM,
    THEN it exits 0; attitude kept coming, finite, with heading RMS < 1 deg; every refusal
    reason is counted, the real stream got through, and fewer than 60 warnings are logged."""
    run = car_run(DURATION_S)
    port_in, port_out = free_port(), free_port()
    cfg = write_config(tmp_path / "navd.toml", {
        "mavlink": {"listen": f"udpin:127.0.0.1:{port_in}",
                    "send": f"udpout:127.0.0.1:{port_out}", "allow": [[1, 1]]},
        "zenoh": {"enabled": False},
        "daemon": {"status_period_s": 0.5},
    })
    notify = NotifySocket()
    log = tmp_path / "navd.log"
    proc = start_daemon(cfg, log, {"NOTIFY_SOCKET": notify.path})
    got: list[tuple[float, Any]] = []
    stop = threading.Event()
    listener = threading.Thread(target=_attitude_listener, args=(port_out, got, stop),
                                daemon=True)
    listener.start()
    rng = random.Random(20240601)
    tx, stranger = MavlinkTx(1, 1), MavlinkTx(9, 1)
    real = MavlinkTx(1, 1)
    fuzz_sent = 0
    try:
        notify.wait_for("READY=1", STARTUP_TIMEOUT_S, proc)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        wall0 = time.monotonic()
        t0 = None
        fuzz_wall = (0.0, 0.0)
        for t, s in timed_samples(run):
            t0 = t if t0 is None else t0
            delay = wall0 + (t - t0) * 1e-6 / RATE_FACTOR - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            good = real.highres_imu(s) if isinstance(s, ImuSample) else real.gps_input(s)
            sock.sendto(good, ("127.0.0.1", port_in))
            if t >= FUZZ_FROM_US:
                if fuzz_wall[0] == 0.0:
                    fuzz_wall = (time.monotonic(), 0.0)
                # after the real frame: fake samples stamped between it and the next one
                for bad in _fuzz_for(rng, t, s, good, tx, stranger):
                    sock.sendto(bad, ("127.0.0.1", port_in))
                    fuzz_sent += 1
        fuzz_wall = (fuzz_wall[0], time.monotonic())
        sock.close()
        time.sleep(1.0)
        assert proc.poll() is None, "the daemon died under fuzz"
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(30)
    finally:
        stop.set()
        listener.join(2)
        stop_daemon(proc)
        notify.close()
    text = log.read_text()
    assert rc == 0, text[-3000:]
    assert fuzz_sent > 8000

    # output kept coming through the fuzz, finite, and still right
    during = [t for t, _ in got if fuzz_wall[0] <= t <= fuzz_wall[1]]
    assert len(during) > 0.8 * (DURATION_S - 3) * 50
    assert np.diff(during).max() < 0.5
    for _, m in got:
        assert all(math.isfinite(v) for v in (m.roll, m.pitch, m.yaw, m.rollspeed,
                                               m.pitchspeed, m.yawspeed))
    late = [m for _, m in got if m.time_boot_ms >= 10_000]
    err = heading_errors_deg(run, [m.time_boot_ms * 1000 for m in late], [m.yaw for m in late])
    assert np.sqrt(np.mean(err**2)) < 1.0 and np.abs(err).max() < 3.0

    # every kind of refusal was counted, and the real stream got through complete
    stats = json.loads(text.split("final stats ", 1)[1].splitlines()[0])
    mav_in = stats["inputs"]["mavlink"]
    for reason in ("bad_prefix", "bad_crc", "truncated", "imu_nonfinite", "imu_absurd_accel",
                   "not_allowed", "gnss_nonfinite"):
        assert mav_in.get(reason, 0) > 50, (reason, mav_in)
    est = stats["estimator"]["counters"]
    assert est.get("gnss_absurd_jump", 0) > 2 * (DURATION_S - 3) * 10 * 0.9, est
    assert est["imu"] == run.imu_t_us.shape[0] - 1  # only the first sample starts the clock
    epochs = run.gnss["t_us"].shape[0]
    assert est["pos_accepted"] >= 0.95 * (epochs - 10) and est["course_accepted"] > 0.9 * epochs
    rejected = sum(v for k, v in mav_in.items() if k not in ("frames_ok", "imu_ok", "gnss_ok",
                                                              "ignored", "seq_lost"))
    # ...and the journal got a handful of lines for all of it (one per reason per 5 s)
    warnings = [ln for ln in text.splitlines() if " WARNING " in ln]
    assert rejected > 5000 and len(warnings) < 60, (rejected, len(warnings))


# -- the recording path (issue 16 item 2) -------------------------------------------------------

# A GPS_INPUT whose uint64 time_usec (2**63 + 1) does not fit a recording's int64 field: it
# ended the daemon when --record was on.
CRAFTED_GPS_INPUT = bytes.fromhex(
    "fd3f0000000101e800000100000000000080000000008081621440d2e8400000c843cdcc4c3f9a99993f"
    "0000000000000000000000009a99993e0000803f000000400000000000030ce130")

_INT_RANGE = {"uint8_t": (0, 0xFF), "int8_t": (-0x80, 0x7F), "uint16_t": (0, 0xFFFF),
              "int16_t": (-0x8000, 0x7FFF), "uint32_t": (0, 0xFFFFFFFF),
              "int32_t": (-0x80000000, 0x7FFFFFFF), "uint64_t": (0, (1 << 64) - 1),
              "int64_t": (-(1 << 63), (1 << 63) - 1)}
_FUZZED = (mavlink.MAVLink_highres_imu_message, mavlink.MAVLink_scaled_imu_message,
           mavlink.MAVLink_scaled_imu2_message, mavlink.MAVLink_raw_imu_message,
           mavlink.MAVLink_gps_raw_int_message, mavlink.MAVLink_gps_input_message,
           mavlink.MAVLink_hil_gps_message)


def _extreme(rng: random.Random, ftype: str) -> Any:
    """A field value at or near the edges of its wire type (valid on the wire)."""
    if ftype in ("float", "double"):
        return rng.choice([math.nan, math.inf, -math.inf, 3.0e38, -3.0e38, 0.0, -0.0, 1e-40,
                           rng.uniform(-1e4, 1e4)])
    lo, hi = _INT_RANGE[ftype]
    return rng.choice([lo, hi, lo + 1, hi - 1, 0, 1, hi // 2 + 1, rng.randint(lo, hi)])


def _mutated(rng: random.Random, packer: Any, good: bytes | None) -> bytes:
    """A CRC-valid frame: ``good`` with 1-3 fields set to extremes, or (None) a handled
    message type with every field at an extreme."""
    if good is not None:
        msg = mavlink.MAVLink(None).parse_buffer(good)[0]
        cls = type(msg)
        vals = {n: getattr(msg, n) for n in cls.fieldnames}
        names = rng.sample(cls.fieldnames, rng.randint(1, 3))
    else:
        cls = rng.choice(_FUZZED)
        vals, names = {}, list(cls.fieldnames)
    for n in names:
        t = cls.fieldtypes[cls.fieldnames.index(n)]
        length = cls.array_lengths[cls.fieldnames.index(n)]
        vals[n] = ([_extreme(rng, t) for _ in range(length)] if length
                   else _extreme(rng, t))
    return bytes(cls(**vals).pack(packer))


def test_daemon_with_record_survives_crafted_frames(tmp_path: Path) -> None:
    """GIVEN navd running with --record, sent the issue's GPS_INPUT whose time does not fit a
    recording and, from 2 s of a 10 s drive, CRC-valid frames with fields at their extremes,
    WHEN it is stopped with SIGTERM,
    THEN it survived and exits 0, counts the out-of-range times, and its recording has no
    errors, is not truncated and holds every recorded sample with a plausible time."""
    from navd.io.recording import RecordingReader

    run = car_run(10.0)
    port_in = free_port()
    cfg = write_config(tmp_path / "navd.toml", {
        "mavlink": {"listen": f"udpin:127.0.0.1:{port_in}", "send": "", "allow": [[1, 1]]},
        "zenoh": {"enabled": False},
        "daemon": {"status_period_s": 0.5},
    })
    notify = NotifySocket()
    log, rec = tmp_path / "navd.log", tmp_path / "run.navdrec"
    proc = start_daemon(cfg, log, {"NOTIFY_SOCKET": notify.path}, ("--record", str(rec)))
    rng = random.Random(16002)
    real = MavlinkTx(1, 1)
    packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    sent = 0
    try:
        notify.wait_for("READY=1", STARTUP_TIMEOUT_S, proc)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.sendto(CRAFTED_GPS_INPUT, ("127.0.0.1", port_in))
        time.sleep(0.5)
        assert proc.poll() is None, "the issue's frame ended the daemon"
        wall0 = time.monotonic()
        for t, s in timed_samples(run):
            delay = wall0 + t * 1e-6 / RATE_FACTOR - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            good = real.highres_imu(s) if isinstance(s, ImuSample) else real.gps_input(s)
            sock.sendto(good, ("127.0.0.1", port_in))
            if t >= 2_000_000:
                for bad in (_mutated(rng, packer, good), _mutated(rng, packer, good),
                            _mutated(rng, packer, None)):
                    sock.sendto(bad, ("127.0.0.1", port_in))
                    sent += 1
        sock.sendto(CRAFTED_GPS_INPUT, ("127.0.0.1", port_in))
        sock.close()
        time.sleep(1.0)
        assert proc.poll() is None, "the daemon died under fuzz with --record"
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(30)
    finally:
        stop_daemon(proc)
        notify.close()
    text = log.read_text()
    assert rc == 0, text[-3000:]
    assert sent > 2000
    stats = json.loads(text.split("final stats ", 1)[1].splitlines()[0])
    assert stats["inputs"]["mavlink"].get("gnss_time_out_of_range", 0) >= 2, stats["inputs"]
    assert stats["recording"]["errors"] == 0 and stats["recording"]["records"] > 0
    # what was recorded is a valid recording of every sample the estimator got
    reader = RecordingReader(rec)
    samples = list(reader.samples())
    assert reader.truncated_bytes == 0 and len(samples) == stats["recording"]["records"]
    assert all(0 < x.t_us < (1 << 53) for x in samples)
