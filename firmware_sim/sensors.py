"""Sensor error models: IMU increments and GNSS fixes.

IMU, per axis, over an interval of ``dt`` seconds (increments, body FRD)::

    dtheta = (1 + s_g) dtheta_true + (b_g + o_g + m_g[k] + r_g[k]) dt + arw sqrt(dt) w
    dvel   = (1 + s_a) dvel_true   + (b_a + o_a + m_a[k] + r_a[k]) dt + vrw sqrt(dt) w'

with constant bias ``b ~ N(0, sigma_b^2)`` and scale factor ``s ~ N(0, sigma_s^2)`` drawn once
per seed, ``o`` a fixed offset given by the scenario (an uncalibrated IMU), ``m`` a
first-order Gauss-Markov process (stationary sigma, time constant tau, discretised exactly:
``m[k+1] = e^(-dt/tau) m[k] + sigma sqrt(1 - e^(-2 dt/tau)) w``), ``r`` a bias random walk
starting at 0 (``r[k+1] = r[k] + q sqrt(dt) w``, q in unit/sqrt(s)), and ``w`` unit white
noise.  White noise is given as a density, so its per-increment sigma is
``density * sqrt(dt)`` (ARW in rad/sqrt(s), VRW in m/s/sqrt(s)).  Airframe vibration, when
the scenario has it, is added as the point samples of a low-passed tone (:func:`vibration`).

GNSS: per-axis position noise (horizontal N/E, vertical D; white or Gauss-Markov), per-axis
velocity noise (optionally larger than the reported accuracy), dropout windows, bursts of
velocity jumps, position steps held over a window, and ECEF position/velocity
consistent with the reported geodetic position and NED velocity.

Every random component draws from its own stream ``default_rng([seed, stream])`` so that
changing one model (or the duration) leaves the others' draws untouched.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt

from firmware_sim.scenario import GnssSpec, ImuSpec, JumpSpec
from navd.core.earth import geodetic_to_ecef, radii
from navd.core.rotation import euler_to_mat

Arr = npt.NDArray[np.float64]
F = TypeVar("F", bound=Callable[..., Any])

# random streams (never renumber: it would change every recorded data set)
STREAM_IMU_CONST = 1
STREAM_GYRO_WHITE = 2
STREAM_ACCEL_WHITE = 3
STREAM_GYRO_GM = 4
STREAM_ACCEL_GM = 5
STREAM_GNSS_POS = 6
STREAM_GNSS_VEL = 7
STREAM_GNSS_JUMPS = 8
STREAM_GYRO_RW = 9
STREAM_ACCEL_RW = 10
STREAM_RANDOMIZE = 11  # the scenario's [randomize] variant (firmware_sim/randomize.py)
# 12, not 11: the vibration first drew from the randomize stream, so on a randomized scenario
# its phases were the variant's own draws (every stream is listed here, one number each)
STREAM_VIBRATION = 12
STREAM_SLIP = 13  # a ground vehicle's wandering sideslip (firmware_sim/profiles.py)


def _njit(fn: F) -> F:
    return cast(F, numba.njit(cache=True, nogil=True)(fn))


def rng(seed: int, stream: int) -> np.random.Generator:
    """The generator of one random component for a given seed."""
    return np.random.default_rng([seed, stream])


@_njit
def _ar1_into(x0: Arr, phi: float, q: float, w: Arr, out: Arr) -> None:
    # recursive, so not expressible as a numpy vector operation without losing precision
    for j in range(w.shape[1]):
        x = x0[j]
        for k in range(w.shape[0]):
            out[k, j] = x
            x = phi * x + q * w[k, j]


def gauss_markov(gen: np.random.Generator, n: int, dim: int, sigma: float, tau_s: float,
                 dt_s: float) -> Arr:
    """Stationary first-order Gauss-Markov samples (n, dim), unit of ``sigma``."""
    if sigma == 0.0 or n == 0:
        return np.zeros((n, dim))
    phi = math.exp(-dt_s / tau_s)
    q = sigma * math.sqrt(-math.expm1(-2.0 * dt_s / tau_s))
    x0 = sigma * gen.standard_normal(dim)
    w = gen.standard_normal((n, dim))
    out = np.empty((n, dim))
    _ar1_into(x0, phi, q, w, out)
    return out


def random_walk(gen: np.random.Generator, n: int, dim: int, q: float, dt_s: float) -> Arr:
    """Random walk samples (n, dim) starting at 0; ``q`` in unit/sqrt(s), so the spread after
    t seconds is ``q sqrt(t)``."""
    if q == 0.0 or n == 0:
        return np.zeros((n, dim))
    steps = (q * math.sqrt(dt_s)) * gen.standard_normal((n, dim))
    out = np.empty((n, dim))
    out[0] = 0.0
    np.cumsum(steps[:-1], axis=0, out=out[1:])
    return out


@dataclass(frozen=True)
class ImuErrors:
    """What was drawn for one run.

    Attributes:
        gyro_bias_rps: (3,) constant gyro bias (drawn + offset), body FRD, rad/s.
        accel_bias_mps2: (3,) constant accelerometer bias (drawn + offset), body FRD, m/s^2.
        gyro_scale: (3,) gyro scale-factor error, dimensionless (ppm * 1e-6).
        accel_scale: (3,) accelerometer scale-factor error, dimensionless.
        gyro_gm_rps: (N, 3) Gauss-Markov gyro bias over each interval, rad/s.
        accel_gm_mps2: (N, 3) Gauss-Markov accelerometer bias, m/s^2.
        gyro_rw_rps: (N, 3) gyro bias random walk over each interval, rad/s.
        accel_rw_mps2: (N, 3) accelerometer bias random walk, m/s^2.
    """

    gyro_bias_rps: Arr
    accel_bias_mps2: Arr
    gyro_scale: Arr
    accel_scale: Arr
    gyro_gm_rps: Arr
    accel_gm_mps2: Arr
    gyro_rw_rps: Arr
    accel_rw_mps2: Arr


def vibration(n: int, dt_s: float, spec: ImuSpec, seed: int) -> Arr:
    """The vibration in each of ``n`` samples (``ImuSpec.vib_*``).

    Returns:
        (n, 6) angular rate (rad/s) then acceleration (m/s^2), IMU axes: the tone after the
        sensor's second-order low-pass, |H| = 1 / sqrt(1 + (f / f_c)^4), sampled at the end of
        each interval.  One phase for all axes (one rotor), each axis at its own drawn offset.
    """
    amp = np.concatenate((np.asarray(spec.vib_gyro_rps, dtype=np.float64),
                          np.asarray(spec.vib_accel_mps2, dtype=np.float64)))
    if spec.vib_freq_hz == 0.0 or n == 0 or not np.any(amp):
        return np.zeros((n, 6))
    gen = rng(seed, STREAM_VIBRATION)
    offset = gen.uniform(0.0, 2.0 * math.pi, 6)
    freq = np.maximum(spec.vib_freq_hz + gauss_markov(gen, n, 1, spec.vib_freq_sd_hz,
                                                      spec.vib_freq_tau_s, dt_s)[:, 0], 0.0)
    # whole cycles dropped before the sine: the phase grows to ~1e6 cycles in an hour
    cycles = np.cumsum(freq * dt_s)
    theta = 2.0 * math.pi * (cycles - np.floor(cycles))
    gain = (1.0 / np.sqrt(1.0 + (freq / spec.vib_lpf_hz) ** 4) if spec.vib_lpf_hz > 0.0
            else np.ones(n))
    out: Arr = gain[:, None] * np.sin(theta[:, None] + offset) * amp
    return out


def corrupt_imu(inc_true: Arr, dt_s: float, spec: ImuSpec, seed: int) -> tuple[Arr, ImuErrors]:
    """Apply the IMU error model to error-free increments.

    Args:
        inc_true: (N, 6) dtheta xyz (rad), dvel xyz (m/s), body FRD.
        dt_s: interval, s.
        spec: IMU error model.
        seed: run seed.

    Returns:
        (N, 6) measured increments, in the IMU's axes (``spec.mount_*_deg``; body FRD
        when zero), and the drawn errors (IMU axes).
    """
    n = inc_true.shape[0]
    mount = (spec.mount_roll_deg, spec.mount_pitch_deg, spec.mount_yaw_deg)
    if any(mount):
        # row vectors: v_s^T = v_b^T C_s^b, with C_s^b the mount as an attitude
        mat_bs = euler_to_mat(*(math.radians(a) for a in mount))
        inc_true = np.hstack((inc_true[:, 0:3] @ mat_bs, inc_true[:, 3:6] @ mat_bs))
    g = rng(seed, STREAM_IMU_CONST)
    # offsets are added after the draws so that they leave every drawn value unchanged
    bg = spec.gyro_bias_sigma_rps * g.standard_normal(3)
    ba = spec.accel_bias_sigma_mps2 * g.standard_normal(3)
    sg = 1e-6 * spec.gyro_scale_factor_sigma_ppm * g.standard_normal(3)
    sa = 1e-6 * spec.accel_scale_factor_sigma_ppm * g.standard_normal(3)
    mg = gauss_markov(rng(seed, STREAM_GYRO_GM), n, 3, spec.gyro_gm_sigma_rps,
                      spec.gyro_gm_tau_s, dt_s)
    ma = gauss_markov(rng(seed, STREAM_ACCEL_GM), n, 3, spec.accel_gm_sigma_mps2,
                      spec.accel_gm_tau_s, dt_s)
    bg = bg + np.asarray(spec.gyro_offset_rps, dtype=np.float64)
    ba = ba + np.asarray(spec.accel_offset_mps2, dtype=np.float64)
    rg = random_walk(rng(seed, STREAM_GYRO_RW), n, 3, spec.gyro_bias_rw_rps_per_sqrt_s, dt_s)
    ra = random_walk(rng(seed, STREAM_ACCEL_RW), n, 3, spec.accel_bias_rw_mps2_per_sqrt_s,
                     dt_s)
    sq = math.sqrt(dt_s)
    wg = rng(seed, STREAM_GYRO_WHITE).standard_normal((n, 3))
    wa = rng(seed, STREAM_ACCEL_WHITE).standard_normal((n, 3))
    out = np.empty_like(inc_true)
    out[:, 0:3] = ((1.0 + sg) * inc_true[:, 0:3] + (bg + mg + rg) * dt_s
                   + (spec.arw_rad_per_sqrt_s * sq) * wg)
    out[:, 3:6] = ((1.0 + sa) * inc_true[:, 3:6] + (ba + ma + ra) * dt_s
                   + (spec.vrw_mps_per_sqrt_s * sq) * wa)
    out += vibration(n, dt_s, spec, seed) * dt_s
    return out, ImuErrors(bg, ba, sg, sa, mg, ma, rg, ra)


# ---------------------------------------------------------------------------------------------
# GNSS
# ---------------------------------------------------------------------------------------------

def mats_ne(lat: Arr, lon: Arr) -> Arr:
    """C_e^n for (N,) latitudes/longitudes (rad) -> (N, 3, 3); rotates ECEF into NED."""
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    m = np.empty((lat.shape[0], 3, 3))
    m[:, 0, 0] = -sl * co
    m[:, 0, 1] = -sl * so
    m[:, 0, 2] = cl
    m[:, 1, 0] = -so
    m[:, 1, 1] = co
    m[:, 1, 2] = 0.0
    m[:, 2, 0] = -cl * co
    m[:, 2, 1] = -cl * so
    m[:, 2, 2] = -sl
    return m


def _random_dirs(gen: np.random.Generator, n: int) -> Arr:
    """(n, 3) unit vectors uniform on the sphere."""
    v = gen.standard_normal((n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v


def place_jumps(t_s: Arr, spec: JumpSpec, seed: int) -> tuple[Arr, npt.NDArray[np.bool_]]:
    """Velocity jumps for the GNSS epochs at times ``t_s`` (M,), s.

    The window ``[start_s, end_s]`` (clipped to the epochs present) is cut into ``bursts``
    equal slots; each burst of ``min_epochs..max_epochs`` consecutive epochs starts at a
    random epoch of its slot, so bursts never overlap and spread over the run.

    Returns:
        (M, 3) NED velocity jump, m/s, and the (M,) outlier flags.
    """
    m = t_s.shape[0]
    jump = np.zeros((m, 3))
    flag = np.zeros(m, dtype=bool)
    if not spec.enabled or spec.bursts == 0 or m == 0:
        return jump, flag
    gen = rng(seed, STREAM_GNSS_JUMPS)
    cand = np.flatnonzero((t_s >= spec.start_s) & (t_s <= spec.end_s))
    if cand.size == 0:
        return jump, flag
    slots = np.array_split(cand, spec.bursts)
    for slot in slots:
        length = int(gen.integers(spec.min_epochs, spec.max_epochs + 1))
        if slot.size == 0:
            continue
        room = max(1, slot.size - length + 1)
        first = int(slot[int(gen.integers(0, room))])
        idx = np.arange(first, min(first + length, int(slot[-1]) + 1))
        mag = gen.uniform(spec.min_mps, spec.max_mps, idx.size)
        dirs = _random_dirs(gen, 1 if spec.shared_direction else idx.size)
        jump[idx] = mag[:, None] * dirs
        flag[idx] = True
    return jump, flag


GNSS_COLUMNS = ("t_us", "lat_deg", "lon_deg", "alt_m", "vel_n", "vel_e", "vel_d",
                "h_acc_m", "v_acc_m", "vel_acc_mps", "vel_x_ecef", "vel_y_ecef", "vel_z_ecef",
                "x_ecef", "y_ecef", "z_ecef", "outlier", "t_arrival_us")


def simulate_gnss(t_us: npt.NDArray[np.int64], pos: Arr, vel_n: Arr, t0_us: int,
                  spec: GnssSpec, seed: int, mat_nb: Arr | None = None,
                  inc: Arr | None = None) -> tuple[dict[str, npt.NDArray[Any]],
                                                   npt.NDArray[np.int64]]:
    """GNSS epochs sampled from the truth, at the antenna (``spec.lever_arm_m``).

    Args:
        t_us: (N+1,) truth sample times, us; the GNSS epochs are a subset of them.
        pos: (N+1, 3) truth lat_rad, lon_rad, alt_m (of the IMU).
        vel_n: (N+1, 3) truth NED velocity, m/s (of the IMU).
        t0_us: time of the first truth sample, us.
        spec: receiver model.
        seed: run seed.
        mat_nb: (N+1, 3, 3) truth C_b^n; inc: (N, 6) truth increments (dtheta first, rad;
            interval k runs k -> k+1): needed for a non-zero lever arm, whose antenna
            velocity uses the body rate of the interval ending at the epoch.

    Returns:
        The gnss.csv columns (see :data:`GNSS_COLUMNS`) and the (M,) truth index of each epoch.
    """
    dt_us = int(t_us[1] - t_us[0])
    period_us = round(1e6 / spec.rate_hz)
    step = period_us // dt_us
    idx_all = np.arange(step, t_us.shape[0], step, dtype=np.int64)
    n_all = idx_all.shape[0]
    ts_all = (t_us[idx_all] - t0_us).astype(np.float64) * 1e-6
    # noise drawn for every nominal epoch before dropouts, so dropouts do not reshuffle it
    gp = rng(seed, STREAM_GNSS_POS)
    period_s = period_us * 1e-6
    if spec.pos_tau_s > 0.0:
        npos = gauss_markov(gp, n_all, 3, 1.0, spec.pos_tau_s, period_s)
    else:
        npos = gp.standard_normal((n_all, 3))
    npos *= np.array([spec.pos_sigma_h_m, spec.pos_sigma_h_m, spec.pos_sigma_v_m])
    nvel = rng(seed, STREAM_GNSS_VEL).standard_normal((n_all, 3))
    # the receiver reports vel_sigma_* whatever noise it really has (vel_noise_scale)
    nvel *= spec.vel_noise_scale * np.array([spec.vel_sigma_h_mps, spec.vel_sigma_h_mps,
                                             spec.vel_sigma_v_mps])
    stepped = np.zeros(n_all, dtype=bool)
    for st in spec.pos_steps:
        inside = (ts_all >= st.start_s) & (ts_all < st.end_s)
        npos[inside] += np.array([st.north_m, st.east_m, st.down_m])
        stepped |= inside
    keep = np.ones(n_all, dtype=bool)
    for d in spec.dropouts:
        keep &= ~((ts_all >= d.start_s) & (ts_all < d.end_s))
    idx = idx_all[keep]
    npos = npos[keep]
    nvel = nvel[keep]
    jump, flag = place_jumps(ts_all[keep], spec.jumps, seed)
    flag = flag | stepped[keep]  # a stepped fix is an outlier too

    p = pos[idx]
    lat_t, alt_t = p[:, 0], p[:, 2]
    r_m = np.empty_like(lat_t)
    r_n = np.empty_like(lat_t)
    for i, la in enumerate(lat_t):
        r_m[i], r_n[i] = radii(float(la))
    vel = vel_n[idx] + nvel + jump
    lever = np.asarray(spec.lever_arm_m, dtype=np.float64)
    if np.any(lever != 0.0):
        if mat_nb is None or inc is None:
            raise ValueError("a GNSS lever arm needs the truth attitude and increments")
        c = mat_nb[idx]
        rate = inc[idx - 1, :3] / ((t_us[1] - t_us[0]) * 1e-6)
        npos = npos + c @ lever  # the antenna's NED offset from the IMU
        vel = vel + np.einsum("kij,kj->ki", c, np.cross(rate, lever))
    lat = lat_t + npos[:, 0] / (r_m + alt_t)
    lon = p[:, 1] + npos[:, 1] / ((r_n + alt_t) * np.cos(lat_t))
    alt = alt_t - npos[:, 2]
    # ECEF velocity rotated at the reported position, as the receiver's own NED <-> ECEF is
    vel_e = np.einsum("kji,kj->ki", mats_ne(lat, lon), vel)
    ecef = np.array([geodetic_to_ecef(float(a), float(b), float(c))
                     for a, b, c in zip(lat, lon, alt, strict=True)]).reshape(-1, 3)
    m = idx.shape[0]
    t_valid = t_us[idx].astype(np.int64)
    t_arrival = t_valid + round(spec.latency_s * 1e6)
    cols: dict[str, npt.NDArray[Any]] = {
        "t_us": t_arrival if spec.stamped_on_arrival else t_valid,
        "lat_deg": np.degrees(lat),
        "lon_deg": np.degrees(lon),
        "alt_m": alt,
        "vel_n": vel[:, 0].copy(),
        "vel_e": vel[:, 1].copy(),
        "vel_d": vel[:, 2].copy(),
        "h_acc_m": np.full(m, spec.pos_sigma_h_m),
        "v_acc_m": np.full(m, spec.pos_sigma_v_m),
        "vel_acc_mps": np.full(m, spec.vel_sigma_h_mps),
        "vel_x_ecef": vel_e[:, 0].copy(),
        "vel_y_ecef": vel_e[:, 1].copy(),
        "vel_z_ecef": vel_e[:, 2].copy(),
        "x_ecef": ecef[:, 0].copy(),
        "y_ecef": ecef[:, 1].copy(),
        "z_ecef": ecef[:, 2].copy(),
        "outlier": flag,
        "t_arrival_us": t_arrival,
    }
    return cols, idx
