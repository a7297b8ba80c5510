"""Learned IMU biases kept from one run to the next (``[bias_store]``).

At rest an accelerometer bias cannot be told from tilt: a vehicle that starts still starts
with a tilt error of ``b/g`` (5 mg: 0.29 deg), which only motion (turns, accelerations)
removes.  On a tilted static vehicle with a polarization compass the heading inherits that
tilt error, amplified by the geometry (docs/polarization.md).  A gyro bias is likewise learned
slowly.  So what the filter learned while it could is written to a small JSON file, and the
next start uses it as the initial bias estimate, as autopilots keep their accelerometer
offsets between flights.

File (JSON, replaced atomically)::

    {"schema": 1, "imu": "<imu_id>", "saved_unix_s": float, "navd": version,
     "gyro_bias_deg_per_h": [3], "gyro_bias_sd_deg_per_h": [3],
     "accel_bias_mg": [3], "accel_bias_sd_mg": [3], "mount_deg": [3]}

Biases are body FRD, measured = true + bias: the axes after the IMU's mounting (``[imu]
mount_roll/pitch/yaw_deg``), which the file records as ``mount_deg`` (a file written before
it did: no mount).  At start (:func:`apply`), a usable file sets
``[imu] gyro_bias_deg_per_h`` / ``accel_bias_mg`` and lowers ``gyro_bias_sd_deg_per_h`` /
``accel_bias_sd_mg`` to the stored 1-sigma combined with the sensor's turn-on repeatability
(``repeat_*``), never raising them.  (The section,
:class:`navd.config.daemon.BiasStoreSection`, holds SI values; the file and this module's
arithmetic are in the keys' units: deg/h, mg, days.) The estimator therefore sees ordinary
config, and a recording made by the daemon carries the biases it started with, so it replays
exactly.  A file is refused, with a warning naming the cause, when it is unreadable, of
another schema, IMU or IMU mount, older than ``max_age_days`` or dated in the future, non-finite, or
implausible against the configured prior (beyond 5 sigma).  It is written (:func:`snapshot`,
:func:`save`) every ``save_period_s`` and at stop, but only while every bias 1-sigma is
within ``max_*_sd``: a run that learned nothing leaves the file as it was.
"""

from __future__ import annotations

import copy
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

from navd import __version__
from navd.config.daemon import BiasStoreSection
from navd.config.estimator import ImuSection
from navd.config.load import from_si
from navd.core.estimator import Estimator
from navd.units import G0

__all__ = ["SCHEMA", "apply", "save", "snapshot"]

SCHEMA = 1
_DPH = 180.0 / math.pi * 3600.0  # rad/s -> deg/h
_MG = 1e3 / G0  # m/s^2 -> mg
_FUTURE_TOLERANCE_S = 86_400.0  # a host clock set back by a day is not yet a bad file
_MOUNT_TOL_DEG = 0.01  # a mount written back rounded is the same mount


def _mount_deg(c: ImuSection) -> list[float]:
    return [math.degrees(a) for a in c.mount]


def _vec3(d: dict[str, Any], key: str) -> list[float]:
    v = d.get(key)
    if (not isinstance(v, list) or len(v) != 3
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)):
        raise ValueError(f"{key} is not a list of 3 numbers")
    out = [float(x) for x in v]
    if not all(math.isfinite(x) for x in out):
        raise ValueError(f"{key} is not finite")
    return out


def _read(path: Path, s: BiasStoreSection, prior: dict[str, float], mount_deg: list[float],
          now_unix_s: float) -> dict[str, list[float]]:
    """The stored vectors, or ValueError naming why the file cannot be used (``mount_deg``:
    the configured ``[imu] mount_*_deg``, degrees: biases in other axes are not these
    axes' biases)."""
    try:
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"unreadable: {exc}") from None
    if not isinstance(d, dict) or d.get("schema") != SCHEMA:
        raise ValueError(f"schema {d.get('schema') if isinstance(d, dict) else '?'}, "
                         f"expected {SCHEMA}")
    if d.get("imu", "") != s.imu_id:
        raise ValueError(f"written for IMU {d.get('imu')!r}, this is {s.imu_id!r}")
    stored = _vec3(d, "mount_deg") if "mount_deg" in d else [0.0, 0.0, 0.0]
    if max(abs(a - b) for a, b in zip(stored, mount_deg, strict=True)) > _MOUNT_TOL_DEG:
        raise ValueError(f"written for an IMU mounted at {_fmt(stored)} deg, [imu] "
                         f"mount_roll/pitch/yaw_deg are {_fmt(mount_deg)}")
    saved = d.get("saved_unix_s")
    if not isinstance(saved, int | float) or not math.isfinite(saved):
        raise ValueError("no valid saved_unix_s")
    age_days = (now_unix_s - float(saved)) / 86_400.0
    if now_unix_s - float(saved) < -_FUTURE_TOLERANCE_S:
        raise ValueError(f"dated {-age_days:.1f} days in the future (host clock?)")
    max_age_days = from_si(s.max_age, "days")
    if age_days > max_age_days:
        raise ValueError(f"{age_days:.1f} days old, max_age_days = {max_age_days:g}")
    v = {k: _vec3(d, k) for k in ("gyro_bias_deg_per_h", "gyro_bias_sd_deg_per_h",
                                  "accel_bias_mg", "accel_bias_sd_mg")}
    if min(v["gyro_bias_sd_deg_per_h"] + v["accel_bias_sd_mg"]) <= 0.0:
        raise ValueError("a 1-sigma is not positive")
    # plausibility against the configured prior
    for key, sd_key in (("gyro_bias_deg_per_h", "gyro_bias_sd_deg_per_h"),
                        ("accel_bias_mg", "accel_bias_sd_mg")):
        worst = max(abs(x) for x in v[key])
        if worst > 5.0 * prior[sd_key]:
            raise ValueError(f"{key} {worst:.3g} is beyond 5 sigma of the prior "
                             f"{sd_key} = {prior[sd_key]:g}")
    return v


