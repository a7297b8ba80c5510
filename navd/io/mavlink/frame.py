"""MAVLink 1/2 frames out of bytes, in time linear in the input, CRC checked.

Why not pymavlink's parser: on a rejected frame it re-copies the rest of its buffer and
computes the checksum in Python; one 64 kB datagram of 0xFE cost ~0.5 s (issue 19).  Here
every input byte is examined a bounded number of times:

* junk between frames is skipped with one C-level regular-expression search for the next
  start marker that could begin a frame (0xFE, or 0xFD followed by a length and a known
  incompatibility flag);
* a candidate frame costs O(1) Python steps plus one C-level checksum over at most 278
  bytes (``binascii.crc_hqx`` on bit-reversed bytes gives MAVLink's reflected X.25 CRC);
* a rejected candidate advances the scan by one byte, an accepted frame by its length;
  nothing is copied except the (< 280 byte) unfinished tail a byte stream keeps between
  calls.

A frame is accepted only when its message id is known (so its CRC_EXTRA is) and its CRC
matches; a frame of an unknown message cannot be told from noise and is rejected like it.
Rejections are reported per *run* of rejected bytes (:class:`Rejects`): a 64 kB datagram
of junk is one junk run with a byte count, not 65,000 "bad CRC" events.
"""

from __future__ import annotations

import binascii
import re
from collections.abc import Callable, Generator, Iterator, Mapping
from typing import NamedTuple

__all__ = ["HEADER_V1", "HEADER_V2", "MAX_FRAME_BYTES", "SIGNATURE_LEN", "STX_V1", "STX_V2",
           "Frame", "FrameScanner", "Rejects", "crc_x25"]

STX_V1 = 0xFE
STX_V2 = 0xFD
HEADER_V1 = 6  # STX, len, seq, sysid, compid, msgid
HEADER_V2 = 10  # STX, len, incompat, compat, seq, sysid, compid, msgid (3 bytes)
SIGNATURE_LEN = 13  # link id, 48-bit timestamp, 48-bit signature
IFLAG_SIGNED = 0x01
MAX_FRAME_BYTES = HEADER_V2 + 255 + 2 + SIGNATURE_LEN  # 280

# A frame can start at 0xFE (MAVLink 1: any header is possible) or at 0xFD whose
# incompatibility flags (third byte) hold no flag but "signed".  A 0xFD too close to the
# end to show its flags is a candidate as well (a byte stream may complete it).
_START = re.compile(rb"\xfe|\xfd.[\x00\x01]|\xfd.?\Z", re.DOTALL)

_REV8 = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))
_REV8_HI = tuple(_REV8[i] << 8 for i in range(256))


def crc_x25(data: bytes, crc_extra: int | None = None) -> int:
    """CRC-16/MCRF4XX (MAVLink's X.25 checksum) of ``data`` (+ the CRC_EXTRA byte).

    MCRF4XX is the bit-reflected form of CRC-CCITT (poly 0x1021, init 0xFFFF), which
    ``binascii.crc_hqx`` computes in C without reflection: feed it bit-reversed bytes and
    bit-reverse the result.
    """
    if crc_extra is not None:
        data = bytes(data) + bytes((crc_extra,))
    c = binascii.crc_hqx(data.translate(_REV8), 0xFFFF)
    return _REV8_HI[c & 0xFF] | _REV8[c >> 8]


class Frame(NamedTuple):
    """One CRC-checked frame.  ``payload`` is as sent (MAVLink 2 may have cut trailing zero
    bytes; the reader pads); ``raw`` is the whole frame, signature included."""

    version: int  # 1 or 2
    msgid: int
    sysid: int
    compid: int
    seq: int
    payload: bytes
    raw: bytes
    signed: bool


