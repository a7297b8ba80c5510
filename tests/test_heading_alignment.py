"""Alignment integrity (navd.core.aiding.heading_alignment): the heading is flagged aligned
only after the course agreed over time, a wrong yaw at low speed is not flagged, and
reversing does not excuse a >90 deg error forever.  Default config."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario
from navd.config import load_config
from navd.core.rotation import exp_into
from navd.pipeline import build_estimator
from navd.types import GnssSample, ImuSample

rb = load_benchmark("robustness")


def _slow_noisy(seed: int) -> Any:
    """car480's route at 2-3.4 m/s with 5x the accelerometer noise (VRW 1.5 m/s/sqrt(s))."""
    o = {"trajectory.speed0_mps": 2.5, "trajectory.speed": rb._car_speeds(2.0, 3.4),
         "imu.vrw_mps_per_sqrt_s": 1.5}
    run = generate(load_scenario("car480", o), seed=seed, progress=False)
    return rb.score_sim(run, "ground")


def test_low_speed_noisy_accelerometer_keeps_the_aligned_heading_within_its_sigma() -> None:
    """GIVEN the issue's false-alignment setting (2-3.4 m/s, noisy accelerometers), seeds
    1-12 (with course updates only from 3 m/s and the run-of-checks watch alone, 9 of the 12
    seeds had aligned instants 13-55 deg off and beyond 3 sigma, and 10.5 % of the aligned
    instants pooled were beyond 3 sigma: docs/results.md, "Low-speed false alignment"),
    WHEN each is run with the default config,
    THEN every seed is flagged aligned for most of the drive (>= 90 % of instants: the flag
    is not simply withheld), no aligned instant is a false alignment (|error| > 10 deg and
    beyond 3 sigma), and pooled over the seeds at most 5 % of the aligned instants are
    beyond 3 sigma.

    Twelve seeds rather than a few picked ones: which seeds go wrong moves with every
    estimator change."""
    n_aligned = n_beyond = 0
    for seed in range(1, 13):
        r = _slow_noisy(seed)
        err = np.abs(r.err_deg[:, 2])
        beyond = err > 3.0 * r.sd_deg[:, 2]
        assert r.aligned.mean() >= 0.9, seed
        false_aligned = r.aligned & beyond & (err > 10.0)
        assert not false_aligned.any(), (seed, float(err[false_aligned].max()))
        n_aligned += int(r.aligned.sum())
        n_beyond += int((r.aligned & beyond).sum())
    assert n_beyond <= 0.05 * n_aligned, n_beyond / n_aligned


def test_one_fast_course_at_start_does_not_flag_the_heading() -> None:
    """GIVEN car480 (10 m/s from the start: the first fix's course sets the yaw),
    THEN right after navigation starts the heading is not yet flagged aligned, and it is
    flagged within 10 s, from the course, once."""
    run = generate(load_scenario("car480", {"duration_s": 30.0}), seed=1, progress=False)
    est = build_estimator(load_config(None, []))
    t_start = t_aligned = -1
    for s in run.samples():
        est.push(s)
        if est.initialized and t_start < 0:
            t_start = est.t_us
            assert not est.heading_aligned
            assert est.counters["heading_yaw_from_course"] == 1
        if est.heading_aligned and t_aligned < 0:
            t_aligned = est.t_us
    assert t_start > 0 and t_aligned > 0
    assert 3.0 <= (t_aligned - t_start) * 1e-6 <= 10.0
    assert est.counters["heading_aligned_from_course"] == 1


def test_reversing_does_not_excuse_a_flipped_heading_forever() -> None:
    """GIVEN the 2-3.4 m/s drive with the default accelerometer, heading aligned,
    WHEN at 100 s the filter's yaw is turned by 180 deg (the course now says "reversing",
    below max_reverse_speed_mps),
    THEN within max_reverse_s (30 s) + 10 s the yaw is set to the course again (counted)
    and the heading error is back under 10 deg."""
    o = {"trajectory.speed0_mps": 2.5, "trajectory.speed": rb._car_speeds(2.0, 3.4)}
    run = generate(load_scenario("car480", o), seed=2, progress=False)
    est = build_estimator(load_config(None, []))
    flip_us, check_us = 100_000_000, 140_000_000
    flipped = False
    e = np.zeros((3, 3))
    err_at_check = math.nan
    for s in run.samples():
        est.push(s)
        if isinstance(s, ImuSample) and not flipped and s.t_us >= flip_us:
            assert est.heading_aligned
            exp_into(e, 0.0, 0.0, math.pi)
            est.mat_nb[:, :] = e @ est.mat_nb
            flipped = True
        if isinstance(s, GnssSample) and s.t_us >= check_us and math.isnan(err_at_check):
            k = min(np.searchsorted(run.truth_t_us, s.t_us), len(run.truth_t_us) - 1)
            yaw = math.atan2(est.mat_nb[1, 0], est.mat_nb[0, 0])
            d = yaw - float(run.truth_euler[k, 2])
            err_at_check = abs(math.degrees((d + math.pi) % (2 * math.pi) - math.pi))
    assert est.counters["heading_reset_reverse"] >= 1
    assert err_at_check < 10.0


