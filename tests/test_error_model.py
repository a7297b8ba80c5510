"""Independent check of the continuous error model F (navd.core.errors.build_f).

The reference is a nonlinear continuous mechanization written here from scratch (its own
WGS-84 radii and Somigliana gravity, its own SO(3) helpers; nothing from navd but the
function under test)::

    C' = C [w_ib x] - [w_in x] C
    v' = C f + gamma(L, h) [0, 0, 1] - (2 w_ie + w_en) x v
    L' = vN / (RM + h),   lon' = vE / ((RN + h) cos L),   h' = -vD
    w_ib = w~ - bg,  f = f~ - ba          (w~, f~: raw sensor output; bg, ba: biases)

A "true" state X and a "computed" state X^ (same raw sensor output, own bias estimates)
define the error e = (phi, dv, dp, dbg, dba) with navd's conventions::

    C^ = Exp(-phi) C,  dv = v^ - v,  dp = p^ - p,  dbg = bg - bg^,  dba = ba - ba^

and its exact time derivative follows from the definitions (below).  Column j of the
Jacobian d(e')/de is the central difference of e' over X^ = X perturbed by +-eps_j in error
component j.  It must equal build_f's column j.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from navd.core.errors import build_f
from navd.core.kalman import propagate_cov

# ---------------------------------------------------------------- independent WGS-84
A_M = 6378137.0
FLAT = 1.0 / 298.257223563
E2 = FLAT * (2.0 - FLAT)
B_M = A_M * (1.0 - FLAT)
W_IE = 7.292115e-5
GM = 3.986004418e14
G_EQ = 9.7803253359
G_POLE = 9.8321849378


def ref_radii(lat: float) -> tuple[float, float]:
    """(R_M meridian, R_N prime vertical)."""
    w2 = 1.0 - E2 * math.sin(lat) ** 2
    return A_M * (1.0 - E2) / w2**1.5, A_M / math.sqrt(w2)


def ref_gravity(lat: float, h: float) -> float:
    """Somigliana normal gravity with the NIMA TR8350.2 second-order free-air term."""
    s2 = math.sin(lat) ** 2
    k = B_M * G_POLE / (A_M * G_EQ) - 1.0
    m = W_IE**2 * A_M**2 * B_M / GM
    g0 = G_EQ * (1.0 + k * s2) / math.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 * h / A_M * (1.0 + FLAT + m - 2.0 * FLAT * s2) + 3.0 * h * h / A_M**2)


# ---------------------------------------------------------------- independent SO(3)
def sk(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def vee(m: np.ndarray) -> np.ndarray:
    return np.array([m[2, 1], m[0, 2], m[1, 0]])


def so3_exp(v: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(v))
    k = sk(v)
    if th < 1e-7:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + math.sin(th) / th * k + (1.0 - math.cos(th)) / th**2 * k @ k


def so3_log(r: np.ndarray) -> np.ndarray:
    c = min(1.0, max(-1.0, 0.5 * (np.trace(r) - 1.0)))
    th = math.acos(c)
    w = 0.5 * vee(r - r.T)
    if th < 1e-7:
        return w * (1.0 + th * th / 6.0)
    return w * th / math.sin(th)


def jl_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse left Jacobian of SO(3): d/dt Log(R) = Jl^-1 w for R' = [w x] R."""
    th = float(np.linalg.norm(phi))
    k = sk(phi)
    if th < 1e-6:
        return np.eye(3) - 0.5 * k + k @ k / 12.0
    a = 1.0 / th**2 - (1.0 + math.cos(th)) / (2.0 * th * math.sin(th))
    return np.eye(3) - 0.5 * k + a * k @ k


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


