"""MCTLS: robust multivariate constrained-total-least-squares GNSS velocity over a window.

Model equation, for epoch k = 1..n of the sliding window (newest k = n)::

    y_k = C_e^n(p̂_k) v̂^e_k = Exp(-δθ_k) Σ_{j=0..p} a_j τ_k^j  +  C_e^n(p̂_k) n_k      (1)

    τ_k = (t_k - t_n) / (t_n - t_1) ∈ [-1, 0]      exact time columns (the constrained part)
    a_j ∈ R^3 (NED, m/s)                           unknowns; a_0 is the velocity at t_n
    n_k ~ N(0, σ_k² I3)                            receiver velocity noise, σ_k = speed accuracy
    δθ_k ~ N(0, Σθ_k)                              tilt of the computed NED frame, from the
                                                   horizontal position error (δN, δE) of fix k:
    δθ = [δE/R_N, -δN/R_M, -δE tanL/R_N]           (Ĉ_e^n = Exp(-δθ) C_e^n, checked numerically)

so 10 m of position error tilts the frame by ~1.6e-6 rad: the "coefficient noise" of the
rotation.  The three NED components share the time columns (multivariate right-hand side)
but are coupled through the non-diagonal per-epoch covariance below.

Constrained TLS.  Total least squares asks for the smallest perturbation of *both* the
coefficients (here the rotation, through δθ_k) and the observations (n_k) that makes (1)
exact: min Σ_k |n_k|²/σ_k² + δθ_kᵀ Σθ_k⁺ δθ_k.  Because the perturbation of the coefficient
matrix is a linear function of the small vector δθ_k (the "constrained" TLS of Abatzoglou,
Mendel & Harada, IEEE TSP 1991), eliminating it to first order leaves a generalized LS
whose weights depend on the unknowns::

    Q(a) = Σ_k w_k e_kᵀ S_k e_k,   e_k = ỹ_k - v_k(a),   v_k(a) = Σ_j a_j τ_k^j
    Σ_k(a) = s² σ_k² I + [v_k×] Σθ_k [v_k×]ᵀ        (coefficient noise acts across v_k)
    S_k = B_k Σ_k⁻¹ B_k,   ỹ_k = B_k⁻¹ y_k,   B_k = E[Exp(-δθ_k)] = I + ½(Σθ_k - tr Σθ_k I)

B_k removes the second-order shrink of a randomly rotated vector (LS is biased by
-½(tr Σθ - Σθ) v, which no first-order method sees).  Q is minimized by re-evaluating
Σ_k at the current fit (fixed point; Σ_k depends on a only weakly, 2-3 passes converge).
w_k = 1 in modes "ls" (which also drops the Σθ and B terms) and "tls".

Why not the unstructured or the mixed LS-TLS (Golub-Hoffman-Stewart / Van Huffel).  In the
NED form (1) the only regressors are the exact time columns; mixed LS-TLS with no noisy
column *is* LS.  In the ECEF form v̂^e_k = Ĉ_kᵀ (φ_kᵀ ⊗ I) a every column carries Ĉ_k, but
Ĉ_k Ĉ_kᵀ = I exactly, so the Gram matrix is noise-free and there is no attenuation for TLS to
undo: the classical correction (subtracting σ_min² from the Gram) only flips LS's second-order
shrink.  Measured (constant velocity 20 m/s, n = 20, isotropic δθ of 0.1 rad, 2000 trials):
LS -0.066 m/s along track, unstructured TLS +0.060 m/s, same RMS.  The structure in (1) is
what carries the information; at realistic 1.6e-6 rad the TLS terms change the estimate by
~1e-5 m/s (|v| δθ) and LS and TLS coincide, which tests/test_mctls.py checks.

Robust reweighting (mode "mctls"), against the receiver's σ: bisquare weights
w_k = (1 - (d_k/c₃)²)² for d_k < c₃, else 0, on the Mahalanobis distance d_k² = e_kᵀ S_k e_k;
c₃ = κ c with κ = 1.172: the scalar c = 4.685 gives 95 % Gaussian efficiency, and for a
3-vector residual the same efficiency needs c₃ = 5.49 (computed from the M-estimator's
asymptotic variance).  An epoch with w = 0 is an outlier.  IRLS on a redescending ρ needs a
start inside the right basin, and jumps come in runs:

* Start: the plain LS fit and fits interpolating 100 minimal subsets (p+1 epochs spanning at
  least half the window; fixed-seed generator, so a replay is bit-exact), scored by the
  h-th smallest d_k², h = ⌊n/2⌋ + ⌊(p+2)/2⌋ (least-quantile, the least-median family;
  ``start="lqs"``, default, scale-free) or by Σ_k ρ(d_k/c₃) at the current scale
  (``start="rho"``).  Alone, the ρ score was slightly better (benchmark bursts: detection
  0.889 vs 0.880); with the polished candidates below the two measure the same (0.988).
* Polished candidates, compared on J = Σρ after IRLS: (1) the best start; (2) the previous
  push's solution, re-expressed in this window's τ, kept unless (1) is better by 1 (one
  outlier's worth; this hysteresis is what keeps a growing run of jumps rejected: detection
  0.89 → 0.99); (3) the winner with a rejected newest epoch re-admitted, if that epoch lies
  within twice the rejection radius, so that a clean epoch is not rejected only because a
  noisy neighbour bent the cubic's end.
* Scale: s² starts from the previous push's value (1 at first); a scale-free check (the
  least h-th smallest d² over the candidates against its clean expectation χ²_3(h/(n+1)))
  takes over if 5x larger; after IRLS, s² is refined on the inliers' Σd²/dof, leaving 1
  only at 99 % significance and never going below 1.  So s inflates an optimistic receiver
  σ (tests: 3x optimistic is recovered) and is 1 otherwise.

Limits, measured (benchmarks/mctls.py): at order 3 the window's end is an extrapolation
whenever the newest epochs are rejected, and its σ grows fast (0.1 → 0.9 m/s over 5
epochs at σ = 0.1 m/s); runs longer than ~5 epochs then get partly accepted (the cubic bends
onto them), and the first clean epochs after a run are often rejected (cheap: skipped).
Order 2 extrapolates much better and, on the benchmark's car, is better everywhere.

Output at the newest epoch: a_0 (NED, m/s) and its covariance from the sandwich
(AᵀWA)⁻¹ (Σ w_k² φφᵀ ⊗ S_k) (AᵀWA)⁻¹ (exact for the final weights held fixed), the weight
of every epoch in the window, the outlier flag of the newest epoch.

Mode "gate" is the cheap alternative, a filter-style χ² innovation gate: LS over the epochs
accepted so far predicts the newest one (covariance P_pred + σ_n² I); it is rejected
(weight 0, output = prediction) when d² > χ²_3(0.999) = 16.27, unless that has happened
``window // 2`` times in a row: then the gate restarts from the rejected run (as a filter
resets after repeated rejections) so that it cannot lock out for good.

Cost (default window 20, order 3, this 2-core machine): ~12 µs a push ("ls"), ~14 µs
("gate"), ~24 µs ("tls"), ~185 µs ("mctls": 100 subsets and up to three IRLS polishes).
Every array is allocated when ``Mctls`` is built, inside a numba jitclass: a push passes
only scalars into compiled code and allocates nothing, not even the NRT meminfo that an
ndarray argument costs per call (tests check tracemalloc and numba's NRT counters).  The
price is ~4 s of compilation at the first ``Mctls`` of a process (jitclasses are not
cached on disk; the kernels they call are).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import numpy.typing as npt
from numba.experimental import jitclass  # type: ignore[attr-defined]

from navd.core._jit import jit
from navd.core.earth import mat_ne_into, radii
from navd.core.rotation import mul3_into

Arr = npt.NDArray[np.float64]
IArr = npt.NDArray[np.int64]

MODES: dict[str, int] = {"ls": 0, "tls": 1, "mctls": 2, "gate": 3}
# Ratio of the bisquare constants giving 95 % efficiency for a 3-D and a 1-D residual
# (5.49 / 4.685); see the module docstring.
KAPPA_3D = 1.172
GATE_CHI2_3 = 16.266  # χ²_3 quantile at 0.999
_SEED = 0x2545F491
_MAX_IRLS = 30
_HYSTERESIS = 1.0  # J advantage the previous solution keeps over a fresh one
_W_TOL = 1e-4

# Status codes returned by the kernel.
_ST_OK = 1
_ST_FILLING = 0
_ST_SINGULAR = -1

# Slots of the float / int output vectors shared with the Python wrapper.
_F_D2 = 0  # Mahalanobis distance² of the newest epoch against the final fit
_F_SCALE = 1  # robust variance-scale factor s (>= 1) of the receiver's σ
_I_COUNT = 0
_I_OUTLIER = 1
_I_CONSEC = 2
_I_ITERS = 3
_I_HAS_PREV = 4  # the previous push left a robust fit in xprev
_F_T_PREV = 2  # newest time of that fit, s
_F_H_PREV = 3  # its window span, s
_F_S2_PREV = 4  # its variance scale s²


def chi2_3_quantile(q: float) -> float:
    """Quantile of the χ² distribution with 3 degrees of freedom (bisection on the CDF)."""
    lo, hi = 0.0, 100.0
    for _ in range(200):
        x = 0.5 * (lo + hi)
        cdf = math.erf(math.sqrt(0.5 * x)) - math.sqrt(2.0 * x / math.pi) * math.exp(-0.5 * x)
        if cdf < q:
            lo = x
        else:
            hi = x
    return 0.5 * (lo + hi)


@jit
def _inv3_sym(out: Arr, m: Arr) -> bool:
    """out = m⁻¹ for a symmetric 3x3 ``m`` by cofactors; False when singular."""
    c00 = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
    c01 = m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]
    c02 = m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]
    det = m[0, 0] * c00 + m[0, 1] * c01 + m[0, 2] * c02
    if not det > 0.0 and not det < 0.0:
        return False
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[0, 1] = (m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]) * inv
    out[0, 2] = (m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]) * inv
    out[1, 0] = c01 * inv
    out[1, 1] = (m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]) * inv
    out[1, 2] = (m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]) * inv
    out[2, 0] = c02 * inv
    out[2, 1] = (m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]) * inv
    out[2, 2] = (m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]) * inv
    return True


@jit
def _sigma_theta_into(out: Arr, lat_rad: float, pos_sigma_m: float) -> None:
    """Σθ (3x3, rad²) of the NED frame tilt for isotropic horizontal position noise."""
    r_m, r_n = radii(lat_rad)
    a2 = (pos_sigma_m / r_n) ** 2
    b2 = (pos_sigma_m / r_m) ** 2
    tl = math.tan(lat_rad)
    out[0, 0] = a2
    out[0, 1] = 0.0
    out[0, 2] = -a2 * tl
    out[1, 0] = 0.0
    out[1, 1] = b2
    out[1, 2] = 0.0
    out[2, 0] = -a2 * tl
    out[2, 1] = 0.0
    out[2, 2] = a2 * tl * tl


@jit
def _epoch_cov_into(sinv: Arr, m3: Arr, tmp: Arr, sth: Arr, bk: Arr, sig2: float,
                    vx: float, vy: float, vz: float, use_coef: bool) -> bool:
    """sinv = B Σ(v)⁻¹ B with Σ(v) = sig2 I + [v×] Σθ [v×]ᵀ (3x3 each); m3, tmp scratch."""
    if not use_coef:
        for a in range(3):
            for b in range(3):
                sinv[a, b] = 0.0
            sinv[a, a] = 1.0 / sig2
        return True
    # tmp = [v×] Σθ, then m3 = tmp [v×]ᵀ = -tmp [v×].
    for b in range(3):
        tmp[0, b] = -vz * sth[1, b] + vy * sth[2, b]
        tmp[1, b] = vz * sth[0, b] - vx * sth[2, b]
        tmp[2, b] = -vy * sth[0, b] + vx * sth[1, b]
    for a in range(3):
        m3[a, 0] = -(tmp[a, 1] * vz - tmp[a, 2] * vy)
        m3[a, 1] = -(-tmp[a, 0] * vz + tmp[a, 2] * vx)
        m3[a, 2] = -(tmp[a, 0] * vy - tmp[a, 1] * vx)
        m3[a, a] += sig2
    if not _inv3_sym(tmp, m3):
        return False
    mul3_into(m3, tmp, bk)
    mul3_into(sinv, bk, m3)
    return True


@jit
def _cholesky_solve(nrm: Arr, rhs: Arr, x: Arr, m: int) -> bool:
    """Factor the leading m x m block of ``nrm`` in place (lower) and solve nrm x = rhs."""
    dmax = 0.0
    for i in range(m):
        dmax = max(dmax, nrm[i, i])
    if not dmax > 0.0:
        return False
    for j in range(m):
        d = nrm[j, j]
        for k in range(j):
            d -= nrm[j, k] * nrm[j, k]
        # Relative pivot floor: a window whose weighted epochs cannot pin the polynomial
        # is reported as singular rather than solved into noise.
        if d <= 1e-13 * dmax:
            return False
        d = math.sqrt(d)
        nrm[j, j] = d
        for i in range(j + 1, m):
            s = nrm[i, j]
            for k in range(j):
                s -= nrm[i, k] * nrm[j, k]
            nrm[i, j] = s / d
    _chol_subst(nrm, rhs, x, m)
    return True


@jit
def _chol_subst(lo: Arr, rhs: Arr, x: Arr, m: int) -> None:
    """x = (L Lᵀ)⁻¹ rhs for a factor stored in the lower triangle of ``lo``."""
    for i in range(m):
        s = rhs[i]
        for k in range(i):
            s -= lo[i, k] * x[k]
        x[i] = s / lo[i, i]
    for i in range(m - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, m):
            s -= lo[k, i] * x[k]
        x[i] = s / lo[i, i]


@jit
def _model_v(phi: Arr, x: Arr, i: int, np_: int, a: int) -> float:
    """Component a of the polynomial velocity at epoch i."""
    s = 0.0
    for j in range(np_):
        s += phi[i, j] * x[3 * j + a]
    return s


@jit
def _fill_sinv(s0: int, nw: int, np_: int, phi: Arr, x: Arr, use_fit: bool, yc: Arr,
               sig: Arr, sth: Arr, bk: Arr, sinv: Arr, m3: Arr, tmp: Arr, scale2: float,
               use_coef: bool) -> bool:
    """Per-epoch weights S_k, with Σ_k evaluated at the fit (or at ỹ_k when not use_fit)."""
    for i in range(s0, nw):
        if use_fit:
            vx = _model_v(phi, x, i, np_, 0)
            vy = _model_v(phi, x, i, np_, 1)
            vz = _model_v(phi, x, i, np_, 2)
        else:
            vx, vy, vz = yc[i, 0], yc[i, 1], yc[i, 2]
        if not _epoch_cov_into(sinv[i], m3, tmp, sth[i], bk[i], scale2 * sig[i] * sig[i],
                               vx, vy, vz, use_coef):
            return False
    return True


@jit
def _gls(s0: int, nw: int, np_: int, phi: Arr, yc: Arr, w: Arr, sinv: Arr, nrm: Arr,
         rhs: Arr, x: Arr) -> bool:
    """Weighted multivariate GLS: x = argmin Σ w_k (ỹ_k - v_k)ᵀ S_k (ỹ_k - v_k); nrm factored."""
    m = 3 * np_
    for r in range(m):
        rhs[r] = 0.0
        for c in range(m):
            nrm[r, c] = 0.0
    for i in range(s0, nw):
        wi = w[i]
        if wi <= 0.0:
            continue
        g0 = sinv[i, 0, 0] * yc[i, 0] + sinv[i, 0, 1] * yc[i, 1] + sinv[i, 0, 2] * yc[i, 2]
        g1 = sinv[i, 1, 0] * yc[i, 0] + sinv[i, 1, 1] * yc[i, 1] + sinv[i, 1, 2] * yc[i, 2]
        g2 = sinv[i, 2, 0] * yc[i, 0] + sinv[i, 2, 1] * yc[i, 1] + sinv[i, 2, 2] * yc[i, 2]
        for j in range(np_):
            fj = wi * phi[i, j]
            rhs[3 * j] += fj * g0
            rhs[3 * j + 1] += fj * g1
            rhs[3 * j + 2] += fj * g2
            # Lower triangle only; Cholesky reads no more.
            for l in range(j + 1):
                f = fj * phi[i, l]
                for a in range(3):
                    for b in range(3):
                        nrm[3 * j + a, 3 * l + b] += f * sinv[i, a, b]
    return _cholesky_solve(nrm, rhs, x, m)


@jit
def _sandwich_cov(s0: int, nw: int, np_: int, phi: Arr, w: Arr, sinv: Arr, nrm: Arr,
                  meat: Arr, xs: Arr, e: Arr, col: Arr, cov: Arr) -> None:
    """cov = block 0 of N⁻¹ (Σ w_k² φφᵀ ⊗ S_k) N⁻¹, with N factored in ``nrm``."""
    m = 3 * np_
    for a in range(3):
        for r in range(m):
            e[r] = 0.0
        e[a] = 1.0
        _chol_subst(nrm, e, col, m)
        for r in range(m):
            xs[r, a] = col[r]
    for r in range(m):
        for c in range(m):
            meat[r, c] = 0.0
    for i in range(s0, nw):
        wi = w[i]
        if wi <= 0.0:
            continue
        for j in range(np_):
            for l in range(np_):
                f = wi * wi * phi[i, j] * phi[i, l]
                for a in range(3):
                    for b in range(3):
                        meat[3 * j + a, 3 * l + b] += f * sinv[i, a, b]
    for a in range(3):
        for b in range(a, 3):
            s = 0.0
            for r in range(m):
                t = 0.0
                for c in range(m):
                    t += meat[r, c] * xs[c, b]
                s += xs[r, a] * t
            cov[a, b] = s
            cov[b, a] = s


@jit
def _mahal(s0: int, nw: int, np_: int, phi: Arr, x: Arr, yc: Arr, sinv: Arr,
           d2: Arr) -> None:
    """d2_k = e_kᵀ S_k e_k for the fit x."""
    for i in range(s0, nw):
        e0 = yc[i, 0] - _model_v(phi, x, i, np_, 0)
        e1 = yc[i, 1] - _model_v(phi, x, i, np_, 1)
        e2 = yc[i, 2] - _model_v(phi, x, i, np_, 2)
        d2[i] = (sinv[i, 0, 0] * e0 * e0 + sinv[i, 1, 1] * e1 * e1 + sinv[i, 2, 2] * e2 * e2
                 + 2.0 * (sinv[i, 0, 1] * e0 * e1 + sinv[i, 0, 2] * e0 * e2
                          + sinv[i, 1, 2] * e1 * e2))


@jit
def _kth_smallest(vals: Arr, s0: int, nw: int, k: int, srt: Arr) -> float:
    """k-th smallest (1-based) of vals[s0:nw] by insertion sort into ``srt``."""
    n = nw - s0
    for i in range(n):
        v = vals[s0 + i]
        j = i - 1
        while j >= 0 and srt[j] > v:
            srt[j + 1] = srt[j]
            j -= 1
        srt[j + 1] = v
    return float(srt[k - 1])


@jit
def _start_crit(s0: int, nw: int, d2: Arr, srt: Arr, h: int, c3: float, crit: int,
                scale2: float) -> float:
    """Score of a fit: h-th smallest d² (crit 0) or Σ bisquare ρ(d/(s c₃)) (crit 1)."""
    if crit == 0:
        return _kth_smallest(d2, s0, nw, h, srt)
    tot = 0.0
    for i in range(s0, nw):
        u2 = d2[i] / (scale2 * c3 * c3)
        if u2 < 1.0:
            v = 1.0 - u2
            tot += 1.0 - v * v * v
        else:
            tot += 1.0
    return tot


@jit
def _robust_start(s0: int, nw: int, np_: int, phi: Arr, yc: Arr, sinv: Arr, d2: Arr,
                  srt: Arr, vaug: Arr, sub: IArr, x: Arr, xb: Arr, xc: Arr, d2c: Arr,
                  n_sub: int, h: int, q_h: float, c3: float, crit: int,
                  scale2_prev: float) -> float:
    """Robust start: leaves the best candidate's coefficients in ``xb``; returns s².

    Candidates: ``x`` (the plain GLS fit, on entry) and fits interpolating minimal subsets,
    kept in ``xc`` (rows) with their d² in ``d2c``.  s² starts from the previous push's
    ``scale2_prev``; the least h-th smallest d² over all candidates, divided by its
    expectation ``q_h`` for clean data, replaces it only when 5x larger: a scale-free
    check that catches a receiver σ far too optimistic, but is not fooled by the 3-4x a
    run of 5-8 jumps in 20 epochs can put on the h-th order statistic (a too-large s²
    lets the cubic bend onto the newest jumps).  Moderate optimism is left to the
    inlier-based refinement after IRLS.  The winner is then the
    minimum of Σρ at that scale (crit 1) or the LQS fit (crit 0).
    """
    m = 3 * np_
    n = nw - s0
    _mahal(s0, nw, np_, phi, x, yc, sinv, d2)
    for r in range(m):
        xc[0, r] = x[r]
    for i in range(s0, nw):
        d2c[0, i] = d2[i]
    nc = 1
    state = _SEED
    min_span = (n - 1) // 2
    attempts = 0
    while nc < n_sub + 1 and attempts < 4 * n_sub:
        attempts += 1
        # Distinct sorted indices; LCG in int64 (state < 2^31 keeps the product exact).
        for q in range(np_):
            while True:
                state = (state * 1103515245 + 12345) & 0x7FFFFFFF
                c = (state >> 8) % n
                dup = False
                for u in range(q):
                    if sub[u] == c:
                        dup = True
                if not dup:
                    break
            u = q - 1
            while u >= 0 and sub[u] > c:
                sub[u + 1] = sub[u]
                u -= 1
            sub[u + 1] = c
        # A subset bunched in time extrapolates wildly over the rest of the window.
        if sub[np_ - 1] - sub[0] < min_span:
            continue
        # Exact interpolation through the subset: Gaussian elimination with partial pivoting
        # on [V | Y] (np_ x (np_+3)), all three components at once.
        for q in range(np_):
            i = s0 + sub[q]
            for j in range(np_):
                vaug[q, j] = phi[i, j]
            for a in range(3):
                vaug[q, np_ + a] = yc[i, a]
        ok = True
        for j in range(np_):
            piv = j
            for q in range(j + 1, np_):
                if abs(vaug[q, j]) > abs(vaug[piv, j]):
                    piv = q
            if abs(vaug[piv, j]) < 1e-12:
                ok = False
                break
            if piv != j:
                for c in range(np_ + 3):
                    tmp = vaug[j, c]
                    vaug[j, c] = vaug[piv, c]
                    vaug[piv, c] = tmp
            for q in range(j + 1, np_):
                f = vaug[q, j] / vaug[j, j]
                for c in range(j, np_ + 3):
                    vaug[q, c] -= f * vaug[j, c]
        if not ok:
            continue
        for a in range(3):
            for j in range(np_ - 1, -1, -1):
                s = vaug[j, np_ + a]
                for c in range(j + 1, np_):
                    s -= vaug[j, c] * xc[nc, 3 * c + a]
                xc[nc, 3 * j + a] = s / vaug[j, j]
        _mahal(s0, nw, np_, phi, xc[nc], yc, sinv, d2c[nc])
        nc += 1
    lq_best = math.inf
    c_lq = 0
    for c in range(nc):
        lq = _kth_smallest(d2c[c], s0, nw, h, srt)
        if lq < lq_best:
            lq_best = lq
            c_lq = c
    scale2 = scale2_prev
    if lq_best / q_h > 5.0 * scale2_prev:
        scale2 = lq_best / q_h
    c_best = c_lq
    if crit == 1:
        best = math.inf
        for c in range(nc):
            sc = _start_crit(s0, nw, d2c[c], srt, h, c3, 1, scale2)
            if sc < best:
                best = sc
                c_best = c
    for r in range(m):
        xb[r] = xc[c_best, r]
    return scale2


@jit
def _irls(s0: int, nw: int, np_: int, phi: Arr, obs: Arr, sig: Arr, sth: Arr, bk: Arr,
          w: Arr, sinv: Arr, d2: Arr, nrm: Arr, rhs: Arr, x: Arr, m3: Arr, tmp: Arr,
          scale2: float, use_coef: bool, c3: float) -> int:
    """Bisquare IRLS from ``x``; leaves the fit in x, its factored normal matrix in nrm, the
    weights in w and the d² against the fit in d2.  Returns iterations, or -1 if singular."""
    for it in range(_MAX_IRLS):
        if not _fill_sinv(s0, nw, np_, phi, x, True, obs, sig, sth, bk, sinv, m3, tmp,
                          scale2, use_coef):
            return -1
        _mahal(s0, nw, np_, phi, x, obs, sinv, d2)
        dw = 0.0
        n_pos = 0
        for i in range(s0, nw):
            u2 = d2[i] / (c3 * c3)
            wn = (1.0 - u2) * (1.0 - u2) if u2 < 1.0 else 0.0
            dw = max(dw, abs(wn - w[i]))
            w[i] = wn
            if wn > 0.0:
                n_pos += 1
        if n_pos < np_ + 1:
            return -1
        if not _gls(s0, nw, np_, phi, obs, w, sinv, nrm, rhs, x):
            return -1
        if it > 0 and dw < _W_TOL:
            return it + 1
    return _MAX_IRLS


@jit
def _reexpress(xp: Arr, xprev: Arr, np_: int, alpha: float, beta: float) -> None:
    """xp = coefficients of the polynomial xprev(τ_old) in τ, where τ_old = α τ + β."""
    for i in range(np_):
        for a in range(3):
            xp[3 * i + a] = 0.0
    for j in range(np_):
        # Σ_i C(j,i) α^i β^(j-i) τ^i, binomial coefficient built incrementally.
        cb = 1.0
        for i in range(j + 1):
            f = cb * alpha**i * beta ** (j - i)
            for a in range(3):
                xp[3 * i + a] += xprev[3 * j + a] * f
            cb = cb * (j - i) / (i + 1)


@jit
def _raw_output(k: int, obs: Arr, sig: Arr, sth: Arr, bk: Arr, sinv: Arr, m3: Arr,
                tmp: Arr, vel: Arr, cov: Arr, use_coef: bool) -> None:
    """vel, cov = the newest epoch alone (used while filling and when a fit is singular)."""
    _epoch_cov_into(sinv[k], m3, tmp, sth[k], bk[k], sig[k] * sig[k],
                    obs[k, 0], obs[k, 1], obs[k, 2], use_coef)
    _inv3_sym(cov, sinv[k])
    for a in range(3):
        vel[a] = obs[k, a]


@jit
def _solve(t: Arr, y: Arr, sig: Arr, sth: Arr, bk: Arr, w: Arr, acc: Arr, tau: Arr, phi: Arr,
           sinv: Arr, d2: Arr, srt: Arr, nrm: Arr, meat: Arr, rhs: Arr, x: Arr, xb: Arr,
           xs: Arr, e: Arr, col: Arr, vaug: Arr, sub: IArr, m3: Arr, tmp: Arr, xp: Arr,
           xprev: Arr, xbest: Arr, wb: Arr, xc: Arr, d2c: Arr, qh: Arr, vel: Arr, cov: Arr,
           fout: Arr, iout: IArr, obs: Arr, use_coef: bool, mode: int, np_: int, c3: float,
           n_sub: int, start_crit: int, s0: int, k: int, count: int) -> int:
    """Fit the full window (count >= min_epochs) per ``mode``; status code."""
    nw = t.shape[0]
    span = t[k] - t[s0]
    for i in range(s0, nw):
        tau[i] = (t[i] - t[k]) / span
        p = 1.0
        for j in range(np_):
            phi[i, j] = p
            p *= tau[i]
    m = 3 * np_

    if mode == 3:
        # χ² gate against the LS prediction from the previously accepted epochs.
        _fill_sinv(s0, nw, np_, phi, x, False, y, sig, sth, bk, sinv, m3, tmp, 1.0, False)
        acc[k] = 0.0
        n_acc = 0
        for i in range(s0, k):
            n_acc += int(acc[i])
        accept = True
        if n_acc >= np_ + 1 and _gls(s0, nw, np_, phi, y, acc, sinv, nrm, rhs, x):
            _sandwich_cov(s0, nw, np_, phi, acc, sinv, nrm, meat, xs, e, col, cov)
            for a in range(3):
                for b in range(3):
                    tmp[a, b] = cov[a, b]
                tmp[a, a] += sig[k] * sig[k]
                e[a] = y[k, a] - x[a]
            _inv3_sym(m3, tmp)
            dg = 0.0
            for a in range(3):
                for b in range(3):
                    dg += e[a] * m3[a, b] * e[b]
            fout[_F_D2] = dg
            if dg > GATE_CHI2_3:
                if iout[_I_CONSEC] < nw // 2:
                    accept = False
                else:
                    # Locked out: the rejected run agrees with itself, not with the history.
                    # Restart from it, as a filter resets its state after repeated rejections.
                    first = k - iout[_I_CONSEC]
                    for i in range(s0, first):
                        acc[i] = 0.0
                    for i in range(max(s0, first), k):
                        acc[i] = 1.0
        if accept:
            iout[_I_CONSEC] = 0
            acc[k] = 1.0
            if not _gls(s0, nw, np_, phi, y, acc, sinv, nrm, rhs, x):
                return _ST_SINGULAR
            _sandwich_cov(s0, nw, np_, phi, acc, sinv, nrm, meat, xs, e, col, cov)
        else:
            # The prediction (x, cov of the fit without the newest epoch) is the output.
            iout[_I_CONSEC] += 1
            iout[_I_OUTLIER] = 1
        for i in range(s0, nw):
            w[i] = acc[i]
        for a in range(3):
            vel[a] = x[a]
        return _ST_OK

    for i in range(s0, nw):
        w[i] = 1.0
    # Plain fit; for the CTLS modes its S_k are evaluated at the observations first.
    if not _fill_sinv(s0, nw, np_, phi, x, False, obs, sig, sth, bk, sinv, m3, tmp, 1.0,
                      use_coef):
        return _ST_SINGULAR
    if not _gls(s0, nw, np_, phi, obs, w, sinv, nrm, rhs, x):
        return _ST_SINGULAR
    if mode == 1:
        # Fixed point on Σ_k(a): the coefficient noise depends on the unknown velocity.
        for _ in range(2):
            if not _fill_sinv(s0, nw, np_, phi, x, True, obs, sig, sth, bk, sinv, m3, tmp,
                              1.0, use_coef):
                return _ST_SINGULAR
            if not _gls(s0, nw, np_, phi, obs, w, sinv, nrm, rhs, x):
                return _ST_SINGULAR
    elif mode == 2:
        n = count
        h = min(n, n // 2 + (np_ + 1) // 2)
        has_prev = iout[_I_HAS_PREV] == 1
        if has_prev:
            hp = fout[_F_H_PREV]
            _reexpress(xp, xprev, np_, span / hp, (t[k] - fout[_F_T_PREV]) / hp)
        scale2 = _robust_start(s0, nw, np_, phi, obs, sinv, d2, srt, vaug, sub, x, xb, xc,
                               d2c, n_sub, h, qh[n], c3, start_crit,
                               fout[_F_S2_PREV] if has_prev else 1.0)
        # Polished starts compared on the M-objective J = Σρ (what IRLS descends; its minima
        # are nearly flat between "this epoch is the outlier" and "that one is", the cubic's
        # end being flexible): (1) the best of LS and the subsets; (2) the previous
        # solution, kept unless (1) explains at least one more epoch (J lower by 1, one
        # outlier's worth): this hysteresis keeps a growing run of jumps rejected; (3) the
        # winner with a rejected newest epoch re-admitted, tried only when that epoch is
        # within twice the rejection radius: a clean epoch must not stay rejected because a
        # noisy neighbour bent the cubic's end, while a jump of many σ is never re-admitted.
        jbest = math.inf
        d2k_best = 0.0
        for cand in range(3):
            if cand == 0:
                for r in range(m):
                    x[r] = xb[r]
            elif cand == 1:
                if not has_prev:
                    continue
                for r in range(m):
                    x[r] = xp[r]
            else:
                if jbest == math.inf or wb[k] > 0.0 or d2k_best > 4.0 * c3 * c3:
                    continue
                for i in range(s0, nw):
                    w[i] = wb[i]
                w[k] = 1.0
                if not (_fill_sinv(s0, nw, np_, phi, xbest, True, obs, sig, sth, bk, sinv, m3,
                                   tmp, scale2, use_coef)
                        and _gls(s0, nw, np_, phi, obs, w, sinv, nrm, rhs, x)):
                    continue
            its = _irls(s0, nw, np_, phi, obs, sig, sth, bk, w, sinv, d2, nrm, rhs, x, m3,
                        tmp, scale2, use_coef, c3)
            if its < 0:
                continue
            # d² already carries s², hence scale 1 here.
            jc = _start_crit(s0, nw, d2, srt, h, c3, 1, 1.0)
            if jc < jbest + (_HYSTERESIS if cand == 1 else 0.0):
                jbest = jc
                d2k_best = d2[k]
                for r in range(m):
                    xbest[r] = x[r]
                for i in range(s0, nw):
                    wb[i] = w[i]
        if jbest == math.inf:
            return _ST_SINGULAR
        # Re-polish the winner so that w, S_k, d² and the factor all belong to it.
        for r in range(m):
            x[r] = xbest[r]
        its = _irls(s0, nw, np_, phi, obs, sig, sth, bk, w, sinv, d2, nrm, rhs, x, m3, tmp,
                    scale2, use_coef, c3)
        if its < 0:
            return _ST_SINGULAR
        # Refine s² on the inliers' residuals against their degrees of freedom: the start's
        # value is coarse (and inflated by contamination).  s² stays 1 unless the receiver's
        # σ is optimistic at 99 %; it never goes below 1.
        for _ in range(4):
            ssum = 0.0
            n_in = 0
            for i in range(s0, nw):
                if w[i] > 0.0:
                    ssum += d2[i]
                    n_in += 1
            dof = 3 * (n_in - np_)
            if dof <= 0:
                break
            ratio = ssum / dof
            if scale2 == 1.0 and ratio <= 1.0 + 2.33 * math.sqrt(2.0 / dof):
                break
            if abs(ratio - 1.0) <= 0.05:
                break
            new = max(1.0, scale2 * ratio)
            if new == scale2:
                break
            scale2 = new
            its2 = _irls(s0, nw, np_, phi, obs, sig, sth, bk, w, sinv, d2, nrm, rhs, x, m3,
                         tmp, scale2, use_coef, c3)
            if its2 < 0:
                return _ST_SINGULAR
            its += its2
        iout[_I_ITERS] = its
        fout[_F_SCALE] = math.sqrt(scale2)
        fout[_F_D2] = d2[k]
        iout[_I_OUTLIER] = 1 if w[k] <= 0.0 else 0
        for r in range(m):
            xprev[r] = x[r]
        fout[_F_T_PREV] = t[k]
        fout[_F_H_PREV] = span
        fout[_F_S2_PREV] = scale2
        iout[_I_HAS_PREV] = 1
    _sandwich_cov(s0, nw, np_, phi, w, sinv, nrm, meat, xs, e, col, cov)
    for a in range(3):
        vel[a] = x[a]
    return _ST_OK


@jit
def _push_kernel(t: Arr, y: Arr, yc: Arr, sig: Arr, sth: Arr, bk: Arr, w: Arr, acc: Arr,
                 tau: Arr, phi: Arr, sinv: Arr, d2: Arr, srt: Arr, nrm: Arr, meat: Arr,
                 rhs: Arr, x: Arr, xb: Arr, xs: Arr, e: Arr, col: Arr, vaug: Arr, sub: IArr,
                 m3: Arr, tmp: Arr, xp: Arr, xprev: Arr, xbest: Arr, wb: Arr, xc: Arr,
                 d2c: Arr, qh: Arr, vel: Arr, cov: Arr, fout: Arr, iout: IArr, t_s: float,
                 vx: float, vy: float, vz: float, sigma_mps: float, lat_rad: float,
                 lon_rad: float, pos_sigma_m: float, mode: int, np_: int, min_epochs: int,
                 c3: float, n_sub: int, start_crit: int, max_gap_s: float) -> int:
    """Insert one epoch and solve; see :class:`Mctls` for the arrays' shapes and units."""
    nw = t.shape[0]
    count = iout[_I_COUNT]
    if count > 0 and (not t_s > t[nw - 1] or t_s - t[nw - 1] > max_gap_s):
        # Time went backwards (replay seek) or a gap the polynomial cannot bridge.
        count = 0
        iout[_I_CONSEC] = 0
        iout[_I_HAS_PREV] = 0
    # Shift the window one slot towards the start; the newest epoch lives at nw - 1.
    for i in range(nw - 1):
        t[i] = t[i + 1]
        sig[i] = sig[i + 1]
        w[i] = w[i + 1]
        acc[i] = acc[i + 1]
        for a in range(3):
            y[i, a] = y[i + 1, a]
            yc[i, a] = yc[i + 1, a]
            for b in range(3):
                sth[i, a, b] = sth[i + 1, a, b]
                bk[i, a, b] = bk[i + 1, a, b]
    count = min(count + 1, nw)
    iout[_I_COUNT] = count
    k = nw - 1
    t[k] = t_s
    sig[k] = max(sigma_mps, 1e-3)
    mat_ne_into(m3, lat_rad, lon_rad)
    for a in range(3):
        y[k, a] = m3[a, 0] * vx + m3[a, 1] * vy + m3[a, 2] * vz
    _sigma_theta_into(sth[k], lat_rad, pos_sigma_m)
    tr = sth[k, 0, 0] + sth[k, 1, 1] + sth[k, 2, 2]
    for a in range(3):
        for b in range(3):
            bk[k, a, b] = 0.5 * sth[k, a, b]
        bk[k, a, a] += 1.0 - 0.5 * tr
    _inv3_sym(tmp, bk[k])
    for a in range(3):
        yc[k, a] = tmp[a, 0] * y[k, 0] + tmp[a, 1] * y[k, 1] + tmp[a, 2] * y[k, 2]
    s0 = nw - count
    for i in range(s0):
        w[i] = 0.0
        acc[i] = 0.0
    w[k] = 1.0
    acc[k] = 1.0
    iout[_I_OUTLIER] = 0
    iout[_I_ITERS] = 0
    fout[_F_D2] = 0.0
    fout[_F_SCALE] = 1.0
    use_coef = mode == 1 or mode == 2
    obs = yc if use_coef else y
    if count < min_epochs:
        # Not enough epochs for a fit: hand out the raw epoch with its own covariance.
        _raw_output(k, obs, sig, sth, bk, sinv, m3, tmp, vel, cov, use_coef)
        for i in range(s0, nw):
            w[i] = 1.0
        return _ST_FILLING

    st = _solve(t, y, sig, sth, bk, w, acc, tau, phi, sinv, d2, srt, nrm, meat, rhs, x, xb,
                xs, e, col, vaug, sub, m3, tmp, xp, xprev, xbest, wb, xc, d2c, qh, vel, cov, fout,
                iout, obs, use_coef, mode, np_, c3, n_sub, start_crit, s0, k, count)
    if st != _ST_OK:
        _raw_output(k, obs, sig, sth, bk, sinv, m3, tmp, vel, cov, use_coef)
        for i in range(s0, nw):
            w[i] = 1.0
        iout[_I_OUTLIER] = 0
        # A stale solution would enjoy the hysteresis at the next push.
        iout[_I_HAS_PREV] = 0
    return st


