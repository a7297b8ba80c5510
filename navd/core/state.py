"""The estimator's memory: one float64 buffer carved into named views at fixed offsets.

Every array the filter touches lives here, allocated once.  Python holds numpy views of
the same memory (``StateViews``); compiled kernels receive only the buffer and slice it
themselves.  This is not just tidiness: numba boxes every array argument on each call,
and a 25-argument kernel call leaves ~1 KB of transient Python garbage where a
one-buffer call leaves ~80 B, which is what keeps a steady-state step allocation-free.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core import kalman
from navd.core._jit import jit
from navd.core.aiding import gnss_heading, gnss_position, gnss_velocity
from navd.core.aiding.gyro_rest import rest_push
from navd.core.aiding.imu_noise import noise_push
from navd.core.rotation import exp_into

Arr = npt.NDArray[np.float64]

MAT = 0  # C_b^n (3, 3)
VEL = 9  # vel_n (3,) m/s
POS = 12  # lat rad, lon rad, alt m
DOV = 15  # xi rad, eta rad, dg_D m/s^2
BG = 18  # gyro bias rad/s, body
BA = 21  # accel bias m/s^2, body
INC = 24  # compensated increments (6,)
PREV = 30  # previous increments (6,)
ACC = 36  # propagation accumulators (8,)
RATE = 44  # compensated body rate (3,) rad/s
LEVER = 47  # GNSS lever arm, body FRD (3,) m
Q = 50  # continuous noise densities (15,)
X = 65  # error state (15,)
P = 80  # covariance (15, 15)
F = 305  # error dynamics (15, 15)
A = 530  # scratch (15, 15)
B = 755  # scratch (15, 15)
WORK = 980  # scratch (8, 3, 3)
H = 1052  # measurement rows (4, 15)
Z = 1112  # innovations (4,)
R = 1116  # measurement covariance (4, 4)
S = 1132  # scratch (4, 4)
L = 1148  # scratch (4, 4)
PH = 1164  # scratch (15,)
W4 = 1179  # scratch (4,)
M3 = 1183  # scratch (3, 3)
SAVE = 1192  # the present nominal state and body rate while a past one is swapped in (18,)
HIST_LEN = 512  # past nominal states kept: 0.5 s at 1 kHz, 5 s at 100 Hz
# t_us, C_b^n (9), vel_n (3), pos (3), compensated body rate (3): a delayed fix's lever-arm
# velocity C (w x l) is the antenna's at its own time, when the vehicle may have been
# turning at another rate (a 60 deg/s yaw with 0.2 s of latency; replays, which push each
# fix at its time of validity, never swap: docs/results.md)
HIST_W = 19
HIST_I = 1210  # index of the newest entry (stored as float); -1 when empty
HIST = 1211  # ring (HIST_LEN, HIST_W)
DPREV = HIST + HIST_LEN * HIST_W  # previous change of the angle increment (3,) rad
# F's multirotor specific-force model (kalman.multirotor_f): low-passes, time constant
# (s; 0: off), rotor-drag coefficient and its regression (kalman.FLP_N)
FLP = DPREV + 3
# the gyro scale-factor allowance's variance and accumulators (kalman.gyro_scale_allowance)
SF = FLP + kalman.FLP_N
# the IMU's mounting ([imu] mount_*_deg): C_s^b (3, 3) taking the IMU's axes to the body's,
# then 1.0 when it is not the identity (the identity skips the product)
MOUNT = SF + kalman.SF_N
SIZE = MOUNT + 10


class StateViews:
    """Named numpy views into the buffer (see the offsets above for shapes and units)."""

    def __init__(self, buf: Arr) -> None:
        assert buf.shape == (SIZE,)
        self.buf = buf
        self.mat_nb = buf[MAT:MAT + 9].reshape(3, 3)
        self.vel_n = buf[VEL:VEL + 3]
        self.pos = buf[POS:POS + 3]
        self.dov = buf[DOV:DOV + 3]
        self.bias_g = buf[BG:BG + 3]
        self.bias_a = buf[BA:BA + 3]
        self.prev_inc = buf[PREV:PREV + 6]
        self.dprev = buf[DPREV:DPREV + 3]
        self.acc = buf[ACC:ACC + 8]
        self.rate_b = buf[RATE:RATE + 3]
        self.lever_b = buf[LEVER:LEVER + 3]
        self.q = buf[Q:Q + 15]
        self.x = buf[X:X + 15]
        self.P = buf[P:P + 225].reshape(15, 15)
        self.work = buf[WORK:WORK + 72].reshape(8, 3, 3)
        self.H = buf[H:H + 60].reshape(4, 15)
        self.z = buf[Z:Z + 4]
        self.R = buf[R:R + 16].reshape(4, 4)
        self.M = buf[M3:M3 + 9].reshape(3, 3)
        self.hist = buf[HIST:HIST + HIST_LEN * HIST_W].reshape(HIST_LEN, HIST_W)
        self.f_lp = buf[FLP:FLP + kalman.FLP_N]
        self.sf = buf[SF:SF + kalman.SF_N]
        self.mat_bs = buf[MOUNT:MOUNT + 9].reshape(3, 3)


@jit
def imu_step(buf: Arr, t_us: float, dtx: float, dty: float, dtz: float, dvx: float,
             dvy: float, dvz: float, dt: float, coning: bool, cov_interval: float) -> bool:
    """:func:`navd.core.kalman.imu_step` on the buffer, then record the state in history."""
    done = kalman.imu_step(
        buf[MAT:MAT + 9].reshape((3, 3)), buf[VEL:VEL + 3], buf[POS:POS + 3],
        buf[DOV:DOV + 3], buf[BG:BG + 3], buf[BA:BA + 3], buf[INC:INC + 6],
        buf[PREV:PREV + 6], buf[DPREV:DPREV + 3], buf[ACC:ACC + 8], dtx, dty, dtz, dvx, dvy,
        dvz, dt, coning,
        cov_interval, buf[P:P + 225].reshape((15, 15)), buf[F:F + 225].reshape((15, 15)),
        buf[Q:Q + 15], buf[A:A + 225].reshape((15, 15)), buf[B:B + 225].reshape((15, 15)),
        buf[WORK:WORK + 72].reshape((8, 3, 3)), buf[RATE:RATE + 3], buf[FLP:FLP + kalman.FLP_N],
        buf[SF:SF + kalman.SF_N])
    i = int(buf[HIST_I]) + 1
    if i >= HIST_LEN:
        i = 0
    buf[HIST_I] = i
    o = HIST + i * HIST_W
    buf[o] = t_us
    for k in range(15):
        buf[o + 1 + k] = buf[MAT + k]  # MAT, VEL, POS are contiguous
    for k in range(3):
        buf[o + 16 + k] = buf[RATE + k]
    return done


@jit
def mount_turn(buf: Arr, x: float, y: float, z: float) -> tuple[float, float, float]:
    """An IMU-axes vector (x, y, z) in the body's axes: C_s^b of ``[imu] mount_*_deg``."""
    m = MOUNT
    return (buf[m] * x + buf[m + 1] * y + buf[m + 2] * z,
            buf[m + 3] * x + buf[m + 4] * y + buf[m + 5] * z,
            buf[m + 6] * x + buf[m + 7] * y + buf[m + 8] * z)


