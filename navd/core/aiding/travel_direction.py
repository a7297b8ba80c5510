"""Which way the yaw points, from the IMU's accelerations (docs/design.md §4, "Reversing").

Why.  The course checks (heading_alignment.py) cannot tell a car reversing from a yaw that
is 180 deg wrong: both put the GNSS course behind the body x axis.  They used to excuse
backward motion for ``[heading] max_reverse_s`` and then set the yaw to the course, so a car
that reversed for 45 s had its correct heading turned by 180 deg (and flagged aligned, sigma
0.1-0.3 deg) until it drove forward again; one that backed out of its parking space at the
start took its yaw from the reversed course and was flagged aligned 180 deg off (issue 14).
The IMU tells the two apart whenever the vehicle accelerates or turns: the velocity change
that the GNSS measures over a few seconds must be the specific force integrated through
the filter's attitude.  A yaw error psi rotates the second against the first by psi, so
their angle *is* the yaw error, whichever way the vehicle moves.

What.  Per GNSS epoch, two leaky sums (time constants ``_TAUS``) of the GNSS velocity's
change ``G`` and of the INS's own velocity change ``J`` between epochs (the propagated
velocity at this epoch less the corrected one after the last: no GNSS in it), horizontal,
north-east.  A sum is *decisive* when both exceed ``_K_SIG`` sigma (GNSS velocity noise,
velocity random walk, and what the filter's tilt and accelerometer-bias sigma make over the
time constant) and agree in size; then ``atan2(J x G, J . G)`` estimates the yaw error.
``_CONFIRM_N`` decisive epochs with the same verdict (within 60 deg / beyond 120 deg
/ between), none of another verdict between them and none more than ``_RUN_GAP_S`` after the
last, record it as :attr:`yaw_error` at :attr:`yaw_error_t` (a GNSS glitch moves G alone: it
fails the size test, and it lasts less than the run; an epoch that shows nothing does not
end the run).  The filter's later yaw
corrections rotate ``J`` and the recorded error with the yaw, so a yaw the checks turn by
180 deg is known to be right at once; so does a yaw turned between epochs by more than the
gyro turned it (another aid, a reset).  A gap of more than ``_MAX_GAP_S`` between epochs
restarts the sums.  Used on the ground and boat profiles only (where course checks run).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.units import G0

Arr = npt.NDArray[np.float64]

_TAUS = (2.0, 6.0)  # s: a speed change or a turn's onset / a slow turn
_K_SIG = 4.0  # both velocity changes beyond this many sigma
_SIZE_TOL = 0.3  # |G| and |J| agree to this fraction (+ 3 sigma): else a glitch or a reset
_CONFIRM_N = 5  # decisive epochs with the same verdict, none of another between
_CONFIRM_S = 0.4  # ... spanning at least this long, s
_MAX_GAP_S = 1.5
_RUN_GAP_S = 1.0  # s: a run of verdicts ends when no epoch was decisive for longer
_RIGHT = 60.0 * math.pi / 180.0  # |error| below: the yaw points the way the vehicle does
_FLIP = 120.0 * math.pi / 180.0  # |error| above: the yaw is about 180 deg off
_RESTART_RUN = 30.0 * math.pi / 180.0  # an epoch turning the yaw more: a realignment
_STALE = 30.0 * math.pi / 180.0  # a yaw sigma beyond this voids a confirmation

# state layout: last epoch time (s, -1: none), its GNSS north/east velocity, the corrected
# INS north/east velocity after it, the run's verdict class (-1 none, 0 right, 1 between,
# 2 flipped), its length, its first time, the recorded yaw error (rad) and its time (s,
# -inf: none), the yaw after the last epoch (rad) and its rate about down then (rad/s);
# the last decisive epoch's own yaw error (rad), its sigma (rad), its time (s, -inf: none),
# and the filter's yaw and the GNSS velocity (north, east, m/s) at it
(_T, _VGN, _VGE, _VIN, _VIE, _CLS, _RUN_N, _RUN_T0, _ERR, _ERR_T, _YAW, _RATE, _RAW_ERR,
 _RAW_SD, _RAW_T, _RAW_YAW, _RAW_VN, _RAW_VE) = range(18)
_N = 18


@jit
def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@jit
def specific_force_sd(P: Arr, mat_nb: Arr) -> float:
    """The larger north / east sigma of the horizontal specific-force error the filter
    leaves, m/s^2: tilt x g and accelerometer bias together as the velocity fixes see them
    (correlated, they mostly cancel; the yaw's part is what the monitor tests).  ``P``
    (15, 15) the error covariance (:mod:`navd` order), ``mat_nb`` (3, 3) C_b^n.

    d(dv_dot)/d(phi_N, phi_E) for f^n = (0, 0, -g) is (0, g) north and (-g, 0) east
    (navd.core.errors: [f^n x] phi), d/d(dba) row ``axis`` of C_b^n."""
    g = G0
    var = 0.0
    for axis in range(2):
        h0 = 0.0 if axis == 0 else -g
        h1 = g if axis == 0 else 0.0
        v = (h0 * h0 * P[0, 0] + h1 * h1 * P[1, 1] + 2.0 * h0 * h1 * P[0, 1])
        for j in range(3):
            cj = mat_nb[axis, j]
            v += 2.0 * cj * (h0 * P[0, 12 + j] + h1 * P[1, 12 + j])
            for k in range(3):
                v += cj * mat_nb[axis, k] * P[12 + j, 12 + k]
        var = max(var, v)
    return math.sqrt(max(var, 0.0))


@jit
def _turn(s: Arr, sums: Arr, d_yaw: float) -> None:
    """The filter's yaw was turned by ``d_yaw`` rad: the INS sums and the recorded error
    turn with it (they are what the INS would have said with the new yaw)."""
    c = math.cos(d_yaw)
    sn = math.sin(d_yaw)
    for i in range(sums.shape[0]):
        n = sums[i, 2]
        e = sums[i, 3]
        sums[i, 2] = c * n - sn * e
        sums[i, 3] = sn * n + c * e
    s[_ERR] = _wrap(s[_ERR] - d_yaw)
    if abs(d_yaw) > _RESTART_RUN:
        # a realignment: the run's verdict was about the old yaw
        s[_CLS] = -1.0
        s[_RUN_N] = 0.0


@jit
def _before(s: Arr, sums: Arr, t_s: float, vg_n: float, vg_e: float, vi_n: float,
            vi_e: float, yaw: float, rate_d: float, vel_sd: float, drift_sd: float,
            vrw: float) -> None:
    """TravelDirection.before_epoch's work (its docstring)."""
    dt = t_s - s[_T]
    if s[_T] < 0.0 or not 0.0 < dt <= _MAX_GAP_S:
        sums[:, :] = 0.0
        s[_CLS] = -1.0
        s[_RUN_N] = 0.0
    else:
        # a yaw turned between epochs by more than the gyro turned it was set by
        # something else (another aid, a reset): the sums and the verdict turn with it
        jump = _wrap(yaw - s[_YAW] - 0.5 * (s[_RATE] + rate_d) * dt)
        if abs(jump) > _RESTART_RUN:
            _turn(s, sums, jump)
        if _judge(s, sums, t_s, dt, vg_n - s[_VGN], vg_e - s[_VGE], vi_n - s[_VIN],
                  vi_e - s[_VIE], vel_sd, drift_sd, vrw):
            s[_RAW_YAW] = yaw
            s[_RAW_VN] = vg_n
            s[_RAW_VE] = vg_e
    s[_T] = t_s
    s[_VGN] = vg_n
    s[_VGE] = vg_e


@jit
def _judge(s: Arr, sums: Arr, t_s: float, dt: float, dgn: float, dge: float, din: float,
           die: float, vel_sd: float, drift_sd: float, vrw: float) -> bool:
    """One epoch's velocity changes (GNSS ``dgn, dge``, INS ``din, die``, m/s) into the
    leaky sums, and the verdict; whether the epoch was decisive."""
    best = -1.0
    err = 0.0
    err_sd = 0.0
    for i in range(len(_TAUS)):
        tau = _TAUS[i]
        lam = math.exp(-dt / tau)
        sums[i, 0] = lam * sums[i, 0] + dgn
        sums[i, 1] = lam * sums[i, 1] + dge
        sums[i, 2] = lam * sums[i, 2] + din
        sums[i, 3] = lam * sums[i, 3] + die
        d = drift_sd * tau
        # white noise through the leaky sum: GNSS ~1 fix's worth each (2 for margin), the
        # accelerometer's VRW^2 tau / 2; the specific-force error over tau
        sig = math.sqrt(2.0 * vel_sd * vel_sd + 0.5 * vrw * vrw * tau + d * d)
        gn, ge, jn, je = sums[i, 0], sums[i, 1], sums[i, 2], sums[i, 3]
        ng = math.sqrt(gn * gn + ge * ge)
        nj = math.sqrt(jn * jn + je * je)
        if (ng < _K_SIG * sig or nj < _K_SIG * sig
                or abs(ng - nj) > _SIZE_TOL * max(ng, nj) + 3.0 * sig):
            continue
        if ng / sig > best:
            best = ng / sig
            # the rotation that takes the INS's change onto the GNSS's: the yaw error
            err = math.atan2(jn * ge - je * gn, jn * gn + je * ge)
            # both changes carry ~sig: the angle between them, sqrt(2) sig / |G|
            err_sd = math.sqrt(2.0) * sig / ng
    if best < 0.0:
        # an epoch that shows nothing (below the noise, or sizes apart) does not end a run:
        # one such epoch inside a turn kept a backwards IMU flagged 180 deg off for 98 s
        # (car480, its first turn's five flipped verdicts broken at 41.7 s); a run whose
        # last decisive epoch is older than _RUN_GAP_S does end
        if t_s - s[_RAW_T] > _RUN_GAP_S:
            s[_CLS] = -1.0
            s[_RUN_N] = 0.0
        return False
    s[_RAW_ERR] = err
    s[_RAW_SD] = err_sd
    s[_RAW_T] = t_s
    a = abs(err)
    cls = 0.0 if a < _RIGHT else (2.0 if a > _FLIP else 1.0)
    if cls != s[_CLS]:
        s[_CLS] = cls
        s[_RUN_N] = 0.0
        s[_RUN_T0] = t_s
    s[_RUN_N] += 1.0
    if s[_RUN_N] >= _CONFIRM_N and t_s - s[_RUN_T0] >= _CONFIRM_S:
        s[_ERR] = err
        s[_ERR_T] = t_s
    return True


class TravelDirection:
    """The yaw error the IMU's accelerations show (module doc); fed by GnssAiding."""

    def __init__(self) -> None:
        self._s = np.zeros(_N)
        # per time constant: G north, G east, J north, J east (m/s)
        self._sums = np.zeros((len(_TAUS), 4))
        self.reset()

    def reset(self) -> None:
        s = self._s
        s[:] = 0.0
        s[_T] = -1.0
        s[_CLS] = -1.0
        s[_ERR_T] = -math.inf
        s[_RAW_T] = -math.inf
        self._sums[:] = 0.0

    @property
    def yaw_error(self) -> float:
        """The last recorded yaw error, true minus filter, rad (with the yaw's later
        corrections taken out); meaningful only when :attr:`yaw_error_t` is finite."""
        return float(self._s[_ERR])

    @property
    def yaw_error_t(self) -> float:
        """When :attr:`yaw_error` was last recorded, s (-inf: never since the reset)."""
        return float(self._s[_ERR_T])

    def decisive_mount(self, t_s: float) -> float:
        """The IMU's yaw from the GNSS course, rad (heading of the body x axis less the
        course: the filter's yaw plus the yaw error the epoch at ``t_s`` showed, less the
        course then), or NaN when that epoch was not decisive.  Unlike the yaw error
        alone, it does not depend on where the fixes have put the yaw."""
        s = self._s
        if s[_RAW_T] != t_s or math.hypot(s[_RAW_VN], s[_RAW_VE]) <= 0.0:
            return math.nan
        return _wrap(s[_RAW_YAW] + s[_RAW_ERR] - math.atan2(s[_RAW_VE], s[_RAW_VN]))

    @property
    def decisive_sd(self) -> float:
        """The last decisive epoch's yaw-error sigma, rad (from the sums' noise)."""
        return float(self._s[_RAW_SD])

    def yaw_right(self, p22: float) -> bool:
        """Whether the IMU's last verdict confirmed the yaw (within 60 deg) and the yaw's
        variance ``p22`` (rad^2) has not grown beyond ``_STALE`` since (a long rest without
        heading information lets it wander)."""
        s = self._s
        return bool(math.isfinite(s[_ERR_T]) and abs(s[_ERR]) < _RIGHT
                    and p22 < _STALE * _STALE)

    def yaw_between_since(self, t0_s: float) -> bool:
        """Whether the IMU showed the yaw 60-120 deg off at or after ``t0_s``: neither
        forward nor backward (never seen on the benchmark's ground and boat cases, seeds
        1-3; an IMU turned on the vehicle, unstated, shows its mounting)."""
        s = self._s
        return bool(s[_ERR_T] >= t0_s and _RIGHT <= abs(s[_ERR]) <= _FLIP)

    def yaw_flipped_since(self, t0_s: float) -> bool:
        """Whether the IMU showed the yaw about 180 deg off at or after ``t0_s``."""
        s = self._s
        return bool(s[_ERR_T] >= t0_s and abs(s[_ERR]) > _FLIP)

    def before_epoch(self, t_s: float, vg_n: float, vg_e: float, vel_n: Arr, yaw: float,
                     rate_d: float, vel_sd: float, drift_sd: float, vrw: float) -> None:
        """One epoch's GNSS velocity (``vg_n, vg_e``, m/s, at ``t_s``) against the INS
        velocity ``vel_n`` (3,) NED m/s propagated to it, before the epoch's updates;
        ``yaw`` rad and ``rate_d`` rad/s (the body rate about down) the filter's now.
        ``vel_sd``: the fix's per-axis velocity sigma, m/s; ``drift_sd``: the sigma of the
        filter's horizontal specific-force error (:func:`specific_force_sd`), m/s^2;
        ``vrw``: the accelerometer's white noise, m/s/sqrt(s)."""
        _before(self._s, self._sums, t_s, vg_n, vg_e, float(vel_n[0]), float(vel_n[1]),
                yaw, rate_d, vel_sd, drift_sd, vrw)

    def after_epoch(self, vel_n: Arr, yaw: float, rate_d: float, d_yaw: float) -> None:
        """The epoch's updates are done: ``vel_n`` (3,) NED m/s is the corrected velocity,
        ``yaw`` rad and ``rate_d`` rad/s the filter's yaw and body rate about down now,
        ``d_yaw`` rad how far the updates turned the yaw."""
        s = self._s
        s[_VIN] = vel_n[0]
        s[_VIE] = vel_n[1]
        s[_YAW] = yaw
        s[_RATE] = rate_d
        if d_yaw != 0.0:
            _turn(s, self._sums, d_yaw)
