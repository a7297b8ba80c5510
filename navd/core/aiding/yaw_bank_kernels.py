"""Compiled kernels of the yaw bank (:mod:`navd.core.aiding.yaw_bank`), allocation-free.

The bank is a Gaussian sum of small EKFs, one per yaw hypothesis.  Member i assumes that
the true attitude is ``Rz(d_i) C_hat``: the main filter's attitude turned about the local
down axis by its yaw offset d_i (the main filter supplies the tilt and integrates the gyro
with its bias estimates, so a member needs no attitude of its own).  Its state is

    x_i = [vN, vE, d_i, r_i, bN_i, bE_i]

NED horizontal velocity (m/s), yaw offset (rad), its rate (rad/s), and a horizontal specific-
force error (m/s^2, NED).  r is the main filter's own yaw drift, its unestimated gyro bias
about down: common to all members, learned in turns, and what tells the estimator how far its
gyro-bias model is off.  b is what the main filter's tilt and accelerometer-bias errors leave
in the horizontal specific force (a 1 deg tilt error is 0.17 m/s^2): without it, one straight
acceleration cannot tell a yaw error from a tilt error, and a bank driven by a poor tilt
converges confidently to a wrong yaw; with it, yaw comes from accelerations that change in
direction or size (a turn, a stop), which separate the two.

Between two GNSS epochs the main filter's specific-force increments, rotated with C_hat,
sum to ``a = sum C_hat dv_b`` (horizontal NED of the main frame, m/s; gravity and Coriolis
have no or a negligible horizontal part).  Member i predicts

    v_i <- v_i + Rz2(d_i) a + b_i T,  d_i <- d_i + r_i T,
    F = I + E,  E[0, 2] = -aE_i, E[1, 2] = aN_i, E[2, 3] = T, E[0, 4] = E[1, 5] = T

with ``(aN_i, aE_i) = Rz2(d_i) a`` and observes the GNSS horizontal velocity at the antenna,

    h_i(x) = v_i + Rz2(d_i) u,   H = [[1, 0, -uE_i, 0, 0, 0], [0, 1, uN_i, 0, 0, 0]],
    u = (C_hat (w x l))_NE

The members' weights follow the Gaussian likelihood of their innovations (log domain, capped
NIS per epoch, floored relative to the best so that no hypothesis is lost for good), and only
while the horizontal specific force is large enough to make yaw observable.

Buffer layout (float64, :data:`SIZE`): a header, :data:`NMAX` member blocks and a ring of
cumulative increments that lets a fix stamped in the past be matched at its own time.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core import state as st
from navd.core._jit import jit

Arr = npt.NDArray[np.float64]

NMAX = 16  # most members a bank can have

# header
H_N = 0  # members in use
H_TLAST = 1  # t_us of the last fix the members were brought to (-1: not started)
H_CUMN = 2  # ring cumulative sums at that time: north, east (m/s), |yaw turned| (rad)
H_CUME = 3
H_CUMY = 4
H_OFF = 5  # composite yaw offset (rad): the main yaw should turn by this much
H_VAR = 6  # composite variance (rad^2), spread of the members included
H_EXC = 7  # excitation: |low-passed horizontal specific force| less its noise (m/s^2)
H_RI = 8  # ring index of the newest entry (-1: empty)
H_ACCN = 9  # last interval's mean horizontal specific force, main frame N, E (m/s^2)
H_ACCE = 10
H_NIS = 11  # weight-averaged NIS of the last update
H_WUPD = 12  # 1 when the last update also updated the weights
H_DT = 13  # last interval (s)
H_LPN = 14  # low-passed horizontal specific force, main frame N, E (m/s^2)
H_LPE = 15
H_RATE = 16  # composite offset rate (rad/s) and its variance
H_RVAR = 17
H_GVN = 18  # the last fix's horizontal velocity N, E (m/s)
H_GVE = 19
H_GLPN = 20  # low-passed horizontal acceleration from GNSS velocity differences N, E (m/s^2)
H_GLPE = 21
H_GEXC = 22  # |H_GLP| less its noise (m/s^2)
SCR = 24  # scratch (48,)
MEM = 72
MW = 48  # per member: vN, vE, d, r, bN, bE, P (6x6 row-major), log weight, weight, NIS
M_P = 6
M_LW = 42
M_W = 43
M_NIS = 44
RING = MEM + NMAX * MW
RING_LEN = 512
RING_W = 4  # t_us, cumulative N, E (m/s), cumulative |yaw turned| (rad)
SIZE = RING + RING_LEN * RING_W

# results of bank_fix
STARTED = 0
PREDICTED = 1  # members updated, weights left alone (not enough excitation)
WEIGHTED = 2  # members and weights updated
NOT_KEPT = -1  # the fix's time is older than the ring (or the ring is empty)
NO_TIME = -2  # no time passed since the last fix


@jit
def wrap(a: float) -> float:
    """Angle to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@jit