@jit
def rest_then_step(acc: Arr, noise: Arr, buf: Arr, t_us: float, dtx: float, dty: float,
                   dtz: float, dvx: float, dvy: float, dvz: float, dt: float, window_s: float,
                   coning: bool, cov_interval: float) -> bool:
    """A navigating IMU sample in one kernel call (issue 18): :func:`noise_push` into the
    white-noise measurement ``noise``, :func:`rest_push` into the rest detector's
    accumulators ``acc``, then :func:`imu_step`, unless the sample completed a rest window:
    then True, and no step (the caller closes the window first)."""
    noise_push(noise, buf[Q:Q + 15], t_us, dtx, dty, dtz, dvx, dvy, dvz, dt)
    if rest_push(acc, dtx, dty, dtz, dvx, dvy, dvz, dt, window_s):
        return True
    imu_step(buf, t_us, dtx, dty, dtz, dvx, dvy, dvz, dt, coning, cov_interval)
    return False


@jit
def history_reset(buf: Arr) -> None:
    buf[HIST_I] = -1.0
    for i in range(HIST_LEN):
        buf[HIST + i * HIST_W] = -1.0


@jit
def history_swap(buf: Arr, t_us: float, tol_us: float) -> bool:
    """Swap in the nominal state recorded at ``t_us`` (within tol_us); False if not kept.

    Measurements older than the newest IMU sample are linearised about the state at their
    own time of validity; their correction is then applied to the present state (the error
    state changes little over a fraction of a second).
    """
    i = int(buf[HIST_I])
    if i < 0:
        return False
    for _ in range(HIST_LEN):
        o = HIST + i * HIST_W
        t = buf[o]
        if t < 0.0:
            return False
        if abs(t - t_us) <= tol_us:
            for k in range(15):
                buf[SAVE + k] = buf[MAT + k]
                buf[MAT + k] = buf[o + 1 + k]
            for k in range(3):
                buf[SAVE + 15 + k] = buf[RATE + k]
                buf[RATE + k] = buf[o + 16 + k]
            return True
        if t < t_us:
            return False
        i -= 1
        if i < 0:
            i = HIST_LEN - 1
    return False


