"""What every flight-log reader shares: the result type, damage reports, options, and the
side files ``navd replay`` writes for ``navd report`` (reference attitude, aiding).

A reader turns one log into the samples the daemon would push (``navd.types``, SI, NED/FRD,
integer microseconds, time-ordered) plus the log's own attitude estimate as a reference.
Rate-type IMU records become increments in :class:`navd.io.common.RateIntegrator`, the same
zero-order hold the live adapters use, so a log and the equivalent rate CSV give the same
increments bit for bit.

Damage: a reader never raises on bad bytes after a valid start.  It stops at the first
damaged record and says where (byte offset for binary logs, file and line for text), and
everything before that point is returned and replays normally.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np
import numpy.typing as npt

from navd.core.aiding import yaw_bank_kernels as yk
from navd.core.aiding.base import (
    ACCEPTED,
    INNOV_COURSE,
    INNOV_FLAG,
    INNOV_POS,
    INNOV_T,
    INNOV_VEL,
    REJECTED,
)
from navd.core.aiding.yaw_bank import STATE_NAMES
from navd.diag import Counters, RateLimitedLog
from navd.io.common import RateIntegrator, Rejector
from navd.io.csv_replay import ReadReport, merge, read_gnss, read_imu
from navd.types import FixType, GnssSample, ImuSample, PolSample
from navd.units import RAD2DEG as R2D

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

FORMATS = ("csv", "ulog", "dataflash", "tlog", "x8")


# MAVLink MAV_TYPE (HEARTBEAT.type; PX4's MAV_TYPE parameter) -> navd's filter.profile.
# Types without a profile that fits (VTOL, which flies both ways; airships, submarines) map
# to nothing: the replay then keeps the configured one.
MAV_TYPE_PROFILE = {
    1: "fixed_wing",                                   # FIXED_WING
    2: "multirotor", 3: "multirotor", 4: "multirotor",  # QUADROTOR, COAXIAL, HELICOPTER
    13: "multirotor", 14: "multirotor", 15: "multirotor",  # HEXA-, OCTO-, TRICOPTER
    29: "multirotor", 35: "multirotor", 43: "multirotor",  # DODECA-, DECA-, GENERIC_MULTIROTOR
    10: "ground",                                      # GROUND_ROVER
    11: "boat",                                        # SURFACE_BOAT
}
MAV_TYPE_NAMES = {
    0: "GENERIC", 1: "FIXED_WING", 2: "QUADROTOR", 3: "COAXIAL", 4: "HELICOPTER",
    5: "ANTENNA_TRACKER", 6: "GCS", 7: "AIRSHIP", 8: "FREE_BALLOON", 9: "ROCKET",
    10: "GROUND_ROVER", 11: "SURFACE_BOAT", 12: "SUBMARINE", 13: "HEXAROTOR", 14: "OCTOROTOR",
    15: "TRICOPTER", 16: "FLAPPING_WING", 17: "KITE", 18: "ONBOARD_CONTROLLER",
    19: "VTOL_DUOROTOR", 20: "VTOL_QUADROTOR", 21: "VTOL_TILTROTOR", 22: "VTOL_RESERVED2",
    23: "VTOL_RESERVED3", 24: "VTOL_RESERVED4", 25: "VTOL_RESERVED5", 29: "DODECAROTOR",
    35: "DECAROTOR", 43: "GENERIC_MULTIROTOR", 47: "VTOL_GYRODYNE",
}


def vehicle_from_mav_type(mav_type: int, where: str) -> tuple[str, str]:
    """(profile or "", what the log says) for a MAVLink MAV_TYPE value found at ``where``."""
    name = MAV_TYPE_NAMES.get(mav_type, str(mav_type))
    return MAV_TYPE_PROFILE.get(mav_type, ""), f"{where} MAV_TYPE {mav_type} ({name})"


# HEARTBEAT types that are not the vehicle: generic, antenna tracker, ground station,
# companion computer, and peripherals (gimbal .. ) that send their own heartbeat
_NOT_A_VEHICLE = frozenset({0, 5, 6, 18, 26, 27, 30, 31, 32, 33, 34, 36, 37, 38, 39, 40, 41,
                            42, 44, 48})
_MAV_AUTOPILOT_INVALID = 8  # a ground station or peripheral, not a flight controller


def vehicle_from_heartbeats(beats: Sequence[tuple[int, int, int]], imu_sys: int | None
                            ) -> tuple[str, str]:
    """(navd profile or "", what states it) from HEARTBEATs as (system id, MAV_TYPE,
    MAV_AUTOPILOT): those of the flight controller, the system that sent the IMU messages
    (``imu_sys``; any system if none of its heartbeats is there), the most common MAV_TYPE
    among them."""
    own = [b for b in beats
           if b[1] not in _NOT_A_VEHICLE and b[2] != _MAV_AUTOPILOT_INVALID]
    mine = [b for b in own if b[0] == imu_sys] or own
    if not mine:
        return "", ""
    mav_type = Counter(b[1] for b in mine).most_common(1)[0][0]
    return vehicle_from_mav_type(mav_type, "HEARTBEAT")


class LogFormatError(ValueError):
    """The file is not a readable log of the given format at all (nothing could be read)."""


@dataclass(frozen=True)
class LogOptions:
    """Reader settings (SI units).

    h_acc_m, v_acc_m, vel_acc_mps: 1-sigma accuracies assumed where the log carries none
        (the X8 text log never does; PX4/ArduPilot logs do when the receiver reports them).
    geoid_sep_m: geoid undulation N = h_ellipsoid - H_msl, added where a log gives only MSL
        altitude (X8, ArduPilot GPS.Alt without GPA.Und, MAVLink alt).
    max_imu_gap_s: a longer interval between rate samples is a gap, not one long hold.
    gnss_delay_s: receiver latency to remove: a fix stamped t (arrival) is valid at t - delay.
        None: the latency the log itself states, where its format has one (an ArduPilot
        DataFlash log's EKF_VEL_DELAY / EKF_POS_DELAY / GPS_DELAY_MS), else 0.
    imu_instance, gnss_instance: which sensor instance to read where a log has several.
    """

    h_acc_m: float = 2.5
    v_acc_m: float = 5.0
    vel_acc_mps: float = 0.3
    geoid_sep_m: float = 0.0
    max_imu_gap_s: float = 0.1
    gnss_delay_s: float | None = None
    imu_instance: int = 0
    gnss_instance: int = 0


@dataclass(frozen=True)
class LogDamage:
    """Where a log stops being readable.  ``unit`` is "byte" (offset) or "line"."""

    path: str
    unit: str
    position: int
    reason: str

    def __str__(self) -> str:
        return (f"{self.path}: damaged at {self.unit} {self.position}: {self.reason}; "
                f"read up to there")


@dataclass
class Reference:
    """An attitude series from the log's own estimator (not truth): ZYX Euler angles, rad."""

    t_us: I64
    roll_rad: F64
    pitch_rad: F64
    yaw_rad: F64
    source: str = ""

    @classmethod
    def empty(cls, source: str = "") -> Reference:
        z = np.zeros(0)
        return cls(np.zeros(0, dtype=np.int64), z, z.copy(), z.copy(), source)

    def __len__(self) -> int:
        return len(self.t_us)

    def sorted_unique(self) -> Reference:
        """Time-ordered, one row per time stamp (the first), non-finite rows removed."""
        ok = (np.isfinite(self.roll_rad) & np.isfinite(self.pitch_rad)
              & np.isfinite(self.yaw_rad))
        t = self.t_us[ok]
        order = np.argsort(t, kind="stable")
        t = t[order]
        keep = np.ones(len(t), dtype=bool)
        keep[1:] = np.diff(t) > 0
        idx = np.flatnonzero(ok)[order][keep]
        return Reference(self.t_us[idx], self.roll_rad[idx], self.pitch_rad[idx],
                         self.yaw_rad[idx], self.source)

    def cut(self, t_end_us: int) -> Reference:
        m = self.t_us <= t_end_us
        return Reference(self.t_us[m], self.roll_rad[m], self.pitch_rad[m], self.yaw_rad[m],
                         self.source)


class SampleBuilder:
    """Collects IMU and GNSS samples as rows; keeps each stream strictly time-ordered.

    A sample whose time is not after the previous one of its stream is dropped and counted
    (``imu_not_increasing`` / ``gnss_not_increasing``), as the CSV reader does.
    """

    def __init__(self, options: LogOptions, counters: Counters | None = None) -> None:
        self.options = options
        self.counters = counters if counters is not None else Counters()
        self._reject = Rejector(self.counters, RateLimitedLog(_quiet_logger(), 1e9), "log")
        self._rates = RateIntegrator(self._reject, None, round(options.max_imu_gap_s * 1e6))
        self._imu_t: list[int] = []
        self._imu_dt: list[int] = []
        self._imu_v: list[tuple[float, float, float, float, float, float]] = []
        self._gnss_delay_us = round((options.gnss_delay_s or 0.0) * 1e6)
        self._gnss_t: list[int] = []
        self._gnss_v: list[tuple[float, ...]] = []
        self._gnss_fix: list[int] = []

    def set_gnss_delay(self, delay_s: float) -> None:
        """Receiver latency for the fixes added from now on (see LogOptions.gnss_delay_s)."""
        self._gnss_delay_us = round(delay_s * 1e6)

    @property
    def last_imu_t_us(self) -> int:
        return self._imu_t[-1] if self._imu_t else -1

    def add_imu(self, s: ImuSample) -> None:
        if self._imu_t and s.t_us <= self._imu_t[-1]:
            self.counters.inc("imu_not_increasing")
            return
        self._imu_t.append(s.t_us)
        self._imu_dt.append(s.dt_us)
        self._imu_v.append((s.dtheta_x, s.dtheta_y, s.dtheta_z, s.dvel_x, s.dvel_y, s.dvel_z))

    def add_rates(self, t_us: int, gyro_rps: tuple[float, float, float],
                  accel_mps2: tuple[float, float, float], key: object = 0) -> None:
        """A point sample of rate and specific force; held back to the previous sample."""
        s = self._rates.push(key, t_us, gyro_rps, accel_mps2)
        if s is not None:
            self.add_imu(s)

    def add_split(self, acc_t_us: I64, accel_mps2: F64, gyr_t_us: I64, gyro_rps: F64
                  ) -> str:
        """Separate accelerometer and gyro streams (each point samples with its own time
        stamps: ArduPilot ACC/GYR, PX4 sensor_accel/sensor_gyro) as increments at the slower
        stream's time stamps.  Return which stream set the rate ("accel" / "gyro").

        Pairing at the slower rate keeps every increment backed by a real sample of both
        sensors; interpolating the slower one up to the faster rate would invent data.  For
        each interval (T[k-1], T[k]] of the slower stream: its own sample at T[k] is held over
        the interval (the zero-order hold RateIntegrator uses), and the faster stream's
        samples inside the interval are averaged, i.e. their increments summed over it.  An
        interval longer than ``max_imu_gap_s`` (``imu_gap``) or without a sample of the faster
        stream (``imu_unpaired``) is dropped, not bridged.
        """
        at = np.asarray(acc_t_us, dtype=np.int64)
        gt = np.asarray(gyr_t_us, dtype=np.int64)
        if len(at) < 2 or len(gt) < 2:
            return "accel"
        # the slower stream has the longer median interval (robust to a few gaps)
        acc_slow = float(np.median(np.diff(at))) >= float(np.median(np.diff(gt)))
        st, sv, ft, fv = ((at, accel_mps2, gt, gyro_rps) if acc_slow
                          else (gt, gyro_rps, at, accel_mps2))
        sv = np.asarray(sv, dtype=np.float64).reshape(-1, 3)
        fv = np.asarray(fv, dtype=np.float64).reshape(-1, 3)
        order = np.argsort(ft, kind="stable")
        ft, fv = ft[order], fv[order]
        csum = np.vstack([np.zeros((1, 3)), np.cumsum(fv, axis=0)])
        # fast samples with T[k-1] < t <= T[k]
        hi = np.searchsorted(ft, st, side="right")
        max_gap = round(self.options.max_imu_gap_s * 1e6)
        for k in range(1, len(st)):
            dt = int(st[k] - st[k - 1])
            if dt <= 0:
                self.counters.inc("imu_not_increasing")
                continue
            if dt > max_gap:
                self.counters.inc("imu_gap")
                continue
            n = int(hi[k] - hi[k - 1])
            if n <= 0:
                self.counters.inc("imu_unpaired")
                continue
            fast = (csum[hi[k]] - csum[hi[k - 1]]) / n
            slow = sv[k]
            g, a = (fast, slow) if acc_slow else (slow, fast)
            s = dt * 1e-6
            self.add_imu(ImuSample(int(st[k]), dt, float(g[0]) * s, float(g[1]) * s,
                                   float(g[2]) * s, float(a[0]) * s, float(a[1]) * s,
                                   float(a[2]) * s))
        return "accel" if acc_slow else "gyro"

    def add_gnss(self, g: GnssSample) -> None:
        if self._gnss_delay_us:
            g = dataclasses.replace(g, t_us=g.t_us - self._gnss_delay_us)
        if self._gnss_t and g.t_us <= self._gnss_t[-1]:
            self.counters.inc("gnss_not_increasing")
            return
        if g.fix_type < FixType.FIX_3D:
            self.counters.inc("gnss_no_3d_fix")
            return
        self._gnss_t.append(g.t_us)
        self._gnss_v.append((g.lat_rad, g.lon_rad, g.alt_m, g.vel_n, g.vel_e, g.vel_d,
                             g.h_acc_m, g.v_acc_m, g.vel_acc_mps))
        self._gnss_fix.append(int(g.fix_type))

    def accuracy(self, h: float | None, v: float | None, s: float | None
                 ) -> tuple[float, float, float]:
        """Receiver accuracies where given (finite, > 0), else the configured ones."""
        o = self.options

        def pick(x: float | None, default: float) -> float:
            return float(x) if x is not None and math.isfinite(x) and x > 0.0 else default

        return pick(h, o.h_acc_m), pick(v, o.v_acc_m), pick(s, o.vel_acc_mps)

    def build(self, fmt: str, path: str, reference: Reference,
              damage: LogDamage | None = None, notes: list[str] | None = None,
              t_end_us: int | None = None, vehicle: tuple[str, str] = ("", ""),
              lever_arm: tuple[tuple[float, float, float], str] | None = None,
              accel_calibrated: str | None = None) -> LogData:
        """The LogData of what was added.  ``vehicle``: (navd profile or "", what in the
        log states the vehicle type or "") (see :attr:`LogData.vehicle`); ``lever_arm``:
        (antenna position relative to the IMU, what states it) or None;
        ``accel_calibrated``: what states that the logged accelerometer data are calibrated
        (:func:`accel_calibration_from_params`) or None."""
        imu_t = np.asarray(self._imu_t, dtype=np.int64)
        imu_dt = np.asarray(self._imu_dt, dtype=np.int64)
        imu_v = np.asarray(self._imu_v, dtype=np.float64).reshape(-1, 6)
        gnss_t = np.asarray(self._gnss_t, dtype=np.int64)
        gnss_v = np.asarray(self._gnss_v, dtype=np.float64).reshape(-1, 9)
        gnss_fix = np.asarray(self._gnss_fix, dtype=np.int64)
        ref = reference.sorted_unique()
        if t_end_us is not None:
            m = imu_t <= t_end_us
            imu_t, imu_dt, imu_v = imu_t[m], imu_dt[m], imu_v[m]
            g = gnss_t <= t_end_us
            gnss_t, gnss_v, gnss_fix = gnss_t[g], gnss_v[g], gnss_fix[g]
            ref = ref.cut(t_end_us)
        all_notes = list(notes or [])
        snap = self.counters.snapshot()
        skipped = {k: v for k, v in snap.items() if v and k != "imu_first_sample"}
        if skipped:
            all_notes.append("records dropped while reading: " + ", ".join(
                f"{k}={v}" for k, v in sorted(skipped.items())))
        lever, lever_from = lever_arm if lever_arm is not None else (None, "")
        if lever is not None:
            all_notes.append(f"GNSS antenna at ({lever[0]:.3f}, {lever[1]:.3f}, "
                             f"{lever[2]:.3f}) m from the IMU (body FRD): {lever_from}; "
                             "--set gnss.lever_arm_m=... overrides")
        if accel_calibrated:
            all_notes.append(f"accelerometer calibrated by the autopilot ({accel_calibrated}): "
                             "the logged data have its offsets and scales applied")
        return LogData(fmt, path, imu_t, imu_dt, imu_v, gnss_t, gnss_v, gnss_fix, ref, damage,
                       all_notes, vehicle[0], vehicle[1], lever, lever_from,
                       accel_calibrated or "")


# An antenna or IMU position beyond this from the body origin (m) is not a setting of a
# vehicle navd runs on (ArduPilot allows -5..5 m): refused as a garbled parameter.
LEVER_ARM_MAX_M = 10.0


def lever_arm_from_params(params: Mapping[str, float],
                          antenna: Sequence[tuple[str, str, str]],
                          imu: Sequence[tuple[str, str, str]]
                          ) -> tuple[tuple[float, float, float], str] | None:
    """The GNSS antenna's position relative to the IMU (body FRD, m) from an autopilot's
    parameters: the first complete ``antenna`` name triple found in ``params`` minus the
    first complete ``imu`` triple (zero when none).  Autopilots give both positions from the
    body origin (ArduPilot ``GPS_POS1_X``.. / ``GPS1_POS_X``.., ``INS_POS1_X``..; PX4
    ``EKF2_GPS_POS_X``.., ``EKF2_IMU_POS_X``..); navd's ``[gnss] lever_arm_m`` is from the
    IMU.  None when no antenna triple is there, a value is not finite or beyond
    LEVER_ARM_MAX_M, or the difference is zero (the default: nothing stated).

    Why it matters: an antenna off the IMU moves at w x l while the vehicle turns; with the
    lever arm unknown the filter explains that velocity by accelerometer bias and tilt
    (log171: a yaw at 55 deg/s, 0.2 m of lateral offset worth ~1 deg of roll; docs/results.md).
    """
    def triple(names: Sequence[tuple[str, str, str]]) -> tuple[list[float], str] | None:
        for trio in names:
            if all(n in params for n in trio):
                try:
                    v = [float(params[n]) for n in trio]
                except (TypeError, ValueError):
                    return None
                return v, f"{trio[0][:-1]}*"
        return None

    ant = triple(antenna)
    if ant is None:
        return None
    ins = triple(imu)
    vals = ant[0] + (ins[0] if ins is not None else [])
    if not all(math.isfinite(v) and abs(v) <= LEVER_ARM_MAX_M for v in vals):
        return None
    base = ins[0] if ins is not None else [0.0, 0.0, 0.0]
    lever = (ant[0][0] - base[0], ant[0][1] - base[1], ant[0][2] - base[2])
    if lever == (0.0, 0.0, 0.0):
        return None
    said = f"parameters {ant[1]}" + (f" minus {ins[1]}" if ins is not None else "")
    return lever, said


def accel_calibration_from_params(params: Mapping[str, float],
                                  names: Sequence[tuple[tuple[str, str, str],
                                                        tuple[str, str, str]]]) -> str | None:
    """What says the logged accelerometer data are calibrated: the first (offset triple,
    scale triple) of ``names`` whose offsets are all in ``params`` and not all zero, or
    whose scales are there and not all one (the autopilots' "never calibrated" values),
    as "NAME* (x, y, z mg)"; None when none is, or a value is not finite.

    Why it matters: ArduPilot and PX4 subtract these offsets (and apply the scales) before
    they log or publish the IMU's data (ArduPilot ``AP_InertialSensor_Backend``: offsets and
    scaling, then the board rotation), so what is left in the data is the calibration's
    residual and the sensor's drift since, not an uncalibrated MEMS's zero-g offset (the
    consumer grade's 30 mg covers +-50 mg datasheet tolerances)."""
    for offs, scales in names:
        try:
            o = [float(params[n]) for n in offs] if all(n in params for n in offs) else None
            sc = ([float(params[n]) for n in scales] if all(n in params for n in scales)
                  else None)
        except (TypeError, ValueError):
            return None
        vals = (o or []) + (sc or [])
        if not all(math.isfinite(v) for v in vals):
            return None
        if o is not None and any(v != 0.0 for v in o):
            mg = ", ".join(f"{v / 9.80665e-3:.1f}" for v in o)
            return f"{offs[0][:-1]}* ({mg} mg)"
        if sc is not None and any(v != 1.0 for v in sc):
            return f"{scales[0][:-1]}* ({', '.join(f'{v:.4f}' for v in sc)})"
    return None


def _quiet_logger() -> logging.Logger:
    # records dropped while reading a log are summarised in LogData.notes instead
    lg = logging.getLogger("navd.io.logs.read")
    if not lg.handlers:
        lg.propagate = False
        lg.addHandler(logging.NullHandler())
    return lg


@dataclass
class LogData:
    """Everything read from one log.

    imu_t_us, imu_dt_us: (N,) int64; imu_inc: (N, 6) dtheta xyz (rad), dvel xyz (m/s), FRD.
    gnss_t_us: (M,) int64; gnss: (M, 9) lat_rad, lon_rad, alt_m (ellipsoid), vel N/E/D (m/s),
        h_acc_m, v_acc_m, vel_acc_mps; gnss_fix: (M,) FixType values.
    reference: the log's own attitude estimate; damage: where reading stopped, if it did.
    vehicle: the navd ``filter.profile`` of the vehicle type the log itself states
        ("multirotor", "fixed_wing", "ground"), "" when it states none or one no profile
        fits; vehicle_from: what in the log states it ("" when nothing does), e.g.
        "firmware APM:Copter V3.3-dev (ae3192b8)" or "parameter MAV_TYPE 2 (QUADROTOR)".
    lever_arm_m: the GNSS antenna's position relative to the IMU, body FRD, m, where the
        log's parameters state a non-zero one (:func:`lever_arm_from_params`), else None;
        lever_arm_from: the parameters it came from ("" when None).
    accel_calibrated: what in the log states that the autopilot calibrated the accelerometer
        whose data these are (offsets / scales applied before logging), "" when nothing
        does (:func:`accel_calibration_from_params`).
    """

    fmt: str
    path: str
    imu_t_us: I64
    imu_dt_us: I64
    imu_inc: F64
    gnss_t_us: I64
    gnss: F64
    gnss_fix: I64
    reference: Reference
    damage: LogDamage | None = None
    notes: list[str] = field(default_factory=list)
    vehicle: str = ""
    vehicle_from: str = ""
    lever_arm_m: tuple[float, float, float] | None = None
    lever_arm_from: str = ""
    accel_calibrated: str = ""

    @property
    def n_samples(self) -> int:
        return len(self.imu_t_us) + len(self.gnss_t_us)

    def imu_samples(self) -> Iterator[ImuSample]:
        t, dt, v = self.imu_t_us.tolist(), self.imu_dt_us.tolist(), self.imu_inc.tolist()
        for k in range(len(t)):
            r = v[k]
            yield ImuSample(t[k], dt[k], r[0], r[1], r[2], r[3], r[4], r[5])

    def gnss_samples(self) -> Iterator[GnssSample]:
        t, v, fx = self.gnss_t_us.tolist(), self.gnss.tolist(), self.gnss_fix.tolist()
        for k in range(len(t)):
            r = v[k]
            yield GnssSample(t[k], r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8],
                             FixType(fx[k]))

    def samples(self) -> Iterator[ImuSample | GnssSample | PolSample]:
        """The merged, time-ordered stream (a fix follows the IMU sample of the same time)."""
        return merge(self.imu_samples(), self.gnss_samples())

    def summary(self) -> str:
        span = ((self.imu_t_us[-1] - self.imu_t_us[0]) * 1e-6) if len(self.imu_t_us) else 0.0
        return (f"{self.fmt} log {self.path}: {len(self.imu_t_us)} IMU samples over "
                f"{span:.1f} s, {len(self.gnss_t_us)} GNSS fixes, {len(self.reference)} "
                f"reference attitudes ({self.reference.source or 'none'})")

    def write_replay_csv(self, directory: str | Path) -> tuple[Path, Path]:
        """Write the samples as replay CSV (increment form, %.17g: reads back bit for bit)."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        imu_p, gnss_p = d / "imu.csv", d / "gnss.csv"
        with open(imu_p, "w") as fh:
            fh.write("t_us,dt_us,dtheta_x,dtheta_y,dtheta_z,dvel_x,dvel_y,dvel_z\n")
            for s in self.imu_samples():
                fh.write(f"{s.t_us},{s.dt_us},{s.dtheta_x:.17g},{s.dtheta_y:.17g},"
                         f"{s.dtheta_z:.17g},{s.dvel_x:.17g},{s.dvel_y:.17g},{s.dvel_z:.17g}\n")
        with open(gnss_p, "w") as fh:
            fh.write("t_us,lat_deg,lon_deg,alt_m,vel_n,vel_e,vel_d,h_acc_m,v_acc_m,"
                     "vel_acc_mps\n")
            for g in self.gnss_samples():
                fh.write(f"{g.t_us},{math.degrees(g.lat_rad):.17g},"
                         f"{math.degrees(g.lon_rad):.17g},{g.alt_m:.17g},{g.vel_n:.17g},"
                         f"{g.vel_e:.17g},{g.vel_d:.17g},{g.h_acc_m:.17g},{g.v_acc_m:.17g},"
                         f"{g.vel_acc_mps:.17g}\n")
        return imu_p, gnss_p


def read_csv_dir(path: str | Path, options: LogOptions | None = None) -> LogData:
    """A replay-CSV folder (``imu.csv`` + ``gnss.csv``) as LogData; bad rows are noted."""
    d = Path(path)
    rep = ReadReport()
    b = SampleBuilder(options if options is not None else LogOptions())
    for s in read_imu(d / "imu.csv", rep):
        b.add_imu(s)
    for g in read_gnss(d / "gnss.csv", rep):
        b.add_gnss(g)
    notes = [f"skipped {i}" for i in rep.issues[:20]]
    if len(rep.issues) > 20:
        notes.append(f"... {len(rep.issues) - 20} more skipped rows")
    return b.build("csv", str(d), Reference.empty(), None, notes)


# ---------------------------------------------------------------------------------------------
# side files written by ``navd replay`` and read by ``navd report``

REFERENCE_COLS = ("t_us", "roll_deg", "pitch_deg", "yaw_deg")


def write_reference(ref: Reference, fh: TextIO) -> int:
    """Write ``t_us,roll_deg,pitch_deg,yaw_deg`` rows; return the number of rows."""
    fh.write(",".join(REFERENCE_COLS) + "\n")
    t = ref.t_us.tolist()
    r = (ref.roll_rad * R2D).tolist()
    p = (ref.pitch_rad * R2D).tolist()
    y = (ref.yaw_rad * R2D).tolist()
    for k in range(len(t)):
        fh.write(f"{t[k]},{r[k]:.6f},{p[k]:.6f},{y[k]:.6f}\n")
    return len(t)


AIDING_COLS = (
    "t_us", "course_status", "course", "pos_accepted", "pos_rejected", "vel_accepted",
    "vel_rejected", "course_accepted", "course_rejected", "speed_mps", "course_deg",
    "innov_pos_n_m", "innov_pos_e_m", "innov_pos_d_m", "innov_vel_n_mps", "innov_vel_e_mps",
    "innov_vel_d_mps", "innov_course_deg", "gnss_lat_deg", "gnss_lon_deg",
    "gyro_bias_x_dph", "gyro_bias_y_dph", "gyro_bias_z_dph", "accel_bias_x_mg",
    "accel_bias_y_mg", "accel_bias_z_mg", "yaw_sd_deg", "yaw_bank_state", "yaw_bank_yaw_deg",
    "yaw_bank_sd_deg", "yaw_bank_weight_max", "yaw_bank_trials", "yaw_bank_realigned",
    "yaw_bank_suspect",
)


def _bank_cells(est: Estimator) -> str:
    """The ``yaw_bank_*`` cells of an aiding row (see :class:`AidingWriter`)."""
    yb = est.yaw_bank
    c = est.counters
    counts = (f"{int(c.get('yaw_bank_trials', 0))},{int(c.get('yaw_bank_realigned', 0))},"
              f"{int(c.get('yaw_bank_suspect', 0))}")
    if yb is None:
        return f"off,nan,nan,nan,{counts}"
    b = yb.buf
    m = est.mat_nb
    yaw = math.atan2(float(m[1, 0]), float(m[0, 0])) + yb.offset
    yaw = (yaw + math.pi) % (2.0 * math.pi) - math.pi
    w = max(float(b[yk.MEM + i * yk.MW + yk.M_W]) for i in range(yb.n))
    return (f"{STATE_NAMES[yb.state]},{yaw * R2D:.3f},{yb.sd * R2D:.3f},{w:.4f},{counts}")


class AidingWriter:
    """One row per GNSS epoch pushed after navigation started: what the filter did with it.

    Read from the estimator right after the push (``Estimator.innov``, see
    :mod:`navd.core.aiding.base`).  ``course`` is ``used`` (the course update was applied at
    this epoch), ``rejected`` (tried and refused: by its own gate, or the joint velocity +
    course block failed and velocity went alone), or ``off`` (not tried: disabled, waiting
    for speed, yaw rate, ...; ``course_status`` says why).  Counters are cumulative.
    Innovations are GNSS minus the filter's prediction just before the update, as the filter
    formed them (NED metres and m/s at the fix's time of validity, lever arm included; the
    negated ``z`` of the models), empty (nan) for a measurement not formed at this epoch;
    ``innov_vel_d_mps`` is nan when the fix has no vertical velocity.  ``innov_course_deg``
    is wrap(yaw - course), the quantity the completed heading update uses (of the raw GNSS
    velocity when the course was not tried, from 1 m/s); biases are the estimates after
    the update.  ``yaw_bank_*`` (issue 15): the heading bank's state (``search``, ``trial``,
    ``aligned``; ``off`` without a bank: its values are then nan), its composite yaw
    and 1-sigma, its largest member weight after the update, and the cumulative trials,
    realignments (heading resets to the bank) and suspicions (the bank cleared "aligned").
    """

    def __init__(self, fh: TextIO) -> None:
        self._fh = fh
        fh.write(",".join(AIDING_COLS) + "\n")

    def after(self, est: Estimator, g: GnssSample) -> None:
        """Call just after ``est.push(g)``; writes nothing unless ``g`` reached a navigating
        estimator."""
        r = est.innov
        if r[INNOV_POS, INNOV_T] != g.t_us or not est.initialized:
            return
        c = est.counters

        def n(name: str) -> int:
            return int(c.get(name, 0))  # .get: never add keys to the estimator's counters

        flag = r[INNOV_COURSE, INNOV_FLAG]
        course = "used" if flag == ACCEPTED else "rejected" if flag == REJECTED else "off"
        speed = math.hypot(g.vel_n, g.vel_e)
        chi = math.atan2(g.vel_e, g.vel_n) if speed > 0.0 else math.nan
        vd = -float(r[INNOV_VEL, 2]) if math.isfinite(g.vel_d) else math.nan
        pre = (speed, chi * R2D, -float(r[INNOV_POS, 0]), -float(r[INNOV_POS, 1]),
               -float(r[INNOV_POS, 2]), -float(r[INNOV_VEL, 0]), -float(r[INNOV_VEL, 1]), vd,
               float(r[INNOV_COURSE, 0]) * R2D)
        sol = est.solution()
        bg = [b * R2D * 3600.0 for b in sol.gyro_bias_rps]
        ba = [b / 9.80665e-3 for b in sol.accel_bias_mps2]
        status = est.course_status.replace(",", ";")
        f = ",".join(f"{x:.6g}" for x in pre)
        self._fh.write(
            f"{g.t_us},{status},{course},{n('pos_accepted')},{n('pos_rejected')},"
            f"{n('vel_accepted') + n('vel_course_accepted')},"
            f"{n('vel_rejected') + n('vel_course_rejected')},"
            f"{n('course_accepted')},{n('course_rejected')},{f},"
            f"{math.degrees(g.lat_rad):.9f},{math.degrees(g.lon_rad):.9f},"
            f"{bg[0]:.4f},{bg[1]:.4f},{bg[2]:.4f},{ba[0]:.4f},{ba[1]:.4f},{ba[2]:.4f},"
            f"{sol.att_sd_rad[2] * R2D:.5f},{_bank_cells(est)}\n")