# ---------------------------------------------------------------- reference mechanization
def rates(p: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(w_ie^n, w_en^n) in NED."""
    lat, h = p[0], p[2]
    rm, rn = ref_radii(lat)
    w_ie = np.array([W_IE * math.cos(lat), 0.0, -W_IE * math.sin(lat)])
    w_en = np.array([v[1] / (rn + h), -v[0] / (rm + h), -v[1] * math.tan(lat) / (rn + h)])
    return w_ie, w_en


def deriv(s: dict, raw_w: np.ndarray, raw_f: np.ndarray) -> dict:
    """Continuous-time derivative of the nonlinear mechanization at state s."""
    c, v, p = s["C"], s["v"], s["p"]
    w_ib = raw_w - s["bg"]
    f_b = raw_f - s["ba"]
    w_ie, w_en = rates(p, v)
    w_in = w_ie + w_en
    rm, rn = ref_radii(p[0])
    return {
        "C": c @ sk(w_ib) - sk(w_in) @ c,
        "v": c @ f_b + np.array([0.0, 0.0, ref_gravity(p[0], p[2])])
        - np.cross(2.0 * w_ie + w_en, v),
        "p": np.array([v[0] / (rm + p[2]), v[1] / ((rn + p[2]) * math.cos(p[0])), -v[2]]),
        "bg": np.zeros(3),
        "ba": np.zeros(3),
    }


def error(hat: dict, true: dict) -> np.ndarray:
    """e = (phi, dv, dp, dbg, dba) with C^ = Exp(-phi) C, biases as residuals b - b^."""
    return np.concatenate([
        so3_log(true["C"] @ hat["C"].T), hat["v"] - true["v"], hat["p"] - true["p"],
        true["bg"] - hat["bg"], true["ba"] - hat["ba"]])


def error_rate(hat: dict, true: dict, raw_w: np.ndarray, raw_f: np.ndarray) -> np.ndarray:
    """Exact d e / dt.

    With R = C C^T_hat = Exp(phi) and both C's following C' = C[w x] - [w_in x] C::

        R' R^T = -C [(w^ - w) x] C^T - [w_in x] + [(R w^_in) x]
        phi'   = Jl(phi)^-1 vee(R' R^T)

    (w^ - w = bg - bg^ is formed directly, so no O(1) body rates cancel in round-off.)
    """
    dh = deriv(hat, raw_w, raw_f)
    dt = deriv(true, raw_w, raw_f)
    c = true["C"]
    r = c @ hat["C"].T
    w_ie, w_en = rates(true["p"], true["v"])
    w_ie_h, w_en_h = rates(hat["p"], hat["v"])
    w_left = -c @ (true["bg"] - hat["bg"]) - (w_ie + w_en) + r @ (w_ie_h + w_en_h)
    phi = so3_log(r)
    return np.concatenate([
        jl_inv(phi) @ w_left, dh["v"] - dt["v"], dh["p"] - dt["p"],
        dt["bg"] - dh["bg"], dt["ba"] - dh["ba"]])


def perturbed(true: dict, j: int, eps: float) -> dict:
    """Computed state whose error is eps in component j (conventions of navd)."""
    hat = {k: np.array(val, dtype=float) for k, val in true.items()}
    if j < 3:
        d = np.zeros(3)
        d[j] = eps
        hat["C"] = so3_exp(-d) @ true["C"]
    elif j < 6:
        hat["v"][j - 3] += eps
    elif j < 9:
        hat["p"][j - 6] += eps
    elif j < 12:
        hat["bg"][j - 9] -= eps  # dbg = bg - bg^
    else:
        hat["ba"][j - 12] -= eps
    return hat


# perturbation sizes per error component (linear regime, above round-off)
EPS = np.array([1e-3] * 3 + [0.1] * 3 + [1e-5, 1e-5, 1000.0] + [1e-4] * 3 + [1e-2] * 3)
# absolute round-off floor of each component of e' (1/s * unit)
FLOOR = np.array([1e-19] * 3 + [5e-15] * 3 + [1e-20, 1e-20, 2e-15] + [1e-30] * 6)


def numerical_f(true: dict, raw_w: np.ndarray, raw_f: np.ndarray) -> np.ndarray:
    J = np.zeros((15, 15))
    for j in range(15):
        ep = error_rate(perturbed(true, j, EPS[j]), true, raw_w, raw_f)
        em = error_rate(perturbed(true, j, -EPS[j]), true, raw_w, raw_f)
        J[:, j] = (ep - em) / (2.0 * EPS[j])
    return J


def random_case(rng: np.random.Generator, lat_deg: float) -> tuple[dict, np.ndarray, np.ndarray]:
    speed = rng.uniform(0.5, 30.0)
    d = rng.normal(size=3)
    d[2] *= 0.5
    v = speed * d / np.linalg.norm(d)
    if abs(v[2]) < 0.5:
        v[2] = 0.5 if v[2] >= 0.0 else -0.5
    true = {
        "C": random_rotation(rng),
        "v": v,
        "p": np.array([math.radians(lat_deg), rng.uniform(-math.pi, math.pi),
                       rng.uniform(-200.0, 5000.0)]),
        "bg": rng.normal(scale=0.01, size=3),
        "ba": rng.normal(scale=0.2, size=3),
    }
    raw_w = rng.normal(scale=0.5, size=3)
    # specific force with substantial horizontal components in n, whatever the attitude
    f_n = np.array([rng.uniform(-6, 6), rng.uniform(-6, 6), -9.8 + rng.uniform(-3, 3)])
    raw_f = true["C"].T @ f_n + true["ba"]
    return true, raw_w, raw_f


LATS = [0.0, 12.5, -33.0, 45.0, 60.0, -60.0, 75.0, -80.0]


def navd_f(true: dict, raw_f: np.ndarray) -> np.ndarray:
    F = np.full((15, 15), np.nan)
    f_n = true["C"] @ (raw_f - true["ba"])
    build_f(F, np.ascontiguousarray(true["C"]), true["v"].copy(), true["p"].copy(), f_n)
    return F


def test_reference_error_rate_matches_time_integration() -> None:
    """Self-check of the reference: analytic e' equals d/dt of e along the integrated flow."""
    rng = np.random.default_rng(7)
    true, raw_w, raw_f = random_case(rng, 47.0)
    hat = perturbed(perturbed(true, 1, 2e-3), 4, 0.3)
    hat["p"][2] += 40.0
    hat["bg"] += 1e-3
    hat["ba"] -= 0.05

    def flow(s: dict, t: float) -> dict:
        # first order in t is enough: a central difference cancels every even-order term
        d = deriv(s, raw_w, raw_f)
        w_ie, w_en = rates(s["p"], s["v"])
        out = {k: s[k] + t * d[k] for k in ("v", "p", "bg", "ba")}
        out["C"] = so3_exp(-t * (w_ie + w_en)) @ s["C"] @ so3_exp(t * (raw_w - s["bg"]))
        return out

    t = 1e-3
    num = (error(flow(hat, t), flow(true, t)) - error(flow(hat, -t), flow(true, -t))) / (2 * t)
    ana = error_rate(hat, true, raw_w, raw_f)
    floor = np.array([1e-12] * 3 + [1e-10] * 3 + [1e-12, 1e-12, 1e-8] + [0.0] * 6)
    assert np.all(np.abs(num - ana) <= 1e-4 * np.abs(ana) + floor), (num, ana)


