"""Heading from motion (issue 15): Monte Carlo over the yaw scenarios, DEFAULT config.

Every seed of every scenario runs ``navd.pipeline.build_estimator`` on
``load_config(None, ["filter.profile=<profile>"])`` through the replay path
(:func:`robustness.score_sim`: the shipped defaults, the scenario's natural profile, errors
sampled every 0.1 s of sensor time).  The scenarios (firmware_sim/scenarios, consumer MEMS IMU,
no magnetometer, ``[randomize]``: each seed has its own initial yaw, leg directions or wind,
turn directions and IMU offsets):

* ``multirotor_manoeuvre`` (multirotor): take-off, hover, legs at 2-8 m/s, 1-3 m/s^2, yaw in
  flight;
* ``fixed_wing_wind`` (fixed_wing): coordinated turns at 20-24 m/s in 3-10 m/s wind, crab up
  to 30 deg;
* ``accel_sign_change`` (multirotor): PX4 PR #28014's case, back and forth along one line,
  three sign changes inside 1.2 s GNSS gaps;
* ``hover_only`` (multirotor): no horizontal acceleration: must never align;
* ``hover_poor_gnss`` (multirotor): ArduPilot #15813's case, the same hover with GNSS velocity
  noise of 1.0 m/s reported as 0.4 m/s: must never align.

What is scored is what the estimator says: its ``heading_aligned`` flag and its heading
1-sigma (``att_sd_rad[2]``).  Per scenario:

* ``t_align``: per seed, time from the first truth horizontal acceleration >= 1 m/s^2 to the
  first instant flagged aligned (negative: aligned before the heading was observable from
  motion); median and max over the seeds that aligned, and ``never`` = seeds never aligned;
* ``hdg rms``: heading RMS over the aligned instants, pooled over seeds, deg;
* ``>3s %``: % of aligned instants with |heading error| > 3 x the reported sigma;
* ``false``: seeds with at least one aligned instant whose |heading error| > 10 deg;
* ``roll/pitch rms`` over all instants, deg (information).

Targets (issue 15), each printed with ok/MISS: aligned within 10 s on every seed (the hovers:
never aligned on any seed); 0 false alignments; heading RMS <= 2 deg (multirotor) / 3 deg
(fixed-wing); <= 5 % beyond 3 sigma.

``--real`` adds the recorded flights (robustness.REAL_LOGS, ``../shared/data``): time from
take-off (or the log's flight start) and from the first GNSS horizontal acceleration >= 1 m/s^2
to aligned, heading vs the onboard (magnetometer-aided) yaw over aligned in-flight instants,
roll/pitch vs onboard in flight (take-off to a crash's onset: navd.eval.flight).  The onboard
attitude is an estimate, not truth.

    python benchmarks/yaw_bank.py [--seeds 100] [--scenarios a,b] [--real] [--json PATH]
                                  [--jobs 2] [--set SCENARIO_KEY=V] [--config NAVD_KEY=V]
                                  [--trace DIR]

``--config`` runs a non-default navd config (e.g. ``yaw_bank.enabled=auto`` while the bank is
off by default); the printed title then says "NOT the default config" and lists it.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import statistics
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parent))
import robustness as rb  # benchmarks/ is not a package: found through sys.path

from firmware_sim import SimRun, generate, load_scenario
from navd.config import load_config
from navd.pipeline import build_estimator, solutions
from navd.units import RAD2DEG

Arr = npt.NDArray[np.float64]

MANOEUVRE_MPS2 = 1.0       # "first horizontal acceleration >= 1 m/s^2"
ALIGN_TARGET_S = 10.0
FALSE_ALIGN_DEG = 10.0
EXCEED_TARGET_PCT = 5.0


@dataclass(frozen=True)
class YawScenario:
    """A built-in scenario, its natural profile and its heading RMS target (deg); ``observable``
    False: the heading cannot be seen from motion, so the target is never to align."""

    name: str
    profile: str
    rms_target_deg: float
    observable: bool = True


SCENARIOS: tuple[YawScenario, ...] = (
    YawScenario("multirotor_manoeuvre", "multirotor", 2.0),
    YawScenario("fixed_wing_wind", "fixed_wing", 3.0),
    YawScenario("accel_sign_change", "multirotor", 2.0),
    YawScenario("hover_only", "multirotor", 2.0, observable=False),
    YawScenario("hover_poor_gnss", "multirotor", 2.0, observable=False),
)


# ---------------------------------------------------------------------------------------------
# one seed
# ---------------------------------------------------------------------------------------------

@dataclass
class SeedResult:
    """One seed's figures.

    ``t_manoeuvre_s``: first truth horizontal acceleration >= 1 m/s^2 (NaN: none);
    ``t_aligned_s``: first instant the estimator flagged heading aligned (NaN: never);
    ``hdg_err_deg`` / ``hdg_sd_deg``: (A,) heading error and reported 1-sigma at the aligned
    instants, deg; ``n_instants``: instants scored; ``roll_pitch_sq``: (2,) sums of squared
    roll / pitch errors over all instants, deg^2; ``drawn``: the seed's scenario variant;
    ``counters``: the estimator's non-zero counters about heading (names with ``head``,
    ``yaw``, ``bank``, ``align`` or ``course``) at the end.
    """

    scenario: str
    seed: int
    t_manoeuvre_s: float
    t_aligned_s: float
    hdg_err_deg: Arr
    hdg_sd_deg: Arr
    n_instants: int
    roll_pitch_sq: Arr
    drawn: dict[str, Any] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)

    @property
    def delay_s(self) -> float:
        """Time from the first manoeuvre to aligned, s (NaN if either never happened)."""
        return self.t_aligned_s - self.t_manoeuvre_s

    @property
    def false_alignment(self) -> bool:
        return bool(np.any(np.abs(self.hdg_err_deg) > FALSE_ALIGN_DEG))

    def summary(self) -> dict[str, Any]:
        """JSON-ready per-seed record (no arrays)."""
        e = self.hdg_err_deg
        return {"seed": self.seed, "t_manoeuvre_s": self.t_manoeuvre_s,
                "t_aligned_s": self.t_aligned_s, "delay_s": self.delay_s,
                "aligned_instants": int(e.size),
                "heading_rms_deg": _rms(e),
                "heading_max_abs_deg": float(np.max(np.abs(e))) if e.size else math.nan,
                "err_at_alignment_deg": float(e[0]) if e.size else math.nan,
                "false_alignment": self.false_alignment, "drawn": self.drawn,
                "counters": self.counters}


def first_manoeuvre_s(run: SimRun, threshold_mps2: float = MANOEUVRE_MPS2) -> float:
    """Time (s from the start) of the first truth horizontal acceleration >= threshold; NaN if
    there is none.  Acceleration by finite differences of the truth velocity per IMU interval
    (the profiles are smooth, so this is the analytic acceleration to O(dt^2))."""
    acc = np.diff(run.truth_vel_n[:, :2], axis=0) / run.imu_dt_s
    hit = np.flatnonzero(np.hypot(acc[:, 0], acc[:, 1]) >= threshold_mps2)
    if hit.size == 0:
        return math.nan
    return float((run.truth_t_us[hit[0]] - run.truth_t_us[0]) * 1e-6)


def seed_result(name: str, seed: int, run: SimRun, res: rb.RunResult) -> SeedResult:
    """Reduce one scored run to its figures (kept apart from the running, for the tests)."""
    al = res.aligned
    t_al = float(res.t_s[np.argmax(al)]) if al.any() else math.nan
    rp = np.sum(res.err_deg[:, :2] ** 2, axis=0)
    keys = ("head", "yaw", "bank", "align", "course")
    counters = {k: v for k, v in res.counters.items() if v and any(w in k for w in keys)}
    return SeedResult(name, seed, first_manoeuvre_s(run), t_al, res.err_deg[al, 2].copy(),
                      res.sd_deg[al, 2].copy(), int(res.t_s.size), rp, dict(run.randomized),
                      counters)


TRACE_COLUMNS = ("t_s", "aligned", "hdg_err_deg", "hdg_sd_deg", "roll_err_deg", "roll_sd_deg",
                 "pitch_err_deg", "pitch_sd_deg", "truth_yaw_deg", "truth_crab_deg",
                 "truth_accel_h_mps2")


def write_trace(path: Path, run: SimRun, res: rb.RunResult) -> None:
    """One run's scored instants as CSV (:data:`TRACE_COLUMNS`): the estimator's errors and
    sigmas with the truth yaw, crab (yaw - GNSS course; 0 when slower than 0.5 m/s) and
    horizontal acceleration at each instant, for looking at a failing seed."""
    dt = run.imu_dt_s
    k = np.clip(np.rint(res.t_s / dt).astype(np.int64), 1, run.truth_vel_n.shape[0] - 1)
    v = run.truth_vel_n
    yaw = run.truth_euler[k, 2]
    course = np.arctan2(v[k, 1], v[k, 0])
    crab = np.where(np.hypot(v[k, 0], v[k, 1]) > 0.5,
                    (yaw - course + math.pi) % (2 * math.pi) - math.pi, 0.0)
    acc = (v[k, :2] - v[k - 1, :2]) / dt
    cols = np.column_stack([res.t_s, res.aligned.astype(np.float64), res.err_deg[:, 2],
                            res.sd_deg[:, 2], res.err_deg[:, 0], res.sd_deg[:, 0],
                            res.err_deg[:, 1], res.sd_deg[:, 1], yaw * RAD2DEG,
                            crab * RAD2DEG, np.hypot(acc[:, 0], acc[:, 1])])
    np.savetxt(path, cols, delimiter=",", header=",".join(TRACE_COLUMNS), comments="",
               fmt="%.6g")


def run_seed(name: str, seed: int, overrides: Mapping[str, Any] | None = None,
             config: Sequence[str] = (), trace_dir: str | None = None) -> SeedResult:
    """Generate seed ``seed`` of scenario ``name`` (scenario ``overrides``) and score the
    estimator: the default config, plus ``config`` navd overrides (``key=value``) if any;
    with ``trace_dir``, also write ``<trace_dir>/<name>_<seed>.csv`` (:func:`write_trace`)."""
    sc = next(s for s in SCENARIOS if s.name == name)
    run = generate(load_scenario(name, dict(overrides or {})), seed=seed)
    res = rb.score_sim(run, sc.profile, tuple(config))
    if trace_dir is not None:
        write_trace(Path(trace_dir) / f"{name}_{seed}.csv", run, res)
    return seed_result(name, seed, run, res)


def _job(args: tuple[str, int, dict[str, Any], tuple[str, ...], str | None]) -> SeedResult:
    return run_seed(*args)


# ---------------------------------------------------------------------------------------------
# seeds -> one table row
# ---------------------------------------------------------------------------------------------

def _rms(x: Arr) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else math.nan


def _le(x: float, lim: float) -> bool:
    return math.isfinite(x) and x <= lim


def scenario_figures(results: Sequence[SeedResult], sc: YawScenario) -> dict[str, Any]:
    """The row of one scenario: figures over its seeds and the verdict of each target."""
    delays = [r.delay_s for r in results if math.isfinite(r.t_aligned_s)]
    finite = [d for d in delays if math.isfinite(d)]
    err = np.concatenate([r.hdg_err_deg for r in results]) if results else np.zeros(0)
    sd = np.concatenate([r.hdg_sd_deg for r in results]) if results else np.zeros(0)
    n_inst = sum(r.n_instants for r in results)
    rp = np.sum([r.roll_pitch_sq for r in results], axis=0) if results else np.zeros(2)
    rec: dict[str, Any] = {
        "scenario": sc.name, "profile": sc.profile, "seeds": len(results),
        "aligned_seeds": sum(math.isfinite(r.t_aligned_s) for r in results),
        "never_aligned": sum(not math.isfinite(r.t_aligned_s) for r in results),
        "aligned_before_manoeuvre": sum(d < 0.0 for d in finite),
        "no_manoeuvre": sum(not math.isfinite(r.t_manoeuvre_s) for r in results),
        "delay_median_s": statistics.median(finite) if finite else math.nan,
        "delay_max_s": max(finite) if finite else math.nan,
        "heading_rms_aligned_deg": _rms(err),
        "aligned_instants": int(err.size),
        "exceed3_pct": 100.0 * float(np.mean(np.abs(err) > 3.0 * sd)) if err.size else math.nan,
        "false_alignments": sum(r.false_alignment for r in results),
        "false_alignment_seeds": [r.seed for r in results if r.false_alignment],
        "roll_rms_deg": math.sqrt(rp[0] / n_inst) if n_inst else math.nan,
        "pitch_rms_deg": math.sqrt(rp[1] / n_inst) if n_inst else math.nan,
    }
    rec["targets"] = targets(rec, sc)
    return rec


def targets(rec: Mapping[str, Any], sc: YawScenario) -> list[dict[str, Any]]:
    """Each issue-15 target of one row: ``target`` text, ``value`` and ``ok``."""
    out: list[dict[str, Any]] = []

    def add(text: str, value: str, ok: bool) -> None:
        out.append({"target": text, "value": value, "ok": ok})

    n = rec["seeds"]
    if sc.observable:
        worst = rec["delay_max_s"]
        add(f"aligned <= {ALIGN_TARGET_S:g} s on every seed",
            f"max {_fmt(worst, '.1f')} s, never {rec['never_aligned']}/{n}"
            + (f", early {rec['aligned_before_manoeuvre']}" if rec["aligned_before_manoeuvre"]
               else ""),
            rec["never_aligned"] == 0 and _le(worst, ALIGN_TARGET_S))
    else:
        add("never aligned (heading unobservable)", f"aligned {rec['aligned_seeds']}/{n}",
            rec["aligned_seeds"] == 0)
    add("0 false alignments (|err| > 10 deg)", f"{rec['false_alignments']}/{n}",
        rec["false_alignments"] == 0)
    if sc.observable or rec["aligned_instants"]:
        add(f"heading RMS <= {sc.rms_target_deg:g} deg",
            f"{_fmt(rec['heading_rms_aligned_deg'], '.2f')} deg",
            _le(rec["heading_rms_aligned_deg"], sc.rms_target_deg))
        add(f"<= {EXCEED_TARGET_PCT:g} % beyond 3 sigma", f"{_fmt(rec['exceed3_pct'], '.1f')} %",
            _le(rec["exceed3_pct"], EXCEED_TARGET_PCT))
    return out


def _fmt(x: float, fmt: str) -> str:
    return format(x, fmt) if isinstance(x, (int, float)) and math.isfinite(x) else "-"


# ---------------------------------------------------------------------------------------------
# real logs
# ---------------------------------------------------------------------------------------------

def gnss_manoeuvre_s(t_us: npt.NDArray[np.int64], vel_ne: Arr, after_us: int,
                     threshold_mps2: float = MANOEUVRE_MPS2, window_s: float = 1.0) -> int:
    """First time (us) at or after ``after_us`` where the horizontal acceleration from GNSS
    velocity, differenced over ``window_s`` (a 1 s baseline keeps receiver noise of
    ~0.1 m/s below 0.2 m/s^2), reaches ``threshold_mps2``; -1 if never.

    Args:
        t_us: (M,) fix times, us, increasing.
        vel_ne: (M, 2) north, east velocity, m/s.
    """
    if t_us.size < 2:
        return -1
    j = np.searchsorted(t_us, t_us + round(window_s * 1e6))
    ok = j < t_us.size
    i = np.flatnonzero(ok)
    j = j[ok]
    dt = (t_us[j] - t_us[i]) * 1e-6
    acc = np.hypot(*(vel_ne[j] - vel_ne[i]).T) / np.maximum(dt, 1e-3)
    # stamped at the middle of the baseline
    t_mid = (t_us[i] + t_us[j]) // 2
    hit = np.flatnonzero((acc >= threshold_mps2) & (t_mid >= after_us) & (dt < 2 * window_s))
    return int(t_mid[hit[0]]) if hit.size else -1


def score_real(spec: rb.RealLog, config: Sequence[str] = ()) -> dict[str, Any]:
    """Replay one real log with the default config (plus ``config`` overrides) and its
    profile; the row (``reason`` when there are no figures)."""
    from navd.cli.replay import log_accel_calibration, log_lever_arm
    from navd.io.logs import LogFormatError, LogOptions, read_log

    rec: dict[str, Any] = {"log": spec.name, "path": str(spec.path), "profile": spec.profile}
    try:
        data = read_log(spec.path, None, LogOptions())
    except (OSError, LogFormatError, ValueError) as exc:
        rec["reason"] = f"cannot read: {exc}"
        return rec
    # the antenna position a log states, as `navd replay --log` takes it (none of ours does)
    tables, _ = log_lever_arm(load_config(None, [f"filter.profile={spec.profile}", *config]),
                              data.lever_arm_m)
    # ... and the accelerometer calibration it states, as the replay does
    tables, _ = log_accel_calibration(tables, data.accel_calibrated)
    est = build_estimator(tables)
    rows = [(s.t_us, s.roll_rad, s.pitch_rad, s.yaw_rad, *s.att_sd_rad, float(s.heading_aligned))
            for s in solutions(est, data.samples(), 10.0)]
    rec["counters"] = {k: v for k, v in est.counters.items() if v}
    ref = data.reference
    if not rows or len(ref) == 0:
        rec["reason"] = "no navigation solution" if not rows else "no onboard attitude"
        return rec
    a = np.array(rows)
    t_us = a[:, 0].astype(np.int64)
    t0 = int(min(data.imu_t_us[0], ref.t_us[0]))
    win = rb.flight_window(data.imu_t_us, data.imu_inc, t0,
                           spec.flight_from_s if spec.flight_from_s > 0.0 else None)
    start_s = win.from_s
    start_us = t0 + round(start_s * 1e6) if math.isfinite(start_s) else t0
    man_us = gnss_manoeuvre_s(data.gnss_t_us, data.gnss[:, 3:5], start_us)
    err, near = rb.reference_errors(t_us, a[:, 1:4],
                                    (ref.t_us, ref.roll_rad, ref.pitch_rad, ref.yaw_rad))
    e = err * RAD2DEG
    sd = a[:, 4:7] * RAD2DEG
    aligned = a[:, 7] > 0.5
    # from take-off to a crash's onset, if any (the rule robustness.py and the replay use)
    fly = near & (t_us >= start_us) & ~(t_us >= t0 + win.to_s * 1e6)
    al_fly = fly & aligned
    t_al = int(t_us[np.argmax(aligned)]) if aligned.any() else -1
    rec.update({
        "flight_from_s": start_s,
        "manoeuvre_from_s": (man_us - t0) * 1e-6 if man_us >= 0 else math.nan,
        "aligned_at_s": (t_al - t0) * 1e-6 if t_al >= 0 else math.nan,
        "align_after_takeoff_s": (t_al - start_us) * 1e-6 if t_al >= 0 else math.nan,
        "align_after_manoeuvre_s": ((t_al - man_us) * 1e-6 if t_al >= 0 and man_us >= 0
                                    else math.nan),
        "flight_instants": int(fly.sum()),
        "aligned_flight_pct": 100.0 * float(al_fly.sum()) / max(1, int(fly.sum())),
        "heading_vs_onboard_rms_deg": _rms(e[al_fly, 2]),
        "heading_vs_onboard_max_deg": (float(np.max(np.abs(e[al_fly, 2]))) if al_fly.any()
                                       else math.nan),
        "heading_beyond_3s_pct": (100.0 * float(np.mean(np.abs(e[al_fly, 2])
                                                        > 3.0 * sd[al_fly, 2]))
                                  if al_fly.any() else math.nan),
        "roll_vs_onboard_rms_deg": _rms(e[fly, 0]),
        "pitch_vs_onboard_rms_deg": _rms(e[fly, 1]),
    })
    if spec.profile == "fixed_wing":
        rec.update(course_figures(t_us, a[:, 3], sd[:, 2], al_fly & (np.abs(a[:, 2]) < PITCH_MAX),
                                  data.gnss_t_us, data.gnss[:, 3:5], ref))
    return rec


COURSE_MIN_SPEED = 8.0  # m/s: GNSS course noise below ~1 deg at 0.1 m/s velocity noise
# rad: in loops the Euler yaw flips by 180 deg through the vertical; heading is course only
# in flight that is not steeply climbing or diving
PITCH_MAX = math.radians(45.0)


def course_figures(t_us: npt.NDArray[np.int64], yaw_rad: Arr, yaw_sd_deg: Arr,
                   al_fly: npt.NDArray[np.bool_], gnss_t_us: npt.NDArray[np.int64],
                   vel_ne: Arr, ref: Any) -> dict[str, Any]:
    """A fixed wing's heading against its GNSS course, where the course is a heading proxy
    (wind small against airspeed: the X8's airspeed triangle fits a 0.3 m/s wind,
    benchmarks/x8_wind.py): navd's aligned in-flight yaw and the onboard yaw, each minus the
    course of the GNSS velocity (interpolated to the row: a 5 Hz fix is 0.1 s old on
    average, 3 deg at a 30 deg/s turn) at ground speeds >= COURSE_MIN_SPEED and, by the
    caller's mask, navd's |pitch| < PITCH_MAX: RMS deg, and navd's share beyond 3 sigma."""
    v = np.column_stack([np.interp(t_us, gnss_t_us, vel_ne[:, 0]),
                         np.interp(t_us, gnss_t_us, vel_ne[:, 1])])
    fast = al_fly & (np.hypot(v[:, 0], v[:, 1]) >= COURSE_MIN_SPEED)
    course = np.arctan2(v[:, 1], v[:, 0])
    e_nv = np.degrees((yaw_rad - course + math.pi) % (2 * math.pi) - math.pi)
    onb = np.interp(t_us, ref.t_us, np.unwrap(ref.yaw_rad))
    e_onb = np.degrees((onb - course + math.pi) % (2 * math.pi) - math.pi)
    return {
        "course_instants": int(fast.sum()),
        "heading_vs_course_rms_deg": _rms(e_nv[fast]),
        "heading_vs_course_beyond_3s_pct": (100.0 * float(np.mean(np.abs(e_nv[fast])
                                                                  > 3.0 * yaw_sd_deg[fast]))
                                            if fast.any() else math.nan),
        "onboard_vs_course_rms_deg": _rms(e_onb[fast]),
    }


