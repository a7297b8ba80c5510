"""[bias_store]: learned IMU biases survive a restart; a bad file is refused, never used."""

from __future__ import annotations

import asyncio
import json
import math
import time
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from daemon_util import car_run

from navd.config import EstimatorConfig, build_section, load_config
from navd.config.daemon import BiasStoreSection, DaemonConfig
from navd.core.estimator import Estimator
from navd.daemon import bias_store
from navd.daemon.daemon import Daemon
from navd.daemon.service import SdNotifier
from navd.io.recording import RecordingReader

NOW = 1.8e9  # 2027-01-15


def _store(**keys: Any) -> BiasStoreSection:
    """A [bias_store] section from TOML keys (units in the names)."""
    return build_section(BiasStoreSection, "bias_store", keys)


def _apply(tables: dict[str, Any], s: BiasStoreSection, now: float
           ) -> tuple[dict[str, Any], str]:
    return bias_store.apply(tables, s, EstimatorConfig.from_dict(tables).imu, now)


@cache
def learned() -> tuple[Estimator, Any]:
    """An estimator after 300 s of the car drive, and the run's true biases."""
    run = car_run(300.0, seed=2)
    est = Estimator(EstimatorConfig.from_dict(load_config(None, [])))
    for s in run.samples():
        est.push(s)
    return est, run


def _record(**changes: Any) -> dict[str, Any]:
    rec: dict[str, Any] = {"schema": 1, "imu": "", "saved_unix_s": NOW - 3600.0,
                           "navd": "0", "gyro_bias_deg_per_h": [3.0, -2.0, 1.0],
                           "gyro_bias_sd_deg_per_h": [0.5, 0.5, 0.8],
                           "accel_bias_mg": [1.5, -0.5, 2.0], "accel_bias_sd_mg": [0.3, 0.3, 0.2]}
    rec.update(changes)
    return rec


def _write(path: Path, rec: Any) -> Path:
    path.write_text(json.dumps(rec) if not isinstance(rec, str) else rec)
    return path


def test_snapshot_saves_what_the_drive_learned_and_the_next_start_uses_it(tmp_path: Path
                                                                           ) -> None:
    """GIVEN an estimator after a 300 s car drive,
    WHEN a snapshot is taken with a too-strict sigma limit, then a loose one, saved, and
    applied at the next start,
    THEN the strict one saves nothing; the file is written without leftovers, loaded as the
    IMU biases with sigma = learned (+) repeatability, and the gyro bias is nearer truth."""
    est, run = learned()
    strict = _store(path=str(tmp_path / "b.json"), max_accel_sd_mg=0.01)
    assert bias_store.snapshot(est, strict, NOW) is None  # not yet known that well
    s = _store(path=str(tmp_path / "b.json"), max_accel_sd_mg=10.0,
                         max_gyro_sd_deg_per_h=20.0)
    rec = bias_store.snapshot(est, s, NOW)
    assert rec is not None
    assert rec["mount_deg"] == [0.0, 0.0, 0.0]
    bias_store.save(s.path, rec)
    assert [p.name for p in tmp_path.iterdir()] == ["b.json"]  # no temporary left behind
    tables, state = _apply({}, s, NOW + 60.0)
    assert state.startswith("loaded"), state
    cfg = EstimatorConfig.from_dict(tables)
    assert np.allclose(cfg.imu.accel_bias, est.bias_a) and np.allclose(cfg.imu.gyro_bias,
                                                                       est.bias_g)
    # the prior is the learned 1-sigma combined with the turn-on repeatability
    a_sd = math.hypot(max(rec["accel_bias_sd_mg"]), s.repeat_accel_sd / 9.80665e-3)
    assert cfg.imu.accel_bias_sd == pytest.approx(a_sd * 9.80665e-3)
    # and what was learned is closer to the truth than the zero a fresh start assumes
    assert (np.linalg.norm(cfg.imu.gyro_bias - run.gyro_bias_rps)
            < np.linalg.norm(run.gyro_bias_rps))


def test_a_loaded_file_never_raises_the_configured_prior(tmp_path: Path) -> None:
    """GIVEN a stored accel bias sigma of 3 mg and a configured prior of 1 mg,
    WHEN the store is applied,
    THEN the file is loaded with its biases but the prior sigma stays 1 mg."""
    s = _store(path=str(_write(tmp_path / "b.json", _record(
        accel_bias_sd_mg=[3.0, 3.0, 3.0]))))
    tables, state = _apply({"imu": {"accel_bias_sd_mg": 1.0}}, s, NOW)
    assert state.startswith("loaded")
    assert tables["imu"]["accel_bias_sd_mg"] == 1.0
    assert tables["imu"]["accel_bias_mg"] == [1.5, -0.5, 2.0]


