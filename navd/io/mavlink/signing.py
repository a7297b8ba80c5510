"""MAVLink 2 message signing: check that a frame came from a holder of the shared key.

A signed frame ends in 13 bytes: link id, a 48-bit timestamp (10 us units since
2015-01-01 UTC) and the first 6 bytes of SHA-256(key + frame up to and including the
timestamp).  A frame is accepted when the signature matches and its timestamp moves its
stream (link id, sysid, compid) forward; a stream seen for the first time may start at
most one minute behind the newest timestamp accepted so far (replay protection without a
clock: a companion computer may boot without one, so "now" is the newest signed time).

Without a key nothing is checked (navd cannot tell a junk signature from a real one);
with one, unsigned frames (all MAVLink 1 frames among them) are refused unless
``accept_unsigned``.
"""

from __future__ import annotations

import hashlib
import logging
import os
import stat
from pathlib import Path

from navd.io.mavlink.frame import SIGNATURE_LEN, Frame

__all__ = ["KEY_LEN", "SignatureCheck", "load_signing_key"]

_log = logging.getLogger("navd.io.mavlink")

KEY_LEN = 32
NEW_STREAM_WINDOW = 60 * 100_000  # one minute in 10 us units
MAX_STREAMS = 256  # only authenticated senders create streams; the cap bounds memory anyway


def load_signing_key(path: str | Path) -> bytes:
    """A 32-byte key from ``path``: either exactly 32 raw bytes or 64 hex digits (surrounding
    white space allowed).  Raises ValueError with what is wrong."""
    p = Path(path)
    data = p.read_bytes()
    mode = p.stat().st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        _log.warning("MAVLink signing key %s is readable by group/others (mode %o)",
                     p, stat.S_IMODE(mode))
    if len(data) == KEY_LEN:
        return data
    text = data.strip()
    if len(text) == 2 * KEY_LEN:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    raise ValueError(f"{os.fspath(p)}: a MAVLink signing key is 32 raw bytes or 64 hex "
                     f"digits, got {len(data)} bytes")


class SignatureCheck:
    """The frame check :class:`navd.io.mavlink.frame.FrameScanner` calls: None to accept,
    else the refusal reason (``unsigned``, ``bad_signature``, ``signature_replay``,
    ``signature_stale``)."""

    __slots__ = ("_key", "_newest", "_streams", "accept_unsigned")

    def __init__(self, key: bytes, accept_unsigned: bool = False) -> None:
        if len(key) != KEY_LEN:
            raise ValueError(f"a MAVLink signing key has {KEY_LEN} bytes, got {len(key)}")
        self._key = bytes(key)
        self.accept_unsigned = accept_unsigned
        self._streams: dict[tuple[int, int, int], int] = {}
        self._newest = 0

    def __call__(self, f: Frame) -> str | None:
        if not f.signed:
            return None if self.accept_unsigned else "unsigned"
        raw = f.raw
        if hashlib.sha256(self._key + raw[:-6]).digest()[:6] != raw[-6:]:
            return "bad_signature"
        link_id = raw[-SIGNATURE_LEN]
        t = int.from_bytes(raw[-12:-6], "little")
        stream = (link_id, f.sysid, f.compid)
        last = self._streams.get(stream)
        if last is not None:
            if t <= last:
                return "signature_replay"
        elif t + NEW_STREAM_WINDOW < self._newest:
            return "signature_stale"
        elif len(self._streams) >= MAX_STREAMS:
            del self._streams[next(iter(self._streams))]
        self._streams[stream] = t
        self._newest = max(self._newest, t)
        return None