def _real_job(args: tuple[str, tuple[str, ...]]) -> dict[str, Any]:
    name, config = args
    return score_real(next(r for r in rb.REAL_LOGS if r.name == name), config)


# ---------------------------------------------------------------------------------------------
# printing and driver
# ---------------------------------------------------------------------------------------------

HEADER = (f"{'scenario':<22}{'profile':<11}{'seeds':>6}{'t_align med':>12}{'max':>7}"
          f"{'never':>6}{'early':>6}{'hdg rms':>9}{'>3s %':>7}{'false':>6}{'roll':>7}{'pitch':>7}")


def format_row(rec: Mapping[str, Any]) -> str:
    return (f"{rec['scenario']:<22}{rec['profile']:<11}{rec['seeds']:>6}"
            f"{_fmt(rec['delay_median_s'], '.1f'):>12}{_fmt(rec['delay_max_s'], '.1f'):>7}"
            f"{rec['never_aligned']:>6}{rec['aligned_before_manoeuvre']:>6}"
            f"{_fmt(rec['heading_rms_aligned_deg'], '.2f'):>9}{_fmt(rec['exceed3_pct'], '.1f'):>7}"
            f"{rec['false_alignments']:>6}{_fmt(rec['roll_rms_deg'], '.2f'):>7}"
            f"{_fmt(rec['pitch_rms_deg'], '.2f'):>7}")


