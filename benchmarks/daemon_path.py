"""The daemon's 1 kHz path in one process: bytecode executed per datagram, and what comes out.

    python benchmarks/daemon_path.py [--seconds 20] [--trace 4000] [--top 25] [--pace-ms 0]
                                     [--mode batch|datagram]

The real :class:`navd.daemon.daemon.Daemon` with its sinks open (MAVLink ``udpout`` to a
local socket nobody reads, Zenoh), fed the datagrams of ``benchmarks/daemon.py`` (car480 with
a 1 kHz HIGHRES_IMU, 10 Hz GPS_INPUT), ``--per-read`` (10) per event-loop turn as the paced
reader delivers them: ``--mode batch`` (default) sent to the daemon's ``udpin`` socket and
read by its :class:`navd.io.mavlink.link.PacedUdpTransport` (its readiness callback called
once per read, which hands the datagrams to the protocol's ``batch_received`` in one call:
the batch lane of issue 18), at the receive time of the last; ``--mode datagram`` each into
``datagram_received`` at its own receive time (the per-datagram path).  The receive clock is
the sensor time (a live stream for the clock guard), so every run is the same computation,
and both modes give the same outputs.

Prints, after 4 s of warm-up:
  instructions  Python bytecode instructions and calls per datagram (``sys.settrace`` with
                opcode events over ``--trace`` datagrams) and the functions that execute
                most: a load-independent measure of the interpreter's share, which on a
                shared or slow machine is most of the daemon's CPU (issue 18)
  CPU           process time per datagram over the rest, without tracing (``--pace-ms``:
                sleep that long after every read, so caches go cold as in the
                daemon; 0 = back to back)
  hashes        of the estimator's state buffer, the MAVLink bytes sent and the Zenoh
                attitude JSON: equal between two trees means the same outputs
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import socket
import sys
import tempfile
import time
from pathlib import Path
from types import FrameType
from typing import Any

from firmware_sim import generate, load_scenario
from firmware_sim.stream import mavlink_events
from navd.cli.demo import free_port


async def run(a: argparse.Namespace) -> None:
    import navd.daemon.sources as sources
    import navd.io.zenoh as nz
    from navd.config.daemon import load_daemon_config
    from navd.daemon.daemon import Daemon, warm_up
    from navd.io.mavlink.link import PacedUdpTransport

    sim = generate(load_scenario("car480", overrides={
        "imu.rate_hz": 1000.0, "duration_s": a.seconds + 2.0}), seed=1)
    events = list(mavlink_events(sim))
    frames = [(t, f) for t, f, _ in events]
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 24)
    tmp = Path(tempfile.mkdtemp(prefix="navd-path-"))
    pz = free_port(socket.SOCK_STREAM)
    (tmp / "navd.toml").write_text(
        f'[mavlink]\nlisten = "udpin:127.0.0.1:{free_port()}"\n'
        f'send = "udpout:127.0.0.1:{rx.getsockname()[1]}"\nnominal_imu_rate_hz = 1000.0\n'
        f'[zenoh]\nvehicle = "path{pz}"\nlisten = ["tcp/127.0.0.1:{pz}"]\n'
        # read on the loop (this feed calls its readiness callback itself; the compiled
        # reader thread hands batches to the same batch_received)
        "[daemon]\nstatus_period_s = 1000\nlog_period_s = 3600\nrx_thread = false\n")

    zenoh_hash = hashlib.sha1()
    text_of = nz.attitude_text

    def attitude_text(*args: Any, **kw: Any) -> str:  # the Zenoh attitude text, as published
        text = text_of(*args, **kw)
        zenoh_hash.update(text.encode())
        return text

    nz.attitude_text = attitude_text

    class _Clock:  # the receive clock: host time = sensor time
        now = 0

        @staticmethod
        def monotonic_ns() -> int:
            return _Clock.now

    setattr(sources, "time", _Clock)  # noqa: B010 - the module attribute the link reads

    cfg = load_daemon_config(tmp / "navd.toml", [])
    d = Daemon(cfg, handle_signals=False)
    warm_up(cfg.nav)
    await d._open()
    link = d.sources.mavlink
    assert link is not None and link._udp is not None
    receive = link._udp.datagram_received
    transport = link._udp_transport
    assert isinstance(transport, PacedUdpTransport)
    # the kernel's arrival stamps are on the host's clock, not this feed's sensor-time
    # clock: unknown arrivals make the link read the (patched) receive clock instead
    transport._stamps = False
    readable = transport._readable
    # the hold is computed but not taken: this feed is not in real time, and a hold would
    # take the socket off the loop (the loop's timer and reader bookkeeping per hold is not
    # counted here, as the per-datagram mode counts no loop machinery either)
    hold = transport.hold_us
    assert hold is not None

    def hold_us() -> int:
        hold()
        return 0

    transport.hold_us = hold_us
    dest = link.local_address
    assert dest is not None
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.bind(("127.0.0.1", 0))
    send = tx.sendto
    task = asyncio.get_running_loop().create_task(d._estimate())
    addr = ("127.0.0.1", 14550)

    async def feed(part: list[tuple[int, bytes]], pause_s: float = 0.0) -> None:
        r = a.per_read
        for i in range(0, len(part), r):
            if a.mode == "batch":
                read = part[i:i + r]
                for _, datagram in read:
                    send(datagram, dest)
                _Clock.now = 10**12 + read[-1][0] * 1000
                readable()
            else:
                for t_us, datagram in part[i:i + r]:
                    _Clock.now = 10**12 + t_us * 1000
                    receive(datagram, addr)
            await asyncio.sleep(pause_s)
        await asyncio.sleep(0)
        await asyncio.sleep(0)

    warm = 4400  # 4 s: levelled and navigating
    await feed(frames[:warm])
    # the figures below are only the steady 1 kHz path if the warm-up reached the estimator
    # as it was sent (a receive clock off the sensor's makes the clock guard hold samples
    # and release them into the traced part: 678 instructions per datagram were measured
    # so, against 304)
    n_imu = sum(1 for _, _, is_imu in events[:warm] if is_imu)
    if not d.est.initialized or d.est.counters.get("imu", 0) != n_imu:
        raise RuntimeError(f"warm-up: the estimator took {d.est.counters.get('imu', 0)} of "
                           f"{n_imu} IMU samples (navigating: {d.est.initialized})")
    traced = frames[warm:warm + a.trace]
    counts = {"call": 0, "opcode": 0}
    by_fn: dict[str, int] = {}

    def tracer(frame: FrameType, event: str, arg: object) -> Any:
        counts[event] = counts.get(event, 0) + 1
        if event == "call":
            frame.f_trace_opcodes = True
        elif event == "opcode":
            code = frame.f_code
            key = f"{Path(code.co_filename).name}:{code.co_name}"
            by_fn[key] = by_fn.get(key, 0) + 1
        return tracer

    sys.settrace(tracer)
    await feed(traced)
    sys.settrace(None)
    rest = frames[warm + a.trace:]
    c0 = time.process_time()
    await feed(rest, a.pace_ms * 1e-3)
    cpu = time.process_time() - c0
    d.queue.close()
    await task
    d._close()
    tx.close()
    rx.setblocking(False)
    mav_hash, n_out = hashlib.sha1(), 0
    while True:
        try:
            mav_hash.update(rx.recv(65536))
        except BlockingIOError:
            break
        n_out += 1
    n = len(traced)
    print(f"per datagram: {counts['opcode'] / n:.1f} bytecode instructions, "
          f"{counts['call'] / n:.2f} Python calls (over {n} datagrams)")
    for key, v in sorted(by_fn.items(), key=lambda kv: -kv[1])[:a.top]:
        print(f"  {v / n:8.1f}  {key}")
    pace = f", {a.pace_ms:g} ms pause per read" if a.pace_ms else ", back to back"
    print(f"CPU {1e6 * cpu / len(rest):.1f} us per datagram over {len(rest)}{pace}")
    print(f"estimator state {hashlib.sha1(d.est.buf.tobytes()).hexdigest()[:16]}, "
          f"counters {dict(d.est.counters)}")
    print(f"outputs: MAVLink {n_out} datagrams {mav_hash.hexdigest()[:16]}, Zenoh attitude "
          f"{zenoh_hash.hexdigest()[:16]}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="sensor seconds after warm-up")
    ap.add_argument("--trace", type=int, default=4000, help="datagrams counted by tracing")
    ap.add_argument("--top", type=int, default=25, help="functions listed")
    ap.add_argument("--mode", choices=("batch", "datagram"), default="batch",
                    help="reads into batch_received (the batch lane) or datagrams into "
                         "datagram_received")
    ap.add_argument("--per-read", type=int, default=10, dest="per_read",
                    help="datagrams per read (per event-loop turn), at most 32")
    ap.add_argument("--pace-ms", type=float, default=0.0, dest="pace_ms",
                    help="pause after every read of the timed part")
    asyncio.run(run(ap.parse_args(argv)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
