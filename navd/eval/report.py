"""``navd report``: an HTML evaluation page (PNG figures, statistics) for one replay.

Inputs are the files ``navd replay`` writes: the solution CSV (``SOLUTION_COLS``), optionally
a reference attitude (``--reference-out`` CSV, or any log ``navd.io.logs`` reads: its onboard
estimate is taken) and the per-epoch aiding side file (``--aiding-out``).

Reference alignment: the reference attitude is interpolated to each solution time by
normalised linear quaternion interpolation (no Euler-angle wrap or gimbal trouble); rows
outside the reference's span or inside a reference gap longer than ``--max-ref-gap-s`` get no
error.  Euler errors are solution minus reference, wrapped to (-180, 180] deg; the "angle"
error is the rotation angle of C_sol C_ref^T (all three axes together).

Figures (matplotlib, Agg backend, no display needed): attitude vs reference; attitude error
with the filter's +-3 sigma; heading with the epochs where the course update was used (green)
or rejected (red); GNSS innovations; bias estimates; the track on a local north/east map.
Statistics: RMS, max and the 50/90/99th percentiles of |error| overall, and RMS/max per
segment (``--segment-s``, 30 s by default); they are also written to ``summary.json``.
"""

from __future__ import annotations

import csv
import html
import json
import math
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from navd.units import DEG as D2R
from navd.units import RAD2DEG as R2D

F64 = npt.NDArray[np.float64]
AXES = ("roll", "pitch", "yaw")
_BIG_BYTES = 5_000_000
_MAX_PLOT_POINTS = 20_000


class ReportError(ValueError):
    """An input cannot be used (missing file, missing column)."""


# ---------------------------------------------------------------------------------------------
# reading


def _rows(path: Path, progress: bool) -> Iterator[list[str]]:
    size = path.stat().st_size
    bar = None
    if progress and size > _BIG_BYTES:
        from tqdm import tqdm

        bar = tqdm(total=size, unit="B", unit_scale=True, desc=path.name, file=sys.stderr,
                   mininterval=0.5)
    with open(path, newline="") as fh:
        for line in fh:
            if bar is not None:
                bar.update(len(line))
            yield next(csv.reader([line]))
    if bar is not None:
        bar.close()


def read_table(path: str | Path, needed: tuple[str, ...], text: tuple[str, ...] = (),
               progress: bool = False) -> dict[str, Any]:
    """Read a CSV with a header into column arrays (float64; ``text`` columns as str lists).

    Rows with a wrong field count or a non-number are skipped (counted in ``_skipped``).
    """
    p = Path(path)
    if not p.is_file():
        raise ReportError(f"no such file: {p}")
    it = _rows(p, progress)
    try:
        head = [h.strip() for h in next(it)]
    except StopIteration as exc:
        raise ReportError(f"{p}: empty file") from exc
    idx = {h: i for i, h in enumerate(head)}
    missing = [c for c in needed if c not in idx]
    if missing:
        raise ReportError(f"{p}: missing column(s) {', '.join(missing)}")
    num_cols = [c for c in head if c not in text]
    vals: dict[str, list[float]] = {c: [] for c in num_cols}
    txt: dict[str, list[str]] = {c: [] for c in text if c in idx}
    skipped = 0
    for row in it:
        if len(row) != len(head):
            if row:
                skipped += 1
            continue
        try:
            parsed = [float(row[idx[c]]) for c in num_cols]
        except ValueError:
            skipped += 1
            continue
        for c, v in zip(num_cols, parsed, strict=True):
            vals[c].append(v)
        for c in txt:
            txt[c].append(row[idx[c]])
    out: dict[str, Any] = {c: np.asarray(v, dtype=np.float64) for c, v in vals.items()}
    out.update(txt)
    out["_skipped"] = skipped
    out["_path"] = str(p)
    return out


@dataclass
class RefSeries:
    t_us: F64
    euler_deg: F64  # (K, 3)
    source: str


