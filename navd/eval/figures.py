"""The report's figures (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from navd.eval.evaluate import AXES, Evaluation
from navd.units import DEG as D2R
from navd.units import RAD2DEG as R2D

F64 = npt.NDArray[np.float64]
_MAX_PLOT_POINTS = 20_000


# ---------------------------------------------------------------------------------------------
# figures


def _stride(n: int) -> int:
    return max(1, n // _MAX_PLOT_POINTS)


def _break_t(t: F64, y: F64, jump: float = 180.0) -> tuple[F64, F64]:
    """``t`` and ``y`` with a NaN between samples that jump by more than ``jump`` (yaw wrap),
    so lines do not cross the plot."""
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
    # wall-clock logs (PX4 SITL: Unix time) count from their start, else matplotlib shows an
    # offset like "+1.7107733e9" and ticks no one can read
    xlabel = ("time [s]" if ev.t0_us == 0.0 else
              f"time from the log's start [s] (log clock {ev.t0_us * 1e-6:.0f} s)")
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
        axs[-1].set_xlabel(xlabel)
        return save(fig, "attitude.png", "Attitude: navd and the reference")

    hs = ev.heading_scored[::s] if ev.heading_scored is not None else None

    def _scored(y: F64, axis: int) -> F64:
        """Heading errors (yaw, angle) where they are scored; roll/pitch everywhere."""
        return y if hs is None or axis != 2 else np.where(hs, y, np.nan)

    def error() -> tuple[str, str] | None:
        if ev.err_deg is None:
            return None
        fig, axs = plt.subplots(4, 1, figsize=(11, 9), sharex=True)
        for i, a in enumerate(AXES):
            ax = axs[i]
            band = 3.0 * ev.sd_deg[::s, i]
            ax.fill_between(t, -band, band, color="0.85", label="±3σ (filter)")
            ax.plot(t, _scored(ev.err_deg[::s, i], i), lw=0.8, color="C3",
                    label="navd − reference")
            if i == 2 and hs is not None and not hs.all():
                ax.plot(t, np.where(hs, np.nan, ev.err_deg[::s, i]), lw=0.8, color="0.6",
                        label="heading not aligned: not scored")
            lim = np.nanpercentile(np.abs(ev.err_deg[:, i]), 99.5) if np.any(
                np.isfinite(ev.err_deg[:, i])) else 1.0
            ax.set_ylim(-1.5 * max(lim, 0.1), 1.5 * max(lim, 0.1))
            ax.set_ylabel(f"{a} error [deg]")
            ax.grid(alpha=0.3)
        axs[0].legend(loc="upper right")
        axs[2].legend(loc="upper right", fontsize=8)
        assert ev.angle_deg is not None
        axs[3].plot(t, _scored(ev.angle_deg[::s], 2), lw=0.8, color="C4")
        if hs is not None and not hs.all():
            axs[3].plot(t, np.where(hs, np.nan, ev.angle_deg[::s]), lw=0.8, color="0.6")
        axs[3].set_ylabel("angle error [deg]")
        axs[3].grid(alpha=0.3)
        axs[-1].set_xlabel(xlabel)
        return save(fig, "error.png", "Attitude error (navd − reference) with the filter's ±3σ; "
                                      "bottom: total rotation angle between the two; grey: "
                                      "heading not yet aligned (not scored)")

    def heading() -> tuple[str, str] | None:
        fig, ax = plt.subplots(1, 1, figsize=(11, 4.5))
        ax.plot(*_break_t(t, ev.sol_deg[::s, 2]), lw=0.9, label="navd yaw")
        if ev.ref_deg is not None:
            ax.plot(*_break_t(t, ev.ref_deg[::s, 2]), lw=0.9, alpha=0.8, label="reference yaw")
        if aid is not None and len(aid["t_us"]):
            at = (aid["t_us"] - ev.t0_us) * 1e-6
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
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
        return save(fig, "heading.png", "Heading, GNSS course, and the epochs where the course "
                                        "update was used (green) or rejected (red)")

    def innovations() -> tuple[str, str] | None:
        if aid is None or not len(aid["t_us"]):
            return None
        at = (aid["t_us"] - ev.t0_us) * 1e-6
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
        axs[-1].set_xlabel(xlabel)
        return save(fig, "innovations.png", "GNSS innovations (measurement − prediction before "
                                            "the update) and yaw − course")

    def biases() -> tuple[str, str] | None:
        if aid is None or not len(aid["t_us"]):
            return None
        at = (aid["t_us"] - ev.t0_us) * 1e-6
        fig, axs = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
        for c in "xyz":
            axs[0].plot(at, aid[f"gyro_bias_{c}_dph"], lw=0.9, label=c)
            axs[1].plot(at, aid[f"accel_bias_{c}_mg"], lw=0.9, label=c)
        axs[0].set_ylabel("gyro bias [deg/h]")
        axs[1].set_ylabel("accel bias [mg]")
        for ax in axs:
            ax.grid(alpha=0.3)
            ax.legend(loc="upper right")
        axs[-1].set_xlabel(xlabel)
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

        bar = tqdm(total=len(steps), unit="figure", file=sys.stderr, disable=None)
    for step in steps:
        r = step()
        if r is not None:
            figs.append(r)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return figs


