"""Evaluation against a reference attitude: alignment, errors, statistics, consistency checks.

Error conventions are stated in :mod:`navd.eval.report`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from navd.core.quat_series import euler_to_quat, quat_conj, quat_mul, quat_to_euler, rotation_angle
from navd.eval.tables import RefSeries
from navd.units import DEG as D2R
from navd.units import RAD2DEG as R2D

F64 = npt.NDArray[np.float64]
AXES = ("roll", "pitch", "yaw")


# ---------------------------------------------------------------------------------------------
# attitude maths (vectorised)


def wrap_deg(a: F64) -> F64:
    return np.asarray(180.0 - np.mod(180.0 - a, 360.0), dtype=np.float64)


def interpolate_reference(ref: RefSeries, t_us: F64, max_gap_s: float) -> tuple[F64, F64]:
    """Reference Euler (deg) and quaternion at ``t_us``; NaN outside span or across gaps."""
    n = len(t_us)
    e_out = np.full((n, 3), np.nan)
    q_out = np.full((n, 4), np.nan)
    if len(ref.t_us) < 2:
        return e_out, q_out
    q = euler_to_quat(ref.euler_deg * D2R)
    # make consecutive quaternions the same hemisphere so interpolation takes the short way
    dots = np.sum(q[1:] * q[:-1], axis=1)
    sign = np.concatenate([[1.0], np.cumprod(np.where(dots < 0.0, -1.0, 1.0))])
    q = q * sign[:, None]
    tr = ref.t_us
    k = np.searchsorted(tr, t_us, side="left")
    kc = np.clip(k, 0, len(tr) - 1)
    exact = tr[kc] == t_us
    kk = np.clip(k, 1, len(tr) - 1)
    inside = (k > 0) & (k < len(tr))
    ok = exact | (inside & (tr[kk] - tr[kk - 1] <= max_gap_s * 1e6))
    qi = np.stack([np.interp(t_us, tr, q[:, c]) for c in range(4)], 1)
    norm = np.linalg.norm(qi, axis=1)
    qi = qi / np.where(norm > 0.0, norm, 1.0)[:, None]
    q_out[ok] = qi[ok]
    e_out[ok] = quat_to_euler(qi[ok]) * R2D
    return e_out, q_out


# ---------------------------------------------------------------------------------------------
# statistics


def error_stats(err: F64) -> dict[str, float]:
    """RMS, max and 50/90/99th percentiles of |err| over the finite values (deg)."""
    e = np.abs(err[np.isfinite(err)])
    if len(e) == 0:
        return {"n": 0, "rms": math.nan, "p50": math.nan, "p90": math.nan, "p99": math.nan,
                "max": math.nan}
    p50, p90, p99 = np.percentile(e, [50, 90, 99])
    return {"n": len(e), "rms": float(np.sqrt(np.mean(e * e))), "p50": float(p50),
            "p90": float(p90), "p99": float(p99), "max": float(e.max())}


def gyro_consistency(imu_t_us: npt.NDArray[np.int64], imu_inc: F64, series: RefSeries,
                     t_from_s: float, window_s: float = 1.0) -> dict[str, Any]:
    """How far an attitude series turns away from the integrated gyros, per window.

    Over consecutive windows of ``window_s`` the body-frame rotation of the series,
    ``C(t0)^T C(t1)``, is compared with the product of the gyro increments over the same
    IMU samples; the residual rotation vector (deg per window) is summarised by its RMS per
    body axis.  A strapdown solution stays close to zero by construction (only its updates
    show); an estimate that leans on other sensors (magnetometer, accelerometer-as-gravity)
    shows how hard it pulls away from the gyros.
    """
    t = imu_t_us
    if len(t) < 3:
        return {"windows": 0}
    bounds = np.arange(max(t_from_s * 1e6, float(t[0])), float(t[-1]), window_s * 1e6)
    idx = np.unique(np.searchsorted(t, bounds))
    idx = idx[idx < len(t)]
    if len(idx) < 2:
        return {"windows": 0}
    _, q_s = interpolate_reference(series, t[idx].astype(np.float64), max(window_s, 1.0))
    # gyro rotation over each window: product of Exp(dtheta_k), k in (i0, i1]
    th = imu_inc[:, :3]
    ang = np.linalg.norm(th, axis=1)
    half = 0.5 * ang
    scale = np.where(ang > 1e-12, np.sin(half) / np.where(ang > 1e-12, ang, 1.0), 0.5)
    dq = np.column_stack([np.cos(half), th * scale[:, None]])
    res: list[F64] = []
    for j in range(len(idx) - 1):
        i0, i1 = int(idx[j]), int(idx[j + 1])
        span = (t[i1] - t[i0]) * 1e-6
        if not np.all(np.isfinite(q_s[[j, j + 1]])) or span > 1.5 * window_s:
            continue
        q = np.array([[1.0, 0.0, 0.0, 0.0]])
        for k in range(i0 + 1, i1 + 1):
            q = quat_mul(q, dq[k:k + 1])
        r = quat_mul(quat_conj(q), quat_mul(quat_conj(q_s[j:j + 1]), q_s[j + 1:j + 2]))[0]
        if r[0] < 0.0:
            r = -r
        v = r[1:]
        n = float(np.linalg.norm(v))
        res.append(v * (2.0 * math.atan2(n, r[0]) / n if n > 0.0 else 0.0) * R2D)
    if not res:
        return {"windows": 0}
    a = np.array(res)
    return {"windows": len(a), "window_s": window_s,
            "rms_deg": [float(x) for x in np.sqrt(np.mean(a * a, axis=0))]}


def course_check(aid: dict[str, Any], series: RefSeries, t_from_s: float,
                 min_speed: float = 8.0) -> dict[str, Any]:
    """yaw - GNSS course at the GNSS epochs faster than ``min_speed`` (deg).

    For a fixed-wing aircraft this is the crab angle (plus sideslip): in a steady wind it is
    a once-per-revolution sinusoid of the course with amplitude asin(wind / airspeed), so
    ``amp_deg`` of the fit ``a sin(course) + b cos(course) + c`` is reported with the
    residual RMS; a heading sensor error that also goes once per revolution (an
    uncompensated magnetometer) adds to the same term.
    """
    t_s = aid["t_us"] * 1e-6
    m = (aid["speed_mps"] >= min_speed) & (t_s >= t_from_s) & np.isfinite(aid["course_deg"])
    if np.count_nonzero(m) < 5:
        return {"n": 0}
    e, _ = interpolate_reference(series, aid["t_us"][m], 1.0)
    chi = aid["course_deg"][m]
    d = wrap_deg(e[:, 2] - chi)
    ok = np.isfinite(d)
    d, c = d[ok], chi[ok] * D2R
    if len(d) < 5:
        return {"n": 0}
    A = np.column_stack([np.sin(c), np.cos(c), np.ones(len(c))])
    coef = np.linalg.lstsq(A, d, rcond=None)[0]
    p25, p50, p75 = np.percentile(d, [25, 50, 75])
    return {"n": len(d), "median_deg": float(p50), "p25_deg": float(p25),
            "p75_deg": float(p75), "amp_deg": float(math.hypot(coef[0], coef[1])),
            "fit_resid_rms_deg": float(np.sqrt(np.mean((d - A @ coef) ** 2)))}


@dataclass
class Segment:
    t0_s: float
    t1_s: float
    n: int
    rms: dict[str, float]
    max: dict[str, float]
    course_used: int = 0
    course_rejected: int = 0


# Time stamps at or past this (~11.6 days) cannot be time since an autopilot's boot: they are
# wall-clock stamps (PX4 SITL logs Unix time), shown from the log's start instead.
WALL_CLOCK_US = 1e12


def time_origin_us(*t_us: F64) -> float:
    """The time the report's axes count from: 0 for a boot clock (already time from the
    log's start), else the earliest stamp of the inputs, floored to a whole second."""
    firsts = [float(np.min(t)) for t in t_us if len(t)]
    first = min(firsts) if firsts else 0.0
    return 0.0 if first < WALL_CLOCK_US else math.floor(first * 1e-6) * 1e6