_STATE_SPEC = [
    # Window data, oldest..newest (newest at index window-1).
    ("t", nb.float64[::1]),  # (W,) epoch times, s
    ("y", nb.float64[:, ::1]),  # (W, 3) C_e^n v^e, NED m/s
    ("yc", nb.float64[:, ::1]),  # (W, 3) B⁻¹ y, NED m/s
    ("sig", nb.float64[::1]),  # (W,) receiver σ, m/s
    ("sth", nb.float64[:, :, ::1]),  # (W, 3, 3) Σθ, rad²
    ("bk", nb.float64[:, :, ::1]),  # (W, 3, 3) B = E[Exp(-δθ)]
    ("w", nb.float64[::1]),  # (W,) weights
    ("acc", nb.float64[::1]),  # (W,) gate: 1 accepted, 0 rejected
    # Scratch (M = 3 (order + 1)).
    ("tau", nb.float64[::1]),  # (W,)
    ("phi", nb.float64[:, ::1]),  # (W, order+1) τ^j
    ("sinv", nb.float64[:, :, ::1]),  # (W, 3, 3) S_k, s²/m²
    ("d2", nb.float64[::1]),  # (W,)
    ("srt", nb.float64[::1]),  # (W,)
    ("nrm", nb.float64[:, ::1]),  # (M, M)
    ("meat", nb.float64[:, ::1]),  # (M, M)
    ("rhs", nb.float64[::1]),  # (M,)
    ("x", nb.float64[::1]),  # (M,) coefficients [a_0 | a_1 | ...], NED m/s
    ("xb", nb.float64[::1]),
    ("xs", nb.float64[:, ::1]),  # (M, 3)
    ("e", nb.float64[::1]),
    ("col", nb.float64[::1]),
    ("vaug", nb.float64[:, ::1]),  # (order+1, order+4)
    ("sub", nb.int64[::1]),  # (order+1,)
    ("m3", nb.float64[:, ::1]),  # (3, 3)
    ("tmp", nb.float64[:, ::1]),  # (3, 3)
    ("xp", nb.float64[::1]),  # (M,) previous fit in this window's τ
    ("xprev", nb.float64[::1]),  # (M,) previous fit in its own τ
    ("xbest", nb.float64[::1]),  # (M,) best polished start
    ("wb", nb.float64[::1]),  # (W,) its weights
    ("xc", nb.float64[:, ::1]),  # (n_subsets+1, M) robust-start candidates
    ("d2c", nb.float64[:, ::1]),  # (n_subsets+1, W) their d²
    ("qh", nb.float64[::1]),  # (W+1,) χ²_3 quantile at h/(n+1) for n valid epochs
    # Outputs.
    ("vel", nb.float64[::1]),  # (3,) NED m/s
    ("cov", nb.float64[:, ::1]),  # (3, 3) m²/s²
    ("fout", nb.float64[::1]),  # (5,) see _F_*
    ("iout", nb.int64[::1]),  # (5,) see _I_*
]


