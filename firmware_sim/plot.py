"""``track.png``: the horizontal track and the speed of a run (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from firmware_sim.run import SimRun
from navd.core.earth import radii


def plot_track(run: SimRun, path: Path) -> None:
    """Track (north/east metres from the start) and speed (truth and GNSS) over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lat0, lon0, h0 = (float(x) for x in run.truth_pos[0])
    r_m, r_n = radii(lat0)
    north = (run.truth_pos[:, 0] - lat0) * (r_m + h0)
    east = (run.truth_pos[:, 1] - lon0) * (r_n + h0) * np.cos(lat0)
    t = (run.truth_t_us - run.truth_t_us[0]) * 1e-6
    g = run.gnss
    tg = (g["t_us"] - run.truth_t_us[0]) * 1e-6
    gn = (np.radians(g["lat_deg"]) - lat0) * (r_m + h0)
    ge = (np.radians(g["lon_deg"]) - lon0) * (r_n + h0) * np.cos(lat0)
    out = g["outlier"].astype(bool)

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    ax1.plot(ge, gn, ".", ms=2, color="0.7", label="GNSS")
    ax1.plot(east, north, "-", lw=1.2, label="truth")
    ax1.plot(east[:1], north[:1], "go", label="start")
    ax1.set_xlabel("east (m)")
    ax1.set_ylabel("north (m)")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.legend(loc="best")
    ax1.set_title(f"{run.scenario.name}, seed {run.seed}")
    ax2.plot(t, np.hypot(run.truth_vel_n[:, 0], run.truth_vel_n[:, 1]), lw=1.2,
             label="truth horizontal speed")
    ax2.plot(tg, np.hypot(g["vel_n"], g["vel_e"]), ".", ms=2, color="0.6", label="GNSS")
    if np.any(out):
        ax2.plot(tg[out], np.hypot(g["vel_n"][out], g["vel_e"][out]), "rx", ms=4,
                 label="velocity jump")
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("speed (m/s)")
    ax2.legend(loc="best")
    ax2.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
