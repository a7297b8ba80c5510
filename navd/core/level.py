"""The covariance of attitude and accelerometer bias right after levelling (docs/design.md §3.8).

Levelling takes the mean specific force as gravity, so whatever the accelerometers add to it
on the horizontal axes becomes a tilt: with the known bias removed, the residual bias δb_a
(body) tilts the levelled attitude by exactly the angle that hides it,

    φ_N = ε_N + (Ĉ δb_a)_E / g,      φ_E = ε_E − (Ĉ δb_a)_N / g,

(§2 conventions: then ``[f^n×] φ + Ĉ δb_a`` has no horizontal part left, the velocity error
grows only with the levelling's own error ε).  ε collects what levelling gets wrong apart from
the bias (noise of the mean, vibration, unmodelled acceleration), σ_ε = ``[init] tilt_sd``.

So tilt and bias start correlated, not independent.  With a diagonal P0 the velocity
updates, which observe only ``[f^n×] φ + Ĉ δb_a`` until a turn separates the two, split
every correction between tilt and bias by their prior variances; with a wide (consumer) bias
prior a large share of the levelling noise went into the bias estimate and stayed in the tilt
until turns (issue 14).  With the correlation the same updates correct ε in the tilt and leave
the bias at its prior mean, and the tilt σ says honestly that −δb_a/g is still unknown.

The heading, when given, is a ZYX yaw: with the nose pitched by θ, a tilt about the nose's
horizontal direction moves its azimuth, ``φ_D = −δψ − tanθ (cosψ φ_N + sinψ φ_E)``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

Arr = npt.NDArray[np.float64]

# w = [ε_N, ε_E, δψ, δb_x, δb_y, δb_z], independent; the states x = A w are
# [φ_N, φ_E, φ_D, δb_ax, δb_ay, δb_az] (indices 0, 1, 2, 12, 13, 14 of the error state)
_X = (0, 1, 2, 12, 13, 14)


def level_cov(P: Arr, mat_nb: Arr, pitch: float, yaw: float, tilt_sd: float,
              heading_sd: float, accel_bias_sd: float, g: float) -> None:
    """Write the attitude and accelerometer-bias block of P0 (rows/columns 0-2, 12-14).

    Args:
        P: (15, 15) covariance; only the rows and columns of φ and δb_a are written (their
            cross terms with the other states are zeroed).
        mat_nb: the levelled C_b^n (3, 3).
        pitch, yaw: the levelled pitch and the initial yaw, rad.
        tilt_sd: 1-sigma of the levelling error apart from the accelerometer bias, rad.
        heading_sd: 1-sigma of the given yaw, rad; inf (or anything past a quarter turn of
            doubt) when the heading is unknown: φ_D then gets (π/2)² and no correlation.
        accel_bias_sd: 1-sigma of the accelerometer bias about its configured value, m/s².
        g: the magnitude of gravity the levelling saw, m/s².
    """
    A = np.zeros((6, 6))
    A[0, 0] = 1.0
    A[1, 1] = 1.0
    for j in range(3):
        A[0, 3 + j] = mat_nb[1, j] / g
        A[1, 3 + j] = -mat_nb[0, j] / g
        A[3 + j, 3 + j] = 1.0
    known = math.isfinite(heading_sd)
    w_var = np.array([tilt_sd**2, tilt_sd**2, heading_sd**2 if known else 0.0]
                     + [accel_bias_sd**2] * 3)
    tp = math.tan(pitch)
    if known:
        A[2] = -tp * (math.cos(yaw) * A[0] + math.sin(yaw) * A[1])
        A[2, 2] = -1.0
    Pw = (A * w_var) @ A.T
    if not known:
        # the bias lies along an unknown heading: the tilt's variance stays (J Σ_b Jᵀ does not
        # depend on the heading for an isotropic Σ_b), its NED correlation with the body-frame
        # bias averages out.  (Keeping it for the guessed yaw 0 and turning P's tilt rows at
        # each later heading reset was tried: the yaw bank's resets then moved the real
        # quad123 log's pitch from 1.2 to 1.8 deg RMS, docs/results.md.)
        for a in range(2):
            for b in range(3, 6):
                Pw[a, b] = Pw[b, a] = 0.0
    if not known or Pw[2, 2] >= (math.pi / 2) ** 2:
        # near 90 deg pitch the nose has no azimuth: past a quarter turn of doubt the
        # heading is simply unknown
        Pw[2, :] = 0.0
        Pw[:, 2] = 0.0
        Pw[2, 2] = (math.pi / 2) ** 2
    for i in _X:
        P[i, :] = 0.0
        P[:, i] = 0.0
    for a, i in enumerate(_X):
        for b, j in enumerate(_X):
            P[i, j] = Pw[a, b]



def relevel_cov(P: Arr, mat_nb: Arr, tilt_sd: float, g: float, heading_known: bool) -> None:
    """P after roll and pitch were levelled again, from a still window's mean specific force
    less the *estimated* accelerometer bias (``gnss_recovery``'s re-level at rest).

    The new tilt error is, as at the start, the levelling's own error ε plus the tilt that
    hides the residual bias, ``φ_h = ε + J δb_a`` (J as in :func:`level_cov`); the old tilt is
    forgotten.  So with T the identity whose φ_N, φ_E rows are replaced by J applied to the δb_a
    rows, ``P <- T P Tᵀ + tilt_sd² on φ_N, φ_E``: the tilt inherits the bias's variance and its
    correlations with every other state.  With the heading unknown (a re-level that moved the
    tilt far) the NED direction of the bias is unknown too: the tilt keeps J P_bb Jᵀ's variance
    but no correlations.  No allocation beyond scalars.

    Args:
        P: (15, 15) covariance, updated in place.
        mat_nb: the re-levelled C_b^n (3, 3).
        tilt_sd: 1-sigma of the levelling's own error, rad.
        g: gravity, m/s².
        heading_known: False when the heading is (now) unknown.
    """
    n = P.shape[0]
    j00, j01, j02 = mat_nb[1, 0] / g, mat_nb[1, 1] / g, mat_nb[1, 2] / g
    j10, j11, j12 = -mat_nb[0, 0] / g, -mat_nb[0, 1] / g, -mat_nb[0, 2] / g
    # new rows 0, 1 against every state other than the tilt: J P[12:15, k]
    for k in range(2, n):
        a = j00 * P[12, k] + j01 * P[13, k] + j02 * P[14, k]
        b = j10 * P[12, k] + j11 * P[13, k] + j12 * P[14, k]
        P[0, k] = P[k, 0] = a
        P[1, k] = P[k, 1] = b
    # the 2x2 tilt block: J P_bb J^T + tilt_sd^2 I (P[0:2, 12:15] now holds J P_bb)
    p00 = P[0, 12] * j00 + P[0, 13] * j01 + P[0, 14] * j02 + tilt_sd * tilt_sd
    p01 = P[0, 12] * j10 + P[0, 13] * j11 + P[0, 14] * j12
    p11 = P[1, 12] * j10 + P[1, 13] * j11 + P[1, 14] * j12 + tilt_sd * tilt_sd
    if not heading_known:
        for k in range(2, n):
            P[0, k] = P[k, 0] = 0.0
            P[1, k] = P[k, 1] = 0.0
    P[0, 0] = p00
    P[1, 1] = p11
    P[0, 1] = P[1, 0] = p01