def bank_reset(bb: Arr, n: int) -> None:
    """Forget everything; ``n`` members from the next fix on."""
    for i in range(SIZE):
        bb[i] = 0.0
    bb[H_N] = float(n)
    bb[H_TLAST] = -1.0
    bb[H_RI] = -1.0
    for i in range(RING_LEN):
        bb[RING + i * RING_W] = -1.0


@jit
def bank_imu(bb: Arr, sb: Arr, t_us: float, dt: float) -> None:
    """After the main filter's IMU step: add its compensated velocity increment, rotated
    with its attitude (horizontal NED of the main frame), and the yaw it turned, to the ring."""
    m = st.MAT
    dv0 = sb[st.INC + 3]
    dv1 = sb[st.INC + 4]
    dv2 = sb[st.INC + 5]
    dn = sb[m] * dv0 + sb[m + 1] * dv1 + sb[m + 2] * dv2
    de = sb[m + 3] * dv0 + sb[m + 4] * dv1 + sb[m + 5] * dv2
    r = st.RATE
    wd = sb[m + 6] * sb[r] + sb[m + 7] * sb[r + 1] + sb[m + 8] * sb[r + 2]
    i = int(bb[H_RI])
    if i < 0:
        cn = 0.0
        ce = 0.0
        cy = 0.0
    else:
        o = RING + i * RING_W
        cn = bb[o + 1]
        ce = bb[o + 2]
        cy = bb[o + 3]
    i += 1
    if i >= RING_LEN:
        i = 0
    bb[H_RI] = float(i)
    o = RING + i * RING_W
    bb[o] = t_us
    bb[o + 1] = cn + dn
    bb[o + 2] = ce + de
    bb[o + 3] = cy + abs(wd) * dt


@jit
def ring_at(bb: Arr, t_us: float, tol_us: float) -> int:
    """Offset of the newest ring entry stamped at or before ``t_us + tol_us`` (-1: none)."""
    i = int(bb[H_RI])
    if i < 0:
        return -1
    for _ in range(RING_LEN):
        o = RING + i * RING_W
        t = bb[o]
        if t < 0.0:
            return -1
        if t <= t_us + tol_us:
            return o
        i -= 1
        if i < 0:
            i = RING_LEN - 1
    return -1


@jit
def composite(bb: Arr) -> None:
    """Weighted circular mean of the offsets and the Gaussian-sum variance about it."""
    n = int(bb[H_N])
    sn = 0.0
    cs = 0.0
    for i in range(n):
        o = MEM + i * MW
        w = bb[o + M_W]
        sn += w * math.sin(bb[o + 2])
        cs += w * math.cos(bb[o + 2])
    mean = math.atan2(sn, cs)
    var = 0.0
    rm = 0.0
    for i in range(n):
        o = MEM + i * MW
        d = wrap(bb[o + 2] - mean)
        var += bb[o + M_W] * (bb[o + M_P + 2 * NX + 2] + d * d)
        rm += bb[o + M_W] * bb[o + 3]
    rv = 0.0
    for i in range(n):
        o = MEM + i * MW
        d = bb[o + 3] - rm
        rv += bb[o + M_W] * (bb[o + M_P + 3 * NX + 3] + d * d)
    bb[H_OFF] = mean
    bb[H_VAR] = var
    bb[H_RATE] = rm
    bb[H_RVAR] = rv


