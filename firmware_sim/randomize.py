"""Monte Carlo variants of a scenario: the ``[randomize]`` section applied for one seed.

A heading-from-motion estimator has to be tried from every initial yaw, on legs in every
direction, in every wind and with every bias sign; a fixed scenario tests one case.  The
variant is drawn from its own random stream of the seed (``STREAM_RANDOMIZE``), so it never
disturbs the sensor-noise draws, and the same seed always gives the same variant.  The result
is an ordinary :class:`Scenario` (with ``randomize.enabled`` off, so applying it twice changes
nothing) plus a record of what was drawn.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from firmware_sim.scenario import (
    FixedWingSpec,
    MultirotorSpec,
    RandomizeSpec,
    Scenario,
    TurnEvent,
    VelEvent,
)
from firmware_sim.sensors import STREAM_RANDOMIZE, rng
from navd.units import DEG


def _sym(gen: np.random.Generator, half_width: float) -> float:
    """Uniform draw in [-half_width, half_width] (0 when the width is 0, still consuming one
    draw so that later draws do not depend on which widths are zero)."""
    u = float(gen.uniform(-1.0, 1.0))
    return half_width * u


def _offsets(gen: np.random.Generator, rng_lh: tuple[float, ...]) -> tuple[float, ...] | None:
    """Three offsets with |x| uniform in [low, high] and random signs; None if no range."""
    mag = gen.uniform(0.0, 1.0, 3)
    sign = np.where(gen.uniform(0.0, 1.0, 3) < 0.5, -1.0, 1.0)
    if not rng_lh:
        return None
    lo, hi = rng_lh
    return tuple(float(x) for x in sign * (lo + (hi - lo) * mag))


def _mirror(turns: tuple[TurnEvent, ...]) -> tuple[TurnEvent, ...]:
    return tuple(dataclasses.replace(t, dyaw_deg=-t.dyaw_deg) for t in turns)


def _rotate_vel(events: tuple[VelEvent, ...], common_rad: float, jitters_rad: list[float]
                ) -> tuple[VelEvent, ...]:
    out = []
    for ev, j in zip(events, jitters_rad, strict=True):
        a = common_rad + j
        c, s = math.cos(a), math.sin(a)
        out.append(dataclasses.replace(ev, to_n_mps=c * ev.to_n_mps - s * ev.to_e_mps,
                                       to_e_mps=s * ev.to_n_mps + c * ev.to_e_mps))
    return tuple(out)


def randomized(sc: Scenario, seed: int) -> tuple[Scenario, dict[str, Any]]:
    """The variant of ``sc`` that seed ``seed`` flies, and what was drawn (deg, m/s, rad/s,
    m/s^2 as the keys say).  A scenario without an enabled ``[randomize]`` comes back as is."""
    r = sc.randomize
    if not r.enabled:
        return sc, {}
    gen = rng(seed, STREAM_RANDOMIZE)
    # fixed draw order, whatever the trajectory kind, so that each seed's numbers are stable
    d_yaw = _sym(gen, r.yaw0_deg)
    d_legs = _sym(gen, r.legs_rotate_deg)
    mirror = bool(gen.uniform(0.0, 1.0) < 0.5) and r.mirror_turns
    wind_u = float(gen.uniform(0.0, 1.0))
    d_wind_dir = _sym(gen, r.wind_dir_deg)
    gyro_off = _offsets(gen, r.gyro_offset_rps)
    accel_off = _offsets(gen, r.accel_offset_mps2)
    drawn: dict[str, Any] = {"yaw0_offset_deg": d_yaw, "mirror_turns": mirror}
    tr: Any = sc.trajectory
    if isinstance(tr, MultirotorSpec):
        jit = [_sym(gen, r.legs_jitter_deg) * DEG for _ in tr.vel]
        tr = dataclasses.replace(tr, yaw0_deg=tr.yaw0_deg + d_yaw,
                                 vel=_rotate_vel(tr.vel, d_legs * DEG, jit),
                                 turns=_mirror(tr.turns) if mirror else tr.turns)
        drawn["legs_rotate_deg"] = d_legs
    elif isinstance(tr, FixedWingSpec):
        tr = _fixed_wing_variant(tr, r, d_yaw, mirror, wind_u, d_wind_dir, drawn)
    elif hasattr(tr, "yaw0_deg"):
        tr = dataclasses.replace(tr, yaw0_deg=tr.yaw0_deg + d_yaw)
    imu = sc.imu
    if gyro_off is not None:
        imu = dataclasses.replace(imu, gyro_offset_rps=gyro_off)
        drawn["gyro_offset_rps"] = gyro_off
    if accel_off is not None:
        imu = dataclasses.replace(imu, accel_offset_mps2=accel_off)
        drawn["accel_offset_mps2"] = accel_off
    out = dataclasses.replace(sc, trajectory=tr, imu=imu,
                              randomize=dataclasses.replace(r, enabled=False))
    return out, drawn


def _fixed_wing_variant(tr: FixedWingSpec, r: RandomizeSpec, d_yaw: float, mirror: bool,
                        wind_u: float, d_wind_dir: float, drawn: dict[str, Any]
                        ) -> FixedWingSpec:
    """Yaw, turn directions and wind of a fixed-wing variant (wind speed capped so that the
    crab angle stays within ``max_crab_deg`` at the slowest horizontal airspeed)."""
    w_n, w_e = tr.wind_n_mps, tr.wind_e_mps
    speed = math.hypot(w_n, w_e)
    from_dir = math.atan2(-w_e, -w_n)  # where the wind blows from, rad
    if r.wind_speed_mps:
        lo, hi = r.wind_speed_mps
        speed = lo + (hi - lo) * wind_u
    cap = tr.min_horizontal_airspeed_mps() * math.sin(r.max_crab_deg * DEG)
    speed = min(speed, cap)
    from_dir += d_wind_dir * DEG
    w_n, w_e = -speed * math.cos(from_dir), -speed * math.sin(from_dir)
    drawn.update({"wind_speed_mps": speed, "wind_from_deg": math.degrees(from_dir) % 360.0})
    return dataclasses.replace(tr, yaw0_deg=tr.yaw0_deg + d_yaw, wind_n_mps=w_n,
                               wind_e_mps=w_e,
                               turns=_mirror(tr.turns) if mirror else tr.turns)
