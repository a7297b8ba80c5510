"""When a real flight log is in flight, and how far a solution's tilt is from the log's own
attitude: one definition for ``navd replay --log`` (its closing RMS line) and the benchmarks
(benchmarks/robustness.py, benchmarks/yaw_bank.py).

In flight (times in s from the log's start, the earliest IMU or reference time stamp):

* from **take-off**: the start of the first 1 s window whose gyro rates spread (RMS of the
  per-axis standard deviations) by more than TAKEOFF_RATE_SPREAD_DPS (2 deg/s), motors spun
  up and the airframe moving, unless 3 s in a row at rest (< 1 deg/s) follow within 10 s:
  the vehicle was handled on the ground (:func:`takeoff_s`).  A vehicle carried about by
  hand before a hand launch (the X8) counts as flying from then on; a caller may fix the
  start instead (the X8 benchmark row: 20 s, after its launch at 16.5 s);
* to a **crash**: CRASH_LEAD_S (1 s) before the first sample whose body rate exceeds
  CRASH_RATE_DPS (1000 deg/s, a rate no vehicle flies at but a tumble reaches: log171 hits
  2042 deg/s), else the end of the log.  The tumble builds up before it reaches that rate
  (log171: 100-280 deg/s in the 0.5 s before), and a 10 Hz reference cannot follow it.

Errors are estimate minus reference, wrapped to [-180, 180) deg, at the solution's instants
that have a reference sample within 0.1 s; the reference is the autopilot's own estimate
(ATT, AHRS2, vehicle_attitude, ATTITUDE), magnetometer-aided: not truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from navd.units import RAD2DEG

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

TAKEOFF_RATE_SPREAD_DPS = 2.0
# ... unless the vehicle is at rest again soon after: handled on the ground, not a take-off
REST_SPREAD_DPS = 1.0
REST_RUN_S = 3
REST_LOOKAHEAD_S = 10
# a body rate no vehicle flies at, but a tumbling crash reaches (a consumer gyro's range is
# 2000 deg/s; the real logs fly below 200 deg/s, log171 hits 2042 deg/s in its crash)
CRASH_RATE_DPS = 1000.0
# ... and the tumble into it has begun this long before (s): log171's rate climbs from 11 to
# 2042 deg/s in the 0.6 s before; scoring that last half second against ATT (10 Hz, and an
# estimator of its own losing the attitude) took its roll RMS from 1.57 to 1.96 deg, while
# ending 0.25-2 s before gives 1.56-1.57 deg (docs/results.md, "The crash's onset")
CRASH_LEAD_S = 1.0
REFERENCE_MAX_GAP_US = 100_000

FLIGHT_RULE = (f"take-off: the first 1 s with gyro-rate spread > {TAKEOFF_RATE_SPREAD_DPS:g} "
               f"deg/s not followed within {REST_LOOKAHEAD_S} s by {REST_RUN_S} s at rest "
               f"(< {REST_SPREAD_DPS:g} deg/s); end: a crash ({CRASH_LEAD_S:g} s before the "
               f"first body rate > {CRASH_RATE_DPS:g} deg/s) or the end of the log")


def imu_rates(imu_t_us: I64, imu_inc: F64) -> tuple[I64, F64]:
    """Body rates (rad/s) from IMU increments: ``(t_us[1:], dtheta[1:] / interval)``, the
    interval to the previous sample (at least 1 us).

    Args:
        imu_t_us: (N,) sample times, us; imu_inc: (N, >=3) increments, dtheta first (rad).
    """
    dt = np.maximum(np.diff(imu_t_us), 1) * 1e-6
    return imu_t_us[1:], imu_inc[1:, 0:3] / dt[:, None]


def crash_s(t_us: I64, rates_rps: F64) -> float:
    """Time (s from ``t_us[0]``) at which a crash begins: CRASH_LEAD_S before the first sample
    whose body rate exceeds CRASH_RATE_DPS (not before ``t_us[0]``), NaN if none: flight ends
    there (what follows is a tumble and a vehicle on the ground, not flight; log171 ends
    upside down).

    Args:
        t_us: (N,) sample times, us.
        rates_rps: (N, 3) angular rates, rad/s.
    """
    hit = np.nonzero(np.sqrt(np.sum(rates_rps * rates_rps, axis=1)) * RAD2DEG
                     > CRASH_RATE_DPS)[0]
    if not hit.size:
        return math.nan
    return max(0.0, float((t_us[hit[0]] - t_us[0]) * 1e-6) - CRASH_LEAD_S)


def window_spreads_dps(t_us: I64, rates_rps: F64) -> F64:
    """Gyro-rate spread of each 1 s window from ``t_us[0]``: the RMS of the per-axis standard
    deviations, deg/s; NaN for a window with fewer than 3 samples (a gap).

    Args:
        t_us: (N,) sample times, us, increasing.
        rates_rps: (N, 3) angular rates, rad/s.
    """
    if t_us.size == 0:
        return np.zeros(0)
    w = ((t_us - t_us[0]) // 1_000_000).astype(np.int64)
    edges = np.searchsorted(w, np.arange(int(w[-1]) + 2))
    out = np.full(len(edges) - 1, math.nan)
    for k in range(len(out)):
        i0, i1 = int(edges[k]), int(edges[k + 1])
        if i1 - i0 >= 3:
            out[k] = float(np.sqrt(np.mean(np.var(rates_rps[i0:i1], axis=0)))) * RAD2DEG
    return out


def takeoff_s(t_us: I64, rates_rps: F64) -> float:
    """Start of the first 1 s window (s from ``t_us[0]``) whose gyro rates spread (RMS of the
    per-axis standard deviations) exceeds TAKEOFF_RATE_SPREAD_DPS, motors spun up and the
    airframe moving, and that is not followed within REST_LOOKAHEAD_S by REST_RUN_S
    consecutive windows at rest (spread < REST_SPREAD_DPS): that was the vehicle handled on
    the ground (log171 is picked up at 9 s and 15 s, then rests until its take-off at 71 s).
    At rest a MEMS gyro spreads by a few hundredths (motors off) to a few tenths of a deg/s.
    NaN when no window qualifies.

    Args:
        t_us: (N,) sample times, us, increasing.
        rates_rps: (N, 3) angular rates, rad/s.
    """
    sp = window_spreads_dps(t_us, rates_rps)
    rest = sp < REST_SPREAD_DPS  # NaN (a gap) is not rest
    for k in np.flatnonzero(sp > TAKEOFF_RATE_SPREAD_DPS):
        after = rest[k + 1:k + 1 + REST_LOOKAHEAD_S]
        run = 0
        for r in after:
            run = run + 1 if r else 0
            if run >= REST_RUN_S:
                break
        else:
            return float(k)
    return math.nan


@dataclass(frozen=True)
class FlightWindow:
    """The in-flight part of a log: ``from_s`` (take-off; NaN: none found) to ``to_s``
    (crash; NaN: none, in flight to the end), s from ``t0_us`` (the log's start)."""

    t0_us: int
    from_s: float
    to_s: float

    def mask(self, t_us: I64) -> npt.NDArray[np.bool_]:
        """(K,) the instants ``t_us`` inside the window (none when no take-off was found)."""
        t_s = (t_us - self.t0_us) * 1e-6
        return np.asarray((t_s >= self.from_s) & ~(t_s >= self.to_s))


def flight_window(imu_t_us: I64, imu_inc: F64, t0_us: int,
                  from_s: float | None = None) -> FlightWindow:
    """The in-flight window of a log from its IMU (see the module docstring).

    Args:
        imu_t_us: (N,) IMU times, us; imu_inc: (N, 6) increments (dtheta first, rad).
        t0_us: the log's start (the window's times count from it).
        from_s: a fixed start of flight (s from ``t0_us``) instead of the take-off rule.
    """
    if len(imu_t_us) < 2:
        return FlightWindow(t0_us, math.nan if from_s is None else from_s, math.nan)
    t, rates = imu_rates(imu_t_us, imu_inc)
    off = (int(t[0]) - t0_us) * 1e-6
    start = from_s if from_s is not None else takeoff_s(t, rates) + off
    return FlightWindow(t0_us, start, crash_s(t, rates) + off)


def reference_errors(t_us: I64, angles_rad: F64, ref: tuple[I64, *tuple[F64, ...]],
                     max_gap_us: int = REFERENCE_MAX_GAP_US
                     ) -> tuple[F64, npt.NDArray[np.bool_]]:
    """Angle errors against a reference series (a log's onboard attitude), wrapped.

    Args:
        t_us: (K,) solution times, us.
        angles_rad: (K, J) estimated angles, rad (e.g. roll, pitch[, yaw]).
        ref: reference times (R,) int64 us (R >= 2), then J (R,) angle series, rad, same
            order.
        max_gap_us: an instant counts only where a reference sample is this close.

    Returns:
        (K, J) estimate - reference, rad, in [-pi, pi); (K,) the instants with a reference
        sample within ``max_gap_us``.  The reference is unwrapped before interpolating, so
        an angle through +-180 deg interpolates the short way.
    """
    rt_us = ref[0]
    rt = rt_us.astype(np.float64)
    idx = np.clip(np.searchsorted(rt_us, t_us), 1, len(rt_us) - 1)
    near = np.minimum(np.abs(rt_us[idx] - t_us), np.abs(rt_us[idx - 1] - t_us)) <= max_gap_us
    err = np.empty((len(t_us), len(ref) - 1))
    for j, ang in enumerate(ref[1:]):
        r = np.interp(t_us.astype(np.float64), rt, np.unwrap(ang))
        err[:, j] = (angles_rad[:, j] - r + math.pi) % (2 * math.pi) - math.pi
    return err, near


@dataclass(frozen=True)
class TiltAgreement:
    """Roll and pitch of a solution against a reference over the scored instants.

    ``n``: instants scored; ``*_rms_deg`` / ``*_mean_deg``: RMS and mean of estimate minus
    reference, deg (NaN when ``n`` is 0); ``whole``: no take-off was found, so every instant
    with a reference was scored; ``window``: the flight window used.
    """

    n: int
    roll_rms_deg: float
    pitch_rms_deg: float
    roll_mean_deg: float
    pitch_mean_deg: float
    whole: bool
    window: FlightWindow


def tilt_agreement(t_us: I64, roll_rad: F64, pitch_rad: F64, ref_t_us: I64, ref_roll_rad: F64,
                   ref_pitch_rad: F64, window: FlightWindow) -> TiltAgreement:
    """Roll/pitch RMS of the solution minus the reference over the in-flight instants (every
    instant with a reference sample within 0.1 s when the window has no take-off).

    Args:
        t_us, roll_rad, pitch_rad: (K,) the solution.
        ref_t_us, ref_roll_rad, ref_pitch_rad: (R,) the reference, time-ordered.
        window: from :func:`flight_window`.
    """
    whole = not math.isfinite(window.from_s)
    if len(ref_t_us) < 2 or len(t_us) == 0:
        return TiltAgreement(0, math.nan, math.nan, math.nan, math.nan, whole, window)
    err, near = reference_errors(t_us, np.column_stack([roll_rad, pitch_rad]),
                                 (ref_t_us, ref_roll_rad, ref_pitch_rad))
    used = near if whole else near & window.mask(t_us)
    e = err[used] * RAD2DEG
    if not len(e):
        return TiltAgreement(0, math.nan, math.nan, math.nan, math.nan, whole, window)
    rms = np.sqrt(np.mean(e * e, axis=0))
    mean = np.mean(e, axis=0)
    return TiltAgreement(len(e), float(rms[0]), float(rms[1]), float(mean[0]),
                         float(mean[1]), whole, window)