NX = 6  # member state size


@jit
def member_f(x: Arr, a_n: float, a_e: float, T: float, out: Arr) -> None:
    """The members' prediction f(x) = [v + Rz2(d) a + b T, d + r T, r, b] (for the Jacobian
    test)."""
    c = math.cos(x[2])
    s = math.sin(x[2])
    out[0] = x[0] + c * a_n - s * a_e + x[4] * T
    out[1] = x[1] + s * a_n + c * a_e + x[5] * T
    out[2] = x[2] + x[3] * T
    out[3] = x[3]
    out[4] = x[4]
    out[5] = x[5]


@jit
def member_h(x: Arr, u_n: float, u_e: float, out: Arr) -> None:
    """The members' measurement h(x) = v + Rz2(d) u (for the Jacobian test)."""
    c = math.cos(x[2])
    s = math.sin(x[2])
    out[0] = x[0] + c * u_n - s * u_e
    out[1] = x[1] + s * u_n + c * u_e


@jit
def predict_member(bb: Arr, o: int, a_n: float, a_e: float, T: float, q_v: float,
                   q_d: float, q_r: float, q_b: float, q_noise: float) -> None:
    """Member at offset ``o``: v + Rz2(d) a + b T, d + r T; P <- F P F^T +
    diag(q_v + P_dd q_noise, same, q_d, q_r, q_b, q_b) with F = I + E (see the module doc);
    ``q_noise``: the variance of each axis of the measured increment a (m/s)^2."""
    c = math.cos(bb[o + 2])
    s = math.sin(bb[o + 2])
    dn = c * a_n - s * a_e
    de = s * a_n + c * a_e
    bb[o] += dn + bb[o + 4] * T
    bb[o + 1] += de + bb[o + 5] * T
    bb[o + 2] = wrap(bb[o + 2] + bb[o + 3] * T)
    p = o + M_P
    w = SCR
    # the increment a is measured: its noise, turned by an offset known only to P_dd, adds
    # P_dd x (its variance) to each axis (the EKF's linearisation would otherwise take the
    # noise for acceleration, and yaw information from it)
    q_v = q_v + bb[p + 2 * NX + 2] * q_noise
    # ... and the information on d an interval gives is |a|^2 less its noise (2 q_noise in
    # expectation), not |a|^2: d's column of the Jacobian takes a shrunk by
    # sqrt(1 - 2 q_noise / |a|^2) (zero for an increment that noise alone explains).  The
    # state itself moves by all of a.
    a2 = a_n * a_n + a_e * a_e
    kap = 1.0 - 2.0 * q_noise / a2 if a2 > 0.0 else 0.0
    kap = math.sqrt(kap) if kap > 0.0 else 0.0
    dn *= kap
    de *= kap
    # rows of F P: row0 = P0 - de P2 + T P4, row1 = P1 + dn P2 + T P5, row2 = P2 + T P3
    for j in range(NX):
        p2 = bb[p + 2 * NX + j]
        p3 = bb[p + 3 * NX + j]
        bb[w + j] = bb[p + j] - de * p2 + T * bb[p + 4 * NX + j]
        bb[w + NX + j] = bb[p + NX + j] + dn * p2 + T * bb[p + 5 * NX + j]
        bb[w + 2 * NX + j] = p2 + T * p3
        for i in range(3, NX):
            bb[w + i * NX + j] = bb[p + i * NX + j]
    # (F P) F^T: the same combination of columns
    for i in range(NX):
        r = w + i * NX
        a2 = bb[r + 2]
        bb[p + i * NX] = bb[r] - de * a2 + T * bb[r + 4]
        bb[p + i * NX + 1] = bb[r + 1] + dn * a2 + T * bb[r + 5]
        bb[p + i * NX + 2] = a2 + T * bb[r + 3]
        for j in range(3, NX):
            bb[p + i * NX + j] = bb[r + j]
    for i in range(NX):
        for j in range(i + 1, NX):
            m = 0.5 * (bb[p + i * NX + j] + bb[p + j * NX + i])
            bb[p + i * NX + j] = m
            bb[p + j * NX + i] = m
    bb[p] += q_v
    bb[p + NX + 1] += q_v
    bb[p + 2 * NX + 2] += q_d
    bb[p + 3 * NX + 3] += q_r
    bb[p + 4 * NX + 4] += q_b
    bb[p + 5 * NX + 5] += q_b


