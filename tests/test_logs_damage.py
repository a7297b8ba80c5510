"""Damaged logs: read up to the damage, say where (byte offset or file:line), and the part
before it still replays to a solution and renders a report."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest
from fixtures.logwriters import Source, source_from_sim, write_dataflash, write_tlog, write_ulog

from navd.cli.replay import main as replay_main
from navd.eval.report import build_report
from navd.io.logs import LogFormatError, read_log

# name -> (file name, writer returning the byte offset of every data record)
BINARY: dict[str, tuple[str, Callable[[Path, Source], list[int]]]] = {
    "ulog": ("run.ulg", write_ulog),
    "dataflash": ("run.bin", write_dataflash),
    "tlog": ("run.tlog", write_tlog),
}


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(20.0)


def _replay_and_report(log: Path, tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    sol, ref, aid = tmp / "sol.csv", tmp / "ref.csv", tmp / "aid.csv"
    assert replay_main(["--log", str(log), "--out", str(sol), "--reference-out", str(ref),
                        "--aiding-out", str(aid), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert sol.read_text().count("\n") > 100  # the part before the damage navigated
    summary = build_report(sol, tmp / "report", ref, aid)
    assert summary["stats_deg"]["yaw"]["n"] > 100
    assert (tmp / "report" / "index.html").is_file()
    return err


@pytest.mark.parametrize("fmt", list(BINARY))
def test_truncated_binary_log(fmt: str, src: Source, tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a ULog, DataFlash or tlog cut in the middle of the record 60 % of the way in,
    WHEN it is read and replayed,
    THEN the damage is at that record's byte offset, "cut short", 50-70 % of the IMU samples
    are read, the part before replays and renders a report, and stderr says
    "damaged at byte <offset>" and "read up to there"."""
    name, writer = BINARY[fmt]
    p = tmp_path / name
    offsets = writer(p, src)
    whole = p.read_bytes()
    k = int(len(offsets) * 0.6)
    cut = offsets[k] + 5  # in the middle of record k
    p.write_bytes(whole[:cut])
    data = read_log(p)
    assert data.damage is not None
    assert (data.damage.unit, data.damage.position) == ("byte", offsets[k])
    assert "cut short" in data.damage.reason
    full = read_log(_rewrite(tmp_path, name, whole))
    assert 0.5 * len(full.imu_t_us) < len(data.imu_t_us) < 0.7 * len(full.imu_t_us)
    err = _replay_and_report(p, tmp_path, capsys)
    assert f"damaged at byte {offsets[k]}" in err and "read up to there" in err


def _rewrite(d: Path, name: str, data: bytes) -> Path:
    q = d / ("whole-" + name)
    q.write_bytes(data)
    return q


@pytest.mark.parametrize("fmt", list(BINARY))
def test_corrupt_binary_log(fmt: str, src: Source, tmp_path: Path,
                            capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a ULog, DataFlash or tlog whose middle record is corrupt (ULog: unknown message
    type; DataFlash: lost header; tlog: a payload byte that fails the CRC),
    WHEN it is read and replayed,
    THEN the damage is at that record's byte offset, the part before replays and renders a
    report, and stderr says "damaged at byte <offset>: <reason>; read up to there"."""
    name, writer = BINARY[fmt]
    p = tmp_path / name
    offsets = writer(p, src)
    buf = bytearray(p.read_bytes())
    k = int(len(offsets) * 0.5)
    o = offsets[k]
    if fmt == "ulog":
        buf[o + 2] = 0x00  # message type byte: no such type
    elif fmt == "dataflash":
        buf[o:o + 2] = b"\x00\x00"  # lost message header
    else:
        buf[o + 8 + 12] ^= 0xFF  # a payload byte: the frame's CRC fails
    p.write_bytes(bytes(buf))
    data = read_log(p)
    assert data.damage is not None, fmt
    assert (data.damage.unit, data.damage.position) == ("byte", o)
    err = _replay_and_report(p, tmp_path, capsys)
    assert re.search(rf"damaged at byte {o}: .+; read up to there", err)


def test_damaged_x8_text(src: Source, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN an X8 IMU.txt with a non-numeric field in line 1201 and cut mid line 1500,
    WHEN it is read and replayed,
    THEN the damage is "not a number" at IMU.txt line 1201, 1199 IMU samples are read, GNSS
    and reference stop at the last good IMU time and stderr names the line;
    with line 1201 repaired, the damage is the short line 1500 (too few columns)."""
    from fixtures.logwriters import write_x8

    d = tmp_path / "x8"
    write_x8(d, src)
    imu = (d / "IMU.txt").read_text().splitlines(keepends=True)
    # a garbage field in line 1201, then the file is cut in the middle of line 1500
    imu[1200] = "12000.000 12000.000 0.1 0.2 0.3 abc 0.5 0.6\n"
    (d / "IMU.txt").write_text("".join(imu[:1499]) + imu[1499][:20])
    data = read_log(d)
    assert data.damage is not None
    assert data.damage.unit == "line" and data.damage.position == 1201
    assert data.damage.path.endswith("IMU.txt") and "not a number" in data.damage.reason
    assert len(data.imu_t_us) == 1199
    # other streams stop at the last good IMU time: no GNSS without IMU
    assert data.gnss_t_us[-1] <= data.imu_t_us[-1]
    assert data.reference.t_us[-1] <= data.imu_t_us[-1]
    err = _replay_and_report(d, tmp_path, capsys)
    assert "IMU.txt: damaged at line 1201" in err
    # cut mid-line only
    imu[1200] = imu[1201]
    (d / "IMU.txt").write_text("".join(imu[:1499]) + imu[1499][:20])
    data = read_log(d)
    assert data.damage is not None and data.damage.position == 1500
    assert "columns" in data.damage.reason


def test_unreadable_starts_are_clear_errors(tmp_path: Path) -> None:
    """GIVEN a ULog shorter than its 16-byte header and a zip with a truncated local header,
    WHEN each is read,
    THEN LogFormatError is raised naming the 16-byte header and the zip respectively."""
    p = tmp_path / "short.ulg"
    p.write_bytes(b"ULog\x01\x12\x35\x01")
    with pytest.raises(LogFormatError, match="16-byte header"):
        read_log(p)
    z = tmp_path / "x8.zip"
    z.write_bytes(b"PK\x03\x04" + b"\x00" * 40)
    with pytest.raises(LogFormatError, match="zip"):
        read_log(z)