@jitclass(_STATE_SPEC)
class _State:
    """Every array of one estimator, allocated once by numba's runtime.

    A jitclass because a plain numpy array passed from Python into compiled code gets a
    fresh NRT meminfo on every call (one allocation per array argument); the jitclass is
    unboxed by reference, so a push passes scalars only and allocates nothing.
    """

    def __init__(self, window: int, np_: int, n_sub: int, qh: Arr) -> None:
        nw = window
        m = 3 * np_
        self.t = np.zeros(nw)
        self.y = np.zeros((nw, 3))
        self.yc = np.zeros((nw, 3))
        self.sig = np.ones(nw)
        self.sth = np.zeros((nw, 3, 3))
        self.bk = np.zeros((nw, 3, 3))
        self.w = np.zeros(nw)
        self.acc = np.zeros(nw)
        self.tau = np.zeros(nw)
        self.phi = np.zeros((nw, np_))
        self.sinv = np.zeros((nw, 3, 3))
        self.d2 = np.zeros(nw)
        self.srt = np.zeros(nw)
        self.nrm = np.zeros((m, m))
        self.meat = np.zeros((m, m))
        self.rhs = np.zeros(m)
        self.x = np.zeros(m)
        self.xb = np.zeros(m)
        self.xs = np.zeros((m, 3))
        self.e = np.zeros(m)
        self.col = np.zeros(m)
        self.vaug = np.zeros((np_, np_ + 3))
        self.sub = np.zeros(np_, dtype=np.int64)
        self.m3 = np.zeros((3, 3))
        self.tmp = np.zeros((3, 3))
        self.xp = np.zeros(m)
        self.xprev = np.zeros(m)
        self.xbest = np.zeros(m)
        self.wb = np.zeros(nw)
        self.xc = np.zeros((n_sub + 1, m))
        self.d2c = np.zeros((n_sub + 1, nw))
        self.qh = qh.copy()
        self.vel = np.zeros(3)
        self.cov = np.zeros((3, 3))
        self.fout = np.zeros(5)
        self.iout = np.zeros(5, dtype=np.int64)