@jit
def history_restore(buf: Arr) -> None:
    for k in range(15):
        buf[MAT + k] = buf[SAVE + k]
    for k in range(3):
        buf[RATE + k] = buf[SAVE + 15 + k]


@jit
def update(buf: Arr, m: int, gate: float, hold: int, hold_mask: int = 0,
           lag: float = 0.0) -> float:
    """:func:`navd.core.kalman.gated_update` of the block in H, z, R (first m rows).

    ``lag`` (s): the block measures the state of that long ago (a delayed fix linearised
    about its time of validity, :meth:`navd.core.estimator.Estimator.state_at`), while P is
    the present one.  With x_now = Phi x_then + w, w the process noise since, of covariance
    Q_d = int Phi(now, s) Q Phi(now, s)^T ds (:func:`_lag_noise`), the measurement carries
    no information on w: the update is the one of Phi P_then Phi^T = P - Q_d, and Q_d is
    added back after it.  Updating the present P instead took the information as covering
    w too: car_foreign (fixes 0.1 s late, VRW 0.3 m/s/sqrt(s): 0.095 m/s of velocity noise
    per lag against a 0.13 m/s sigma) had its velocity NEES at 4.7, 2.8 without the latency
    (docs/results.md, "A late fix's covariance").  P - Q_d is positive definite when P came
    from the propagation over the lag; where it did not (an update of an older fix, a reset
    or a noise scale changed within the lag) Q_d is halved until it is (Cholesky, up to
    four times), else not taken out."""
    Pm = buf[P:P + 225].reshape((15, 15))
    D = buf[A:A + 225].reshape((15, 15))  # scratch: the propagation's, unused here
    f = 0.0
    if lag > 0.0:
        f = _lag_noise(buf, Pm, D, lag)
        for i in range(15):
            for j in range(15):
                Pm[i, j] -= f * D[i, j]
    nis = kalman.gated_update(
        buf[X:X + 15], Pm, buf[H:H + 60].reshape((4, 15)),
        buf[Z:Z + 4], buf[R:R + 16].reshape((4, 4)), m, gate,
        buf[S:S + 16].reshape((4, 4)), buf[L:L + 16].reshape((4, 4)), buf[PH:PH + 15],
        buf[W4:W4 + 4], hold, hold_mask)
    if f > 0.0:
        for i in range(15):
            for j in range(15):
                Pm[i, j] += f * D[i, j]
    return nis


@jit
def _lag_noise(buf: Arr, Pm: Arr, D: Arr, lag: float) -> float:
    """The process noise of the last ``lag`` s into ``D`` (15, 15): Q T + (F Q + Q F^T) T^2/2
    + F Q F^T T^3/3 (Q = diag(q), F the last error dynamics: the gyro's noise turned into
    velocity error over the lag is in it); returns the share f of it (1, 1/2, .. 1/8, or 0)
    for which P - f D is positive definite (its Cholesky in the scratch B)."""
    Fm = buf[F:F + 225].reshape((15, 15))
    t1, t2, t3 = lag, 0.5 * lag * lag, lag * lag * lag / 3.0
    for i in range(15):
        qi = buf[Q + i]
        for j in range(15):
            qj = buf[Q + j]
            fqf = 0.0
            for k in range(15):
                fqf += Fm[i, k] * buf[Q + k] * Fm[j, k]
            D[i, j] = (qi * t1 if i == j else 0.0) + (Fm[i, j] * qj + qi * Fm[j, i]) * t2 \
                + fqf * t3
    Lc = buf[B:B + 225].reshape((15, 15))
    f = 1.0
    for _ in range(4):
        if _minus_is_pd(Pm, D, f, Lc):
            return f
        f *= 0.5
    return 0.0