def test_reference_earth_model_values() -> None:
    """GIVEN this file's independent WGS-84 radii and Somigliana gravity,
    WHEN they are evaluated at the equator, the pole and 100 m above 0.7 rad latitude,
    THEN they give R_N = a, R_M = 6335439.327 m, the TR8350.2 equator and pole gravity
    and the -3.086e-6 s^-2 free-air gradient."""
    # textbook anchors for the independent WGS-84 helpers
    rm, rn = ref_radii(0.0)
    assert rn == A_M and abs(rm - 6335439.327) < 1e-3
    assert abs(ref_gravity(0.0, 0.0) - G_EQ) < 1e-12
    assert abs(ref_gravity(math.pi / 2, 0.0) - G_POLE) < 1e-9
    assert abs((ref_gravity(0.7, 100.0) - ref_gravity(0.7, 0.0)) / 100.0 + 3.086e-6) < 2e-8


@pytest.mark.parametrize("lat_deg", LATS)
def test_build_f_matches_numerical_jacobian(lat_deg: float) -> None:
    """GIVEN random states (attitude, 0.5-30 m/s velocity, height, biases, sensor output)
    at latitudes from -80 to 75 deg,
    WHEN navd's build_f is compared with the central-difference Jacobian of the independent
    reference mechanization's exact error rate,
    THEN F is finite and every entry matches to 1e-4 relative, above each component's
    round-off floor."""
    rng = np.random.default_rng(int(1000 + 10 * lat_deg))
    for _ in range(3):
        true, raw_w, raw_f = random_case(rng, lat_deg)
        J = numerical_f(true, raw_w, raw_f)
        F = navd_f(true, raw_f)
        assert np.all(np.isfinite(F))
        atol = FLOOR[:, None] / EPS[None, :]
        err = np.abs(F - J)
        bad = err > 1e-4 * np.abs(J) + atol
        if bad.any():
            lines = [f"F[{i},{j}]: navd {F[i, j]:.9e} numerical {J[i, j]:.9e}"
                     for i, j in zip(*np.nonzero(bad), strict=True)]
            pytest.fail(f"lat {lat_deg}: " + "; ".join(lines))


