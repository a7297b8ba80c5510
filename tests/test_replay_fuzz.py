"""Replay robustness (issue 19 items 3 and 7): one wild CSV time stamp costs one row, too many
skipped rows is an error, and damaged inputs (recordings, CSVs) give one clear line, exit 2
and leave no half-written ``.part`` behind."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import numpy as np
import pytest
from fixtures.logwriters import Source, source_from_sim, write_rate_csv

from navd.cli.replay import main as replay_main
from navd.io.csv_replay import GNSS_COLS, ReadReport, read_imu
from navd.io.recording import RecordingWriter
from navd.types import ImuSample


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(8.0)


def _gnss_csv(src: Source, path: Path) -> None:
    with open(path, "w") as fh:
        fh.write(",".join(GNSS_COLS) + "\n")
        for g in src.gnss:
            fh.write(f"{g.t_us},{np.degrees(g.lat_rad):.10f},{np.degrees(g.lon_rad):.10f},"
                     f"{g.alt_m},{g.vel_n},{g.vel_e},{g.vel_d},{g.h_acc_m},{g.v_acc_m},"
                     f"{g.vel_acc_mps}\n")


def _replay(d: Path, imu: Path, gnss: Path, *extra: str) -> tuple[int, Path]:
    out = d / "sol.csv"
    rc = replay_main(["--imu", str(imu), "--gnss", str(gnss), "--out", str(out), "--quiet",
                      *extra])
    return rc, out


def _rows(path: Path) -> int:
    return sum(1 for _ in open(path)) - 1


@pytest.mark.parametrize("wild", [2**63 + 5, 3_600_000_000, -5, 0])
def test_one_wild_csv_time_stamp_costs_one_row(src: Source, tmp_path: Path, wild: int,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN an 8 s rate CSV whose row 400 has t_us = 2**63+5 (or +1 h, negative, 0),
    WHEN it is read and replayed,
    THEN exactly that row is skipped, the replay equals the clean one but for the solution
    rows that row's interval feeds, and it exits 0."""
    t = src.imu_t_us
    clean, dirty, gnss = tmp_path / "clean.csv", tmp_path / "dirty.csv", tmp_path / "g.csv"
    write_rate_csv(src, clean)
    k = 400
    t_wild = int(t[k]) + wild if wild == 3_600_000_000 else wild
    lines = clean.read_text().splitlines(keepends=True)
    lines[k + 1] = f"{t_wild},{lines[k + 1].split(',', 1)[1]}"
    dirty.write_text("".join(lines))
    _gnss_csv(src, gnss)
    rep = ReadReport()
    n = sum(1 for _ in read_imu(dirty, rep))
    assert len(rep.issues) == 1 and rep.issues[0].line == k + 2, rep.issues[:3]
    assert n == len(t) - 2  # the first row starts the clock; the wild row is gone
    rc0, out0 = _replay(tmp_path, clean, gnss)
    rows0 = _rows(out0)
    rc, out = _replay(tmp_path, dirty, gnss)
    err = capsys.readouterr().err
    assert rc0 == 0 and rc == 0, err
    assert abs(_rows(out) - rows0) <= 1, err


def test_a_real_jump_is_kept(tmp_path: Path) -> None:
    """GIVEN a GNSS CSV with a 60 s outage (every row after it 60 s later),
    WHEN it is read,
    THEN no row is skipped."""
    p = tmp_path / "g.csv"
    rows = [",".join(GNSS_COLS)]
    for k in range(20):
        t = k * 1_000_000 + (60_000_000 if k >= 10 else 0)
        rows.append(f"{t},45,7,100,1,0,0,2,3,0.1")
    p.write_text("\n".join(rows) + "\n")
    from navd.io.csv_replay import read_gnss

    rep = ReadReport()
    got = [g.t_us for g in read_gnss(p, rep)]
    assert not rep.issues and len(got) == 20 and got == sorted(got)


