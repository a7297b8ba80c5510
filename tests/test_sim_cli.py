"""``firmware-sim`` command line: writes complete runs, never half-written ones."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import firmware_sim.csvio
from firmware_sim import generate, load_scenario
from firmware_sim.__main__ import main, parse_set
from firmware_sim.csvio import read_table
from navd.core.rotation import log_so3
from navd.core.strapdown import strapdown_step


def test_generate_writes_csvs_meta_and_plot(tmp_path: Path) -> None:
    """GIVEN firmware-sim generate for a 20 s car480 run with jumps on and --plot,
    WHEN it runs,
    THEN the output folder holds exactly imu.csv, gnss.csv, truth.csv, meta.json and track.png
    (no temp left, not private), the tables match the in-memory run bit for bit in the
    documented column order, and meta.json records the seed, scenario and drawn biases."""
    out = tmp_path / "run"
    rc = main(["generate", "--scenario", "car480", "--seed", "1", "--out", str(out), "--quiet",
               "--plot", "--set", "duration_s=20", "--set", "gnss.jumps.enabled=true",
               "--set", "gnss.jumps.start_s=1.0"])
    assert rc == 0
    assert {p.name for p in out.iterdir()} == {"imu.csv", "gnss.csv", "truth.csv",
                                              "meta.json", "track.png"}
    assert [p.name for p in tmp_path.iterdir()] == ["run"]       # no temp left behind
    assert (out.stat().st_mode & 0o777) != 0o700

    run = generate(load_scenario("car480", overrides={
        "duration_s": 20.0, "gnss.jumps.enabled": True, "gnss.jumps.start_s": 1.0}), seed=1)
    imu = read_table(out / "imu.csv")
    assert list(imu) == ["t_us", "dt_us", "dtheta_x", "dtheta_y", "dtheta_z", "dvel_x",
                         "dvel_y", "dvel_z"]
    np.testing.assert_array_equal(imu["t_us"], run.imu_t_us)
    assert np.all(imu["dt_us"] == 10_000)
    got = np.stack([imu[k] for k in list(imu)[2:]], axis=1)
    np.testing.assert_array_equal(got, run.imu_inc)            # bit-exact round trip

    gnss = read_table(out / "gnss.csv")
    assert list(gnss)[:10] == ["t_us", "lat_deg", "lon_deg", "alt_m", "vel_n", "vel_e",
                               "vel_d", "h_acc_m", "v_acc_m", "vel_acc_mps"]
    for k, v in run.gnss.items():
        np.testing.assert_array_equal(gnss[k], v)
    assert gnss["outlier"].any()

    truth = read_table(out / "truth.csv")
    assert list(truth)[:10] == ["t_us", "lat_deg", "lon_deg", "alt_m", "vel_n", "vel_e",
                                "vel_d", "roll_deg", "pitch_deg", "yaw_deg"]
    assert truth["t_us"].shape[0] == imu["t_us"].shape[0] + 1
    np.testing.assert_allclose(np.radians(truth["yaw_deg"]), run.truth_euler[:, 2],
                               atol=1e-15)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["seed"] == 1
    assert meta["scenario"]["duration_s"] == 20.0
    np.testing.assert_array_equal(meta["gyro_bias_rps"], run.gyro_bias_rps)


def test_csv_increments_replay_truth(tmp_path: Path) -> None:
    """GIVEN a 40 s car480 run whose error-free IMU increments are written to CSV,
    WHEN the increments read back are integrated by strapdown_step from the true start state,
    THEN the final attitude matches the truth within 1e-9 rad and velocity within 1e-6 m/s."""
    run = generate(load_scenario("car480", overrides={"duration_s": 40.0}), seed=1)
    run.imu_inc = run.imu_inc_true          # write the error-free data
    run.write_csv(tmp_path)
    imu = read_table(tmp_path / "imu.csv")
    truth = read_table(tmp_path / "truth.csv")
    inc = np.stack([imu[k] for k in list(imu)[2:]], axis=1)
    c = run.truth_mat_nb[0].copy()
    v = run.truth_vel_n[0].copy()
    p = np.array([np.radians(truth["lat_deg"][0]), np.radians(truth["lon_deg"][0]),
                  truth["alt_m"][0]])
    prev = np.zeros(6)
    work = np.zeros((8, 3, 3))
    dov = np.zeros(3)
    for k in range(inc.shape[0]):
        strapdown_step(c, v, p, dov, inc[k], prev, imu["dt_us"][k] * 1e-6, True, work)
        prev[:] = inc[k]
    assert np.linalg.norm(log_so3(c.T @ run.truth_mat_nb[-1])) < 1e-9
    assert np.abs(v - [truth["vel_n"][-1], truth["vel_e"][-1], truth["vel_d"][-1]]).max() < 1e-6


def test_bad_scenario_leaves_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a scenario file with an unknown key, or a --set value of the wrong type,
    WHEN firmware-sim generate runs,
    THEN it returns 2, the error names the field (with the right name and unit), and no
    output folder is left behind."""
    bad = tmp_path / "bad.toml"
    text = (Path(firmware_sim.__file__).parent / "scenarios" / "static.toml").read_text()
    bad.write_text(text.replace("rate_hz = 100.0", "rate_hz = 100.0\nrate_khz = 1.0"))
    out = tmp_path / "out" / "run"
    rc = main(["generate", "--scenario", str(bad), "--seed", "1", "--out", str(out)])
    assert rc == 2
    err = capsys.readouterr().err
    assert "imu.rate_khz: unknown field" in err and "imu.rate_hz" in err and "Hz" in err
    assert not out.exists()
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    rc = main(["generate", "--scenario", "static", "--seed", "1", "--out", str(out),
               "--set", "imu.arw_rad_per_sqrt_s=fast"])
    assert rc == 2
    assert "imu.arw_rad_per_sqrt_s: expected a number in rad/sqrt(s)" in capsys.readouterr().err
    assert not out.exists()


