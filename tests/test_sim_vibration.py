"""``firmware_sim``'s airframe vibration (``[imu] vib_*``): a rotor's tone low-passed by the
sensor and read as point samples, so that it aliases as a rate message's samples do.

Checked against what sampling theory says of a pure tone: at ``rate_hz`` a tone of f Hz shows
at |f - k rate_hz|, with the amplitude the second-order low-pass leaves; at a multiple of the
rate it is a constant offset.  And the model adds only itself: every other draw of the run is
unchanged.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from firmware_sim.scenario import ImuSpec
from firmware_sim.sensors import corrupt_imu, vibration

RATE_HZ = 200.0
DT_S = 1.0 / RATE_HZ
N = 4000  # 20 s

QUIET = ImuSpec(rate_hz=RATE_HZ, gyro_bias_sigma_rps=0.0, accel_bias_sigma_mps2=0.0,
                arw_rad_per_sqrt_s=0.0, vrw_mps_per_sqrt_s=0.0)
AMP = (0.3, 0.2, 0.1, 4.0, 5.0, 6.0)  # rad/s x y z, m/s^2 x y z


def _tone(freq_hz: float, lpf_hz: float = 0.0, **kw: float) -> ImuSpec:
    return dataclasses.replace(QUIET, vib_freq_hz=freq_hz, vib_lpf_hz=lpf_hz,
                               vib_gyro_rps=AMP[:3], vib_accel_mps2=AMP[3:], **kw)


def _peak(x: np.ndarray) -> tuple[float, float]:
    """Frequency (Hz) and amplitude of the strongest line of ``x`` (a whole number of cycles
    of every frequency on the 0.05 Hz grid, so no leakage)."""
    spec = np.fft.rfft(x) / (len(x) / 2)
    k = int(np.argmax(np.abs(spec[1:]))) + 1
    return k * RATE_HZ / len(x), float(np.abs(spec[k]))


@pytest.mark.parametrize("freq_hz, alias_hz", [(170.0, 30.0), (230.0, 30.0), (455.0, 55.0)])
def test_a_tone_shows_at_its_alias_with_its_amplitude(freq_hz: float, alias_hz: float) -> None:
    """GIVEN a constant rotor frequency above the sample rate, no low-pass,
    WHEN sampled at 200 Hz,
    THEN every axis holds one line at |f - k * 200| Hz of the tone's amplitude."""
    vib = vibration(N, DT_S, _tone(freq_hz), seed=3)
    for j in range(6):
        f, a = _peak(vib[:, j])
        assert f == pytest.approx(alias_hz, abs=1e-9)
        assert a == pytest.approx(AMP[j], rel=1e-6)


def test_the_low_pass_leaves_the_second_order_gain() -> None:
    """GIVEN a 170 Hz tone through a 20 Hz second-order low-pass,
    THEN the 30 Hz alias has amplitude A / sqrt(1 + (170 / 20)^4) (1.4 % of A)."""
    vib = vibration(N, DT_S, _tone(170.0, lpf_hz=20.0), seed=3)
    gain = 1.0 / math.sqrt(1.0 + (170.0 / 20.0) ** 4)
    for j in range(6):
        assert _peak(vib[:, j])[1] == pytest.approx(AMP[j] * gain, rel=1e-6)


def test_a_tone_at_a_multiple_of_the_rate_is_a_constant_offset() -> None:
    """GIVEN the rotor at exactly twice the sample rate,
    THEN every sample of an axis is the same value, within its amplitude, and the axes'
    values differ (each axis has its own phase): a bias the gyro's data cannot tell."""
    vib = vibration(N, DT_S, _tone(2.0 * RATE_HZ), seed=3)
    assert np.ptp(vib, axis=0) == pytest.approx(np.zeros(6), abs=1e-9)
    assert np.all(np.abs(vib[0]) <= np.asarray(AMP) + 1e-12)
    assert len(set(np.round(vib[0] / np.asarray(AMP), 6))) == 6


def test_a_wandering_frequency_sweeps_the_alias_through_dc() -> None:
    """GIVEN a rotor at 200 +- 3 Hz (Gauss-Markov, 3 s) at 200 Hz,
    THEN the samples carry a slowly varying offset: their 1-s means spread over a good part
    of the amplitude, where a steady 30 Hz alias averages to nearly 0."""
    wander = vibration(N, DT_S, _tone(RATE_HZ, vib_freq_sd_hz=3.0, vib_freq_tau_s=3.0), 3)
    steady = vibration(N, DT_S, _tone(170.0), seed=3)
    means_w = wander[:, 0].reshape(-1, 200).mean(axis=1)
    means_s = steady[:, 0].reshape(-1, 200).mean(axis=1)
    assert np.ptp(means_w) > 0.5 * AMP[0]
    assert np.ptp(means_s) < 0.01 * AMP[0]


def test_vibration_adds_only_itself() -> None:
    """GIVEN a noisy, biased IMU with and without vibration (same seed),
    THEN the increments differ by exactly the vibration times dt, and without ``vib_*`` the
    model adds nothing (every recorded data set is unchanged)."""
    noisy = dataclasses.replace(QUIET, gyro_bias_sigma_rps=1e-3, accel_bias_sigma_mps2=0.05,
                                arw_rad_per_sqrt_s=1e-4, vrw_mps_per_sqrt_s=1e-2)
    inc_true = np.tile([0.0, 0.0, 1e-3, 0.0, 0.0, -9.8 * DT_S], (N, 1))
    plain, _ = corrupt_imu(inc_true, DT_S, noisy, seed=5)
    spec = dataclasses.replace(noisy, vib_freq_hz=150.0, vib_freq_sd_hz=10.0, vib_lpf_hz=20.0,
                               vib_gyro_rps=AMP[:3], vib_accel_mps2=AMP[3:])
    shaken, _ = corrupt_imu(inc_true, DT_S, spec, seed=5)
    assert np.allclose(shaken - vibration(N, DT_S, spec, seed=5) * DT_S, plain, rtol=0.0,
                       atol=1e-15)
    assert not np.allclose(shaken, plain)
    assert not np.any(vibration(N, DT_S, noisy, seed=5))


def test_a_negative_frequency_is_refused() -> None:
    """GIVEN ``imu.vib_freq_hz`` < 0 in a scenario, THEN loading it fails and names the key."""
    from firmware_sim import load_scenario

    with pytest.raises(ValueError, match=r"imu\.vib_freq_hz"):
        load_scenario("multirotor", {"imu.vib_freq_hz": -1.0})


def test_every_random_stream_has_its_own_number() -> None:
    """GIVEN the simulator's random streams (firmware_sim.sensors.STREAM_*, the randomize
    stream included),
    THEN no two share a number: two components drawing from one stream would be the same
    draws, not independent ones (the vibration once drew from the randomize stream)."""
    import firmware_sim.sensors as sensors

    streams = {k: v for k, v in vars(sensors).items() if k.startswith("STREAM_")}
    assert len(streams) >= 12, streams
    assert len(set(streams.values())) == len(streams), streams
