"""Command-line help and documentation a new user reads first (issue 16 item 9)."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest

import navd
from firmware_sim.__main__ import main as sim_main
from navd.__main__ import main as navd_main
from navd.cli import demo, replay, report

ROOT = Path(__file__).resolve().parents[1]

# reStructuredText and Python names mean nothing on a terminal
_RST = re.compile(r"``|:mod:|:func:|:class:|navd\.(eval|io|core|cli)\.|SOLUTION_COLS")


def _help(main: Callable[[list[str]], int], argv: list[str],
          capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    out: str = capsys.readouterr().out
    return out


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the navd command,
    WHEN it is run with --version, -V or --help,
    THEN --version prints "navd <version>", -V also exits 0, and the help lists --version."""
    assert navd_main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"navd {navd.__version__}"
    assert navd_main(["-V"]) == 0
    assert "--version" in (navd_main(["--help"]), capsys.readouterr().out)[1]


def _description(text: str) -> str:
    """The help text between the usage block and the first option group."""
    return text.split("\n\n", 2)[1]


def test_demo_help_is_whole_sentences(capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the navd demo command,
    WHEN its --help is printed,
    THEN the description ends with a full stop (not cut at the docstring's first line), has no
    reST markup or internal names, and mentions real time and --duration."""
    text = _help(demo.main, ["--help"], capsys)
    desc = " ".join(_description(text).split())
    assert desc.endswith("."), desc          # not cut at the docstring's first line
    assert not _RST.search(text), text
    assert "real time" in text and "--duration" in text


def test_report_help_has_no_rst_or_internal_names(capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the navd report command,
    WHEN its --help is printed,
    THEN it has no reST markup or internal names, and mentions navd replay and --reference-out."""
    text = _help(report.main, ["--help"], capsys)
    assert not _RST.search(text), text
    assert "navd replay" in text and "--reference-out" in text


def test_replay_help_says_which_input_is_required(capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the navd replay command,
    WHEN its --help is printed,
    THEN it has no reST markup and says one of --imu/--gnss, --recording or --log is required."""
    text = _help(replay.main, ["--help"], capsys)
    assert not _RST.search(text), text
    flat = " ".join(text.split())
    assert re.search(r"one of .*--imu.*--gnss.*--recording.*--log.* is required", flat), flat


def test_replay_without_input_names_all_three(capsys: pytest.CaptureFixture[str],
                                              tmp_path: Path) -> None:
    """GIVEN navd replay given only --out,
    WHEN it runs,
    THEN it exits with code 2 and the error names all three inputs: --imu and --gnss,
    --recording, --log."""
    with pytest.raises(SystemExit) as exc:
        replay.main(["--out", str(tmp_path / "s.csv")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--imu and --gnss" in err and "--recording" in err and "--log" in err


def test_stream_help_has_description_and_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the firmware_sim stream subcommand,
    WHEN its --help is printed,
    THEN it has a description mentioning MAVLink, shows the real defaults (address, message
    names, CAN channel, node ID 42) and never "(default: None)" or "(default: False)"."""
    text = _help(sim_main, ["stream", "--help"], capsys)
    desc = _description(text)
    text = " ".join(text.split())
    assert not desc.startswith("options"), text
    assert "MAVLink" in desc
    for default in ("udp:127.0.0.1:14560", "HIGHRES_IMU", "GPS_INPUT", "vcan0", "42"):
        assert f"(default: {default})" in text, (default, text)
    assert "(default: None)" not in text and "(default: False)" not in text


def test_readme_documents_commands() -> None:
    """GIVEN README.md,
    WHEN it is read,
    THEN its first shell block has make run and make test, it says the run is 480 s in real
    time, and it mentions navd report, --log and navd dov-grid."""
    readme = (ROOT / "README.md").read_text()
    first = readme.split("```sh", 1)[1].split("```", 1)[0]
    assert "make run" in first and "make test" in first
    # `make run` plays the whole car480 drive in real time: say how long
    assert re.search(r"480 s", readme) and "real time" in readme
    for cmd in ("navd report", "--log", "navd dov-grid"):
        assert cmd in readme, cmd


def test_replay_format_lists_log_formats() -> None:
    """GIVEN docs/replay-format.md,
    WHEN its "## Flight logs" section is read,
    THEN it names every format in navd.io.logs.FORMATS and mentions ULog, DataFlash, tlog and X8."""
    doc = (ROOT / "docs" / "replay-format.md").read_text()
    from navd.io.logs import FORMATS
    section = doc.split("## Flight logs", 1)
    assert len(section) == 2, "docs/replay-format.md has no '## Flight logs' section"
    for fmt in FORMATS:
        assert f"`{fmt}`" in section[1], fmt
    for word in ("ULog", "DataFlash", "tlog", "X8"):
        assert word in section[1], word


def test_firmware_sim_help_is_plain(capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the firmware-sim command,
    WHEN its top-level --help is printed,
    THEN it has no reST markup (it showed ``firmware-sim``) and names its three commands."""
    text = _help(sim_main, ["--help"], capsys)
    assert not _RST.search(text), text
    desc = " ".join(_description(text).split())
    assert all(w in desc for w in ("generate", "list", "stream")), desc


def test_report_help_shows_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the navd report command,
    WHEN its --help is printed,
    THEN the options with a default say it: --segment-s 30, --max-ref-gap-s 1, and what
    --stats-from-s, --reference and --title do when not given."""
    flat = " ".join(_help(report.main, ["--help"], capsys).split())
    assert "(0: none; default 30.0)" in flat and "(default 1.0)" in flat, flat
    assert "default: from the first row" in flat, flat
    assert "default: the --log's onboard attitude" in flat, flat
    assert "default: navd report: <solution file name>" in flat, flat


def test_log_help_and_format_doc_name_the_inertialnav_quads(
        capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN navd replay --help and docs/replay-format.md,
    WHEN --log's help and the `x8` row of the log table are read,
    THEN both name the InertialNav quad layouts (f450_glitch, quad123) besides the X8, and
    the help says the profile follows the log's vehicle type and the RMS is printed."""
    flat = " ".join(_help(replay.main, ["--help"], capsys).split())
    log_help = flat.rsplit("--log FILE", 1)[1].split("--format", 1)[0]  # not the usage
    for word in ("X8", "f450_glitch", "quad123", "vehicle type", "RMS"):
        assert word in log_help, (word, log_help)
    doc = (ROOT / "docs" / "replay-format.md").read_text()
    row = next(ln for ln in doc.splitlines() if ln.startswith("| `x8` |"))
    for word in ("X8", "f450_glitch_log.zip", "quad123.zip", "GPS.txt"):
        assert word in row, (word, row)