# Not cached: numba cannot cache functions of jitclass arguments.  It is a thin shim; the
# cached kernels it calls are loaded from disk.
@nb.njit(nogil=True)
def _push_state(st: _State, t_s: float, vx: float, vy: float, vz: float, sigma_mps: float,
                lat_rad: float, lon_rad: float, pos_sigma_m: float, mode: int, np_: int,
                min_epochs: int, c3: float, n_sub: int, start_crit: int,
                max_gap_s: float) -> int:
    return _push_kernel(st.t, st.y, st.yc, st.sig, st.sth, st.bk, st.w, st.acc, st.tau,
                        st.phi, st.sinv, st.d2, st.srt, st.nrm, st.meat, st.rhs, st.x,
                        st.xb, st.xs, st.e, st.col, st.vaug, st.sub, st.m3, st.tmp, st.xp,
                        st.xprev, st.xbest, st.wb, st.xc, st.d2c, st.qh, st.vel, st.cov,
                        st.fout, st.iout, t_s, vx, vy, vz, sigma_mps, lat_rad, lon_rad,
                        pos_sigma_m, mode, np_, min_epochs, c3, n_sub, start_crit, max_gap_s)


class Mctls:
    """Robust sliding-window GNSS velocity (MCTLS); see the module docstring for the model.

    Parameters
    ----------
    window : epochs in the sliding window (>= min_epochs).
    order : polynomial order p of the NED velocity in time (3 = constant jerk).
    mode : "ls" (weighted LS), "tls" (constrained TLS), "mctls" (constrained TLS + robust
        start + bisquare IRLS) or "gate" (LS with a χ² innovation gate on the newest epoch,
        the cheap alternative).
    bisquare_c : scalar bisquare tuning constant; scaled by ``KAPPA_3D`` for the 3-D residual.
    min_epochs : epochs needed before an estimate is produced (>= order + 2).
    pos_sigma_m : default 1-σ horizontal position error of a fix (m): the coefficient noise
        of the ECEF→NED rotation.  ``push`` may override it per epoch (receiver h_acc).
    n_subsets : minimal subsets tried by the robust start.
    start : robust-start criterion, "lqs" (h-th smallest d², least-median style) or "rho"
        (Σ bisquare ρ at the current σ scale); see the module docstring.
    max_gap_s : a larger gap between epochs (s) restarts the window.

    Attributes (views of internal arrays, updated in place by ``push``)
    ----------
    vel_n : (3,) NED velocity at the newest epoch, m/s.
    cov_n : (3, 3) its covariance, m²/s².
    weights : (window,) weight in [0, 1] per epoch, oldest..newest; the valid entries are
        the last ``count``, the others are 0.
    """

    def __init__(self, window: int = 20, order: int = 3, mode: str = "mctls",
                 bisquare_c: float = 4.685, min_epochs: int = 8, *,
                 pos_sigma_m: float = 10.0, n_subsets: int = 100, start: str = "lqs",
                 max_gap_s: float = 1.0) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {sorted(MODES)}, got {mode!r}")
        if start not in ("rho", "lqs"):
            raise ValueError(f"start must be 'rho' or 'lqs', got {start!r}")
        if not 0 <= order <= 5:
            raise ValueError("order must be in 0..5")
        if min_epochs < order + 2:
            raise ValueError("min_epochs must be >= order + 2 (one redundant epoch)")
        if window < min_epochs:
            raise ValueError("window must be >= min_epochs")
        if not bisquare_c > 0.0 or not pos_sigma_m >= 0.0 or not max_gap_s > 0.0:
            raise ValueError("bisquare_c and max_gap_s must be > 0, pos_sigma_m >= 0")
        if n_subsets < 0:
            raise ValueError("n_subsets must be >= 0")
        self.window = window
        self.order = order
        self.mode = mode
        self.min_epochs = min_epochs
        self.bisquare_c = bisquare_c
        self.pos_sigma_m = pos_sigma_m
        self.n_subsets = n_subsets
        self.start = start
        self.max_gap_s = max_gap_s
        self._mode = MODES[mode]
        self._c3 = KAPPA_3D * bisquare_c
        self._start_crit = 1 if start == "rho" else 0
        self._np = order + 1
        qh = np.ones(window + 1)
        for n in range(1, window + 1):
            h = min(n, n // 2 + (self._np + 1) // 2)
            qh[n] = chi2_3_quantile(h / (n + 1.0))
        self._st = _State(window, self._np, n_subsets, qh)
        # Boxed once: these ndarrays share memory with the jitclass' arrays.
        self.vel_n: Arr = self._st.vel
        self.cov_n: Arr = self._st.cov
        self.weights: Arr = self._st.w
        self._fout: Arr = self._st.fout
        self._iout: IArr = self._st.iout
        self._valid = False

    def reset(self) -> None:
        """Forget the window (e.g. after a receiver restart)."""
        self._iout[:] = 0
        self._fout[:] = 0.0
        self.weights[:] = 0.0
        self.vel_n[:] = 0.0
        self.cov_n[:] = 0.0
        self._valid = False

    def push(self, t_s: float, vel_ecef: Arr, sigma_mps: float, lat_rad: float,
             lon_rad: float, pos_sigma_m: float | None = None) -> bool:
        """Add one GNSS epoch; True when ``vel_n``/``cov_n`` hold a windowed estimate.

        t_s : receive time, s (monotonic).  vel_ecef : (3,) ECEF velocity, m/s.
        sigma_mps : receiver 1-σ speed accuracy, m/s.  lat_rad, lon_rad : geodetic position
        of the fix (defines C_e^n).  pos_sigma_m : this fix's 1-σ horizontal position error
        (m), default the constructor's.  A non-finite input is ignored (returns False and
        leaves the window untouched).
        """
        ps = self.pos_sigma_m if pos_sigma_m is None else float(pos_sigma_m)
        vx = float(vel_ecef[0])
        vy = float(vel_ecef[1])
        vz = float(vel_ecef[2])
        if not (math.isfinite(t_s) and math.isfinite(sigma_mps) and math.isfinite(lat_rad)
                and math.isfinite(lon_rad) and math.isfinite(ps) and math.isfinite(vx)
                and math.isfinite(vy) and math.isfinite(vz)):
            return False
        st = _push_state(self._st, float(t_s), vx, vy, vz, float(sigma_mps), float(lat_rad),
                         float(lon_rad), ps, self._mode, self._np, self.min_epochs, self._c3,
                         self.n_subsets, self._start_crit, self.max_gap_s)
        self._valid = st == _ST_OK
        return self._valid

    @property
    def count(self) -> int:
        """Valid epochs in the window."""
        return int(self._iout[_I_COUNT])

    @property
    def window_full(self) -> bool:
        return int(self._iout[_I_COUNT]) == self.window

    @property
    def valid(self) -> bool:
        """Whether the last push produced a windowed estimate."""
        return self._valid

    @property
    def newest_weight(self) -> float:
        """Weight in [0, 1] of the newest epoch (0: skip the raw epoch)."""
        return float(self.weights[-1])

    @property
    def newest_outlier(self) -> bool:
        """The newest epoch was rejected (robust weight 0, or gated)."""
        return bool(self._iout[_I_OUTLIER])

    @property
    def newest_d2(self) -> float:
        """Mahalanobis distance² of the newest epoch (against the fit, or the gate's d²)."""
        return float(self._fout[_F_D2])

    @property
    def scale(self) -> float:
        """Factor (>= 1) applied to the receiver's σ in the last "mctls" solve."""
        return float(self._fout[_F_SCALE])