@pytest.mark.parametrize(("content", "why"), [
    ("{not json", "unreadable"),
    (_record(schema=2), "schema 2"),
    (_record(imu="other-imu"), "written for IMU 'other-imu'"),
    (_record(saved_unix_s=NOW - 40 * 86_400.0), "days old"),
    (_record(saved_unix_s=NOW + 3 * 86_400.0), "in the future"),
    (_record(saved_unix_s="yesterday"), "saved_unix_s"),
    (_record(accel_bias_mg=[1.0, float("nan"), 0.0]), "accel_bias_mg is not finite"),
    (_record(gyro_bias_deg_per_h=[1.0, 2.0]), "gyro_bias_deg_per_h is not a list of 3"),
    (_record(accel_bias_sd_mg=[0.0, 0.3, 0.3]), "not positive"),
    (_record(accel_bias_mg=[40.0, 0.0, 0.0]), "beyond 5 sigma"),
    (_record(mount_deg=[0.0, 0.0, 90.0]), "mounted at [0.00, 0.00, 90.00] deg"),
    ([1, 2, 3], "schema ?"),
])
def test_bad_files_are_refused_with_the_cause_and_change_nothing(
        tmp_path: Path, content: Any, why: str) -> None:
    """GIVEN a bias file that is unreadable, of another schema or IMU, too old, from the
    future, or with a bad, non-finite, short, non-positive or implausible value,
    WHEN the store is applied,
    THEN it is refused with the cause in the state and the config tables are returned as is."""
    s = _store(path=str(_write(tmp_path / "b.json", content)))
    tables = {"imu": {"accel_bias_sd_mg": 5.0}}
    out, state = _apply(tables, s, NOW)
    assert out is tables
    assert state.startswith("refused") and why in state, state


def test_a_file_is_used_only_for_the_imu_mount_it_was_learnt_in(tmp_path: Path) -> None:
    """GIVEN a bias file written with the IMU mounted at (180, 0, 90) deg, and an older file
    that names no mount,
    WHEN the store is applied with that mount configured, and with none,
    THEN the first is loaded with the mount and refused without it (its axes are other
    axes); the older one is loaded without a mount and refused with one."""
    mounted = {"imu": {"mount_roll_deg": 180.0, "mount_yaw_deg": 90.0}}
    turned = _store(path=str(_write(tmp_path / "m.json",
                                    _record(mount_deg=[180.0, 0.0, 90.0]))))
    old = _store(path=str(_write(tmp_path / "o.json", _record())))
    assert _apply(mounted, turned, NOW)[1].startswith("loaded")
    assert "mounted at [180.00, 0.00, 90.00] deg" in _apply({}, turned, NOW)[1]
    assert _apply({}, old, NOW)[1].startswith("loaded")
    assert "mounted at [0.00, 0.00, 0.00] deg" in _apply(mounted, old, NOW)[1]


def test_off_and_absent() -> None:
    """GIVEN a store with no path, or a path to a file that does not exist,
    WHEN the store is applied,
    THEN the config is unchanged and the state is "off", resp. "none yet: <path>"."""
    assert _apply({}, _store(), NOW) == ({}, "off")
    out, state = _apply({}, _store(path="/nonexistent/b.json"), NOW)
    assert out == {} and state == "none yet: /nonexistent/b.json"


def _daemon(tmp_path: Path, *extra: str) -> Daemon:
    cfg = DaemonConfig.from_dict(load_config(None, [
        'mavlink.listen="udpin:127.0.0.1:0"', 'mavlink.send=""', "zenoh.enabled=false",
        f'bias_store.path="{tmp_path / "bias.json"}"', *extra]))
    return Daemon(cfg, notifier=SdNotifier({}), handle_signals=False)


def test_daemon_loads_saves_and_records_the_biases_it_started_with(tmp_path: Path) -> None:
    """GIVEN a daemon with an empty bias store,
    WHEN it saves before learning, a daemon with a driven estimator saves, and a third starts
    and records,
    THEN nothing is written at first, then the file is saved now; the third daemon loads those
    biases and its recording header carries them."""
    d = _daemon(tmp_path)
    assert d.status()["bias_store"].startswith("none yet")
    est, _ = learned()
    assert not d.save_biases()  # nothing learned yet: the file is not written
    assert not (tmp_path / "bias.json").exists()
    d.est = est  # as if the daemon had run the drive
    d2 = _daemon(tmp_path, "bias_store.max_accel_sd_mg=10.0",
                 "bias_store.max_gyro_sd_deg_per_h=20.0")
    d2.est = est
    assert d2.save_biases() and d2.status()["bias_store"].startswith("saved")
    saved = json.loads((tmp_path / "bias.json").read_text())
    assert saved["saved_unix_s"] == pytest.approx(time.time(), abs=60.0)

    d3 = _daemon(tmp_path)
    assert d3.status()["bias_store"].startswith("loaded")
    assert np.allclose(d3.cfg.estimator.imu.accel_bias, est.bias_a)
    assert np.allclose(d3.est.cfg.imu.gyro_bias, est.bias_g)
    # a recording made now carries the biases in its config: replays start the same way
    rec_path = tmp_path / "run.navrec"
    d3.record_path = str(rec_path)
    asyncio.run(_open_close(d3))
    header_imu = RecordingReader(rec_path).config["imu"]
    assert header_imu["accel_bias_mg"] == saved["accel_bias_mg"]


async def _open_close(d: Daemon) -> None:
    await d._open()
    d._close()


def test_unwritable_store_is_warned_not_fatal(tmp_path: Path,
                                              caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN a daemon with learned biases and a store path in a directory that does not exist,
    WHEN it saves the biases,
    THEN the save fails and "cannot save learned IMU biases" is logged, without raising."""
    d = _daemon(tmp_path, f'bias_store.path="{tmp_path / "missing-dir" / "b.json"}"',
                "bias_store.max_accel_sd_mg=10.0", "bias_store.max_gyro_sd_deg_per_h=20.0")
    d.est, _ = learned()
    assert not d.save_biases()
    assert "cannot save learned IMU biases" in caplog.text