def apply(tables: dict[str, Any], s: BiasStoreSection, imu_cfg: ImuSection, now_unix_s: float
          ) -> tuple[dict[str, Any], str]:
    """Config tables with the stored biases merged into ``[imu]``, and what happened
    ("off", "none yet: PATH", "loaded ...", "refused: ...").  Never raises for a bad file.

    ``imu_cfg`` is the ``[imu]`` section already built from ``tables`` (the configured prior)."""
    if not s.path:
        return tables, "off"
    path = Path(s.path)
    if not path.exists():
        return tables, f"none yet: {path}"
    table = tables.get("imu", {})
    c = imu_cfg  # validated, defaults filled in (SI)
    # the configured prior, as written in the table (no unit round trip) or the default
    prior = {"gyro_bias_sd_deg_per_h": float(table.get("gyro_bias_sd_deg_per_h",
                                                       c.gyro_bias_sd * _DPH)),
             "accel_bias_sd_mg": float(table.get("accel_bias_sd_mg", c.accel_bias_sd * _MG))}
    try:
        v = _read(path, s, prior, _mount_deg(imu_cfg), now_unix_s)
    except ValueError as exc:
        return tables, f"refused: {path}: {exc}"
    g_sd = math.hypot(max(v["gyro_bias_sd_deg_per_h"]), from_si(s.repeat_gyro_sd, "deg_per_h"))
    a_sd = math.hypot(max(v["accel_bias_sd_mg"]), from_si(s.repeat_accel_sd, "mg"))
    imu = dict(table)
    imu["gyro_bias_deg_per_h"] = v["gyro_bias_deg_per_h"]
    imu["accel_bias_mg"] = v["accel_bias_mg"]
    imu["gyro_bias_sd_deg_per_h"] = min(prior["gyro_bias_sd_deg_per_h"], g_sd)
    imu["accel_bias_sd_mg"] = min(prior["accel_bias_sd_mg"], a_sd)
    out = copy.deepcopy(tables)
    out["imu"] = imu
    return out, (f"loaded {path}: gyro {_fmt(v['gyro_bias_deg_per_h'])} deg/h "
                 f"(1-sigma {imu['gyro_bias_sd_deg_per_h']:.2f}), accel "
                 f"{_fmt(v['accel_bias_mg'])} mg (1-sigma {imu['accel_bias_sd_mg']:.2f})")


def _fmt(v: list[float]) -> str:
    return "[" + ", ".join(f"{x:.2f}" for x in v) + "]"


def snapshot(est: Estimator, s: BiasStoreSection, now_unix_s: float) -> dict[str, Any] | None:
    """The record to save, or None while navigation is not running or a bias is not yet
    known to ``max_*_sd``."""
    if not est.initialized:
        return None
    P = est.P
    g_sd = [math.sqrt(max(float(P[9 + i, 9 + i]), 0.0)) * _DPH for i in range(3)]
    a_sd = [math.sqrt(max(float(P[12 + i, 12 + i]), 0.0)) * _MG for i in range(3)]
    bg = [float(x) * _DPH for x in est.bias_g]
    ba = [float(x) * _MG for x in est.bias_a]
    if not all(math.isfinite(x) for x in bg + ba + g_sd + a_sd):
        return None
    if (max(g_sd) > from_si(s.max_gyro_sd, "deg_per_h")
            or max(a_sd) > from_si(s.max_accel_sd, "mg")):
        return None
    return {"schema": SCHEMA, "imu": s.imu_id, "saved_unix_s": now_unix_s, "navd": __version__,
            "gyro_bias_deg_per_h": bg, "gyro_bias_sd_deg_per_h": g_sd,
            "accel_bias_mg": ba, "accel_bias_sd_mg": a_sd,
            "mount_deg": _mount_deg(est.cfg.imu)}


def save(path: str | Path, record: dict[str, Any]) -> None:
    """Write ``record`` so that a crash leaves either the old file or the new one."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=p.name + ".", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(record, fh, indent=1)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