def load_reference(path: str | Path, progress: bool = False) -> RefSeries:
    """A reference CSV (t_us,roll_deg,pitch_deg,yaw_deg) or any log navd can read."""
    p = Path(path)
    if p.is_file():
        with open(p, "rb") as fh:
            head = fh.read(64)
        if head.startswith(b"t_us,"):
            t = read_table(p, ("t_us", "roll_deg", "pitch_deg", "yaw_deg"), progress=progress)
            e = np.stack([t["roll_deg"], t["pitch_deg"], t["yaw_deg"]], 1)
            return RefSeries(t["t_us"], e, str(p))
    from navd.io.logs import LogFormatError, read_log

    try:
        data = read_log(p)
    except LogFormatError as exc:
        raise ReportError(f"reference {p}: {exc}") from exc
    r = data.reference
    if len(r) == 0:
        raise ReportError(f"reference {p}: the log has no onboard attitude")
    e = np.stack([r.roll_rad, r.pitch_rad, r.yaw_rad], 1) * R2D
    return RefSeries(r.t_us.astype(np.float64), e, f"{p} ({r.source})")


# ---------------------------------------------------------------------------------------------
# attitude maths (vectorised)


def euler_to_quat(e_deg: F64) -> F64:
    """(K, 3) roll, pitch, yaw deg -> (K, 4) w, x, y, z of C = Rz Ry Rx."""
    h = e_deg * (0.5 * D2R)
    cr, sr = np.cos(h[:, 0]), np.sin(h[:, 0])
    cp, sp = np.cos(h[:, 1]), np.sin(h[:, 1])
    cy, sy = np.cos(h[:, 2]), np.sin(h[:, 2])
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], 1)


def quat_to_euler_deg(q: F64) -> F64:
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], 1) * R2D


def wrap_deg(a: F64) -> F64:
    return np.asarray(180.0 - np.mod(180.0 - a, 360.0), dtype=np.float64)


def interpolate_reference(ref: RefSeries, t_us: F64, max_gap_s: float) -> tuple[F64, F64]:
    """Reference Euler (deg) and quaternion at ``t_us``; NaN outside span or across gaps."""
    n = len(t_us)
    e_out = np.full((n, 3), np.nan)
    q_out = np.full((n, 4), np.nan)
    if len(ref.t_us) < 2:
        return e_out, q_out
    q = euler_to_quat(ref.euler_deg)
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
    e_out[ok] = quat_to_euler_deg(qi[ok])
    return e_out, q_out


def rotation_angle_deg(q_a: F64, q_b: F64) -> F64:
    """Angle of the rotation between two attitude series (deg), NaN where either is NaN."""
    dot = np.abs(np.sum(q_a * q_b, axis=1))
    return np.asarray(2.0 * np.arccos(np.clip(dot, 0.0, 1.0)) * R2D, dtype=np.float64)


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


def _qmul(a: F64, b: F64) -> F64:
    """Hamilton product of (K, 4) scalar-first quaternions."""
    w1, x1, y1, z1 = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    w2, x2, y2, z2 = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2],
                    1)


def _conj(q: F64) -> F64:
    return np.asarray(q * np.array([1.0, -1.0, -1.0, -1.0]), dtype=np.float64)


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
            q = _qmul(q, dq[k:k + 1])
        r = _qmul(_conj(q), _qmul(_conj(q_s[j:j + 1]), q_s[j + 1:j + 2]))[0]
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


