"""Smooth attitude and velocity profiles at the IMU sample times, one builder per vehicle kind.

Every profile returns ZYX Euler angles (roll, pitch, yaw; rad) of C_b^n and NED velocity (m/s)
at the truth sample times.  Positions are not built here: they are integrated from the
velocities exactly as the strapdown does (see :mod:`firmware_sim.truth`).

Transitions use ``s(u) = u - sin(2 pi u) / (2 pi)`` on ``u in [0, 1]``: its first and second
derivatives vanish at both ends, so a speed change has continuous acceleration and jerk-limited
ends, and a heading change has continuous yaw rate and yaw acceleration.  A change of size D
over T seconds has a peak rate of 2 D / T.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from firmware_sim.scenario import (
    DovSpec,
    FixedWingSpec,
    GroundSpec,
    ModulationSpec,
    MultirotorSpec,
    ShipSpec,
    StaticSpec,
    TargetEvent,
    TrajectorySpec,
    TurnEvent,
)
from firmware_sim.sensors import STREAM_SLIP, rng
from navd.core.earth import gravity
from navd.units import ARCSEC, DEG

Arr = npt.NDArray[np.float64]
TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class Profile:
    """Truth kinematics at the sample times.

    Attributes:
        euler: (N, 3) roll, pitch, yaw of C_b^n, rad (yaw continuous, not wrapped).
        vel_n: (N, 3) NED velocity, m/s.
    """

    euler: Arr
    vel_n: Arr


def smoothstep(u: Arr) -> tuple[Arr, Arr]:
    """``s(u)`` and ``ds/du`` for u clipped to [0, 1]; both arrays shaped like ``u``."""
    c = np.clip(u, 0.0, 1.0)
    s = c - np.sin(TWO_PI * c) / TWO_PI
    ds = 1.0 - np.cos(TWO_PI * c)
    # exact end values so that a stop is exactly 0 m/s and a finished turn exactly its angle
    s = np.where(c >= 1.0, 1.0, s)
    return s, ds


def targets(t: Arr, start: float, events: tuple[tuple[float, float, float], ...]
            ) -> tuple[Arr, Arr]:
    """Piecewise smooth profile through absolute targets.

    Args:
        t: (N,) times, s.
        start: value before the first event.
        events: (t_start_s, duration_s, target) in time order, not overlapping.

    Returns:
        value (N,) and its time derivative (N,) per second, in the unit of ``start``.
    """
    val = np.full_like(t, start)
    rate = np.zeros_like(t)
    prev = start
    for t0, dur, to in events:
        m = t >= t0
        if np.any(m):
            s, ds = smoothstep((t[m] - t0) / dur)
            # after the event the value is the target itself, bit for bit
            val[m] = np.where(s >= 1.0, to, prev + (to - prev) * s)
            rate[m] = (to - prev) * ds / dur
        prev = to
    return val, rate


def _turn_targets(start_rad: float, turns: tuple[TurnEvent, ...]
                  ) -> tuple[tuple[float, float, float], ...]:
    out = []
    acc = start_rad
    for ev in turns:
        acc += ev.dyaw_deg * DEG
        out.append((ev.t_s, ev.dur_s, acc))
    return tuple(out)


def _abs_targets(events: tuple[TargetEvent, ...], scale: float
                 ) -> tuple[tuple[float, float, float], ...]:
    return tuple((ev.t_s, ev.dur_s, ev.to * scale) for ev in events)


def static_profile(t: Arr, spec: StaticSpec) -> Profile:
    n = t.shape[0]
    euler = np.empty((n, 3))
    euler[:] = (spec.roll_deg * DEG, spec.pitch_deg * DEG, spec.yaw_deg * DEG)
    if spec.sway_deg > 0.0:
        w = 2.0 * np.pi / spec.sway_period_s
        euler[:, 0] += spec.sway_deg * DEG * np.sin(w * t)
        euler[:, 1] += spec.sway_deg * DEG * np.sin(w / 1.37 * t + 1.0)
    return Profile(euler, np.zeros((n, 3)))


# cosines summed into a wandering sideslip
SLIP_TONES = 16


def slip_wander(t: Arr, sigma_rad: float, tau_s: float, seed: int) -> Arr:
    """A smooth random sideslip (N,), rad: ``SLIP_TONES`` cosines with uniform phases and
    frequencies drawn from N(0, 1 / (2 pi tau)), each of amplitude sigma sqrt(2 / K), so its
    variance is sigma^2 and its autocorrelation exp(-dt^2 / (2 tau^2)).  Smooth (unlike a
    Gauss-Markov path), so the lateral acceleration it makes, v d(beta)/dt, stays finite."""
    if sigma_rad == 0.0:
        return np.zeros_like(t)
    gen = rng(seed, STREAM_SLIP)
    f = gen.normal(0.0, 1.0 / (2.0 * np.pi * tau_s), SLIP_TONES)
    ph = gen.uniform(0.0, 2.0 * np.pi, SLIP_TONES)
    out: Arr = sigma_rad * np.sqrt(2.0 / SLIP_TONES) * np.cos(
        2.0 * np.pi * t[:, None] * f + ph).sum(axis=1)
    return out


def ground_profile(t: Arr, spec: GroundSpec, seed: int = 0) -> Profile:
    """Ground vehicle: the velocity lies along body x unless sideslip is enabled.

    Body roll follows the lateral (centripetal) acceleration ``a_lat = v_h * yaw_rate``
    (positive to the right): ``roll = roll_gain * a_lat`` (a negative gain leans the car out
    of the turn, as a real car does).  Sideslip ``beta = sideslip_gain * a_lat`` turns the
    velocity away from body x, so GNSS course = yaw + beta; ``slip_wander_rad`` adds a
    sideslip of its own (:func:`slip_wander`, drawn from ``seed``).  A water current adds to the
    horizontal velocity (a boat's crab); sway adds wave roll and pitch (:class:`GroundSpec`).
    """
    speed, _ = targets(t, spec.speed0_mps, _abs_targets(spec.speed, 1.0))
    yaw, yaw_rate = targets(t, spec.yaw0_deg * DEG, _turn_targets(spec.yaw0_deg * DEG,
                                                                  spec.turns))
    pitch, _ = targets(t, 0.0, _abs_targets(spec.grade, DEG))
    v_h = speed * np.cos(pitch)
    a_lat = v_h * yaw_rate
    roll = spec.roll_gain_rad_per_mps2 * a_lat
    course = yaw + spec.sideslip_gain_rad_per_mps2 * a_lat
    if spec.slip_wander_rad > 0.0:
        course = course + slip_wander(t, spec.slip_wander_rad, spec.slip_wander_tau_s, seed)
    vel = np.stack([v_h * np.cos(course) + spec.current_n_mps,
                    v_h * np.sin(course) + spec.current_e_mps, -speed * np.sin(pitch)], axis=1)
    if spec.sway_deg > 0.0:
        w = 2.0 * np.pi / spec.sway_period_s
        roll = roll + spec.sway_deg * DEG * np.sin(w * t)
        pitch = pitch + 0.5 * spec.sway_deg * DEG * np.sin(w / 0.73 * t + 1.0)
    return Profile(np.stack([roll, pitch, yaw], axis=1), vel)


def tilt_from_thrust(thrust_n: Arr, yaw: Arr) -> tuple[Arr, Arr]:
    """Roll and pitch (rad) that put body -z along ``thrust_n`` (N, 3, NED) at a given yaw.

    With C = Rz(yaw) Ry(pitch) Rx(roll), the body z axis in n rotated back by -yaw is
    (cos r sin p, -sin r, cos r cos p); equate it to -thrust / |thrust|.
    """
    z = -thrust_n / np.linalg.norm(thrust_n, axis=1, keepdims=True)
    cy, sy = np.cos(yaw), np.sin(yaw)
    wx = cy * z[:, 0] + sy * z[:, 1]
    wy = -sy * z[:, 0] + cy * z[:, 1]
    roll = -np.arcsin(np.clip(wy, -1.0, 1.0))
    pitch = np.arctan2(wx, z[:, 2])
    return roll, pitch


def multirotor_profile(t: Arr, spec: MultirotorSpec) -> Profile:
    """Multirotor: velocity and heading are independent (sideways/backwards flight).

    The thrust per unit mass is ``a - g + drag * v`` (no wind), and the airframe tilts so
    that body -z points along it: level in hover, tilted into the acceleration, and tilted
    forward in steady flight when ``drag_per_s > 0``.
    """
    comps = []
    accs = []
    for key in ("to_n_mps", "to_e_mps", "to_d_mps"):
        ev = tuple((e.t_s, e.dur_s, float(getattr(e, key))) for e in spec.vel)
        v, a = targets(t, 0.0, ev)
        comps.append(v)
        accs.append(a)
    vel = np.stack(comps, axis=1)
    acc = np.stack(accs, axis=1)
    yaw, _ = targets(t, spec.yaw0_deg * DEG, _turn_targets(spec.yaw0_deg * DEG, spec.turns))
    g = gravity(spec.lat_deg * DEG, spec.alt_m)
    thrust = acc + spec.drag_per_s * vel
    thrust[:, 2] -= g
    roll, pitch = tilt_from_thrust(thrust, yaw)
    return Profile(np.stack([roll, pitch, yaw], axis=1), vel)


def fixed_wing_profile(t: Arr, spec: FixedWingSpec) -> Profile:
    """Fixed-wing in coordinated flight through a steady wind (see :class:`FixedWingSpec`).

    Ground velocity = air velocity (horizontal part along the yaw, vertical part the climb
    rate) + wind.  The roll is solved exactly for zero lateral specific force at the given yaw
    and pitch: with ``u = Rz(yaw)^T f`` and ``w = Ry(pitch)^T u``, the body y component of
    ``Rx(roll)^T w`` vanishes for ``roll = atan2(w_y, -w_z)`` (the branch with the specific
    force along body -z, i.e. the lift up through the wing).
    """
    va, va_dot = targets(t, spec.airspeed0_mps, _abs_targets(spec.airspeed, 1.0))
    yaw, yaw_rate = targets(t, spec.yaw0_deg * DEG, _turn_targets(spec.yaw0_deg * DEG,
                                                                  spec.turns))
    hdot, hddot = targets(t, 0.0, _abs_targets(spec.climb, 1.0))
    vh = np.sqrt(va**2 - hdot**2)
    vh_dot = (va * va_dot - hdot * hddot) / vh
    cy, sy = np.cos(yaw), np.sin(yaw)
    vel = np.stack([vh * cy + spec.wind_n_mps, vh * sy + spec.wind_e_mps, -hdot], axis=1)
    acc = np.stack([vh_dot * cy - vh * yaw_rate * sy, vh_dot * sy + vh * yaw_rate * cy,
                    -hddot], axis=1)
    g = gravity(spec.lat_deg * DEG, spec.alt_m)
    f = acc.copy()
    f[:, 2] -= g
    load = np.linalg.norm(f, axis=1) / g
    pitch = np.arcsin(hdot / va) + spec.alpha_deg * DEG * load
    u_x = cy * f[:, 0] + sy * f[:, 1]
    u_y = -sy * f[:, 0] + cy * f[:, 1]
    cp, sp = np.cos(pitch), np.sin(pitch)
    w_y = u_y
    w_z = sp * u_x + cp * f[:, 2]
    roll = np.arctan2(w_y, -w_z)
    return Profile(np.stack([roll, pitch, yaw], axis=1), vel)


def modulation_angle(t: Arr, m: ModulationSpec) -> Arr:
    """Rotation-modulation angle (rad) at ``t``: dwell, rotate +angle, dwell, rotate back.

    Each rotation runs at ``rate_rps`` with raised-cosine rate ramps of ``ramp_s`` at both
    ends, so the rotation lasts ``angle / rate + ramp_s``.
    """
    amp = m.angle_deg * DEG
    r = m.rate_rps if amp >= 0.0 else -m.rate_rps
    tau = m.ramp_s
    t_rot = abs(amp) / m.rate_rps + tau
    period = 2.0 * (m.dwell_s + t_rot)
    ph = np.mod(t, period)
    half = ph >= m.dwell_s + t_rot
    u = np.where(half, ph - (m.dwell_s + t_rot), ph) - m.dwell_s  # time into the rotation
    a = np.zeros_like(t)
    if tau > 0.0:
        up = (u > 0.0) & (u <= tau)
        a[up] = 0.5 * r * (u[up] - tau / np.pi * np.sin(np.pi * u[up] / tau))
    mid = (u > tau) & (u <= t_rot - tau)
    a[mid] = 0.5 * r * tau + r * (u[mid] - tau)
    down = (u > max(tau, t_rot - tau)) & (u < t_rot)
    w = t_rot - u[down]
    if tau > 0.0:
        a[down] = amp - 0.5 * r * (w - tau / np.pi * np.sin(np.pi * w / tau))
    a[u >= t_rot] = amp
    return np.where(half, amp - a, a)


def ship_profile(t: Arr, spec: ShipSpec) -> Profile:
    """Ship on a course; the IMU body yaw adds the rotation-modulation angle.

    The ship's velocity follows its heading (no crab), so with modulation on, body yaw and
    GNSS course differ by the modulation angle.
    """
    ev = ((spec.static_s, spec.accel_s, spec.speed_mps),)
    speed, _ = targets(t, 0.0, ev)
    heading, _ = targets(t, spec.course_deg * DEG,
                         _turn_targets(spec.course_deg * DEG, spec.turns))
    vel = np.stack([speed * np.cos(heading), speed * np.sin(heading), np.zeros_like(t)], axis=1)
    roll = spec.roll_amp_deg * DEG * np.sin(TWO_PI * t / spec.roll_period_s)
    pitch = spec.pitch_amp_deg * DEG * np.sin(TWO_PI * t / spec.pitch_period_s)
    yaw = heading.copy()
    if spec.modulation.enabled:
        yaw += modulation_angle(t, spec.modulation)
    return Profile(np.stack([roll, pitch, yaw], axis=1), vel)


def build_profile(t: Arr, spec: TrajectorySpec, seed: int = 0) -> Profile:
    """Dispatch on the trajectory kind.  ``t``: (N,) seconds from the start; ``seed``: the
    run's (the only random part of a trajectory is a ground vehicle's wandering slip)."""
    if isinstance(spec, GroundSpec):
        return ground_profile(t, spec, seed)
    if isinstance(spec, MultirotorSpec):
        return multirotor_profile(t, spec)
    if isinstance(spec, ShipSpec):
        return ship_profile(t, spec)
    if isinstance(spec, FixedWingSpec):
        return fixed_wing_profile(t, spec)
    return static_profile(t, spec)


def dov_profile(t: Arr, spec: DovSpec) -> Arr:
    """Truth gravity disturbance (N, 3): xi (rad, north-south), eta (rad, east-west), dg_D (m/s^2).

    A sinusoid in time along the track for each component, plus a constant offset; zeros
    when disabled.
    """
    out = np.zeros((t.shape[0], 3))
    if not spec.enabled:
        return out
    out[:, 0] = ARCSEC * (spec.xi_offset_arcsec + spec.xi_amp_arcsec
                          * np.sin(TWO_PI * t / spec.xi_period_s + spec.xi_phase_deg * DEG))
    out[:, 1] = ARCSEC * (spec.eta_offset_arcsec + spec.eta_amp_arcsec
                          * np.sin(TWO_PI * t / spec.eta_period_s + spec.eta_phase_deg * DEG))
    out[:, 2] = spec.dg_mps2
    return out
