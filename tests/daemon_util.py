"""Shared pieces of the daemon tests: ports, a fake NOTIFY_SOCKET, configs, truth lookup.

Everything runs on 127.0.0.1 with Zenoh multicast scouting off.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from firmware_sim import SimRun, generate, load_scenario

ROOT = Path(__file__).resolve().parents[1]
# A cold numba cache compiles the estimator for 10-20 s (more on a loaded CI machine)
# before navd says READY=1.
STARTUP_TIMEOUT_S = 180.0


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def car_run(duration_s: float, seed: int = 1, **overrides: Any) -> SimRun:
    return generate(load_scenario("car480", overrides={"duration_s": duration_s, **overrides}),
                    seed=seed)


def heading_errors_deg(run: SimRun, t_us: list[int], yaw_rad: list[float]) -> np.ndarray:
    """navd yaw - true yaw at the same sensor time, wrapped to +-180 deg."""
    idx = np.asarray(t_us) // run.imu_dt_us  # truth row k is at k * dt
    assert np.all(run.truth_t_us[idx] == np.asarray(t_us)), "outputs must be at IMU times"
    d = np.degrees(np.asarray(yaw_rad) - run.truth_euler[idx, 2])
    return (d + 180.0) % 360.0 - 180.0


def toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return repr(v)


def write_config(path: Path, sections: dict[str, dict[str, Any]]) -> Path:
    lines = []
    for name, table in sections.items():
        lines.append(f"[{name}]")
        lines += [f"{k} = {toml_value(v)}" for k, v in table.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


@dataclass
class NotifySocket:
    """A fake systemd NOTIFY_SOCKET: a unix datagram socket read by a thread; every message
    is kept with its arrival time (time.monotonic)."""

    path: str = ""
    messages: list[tuple[float, list[str]]] = field(default_factory=list)

    def __post_init__(self) -> None:
        # short path: sun_path holds 108 bytes, pytest's tmp_path can be longer
        self._dir = tempfile.mkdtemp(prefix="nvd")
        self.path = os.path.join(self._dir, "notify")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.bind(self.path)
        self._sock.settimeout(0.1)
        self._run = True
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._reader, daemon=True)
        self._thread.start()

    def _reader(self) -> None:
        while self._run:
            try:
                data = self._sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            with self._lock:
                self.messages.append((time.monotonic(), data.decode().split("\n")))

    def times(self, line: str) -> list[float]:
        with self._lock:
            return [t for t, lines in self.messages if line in lines]

    def wait_for(self, line: str, timeout_s: float, proc: subprocess.Popen[bytes] | None = None
                 ) -> float:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            got = self.times(line)
            if got:
                return got[0]
            if proc is not None and proc.poll() is not None:
                raise AssertionError(f"daemon exited with {proc.returncode} before {line}")
            time.sleep(0.05)
        raise AssertionError(f"no {line} within {timeout_s} s")

    def close(self) -> None:
        self._run = False
        self._thread.join(2.0)
        self._sock.close()
        for p in (self.path,):
            if os.path.exists(p):
                os.unlink(p)
        os.rmdir(self._dir)


def start_daemon(config: Path, log: Path, env: dict[str, str] | None = None,
                 args: tuple[str, ...] = ()) -> subprocess.Popen[bytes]:
    full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
    with open(log, "wb") as fh:
        return subprocess.Popen([sys.executable, "-m", "navd", "run", "--config", str(config),
                                 *args], stdout=fh, stderr=fh, env=full_env, cwd=ROOT)


def stop_daemon(proc: subprocess.Popen[bytes], timeout_s: float = 20.0) -> int:
    if proc.poll() is None:
        proc.terminate()
        try:
            return proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise
    return int(proc.returncode)


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def send_paced(port: int, frames: list[bytes], period_s: float) -> None:
    """Send ``frames`` to 127.0.0.1:``port``, one every ``period_s`` (catching up at once
    when behind), from a fresh UDP socket."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    t0 = time.monotonic()
    for k, f in enumerate(frames):
        delay = t0 + k * period_s - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        s.sendto(f, ("127.0.0.1", port))
    s.close()
