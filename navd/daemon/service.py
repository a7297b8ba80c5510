"""systemd service protocol (sd_notify), implemented here: it is one datagram per message.

systemd passes ``NOTIFY_SOCKET`` (a path, or ``@name`` for the abstract namespace) to a
``Type=notify`` service; the service sends newline-separated ``KEY=VALUE`` lines to it:
``READY=1`` when it serves, ``WATCHDOG=1`` to prove it is alive (at least every
``WATCHDOG_USEC`` microseconds, which systemd sets from ``WatchdogSec=``), ``STATUS=...``
for ``systemctl status`` and ``STOPPING=1`` when it begins to shut down.  Without
``NOTIFY_SOCKET`` (not under systemd) every call is a no-op, so the daemon needs no special
mode for running in a terminal.  Sending never blocks and never raises: a full or vanished
socket must not take the navigator down.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

__all__ = ["SdNotifier", "watchdog_interval_s"]

_log = logging.getLogger(__name__)


def _socket_address(raw: str) -> str | None:
    if raw.startswith("@"):
        return "\0" + raw[1:]  # abstract namespace: leading NUL instead of '@'
    if raw.startswith("/"):
        return raw
    return None  # vsock and other forms are not used for services on a companion computer


class SdNotifier:
    """Sends sd_notify messages to ``$NOTIFY_SOCKET``; a no-op when it is unset."""

    def __init__(self, env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        raw = env.get("NOTIFY_SOCKET", "")
        self.address = _socket_address(raw) if raw else None
        if raw and self.address is None:
            _log.warning("ignoring unsupported NOTIFY_SOCKET %r", raw)
        self._sock: socket.socket | None = None
        if self.address is not None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.setblocking(False)
        self.sent = 0
        self.errors = 0

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, *lines: str) -> bool:
        """Send ``lines`` as one message; True if it went out (False when disabled)."""
        if self._sock is None or self.address is None:
            return False
        # STATUS text must stay on one line: a newline would start a new KEY=VALUE pair.
        msg = "\n".join(line.replace("\n", " ") for line in lines)
        try:
            self._sock.sendto(msg.encode("utf-8", "replace"), self.address)
        except OSError as exc:
            self.errors += 1
            if self.errors == 1 or self.errors % 100 == 0:
                _log.warning("sd_notify to %r failed (%d so far): %s", self.address,
                             self.errors, exc)
            return False
        self.sent += 1
        return True

    def ready(self, status: str = "") -> bool:
        return self.notify("READY=1", *((f"STATUS={status}",) if status else ()))

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def stopping(self, status: str = "") -> bool:
        return self.notify("STOPPING=1", *((f"STATUS={status}",) if status else ()))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def watchdog_interval_s(env: Mapping[str, str] | None = None) -> float | None:
    """The watchdog timeout systemd expects us to beat, in seconds, or None if not armed.

    ``WATCHDOG_PID``, when set, names the process meant; a child that inherited the
    environment must not answer for its parent.
    """
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    pid = env.get("WATCHDOG_PID", "")
    if pid and (not pid.isdigit() or int(pid) != os.getpid()):
        return None
    return int(usec) * 1e-6
