"""Start-up failures say which setting failed and what to do (issue 16 item 7): a port in use
names the config key and the fix, without Zenoh's Rust source paths."""

from __future__ import annotations

import socket
from pathlib import Path

from daemon_util import free_port, start_daemon, stop_daemon, write_config


def _run_until_exit(tmp_path: Path, sections: dict[str, dict[str, object]],
                    args: tuple[str, ...] = ()) -> tuple[int, str]:
    cfg = write_config(tmp_path / "navd.toml", {**sections, "daemon": {"warm_up": False}})
    log = tmp_path / "navd.log"
    proc = start_daemon(cfg, log, args=args)
    try:
        rc = proc.wait(120)
    finally:
        stop_daemon(proc)
    return rc, log.read_text()


def test_mavlink_port_in_use_names_the_key_and_the_fix(tmp_path: Path) -> None:
    """GIVEN a MAVLink listen port already bound by another socket,
    WHEN navd starts,
    THEN it exits 1 with a "startup failed" line naming [mavlink] listen, the port,
    "in use" and the --set mavlink.listen= fix."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        rc, text = _run_until_exit(tmp_path, {
            "mavlink": {"listen": f"udpin:127.0.0.1:{port}", "send": ""},
            "zenoh": {"enabled": False}})
    assert rc == 1, text
    line = next(ln for ln in text.splitlines() if "startup failed" in ln)
    assert "[mavlink] listen" in line and f"{port}" in line, line
    assert "in use" in line and "--set mavlink.listen=" in line, line


def test_zenoh_port_in_use_names_the_key_without_rust_paths(tmp_path: Path) -> None:
    """GIVEN a Zenoh listen port already taken by another listening socket,
    WHEN navd starts,
    THEN it exits 1 with a "startup failed" line naming [zenoh] listen and the
    --set zenoh.listen= fix, and the log holds no Rust source paths."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        rc, text = _run_until_exit(tmp_path, {
            "mavlink": {"listen": f"udpin:127.0.0.1:{free_port()}", "send": ""},
            "zenoh": {"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"],
                      "multicast_scouting": False}})
    assert rc == 1, text
    line = next(ln for ln in text.splitlines() if "startup failed" in ln)
    assert "[zenoh] listen" in line and "--set zenoh.listen=" in line, line
    assert ".rs:" not in text and "/.cargo/" not in text, text


def test_record_into_a_missing_directory_is_one_clear_line(tmp_path: Path) -> None:
    """GIVEN --record pointing into a directory that does not exist,
    WHEN navd starts,
    THEN it exits 1 with a "startup failed" line naming --record and asking whether the
    directory exists, and no traceback."""
    rc, text = _run_until_exit(tmp_path, {
        "mavlink": {"listen": f"udpin:127.0.0.1:{free_port()}", "send": ""},
        "zenoh": {"enabled": False}}, ("--record", str(tmp_path / "nowhere" / "r.navdrec")))
    assert rc == 1, text
    line = next(ln for ln in text.splitlines() if "startup failed" in ln)
    assert "--record" in line and "does its directory exist" in line, line
    assert "Traceback" not in text
