"""Kalman filter kernels on preallocated arrays: propagation, gated update, injection.

Propagation (interval T, F held constant over it)::

    Phi = I + F T + (F T)^2 / 2,    P <- Phi P Phi^T + Qd,    Qd = diag(q) T

Update of a small measurement block ``z = H x + v``, ``v ~ N(0, R)`` (m <= 4) with a full,
possibly correlated or singular R (GNSS course shares its noise with the velocity): the
normalised innovation squared ``z^T S^-1 z`` (S = H P H^T + R) is gated first; an accepted
block is applied through the Cholesky factor L of S, ``U = L^-1 H P``, ``x += U^T L^-1
(z - H x)``, ``P -= U^T U``, which is the textbook ``K = P H^T S^-1`` update written so that
P stays exactly symmetric.  Nothing here allocates.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.core.errors import build_f
from navd.core.rotation import exp_into, mul3_into, orthonormalize
from navd.core.strapdown import strapdown_step

Arr = npt.NDArray[np.float64]
N = 15

# The specific force that F (the error dynamics) uses, on a multirotor (multirotor_f; the
# low-pass time constant F_TAU_S, s, is set by navd.core.estimator in f_lp[6]; 0: the raw
# mean).  The velocity error grows as f x phi with the TRUE specific force; the filter only
# has the measured one, and every bit of horizontal f in F is heading information it claims,
# |f_h|^2 / VRW^2 per second, where the data holds the true f_h's share.  With the raw
# interval mean the noise's energy is claimed too: in a hover (true horizontal f = 0) the
# filter reads "the velocity innovations do not turn with the noise" as "the heading is
# right" and holds it while its sigma shrinks (mr_clean seed 4: 4-5 deg off at a 1.6 deg
# sigma; docs/results.md, issue 14).  A multirotor's body specific force is its thrust along
# body z, smooth, plus the rotor drag -kd v_b along body x/y, which follows the velocity: so
# the body vector plus kd v_b is low-passed (noise VRW / sqrt(2 F_TAU_S) per axis) and kd v_b
# taken off again, with kd learnt in flight (a complementary filter: the drag is not
# delayed, and a wrong kd only leaves the lag of what it does not explain), then rotated with
# the present attitude (a lean into an acceleration is not delayed), and the noise's energy
# is subtracted from the horizontal part's.  A body low-pass without the drag model lagged
# the drag by ~1 s after every change of speed and, with the noise's energy, claimed 1.5-2x
# the heading information the data holds (sigma 20 % below the information floor,
# benchmarks/info_floor.py); a navigation-frame low-pass was honest but lagged the legs and
# lost accuracy (docs/results.md).  A change larger than the noise allows (F_SNAP_SD sigmas
# between an F_FAST_S low-pass and the slow one, ~3 m/s^2 at VRW 0.3: a hard climb or stop)
# is followed at once.  Cars and fixed wings keep the raw mean: their specific force changes
# quickly and for real (braking, bumps, gusts, pull-ups), and low-passing it cost car480
# 0.05 deg of pitch RMS and the X8 replayed as a ground vehicle 2 deg of pitch against ATT
# (docs/results.md).  The mechanization is never filtered.
F_TAU_S = 1.0
F_FAST_S = 0.1
F_SNAP_SD = 4.0
# the rotor-drag coefficient's regression (multirotor_f): high-pass, forgetting, its prior
# (1/s; the quads of log171 and f450_glitch learn 0.19 and 0.13-0.20, the simulator's
# multirotors fly 0.3-0.35) and its range (1/s)
DRAG_HP_S = 2.0
DRAG_FORGET_S = 120.0
DRAG_PRIOR_PER_S = 0.2
DRAG_PRIOR_SD = 0.15
DRAG_MAX_PER_S = 1.0
FLP_N = 16
# the gyro scale-factor allowance (gyro_scale_allowance): [0] the variance of each axis's
# scale error (dimensionless^2; 0: off), [1:10] A (3, 3) row-major, column i the
# navigation-frame attitude error per unit scale error of body axis i (rad), [10:13] the
# squared length of each column already put into P, [13] the forgetting time constant, s,
# [14] the body z gyro's scale error learnt from the course (navd.core.aiding.gnss_heading),
# taken out of every increment
SF_N = 15
SF_YAW_Z = 1 + 3 * 2 + 2  # A[D, z]: the yaw the z gyro turned lately, rad
SF_SCALE_Z = 14
# car480 with 1 % per axis, seeds 1-3, heading beyond 3 sigma: no allowance 21 %; forgetting
# in 2 / 5 / 10 / 20 / 40 s: 5.0 / 2.6 / 3.1 / 3.8 / 5.7 %; forgetting by the updates' own
# variance ratio instead (P+/P-): 6.0 % (the course reads a turn's error as sideslip, so the
# updates shrink P without removing it); the same scale as a gyro-bias allowance: 6.5 %
SF_FORGET_S = 5.0


@jit
def propagate_cov(P: Arr, F: Arr, q: Arr, T: float, A: Arr, B: Arr) -> None:
    """P <- Phi P Phi^T + diag(q) T with Phi = I + FT + (FT)^2/2.  A, B: (15,15) scratch."""
    n = P.shape[0]
    # A = F T ; B = I + A + A A / 2   (skip zeros: F is ~70 % zeros)
    for i in range(n):
        for j in range(n):
            A[i, j] = F[i, j] * T
    for i in range(n):
        for j in range(n):
            B[i, j] = A[i, j]
        for k in range(n):
            a = A[i, k]
            if a != 0.0:
                for j in range(n):
                    B[i, j] += 0.5 * a * A[k, j]
        B[i, i] += 1.0
    # A <- Phi P
    for i in range(n):
        for j in range(n):
            A[i, j] = 0.0
        for k in range(n):
            b = B[i, k]
            if b != 0.0:
                for j in range(n):
                    A[i, j] += b * P[k, j]
    # P <- (Phi P) Phi^T + Qd, symmetric by construction of the upper triangle
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(n):
                b = B[j, k]
                if b != 0.0:
                    s += A[i, k] * b
            P[i, j] = s
            P[j, i] = s
        P[i, i] += q[i] * T


@jit
def gated_update(x: Arr, P: Arr, H: Arr, z: Arr, R: Arr, m: int, gate: float,
                 S: Arr, L: Arr, ph: Arr, w: Arr, hold: int = -1,
                 hold_mask: int = 0) -> float:
    """Gate and apply a measurement block of size m in place.

    ``hold`` (an index, -1 for none) makes that state a Schmidt "consider" state: its
    estimate and variance stay as they are (zero gain) while its correlations with the
    others update exactly, so P remains the true covariance of the (suboptimal) estimate.
    ``hold_mask`` (bit i: state i) makes further states consider states the same way.

    Args:
        x: error state (15,), updated.
        P: covariance (15, 15), updated.
        H: (4, 15) rows 0..m-1 used.  Rows are overwritten on accept.
        z: (4,) innovation (computed - measured), first m used.
        R: (4, 4) measurement covariance, top-left m x m used.
        gate: chi-square threshold for m degrees of freedom (<= 0 disables the gate).
        S, L: (4, 4) scratch.  ph: (15,) scratch.  w: (4,) scratch.
        hold: index of a consider state, or -1.
        hold_mask: bit mask of further consider states (0: none).
    Returns:
        The normalised innovation squared; negative (-NIS) when the gate rejected it, and
        -inf when S was not positive definite (nothing applied).
    """
    n = x.shape[0]
    # S = H P H^T + R
    for a in range(m):
        for i in range(n):
            s = 0.0
            for k in range(n):
                s += P[i, k] * H[a, k]
            ph[i] = s
        for b in range(m):
            s = 0.0
            for i in range(n):
                s += H[b, i] * ph[i]
            S[a, b] = s + R[a, b]
    # Cholesky of S -> NIS
    for i in range(m):
        for j in range(i + 1):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if s <= 0.0:
                    return -math.inf
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    nis = 0.0
    for i in range(m):
        s = z[i]
        for k in range(i):
            s -= L[i, k] * w[k]
        w[i] = s / L[i, i]
        nis += w[i] * w[i]
    if not math.isfinite(nis):
        return -math.inf
    if gate > 0.0 and nis > gate:
        return -nis
    # Block update through chol(S) (S is PD even when R is singular, e.g. a perfect
    # measurement or a course sharing all its noise with the velocity):
    #   U = L^-1 H P,  r = L^-1 (z - H x),  x += U^T r,  P -= U^T U
    for a in range(m):
        r = z[a]
        for k in range(n):
            r -= H[a, k] * x[k]
        for k in range(a):
            r -= L[a, k] * w[k]
        w[a] = r / L[a, a]
    for a in range(m):
        for j in range(n):
            s = 0.0
            for k in range(n):
                hk = H[a, k]
                if hk != 0.0:
                    s += hk * P[k, j]
            ph[j] = s
        for j in range(n):
            v = ph[j]
            for k in range(a):
                v -= L[a, k] * H[k, j]
            H[a, j] = v / L[a, a]
    # With K = U^T L^-1 and zero gain rows for the held states C, the Joseph form reduces
    # to the usual P -= U^T U everywhere except the block P[C, C], which keeps its value.
    if hold >= 0:
        hold_mask |= 1 << hold
    for i in range(n):
        if (hold_mask >> i) & 1:
            continue
        s = 0.0
        for a in range(m):
            s += H[a, i] * w[a]
        x[i] += s
    for i in range(n):
        for j in range(i, n):
            if (hold_mask >> i) & 1 and (hold_mask >> j) & 1:
                continue
            s = 0.0
            for a in range(m):
                s += H[a, i] * H[a, j]
            v = P[i, j] - s
            P[i, j] = v
            P[j, i] = v
    return nis


@jit
def inject(x: Arr, mat_nb: Arr, vel_n: Arr, pos: Arr, bg: Arr, ba: Arr, work: Arr) -> None:
    """Fold the error state into the nominal state and zero it (conventions in navd)."""
    e = work[4]
    t = work[5]
    exp_into(e, x[0], x[1], x[2])
    mul3_into(t, e, mat_nb)
    for i in range(3):
        for j in range(3):
            mat_nb[i, j] = t[i, j]
        vel_n[i] -= x[3 + i]
        pos[i] -= x[6 + i]
        bg[i] += x[9 + i]
        ba[i] += x[12 + i]
    for i in range(x.shape[0]):
        x[i] = 0.0


@jit
def multirotor_f(f_lp: Arr, mat_nb: Arr, vel_n: Arr, fx: float, fy: float, fz: float,
                 T: float, vrw2: float, f_n: Arr) -> None:
    """F's NED specific force on a multirotor (see F_TAU_S) into ``f_n`` (3,), m/s^2.

    ``fx, fy, fz``: this covariance interval's mean body specific force, m/s^2 (bias
    compensated); ``T`` its length, s; ``vrw2`` the configured VRW^2 (m/s)^2/s.  ``f_lp``
    (FLP_N,): [0:3] slow and [3:6] fast body low-passes of f + kd v_b (x, y) (all zero:
    none yet); [6] tau, s; [7] kd, the rotor-drag coefficient, 1/s; [8:10] and [10:12]
    the high-pass states of body f and of the body velocity (x, y); [12:14] the body
    velocity at the end of the previous interval, m/s; [14] sum of hp(f) hp(v), [15] sum of
    hp(v)^2 (forgetting DRAG_FORGET_S).

    The body x/y specific force of a multirotor is its rotor drag, -kd v_b (thrust is along
    body z): it follows the velocity at once, so it is carried past the low-pass by the
    model (low-pass of f + kd v_b, then - kd v_b: a complementary filter; a wrong kd only
    leaves the lag of the part it does not explain, constant wind and bias pass through).
    kd is learnt here from the high-passed body f against the high-passed body velocity of
    the interval before (this interval's accelerometer noise is in its own velocity), from
    the prior DRAG_PRIOR_PER_S.  Then the horizontal part is scaled by
    sqrt(1 - n^2 / |f_h|^2), n^2 the low-pass's noise over two axes, so that |f_h|^2 is, on
    average, the signal's and not the noise's (in a hover ~1/e of the noise's energy
    remains, against all of it unscaled).
    """
    tau = f_lp[6]
    kd = f_lp[7]
    vbx = mat_nb[0, 0] * vel_n[0] + mat_nb[1, 0] * vel_n[1] + mat_nb[2, 0] * vel_n[2]
    vby = mat_nb[0, 1] * vel_n[0] + mat_nb[1, 1] * vel_n[1] + mat_nb[2, 1] * vel_n[2]
    # the drag regression
    c = T / (DRAG_HP_S + T)
    hfx = fx - f_lp[8]
    hfy = fy - f_lp[9]
    f_lp[8] += c * hfx
    f_lp[9] += c * hfy
    hvx = f_lp[12] - f_lp[10]
    hvy = f_lp[13] - f_lp[11]
    f_lp[10] += c * hvx
    f_lp[11] += c * hvy
    f_lp[12] = vbx
    f_lp[13] = vby
    lam = math.exp(-T / DRAG_FORGET_S)
    f_lp[14] = lam * f_lp[14] + hfx * hvx + hfy * hvy
    f_lp[15] = lam * f_lp[15] + hvx * hvx + hvy * hvy
    # least squares from the prior DRAG_PRIOR_PER_S +- DRAG_PRIOR_SD, whose information in
    # units of sum hp(v)^2 is w (hp(f)'s noise per interval being VRW^2 / T per axis); the
    # sums forget, the prior does not: a long hover returns kd to it
    w = vrw2 / (T * DRAG_PRIOR_SD * DRAG_PRIOR_SD)
    kd = (w * DRAG_PRIOR_PER_S - f_lp[14]) / (w + f_lp[15])
    kd = min(max(kd, 0.0), DRAG_MAX_PER_S)
    f_lp[7] = kd
    fx += kd * vbx
    fy += kd * vby
    if f_lp[0] == 0.0 and f_lp[1] == 0.0 and f_lp[2] == 0.0:
        f_lp[0] = f_lp[3] = fx
        f_lp[1] = f_lp[4] = fy
        f_lp[2] = f_lp[5] = fz
    else:
        a = T / (tau + T)
        b = T / (F_FAST_S + T)
        d2 = 0.0
        for i in range(3):
            fi = fx if i == 0 else (fy if i == 1 else fz)
            f_lp[i] += a * (fi - f_lp[i])
            f_lp[3 + i] += b * (fi - f_lp[3 + i])
            d2 += (f_lp[3 + i] - f_lp[i]) ** 2
        # per axis, the two low-passes' noise variances are VRW^2 / (2 tau) each
        if d2 > F_SNAP_SD * F_SNAP_SD * vrw2 * (0.5 / F_FAST_S + 0.5 / tau):
            for i in range(3):
                f_lp[i] = f_lp[3 + i]
    bx = f_lp[0] - kd * vbx
    by = f_lp[1] - kd * vby
    bz = f_lp[2]
    for i in range(3):
        f_n[i] = mat_nb[i, 0] * bx + mat_nb[i, 1] * by + mat_nb[i, 2] * bz
    # the low-pass's noise (VRW^2 / (2 tau) per axis, two horizontal axes) adds energy
    # (heading information that is not there): subtract it from |f_h|^2
    h2 = f_n[0] * f_n[0] + f_n[1] * f_n[1]
    k = 0.0
    if h2 > vrw2 / tau:
        k = math.sqrt(1.0 - vrw2 / (tau * h2))
    f_n[0] *= k
    f_n[1] *= k


@jit
def gyro_scale_allowance(sf: Arr, mat_nb: Arr, inc: Arr, dt: float, P: Arr) -> None:
    """Add to P's attitude block what an unknown gyro scale-factor error makes of this step's
    rotation (``inc`` (6,): the compensated increments, rad and m/s; ``dt`` s).

    A scale error s_i of body axis i turns every rotation about that axis into attitude
    error: phi_n = sum_i a_i s_i with a_i = sum_k C_k e_i dtheta_ki, the net rotation about
    the axis in the navigation frame (C_k: C_b^n of step k).  It is one fixed error, not
    white noise: a 90 deg turn at 1 % is 0.9 deg of heading, reached within the turn, which
    the heading updates cannot follow (the course sees it as sideslip until the turn ends),
    and a turn back undoes it.  So its variance is added as the coherent sum grows: while
    |a_i|^2 exceeds what was already put in (``sf[10 + i]``), s^2 times the excess along a_i.
    An oscillation (a multirotor's wobble) adds its amplitude once, a turn its angle
    squared, a turn back nothing.  The a_i forget with the time constant ``sf[13]``
    (SF_FORGET_S): once the vehicle stops turning the updates remove the error (car480: to
    a fifth within ~10 s of a turn's end), and the next turn is an error of its own; in a
    long turn the allowance becomes a white noise of density 2 s^2 w^2 SF_FORGET_S.
    """
    var = sf[0]
    if var <= 0.0:
        return
    lam = math.exp(-dt / sf[13])
    for i in range(3):
        d = inc[i]
        n2 = 0.0
        for j in range(3):
            a = lam * sf[1 + 3 * j + i] + mat_nb[j, i] * d
            sf[1 + 3 * j + i] = a
            n2 += a * a
        acc = sf[10 + i] * lam * lam
        if n2 > acc:
            k = var * (n2 - acc) / n2
            for j in range(3):
                aj = sf[1 + 3 * j + i]
                for m in range(3):
                    P[j, m] += k * aj * sf[1 + 3 * m + i]
            acc = n2
        sf[10 + i] = acc


@jit
def imu_step(mat_nb: Arr, vel_n: Arr, pos: Arr, dov: Arr, bg: Arr, ba: Arr,
             inc: Arr, prev_inc: Arr, dprev: Arr, acc: Arr,
             dtx: float, dty: float, dtz: float, dvx: float, dvy: float, dvz: float,
             dt: float, coning: bool, cov_interval: float,
             P: Arr, F: Arr, q: Arr, A: Arr, B: Arr, work: Arr, rate: Arr,
             f_lp: Arr, sf: Arr) -> bool:
    """One IMU sample: bias compensation, strapdown, and covariance propagation when due.

    ``acc`` (8,) accumulates (sum dv_b xyz, sum dt, step count, -, -, -) between covariance
    propagations; ``f_lp`` (7,) keeps the low-passed body specific force F uses and its time
    constant (F_TAU_S).  ``rate`` (3,) receives the compensated body rate (rad/s).  Returns
    True when P was propagated.  ``sf`` (SF_N,): the gyro scale-factor allowance's state
    (:func:`gyro_scale_allowance`).

    Sampling error: an increment made from a point-sampled rate (HIGHRES_IMU, a log's IMU
    message at 50 Hz) misses what the rate did between samples, which the gyro's noise
    density knows nothing about: a multirotor sampled at 50 Hz whose rate changes by
    2-3 rad/s^2, and whose vibration aliases into the samples, loses a good fraction of a
    degree per second.  What a rate that changes linearly over a few steps cannot explain is
    the second difference of the increments, d2 = inc_k - 2 inc_(k-1) + inc_(k-2) (``dprev``
    (3,) keeps inc_(k-1) - inc_(k-2)); for true delta angles of a smooth motion it is
    ~omega'' dt^3, nothing (a ship's swell: 1e-8 rad).  Its square beyond three times what
    the gyro's white noise alone gives it on average (6 q dt per axis: only ~3 % of the
    white noise gets through) is added to the attitude variance at each step, /12 per axis
    (|d2| / 2 squared, over three axes).
    """
    inc[0] = dtx - bg[0] * dt
    inc[1] = dty - bg[1] * dt
    inc[2] = (dtz - bg[2] * dt) / (1.0 + sf[SF_SCALE_Z])
    inc[3] = dvx - ba[0] * dt
    inc[4] = dvy - ba[1] * dt
    inc[5] = dvz - ba[2] * dt
    rate[0] = inc[0] / dt
    rate[1] = inc[1] / dt
    rate[2] = inc[2] / dt
    gyro_scale_allowance(sf, mat_nb, inc, dt, P)
    sampling = -18.0 * (q[0] + q[1] + q[2]) * dt  # 3 x the white noise's mean |d2|^2
    for i in range(3):
        d1 = inc[i] - prev_inc[i]
        d2 = d1 - dprev[i]
        dprev[i] = d1
        sampling += d2 * d2
    if sampling > 0.0:
        sampling /= 12.0  # (|d2| / 2)^2 over 3 axes
        P[0, 0] += sampling
        P[1, 1] += sampling
        P[2, 2] += sampling
    strapdown_step(mat_nb, vel_n, pos, dov, inc, prev_inc, dt, coning, work)
    for i in range(6):
        prev_inc[i] = inc[i]
    acc[0] += inc[3]
    acc[1] += inc[4]
    acc[2] += inc[5]
    acc[3] += dt
    acc[4] += 1.0
    if acc[4] >= 1000.0:
        # keep C orthonormal against round-off drift (cheap, every ~1000 samples)
        orthonormalize(mat_nb, work[6], work[7])
        acc[4] = 0.0
    if acc[3] + 0.5 * dt < cov_interval:
        return False
    T = acc[3]
    f_n = work[0, 0]
    fx = acc[0] / T
    fy = acc[1] / T
    fz = acc[2] / T
    # F's specific force (see F_TAU_S): the interval's mean; on a multirotor (f_lp[6] > 0)
    # the model of multirotor_f
    if f_lp[6] > 0.0:
        multirotor_f(f_lp, mat_nb, vel_n, fx, fy, fz, T, max(q[3], q[4], q[5]), f_n)
    else:
        for i in range(3):
            f_n[i] = mat_nb[i, 0] * fx + mat_nb[i, 1] * fy + mat_nb[i, 2] * fz
    build_f(F, mat_nb, vel_n, pos, f_n)
    propagate_cov(P, F, q, T, A, B)
    acc[0] = 0.0
    acc[1] = 0.0
    acc[2] = 0.0
    acc[3] = 0.0
    return True