def test_too_many_skipped_rows_exit_nonzero(src: Source, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a rate CSV with 2 % of its rows duplicated in time,
    WHEN it is replayed with the default --max-skipped (1 %), then with --max-skipped 5,
    THEN the first exits 1 naming --max-skipped (the output is still written), the second 0."""
    imu, gnss = tmp_path / "imu.csv", tmp_path / "g.csv"
    t = src.imu_t_us.copy()
    bad = np.arange(5, len(t), 50)  # 2 %
    t[bad] = t[bad - 1]
    write_rate_csv(src, imu, t)
    _gnss_csv(src, gnss)
    rc, out = _replay(tmp_path, imu, gnss)
    err = capsys.readouterr().err
    assert rc == 1 and "--max-skipped" in err and out.exists(), err
    rc, _ = _replay(tmp_path, imu, gnss, "--max-skipped", "5")
    assert rc == 0, capsys.readouterr().err


@pytest.mark.parametrize("damage", ["huge_field", "not_utf8"])
def test_damaged_csv_is_a_clear_error(src: Source, tmp_path: Path, damage: str,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a rate CSV with a 200,000-character field, or with bytes that are not UTF-8,
    WHEN it is replayed,
    THEN replay exits 2 with one line naming the file, and leaves neither output nor .part."""
    imu, gnss = tmp_path / "imu.csv", tmp_path / "g.csv"
    write_rate_csv(src, imu)
    _gnss_csv(src, gnss)
    data = imu.read_bytes().splitlines(keepends=True)
    data[300] = (b"1," + b"9" * 200_000 + b",0,0,0,0,0\n" if damage == "huge_field"
                 else b"\xff\xfe\x00\x93,1,2,3,4,5,6\n")
    imu.write_bytes(b"".join(data))
    rc, out = _replay(tmp_path, imu, gnss)
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err and str(imu) in err, err
    assert not out.exists() and not list(tmp_path.glob("*.part"))


def _recording(path: Path, src: Source) -> None:
    w = RecordingWriter(path, {}, 50.0)
    gi = 0
    for k in range(len(src.imu_t_us)):
        t, dt = int(src.imu_t_us[k]), int(src.dt_us[k])
        g, a = src.gyro[k] * dt * 1e-6, src.accel[k] * dt * 1e-6
        w.write(ImuSample(t, dt, *g, *a))
        while gi < len(src.gnss) and src.gnss[gi].t_us <= t:
            w.write(src.gnss[gi])
            gi += 1
    w.close()


def test_recording_with_a_bad_fix_type_is_a_clear_error(
        src: Source, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a recording whose first GNSS record has fix type byte 223,
    WHEN it is replayed,
    THEN replay exits 2 saying "fix type 223", with no traceback, no output and no .part."""
    rec = tmp_path / "r.navdrec"
    _recording(rec, src)
    data = bytearray(rec.read_bytes())
    g = src.gnss[0]
    t = struct.pack("<q", g.t_us)
    off = data.index(b"G" + t)
    data[off + 1 + struct.calcsize("<q9d")] = 223
    rec.write_bytes(bytes(data))
    out = tmp_path / "s.csv"
    rc = replay_main(["--recording", str(rec), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "fix type 223" in err and "Traceback" not in err, err
    assert not out.exists() and not list(tmp_path.glob("*.part"))


def test_fuzz_mutated_recordings(src: Source, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN 150 copies of a 3 s recording, each with 1-8 random bytes changed, inserted or
    deleted, or cut short (seeded),
    WHEN each is replayed,
    THEN none raises: each exits 0, 1 (no solution) or 2 (damaged, one line), no .part is
    left, and a failure leaves no output file."""
    short = Source(src.imu_t_us[:300], src.dt_us[:300], src.gyro[:300], src.accel[:300],
                   [g for g in src.gnss if g.t_us <= src.imu_t_us[299]], src.ref_t_us,
                   src.ref_euler)
    base = tmp_path / "base.navdrec"
    _recording(base, short)
    clean = base.read_bytes()
    rng = random.Random(19)
    codes: dict[int, int] = {}
    for case in range(150):
        d = bytearray(clean)
        for _ in range(rng.randint(1, 8)):
            op = rng.random()
            i = rng.randrange(len(d))
            if op < 0.6:
                d[i] = rng.randrange(256)
            elif op < 0.8:
                d.insert(i, rng.randrange(256))
            elif op < 0.95:
                del d[i]
            else:
                del d[i:]
                break
        rec = tmp_path / f"m{case}.navdrec"
        rec.write_bytes(bytes(d))
        out = tmp_path / f"m{case}.csv"
        rc = replay_main(["--recording", str(rec), "--out", str(out)])
        err = capsys.readouterr().err
        assert rc in (0, 1, 2), (case, rc, err)
        assert "Traceback" not in err
        assert not list(tmp_path.glob("*.part")), case
        if rc != 0:
            assert not out.exists() or rc == 1, (case, err)
        codes[rc] = codes.get(rc, 0) + 1
    # the mutations reach both outcomes: damage found, and damage the replay survives
    assert codes.get(2, 0) >= 10 and codes.get(0, 0) >= 10, codes



def test_fuzz_mutated_replay_csvs(src: Source, tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN 60 copies of a 3 s IMU + GNSS replay CSV pair, one of the two files with 1-8
    random bytes changed, inserted or deleted, or cut short (seeded),
    WHEN each pair is replayed,
    THEN none raises: each exits 0, 1 (no solution, or more than --max-skipped rows
    skipped) or 2 (not a CSV / not UTF-8 / a column missing, one line), and no .part is
    left."""
    short = Source(src.imu_t_us[:300], src.dt_us[:300], src.gyro[:300], src.accel[:300],
                   [g for g in src.gnss if g.t_us <= src.imu_t_us[299]], src.ref_t_us,
                   src.ref_euler)
    imu0, gnss0 = tmp_path / "imu0.csv", tmp_path / "gnss0.csv"
    write_rate_csv(short, imu0)
    _gnss_csv(short, gnss0)
    clean = {"imu": imu0.read_bytes(), "gnss": gnss0.read_bytes()}
    rng = random.Random(7)
    codes: dict[int, int] = {}
    for case in range(60):
        which = rng.choice(["imu", "gnss"])
        d = bytearray(clean[which])
        for _ in range(rng.randint(1, 8)):
            op = rng.random()
            i = rng.randrange(len(d))
            if op < 0.6:
                d[i] = rng.choice([rng.randrange(256), ord(","), ord("\n"), ord('"'), 0xFF])
            elif op < 0.8:
                d.insert(i, rng.randrange(256))
            elif op < 0.95:
                del d[i]
            else:
                del d[i:]
                break
        imu, gnss = tmp_path / f"imu{case}.csv", tmp_path / f"gnss{case}.csv"
        imu.write_bytes(bytes(d) if which == "imu" else clean["imu"])
        gnss.write_bytes(bytes(d) if which == "gnss" else clean["gnss"])
        out = tmp_path / f"s{case}.csv"
        rc = replay_main(["--imu", str(imu), "--gnss", str(gnss), "--out", str(out),
                          "--quiet"])
        err = capsys.readouterr().err
        assert rc in (0, 1, 2), (case, rc, err)
        assert "Traceback" not in err
        assert not list(tmp_path.glob("*.part")), case
        codes[rc] = codes.get(rc, 0) + 1
    assert codes.get(0, 0) >= 10, codes
