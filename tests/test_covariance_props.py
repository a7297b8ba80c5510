"""Property test: propagation and gated updates keep P symmetric positive definite.

Random sequences of covariance propagations (random valid states and specific force,
T up to 0.02 s) and gated updates (GNSS position, velocity with lever arm, joint
velocity + course, and random correlated blocks) are applied to a realistic P0.  After
every step P must be finite, exactly symmetric, and positive definite *relative to its
scale*: position states in radians have variances ~1e-12 rad^2, so the check is done on the
correlation matrix D^-1 P D^-1 (D = sqrt(diag P)).
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from navd.core.aiding import gnss_heading, gnss_position, gnss_velocity
from navd.core.errors import build_f
from navd.core.kalman import gated_update, propagate_cov

R_EARTH = 6.371e6
DEG = math.pi / 180.0
MIN_EIG = 1e-10
SIG0 = np.array([0.05, 0.05, 0.3, 0.5, 0.5, 0.5, 10.0 / R_EARTH, 10.0 / R_EARTH, 10.0,
                 0.2 * DEG, 0.2 * DEG, 0.2 * DEG, 0.01, 0.01, 0.01])
# continuous white-noise densities: ARW, VRW, bias random walks (positions: none)
Q = np.array([(0.24 * DEG / 60.0) ** 2] * 3 + [0.01**2] * 3 + [0.0] * 3
             + [1e-10] * 3 + [1e-8] * 3)


def rot(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def level_rot(rng: np.random.Generator, max_pitch: float = 0.5) -> np.ndarray:
    r, p, y = rng.uniform(-0.5, 0.5), rng.uniform(-max_pitch, max_pitch), rng.uniform(-3, 3)
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y),
                              math.sin(y))
    return (np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
            @ np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
            @ np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]]))


def check_spd(P: np.ndarray, what: str) -> None:
    assert np.all(np.isfinite(P)), what
    assert np.array_equal(P, P.T), what
    d = np.diag(P)
    assert np.all(d > 0.0), (what, d)
    s = 1.0 / np.sqrt(d)
    lam = np.linalg.eigvalsh(P * np.outer(s, s))
    assert lam[0] > MIN_EIG, (what, lam[0])


class Filter:
    def __init__(self, rng: np.random.Generator, lat: float) -> None:
        self.rng = rng
        self.P = np.diag(SIG0**2)
        self.x = np.zeros(15)
        self.F = np.zeros((15, 15))
        self.A = np.zeros((15, 15))
        self.B = np.zeros((15, 15))
        self.H = np.zeros((4, 15))
        self.z = np.zeros(4)
        self.R = np.zeros((4, 4))
        self.S = np.zeros((4, 4))
        self.L = np.zeros((4, 4))
        self.ph = np.zeros(15)
        self.w = np.zeros(4)
        self.lat = lat
        self.mat = level_rot(rng)
        self.vel = rng.normal(scale=8.0, size=3)
        self.pos = np.array([lat, rng.uniform(-3, 3), rng.uniform(0, 2000)])

    def new_state(self) -> None:
        rng = self.rng
        self.mat = rot(rng) if rng.uniform() < 0.3 else level_rot(rng)
        self.vel = rng.normal(scale=10.0, size=3)
        self.pos[2] = rng.uniform(-100, 4000)

    def propagate(self, T: float) -> None:
        f_n = np.array([self.rng.uniform(-5, 5), self.rng.uniform(-5, 5),
                        -9.8 + self.rng.uniform(-3, 3)])
        build_f(self.F, self.mat, self.vel, self.pos, f_n)
        propagate_cov(self.P, self.F, Q, T, self.A, self.B)

    def _apply(self, m: int, scale: float, gated: bool) -> float:
        """Draw an innovation consistent with S (times ``scale``) and update."""
        H = self.H[:m]
        S = H @ self.P @ H.T + self.R[:m, :m]
        self.z[:m] = scale * (np.linalg.cholesky(S) @ self.rng.normal(size=m))
        gate = {1: 15.1, 2: 18.4, 3: 21.1, 4: 23.5}[m] if gated else 0.0
        nis = gated_update(self.x, self.P, self.H, self.z, self.R, m, gate, self.S, self.L,
                           self.ph, self.w)
        assert not math.isnan(nis)
        assert np.all(np.isfinite(self.x))
        self.x[:] = 0.0  # the estimator injects and zeroes after every accepted block
        return nis

    def position(self, sd: float, scale: float, gated: bool) -> float:
        lever = self.rng.normal(scale=0.5, size=3)
        m = gnss_position.fill(self.H, self.z, self.R, self.mat, self.pos, lever,
                               self.pos[0], self.pos[1], self.pos[2], sd, 2.0 * sd)
        return self._apply(m, scale, gated)

    def velocity(self, sd: float, scale: float, gated: bool, course: bool,
                 sd_beta: float) -> float:
        lever = self.rng.normal(scale=0.5, size=3)
        rate = self.rng.normal(scale=0.3, size=3)
        v = self.vel
        if course and math.hypot(v[0], v[1]) < 3.0:
            v[0] += 5.0
        m = gnss_velocity.fill(self.H, self.z, self.R, self.mat, v, rate, lever,
                               v[0], v[1], v[2], sd, sd)
        if course:
            gnss_heading.course_row(self.H, self.z, self.R, 3, self.mat, rate, lever, v[0],
                                    v[1], sd, sd_beta)
            m = 4
        return self._apply(m, scale, gated)

    def random_block(self, m: int, rel_r: float, scale: float, gated: bool) -> float:
        rng = self.rng
        self.H[:, :] = 0.0
        self.H[:m] = rng.normal(size=(m, 15)) / SIG0 * (rng.uniform(size=(m, 15)) < 0.4)
        self.H[:m, rng.integers(0, 15)] += 1.0 / SIG0[0]
        hph = self.H[:m] @ self.P @ self.H[:m].T
        g = rng.normal(size=(m, m))
        r = g @ g.T + 0.1 * np.eye(m)
        r *= rel_r * np.trace(hph) / np.trace(r)
        self.R[:, :] = 0.0
        self.R[:m, :m] = r
        return self._apply(m, scale, gated)


OPS = st.sampled_from(["prop", "prop", "prop", "pos", "vel", "course", "block", "state"])


@settings(derandomize=True, database=None, max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), lat_deg=st.floats(-80.0, 80.0),
       ops=st.lists(OPS, min_size=1, max_size=80),
       T=st.floats(1e-4, 0.02), sd_pos=st.floats(0.01, 20.0), sd_vel=st.floats(0.005, 2.0),
       sd_beta=st.floats(1e-4, 0.05), rel_r=st.floats(1e-6, 10.0),
       outlier=st.floats(0.5, 20.0))
def test_covariance_stays_spd(seed: int, lat_deg: float, ops: list[str], T: float,
                              sd_pos: float, sd_vel: float, sd_beta: float, rel_r: float,
                              outlier: float) -> None:
    """GIVEN a realistic P0 at a random latitude and random sequences of propagations
    (T up to 0.02 s), state changes and gated or ungated updates (GNSS position, velocity,
    velocity + course, random correlated blocks), every 5th innovation scaled by 0.5-20,
    WHEN each step is applied,
    THEN P stays finite, exactly symmetric and positive definite in correlation form."""
    rng = np.random.default_rng(seed)
    f = Filter(rng, lat_deg * DEG)
    check_spd(f.P, "P0")
    for k, op in enumerate(ops):
        gated = bool(k % 2)
        scale = outlier if k % 5 == 0 else 1.0
        if op == "prop":
            f.propagate(T * rng.uniform(0.5, 1.0))
        elif op == "state":
            f.new_state()
        elif op == "pos":
            f.position(sd_pos, scale, gated)
        elif op == "vel":
            f.velocity(sd_vel, scale, gated, False, sd_beta)
        elif op == "course":
            f.velocity(sd_vel, scale, gated, True, sd_beta)
        else:
            f.random_block(int(rng.integers(1, 5)), rel_r, scale, gated)
        check_spd(f.P, f"step {k} ({op})")


def test_gate_rejections_do_not_touch_p() -> None:
    """GIVEN a P propagated for 0.2 s,
    WHEN a GNSS position innovation 1000 times its sigma goes through a gated update,
    THEN the block is rejected (negative NIS) and P is left bit-identical."""
    rng = np.random.default_rng(1)
    f = Filter(rng, 0.7)
    for _ in range(20):
        f.propagate(0.01)
    before = f.P.copy()
    nis = f.position(1.0, 1e3, True)
    assert nis < 0.0
    np.testing.assert_array_equal(f.P, before)