@jit
def update_member(bb: Arr, o: int, vn: float, ve: float, u_n: float, u_e: float,
                  r_var: float, hold_yaw: bool) -> float:
    """EKF update of the member at ``o`` with the GNSS horizontal velocity (vn, ve) m/s at
    the antenna, lever-arm velocity ``u`` (main frame, m/s) and per-axis variance r_var.
    Stores the NIS in the member block; returns -0.5 log det S (-inf: S not positive).

    ``hold_yaw``: the offset d and its rate r are Schmidt consider states in this update (no
    gain; P in Joseph form, exact for any gain).  For epochs without excitation: there the
    increment a in F is noise, and an EKF that takes it for acceleration learns yaw from
    it (multirotor seed 4: every member's offset sigma fell from 22.5 to 4.7 deg in 35 s of
    hover without moving; at the first leg the member nearest the truth, 21 deg away, took
    all the weight at sigma 4 deg, and the main heading was aligned 20 deg off)."""
    c = math.cos(bb[o + 2])
    s = math.sin(bb[o + 2])
    ln = c * u_n - s * u_e
    le = s * u_n + c * u_e
    z0 = vn - bb[o] - ln
    z1 = ve - bb[o + 1] - le
    h0 = -le  # d(ln)/dd
    h1 = ln  # d(le)/dd
    p = o + M_P
    w = SCR
    # P H^T (NX x 2): column a = P[:, a] + h_a P[:, 2]
    for i in range(NX):
        bb[w + 2 * i] = bb[p + i * NX] + h0 * bb[p + i * NX + 2]
        bb[w + 2 * i + 1] = bb[p + i * NX + 1] + h1 * bb[p + i * NX + 2]
    s00 = bb[w] + h0 * bb[w + 4] + r_var
    s01 = bb[w + 1] + h0 * bb[w + 5]
    s11 = bb[w + 3] + h1 * bb[w + 5] + r_var
    det = s00 * s11 - s01 * s01
    if not (det > 0.0) or not (s00 > 0.0):
        bb[o + M_NIS] = math.inf
        return -math.inf
    i00 = s11 / det
    i01 = -s01 / det
    i11 = s00 / det
    nis = z0 * (i00 * z0 + i01 * z1) + z1 * (i01 * z0 + i11 * z1)
    # K = P H^T S^-1 (NX x 2), after P H^T in the scratch
    k = w + 2 * NX
    for i in range(NX):
        a0 = bb[w + 2 * i]
        a1 = bb[w + 2 * i + 1]
        bb[k + 2 * i] = a0 * i00 + a1 * i01
        bb[k + 2 * i + 1] = a0 * i01 + a1 * i11
    if hold_yaw:
        for i in (2, 3):
            bb[k + 2 * i] = 0.0
            bb[k + 2 * i + 1] = 0.0
    for i in range(NX):
        bb[o + i] += bb[k + 2 * i] * z0 + bb[k + 2 * i + 1] * z1
    bb[o + 2] = wrap(bb[o + 2])
    # P - K A^T - A K^T + K S K^T (A = P H^T), written symmetric: Joseph's form, right for the
    # held gain as for the optimal one (where it equals P - K A^T)
    for i in range(NX):
        k0 = bb[k + 2 * i]
        k1 = bb[k + 2 * i + 1]
        ks0 = k0 * s00 + k1 * s01
        ks1 = k0 * s01 + k1 * s11
        for j in range(i, NX):
            v = (bb[p + i * NX + j]
                 - (k0 * bb[w + 2 * j] + k1 * bb[w + 2 * j + 1])
                 - (bb[w + 2 * i] * bb[k + 2 * j] + bb[w + 2 * i + 1] * bb[k + 2 * j + 1])
                 + ks0 * bb[k + 2 * j] + ks1 * bb[k + 2 * j + 1])
            bb[p + i * NX + j] = v
            bb[p + j * NX + i] = v
    for i in range(NX):
        bb[p + i * NX + i] = max(bb[p + i * NX + i], 1e-14)
    bb[o + M_NIS] = nis
    return -0.5 * math.log(det)