def format_targets(records: Sequence[Mapping[str, Any]]) -> list[str]:
    lines = [f"{'scenario':<22}{'target':<42}{'value':<36}verdict"]
    for rec in records:
        for t in rec["targets"]:
            lines.append(f"{rec['scenario']:<22}{t['target']:<42}{t['value']:<36}"
                         f"{'ok' if t['ok'] else 'MISS'}")
    return lines


REAL_HEADER = (f"{'log':<13}{'profile':<11}{'align@':>8}{'-takeoff':>9}{'-manoeuv':>9}"
               f"{'al %':>6}{'hdg-onb rms':>12}{'max':>7}{'>3s %':>7}{'roll':>7}{'pitch':>7}")


def format_real(rec: Mapping[str, Any]) -> str:
    head = f"{rec['log']:<13}{rec['profile']:<11}"
    if "reason" in rec:
        return f"{head}not measured: {rec['reason']}"
    return (f"{head}{_fmt(rec['aligned_at_s'], '.1f'):>8}"
            f"{_fmt(rec['align_after_takeoff_s'], '.1f'):>9}"
            f"{_fmt(rec['align_after_manoeuvre_s'], '.1f'):>9}"
            f"{_fmt(rec['aligned_flight_pct'], '.0f'):>6}"
            f"{_fmt(rec['heading_vs_onboard_rms_deg'], '.2f'):>12}"
            f"{_fmt(rec['heading_vs_onboard_max_deg'], '.1f'):>7}"
            f"{_fmt(rec['heading_beyond_3s_pct'], '.1f'):>7}"
            f"{_fmt(rec['roll_vs_onboard_rms_deg'], '.2f'):>7}"
            f"{_fmt(rec['pitch_vs_onboard_rms_deg'], '.2f'):>7}"
            + (f"\n{'':<13}vs GNSS course at >= {COURSE_MIN_SPEED:.0f} m/s, aligned, "
               f"{rec['course_instants']} instants: navd "
               f"{_fmt(rec['heading_vs_course_rms_deg'], '.2f')} deg RMS "
               f"({_fmt(rec['heading_vs_course_beyond_3s_pct'], '.1f')} % beyond 3 sigma), "
               f"onboard {_fmt(rec['onboard_vs_course_rms_deg'], '.2f')} deg RMS"
               if "heading_vs_course_rms_deg" in rec else ""))