def _checks(est: Any, course_off_deg: float, n: int, t0_s: float) -> None:
    """``n`` course checks at 10 Hz and 2 m/s whose course is ``course_off_deg`` from the
    filter's yaw (0.1 m/s speed sigma: ~2.9 deg of course noise per check)."""
    yaw = math.atan2(est.mat_nb[1, 0], est.mat_nb[0, 0])
    chi = yaw - math.radians(course_off_deg)
    al = est.gnss.course.align
    for k in range(n):
        al.check_course(est, int((t0_s + 0.1 * k) * 1e6), 2.0 * math.cos(chi),
                        2.0 * math.sin(chi), 0.1, est.gnss.course.learn, math.radians(0.3),
                        est.gnss.course.direction)


def test_a_yaw_off_within_each_checks_sigma_but_not_the_means_is_unflagged() -> None:
    """GIVEN a flagged heading with a 1 deg sigma at 2 m/s (one check's sigma 3.1 deg: yaw,
    course noise, sideslip),
    WHEN the course checks say the yaw is 8 deg off (inside every single check's 3 sigma of
    9.3 deg, so the run of checks beyond 3 sigma never starts),
    THEN within 5 checks the mean of the last five (3 sigma ~5 deg) drops the flag
    (counted heading_unflagged_drift) and the yaw is left alone; and a yaw 4 deg off (below
    the watch's 5 deg floor) keeps its flag for 10 s."""
    for off, dropped in ((8.0, True), (4.0, False)):
        est = build_estimator(load_config(None, []))
        est.gnss.course.align.yaw_given(est, from_course=True)
        est.P[2, :] = 0.0
        est.P[:, 2] = 0.0
        est.P[2, 2] = math.radians(1.0) ** 2
        # at 2 m/s (a reversing speed) forward checks flag the yaw after max_reverse_s
        _checks(est, 0.0, 310, 0.0)
        assert est.heading_aligned
        yaw = math.atan2(est.mat_nb[1, 0], est.mat_nb[0, 0])
        _checks(est, off, 5 if dropped else 100, 31.0)
        assert est.heading_aligned is not dropped, off
        assert est.counters["heading_unflagged_drift"] == int(dropped)
        assert not est.gnss.course.align.realign_requested
        assert math.atan2(est.mat_nb[1, 0], est.mat_nb[0, 0]) == yaw


def test_one_epoch_turning_a_flagged_yaw_beyond_three_aligned_sigmas_unflags_it() -> None:
    """GIVEN a flagged heading (ground profile, no yaw bank; multirotor: a yaw bank),
    WHEN one epoch's GNSS updates turn the yaw by 7 deg (> 3 x [init] aligned_sd = 6 deg)
    or by 5 deg,
    THEN the 7 deg turn drops the flag (``heading_unflagged_jump``; the yaw was that far off
    while flagged), the 5 deg turn does not, and with a yaw bank the bank keeps the flag."""
    for profile, turn_deg, stays in (("ground", 7.0, False), ("ground", 5.0, True),
                                     ("multirotor", 7.0, True)):
        est = build_estimator(load_config(None, [f"filter.profile={profile}"]))
        est.heading_aligned = True
        est.gnss.course.align.note_yaw_moved(est, math.radians(turn_deg))
        assert est.heading_aligned is stays, (profile, turn_deg)
        assert est.counters["heading_unflagged_jump"] == (0 if stays else 1)


def test_at_reversing_speed_forward_checks_flag_only_after_max_reverse_s() -> None:
    """GIVEN a yaw set from the course and no verdict of the IMU (travel_direction.py),
    WHEN the course checks agree at 2 m/s (below max_reverse_speed_mps: a car backing out
    has the same course), THEN 4 s of them do not flag the heading and 31 s do; at 5 m/s
    4 s do."""
    for speed, n, flagged in ((2.0, 40, False), (2.0, 310, True), (5.0, 40, True)):
        est = build_estimator(load_config(None, []))
        est.gnss.course.align.yaw_given(est, from_course=True)
        est.P[2, 2] = math.radians(1.0) ** 2
        yaw = math.atan2(est.mat_nb[1, 0], est.mat_nb[0, 0])
        al = est.gnss.course.align
        for k in range(n):
            al.check_course(est, int(0.1 * k * 1e6), speed * math.cos(yaw),
                            speed * math.sin(yaw), 0.1, est.gnss.course.learn,
                            math.radians(0.3), est.gnss.course.direction)
        assert est.heading_aligned is flagged, (speed, n)
