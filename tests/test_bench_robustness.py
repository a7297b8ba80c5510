"""The robustness benchmark's scoring (benchmarks/robustness.py): lock-out measurement, counter
classification, row figures and target verdicts, and one short end-to-end case whose lock-out
is known by construction."""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np
import pytest
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario


@pytest.fixture(scope="module")
def b() -> ModuleType:
    return load_benchmark("robustness")


def test_longest_lockout_rule(b: ModuleType) -> None:
    """GIVEN sequences of GNSS outcomes (accepted, rejected, not tried) at 0.1 s spacing,
    WHEN longest_lockout_s measures them,
    THEN a lock-out runs from the first refusal to the next acceptance (untried epochs do not
    end it), the longest run counts, a run never ended lasts until the end of the data, and
    no refusals (or no data) give 0."""
    A, R, N = b.ACCEPTED, b.REJECTED, b.NOT_TRIED
    t = [0, 100_000, 200_000, 300_000, 400_000, 500_000, 600_000, 700_000]
    # a run from 0.1 s to the acceptance at 0.4 s (the untried epoch in it does not end it)
    assert b.longest_lockout_s(t, [A, R, N, R, A, A, A, A], 800_000) == pytest.approx(0.3)
    # the longer of two runs
    assert b.longest_lockout_s(t, [R, A, R, R, R, R, A, A], 800_000) == pytest.approx(0.4)
    # never accepted again: locked out until the end of the data
    assert b.longest_lockout_s(t, [A, A, A, R, R, N, R, R], 2_000_000) == pytest.approx(1.7)
    assert b.longest_lockout_s(t, [A, N, A, N, A, N, A, N], 800_000) == 0.0
    assert b.longest_lockout_s([], [], 800_000) == 0.0


def test_outcome_from_counter_deltas(b: ModuleType) -> None:
    """GIVEN estimator counters before and after one GNSS push,
    WHEN _outcome classifies the push and GnssOutcomes.both combines position and velocity,
    THEN any rise in an "ok" counter means accepted, else a rise in a "bad" counter (including
    gnss_absurd_jump) means rejected, else not tried; combined, either accepted wins, then
    either rejected."""
    before = {"pos_accepted": 5, "vel_rejected": 2, "vel_course_rejected": 1}
    # the joint block failed, velocity alone then passed: the velocity update was accepted
    after = dict(before, vel_course_rejected=2, vel_accepted=1, pos_rejected=1)
    assert b._outcome(before, after, b.VEL_OK, b.VEL_BAD) == b.ACCEPTED
    assert b._outcome(before, after, b.POS_OK, b.POS_BAD) == b.REJECTED
    assert b._outcome(before, before, b.POS_OK, b.POS_BAD) == b.NOT_TRIED
    absurd = dict(before, gnss_absurd_jump=1)
    assert b._outcome(before, absurd, b.VEL_OK, b.VEL_BAD) == b.REJECTED
    g = b.GnssOutcomes([0, 1, 2, 3], [b.ACCEPTED, b.REJECTED, b.REJECTED, b.NOT_TRIED],
                       [b.REJECTED, b.REJECTED, b.NOT_TRIED, b.NOT_TRIED])
    assert g.both() == [b.ACCEPTED, b.REJECTED, b.REJECTED, b.NOT_TRIED]


def test_resets_counts_reinit_and_reset_counters(b: ModuleType) -> None:
    """GIVEN a counter dict with reinit*, *_reset, reset_* and unrelated counters,
    WHEN resets() sums it,
    THEN only the reinit, reset_ and _reset counters are added (2 + 3 + 4 = 9)."""
    assert b.resets({"reinit_gnss_jump": 2, "heading_reset": 3, "pos_rejected": 40,
                     "reset_lockout_vel": 4, "heading_aligned_from_course": 7}) == 9


def test_row_figures_and_verdict(b: ModuleType) -> None:
    """GIVEN synthetic per-instant errors and sigmas with a 10-instant unaligned start,
    WHEN row_figures builds the table row for one run, and for two runs pooled,
    THEN RMS, aligned-heading RMS, 3-sigma exceedance and tilt-after-60-s figures are as
    constructed, the clean target misses hdg, tilt, >3s and lock; pooled runs share their
    instants, keep the worst lock-outs and add the resets."""
    t = np.arange(100) * 1.0  # 100 instants, 40 of them at t < 60 s
    err = np.zeros((100, 3))
    err[:, 0] = 0.05          # roll RMS 0.05
    err[:, 1] = np.where(np.arange(100) % 2 == 0, 0.3, -0.3)  # pitch RMS 0.3
    err[:, 2] = 2.0
    err[:10, 2] = 40.0        # the unaligned start
    sd = np.full((100, 3), 0.2)
    aligned = np.arange(100) >= 10
    sd[:, 2] = np.where(np.arange(100) < 30, 0.5, 1.0)  # 20 aligned instants exceed 3 sigma
    r = b.RunResult(t, err, sd, aligned, 12.0, 0.0, 0.0, 1, {})
    rec = b.row_figures([r], "clean")
    assert rec["roll_rms_deg"] == pytest.approx(0.05)
    assert rec["pitch_rms_deg"] == pytest.approx(0.3)
    assert rec["heading_rms_deg"] == pytest.approx(math.sqrt((10 * 40**2 + 90 * 4) / 100))
    assert rec["heading_aligned_rms_deg"] == pytest.approx(2.0)
    assert rec["exceed3_roll_pct"] == 0.0
    assert rec["exceed3_pitch_pct"] == 0.0      # 0.3 <= 3 x 0.2
    assert rec["exceed3_heading_pct"] == pytest.approx(100.0 * 20 / 90)
    assert rec["tilt_max_after_60s_deg"] == pytest.approx(0.3)
    assert rec["lock_pos_s"] == 12.0 and rec["resets"] == 1
    assert rec["misses"] == ["hdg", "tilt", ">3s", "lock"]
    # two seeds pool their instants, take the worst lock-out and add resets
    r2 = b.RunResult(t, err * 0.0, sd, aligned, 1.0, 6.0, 0.0, 2, {})
    rec2 = b.row_figures([r, r2], "integrity")
    assert rec2["roll_rms_deg"] == pytest.approx(0.05 / math.sqrt(2))
    assert rec2["lock_vel_s"] == 6.0 and rec2["lock_pos_s"] == 12.0 and rec2["resets"] == 3
    assert "lock" in rec2["misses"] and "hdg" not in rec2["misses"]


