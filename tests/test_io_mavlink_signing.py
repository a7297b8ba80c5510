"""MAVLink 2 signing (issue 19 item 2): with a key, only frames signed with it are taken;
junk, foreign-key and replayed signatures are refused and counted; frames pymavlink signs
pass."""

from __future__ import annotations

from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from navd.config.load import ConfigError
from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig
from navd.io.mavlink.signing import load_signing_key

KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))
T0 = 300_000_000_000  # signing time (10 us units since 2015): some 95 days in


def signer(key: bytes = KEY, link_id: int = 0, t: int = T0, sysid: int = 1) -> mav.MAVLink:
    enc = mav.MAVLink(None, sysid, 1)
    enc.signing.secret_key = key
    enc.signing.sign_outgoing = True
    enc.signing.link_id = link_id
    enc.signing.timestamp = t
    return enc


def fix(enc: mav.MAVLink, t_us: int, *, v1: bool = False) -> bytes:
    """A GPS_INPUT frame; pymavlink signs it when ``enc`` signs (and advances its time)."""
    m = enc.gps_input_encode(t_us, 0, 0, 0, 0, 3, 473977000, 85456000, 400.0, 1.0, 1.0,
                             1.0, 2.0, 0.5, 0.3, 1.0, 2.0, 9)
    frame: bytes = m.pack(enc, force_mavlink1=v1)
    enc.seq = (enc.seq + 1) & 0xFF
    return frame


def decoder(**kw: object) -> MavlinkDecoder:
    base: dict[str, object] = {"signing_key": KEY}
    base.update(kw)
    return MavlinkDecoder(MavlinkInputConfig(**base))  # type: ignore[arg-type]


def times(dec: MavlinkDecoder, frames: list[bytes]) -> list[int]:
    return [s.t_us for f in frames for s in dec.feed_datagram(f, 0)]


def test_pymavlink_signed_frames_pass_and_junk_signatures_do_not() -> None:
    """GIVEN frames pymavlink signed with the key, and copies with a flipped signature
    byte, a random signature block, or signed with another key,
    WHEN a decoder holding the key reads them,
    THEN exactly the correctly signed fixes come out and each other frame counts once as
    ``bad_signature``."""
    enc = signer()
    good = [fix(enc, 1000 + i) for i in range(5)]
    assert all(f[2] & 0x01 for f in good)  # signed
    flipped = bytearray(fix(enc, 2000))
    flipped[-1] ^= 0x01
    junk_block = fix(enc, 2001)[:-13] + bytes.fromhex("00" + "ffeeddccbbaa" + "0123456789ab")
    foreign = fix(signer(OTHER_KEY, t=T0 + 50), 2002)
    dec = decoder()
    assert times(dec, [good[0], bytes(flipped), good[1], junk_block, good[2], foreign,
                       good[3], good[4]]) == [1000, 1001, 1002, 1003, 1004]
    assert dec.counters["bad_signature"] == 3


def test_replayed_and_stale_signed_frames_are_refused() -> None:
    """GIVEN a stream of signed frames, one of them sent again later, and a second link id
    that starts more than a minute behind the newest time seen,
    WHEN they are decoded with the key,
    THEN the replay counts ``signature_replay``, the stale stream ``signature_stale``, a
    fresh second stream is accepted, and no refused frame yields a fix."""
    enc = signer()
    frames = [fix(enc, 10 + i) for i in range(3)]
    dec = decoder()
    assert times(dec, [*frames, frames[1]]) == [10, 11, 12]
    assert dec.counters["signature_replay"] == 1
    stale = fix(signer(link_id=1, t=T0 - 61 * 100_000), 20)
    fresh = fix(signer(link_id=2, t=T0 - 30 * 100_000), 21)
    assert times(dec, [stale, fresh]) == [21]
    assert dec.counters["signature_stale"] == 1


def test_unsigned_frames_need_accept_unsigned() -> None:
    """GIVEN an unsigned MAVLink 2 fix and a MAVLink 1 fix (which cannot be signed),
    WHEN decoded with a key, first without then with ``accept_unsigned``,
    THEN both are refused (counted ``unsigned``), then both accepted."""
    plain = mav.MAVLink(None, 1, 1)
    frames = [fix(plain, 1), fix(plain, 2, v1=True)]
    dec = decoder()
    assert times(dec, frames) == []
    assert dec.counters["unsigned"] == 2
    assert times(decoder(accept_unsigned=True), frames) == [1, 2]


def test_signed_frames_in_a_byte_stream_are_checked_too() -> None:
    """GIVEN a byte stream of signed fixes with a junk-signed one between them,
    WHEN it is fed in 7-byte pieces to a decoder holding the key,
    THEN the good fixes come out in order and the junk one is counted once."""
    enc = signer()
    bad = bytearray(fix(enc, 50))
    bad[-3] ^= 0xFF
    blob = fix(enc, 49) + bytes(bad) + fix(enc, 51)
    dec = decoder()
    got = [s.t_us for i in range(0, len(blob), 7) for s in dec.feed(blob[i:i + 7], 0)]
    assert got == [49, 51]
    assert dec.counters["bad_signature"] == 1


def test_key_file_raw_or_hex_and_config_errors(tmp_path: Path) -> None:
    """GIVEN key files of 32 raw bytes, of 64 hex digits, and of the wrong size,
    WHEN loaded directly and through ``[mavlink] signing_key_file``,
    THEN the first two give the key, the third is refused with a message naming the key
    file setting, and a daemon built from the config checks signatures."""
    from navd.config.daemon import load_daemon_config
    from navd.daemon.adapters import mavlink_input_config

    raw, hexf, bad = tmp_path / "raw.key", tmp_path / "hex.key", tmp_path / "bad.key"
    raw.write_bytes(KEY)
    hexf.write_text(KEY.hex() + "\n")
    bad.write_bytes(b"0123")
    for p in (raw, hexf):
        p.chmod(0o600)
        assert load_signing_key(p) == KEY
    with pytest.raises(ValueError, match="32 raw bytes or 64 hex"):
        load_signing_key(bad)
    with pytest.raises(ConfigError, match="signing_key_file"):
        load_daemon_config(None, [f'mavlink.signing_key_file="{bad}"'])
    with pytest.raises(ConfigError, match="signing_key_file"):
        load_daemon_config(None, [f'mavlink.signing_key_file="{tmp_path / "missing"}"'])
    dc = load_daemon_config(None, [f'mavlink.signing_key_file="{hexf}"'])
    dec = MavlinkDecoder(mavlink_input_config(dc.mavlink))
    enc = signer()
    junk = bytearray(fix(enc, 8))
    junk[-2] ^= 0x10
    out = dec.feed_datagram(fix(enc, 7), 0) + dec.feed_datagram(bytes(junk), 0)
    assert [s.t_us for s in out] == [7] and dec.counters["bad_signature"] == 1