def evaluate(sol: dict[str, Any], ref: RefSeries | None, aid: dict[str, Any] | None,
             segment_s: float, stats_from_s: float | None, max_gap_s: float) -> Evaluation:
    t_us = sol["t_us"]
    t_s = t_us * 1e-6
    e_sol = np.stack([sol["roll_deg"], sol["pitch_deg"], sol["yaw_deg"]], 1)
    sd = np.stack([sol["roll_sd_deg"], sol["pitch_sd_deg"], sol["yaw_sd_deg"]], 1)
    ev = Evaluation(t_s, e_sol, sd, None, None, None)
    if ref is None or len(t_s) == 0:
        return ev
    e_ref, q_ref = interpolate_reference(ref, t_us, max_gap_s)
    err = wrap_deg(e_sol - e_ref)
    ang = rotation_angle_deg(euler_to_quat(e_sol), q_ref)
    ev.ref_deg, ev.err_deg, ev.angle_deg = e_ref, err, ang
    start = t_s[0] if stats_from_s is None else max(float(t_s[0]), stats_from_s)
    use = t_s >= start
    for i, a in enumerate(AXES):
        ev.stats[a] = error_stats(err[use, i])
    ev.stats["angle"] = error_stats(ang[use])
    if segment_s > 0 and start <= t_s[-1]:
        n_seg = max(1, math.ceil((t_s[-1] - start) / segment_s))
        a_t = aid["t_us"] * 1e-6 if aid is not None else np.zeros(0)
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


# ---------------------------------------------------------------------------------------------
# figures