# bank_fix parameters (``par``, set once from the config)
P_QV = 0  # VRW^2, m^2/s^3
P_QA = 1  # unmodelled horizontal specific force^2, m^2/s^4
P_QD = 2  # yaw random walk, rad^2/s
P_QS = 3  # gyro scale factor^2, rad per rad turned
P_QR = 4  # offset-rate random walk, (rad/s)^2/s
P_QB = 5  # specific-force error random walk, (m/s^2)^2/s
P_MINACC = 6  # excitation threshold, m/s^2
P_TAU = 7  # excitation low-pass, s
P_NISCAP = 8
P_FLOOR = 9  # log-weight floor below the best, nats
P_D0 = 10  # initial offset sigma, rad
P_R0 = 11  # initial offset-rate sigma, rad/s
P_B0 = 12  # initial specific-force error sigma, m/s^2
N_PAR = 13


@jit
def bank_fix(bb: Arr, sb: Arr, par: Arr, t_us: float, tol_us: float, vn: float, ve: float,
             sd_v: float) -> int:
    """One GNSS horizontal velocity (vn, ve) m/s with per-axis sigma ``sd_v`` stamped at
    ``t_us``: bring the members to that time, update them, and (when excited) their weights.
    ``par`` (N_PAR,): the parameters named P_* above.

    Noise: velocity ``q_v_rate * T + q_a * T^2`` per axis (VRW, and unmodelled horizontal
    specific force such as tilt error x g or vibration, m/s^2 squared as ``q_a``); offset
    ``q_d_rate * T + q_scale * turned`` (a yaw random walk, rad^2/s, and the gyro scale
    factor's share, rad per rad turned); offset rate ``q_r_rate * T`` ((rad/s)^2/s);
    specific-force error ``q_b_rate * T`` ((m/s^2)^2/s).  Members start at offsets evenly
    spread with sigma ``d0_sd``, rate 0 +- ``r0_sd``, specific-force error 0 +- ``b0_sd``.  Weights
    change only while the low-passed horizontal specific-force vector (time constant
    ``tau_exc``), less its noise, is at least ``min_accel``.
    Returns STARTED, PREDICTED, WEIGHTED, NOT_KEPT or NO_TIME.
    """
    q_v_rate = par[P_QV]
    q_a = par[P_QA]
    q_d_rate = par[P_QD]
    q_scale = par[P_QS]
    q_r_rate = par[P_QR]
    q_b_rate = par[P_QB]
    min_accel = par[P_MINACC]
    tau_exc = par[P_TAU]
    nis_cap = par[P_NISCAP]
    lw_floor = par[P_FLOOR]
    d0_sd = par[P_D0]
    r0_sd = par[P_R0]
    b0_sd = par[P_B0]
    o_r = ring_at(bb, t_us, tol_us)
    if o_r < 0:
        return NOT_KEPT
    t_r = bb[o_r]
    n = int(bb[H_N])
    m = st.MAT
    # lever-arm velocity C_hat (w x l), horizontal (main frame)
    r = st.RATE
    lv = st.LEVER
    ux = sb[r + 1] * sb[lv + 2] - sb[r + 2] * sb[lv + 1]
    uy = sb[r + 2] * sb[lv] - sb[r] * sb[lv + 2]
    uz = sb[r] * sb[lv + 1] - sb[r + 1] * sb[lv]
    u_n = sb[m] * ux + sb[m + 1] * uy + sb[m + 2] * uz
    u_e = sb[m + 3] * ux + sb[m + 4] * uy + sb[m + 5] * uz
    r_var = sd_v * sd_v
    if bb[H_TLAST] < 0.0:
        for i in range(n):
            o = MEM + i * MW
            d = -math.pi + (i + 0.5) * 2.0 * math.pi / n
            c = math.cos(d)
            s = math.sin(d)
            bb[o] = vn - (c * u_n - s * u_e)
            bb[o + 1] = ve - (s * u_n + c * u_e)
            bb[o + 2] = d
            bb[o + 3] = 0.0
            bb[o + 4] = 0.0
            bb[o + 5] = 0.0
            for k in range(NX * NX):
                bb[o + M_P + k] = 0.0
            bb[o + M_P] = r_var
            bb[o + M_P + NX + 1] = r_var
            bb[o + M_P + 2 * NX + 2] = d0_sd * d0_sd
            bb[o + M_P + 3 * NX + 3] = r0_sd * r0_sd
            bb[o + M_P + 4 * NX + 4] = b0_sd * b0_sd
            bb[o + M_P + 5 * NX + 5] = b0_sd * b0_sd
            bb[o + M_LW] = 0.0
            bb[o + M_W] = 1.0 / n
            bb[o + M_NIS] = 0.0
        bb[H_TLAST] = t_r
        bb[H_CUMN] = bb[o_r + 1]
        bb[H_CUME] = bb[o_r + 2]
        bb[H_CUMY] = bb[o_r + 3]
        bb[H_EXC] = 0.0
        bb[H_LPN] = 0.0
        bb[H_LPE] = 0.0
        bb[H_GVN] = vn
        bb[H_GVE] = ve
        bb[H_GLPN] = 0.0
        bb[H_GLPE] = 0.0
        bb[H_GEXC] = 0.0
        composite(bb)
        return STARTED
    T = (t_r - bb[H_TLAST]) * 1e-6
    if T <= 0.0:
        return NO_TIME
    a_n = bb[o_r + 1] - bb[H_CUMN]
    a_e = bb[o_r + 2] - bb[H_CUME]
    turned = bb[o_r + 3] - bb[H_CUMY]
    bb[H_TLAST] = t_r
    bb[H_CUMN] = bb[o_r + 1]
    bb[H_CUME] = bb[o_r + 2]
    bb[H_CUMY] = bb[o_r + 3]
    bb[H_DT] = T
    bb[H_ACCN] = a_n / T
    bb[H_ACCE] = a_e / T
    # Excitation is judged on the low-passed specific-force *vector*: it passes through zero
    # where the acceleration changes sign (PX4 #28014), and its noise floor is removed (the
    # filter's steady-state noise power is 2 axes x (VRW^2/T) x g/(2-g)).
    g = min(1.0, T / tau_exc)
    bb[H_LPN] += g * (a_n / T - bb[H_LPN])
    bb[H_LPE] += g * (a_e / T - bb[H_LPE])
    noise2 = 2.0 * q_v_rate / T * g / (2.0 - g)
    e2 = bb[H_LPN] * bb[H_LPN] + bb[H_LPE] * bb[H_LPE] - noise2
    bb[H_EXC] = math.sqrt(e2) if e2 > 0.0 else 0.0
    # The same low-pass of the acceleration GNSS saw (velocity differences: white velocity
    # noise of variance r_var gives each axis (r_var / T^2) x 2 g^2 / (2 - g)).  The IMU's
    # horizontal specific force alone is no evidence of acceleration: at rest or in hover
    # its noise and the main filter's tilt error pass min_accel in some epochs, and each
    # such epoch teaches every member a yaw from nothing (mr_clean seed 12: offset sigmas
    # 17.7 -> 11.0 deg in 2 s at rest; docs/results.md).  A real acceleration shows in both,
    # and its magnitude does not depend on the yaw.
    bb[H_GLPN] += g * ((vn - bb[H_GVN]) / T - bb[H_GLPN])
    bb[H_GLPE] += g * ((ve - bb[H_GVE]) / T - bb[H_GLPE])
    bb[H_GVN] = vn
    bb[H_GVE] = ve
    gnoise2 = 4.0 * r_var / (T * T) * g * g / (2.0 - g)
    e2 = bb[H_GLPN] * bb[H_GLPN] + bb[H_GLPE] * bb[H_GLPE] - gnoise2
    bb[H_GEXC] = math.sqrt(e2) if e2 > 0.0 else 0.0
    q_v = q_v_rate * T + q_a * T * T
    q_d = q_d_rate * T + q_scale * turned
    q_b = q_b_rate * T
    excited = bb[H_EXC] >= min_accel and bb[H_GEXC] >= min_accel
    best = -math.inf
    nis_w = 0.0
    for i in range(n):
        o = MEM + i * MW
        predict_member(bb, o, a_n, a_e, T, q_v, q_d, q_r_rate * T, q_b, q_v_rate * T)
        half_logdet = update_member(bb, o, vn, ve, u_n, u_e, r_var, not excited)
        nis = bb[o + M_NIS]
        nis_w += bb[o + M_W] * min(nis, 1e6)
        if excited:
            bb[o + M_LW] += half_logdet - 0.5 * min(nis, nis_cap)
            if bb[o + M_LW] > best:
                best = bb[o + M_LW]
    bb[H_NIS] = nis_w
    if excited and best > -math.inf:
        tot = 0.0
        for i in range(n):
            o = MEM + i * MW
            lw = max(bb[o + M_LW] - best, -lw_floor)
            bb[o + M_LW] = lw
            w = math.exp(lw)
            bb[o + M_W] = w
            tot += w
        for i in range(n):
            bb[MEM + i * MW + M_W] /= tot
    bb[H_WUPD] = 1.0 if excited else 0.0
    composite(bb)
    return WEIGHTED if excited else PREDICTED