def test_short_case_lockout_is_measured_as_its_length(b: ModuleType) -> None:
    """GIVEN car480 for 100 s with every fix in [40, 60) s 500 m off,
    WHEN it is scored with the default lock-out reset and with the reset off,
    THEN the default reset keeps the position lock-out within max_lockout_s (5 s); with it
    off the lock-out measures the 20 s of refused positions and the row reports a miss."""
    run = generate(load_scenario("car480", {
        "duration_s": 100.0,
        "gnss.pos_steps": [{"start_s": 40.0, "end_s": 60.0, "north_m": 500.0}]}), seed=1)
    assert b.score_sim(run, "ground").lock_pos_s <= 5.0
    res = b.score_sim(run, "ground", ("filter.max_lockout_s=0",))
    # the first accepted position is the first fix back (t = 60.0 s) or, at worst, a few
    # epochs later while the gate re-admits it
    assert 20.0 <= res.lock_pos_s <= 21.0
    assert res.lock_vel_s == 0.0 and res.lock_all_s == 0.0  # velocity was never wrong
    assert res.counters["pos_rejected"] >= 200
    assert res.resets == 0
    rec = b.row_figures([res], "integrity")
    assert rec["lock_pos_s"] == res.lock_pos_s
    assert rec["misses"] == ["lock"] or rec["misses"] == [">3s", "lock"]
    assert rec["instants"] == res.t_s.size > 900
    line = b.format_row({"case": "jump", **rec})
    assert "20." in line and "MISS" in line


def test_nees_figures_and_band(b: ModuleType) -> None:
    """GIVEN runs whose attitude NEES are chi-square(3) draws (a consistent filter, one
    independent draw per 2 s block, held over the block's 0.1 s instants) and whose velocity
    NEES are the same draws x 2 (sigma 1.4x too small),
    WHEN nees_figures pools them after 60 s,
    THEN the attitude mean lies inside the 99 % band, the velocity mean above it, the band
    brackets 3 and narrows with more data; runs without NEES give NaN."""
    # (a consistent filter's mean falls outside its 99 % band in 1 % of draws: seed 7's 301
    # draws average 2.44, a 4-sigma draw; seed 1's 2.89)
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 600.0, 0.1)
    draws = rng.chisquare(3, size=t.size // 20 + 1)
    nees = np.repeat(draws, 20)[: t.size]
    zero = np.zeros((t.size, 3))
    r = b.RunResult(t, zero, zero + 1.0, np.ones(t.size, bool), 0.0, 0.0, 0.0, 0, {},
                    nees, 2.0 * nees)
    one = b.nees_figures([r])
    lo, hi = one["nees_band"]
    assert lo < 3.0 < hi
    assert lo < one["nees_att"] < hi
    assert one["nees_vel"] > hi
    lo5, hi5 = b.nees_figures([r] * 5)["nees_band"]
    assert lo < lo5 < 3.0 < hi5 < hi
    bare = b.RunResult(t, zero, zero, np.ones(t.size, bool), 0.0, 0.0, 0.0, 0, {})
    assert math.isnan(b.nees_figures([bare])["nees_att"])


def test_reference_gyro_corr_tells_a_reference_of_this_imu_from_another(b: ModuleType) -> None:
    """GIVEN 60 s of body rates (100 Hz) and a reference (10 Hz) whose roll/pitch are their
    integrals, or the integrals negated, or an unrelated signal,
    WHEN reference_gyro_corr compares them,
    THEN the correlation is > 0.95, < -0.95 and within 0.2 of zero, and a window shorter
    than 10 s gives NaN."""
    t = np.arange(0, 60_000_000, 10_000, dtype=np.int64)
    ts = t * 1e-6
    rates = np.stack([0.3 * np.sin(1.3 * ts), 0.2 * np.cos(0.7 * ts), 0 * ts], axis=1)
    roll = -0.3 / 1.3 * np.cos(1.3 * ts)
    pitch = 0.2 / 0.7 * np.sin(0.7 * ts)
    rt = t[::10]
    same = b.reference_gyro_corr(t, rates, rt, roll[::10], pitch[::10], 0, None)
    flip = b.reference_gyro_corr(t, rates, rt, -roll[::10], -pitch[::10], 0, None)
    rng = np.random.default_rng(3)
    other = b.reference_gyro_corr(t, rates, rt, np.cumsum(rng.normal(0, 0.01, rt.size)),
                                  np.cumsum(rng.normal(0, 0.01, rt.size)), 0, None)
    assert min(same) > 0.95 and max(flip) < -0.95
    assert max(abs(x) for x in other) < 0.2
    assert all(math.isnan(x) for x in b.reference_gyro_corr(t, rates, rt, roll[::10],
                                                            pitch[::10], 0, 5_000_000))
