"""MAVLink 1/2 frames out of bytes, in time linear in the input, CRC checked.

Why not pymavlink's parser: on a rejected frame it re-copies the rest of its buffer and
computes the checksum in Python; one 64 kB datagram of 0xFE cost ~0.5 s (issue 19).  Here
every input byte is examined a bounded number of times:

* junk between frames is skipped with one C-level regular-expression search for the next
  place that could begin a frame: 0xFE with a length some MAVLink 1 message can have and
  the id of a MAVLink 1 message, or 0xFD with no unknown incompatibility flag and the id of
  a known message (or either too close to the end to tell).  FE/FD-dense junk ("FE 01 FD"
  repeated) so costs the C search, not a Python step per start byte; only places that pass
  this filter reach Python, and a rejected one resumes the search one byte on;
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
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping
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


def _byte_class(values: Iterable[int]) -> bytes:
    return b"[" + b"".join(re.escape(bytes((v,))) for v in sorted(set(values))) + b"]"


def _start_pattern(crc_extra: Mapping[int, int], v1_lengths: Mapping[int, int]
                   ) -> re.Pattern[bytes]:
    """Where a frame may start, as one C-level search (see the module docstring).

    MAVLink 1: 0xFE, a payload length, 3 bytes, the id of a message that may have that
    length (one alternative per length, each opening with its length byte, which the
    regular-expression engine tests before entering it; a look-ahead first refuses a length
    no message has).  MAVLink 2: 0xFD, any length, incompatibility flags 0 or "signed", 4
    bytes, then low, middle and high byte of the id each one that some known id has (the
    exact id is looked up in Python).  Start bytes within 9 bytes of the end are not found
    here (:meth:`FrameScanner._scan` looks at those itself)."""
    alts = []
    by_len: dict[int, list[int]] = {}
    for m, mask in v1_lengths.items():
        if 0 <= m < 256:
            for n in range(256):
                if mask >> n & 1:
                    by_len.setdefault(n, []).append(m)
    if by_len:
        alts.append(rb"\xfe(?=" + _byte_class(by_len) + rb")(?:"
                    + b"|".join(re.escape(bytes((n,))) + rb".{3}" + _byte_class(ids)
                                for n, ids in sorted(by_len.items())) + b")")
    ids24 = [m for m in crc_extra if 0 <= m < 1 << 24]
    if ids24:
        alts.append(rb"\xfd.[\x00\x01].{4}" + _byte_class(m & 0xFF for m in ids24)
                    + _byte_class(m >> 8 & 0xFF for m in ids24)
                    + _byte_class(m >> 16 for m in ids24))
    return re.compile(b"|".join(alts) if alts else rb"(?!)", re.DOTALL)


# a start byte: the places near the end of a buffer the start pattern cannot judge
_MARK = re.compile(rb"[\xfd\xfe]")
_NEAR_END = HEADER_V2 - 1  # a start byte closer than this to the end: not judged by _START

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


def _crc_matches(rev: bytes, p: int, body_end: int, rev_extra: bytes) -> bool:
    """Whether the frame at ``p`` carries its checksum, computed in the bit-reversed domain
    (``rev``: the buffer with every byte bit-reversed, ``rev_extra``: the message's
    CRC_EXTRA byte so reversed): there the received CRC (little-endian), reversed byte by
    byte, is the high and low byte of ``crc_hqx``'s result, so no result is reversed back."""
    return (binascii.crc_hqx(rev_extra, binascii.crc_hqx(rev[p + 1:body_end], 0xFFFF))
            == rev[body_end] << 8 | rev[body_end + 1])


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
        self._start = _start_pattern(self.crc_extra, self.v1_lengths)
        # message id -> its CRC_EXTRA bit-reversed, as the one byte the checksum runs over
        self._rev_extra = {k: _REV8[v:v + 1] for k, v in self.crc_extra.items()}
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
        extra = self._rev_extra.get(msgid)
        if extra is None:
            return None
        body_end = hdr + plen
        if not _crc_matches(data.translate(_REV8), 0, body_end, extra):
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

    def is_unsigned_v2(self, data: bytes, msgid: int) -> bool:
        """Whether :meth:`whole` would accept ``data`` as one unsigned MAVLink 2 frame of
        message ``msgid`` (with no frame check configured).  Counts nothing and builds no
        :class:`Frame`: the decoder's per-sample path reads the header bytes itself (issue
        18); when False it goes through :meth:`whole` as before."""
        n = len(data)
        if (n < 12 or data[0] != STX_V2 or data[2] or n != data[1] + HEADER_V2 + 2
                or data[7] | data[8] << 8 | data[9] << 16 != msgid
                or self.check_frame is not None):
            return False
        extra = self._rev_extra.get(msgid)
        if extra is None:
            return False
        return _crc_matches(data.translate(_REV8), 0, n - 2, extra)

    def _skip_reason(self, buf: bytes, p: int) -> str:
        """Why the start byte at ``p`` (at least 9 bytes from the end), passed over by the
        start search, begins no frame."""
        if buf[p] == STX_V2:
            return "bad_frame" if buf[p + 2] & ~IFLAG_SIGNED else "unknown_msgid"
        return "bad_frame" if buf[p + 5] in self.crc_extra else "unknown_msgid"

    def _scan(self, buf: bytes, final: bool, rj: Rejects) -> Generator[Frame, None, int]:
        """Yield the frames in ``buf``; return where an unfinished frame starts (``final``:
        there is none, the whole buffer is consumed)."""
        n = len(buf)
        p = 0
        search = self._start.search
        near_end = n - _NEAR_END
        rev = buf.translate(_REV8)  # the checksum runs on bit-reversed bytes
        rev_extra = self._rev_extra
        v1_lens = self.v1_lengths
        check = self.check_frame
        crc_ok = _crc_matches
        while p < n:
            m = search(buf, p)
            q = n if m is None else m.start()
            if q > near_end:  # a start byte too near the end for the search to judge?
                m = _MARK.search(buf, max(p, near_end))
                if m is not None and m.start() < q:
                    q = m.start()
            if q != p:  # bytes that cannot begin a frame: one run of junk, skipped in C
                rj.junk_bytes += q - p
                b0 = buf[p]
                rj.note("bad_prefix" if b0 != STX_V1 and b0 != STX_V2
                        else self._skip_reason(buf, p))
                p = q
                if p == n:
                    break
            # a place the search let through: decided here, a rejection resumes one byte on
            if buf[p] == STX_V2:
                hdr = HEADER_V2
                if n - p < hdr:  # near the end: the search could not see the header
                    if p + 2 < n and buf[p + 2] & ~IFLAG_SIGNED:
                        rj.note("bad_frame")
                    elif not final:
                        return p
                    else:
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
                    rj.note("bad_frame" if msgid in rev_extra else "unknown_msgid")
                    rj.junk_bytes += 1
                    p += 1
                    continue
            extra = rev_extra.get(msgid)
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
            if not crc_ok(rev, p, body_end, extra):
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
