@pytest.mark.parametrize("yaw0_deg", [-157.5, -112.5, -67.5, -22.5, 22.5, 67.5, 112.5, 157.5])
def test_bank_converges_from_every_starting_yaw(yaw0_deg: float) -> None:
    """GIVEN the multirotor scenario (first 60 s: hover, then a 5 m/s leg north from 35 s)
    flown with the nose anywhere on the circle, while the filter starts at yaw 0,
    WHEN it runs with the multirotor profile,
    THEN by 45 s the bank's composite yaw is within 3 of its sigmas of the truth, its sigma
    is below 10 deg (so within 30 deg: the right one of the eight hypotheses won; the
    scenario's IMU is seed 001's, VRW 0.3 m/s/sqrt(s), ~100x a consumer part's), and the
    heading was never aligned more than 10 deg wrong."""
    run = multirotor(1, 60.0, yaw0_deg)
    e = Estimator(cfg("filter.profile=multirotor"))
    rows = _run(run, e)
    t, err, sd, aligned = (np.array(c) for c in zip(*rows, strict=True))
    k = int(np.searchsorted(t, 45.0))
    assert abs(err[k]) < 3.0 * sd[k]
    assert math.degrees(sd[k]) < 10.0
    assert not np.any(aligned.astype(bool) & (np.abs(err) > math.radians(10.0)))


