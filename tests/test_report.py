"""``navd report`` renders headless: every PNG the page links exists; statistics are right."""

from __future__ import annotations

import json
import math
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from fixtures.logwriters import Source, source_from_sim, write_ulog, write_x8

from navd.cli.replay import main as replay_main
from navd.cli.report import main as report_main
from navd.eval.evaluate import course_check, error_stats, interpolate_reference, wrap_deg
from navd.eval.report import build_report
from navd.eval.tables import RefSeries


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "img" and a.get("src"):
            self.images.append(str(a["src"]))
        if tag == "a" and a.get("href"):
            self.links.append(str(a["href"]))


def _linked_files(index: Path) -> list[str]:
    p = _Links()
    p.feed(index.read_text())
    return p.images + [h for h in p.links if h.endswith(".png")]


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(20.0)


@pytest.fixture(scope="module")
def replayed(src: Source, tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("rep")
    write_x8(d / "x8", src)
    assert replay_main(["--log", str(d / "x8"), "--out", str(d / "sol.csv"), "--reference-out",
                        str(d / "ref.csv"), "--aiding-out", str(d / "aid.csv"), "--quiet"]) == 0
    return d


def test_report_renders_and_every_png_exists(replayed: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    d = replayed
    out = d / "report"
    assert report_main(["--solution", str(d / "sol.csv"), "--reference", str(d / "ref.csv"),
                        "--aiding", str(d / "aid.csv"), "--out", str(out), "--segment-s", "5",
                        "--quiet"]) == 0
    assert "yaw" in capsys.readouterr().err
    files = _linked_files(out / "index.html")
    assert {"attitude.png", "error.png", "heading.png", "innovations.png", "bias.png",
            "track.png"} <= set(files)
    for f in files:
        assert (out / f).is_file() and (out / f).stat().st_size > 5000, f
        assert (out / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    s = json.loads((out / "summary.json").read_text())
    # the fixture's reference is the simulated truth: the filter agrees with it closely
    for axis in ("roll", "pitch", "yaw", "angle"):
        st = s["stats_deg"][axis]
        assert st["n"] > 500 and st["p50"] <= st["p90"] <= st["p99"] <= st["max"]
        assert st["rms"] < 1.0, (axis, st)
    assert len(s["segments"]) == 4  # ~19 s of solution in 5 s segments
    assert sum(sg["course_used"] for sg in s["segments"]) > 150
    html = (out / "index.html").read_text()
    assert "course_accepted" in html and "p99" in html


def test_report_with_a_log_as_reference_and_no_aiding(src: Source, replayed: Path,
                                                      tmp_path: Path) -> None:
    ulg = tmp_path / "run.ulg"
    write_ulog(ulg, src)
    s = build_report(replayed / "sol.csv", tmp_path / "r", reference=ulg,
                     stats_from_s=10.0, segment_s=0, log=replayed / "x8")
    assert s["figures"] == ["attitude.png", "error.png", "heading.png", "track.png"]
    for f in _linked_files(tmp_path / "r" / "index.html"):
        assert (tmp_path / "r" / f).is_file()
    assert s["stats_deg"]["yaw"]["rms"] < 1.0 and s["segments"] == []
    assert "vehicle_attitude" in s["inputs"]["reference"]
    # the gyro check: the fixture's reference is the simulated truth, which these MEMS-grade
    # gyros integrate to within their noise; navd adds its (early, converging) corrections
    g_navd = s["checks"]["navd"]["gyro"]
    g_ref = s["checks"]["reference"]["gyro"]
    assert g_navd["windows"] >= 9 and max(g_navd["rms_deg"]) < 0.5
    assert max(g_ref["rms_deg"]) < 0.02
    # no reference at all: attitude, heading and track only
    s = build_report(replayed / "sol.csv", tmp_path / "n")
    assert s["stats_deg"] == {} and "error.png" not in s["figures"]


def test_report_bad_inputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert report_main(["--solution", str(tmp_path / "nope.csv"), "--out",
                        str(tmp_path / "o"), "--quiet"]) == 2
    assert "no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("t_us,roll_deg\n1,2\n")
    assert report_main(["--solution", str(bad), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert re.search(r"missing column\(s\) pitch_deg", capsys.readouterr().err)


def test_reference_interpolation_across_the_yaw_wrap() -> None:
    ref = RefSeries(np.array([0.0, 1e6, 2e6, 5e6]),
                    np.array([[0.0, 0.0, 178.0], [0.0, 0.0, -178.0], [10.0, 0.0, -170.0],
                              [10.0, 0.0, -170.0]]), "t")
    e, q = interpolate_reference(ref, np.array([-1.0, 0.5e6, 1.5e6, 3e6, 5e6]), 2.0)
    assert np.all(np.isnan(e[0]))  # before the reference starts
    assert abs(wrap_deg(np.array([e[1, 2] - 180.0]))[0]) < 1e-9  # 178 -> -178 passes 180
    assert e[2, 0] == pytest.approx(5.0, abs=0.05) and e[2, 2] == pytest.approx(-174, abs=0.1)
    assert np.all(np.isnan(e[3]))  # inside a 3 s gap, longer than 2 s
    assert e[4, 0] == pytest.approx(10.0)
    assert np.allclose(np.linalg.norm(q[[1, 2, 4]], axis=1), 1.0)


def test_course_check_finds_a_once_per_revolution_crab() -> None:
    """A steady wind gives yaw - course = asin(w/V) sin(course - wind dir): the fit finds it."""
    chi = np.linspace(-180.0, 180.0, 181, endpoint=False)
    crab = 12.0 * np.sin(np.radians(chi - 30.0))
    t = np.arange(len(chi)) * 2e5
    aid = {"t_us": t, "speed_mps": np.full(len(t), 15.0), "course_deg": chi}
    ser = RefSeries(t, np.column_stack([np.zeros(len(t)), np.zeros(len(t)),
                                        wrap_deg(chi + crab)]), "s")
    c = course_check(aid, ser, 0.0)
    assert c["n"] == len(chi)
    assert c["amp_deg"] == pytest.approx(12.0, abs=0.05) and c["fit_resid_rms_deg"] < 0.1


def test_error_stats_and_wrap() -> None:
    assert np.allclose(wrap_deg(np.array([190.0, -190.0, 180.0, 0.0])), [-170, 170, 180, 0])
    s = error_stats(np.array([-3.0, 4.0, math.nan]))
    assert s["n"] == 2 and s["max"] == 4.0 and s["rms"] == pytest.approx(math.sqrt(12.5))