class Rejects:
    """What one scan rejected, by reason, and how many bytes belonged to no frame.

    ``junk_bytes`` counts every byte not in an accepted frame.  ``counts[reason]``: a
    framing reason (bad_prefix, bad_frame, unknown_msgid, truncated, bad_crc) is counted at
    most once per run of rejected bytes (a run ends at an accepted frame or at the end of
    the input), so it counts damaged places, not candidate start bytes; a whole frame
    refused by the frame check (e.g. a bad signature) is counted every time.
    """

    __slots__ = ("_in_run", "counts", "junk_bytes", "truncated")

    def __init__(self) -> None:
        self.junk_bytes = 0
        self.counts: dict[str, int] = {}
        self.truncated = 0
        self._in_run: set[str] = set()

    def note(self, reason: str) -> None:
        if reason not in self._in_run:
            self._in_run.add(reason)
            self.counts[reason] = self.counts.get(reason, 0) + 1

    def count(self, reason: str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1

    def end_run(self) -> None:
        self._in_run.clear()


class FrameScanner:
    """Splits bytes into CRC-checked frames; keeps the unfinished tail of a byte stream.

    ``crc_extra``: message id -> CRC_EXTRA of every message the reader knows.
    ``max_len``: message id -> its payload length with every extension field (a MAVLink 2
    frame may be longer: a newer sender's extensions are ignored).
    ``v1_lengths``: message id -> bit mask of the payload lengths a MAVLink 1 frame may
    have (it is never truncated); without it, any length up to ``max_len``.
    ``check_frame``: optional further test of a CRC-valid frame (the signature check);
    it returns None to accept or a rejection reason.  A frame it rejects is skipped whole:
    its CRC shows it was sent as one frame, so no frame can start inside it.
    """

    def __init__(self, crc_extra: Mapping[int, int], max_len: Mapping[int, int],
                 check_frame: Callable[[Frame], str | None] | None = None,
                 v1_lengths: Mapping[int, int] | None = None) -> None:
        self.crc_extra = dict(crc_extra)
        self.v1_lengths = ({k: v for k, v in v1_lengths.items() if k in self.crc_extra}
                           if v1_lengths is not None else
                           {k: (2 << v) - 1 for k, v in max_len.items() if k < 256})
        self.check_frame = check_frame
        self._tail = b""

    def reset(self) -> None:
        """Forget an unfinished frame (after a reconnect)."""
        self._tail = b""

    @property
    def pending(self) -> int:
        """Bytes of an unfinished frame kept for the next :meth:`stream` call (< 280)."""
        return len(self._tail)

    def stream(self, data: bytes, rejects: Rejects) -> Iterator[Frame]:
        """Frames completed by ``data`` (a piece of a byte stream: serial, TCP)."""
        buf = self._tail + data if self._tail else bytes(data)
        self._tail = b""
        end = yield from self._scan(buf, False, rejects)
        self._tail = buf[end:]

    def datagram(self, data: bytes, rejects: Rejects) -> Iterator[Frame]:
        """Frames in one datagram; a frame never spans datagrams, so a cut one at the end is
        counted (``rejects.truncated``) and the bytes after its start are still searched."""
        yield from self._scan(bytes(data), True, rejects)

    def whole(self, data: bytes) -> Frame | None:
        """``data`` as one valid frame that fills it exactly (the usual datagram), or None
        (then :meth:`datagram` sorts it out and counts what is wrong).  Counts nothing."""
        n = len(data)
        if n < 8:
            return None
        b0 = data[0]
        if b0 == STX_V2:
            if n < 12 or data[2] & ~IFLAG_SIGNED:
                return None
            hdr, plen, signed = HEADER_V2, data[1], data[2]
            if n != hdr + plen + 2 + (SIGNATURE_LEN if signed else 0):
                return None
            msgid = data[7] | data[8] << 8 | data[9] << 16
        elif b0 == STX_V1:
            hdr, plen, signed, msgid = HEADER_V1, data[1], 0, data[5]
            if n != hdr + plen + 2 or not self.v1_lengths.get(msgid, 0) >> plen & 1:
                return None
        else:
            return None
        extra = self.crc_extra.get(msgid)
        if extra is None:
            return None
        body_end = hdr + plen
        c = binascii.crc_hqx(data[1:body_end].translate(_REV8), 0xFFFF)
        c = binascii.crc_hqx(_REV8[extra:extra + 1], c)
        if (_REV8_HI[c & 0xFF] | _REV8[c >> 8]) != data[body_end] | data[body_end + 1] << 8:
            return None
        data = bytes(data)
        if hdr == HEADER_V2:
            f = Frame(2, msgid, data[5], data[6], data[4], data[hdr:body_end], data,
                      bool(signed))
        else:
            f = Frame(1, msgid, data[3], data[4], data[2], data[hdr:body_end], data, False)
        # A refused frame goes round again through datagram(), which counts it; the check
        # changes no state when it refuses.
        if self.check_frame is not None and self.check_frame(f) is not None:
            return None
        return f

    def _scan(self, buf: bytes, final: bool, rj: Rejects) -> Generator[Frame, None, int]:
        """Yield the frames in ``buf``; return where an unfinished frame starts (``final``:
        there is none, the whole buffer is consumed)."""
        n = len(buf)
        p = 0
        search = _START.search
        crc_table = self.crc_extra
        v1_lens = self.v1_lengths
        check = self.check_frame
        while p < n:
            b0 = buf[p]
            if b0 != STX_V1 and (b0 != STX_V2 or (p + 2 < n and buf[p + 2] & ~IFLAG_SIGNED)):
                m = search(buf, p + 1) if b0 in (STX_V1, STX_V2) else search(buf, p)
                q = n if m is None else m.start()
                rj.junk_bytes += q - p
                rj.note("bad_prefix" if b0 not in (STX_V1, STX_V2) else "bad_frame")
                p = q
                continue
            if b0 == STX_V2:
                hdr = HEADER_V2
                if n - p < hdr:
                    if not final:
                        return p
                    rj.truncated += 1
                    rj.note("truncated")
                    rj.junk_bytes += 1
                    p += 1
                    continue
                plen = buf[p + 1]
                signed = buf[p + 2] & IFLAG_SIGNED
                size = hdr + plen + 2 + (SIGNATURE_LEN if signed else 0)
                msgid = buf[p + 7] | buf[p + 8] << 8 | buf[p + 9] << 16
            else:
                hdr = HEADER_V1
                if n - p < hdr:
                    if not final:
                        return p
                    rj.truncated += 1
                    rj.note("truncated")
                    rj.junk_bytes += 1
                    p += 1
                    continue
                plen = buf[p + 1]
                signed = 0
                size = hdr + plen + 2
                msgid = buf[p + 5]
                # MAVLink 1 is never truncated: a length that is not a field boundary of
                # the message is noise, refused before paying for a checksum.
                if not v1_lens.get(msgid, 0) >> plen & 1:
                    rj.note("bad_frame" if msgid in crc_table else "unknown_msgid")
                    rj.junk_bytes += 1
                    p += 1
                    continue
            extra = crc_table.get(msgid)
            if extra is None:
                rj.note("unknown_msgid")
                rj.junk_bytes += 1
                p += 1
                continue
            if n - p < size:
                if not final:
                    return p
                rj.truncated += 1
                rj.note("truncated")
                rj.junk_bytes += 1
                p += 1
                continue
            body_end = p + hdr + plen
            c = binascii.crc_hqx(buf[p + 1:body_end].translate(_REV8), 0xFFFF)
            c = binascii.crc_hqx(_REV8[extra:extra + 1], c)
            if (_REV8_HI[c & 0xFF] | _REV8[c >> 8]) != buf[body_end] | buf[body_end + 1] << 8:
                rj.note("bad_crc")
                rj.junk_bytes += 1
                p += 1
                continue
            if hdr == HEADER_V2:
                f = Frame(2, msgid, buf[p + 5], buf[p + 6], buf[p + 4],
                          buf[p + hdr:body_end], buf[p:p + size], bool(signed))
            else:
                f = Frame(1, msgid, buf[p + 3], buf[p + 4], buf[p + 2],
                          buf[p + hdr:body_end], buf[p:p + size], False)
            if check is not None:
                why = check(f)
                if why is not None:
                    rj.count(why)
                    rj.junk_bytes += size
                    p += size
                    continue
            rj.end_run()
            p += size
            yield f
        return n
