"""The floor under the daemon's 1 kHz CPU figure: what the event loop alone costs to receive
1000 UDP datagrams per second, and what handing each one to a consumer task through an
asyncio.Queue adds (navd's input -> estimator hand-off).

    python benchmarks/loop_floor.py [--seconds 10] [--loop uvloop|asyncio] [--json PATH]

A sender subprocess paces 52-byte datagrams at 1 kHz over loopback; this process receives
them with a no-op protocol ("noop"), then with protocol -> Queue -> task ("queue"), then
with protocol -> deque + one parked future -> task ("deque": what the hand-off costs without
asyncio.Queue's bookkeeping), and reports its own CPU (user + system, getrusage) per mode
as % of one core and per datagram.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import json
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

_SENDER = """
import socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
port, seconds = int(sys.argv[1]), float(sys.argv[2])
t0 = time.monotonic(); k = 0; d = bytes(52)
while time.monotonic() - t0 < seconds:
    k += 1
    delay = t0 + k * 1e-3 - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    s.sendto(d, ("127.0.0.1", port))
"""


async def measure(mode: str, seconds: float) -> dict[str, Any]:
    loop = asyncio.get_running_loop()
    q: asyncio.Queue[bytes] = asyncio.Queue()
    dq: collections.deque[bytes] = collections.deque()
    waiter: list[asyncio.Future[None]] = []  # the parked consumer's future, if any
    n = 0

    class Proto(asyncio.DatagramProtocol):
        def datagram_received(self, data: bytes, addr: tuple[Any, ...]) -> None:
            nonlocal n
            if mode == "queue":
                q.put_nowait(data)
            elif mode == "deque":
                dq.append(data)
                if waiter:
                    fut = waiter.pop()
                    if not fut.done():
                        fut.set_result(None)
            else:  # noop, and inline: the consumer's work done right here
                n += 1

    async def consume() -> None:
        nonlocal n
        if mode == "queue":
            while True:
                await q.get()
                n += 1
        while True:
            while not dq:
                fut = loop.create_future()
                waiter.append(fut)
                await fut
            dq.popleft()
            n += 1

    transport, _ = await loop.create_datagram_endpoint(Proto, local_addr=("127.0.0.1", 0))
    port = transport.get_extra_info("sockname")[1]
    task = loop.create_task(consume()) if mode in ("queue", "deque") else None
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
    sender = subprocess.Popen([sys.executable, "-c", _SENDER, str(port), str(seconds)])
    while sender.poll() is None:
        await asyncio.sleep(0.2)
    r1, wall = resource.getrusage(resource.RUSAGE_SELF), time.monotonic() - t0
    transport.close()
    if task is not None:
        task.cancel()
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"mode": mode, "datagrams": n, "cpu_pct_one_core": round(100.0 * cpu / wall, 2),
            "us_per_datagram": round(1e6 * cpu / max(n, 1), 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--loop", choices=("uvloop", "asyncio"), default="uvloop")
    ap.add_argument("--json", help="write the figures to this file")
    a = ap.parse_args(argv)

    async def both() -> list[dict[str, Any]]:
        return [await measure(m, a.seconds) for m in ("noop", "queue", "deque")]

    if a.loop == "uvloop":
        import uvloop

        rows = uvloop.run(both())
    else:
        rows = asyncio.run(both())
    print(f"{a.loop}, 1000 datagrams/s for {a.seconds:.0f} s")
    print(f"{'mode':8s} {'datagrams':>9s} {'CPU % of a core':>16s} {'us/datagram':>12s}")
    for r in rows:
        print(f"{r['mode']:8s} {r['datagrams']:9d} {r['cpu_pct_one_core']:16.2f} "
              f"{r['us_per_datagram']:12.1f}")
    if a.json:
        Path(a.json).write_text(json.dumps({"loop": a.loop, "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
