"""DroneCAN transport layer: classic-CAN frames <-> transfers (no data types here).

The ``dronecan`` package supplies the transfer codec (``transport.Transfer``: multi-frame
split, transfer CRC seeded with the data type signature).  Its driver and node are not
used: frames come from python-can, and reassembly is done here, frame by frame, as
libcanard does it:

* only 29-bit message frames from a non-anonymous node of an accepted data type are
  considered (service, anonymous, 11-bit, remote, error and FD frames are counted and
  dropped);
* a transfer session is (source node, data type ID); a start-of-transfer frame (re)starts
  it; later frames must carry the same transfer ID and the alternating toggle bit (a frame
  with the wrong toggle is dropped, not the session, so a duplicated frame is harmless);
  every frame but the last must be full (8 bytes);
* a session with no end after the transfer timeout (100 ms by default) is evicted and
  counted.

The transfer CRC is checked by the decoder (:mod:`navd.io.dronecan.decode`), which knows
the data type signatures that seed it.  Every rejection goes through the decoder's
:class:`~navd.io.common.Rejector`, so counters read as they did in the single-file adapter.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import Any, NamedTuple

import can
from dronecan import transport

from navd.io.common import Rejector

__all__ = ["RawTransfer", "TransferReassembler", "payload_len", "transfer_messages"]

MAX_TRANSFER_BYTES = 512  # larger than any accepted type; caps memory per session


class RawTransfer(NamedTuple):
    """A reassembled message transfer: its frames (tail bytes still on) and where from."""

    can_id: int
    src: int
    dtid: int
    start_us: int  # receive time of the first frame
    frames: list[bytes]


class _Session:
    __slots__ = ("frames", "nbytes", "next_toggle", "start_us", "tid")

    def __init__(self, tid: int, start_us: int) -> None:
        self.tid = tid
        self.start_us = start_us
        self.next_toggle = 0
        self.nbytes = 0
        self.frames: list[bytes] = []



class TransferReassembler:
    """Per-(node, data type) sessions; :meth:`push` returns a transfer once its last frame is
    in (toggles, transfer IDs and frame lengths checked; CRC not yet)."""

    def __init__(
        self,
        reject: Rejector,
        dtids: Collection[int],
        allow_nodes: frozenset[int] | None,
        timeout_us: int,
    ) -> None:
        self._reject = reject
        self.counters = reject.counters
        self._dtids = dtids
        self._allow_nodes = allow_nodes
        self._timeout_us = timeout_us
        self._sessions: dict[tuple[int, int], _Session] = {}

    @property
    def pending(self) -> int:
        """Partial transfers being reassembled."""
        return len(self._sessions)

    def evict_stale(self, now_us: int) -> int:
        stale = [k for k, s in self._sessions.items() if now_us - s.start_us > self._timeout_us]
        for k in stale:
            del self._sessions[k]
            self._reject("stale_transfer", "node %d dtid %d: no end within timeout", *k)
        return len(stale)

    def push(self, msg: can.Message, now: int) -> RawTransfer | None:
        if msg.is_error_frame or msg.is_remote_frame:
            self.counters.inc("bad_frame_kind")
            return None
        if not msg.is_extended_id:
            self.counters.inc("not_extended")
            return None
        if msg.is_fd:
            self._reject("fd_unsupported", "CAN FD frame id=0x%08x", msg.arbitration_id)
            return None
        data = bytes(msg.data[: msg.dlc])
        if not data:
            self._reject("bad_frame_len", "empty frame id=0x%08x", msg.arbitration_id)
            return None
        cid: int = msg.arbitration_id
        if cid & 0x80:
            self.counters.inc("service_ignored")
            return None
        src = cid & 0x7F
        if src == 0:
            self.counters.inc("anonymous_ignored")
            return None
        dtid = (cid >> 8) & 0xFFFF
        if dtid not in self._dtids:
            self.counters.inc("ignored")
            return None
        if self._allow_nodes is not None and src not in self._allow_nodes:
            self._reject("not_allowed", "node %d", src)
            return None

        tail = data[-1]
        sot, eot, toggle, tid = bool(tail & 0x80), bool(tail & 0x40), (tail >> 5) & 1, tail & 0x1F
        key = (src, dtid)
        frame = data
        if sot:
            if key in self._sessions:
                self._reject("transfer_restarted", "node %d dtid %d: new start before end", *key)
                del self._sessions[key]
            if toggle != 0:
                self._reject("bad_toggle", "node %d dtid %d: start frame with toggle set", *key)
                return None
            if eot:
                return RawTransfer(cid, src, dtid, now, [frame])
            if len(data) != 8:
                self._reject("bad_frame_len", "node %d dtid %d: short non-final frame", *key)
                return None
            sess = _Session(tid, now)
            sess.frames.append(frame)
            sess.nbytes = len(data) - 1
            sess.next_toggle = 1
            self._sessions[key] = sess
            return None

        sess_opt = self._sessions.get(key)
        if sess_opt is None:
            self._reject("orphan_frame", "node %d dtid %d: continuation without start", *key)
            return None
        sess = sess_opt
        if tid != sess.tid:
            self._reject("bad_transfer_id", "node %d dtid %d: tid %d during %d",
                         src, dtid, tid, sess.tid)
            return None
        if toggle != sess.next_toggle:
            self._reject("bad_toggle", "node %d dtid %d: toggle %d, expected %d",
                         src, dtid, toggle, sess.next_toggle)
            return None
        if not eot and len(data) != 8:
            self._reject("bad_frame_len", "node %d dtid %d: short non-final frame", *key)
            del self._sessions[key]
            return None
        sess.frames.append(frame)
        sess.nbytes += len(data) - 1
        sess.next_toggle ^= 1
        if sess.nbytes > MAX_TRANSFER_BYTES:
            self._reject("oversize_transfer", "node %d dtid %d: > %d bytes",
                         src, dtid, MAX_TRANSFER_BYTES)
            del self._sessions[key]
            return None
        if not eot:
            return None
        del self._sessions[key]
        return RawTransfer(cid, src, dtid, sess.start_us, sess.frames)


def payload_len(frames: list[bytes]) -> int:
    n = sum(len(f) - 1 for f in frames)
    return n - 2 if len(frames) > 1 else n  # multi-frame transfers start with the CRC


def transfer_messages(
    payload: Any, node_id: int, transfer_id: int, priority: int
) -> list[can.Message]:
    """Serialise one message transfer into classic-CAN frames (tail bytes, CRC)."""
    t = transport.Transfer(
        transfer_id=transfer_id & 0x1F,
        source_node_id=node_id,
        payload=payload,
        transfer_priority=priority,
    )
    return [
        can.Message(arbitration_id=f.message_id, data=bytes(f.bytes), is_extended_id=True)
        for f in t.to_frames()
    ]

