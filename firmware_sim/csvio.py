"""CSV files of a run (format: docs/replay-format.md).

Floats are written with ``%.17g``, which round-trips every float64 exactly: the increments
replay the truth to round-off only if they are read back bit for bit.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from firmware_sim.polarization import POL_COLUMNS
from firmware_sim.scenario import scenario_dict
from firmware_sim.sensors import GNSS_COLUMNS

if TYPE_CHECKING:
    from firmware_sim.run import SimRun

IMU_COLUMNS = ("t_us", "dt_us", "dtheta_x", "dtheta_y", "dtheta_z", "dvel_x", "dvel_y", "dvel_z")
TRUTH_COLUMNS = ("t_us", "lat_deg", "lon_deg", "alt_m", "vel_n", "vel_e", "vel_d",
                 "roll_deg", "pitch_deg", "yaw_deg", "xi_arcsec", "eta_arcsec", "dg_mps2")
_INT_COLUMNS = frozenset({"t_us", "dt_us", "t_arrival_us", "outlier"})
_ARCSEC_PER_RAD = 180.0 * 3600.0 / np.pi
_CHUNK = 65536


def write_table(path: Path, names: Sequence[str], columns: Sequence[npt.NDArray[Any]],
                bar: tqdm[Any] | None = None) -> None:
    """Write equally long 1-D columns as CSV with a header row; ints as ints, floats %.17g.

    ``bar`` (optional) is advanced by the number of rows written.
    """
    fmt = ",".join("%d" if n in _INT_COLUMNS else "%.17g" for n in names)
    n = columns[0].shape[0] if columns else 0
    with path.open("w", encoding="ascii", newline="\n") as fh:
        fh.write(",".join(names) + "\n")
        for a in range(0, n, _CHUNK):
            # + 0.0 turns -0.0 into 0.0: same value, less noise in the files
            block = [c[a:a + _CHUNK] if c.dtype.kind in "biu" else c[a:a + _CHUNK] + 0.0
                     for c in columns]
            rows = zip(*(b.tolist() for b in block), strict=True)
            fh.write("".join(fmt % r + "\n" for r in rows))
            if bar is not None:
                bar.update(block[0].shape[0])


def read_table(path: str | Path) -> dict[str, npt.NDArray[Any]]:
    """Read a CSV written by :func:`write_table` back into named columns.

    Integer columns (``t_us``, ``dt_us``, ``t_arrival_us``) come back as int64, ``outlier`` as
    bool, everything else as float64 (bit-exact).
    """
    with Path(path).open(encoding="ascii", newline="") as fh:
        reader = csv.reader(fh)
        names = next(reader)
        rows = list(reader)
    out: dict[str, npt.NDArray[Any]] = {}
    for j, name in enumerate(names):
        col = [r[j] for r in rows]
        if name == "outlier":
            out[name] = np.array([int(v) for v in col], dtype=np.int64).astype(bool)
        elif name in _INT_COLUMNS:
            out[name] = np.array([int(v) for v in col], dtype=np.int64)
        else:
            out[name] = np.array([float(v) for v in col], dtype=np.float64)
    return out


def write_run(run: SimRun, out_dir: Path, progress: bool = False) -> None:
    """Write imu.csv (increments form), gnss.csv, truth.csv, pol.csv (with a polarization
    sensor) and meta.json into ``out_dir``.

    ``progress`` shows a tqdm bar over the rows written.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    n = run.imu_t_us.shape[0]
    rows = 2 * n + 1 + run.gnss["t_us"].shape[0]
    with tqdm(total=rows, desc="writing", unit="row", unit_scale=True, disable=not progress,
              leave=False) as bar:
        imu_cols: list[npt.NDArray[Any]] = [run.imu_t_us,
                                            np.full(n, run.imu_dt_us, dtype=np.int64)]
        imu_cols += [run.imu_inc[:, j] for j in range(6)]
        write_table(out_dir / "imu.csv", IMU_COLUMNS, imu_cols, bar)
        write_table(out_dir / "gnss.csv", GNSS_COLUMNS,
                    [run.gnss[k].astype(np.int64) if k == "outlier" else run.gnss[k]
                     for k in GNSS_COLUMNS], bar)
        eul = np.degrees(run.truth_euler)
        truth_cols: list[npt.NDArray[Any]] = [
            run.truth_t_us, np.degrees(run.truth_pos[:, 0]), np.degrees(run.truth_pos[:, 1]),
            run.truth_pos[:, 2], run.truth_vel_n[:, 0], run.truth_vel_n[:, 1],
            run.truth_vel_n[:, 2], eul[:, 0], eul[:, 1], eul[:, 2],
            run.truth_dov[:, 0] * _ARCSEC_PER_RAD, run.truth_dov[:, 1] * _ARCSEC_PER_RAD,
            run.truth_dov[:, 2],
        ]
        write_table(out_dir / "truth.csv", TRUTH_COLUMNS, truth_cols, bar)
        if run.pol is not None:
            write_table(out_dir / "pol.csv", POL_COLUMNS,
                        [run.pol[k] for k in POL_COLUMNS], bar)
    meta = {
        "format": "firmware_sim run 1",
        "seed": run.seed,
        "scenario": scenario_dict(run.scenario),
        "imu_samples": n,
        "imu_dt_us": run.imu_dt_us,
        "gnss_epochs": int(run.gnss["t_us"].shape[0]),
        "gnss_outliers": int(np.count_nonzero(run.gnss["outlier"])),
        "gyro_bias_rps": run.gyro_bias_rps.tolist(),
        "accel_bias_mps2": run.accel_bias_mps2.tolist(),
        "gyro_scale_factor_ppm": (run.gyro_scale * 1e6).tolist(),
        "accel_scale_factor_ppm": (run.accel_scale * 1e6).tolist(),
        "randomized": run.randomized,
    }
    (out_dir / "meta.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