@jit
def bank_rotate(bb: Arr, d: float) -> None:
    """The main filter's attitude was turned about down by ``d`` rad (C <- Rz(d) C): keep
    every hypothesis where it was (offsets minus d) and re-express the ring's sums and the
    low-passed specific force, which were rotated with the old attitude, in the new main
    frame."""
    n = int(bb[H_N])
    for i in range(n):
        o = MEM + i * MW
        bb[o + 2] = wrap(bb[o + 2] - d)
    c = math.cos(d)
    s = math.sin(d)
    x = bb[H_CUMN]
    y = bb[H_CUME]
    bb[H_CUMN] = c * x - s * y
    bb[H_CUME] = s * x + c * y
    x = bb[H_LPN]
    y = bb[H_LPE]
    bb[H_LPN] = c * x - s * y
    bb[H_LPE] = s * x + c * y
    for i in range(RING_LEN):
        o = RING + i * RING_W
        if bb[o] < 0.0:
            continue
        x = bb[o + 1]
        y = bb[o + 2]
        bb[o + 1] = c * x - s * y
        bb[o + 2] = s * x + c * y
    composite(bb)


@jit
def main_yaw(sb: Arr) -> float:
    """ZYX yaw of the main filter's attitude, rad."""
    return math.atan2(sb[st.MAT + 3], sb[st.MAT])


@jit
def rotate_main(sb: Arr, d: float) -> None:
    """Turn the main filter's attitude and its recorded history about down by ``d`` rad
    (C <- Rz(d) C): a heading reset that leaves tilt, velocity and position alone."""
    c = math.cos(d)
    s = math.sin(d)
    m = st.MAT
    for j in range(3):
        x = sb[m + j]
        y = sb[m + 3 + j]
        sb[m + j] = c * x - s * y
        sb[m + 3 + j] = s * x + c * y
    for i in range(st.HIST_LEN):
        o = st.HIST + i * st.HIST_W
        if sb[o] < 0.0:
            continue
        for j in range(3):
            x = sb[o + 1 + j]
            y = sb[o + 4 + j]
            sb[o + 1 + j] = c * x - s * y
            sb[o + 4 + j] = s * x + c * y