def test_failure_while_writing_leaves_nothing(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN a write_table that fails with "disk full" on its second call,
    WHEN firmware-sim generate runs,
    THEN the OSError propagates and the parent folder is left empty."""
    real = firmware_sim.csvio.write_table
    calls = []

    def flaky(*args: object, **kw: object) -> None:
        calls.append(1)
        if len(calls) == 2:
            raise OSError("disk full")
        real(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(firmware_sim.csvio, "write_table", flaky)
    out = tmp_path / "run"
    with pytest.raises(OSError, match="disk full"):
        main(["generate", "--scenario", "static", "--seed", "1", "--out", str(out), "--quiet",
              "--set", "duration_s=2"])
    assert list(tmp_path.iterdir()) == []


def test_existing_output_needs_force(tmp_path: Path) -> None:
    """GIVEN an output folder that already holds a file,
    WHEN firmware-sim generate runs without and then with --force,
    THEN without it returns 2 and keeps the file; with it returns 0 and replaces the folder's
    contents with the new run."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.txt").write_text("keep")
    args = ["generate", "--scenario", "static", "--seed", "1", "--out", str(out), "--quiet",
            "--set", "duration_s=2"]
    assert main(args) == 2
    assert (out / "old.txt").exists()
    assert main([*args, "--force"]) == 0
    assert not (out / "old.txt").exists() and (out / "imu.csv").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_parse_set() -> None:
    """GIVEN --set strings of the form key=value,
    WHEN parse_set reads them,
    THEN each value is parsed as TOML (int, bool, list, quoted string, float) and a bare
    word is kept as a string."""
    assert parse_set(["a.b=1", "c=true", "d=fast", "e=[1, 2]", 'f="x"', "g=2.5"]) == {
        "a.b": 1, "c": True, "d": "fast", "e": [1, 2], "f": "x", "g": 2.5}


def test_module_entry_point(tmp_path: Path) -> None:
    """GIVEN python -m firmware_sim run as a subprocess,
    WHEN it is asked to list scenarios and to generate a 3 s multirotor run,
    THEN both exit 0, the list names car480 and ship_dov, and the three CSVs are written."""
    r = subprocess.run([sys.executable, "-m", "firmware_sim", "list"], capture_output=True,
                       text=True, check=False, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "car480" in r.stdout and "ship_dov" in r.stdout
    out = tmp_path / "cli"
    r = subprocess.run([sys.executable, "-m", "firmware_sim", "generate", "--scenario",
                        "multirotor", "--seed", "4", "--out", str(out), "--set",
                        "duration_s=3"], capture_output=True, text=True, check=False,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert (out / "imu.csv").exists() and (out / "gnss.csv").exists()
    assert (out / "truth.csv").exists()