@jit
def _minus_is_pd(Pm: Arr, D: Arr, f: float, Lc: Arr) -> bool:
    """Whether Pm - f D is positive definite (its Cholesky factor into ``Lc``)."""
    for i in range(15):
        for j in range(i + 1):
            v = Pm[i, j] - f * D[i, j]
            for k in range(j):
                v -= Lc[i, k] * Lc[j, k]
            if i == j:
                if v <= 0.0:
                    return False
                Lc[i, i] = math.sqrt(v)
            else:
                Lc[i, j] = v / Lc[j, j]
    return True


@jit
def turn_tilt_cov(buf: Arr, d: float) -> None:
    """P <- G P G^T, G turning the tilt error (phiN, phiE) by ``d`` rad about down: the
    heading correction ``d`` (the error state's phiD) is about to turn the attitude.

    The filter's tilt is the mismatch of the estimated down direction in navigation
    coordinates, ``phi x z = z - C_hat C^T z``: what F's ``f x phi`` turns into velocity
    error and what GNSS velocity measures.  Turning C_hat by d about down turns that
    mismatch by d in navigation coordinates (``z - Rz(d) C_hat C^T z = Rz(d) (z - C_hat
    C^T z)``) and leaves it fixed in the body, where the accelerometer bias lives; a tilt
    correction moves the mismatch but does not turn it, and no heading error enters it.
    Left unturned (G = I, as error-state filters commonly do), P keeps the tilt /
    accelerometer-bias pairing that levelling taught in the old frame while F pairs them in
    the new one, so every heading correction looks like the body having turned, which is
    what separates tilt from bias: the tilt sigma falls with no information to show for it
    (accel_20mg_mr seed 5, heading corrected by tens of degrees over its first legs: roll
    sigma 0.64 deg at 120 s against an information floor of 1.20 deg, roll 2.5 deg off;
    turned: 1.29 deg, 0.8 deg off; docs/results.md, issue 14).  The textbook first-order
    reset ``I + [phi_hat/2 x]`` is that of the rotation vector of the whole error, whose
    horizontal part is not this mismatch once the heading error is large.  The yaw bank's
    heading reset (``YawBank._set_main_yaw``) turns P the same way."""
    if d == 0.0:
        return
    c = math.cos(d)
    s = math.sin(d)
    for k in range(15):
        a0 = buf[P + k]
        a1 = buf[P + 15 + k]
        buf[P + k] = c * a0 - s * a1
        buf[P + 15 + k] = s * a0 + c * a1
    for k in range(15):
        o = P + 15 * k
        a0 = buf[o]
        a1 = buf[o + 1]
        buf[o] = c * a0 - s * a1
        buf[o + 1] = s * a0 + c * a1


@jit
def inject(buf: Arr) -> None:
    """Fold the error state into the nominal state and into the recorded history.

    The history must carry the correction too, or a later delayed measurement would be
    linearised about a state that no longer matches the present one.
    """
    e = buf[WORK + 36:WORK + 45].reshape((3, 3))
    exp_into(e, buf[X], buf[X + 1], buf[X + 2])
    turn_tilt_cov(buf, buf[X + 2])
    n = int(buf[HIST_I])
    if n >= 0:
        for i in range(HIST_LEN):
            o = HIST + i * HIST_W
            if buf[o] < 0.0:
                continue
            for c in range(3):
                a0 = buf[o + 1 + c]
                a1 = buf[o + 4 + c]
                a2 = buf[o + 7 + c]
                for r in range(3):
                    buf[o + 1 + 3 * r + c] = e[r, 0] * a0 + e[r, 1] * a1 + e[r, 2] * a2
            for k in range(3):
                buf[o + 10 + k] -= buf[X + 3 + k]
                buf[o + 13 + k] -= buf[X + 6 + k]
    kalman.inject(buf[X:X + 15], buf[MAT:MAT + 9].reshape((3, 3)), buf[VEL:VEL + 3],
                  buf[POS:POS + 3], buf[BG:BG + 3], buf[BA:BA + 3],
                  buf[WORK:WORK + 72].reshape((8, 3, 3)))