def _stride(n: int) -> int:
    return max(1, n // _MAX_PLOT_POINTS)


def _break_wraps(y: F64, jump: float = 180.0) -> F64:
    """NaN between samples that jump by more than ``jump`` (yaw wrap) so lines do not cross."""
    out = y.astype(np.float64).copy()
    if len(out) > 1:
        j = np.flatnonzero(np.abs(np.diff(out)) > jump)
        out = np.insert(out, j + 1, np.nan)
    return out


def _break_t(t: F64, y: F64, jump: float = 180.0) -> tuple[F64, F64]:
    if len(y) < 2:
        return t, y
    j = np.flatnonzero(np.abs(np.diff(y)) > jump)
    return np.insert(t.astype(np.float64), j + 1, np.nan), np.insert(y.astype(np.float64),
                                                                     j + 1, np.nan)


def _runs(t: F64, mask: npt.NDArray[np.bool_]) -> list[tuple[float, float]]:
    """Contiguous runs of True as (start, width); each epoch extends to the next epoch."""
    if len(t) == 0:
        return []
    ends = np.append(t[1:], t[-1] + (t[-1] - t[-2] if len(t) > 1 else 0.2))
    out: list[tuple[float, float]] = []
    k = 0
    n = len(t)
    while k < n:
        if not mask[k]:
            k += 1
            continue
        j = k
        while j + 1 < n and mask[j + 1]:
            j += 1
        out.append((float(t[k]), float(ends[j] - t[k])))
        k = j + 1
    return out


def make_figures(ev: Evaluation, sol: dict[str, Any], aid: dict[str, Any] | None,
                 out: Path, progress: bool = False) -> list[tuple[str, str]]:
    """Render the PNGs into ``out``; return (file name, caption) pairs in page order."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs: list[tuple[str, str]] = []
    s = _stride(len(ev.t_s))
    t = ev.t_s[::s]
    steps: list[Callable[[], tuple[str, str] | None]] = []

    def save(fig: Any, name: str, caption: str, left: float = 0.08) -> tuple[str, str]:
        # fixed margins (in inches for the bottom and top): tight_layout costs more than
        # drawing the figure
        h = float(fig.get_figheight())
        fig.subplots_adjust(left=left, right=0.97, top=1.0 - 0.2 / h, bottom=0.55 / h,
                            hspace=0.12)
        fig.savefig(out / name, dpi=90)
        plt.close(fig)
        return name, caption

    def attitude() -> tuple[str, str] | None:
        fig, axs = plt.subplots(3, 1, figsize=(11, 7.5), sharex=True)
        for i, a in enumerate(AXES):
            ax = axs[i]
            ax.plot(*_break_t(t, ev.sol_deg[::s, i]), lw=0.9, label="navd")
            if ev.ref_deg is not None:
                ax.plot(*_break_t(t, ev.ref_deg[::s, i]), lw=0.9, label="reference", alpha=0.8)
            ax.set_ylabel(f"{a} [deg]")
            ax.grid(alpha=0.3)
        axs[0].legend(loc="upper right")
        axs[-1].set_xlabel("time [s]")
        return save(fig, "attitude.png", "Attitude: navd and the reference")

    def error() -> tuple[str, str] | None:
        if ev.err_deg is None:
            return None
        fig, axs = plt.subplots(4, 1, figsize=(11, 9), sharex=True)
        for i, a in enumerate(AXES):
            ax = axs[i]
            band = 3.0 * ev.sd_deg[::s, i]
            ax.fill_between(t, -band, band, color="0.85", label="±3σ (filter)")
            ax.plot(t, ev.err_deg[::s, i], lw=0.8, color="C3", label="navd − reference")
            lim = np.nanpercentile(np.abs(ev.err_deg[:, i]), 99.5) if np.any(
                np.isfinite(ev.err_deg[:, i])) else 1.0
            ax.set_ylim(-1.5 * max(lim, 0.1), 1.5 * max(lim, 0.1))
            ax.set_ylabel(f"{a} error [deg]")
            ax.grid(alpha=0.3)
        axs[0].legend(loc="upper right")
        assert ev.angle_deg is not None
        axs[3].plot(t, ev.angle_deg[::s], lw=0.8, color="C4")
        axs[3].set_ylabel("angle error [deg]")
        axs[3].grid(alpha=0.3)
        axs[-1].set_xlabel("time [s]")
        return save(fig, "error.png", "Attitude error (navd − reference) with the filter's ±3σ; "
                                      "bottom: total rotation angle between the two")

    def heading() -> tuple[str, str] | None:
        fig, ax = plt.subplots(1, 1, figsize=(11, 4.5))
        ax.plot(*_break_t(t, ev.sol_deg[::s, 2]), lw=0.9, label="navd yaw")
        if ev.ref_deg is not None:
            ax.plot(*_break_t(t, ev.ref_deg[::s, 2]), lw=0.9, alpha=0.8, label="reference yaw")
        if aid is not None and len(aid["t_us"]):
            at = aid["t_us"] * 1e-6
            fast = aid["speed_mps"] >= 3.0
            ax.plot(at[fast], aid["course_deg"][fast], ".", ms=2.5, color="k",
                    label="GNSS course (speed ≥ 3 m/s)")
            course = np.asarray(aid["course"])
            for what, color in (("used", "tab:green"), ("rejected", "tab:red")):
                runs = _runs(at, course == what)
                if runs:
                    ax.broken_barh(runs, (-180, 360), color=color, alpha=0.18, lw=0,
                                   label=f"course update {what}")
        ax.set_ylim(-180, 180)
        ax.set_yticks(range(-180, 181, 60))
        ax.set_ylabel("yaw / course [deg]")
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
        return save(fig, "heading.png", "Heading, GNSS course, and the epochs where the course "
                                        "update was used (green) or rejected (red)")

    def innovations() -> tuple[str, str] | None:
        if aid is None or not len(aid["t_us"]):
            return None
        at = aid["t_us"] * 1e-6
        fig, axs = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
        for c, lab in zip("ned", ("N", "E", "D"), strict=True):
            axs[0].plot(at, aid[f"innov_pos_{c}_m"], lw=0.8, label=lab)
            axs[1].plot(at, aid[f"innov_vel_{c}_mps"], lw=0.8, label=lab)
        axs[0].set_ylabel("position innov. [m]")
        axs[1].set_ylabel("velocity innov. [m/s]")
        axs[2].plot(at, aid["innov_course_deg"], ".", ms=2.5, color="C2")
        axs[2].set_ylabel("yaw − course [deg]")
        axs[2].set_ylim(-180, 180)
        for ax in axs:
            ax.grid(alpha=0.3)
        axs[0].legend(loc="upper right")
        axs[-1].set_xlabel("time [s]")
        return save(fig, "innovations.png", "GNSS innovations (measurement − prediction before "
                                            "the update) and yaw − course")

    def biases() -> tuple[str, str] | None:
        if aid is None or not len(aid["t_us"]):
            return None
        at = aid["t_us"] * 1e-6
        fig, axs = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
        for c in "xyz":
            axs[0].plot(at, aid[f"gyro_bias_{c}_dph"], lw=0.9, label=c)
            axs[1].plot(at, aid[f"accel_bias_{c}_mg"], lw=0.9, label=c)
        axs[0].set_ylabel("gyro bias [deg/h]")
        axs[1].set_ylabel("accel bias [mg]")
        for ax in axs:
            ax.grid(alpha=0.3)
            ax.legend(loc="upper right")
        axs[-1].set_xlabel("time [s]")
        return save(fig, "bias.png", "Bias estimates (body FRD)")

    def track() -> tuple[str, str] | None:
        lat = sol["lat_deg"] * D2R
        lon = sol["lon_deg"] * D2R
        if not len(lat):
            return None
        from navd.core.earth import radii

        lat0, lon0 = float(lat[0]), float(lon[0])
        r_m, r_n = radii(lat0)
        north = (lat - lat0) * r_m
        east = (lon - lon0) * r_n * math.cos(lat0)
        fig, ax = plt.subplots(1, 1, figsize=(7.5, 7.5))
        sc = ax.scatter(east[::s], north[::s], c=ev.t_s[::s], s=2, cmap="viridis")
        fig.colorbar(sc, ax=ax, label="time [s]", shrink=0.8)
        if aid is not None and len(aid["t_us"]):
            gn = (aid["gnss_lat_deg"] * D2R - lat0) * r_m
            ge = (aid["gnss_lon_deg"] * D2R - lon0) * r_n * math.cos(lat0)
            ax.plot(ge, gn, "k+", ms=3, alpha=0.5, label="GNSS fixes")
            ax.legend(loc="upper right")
        ax.plot(east[0], north[0], "g^", ms=9)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("east [m]")
        ax.set_ylabel("north [m]")
        ax.grid(alpha=0.3)
        return save(fig, "track.png", f"Track on a local map (origin {lat0 * R2D:.6f}°, "
                                      f"{lon0 * R2D:.6f}°; triangle: start)", left=0.13)

    steps = [attitude, error, heading, innovations, biases, track]
    bar = None
    if progress and len(ev.t_s) > 200_000:
        from tqdm import tqdm

        bar = tqdm(total=len(steps), unit="figure", file=sys.stderr)
    for step in steps:
        r = step()
        if r is not None:
            figs.append(r)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return figs


# ---------------------------------------------------------------------------------------------
# page


def _fmt(x: float, nd: int = 2) -> str:
    return "–" if not math.isfinite(x) else f"{x:.{nd}f}"


def render_html(ev: Evaluation, figs: list[tuple[str, str]], title: str,
                inputs: dict[str, str], aid: dict[str, Any] | None, notes: list[str],
                checks: dict[str, dict[str, Any]] | None = None) -> str:
    e = html.escape
    parts = [
        "<!DOCTYPE html>",
        f"<html><head><meta charset='utf-8'><title>{e(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1150px;margin:auto;padding:1em}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;"
        "padding:2px 8px;text-align:right}th{background:#eee}img{max-width:100%}"
        "figure{margin:1em 0}figcaption{color:#444}</style></head><body>",
        f"<h1>{e(title)}</h1>",
        "<h2>Inputs</h2><table>",
    ]
    for k, v in inputs.items():
        parts.append(f"<tr><th>{e(k)}</th><td style='text-align:left'>{e(v)}</td></tr>")
    parts.append("</table>")
    if ev.stats:
        parts.append("<h2>Agreement with the reference (|navd − reference|, deg)</h2>")
        parts.append("<table><tr><th>axis</th><th>RMS</th><th>p50</th><th>p90</th>"
                     "<th>p99</th><th>max</th><th>rows</th></tr>")
        for a, st in ev.stats.items():
            parts.append(f"<tr><th>{e(a)}</th><td>{_fmt(st['rms'])}</td>"
                         f"<td>{_fmt(st['p50'])}</td><td>{_fmt(st['p90'])}</td>"
                         f"<td>{_fmt(st['p99'])}</td><td>{_fmt(st['max'])}</td>"
                         f"<td>{int(st['n'])}</td></tr>")
        parts.append("</table>")
    if ev.segments:
        parts.append("<h2>Per segment (RMS / max, deg)</h2><table><tr><th>from [s]</th>"
                     "<th>to [s]</th>" + "".join(f"<th>{a}</th>" for a in (*AXES, "angle"))
                     + "<th>course used</th><th>course rejected</th></tr>")
        for sg in ev.segments:
            cells = "".join(f"<td>{_fmt(sg.rms[a])} / {_fmt(sg.max[a])}</td>"
                            for a in (*AXES, "angle"))
            parts.append(f"<tr><td>{sg.t0_s:.1f}</td><td>{sg.t1_s:.1f}</td>{cells}"
                         f"<td>{sg.course_used}</td><td>{sg.course_rejected}</td></tr>")
        parts.append("</table>")
    if aid is not None and len(aid["t_us"]):
        last = {k: int(aid[k][-1]) for k in ("pos_accepted", "pos_rejected", "vel_accepted",
                                             "vel_rejected", "course_accepted",
                                             "course_rejected")}
        status = aid["course_status"][-1] if aid.get("course_status") else ""
        parts.append("<h2>Aiding</h2><table>")
        for name, count in last.items():
            parts.append(f"<tr><th>{e(name)}</th><td>{count}</td></tr>")
        parts.append(f"<tr><th>course update at the end</th><td style='text-align:left'>"
                     f"{e(status)}</td></tr></table>")
    if checks:
        parts.append(
            "<h2>Consistency checks</h2><p>gyro: RMS per body axis (x, y, z) of the rotation "
            "by which the attitude series departs from the integrated gyros over 1 s windows; "
            "yaw − course: at GNSS epochs faster than 8 m/s, median, interquartile range, and "
            "the amplitude of its once-per-revolution component (crab in a steady wind, or a "
            "heading-sensor error) with the RMS left after removing it.</p>"
            "<table><tr><th>series</th><th>gyro x / y / z [deg per window]</th>"
            "<th>yaw − course median [deg]</th><th>IQR [deg]</th><th>1/rev amplitude [deg]"
            "</th><th>residual RMS [deg]</th></tr>")
        for name, c in checks.items():
            g = c.get("gyro", {})
            gy = (" / ".join(_fmt(x) for x in g["rms_deg"]) if g.get("windows") else "–")
            co = c.get("course", {})
            if co.get("n"):
                cells = (f"<td>{_fmt(co['median_deg'], 1)}</td><td>{_fmt(co['p25_deg'], 1)} … "
                         f"{_fmt(co['p75_deg'], 1)}</td><td>{_fmt(co['amp_deg'], 1)}</td>"
                         f"<td>{_fmt(co['fit_resid_rms_deg'], 1)}</td>")
            else:
                cells = "<td>–</td>" * 4
            parts.append(f"<tr><th>{e(name)}</th><td>{gy}</td>{cells}</tr>")
        parts.append("</table>")
    if notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f"<li>{e(n)}</li>" for n in notes)
                     + "</ul>")
    parts.append("<h2>Figures</h2>")
    for name, cap in figs:
        parts.append(f"<figure><img src='{e(name)}' alt='{e(cap)}'>"
                     f"<figcaption>{e(cap)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def _checks(ev: Evaluation, sol: dict[str, Any], ref: RefSeries | None,
            aid: dict[str, Any] | None, log_data: Any, stats_from_s: float | None
            ) -> dict[str, dict[str, Any]]:
    """Consistency of navd and of the reference with the gyros and with the GNSS course."""
    if not len(ev.t_s):
        return {}
    t_from = float(ev.t_s[0]) if stats_from_s is None else stats_from_s
    series = {"navd": RefSeries(sol["t_us"], ev.sol_deg, "navd")}
    if ref is not None:
        series["reference"] = ref
    out: dict[str, dict[str, Any]] = {}
    for name, ser in series.items():
        c: dict[str, Any] = {}
        if log_data is not None and len(log_data.imu_t_us):
            c["gyro"] = gyro_consistency(log_data.imu_t_us, log_data.imu_inc, ser, t_from)
        if aid is not None and len(aid["t_us"]):
            c["course"] = course_check(aid, ser, t_from)
        if c:
            out[name] = c
    return out


SOL_NEEDED = ("t_us", "roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "lon_deg",
              "roll_sd_deg", "pitch_sd_deg", "yaw_sd_deg")


def build_report(solution: str | Path, out: str | Path, reference: str | Path | None = None,
                 aiding: str | Path | None = None, segment_s: float = 30.0,
                 stats_from_s: float | None = None, max_ref_gap_s: float = 1.0,
                 title: str | None = None, progress: bool = False,
                 log: str | Path | None = None) -> dict[str, Any]:
    """Write ``index.html``, the PNGs and ``summary.json`` into ``out``; return the summary.

    ``log``: the flight log the solution was replayed from; its IMU feeds the gyro
    consistency check (and its onboard attitude is the reference if none is given).
    """
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    sol = read_table(solution, SOL_NEEDED, progress=progress)
    notes: list[str] = []
    if sol["_skipped"]:
        notes.append(f"{sol['_skipped']} unreadable solution rows skipped")
    if not len(sol["t_us"]):
        notes.append("the solution is empty: the filter never started")
    log_data = None
    if log is not None:
        from navd.io.logs import LogFormatError, read_log

        try:
            log_data = read_log(log)
        except LogFormatError as exc:
            raise ReportError(f"log {log}: {exc}") from exc
    ref_src = reference if reference is not None else log
    ref = load_reference(ref_src, progress) if ref_src is not None else None
    aid = None
    if aiding is not None:
        aid = read_table(aiding, ("t_us", "course", "speed_mps", "course_deg"),
                         text=("course_status", "course"), progress=progress)
    ev = evaluate(sol, ref, aid, segment_s, stats_from_s, max_ref_gap_s)
    if ev.err_deg is not None and not np.any(np.isfinite(ev.err_deg)):
        notes.append("the reference does not overlap the solution in time")
    if stats_from_s is not None:
        notes.append(f"statistics and segments from t = {stats_from_s:g} s on")
    checks = _checks(ev, sol, ref, aid, log_data, stats_from_s)
    figs = make_figures(ev, sol, aid, out_dir, progress)
    inputs = {"solution": str(solution)}
    if ref is not None:
        inputs["reference"] = ref.source
    if aiding is not None:
        inputs["aiding"] = str(aiding)
    if len(ev.t_s):
        inputs["span"] = f"{ev.t_s[0]:.2f} … {ev.t_s[-1]:.2f} s, {len(ev.t_s)} rows"
    if log is not None:
        inputs["log"] = str(log)
    page = render_html(ev, figs, title or f"navd report: {Path(solution).name}", inputs, aid,
                       notes, checks)
    (out_dir / "index.html").write_text(page)
    summary: dict[str, Any] = {
        "inputs": inputs,
        "stats_deg": ev.stats,
        "segments": [{"t0_s": sg.t0_s, "t1_s": sg.t1_s, "n": sg.n, "rms_deg": sg.rms,
                      "max_deg": sg.max, "course_used": sg.course_used,
                      "course_rejected": sg.course_rejected} for sg in ev.segments],
        "figures": [f for f, _ in figs],
        "checks": checks,
        "notes": notes,
    }
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=True) + "\n")
    return summary
