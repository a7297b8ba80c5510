"""Whose heading is right on the X8 flight? The airspeed triangle, independent of both.

The X8 log (``../shared/data/px4-x8-flight``) carries airspeed (``NTUN.txt`` column 7, m/s).
With the right heading psi, the GNSS ground velocity is ``k * airspeed * [cos psi, sin psi]
+ wind`` with one airspeed scale k and a wind that is constant over the 80 s flight (sideslip
and the climb angle ignored: they add to the residual of every candidate alike).  Fitting
(k, wind N, wind E) by least squares for each candidate heading, the residual RMS says how
well that heading explains the flight:

* navd's yaw (default config, fixed_wing profile, as ``benchmarks/yaw_bank.py --real``);
* the onboard estimator's yaw (``ATT.txt``), the reference of the yaw-bank real-log table;
* the GNSS course (heading = course: right only if the wind is small).

Epochs: t >= 20 s (after the hand launch), ground speed and airspeed >= 8 m/s.

    python benchmarks/x8_wind.py [--json PATH]
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parent))

import robustness as rb

from navd.config import load_config
from navd.io.logs import LogOptions, read_log
from navd.pipeline import build_estimator, solutions

Arr = npt.NDArray[np.float64]
MIN_SPEED = 8.0  # m/s
FROM_S = 20.0  # s from the log start: the X8 is hand-launched at 16.5 s


def triangle_fit(vel_ne: Arr, airspeed: Arr, psi: Arr) -> dict[str, float]:
    """Least squares of vel_ne = k * airspeed * [cos psi, sin psi] + [wN, wE]; returns k,
    the wind (m/s) and the residual RMS per component (m/s)."""
    n = len(psi)
    A = np.zeros((2 * n, 3))
    A[0::2, 0] = airspeed * np.cos(psi)
    A[1::2, 0] = airspeed * np.sin(psi)
    A[0::2, 1] = 1.0
    A[1::2, 2] = 1.0
    b = np.empty(2 * n)
    b[0::2] = vel_ne[:, 0]
    b[1::2] = vel_ne[:, 1]
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    r = b - A @ x
    return {"k": float(x[0]), "wind_n_mps": float(x[1]), "wind_e_mps": float(x[2]),
            "residual_rms_mps": float(np.sqrt(np.mean(r**2)))}


def _table(zf: zipfile.ZipFile, name: str) -> Arr:
    return np.loadtxt(io.StringIO(zf.read(name).decode()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    spec = next(r for r in rb.REAL_LOGS if r.name == "X8")
    if not spec.path.exists():
        print(f"x8_wind: {spec.path} not found (set NAVD_DATA)", file=sys.stderr)
        return 2
    with zipfile.ZipFile(spec.path) as zf:
        names = {Path(n).name: n for n in zf.namelist()}
        ntun, gps, att = (_table(zf, names[f]) for f in ("NTUN.txt", "GPSraw.txt", "ATT.txt"))
    data = read_log(spec.path, None, LogOptions())
    est = build_estimator(load_config(None, [f"filter.profile={spec.profile}"]))
    sol = np.array([(s.t_us, s.yaw_rad, float(s.heading_aligned))
                    for s in solutions(est, data.samples(), 10.0)])
    # navd/io/logs/x8.py stamps every stream with the text files' own milliseconds (x 1000)
    t_g = gps[:, 0] * 1e-3
    vel = gps[:, 4:6]
    air = np.interp(t_g, ntun[:, 0] * 1e-3, ntun[:, 7])
    t_sol = sol[:, 0] * 1e-6
    yaw_navd = np.interp(t_g, t_sol, np.unwrap(sol[:, 1]))
    aligned = np.interp(t_g, t_sol, sol[:, 2]) > 0.5
    yaw_att = np.interp(t_g, att[:, 0] * 1e-3, np.unwrap(np.radians(att[:, 4])))
    course = np.arctan2(vel[:, 1], vel[:, 0])
    m = (t_g >= FROM_S) & (np.hypot(vel[:, 0], vel[:, 1]) >= MIN_SPEED) & (air >= MIN_SPEED)
    rows: list[dict[str, Any]] = []
    for label, psi, mask in (("navd yaw", yaw_navd, m), ("navd yaw, aligned epochs", yaw_navd,
                                                        m & aligned),
                             ("onboard yaw (ATT)", yaw_att, m), ("GNSS course", course, m)):
        rows.append({"heading": label, "epochs": int(mask.sum()),
                     **triangle_fit(vel[mask], air[mask], psi[mask])})
    print(f"X8 airspeed triangle: t >= {FROM_S:.0f} s, ground and air speed >= "
          f"{MIN_SPEED:.0f} m/s")
    print("| heading | epochs | airspeed scale k | wind N / E, m/s | residual RMS, m/s |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['heading']} | {r['epochs']} | {r['k']:.3f} | {r['wind_n_mps']:+.2f} / "
              f"{r['wind_e_mps']:+.2f} | {r['residual_rms_mps']:.2f} |")
    d = np.degrees((yaw_navd - yaw_att + math.pi) % (2 * math.pi) - math.pi)
    print(f"navd - onboard yaw over these epochs: RMS {float(np.sqrt(np.mean(d[m] ** 2))):.1f} deg")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
