"""``navd dov-grid``: write a regional deflection-of-the-vertical grid from a gravity model.

The model and the synthesis are in :mod:`navd.eval.gravity_model`; docs/dov.md explains both.

Example::

    navd dov-grid --lat-min 21 --lat-max 24 --lon-min 112 --lon-max 116 \\
        --step-arcmin 2 --out south_china_sea.nc
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from navd.eval.gravity_model import grid_axis, make_model, synthesize


def main(argv: list[str] | None = None) -> int:
    from navd.core.aiding.dov import DovGrid, DovGridError
    from navd.io.dov_grid import describe_values, save_dov_grid

    ap = argparse.ArgumentParser(
        prog="navd dov-grid", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Compute a regional deflection-of-the-vertical grid (xi, eta, dg) from "
                    "a spherical-harmonic gravity model; see docs/dov.md.")
    ap.add_argument("--lat-min", type=float, required=True, help="deg")
    ap.add_argument("--lat-max", type=float, required=True, help="deg")
    ap.add_argument("--lon-min", type=float, required=True, help="deg")
    ap.add_argument("--lon-max", type=float, required=True, help="deg")
    ap.add_argument("--step-arcmin", type=float, required=True,
                    help="node spacing, arcmin (EGM96 resolves ~55 km: 2-5' is plenty)")
    ap.add_argument("--out", required=True, help="output .npz (navd layout) or .nc (netCDF)")
    ap.add_argument("--height-m", type=float, default=0.0,
                    help="ellipsoidal height of the grid, m (default 0: sea level ships)")
    ap.add_argument("--model", default="egm96", choices=("egm96", "normal", "normal-j2"))
    ap.add_argument("--nmax", type=int, default=360, help="EGM96 maximum degree (<= 360)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    a = ap.parse_args(argv)
    if not (a.step_arcmin > 0.0 and math.isfinite(a.step_arcmin)):
        ap.error("--step-arcmin must be > 0")
    if not (-90.0 <= a.lat_min < a.lat_max <= 90.0):
        ap.error("need -90 <= --lat-min < --lat-max <= 90")
    if not (a.lon_max > a.lon_min and a.lon_max - a.lon_min <= 360.0):
        ap.error("need --lon-min < --lon-max spanning at most 360 deg")
    if not -1e4 <= a.height_m <= 1e5:
        ap.error("--height-m must be in [-10 km, 100 km]")
    out = Path(a.out)
    if out.suffix.lower() not in (".npz", ".nc", ".grd", ".nc4"):
        ap.error("--out must end in .npz or .nc")
    step = a.step_arcmin / 60.0
    lat = grid_axis(a.lat_min, a.lat_max, step, "lat")
    lat = lat[lat <= 90.0 + 1e-9]
    lon = grid_axis(a.lon_min, a.lon_max, step, "lon")
    try:
        model = make_model(a.model, a.nmax)
    except (RuntimeError, ValueError) as exc:
        print(f"navd dov-grid: {exc}", file=sys.stderr)
        return 2
    print(f"navd dov-grid: {model.name}, {lat.size} x {lon.size} nodes, lat "
          f"{lat[0]:.4f}..{lat[-1]:.4f}, lon {lon[0]:.4f}..{lon[-1]:.4f} deg, h {a.height_m} m",
          file=sys.stderr)
    t0 = time.perf_counter()
    xi, eta, dg = synthesize(model, lat, lon, a.height_m, progress=not a.quiet)
    try:
        DovGrid(lat, lon, xi, eta, dg, str(out))  # the same checks a loader applies
        save_dov_grid(out, lat, lon, xi, eta, dg, height_m=a.height_m, model=model.name,
                      history=f"navd dov-grid {' '.join(sys.argv[2:] if argv is None else argv)}")
    except (DovGridError, OSError) as exc:
        print(f"navd dov-grid: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {out}: {describe_values(xi, eta)}, dg {dg.min() / 1e-5:+.1f}.."
          f"{dg.max() / 1e-5:+.1f} mGal ({time.perf_counter() - t0:.1f} s)")
    return 0

