"""Lock-out recovery (navd.core.aiding.gnss_recovery): a state the gate no longer lets GNSS
correct is reset to GNSS within ``[filter] max_lockout_s``, with the default config."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from firmware_sim import SimRun, generate, load_scenario
from navd.config import load_config
from navd.core.aiding.base import ACCEPTED, INNOV_FLAG, INNOV_POS, INNOV_VEL, REJECTED
from navd.core.estimator import Estimator
from navd.pipeline import build_estimator
from navd.types import GnssSample, ImuSample

R_EARTH = 6.371e6
KNOCK_DEG = 150.0  # attitude knocked this far in roll (deg): a crash, then at rest


@pytest.fixture(scope="module")
def run() -> SimRun:
    return generate(load_scenario("car480", {"duration_s": 90.0}), seed=3, progress=False)


def _longest_refusal_s(flags: list[tuple[int, float]]) -> float:
    """Longest sensor time from the first of a run of refused epochs to the next accepted."""
    longest, first = 0.0, -1
    for t_us, flag in flags:
        if flag == REJECTED and first < 0:
            first = t_us
        elif flag == ACCEPTED and first >= 0:
            longest = max(longest, (t_us - first) * 1e-6)
            first = -1
    if first >= 0:
        longest = max(longest, (flags[-1][0] - first) * 1e-6)
    return longest


def _drive(est: Estimator, run: SimRun, shift_after_us: int = -1, shift_m: float = 0.0,
           kick_at_us: int = -1, kick_vel_e: float = 0.0, keep: tuple[int, ...] = ()
           ) -> tuple[list[tuple[int, float]], list[tuple[int, float]]]:
    """Push the run; fixes valid from ``shift_after_us`` on are moved ``shift_m`` north; at
    ``kick_at_us`` the estimator's east velocity is corrupted by ``kick_vel_e`` (covariance
    left as it was: a state the filter wrongly trusts); ``keep``: if given, only fixes whose
    index modulo 7 is in it are pushed (uneven intervals).  Returns (t, flag) per epoch for
    position and velocity."""
    pos_flags: list[tuple[int, float]] = []
    vel_flags: list[tuple[int, float]] = []
    kicked = False
    n_fix = -1
    for s in run.samples():
        if isinstance(s, GnssSample):
            n_fix += 1
            if keep and n_fix % 7 not in keep:
                continue
            if 0 <= shift_after_us <= s.t_us:
                s = dataclasses.replace(s, lat_rad=s.lat_rad + shift_m / R_EARTH,
                                        pos_ecef_m=None)
            est.push(s)
            if est.initialized:
                pos_flags.append((s.t_us, float(est.innov[INNOV_POS, INNOV_FLAG])))
                vel_flags.append((s.t_us, float(est.innov[INNOV_VEL, INNOV_FLAG])))
            continue
        est.push(s)
        if isinstance(s, ImuSample) and not kicked and 0 <= kick_at_us <= s.t_us:
            est.vel_n[1] += kick_vel_e
            kicked = True
    return pos_flags, vel_flags


def test_a_persistent_position_offset_is_taken_after_the_lockout_time(run: SimRun) -> None:
    """GIVEN the default config on a 90 s drive,
    WHEN from t = 40 s on every fix is 500 m further north (a receiver that re-converged
    elsewhere: no single outlier, the gate refuses them all),
    THEN the position is reset to GNSS once, so that no more than max_lockout_s (5 s) pass
    from the first refused fix to the next accepted one, and the fixes stay accepted."""
    est = build_estimator(load_config(None, []))
    pos, _ = _drive(est, run, shift_after_us=40_000_000, shift_m=500.0)
    assert est.counters["reset_lockout_pos"] == 1
    assert _longest_refusal_s(pos) <= 5.0
    late = [f for t, f in pos if t > 50_000_000]
    assert late and all(f == ACCEPTED for f in late)
    # the state follows the (shifted) fixes, not the old track
    g = list(run.gnss_samples())[-1]
    dn = (float(est.pos[0]) - (g.lat_rad + 500.0 / R_EARTH)) * R_EARTH
    assert abs(dn) < 10.0


def test_a_velocity_the_filter_wrongly_trusts_is_reset_and_attitude_recovers(
        run: SimRun) -> None:
    """GIVEN the default config, navigating normally,
    WHEN the velocity state is knocked 15 m/s east at t = 40 s while its covariance stays
    small (the filter is certain of a wrong state: every velocity fix is refused),
    THEN the velocity is reset to GNSS (refused for at most 5 s), counted, and at the end
    the heading is within 1 deg of the truth with no lock-out left."""
    est = build_estimator(load_config(None, []))
    _, vel = _drive(est, run, kick_at_us=40_000_000, kick_vel_e=15.0)
    assert est.counters["reset_lockout_vel"] >= 1
    assert _longest_refusal_s(vel) <= 5.0
    assert vel[-1][1] == ACCEPTED
    k = len(run.truth_t_us) - 1
    assert est.t_us == int(run.truth_t_us[k])
    yaw_err = math.degrees(math.atan2(est.mat_nb[1, 0], est.mat_nb[0, 0])
                           - run.truth_euler[k, 2])
    assert abs((yaw_err + 180.0) % 360.0 - 180.0) < 1.0
    assert np.all(np.isfinite(est.P)) and np.all(np.linalg.eigvalsh(est.P) > -1e-12)


def test_no_reset_when_the_fixes_are_merely_noisy(run: SimRun) -> None:
    """GIVEN the default config and the simulator's receiver (noise as reported),
    WHEN the whole drive is replayed,
    THEN no lock-out reset happens (a reset is a repair, not part of normal running)."""
    est = build_estimator(load_config(None, []))
    _drive(est, run)
    assert est.counters["reset_lockout_pos"] == 0
    assert est.counters["reset_lockout_vel"] == 0


def test_max_lockout_zero_disables_the_reset(run: SimRun) -> None:
    """GIVEN ``[filter] max_lockout_s = 0``, WHEN the fixes jump 500 m for good,
    THEN nothing resets and the fixes stay refused (the old behaviour, for comparison)."""
    est = build_estimator(load_config(None, ["filter.max_lockout_s=0"]))
    pos, _ = _drive(est, run, shift_after_us=40_000_000, shift_m=500.0)
    assert est.counters["reset_lockout_pos"] == 0
    assert _longest_refusal_s(pos) > 40.0


def test_one_outlier_after_an_outage_is_not_a_lockout(run: SimRun) -> None:
    """GIVEN the default config and a 10 s GNSS outage at t = 40 s (a tunnel),
    WHEN the first fix after it is 500 m off (multipath) and the following ones are good,
    THEN that fix is refused but nothing is reset: one refusal is an outlier however long
    the gap before it, and the good fixes are accepted."""
    est = build_estimator(load_config(None, []))
    pos_flags: list[tuple[int, float]] = []
    first_after: int | None = None
    for s in run.samples():
        if isinstance(s, GnssSample):
            if 40_000_000 <= s.t_us < 50_000_000:
                continue
            if s.t_us >= 50_000_000 and first_after is None:
                first_after = s.t_us
                s = dataclasses.replace(s, lat_rad=s.lat_rad + 500.0 / R_EARTH,
                                        pos_ecef_m=None)
        est.push(s)
        if isinstance(s, GnssSample) and est.initialized:
            pos_flags.append((s.t_us, float(est.innov[INNOV_POS, INNOV_FLAG])))
    assert dict(pos_flags)[first_after] == REJECTED
    assert est.counters["reset_lockout_pos"] == 0
    assert [f for t, f in pos_flags if t > first_after][:5] == [ACCEPTED] * 5


def test_uneven_fix_intervals_still_end_the_lockout_within_max_lockout(run: SimRun) -> None:
    """GIVEN the default config and fixes that arrive unevenly (every 0.2, 0.2, 0.3 s: the
    10 Hz run with some epochs dropped, like f450_glitch's 0.18-0.25 s),
    WHEN from t = 40 s on every fix is 500 m further north,
    THEN the reset comes early enough that no more than max_lockout_s (5 s) pass from the
    first refused fix to the next accepted one (allowing one nominal interval for the next
    fix gave 5.2 s on f450_glitch)."""
    est = build_estimator(load_config(None, []))
    pos, _ = _drive(est, run, shift_after_us=40_000_000, shift_m=500.0, keep=(0, 2, 4))
    assert est.counters["reset_lockout_pos"] == 1
    assert 4.0 <= _longest_refusal_s(pos) <= 5.0


def _tilted_at_rest(relevel: bool, monkeypatch: pytest.MonkeyPatch) -> tuple[Estimator, list[
        tuple[int, float]], float]:
    """A level vehicle at rest (10 Hz fixes) whose attitude is knocked KNOCK_DEG in roll at
    t = 30 s, covariance untouched (a gyro saturated in a crash).  Returns the estimator,
    the velocity outcomes and the final roll error in units of the filter's roll sigma."""
    from navd.core.aiding import gnss_recovery
    if not relevel:
        monkeypatch.setattr(gnss_recovery, "relevel_at_rest", lambda est: False)
    sc = load_scenario("static", {"duration_s": 60.0, "gnss.rate_hz": 10.0})
    r = generate(sc, seed=1, progress=False)
    est = build_estimator(load_config(None, []))
    vel: list[tuple[int, float]] = []
    knocked = False
    for s in r.samples():
        est.push(s)
        if isinstance(s, GnssSample) and est.initialized:
            vel.append((s.t_us, float(est.innov[INNOV_VEL, INNOV_FLAG])))
        if isinstance(s, ImuSample) and not knocked and s.t_us >= 30_000_000:
            c, sn = math.cos(math.radians(KNOCK_DEG)), math.sin(math.radians(KNOCK_DEG))
            est.mat_nb[:, :] = est.mat_nb @ np.array([[1.0, 0.0, 0.0], [0.0, c, -sn],
                                                      [0.0, sn, c]])
            knocked = True
    k = len(r.truth_t_us) - 1
    roll = math.atan2(est.mat_nb[2, 1], est.mat_nb[2, 2])
    return est, vel, math.degrees(roll - r.truth_euler[k, 0]) / math.degrees(
        est.solution().att_sd_rad[0])


def test_a_tilt_knocked_far_off_at_rest_is_relevelled_at_the_velocity_reset(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN the default config, a vehicle at rest, its attitude knocked 150 deg in roll with
    the covariance left small (log171's crash: the gyro saturated, then upside down at rest),
    WHEN the velocity fixes are refused for max_lockout_s,
    THEN the reset re-levels roll and pitch from the accelerometer (counted), the velocity is
    refused for at most 5 s and accepted at the end, and roll ends within 3 sigma of the
    truth; the control without the re-level still has its velocity refused at the end or
    roll beyond 10 sigma (widening the tilt variance alone cannot undo 150 deg: it was refused
    for the last 30 s through six resets, roll 25 sigma off; from 60 deg it did recover)."""
    est, vel, roll_err = _tilted_at_rest(True, monkeypatch)
    assert est.counters["reset_level_at_rest"] >= 1
    assert _longest_refusal_s(vel) <= 5.0
    assert vel[-1][1] == ACCEPTED
    assert abs(roll_err) < 3.0
    assert np.all(np.isfinite(est.P)) and np.all(np.linalg.eigvalsh(est.P) > -1e-12)
    monkeypatch.undo()
    ctl, ctl_vel, ctl_roll = _tilted_at_rest(False, monkeypatch)
    assert ctl.counters["reset_level_at_rest"] == 0
    assert ctl_vel[-1][1] != ACCEPTED or abs(ctl_roll) > 10.0