def run_all(names: Sequence[str], seeds: int, jobs: int, real: bool,
            overrides: Mapping[str, Any] | None = None, config: Sequence[str] = (),
            trace_dir: str | None = None
            ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, list[SeedResult]]]:
    """Every seed of every scenario named, and the real logs if asked; rows, real rows and
    the per-seed results."""
    cfg = tuple(config)
    work = [(n, s, dict(overrides or {}), cfg, trace_dir) for n in names
            for s in range(1, seeds + 1)]
    logs = [(r.name, cfg) for r in rb.REAL_LOGS] if real else []
    if jobs <= 1:
        out = [_job(w) for w in work]
        real_out = [_real_job(n) for n in logs]
    else:
        with multiprocessing.get_context("spawn").Pool(jobs) as pool:
            real_async = pool.map_async(_real_job, logs)
            out = pool.map(_job, work, chunksize=1)
            real_out = real_async.get()
    per: dict[str, list[SeedResult]] = {n: [r for r in out if r.scenario == n] for n in names}
    rows = [scenario_figures(per[sc.name], sc) for sc in SCENARIOS if sc.name in names]
    return rows, real_out, per


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=100, help="Monte Carlo seeds 1..N (100)")
    ap.add_argument("--scenarios", help="comma-separated scenario names (default: all: "
                    + ", ".join(s.name for s in SCENARIOS) + ")")
    ap.add_argument("--real", action="store_true", help="also the real logs")
    ap.add_argument("--json", help="write the rows, per-seed records and real logs here")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="scenario override for every seed (e.g. duration_s=60)")
    ap.add_argument("--trace", metavar="DIR",
                    help="write each run's scored instants to DIR/<scenario>_<seed>.csv")
    ap.add_argument("--config", action="append", default=[], metavar="KEY=VALUE",
                    help="navd config override (e.g. yaw_bank.enabled=auto): the run is then "
                         "NOT the default config, and the output says so")
    a = ap.parse_args(argv)
    known = [s.name for s in SCENARIOS]
    names = known if not a.scenarios else [n.strip() for n in a.scenarios.split(",")
                                            if n.strip()]
    bad = [n for n in names if n not in known]
    if bad:
        ap.error(f"unknown scenario(s) {bad}; known: {', '.join(known)}")
    if a.seeds < 1:
        ap.error("--seeds must be >= 1")
    from firmware_sim import ScenarioError
    from firmware_sim.__main__ import parse_set

    try:
        overrides = parse_set(a.set)
        for n in names:  # a bad scenario override fails here, not in every worker
            load_scenario(n, overrides)
    except ScenarioError as exc:
        ap.error(f"--set: {exc}")
    t_start = time.perf_counter()
    from navd.config import ConfigError

    try:
        # a bad key or value fails here, before any work
        build_estimator(load_config(None, ["filter.profile=multirotor", *a.config]))
    except ConfigError as exc:
        ap.error(f"--config: {exc}")
    if a.trace:
        Path(a.trace).mkdir(parents=True, exist_ok=True)
    rows, real_rows, per = run_all(names, a.seeds, max(1, a.jobs), a.real, overrides,
                                   a.config, a.trace)
    what = ("DEFAULT config" if not a.config
            else "NOT the default config: " + " ".join(a.config) + ",")
    print(f"issue-15 yaw from motion: {what} + natural profile, seeds 1..{a.seeds}; "
          f"t_align from first |a_h| >= {MANOEUVRE_MPS2:g} m/s^2, s; deg; %")
    print(HEADER)
    print("-" * len(HEADER))
    for rec in rows:
        print(format_row(rec))
    print("never: seeds never aligned; early: aligned before the first manoeuvre; hdg rms and "
          ">3s over aligned instants (pooled); false: seeds aligned with |err| > 10 deg")
    print()
    for line in format_targets(rows):
        print(line)
    if a.real:
        print()
        print("real logs vs the onboard estimator (an estimate, not truth); align@ s from the "
              "log start, -takeoff / -manoeuv: after take-off / first GNSS |a_h| >= 1 m/s^2")
        print(REAL_HEADER)
        for rec in real_rows:
            print(format_real(rec))
    print(f"({time.perf_counter() - t_start:.0f} s)")
    if a.json:
        doc = {"seeds": a.seeds, "overrides": overrides, "config": list(a.config),
               "scenarios": rows,
               "per_seed": {n: [r.summary() for r in v] for n, v in per.items()},
               "real": real_rows}
        with open(a.json, "w") as fh:
            json.dump(doc, fh, indent=2, default=str)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

