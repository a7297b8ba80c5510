"""The yaw-bank benchmark's scoring (benchmarks/yaw_bank.py): figures and verdicts against a
hand computation on synthetic seeds, the manoeuvre-onset rules, and one short end-to-end run."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario


@pytest.fixture(scope="module")
def b() -> ModuleType:
    return load_benchmark("yaw_bank")


def _seed(b: ModuleType, seed: int, t_man: float, t_al: float, err: list[float],
          sd: list[float], n: int, rp: list[float]) -> object:
    return b.SeedResult("multirotor_manoeuvre", seed, t_man, t_al, np.array(err), np.array(sd),
                        n, np.array(rp))


def test_figures_match_a_hand_computation(b: ModuleType) -> None:
    """GIVEN three synthetic seeds: A aligned 5 s after its first manoeuvre with aligned
    heading errors 1, -2, 12 deg (sigmas 1, 1, 5), B never aligned, C aligned 5 s *before* its
    manoeuvre with errors 3, 4 deg (sigmas 0.5, 2),
    WHEN scenario_figures reduces them,
    THEN (by hand) delays are median 0 s and max 5 s, 1 never and 1 early, the pooled heading
    RMS is sqrt(174 / 5) = 5.899 deg, 1 of 5 aligned instants is beyond 3 sigma (20 %),
    1 false alignment (A's 12 deg), roll / pitch RMS sqrt(20/40) and sqrt(10/40), and
    every multirotor target is a MISS."""
    seeds = [_seed(b, 1, 30.0, 35.0, [1.0, -2.0, 12.0], [1.0, 1.0, 5.0], 10, [4.0, 9.0]),
             _seed(b, 2, 30.0, math.nan, [], [], 10, [0.0, 0.0]),
             _seed(b, 3, 20.0, 15.0, [3.0, 4.0], [0.5, 2.0], 20, [16.0, 1.0])]
    sc = b.SCENARIOS[0]
    rec = b.scenario_figures(seeds, sc)
    assert rec["seeds"] == 3
    assert rec["aligned_seeds"] == 2 and rec["never_aligned"] == 1
    assert rec["aligned_before_manoeuvre"] == 1
    assert rec["delay_median_s"] == pytest.approx(0.0)
    assert rec["delay_max_s"] == pytest.approx(5.0)
    assert rec["heading_rms_aligned_deg"] == pytest.approx(math.sqrt(174.0 / 5.0))
    assert rec["aligned_instants"] == 5
    assert rec["exceed3_pct"] == pytest.approx(20.0)
    assert rec["false_alignments"] == 1
    assert rec["roll_rms_deg"] == pytest.approx(math.sqrt(0.5))
    assert rec["pitch_rms_deg"] == pytest.approx(0.5)
    assert [t["ok"] for t in rec["targets"]] == [False, False, False, False]
    lines = b.format_targets([rec])
    assert sum(line.endswith("MISS") for line in lines) == 4
    assert "5.90" in b.format_row(rec)


def test_targets_pass_and_fail_at_their_limits(b: ModuleType) -> None:
    """GIVEN seeds that all align 9.9 s after the manoeuvre with errors within 1.9 deg and
    inside 3 sigma, then the same with one seed at 10.1 s, then a hover scenario where one seed
    aligned,
    WHEN the targets are judged,
    THEN the first passes all four, the second misses only the time target, the hover one
    misses 'never aligned' while a clean hover passes."""
    good = [_seed(b, k, 10.0, 19.9, [1.9, -1.9], [1.0, 1.0], 4, [0.0, 0.0]) for k in (1, 2)]
    sc = b.SCENARIOS[0]
    assert all(t["ok"] for t in b.scenario_figures(good, sc)["targets"])
    late = [*good, _seed(b, 3, 10.0, 20.1, [0.5], [1.0], 4, [0.0, 0.0])]
    oks = [t["ok"] for t in b.scenario_figures(late, sc)["targets"]]
    assert oks == [False, True, True, True]
    hover = next(s for s in b.SCENARIOS if not s.observable)
    clean = [_seed(b, 1, math.nan, math.nan, [], [], 4, [0.0, 0.0])]
    rec = b.scenario_figures(clean, hover)
    assert all(t["ok"] for t in rec["targets"]) and len(rec["targets"]) == 2
    bad = [*clean, _seed(b, 2, math.nan, 50.0, [2.0], [5.0], 4, [0.0, 0.0])]
    assert not b.scenario_figures(bad, hover)["targets"][0]["ok"]


def test_first_manoeuvre_time_is_the_analytic_one(b: ModuleType) -> None:
    """GIVEN multirotor_manoeuvre, whose first leg accelerates 0 -> 5 m/s over 5 s from 30 s
    (a(t) = 1 - cos(2 pi u) m/s^2, u = (t - 30) / 5),
    WHEN first_manoeuvre_s looks for the first horizontal acceleration >= 1 m/s^2,
    THEN it is at u = 1/4, i.e. 31.25 s (within one IMU interval), whatever leg direction the
    seed drew; with a threshold of 3 m/s^2 (above every peak) it is NaN."""
    sc = load_scenario("multirotor_manoeuvre", {"duration_s": 40.0})
    for seed in (1, 2):
        run = generate(sc, seed=seed)
        assert b.first_manoeuvre_s(run) == pytest.approx(31.25, abs=0.006)
        assert math.isnan(b.first_manoeuvre_s(run, 3.0))


def test_gnss_manoeuvre_onset(b: ModuleType) -> None:
    """GIVEN 5 Hz GNSS velocity at rest, then a 2 m/s^2 ramp east from 10 s,
    WHEN gnss_manoeuvre_s differences it over 1 s,
    THEN the onset is the first baseline whose average acceleration reaches 1 m/s^2 (the
    ramp is 2 m/s^2 from 10 s, so the 1 s baseline 9.6-10.6 s averages 1.2: midpoint 10.1 s);
    starting the search at 12 s returns the first baseline midpoint at or after it (12.1 s:
    baselines start on the 0.2 s grid, so midpoints fall on odd tenths); no acceleration
    returns -1."""
    t = np.arange(0, 20_000_000, 200_000, dtype=np.int64)
    ts = t * 1e-6
    v = np.zeros((t.size, 2))
    v[:, 1] = np.where(ts > 10.0, 2.0 * (ts - 10.0), 0.0)
    assert b.gnss_manoeuvre_s(t, v, 0) == 10_100_000
    assert b.gnss_manoeuvre_s(t, v, 12_000_000) == 12_100_000
    assert b.gnss_manoeuvre_s(t, np.zeros_like(v), 0) == -1


def test_short_end_to_end(b: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
                          ) -> None:
    """GIVEN multirotor_manoeuvre and hover_only cut to 40 s, 1 seed, one process,
    WHEN the benchmark's main runs with --json,
    THEN it prints the table and the target block, the JSON rows agree with the per-seed
    records (aligned + never = seeds; false alignments = per-seed flags) and with an
    independent scoring of the same seed, and the trace of that seed holds every scored
    instant: its aligned heading errors are the record's, and its truth acceleration first
    reaches 1 m/s^2 within 0.1 s after 31.25 s (the instants are 0.1 s apart)."""
    out = tmp_path / "y.json"
    trace = tmp_path / "trace"
    assert b.main(["--seeds", "1", "--jobs", "1", "--scenarios",
                   "multirotor_manoeuvre,hover_only", "--set", "duration_s=40",
                   "--json", str(out), "--trace", str(trace)]) == 0
    text = capsys.readouterr().out
    assert "multirotor_manoeuvre" in text and "verdict" in text
    doc = json.loads(out.read_text())
    for row in doc["scenarios"]:
        seeds = doc["per_seed"][row["scenario"]]
        assert row["aligned_seeds"] + row["never_aligned"] == row["seeds"] == 1
        assert row["false_alignments"] == sum(s["false_alignment"] for s in seeds)
    one = b.run_seed("multirotor_manoeuvre", 1, {"duration_s": 40.0})
    rec = doc["per_seed"]["multirotor_manoeuvre"][0]
    assert rec["aligned_instants"] == one.hdg_err_deg.size
    assert rec["t_manoeuvre_s"] == pytest.approx(31.25, abs=0.006)
    tr = np.genfromtxt(trace / "multirotor_manoeuvre_1.csv", delimiter=",", names=True)
    assert tr.size == len(one.hdg_err_deg) + int(np.sum(tr["aligned"] < 0.5))
    assert np.allclose(tr["hdg_err_deg"][tr["aligned"] > 0.5], one.hdg_err_deg, atol=1e-4)
    first = tr["t_s"][np.argmax(tr["truth_accel_h_mps2"] >= 1.0)]
    assert 31.25 <= first <= 31.35 + 1e-9
    assert (trace / "hover_only_1.csv").is_file()


def test_config_override_is_announced(b: ModuleType, capsys: pytest.CaptureFixture[str]
                                      ) -> None:
    """GIVEN the benchmark asked for a non-default navd config,
    WHEN it runs one 35 s hover seed with --config init.heading_sd_deg=90 (a real key), and
    again with a key the [yaw_bank] section does not have,
    THEN the title says "NOT the default config" and names the override, and the unknown key
    is a usage error (exit 2) before any run, as is an unknown scenario key in --set."""
    assert b.main(["--seeds", "1", "--jobs", "1", "--scenarios", "hover_only",
                   "--set", "duration_s=35", "--config", "init.heading_sd_deg=90"]) == 0
    out = capsys.readouterr().out
    assert "NOT the default config: init.heading_sd_deg=90" in out
    with pytest.raises(SystemExit) as ex:
        b.main(["--seeds", "1", "--jobs", "1", "--scenarios", "hover_only",
                "--set", "duration_s=35", "--config", "yaw_bank.nosuch=1"])
    assert ex.value.code == 2
    with pytest.raises(SystemExit) as ex:
        b.main(["--seeds", "1", "--jobs", "1", "--scenarios", "hover_only",
                "--set", "trajectory.nosuch=1"])
    assert ex.value.code == 2


def test_course_figures_against_a_hand_computation(b: ModuleType) -> None:
    """GIVEN a fixed wing flying a circle at 15 m/s (GNSS at the rows' 10 Hz) whose navd yaw is the
    course + 2 deg (sigma 1 deg) and onboard yaw the course - 10 deg, with a slow stretch and
    an unaligned stretch,
    WHEN course_figures scores it,
    THEN navd is 2 deg RMS from the course, 0 % beyond 3 sigma (2 > 3 x 0.5 makes it 100 %),
    the onboard 10 deg, and the slow and unaligned rows do not count."""
    from types import SimpleNamespace

    t_g = np.arange(0, 60_000_000, 100_000, dtype=np.int64)
    course_g = 0.2 * t_g * 1e-6  # rad, a 0.2 rad/s circle
    speed = np.where(t_g < 10_000_000, 5.0, 15.0)
    vel = np.column_stack([speed * np.cos(course_g), speed * np.sin(course_g)])
    t = np.arange(0, 59_000_000, 100_000, dtype=np.int64)
    course = 0.2 * t * 1e-6
    yaw = course + math.radians(2.0)
    aligned = t >= 5_000_000
    aligned[(t >= 30_000_000) & (t < 40_000_000)] = False
    ref = SimpleNamespace(t_us=t, yaw_rad=course - math.radians(10.0))
    f = b.course_figures(t, yaw, np.full(t.size, 1.0), aligned, t_g, vel, ref)
    counted = aligned & (t >= 10_000_000)
    assert f["course_instants"] == int(counted.sum())
    assert f["heading_vs_course_rms_deg"] == pytest.approx(2.0, abs=0.05)
    assert f["heading_vs_course_beyond_3s_pct"] == 0.0
    assert f["onboard_vs_course_rms_deg"] == pytest.approx(10.0, abs=0.05)
    f2 = b.course_figures(t, yaw, np.full(t.size, 0.5), aligned, t_g, vel, ref)
    assert f2["heading_vs_course_beyond_3s_pct"] == 100.0


def test_x8_airspeed_triangle_recovers_a_known_wind() -> None:
    """GIVEN ground velocities made from airspeed 12-20 m/s x 0.95 along a heading that turns
    through 360 deg, plus a 4 m/s wind from the south-west,
    WHEN benchmarks/x8_wind.triangle_fit fits the true heading and one 20 deg off,
    THEN the true heading gives k 0.95, the wind, and ~0 residual; the wrong one a large
    residual."""
    w = load_benchmark("x8_wind")
    psi = np.linspace(0.0, 4.0 * math.pi, 400)
    air = 16.0 + 4.0 * np.sin(psi * 3.0)
    wind = np.array([2.83, 2.83])
    vel = 0.95 * air[:, None] * np.column_stack([np.cos(psi), np.sin(psi)]) + wind
    good = w.triangle_fit(vel, air, psi)
    assert good["k"] == pytest.approx(0.95, abs=1e-9)
    assert good["wind_n_mps"] == pytest.approx(2.83, abs=1e-9)
    assert good["wind_e_mps"] == pytest.approx(2.83, abs=1e-9)
    assert good["residual_rms_mps"] < 1e-9
    bad = w.triangle_fit(vel, air, psi + math.radians(20.0))
    assert bad["residual_rms_mps"] > 3.0