def test_build_f_structure_and_design_entries() -> None:
    """Spot checks of the exact closed forms in docs/design.md §3 (no radii derivatives)."""
    rng = np.random.default_rng(3)
    true, _, raw_f = random_case(rng, 37.0)
    F = navd_f(true, raw_f)
    lat, h = true["p"][0], true["p"][2]
    vn, ve, vd = true["v"]
    rm, rn = ref_radii(lat)
    rmh, rnh = rm + h, rn + h
    tl = math.tan(lat)
    w_in = np.array([W_IE * math.cos(lat) + ve / rnh, -vn / rmh, -W_IE * math.sin(lat)
                     - ve * tl / rnh])
    f_n = true["C"] @ (raw_f - true["ba"])
    np.testing.assert_allclose(F[0:3, 0:3], -sk(w_in), rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(F[0:3, 3:6], [[0, 1 / rnh, 0], [-1 / rmh, 0, 0],
                                             [0, -tl / rnh, 0]], rtol=1e-12)
    np.testing.assert_allclose(F[0:3, 9:12], -true["C"], rtol=1e-12)
    np.testing.assert_allclose(F[3:6, 12:15], true["C"], rtol=1e-12)
    np.testing.assert_allclose(F[3:6, 0:3], sk(f_n), rtol=1e-12)
    np.testing.assert_allclose(F[6:9, 3:6], np.diag([1 / rmh, 1 / (rnh * math.cos(lat)), -1]),
                               rtol=1e-12)
    np.testing.assert_allclose(F[0:3, 8], [-ve / rnh**2, vn / rmh**2, ve * tl / rnh**2],
                               rtol=1e-12)
    # vertical gravity gradient dominates F[5, 8]: about +2 g / R (g down positive, h up)
    assert abs(F[5, 8] + 3.086e-6) < 2e-8
    assert np.all(F[9:15, :] == 0.0)
    assert vd != 0.0


def test_propagate_cov_matches_second_order_phi() -> None:
    """GIVEN build_f's F at five latitudes, random covariances P and noise q, and steps
    T from 1 ms to 0.1 s,
    WHEN propagate_cov propagates P over T,
    THEN the result is exactly symmetric and equals Phi P Phi^T + diag(q) T with
    Phi = I + F T + (F T)^2 / 2, to 1e-12 after scaling by the expected standard deviations."""
    rng = np.random.default_rng(11)
    A = np.zeros((15, 15))
    B = np.zeros((15, 15))
    for k, T in enumerate([1e-3, 5e-3, 1e-2, 2e-2, 0.1]):
        true, _, raw_f = random_case(rng, LATS[k])
        F = navd_f(true, raw_f)
        s = np.array([1e-2] * 3 + [0.5] * 3 + [1e-6, 1e-6, 5.0] + [1e-3] * 3 + [0.05] * 3)
        G = rng.normal(size=(15, 15))
        P = (G @ G.T / 15.0 + 0.1 * np.eye(15)) * np.outer(s, s)
        q = rng.uniform(0.1, 1.0, size=15) * s**2 * 1e-2
        ft = F * T
        phi = np.eye(15) + ft + 0.5 * ft @ ft
        want = phi @ P @ phi.T + np.diag(q) * T
        got = P.copy()
        propagate_cov(got, F, q, T, A, B)
        np.testing.assert_array_equal(got, got.T)
        d = 1.0 / np.sqrt(np.diag(want))
        np.testing.assert_allclose(got * np.outer(d, d), want * np.outer(d, d), rtol=0,
                                   atol=1e-12)
