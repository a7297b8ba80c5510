"""kalman.multirotor_f: F's specific force on a multirotor (thrust along body z + rotor drag)."""

from __future__ import annotations

import math

import numpy as np

from navd.core.kalman import DRAG_PRIOR_PER_S, F_TAU_S, FLP_N, multirotor_f

G = 9.80665
T = 0.01


def _run(k_true: float, speed: np.ndarray, vrw: float, seed: int = 1,
         k_start: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A level airframe flying north at ``speed[i]`` (m/s, one value per 10 ms interval)
    with rotor drag -k_true v_b: F's horizontal specific force and kd after each interval."""
    rng = np.random.default_rng(seed)
    f_lp = np.zeros(FLP_N)
    f_lp[6] = F_TAU_S
    f_lp[7] = DRAG_PRIOR_PER_S if k_start is None else k_start
    mat = np.eye(3)
    f_n = np.zeros(3)
    out = np.zeros((speed.size, 2))
    for i, v in enumerate(speed):
        vel = np.array([v, 0.0, 0.0])
        n = rng.normal(0.0, vrw / math.sqrt(T), 3)
        multirotor_f(f_lp, mat, vel, -k_true * v + n[0], n[1], -G + n[2], T, vrw * vrw, f_n)
        out[i] = (f_n[0], f_lp[7])
    return out[:, 0], out[:, 1]


def test_the_drag_coefficient_is_learnt_from_speed_changes() -> None:
    """Speed swinging 0-6 m/s with the consumer VRW (0.3 m/s/sqrt(s)): kd settles on the
    airframe's 0.35 /s from the 0.2 /s prior, and on 0.1 /s for another airframe."""
    t = np.arange(0, 300.0, T)
    speed = 3.0 + 3.0 * np.sin(2 * math.pi * t / 20.0)
    for k_true in (0.35, 0.1):
        _, kd = _run(k_true, speed, 0.3)
        assert abs(float(np.mean(kd[-6000:])) - k_true) < 0.04, (k_true, kd[-6000:].mean())


def _low_pass(x: np.ndarray) -> np.ndarray:
    """The 1 s first-order low-pass of F before the drag model (body frame, no model)."""
    a = T / (F_TAU_S + T)
    y = np.zeros_like(x)
    acc = x[0]
    for i, xi in enumerate(x):
        acc += a * (xi - acc)
        y[i] = acc
    return y


def test_the_drag_is_not_delayed_by_the_low_pass() -> None:
    """Noise-free, kd known: 0.5 s after a speed step F's horizontal specific force is the
    drag; the plain 1 s low-pass of the same body specific force is still 1 m/s^2 short."""
    speed = np.concatenate([np.zeros(500), np.full(300, 5.0)])
    f_h, _ = _run(0.35, speed, 1e-6, k_start=0.35)
    i = 500 + 50
    assert abs(f_h[i] - (-0.35 * 5.0)) < 0.05, f_h[i]
    plain = _low_pass(-0.35 * speed)
    assert abs(plain[i] - (-0.35 * 5.0)) > 1.0, plain[i]


def test_a_hover_claims_less_than_the_low_passed_noise() -> None:
    """In a hover the energy of the low-pass's noise is scaled out of F's horizontal
    specific force (sqrt(1 - n^2 / |f_h|^2)): on average 1/e of it remains, against all of
    it in the plain low-pass of the same noise."""
    vrw = 0.3
    f_h, _ = _run(0.3, np.zeros(20000), vrw, seed=3)
    rng = np.random.default_rng(3)
    noise = np.array([rng.normal(0.0, vrw / math.sqrt(T), 3)[0] for _ in range(20000)])
    plain = _low_pass(noise)
    ratio = float(np.mean(f_h[1000:] ** 2)) / float(np.mean(plain[1000:] ** 2))
    assert ratio < 0.5, ratio
    assert ratio > 0.1, ratio  # the scaling is no blanket zero either


def test_the_estimator_reports_the_learnt_drag_coefficient() -> None:
    """mr_clean (the simulator's multirotor, drag 0.35 /s) through the default config on the
    multirotor profile: status drag_per_s is the learnt coefficient; None on a car."""
    from firmware_sim import generate, load_scenario
    from navd.config import load_config
    from navd.pipeline import build_estimator

    run = generate(load_scenario("multirotor", {"duration_s": 120.0}), seed=1, progress=False)
    est = build_estimator(load_config(None, ["filter.profile=multirotor"]))
    for s in run.samples():
        est.push(s)
    drag = est.status()["drag_per_s"]
    assert isinstance(drag, float) and 0.25 < drag < 0.4, drag
    assert build_estimator(load_config(None, [])).status()["drag_per_s"] is None