@dataclass
class Evaluation:
    t_s: F64
    sol_deg: F64
    sd_deg: F64
    ref_deg: F64 | None
    err_deg: F64 | None
    angle_deg: F64 | None
    stats: dict[str, dict[str, float]] = field(default_factory=dict)
    segments: list[Segment] = field(default_factory=list)
    t0_us: float = 0.0  # t_s = (t_us - t0_us) * 1e-6 (time_origin_us)
    # rows whose heading is scored (navd's heading_aligned); None: the column is absent
    heading_scored: npt.NDArray[np.bool_] | None = None


def evaluate(sol: dict[str, Any], ref: RefSeries | None, aid: dict[str, Any] | None,
             segment_s: float, stats_from_s: float | None, max_gap_s: float,
             t0_us: float = 0.0) -> Evaluation:
    """Errors and statistics.  Times (``t_s``, ``stats_from_s``, segments) count from
    ``t0_us``.  Heading (yaw and the total angle) is scored only on rows where navd says its
    heading is aligned (``heading_aligned`` = 1): before that the yaw is a placeholder with a
    wide sigma, and scoring it would report an accuracy navd never claimed."""
    t_us = sol["t_us"]
    t_s = (t_us - t0_us) * 1e-6
    e_sol = np.stack([sol["roll_deg"], sol["pitch_deg"], sol["yaw_deg"]], 1)
    sd = np.stack([sol["roll_sd_deg"], sol["pitch_sd_deg"], sol["yaw_sd_deg"]], 1)
    ev = Evaluation(t_s, e_sol, sd, None, None, None, t0_us=t0_us)
    if "heading_aligned" in sol:
        ev.heading_scored = np.asarray(sol["heading_aligned"] > 0.5)
    if ref is None or len(t_s) == 0:
        return ev
    e_ref, q_ref = interpolate_reference(ref, t_us, max_gap_s)
    err = wrap_deg(e_sol - e_ref)
    ang = rotation_angle(euler_to_quat(e_sol * D2R), q_ref) * R2D
    ev.ref_deg, ev.err_deg, ev.angle_deg = e_ref, err, ang
    # the scored copies: heading errors only where aligned (the figures show all of it)
    err = err.copy()
    ang = ang.copy()
    if ev.heading_scored is not None:
        err[~ev.heading_scored, 2] = np.nan
        ang[~ev.heading_scored] = np.nan
    start = t_s[0] if stats_from_s is None else max(float(t_s[0]), stats_from_s)
    use = t_s >= start
    for i, a in enumerate(AXES):
        ev.stats[a] = error_stats(err[use, i])
    ev.stats["angle"] = error_stats(ang[use])
    if segment_s > 0 and start <= t_s[-1]:
        n_seg = max(1, math.ceil((t_s[-1] - start) / segment_s))
        a_t = (aid["t_us"] - t0_us) * 1e-6 if aid is not None else np.zeros(0)
        a_c = aid.get("course", []) if aid is not None else []
        for k in range(n_seg):
            t0, t1 = start + k * segment_s, start + (k + 1) * segment_s
            m = (t_s >= t0) & (t_s < t1) if k < n_seg - 1 else (t_s >= t0)
            rms: dict[str, float] = {}
            mx: dict[str, float] = {}
            cols = [*(err[m, i] for i in range(3)), ang[m]]
            nfin = 0
            for name, col in zip((*AXES, "angle"), cols, strict=True):
                s = error_stats(col)
                rms[name], mx[name] = s["rms"], s["max"]
                nfin = max(nfin, int(s["n"]))
            am = (a_t >= t0) & (a_t < t1)
            used = sum(1 for j in np.flatnonzero(am) if a_c[j] == "used")
            rej = sum(1 for j in np.flatnonzero(am) if a_c[j] == "rejected")
            ev.segments.append(Segment(float(t0), float(min(t1, t_s[-1])), nfin, rms, mx,
                                       used, rej))
    return ev