@jit
def fill_position(buf: Arr, lat: float, lon: float, alt: float, sd_h: float,
                  sd_v: float, delay_var: float = 0.0) -> int:
    """Position rows; ``delay_var`` (s^2): variance of the fix's unknown latency, whose
    position error v dt joins R (:func:`navd.core.aiding.gnss_position.delay_noise`)."""
    m = gnss_position.fill(buf[H:H + 60].reshape((4, 15)), buf[Z:Z + 4],
                           buf[R:R + 16].reshape((4, 4)), buf[MAT:MAT + 9].reshape((3, 3)),
                           buf[POS:POS + 3], buf[LEVER:LEVER + 3], lat, lon, alt, sd_h, sd_v)
    if delay_var > 0.0:
        gnss_position.delay_noise(buf[R:R + 16].reshape((4, 4)), buf[VEL:VEL + 3], delay_var)
    return m


# span of the INS velocity change that stands for the vehicle's acceleration in the latency
# allowance (at most the ring's, 0.5 s at 1 kHz): long enough that the accelerometer's white
# noise in it stays small (a consumer VRW of 0.3 m/s/sqrt(s) leaves 0.3 m/s^2 per axis over
# 1 s; over 0.4 s, 0.47, which cost the clean car 40 % of its heading accuracy)
ACCEL_SPAN_US = 1e6


@jit
def history_accel(buf: Arr) -> tuple[float, float, float]:
    """The NED acceleration (m/s^2) over the newest ~ACCEL_SPAN_US of the history ring, from
    its velocities (every correction moves all entries alike, so their difference is the
    propagation's); zeros when the ring holds less than 50 ms."""
    i = int(buf[HIST_I])
    if i < 0:
        return 0.0, 0.0, 0.0
    o_new = HIST + i * HIST_W
    t_new = buf[o_new]
    o_old = o_new
    for _ in range(HIST_LEN - 1):
        i -= 1
        if i < 0:
            i = HIST_LEN - 1
        o = HIST + i * HIST_W
        t = buf[o]
        if t < 0.0 or t > t_new:
            break
        o_old = o
        if t_new - t >= ACCEL_SPAN_US:
            break
    dt = (t_new - buf[o_old]) * 1e-6
    if dt < 0.05:
        return 0.0, 0.0, 0.0
    return ((buf[o_new + 10] - buf[o_old + 10]) / dt, (buf[o_new + 11] - buf[o_old + 11]) / dt,
            (buf[o_new + 12] - buf[o_old + 12]) / dt)


@jit
def fill_velocity(buf: Arr, vn: float, ve: float, vd: float, sd_h: float, sd_v: float,
                  lever_var: float, delay_var: float = 0.0) -> int:
    """Velocity rows; ``delay_var`` (s^2): variance of the fix's unknown latency, whose
    velocity error a dt joins R (:func:`navd.core.aiding.gnss_velocity.delay_noise`, a from
    :func:`history_accel`)."""
    m = gnss_velocity.fill(buf[H:H + 60].reshape((4, 15)), buf[Z:Z + 4],
                           buf[R:R + 16].reshape((4, 4)), buf[MAT:MAT + 9].reshape((3, 3)),
                           buf[VEL:VEL + 3], buf[RATE:RATE + 3], buf[LEVER:LEVER + 3],
                           vn, ve, vd, sd_h, sd_v, lever_var)
    if delay_var > 0.0:
        ax, ay, az = history_accel(buf)
        gnss_velocity.delay_noise(buf[R:R + 16].reshape((4, 4)), ax, ay, az, delay_var)
    return m


@jit
def course_row(buf: Arr, row: int, vn: float, ve: float, sd_h: float, sd_beta: float) -> None:
    gnss_heading.course_row(buf[H:H + 60].reshape((4, 15)), buf[Z:Z + 4],
                            buf[R:R + 16].reshape((4, 4)), row,
                            buf[MAT:MAT + 9].reshape((3, 3)), buf[RATE:RATE + 3],
                            buf[LEVER:LEVER + 3], vn, ve, sd_h, sd_beta)
