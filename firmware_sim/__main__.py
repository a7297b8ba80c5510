"""``firmware-sim``: generate replay files from a scenario.

    firmware-sim generate --scenario car480 --seed 1 --out runs/car480-1 [--plot]
                          [--set gnss.jumps.enabled=true --set duration_s=60] [--force]
    firmware-sim list
    firmware-sim stream --scenario car480 --transport mavlink|dronecan --rate-factor K
                        [--target udp:127.0.0.1:14560] [--interface socketcan --channel vcan0]
                        [--seed N] [--set duration_s=60] [--truth-out FILE]

The run is written into a hidden temporary directory beside ``--out`` and renamed into place
only when every file is complete, so a failure never leaves a half-written output folder.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from firmware_sim.scenario import ScenarioError, builtin_scenarios, load_scenario
from navd.config import ConfigError, parse_override

EXIT_USAGE = 2


def parse_set(items: Sequence[str]) -> dict[str, Any]:
    """``key=value`` pairs; values are TOML (``60``, ``true``, ``[1, 2]``, ``"x"``), else text
    (parsed as navd's ``--set``: :func:`navd.config.parse_override`)."""
    out: dict[str, Any] = {}
    for item in items:
        try:
            parts, value = parse_override(item, min_depth=1)
        except ConfigError:
            raise ScenarioError(f"--set {item!r}: expected key=value") from None
        out[".".join(parts)] = value
    return out


def _non_empty_dir(p: Path) -> bool:
    return p.is_dir() and any(p.iterdir())


def _install(tmp: Path, out: Path) -> None:
    """Move the finished ``tmp`` directory to ``out`` (replacing an old run, if any)."""
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        os.replace(tmp, out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
    os.replace(out, old / out.name)
    os.replace(tmp, out)
    shutil.rmtree(old, ignore_errors=True)


def cmd_generate(args: argparse.Namespace) -> int:
    from firmware_sim.run import generate

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        print(f"firmware-sim: --out {out} exists and is not a directory", file=sys.stderr)
        return EXIT_USAGE
    if _non_empty_dir(out) and not args.force:
        print(f"firmware-sim: --out {out} is not empty (use --force to replace it)",
              file=sys.stderr)
        return EXIT_USAGE
    # validate everything before touching the file system
    sc = load_scenario(args.scenario, parse_set(args.set))
    run = generate(sc, args.seed, progress=not args.quiet)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        # mkdtemp makes the directory private (0700); the result is an ordinary output folder
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o777 & ~umask)
        run.write_csv(tmp, progress=not args.quiet)
        if args.plot:
            from firmware_sim.plot import plot_track

            plot_track(run, tmp / "track.png")
        _install(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if not args.quiet:
        n_out = int(run.gnss["outlier"].sum())
        print(f"{sc.name}: {run.imu_t_us.shape[0]} IMU samples, {run.gnss['t_us'].shape[0]} "
              f"GNSS epochs ({n_out} with velocity jumps) -> {out}", file=sys.stderr)
    return 0


def cmd_list(_: argparse.Namespace) -> int:
    names = builtin_scenarios()
    width = max(len(n) for n in names)
    for name in names:
        sc = load_scenario(name)
        print(f"{name:{width}s} {sc.duration:8.0f} s  {sc.description}")
    return 0


def cmd_stream(args: argparse.Namespace) -> int:
    import signal

    from firmware_sim.run import generate
    from firmware_sim.stream import (
        dronecan_events,
        mavlink_events,
        stream_dronecan,
        stream_mavlink_udp,
        write_truth_attitude,
    )

    if args.rate_factor < 0:
        print("firmware-sim: --rate-factor must be >= 0 (0 = as fast as possible)",
              file=sys.stderr)
        return EXIT_USAGE
    sc = load_scenario(args.scenario, parse_set(args.set))
    run = generate(sc, args.seed)
    if args.truth_out:
        write_truth_attitude(run, args.truth_out)
    # SIGTERM ends the stream like Ctrl-C: print what was sent, exit quietly
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    what = (f"{sc.name} -> {args.target}" if args.transport == "mavlink"
            else f"{sc.name} -> {args.interface}:{args.channel}")
    if not args.quiet:
        print(f"firmware-sim: streaming {what} at x{args.rate_factor:g} "
              f"({sc.duration:.0f} s of sensor time)", file=sys.stderr)
    try:
        if args.transport == "mavlink":
            try:
                events = mavlink_events(run, args.imu_message, args.gnss_message,
                                        args.sysid, args.compid)
                st = stream_mavlink_udp(events, args.target, args.rate_factor)
            except ValueError as exc:
                print(f"firmware-sim: {exc}", file=sys.stderr)
                return EXIT_USAGE
        else:
            import can

            try:
                bus = can.Bus(interface=args.interface, channel=args.channel)
            except (can.CanError, OSError, ValueError) as exc:
                print(f"firmware-sim: cannot open CAN {args.interface}:{args.channel}: {exc}",
                      file=sys.stderr)
                return 1
            try:
                st = stream_dronecan(dronecan_events(run, args.node_id), bus,
                                     args.rate_factor)
            finally:
                bus.shutdown()
    except KeyboardInterrupt:
        if not args.quiet:
            print("firmware-sim: stream interrupted", file=sys.stderr)
        return 130
    if not args.quiet:
        print(f"firmware-sim: sent {st.imu} IMU + {st.gnss} GNSS messages ({st.packets} "
              f"{'datagrams' if args.transport == 'mavlink' else 'CAN frames'}) in "
              f"{st.wall_s:.1f} s; worst lateness {st.max_late_s * 1e3:.1f} ms",
              file=sys.stderr)
    return 0


class _DefaultsFormatter(argparse.HelpFormatter):
    """Appends "(default: X)" where an option has a real default; argparse's own
    ArgumentDefaultsHelpFormatter also prints None, False and [] for flags and lists."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if action.default in (None, False, [], argparse.SUPPRESS) or "%(default)" in text:
            return text
        return f"{text} (default: %(default)s)"


def build_parser() -> argparse.ArgumentParser:
    # plain words: the module docstring's first line is reST ("``firmware-sim``")
    p = argparse.ArgumentParser(
        prog="firmware-sim",
        description="firmware-sim: generate replay files from a scenario (generate), list the "
                    "built-in scenarios (list), or send a scenario's sensor data to a running "
                    "daemon over MAVLink UDP or DroneCAN (stream).")
    sub = p.add_subparsers(dest="command", required=True)
    g = sub.add_parser("generate", help="simulate a scenario and write imu/gnss/truth CSVs")
    g.add_argument("--scenario", required=True, help="built-in name or path to a .toml file")
    g.add_argument("--seed", type=int, required=True, help="non-negative integer seed")
    g.add_argument("--out", required=True, help="output directory (created)")
    g.add_argument("--plot", action="store_true", help="also write track.png")
    g.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario field by dotted key, e.g. gnss.rate_hz=5")
    g.add_argument("--force", action="store_true", help="replace a non-empty --out")
    g.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    g.set_defaults(func=cmd_generate)
    ls = sub.add_parser("list", help="list the built-in scenarios")
    ls.set_defaults(func=cmd_list)
    # defaults shown: a user wiring the stream to a daemon needs the target, messages, IDs
    st = sub.add_parser(
        "stream", help="send a scenario over MAVLink UDP or DroneCAN in (scaled) real time",
        formatter_class=_DefaultsFormatter,
        description="Simulate a scenario and send its IMU samples and GNSS fixes, as a "
                    "sensor's firmware would, over MAVLink UDP or DroneCAN, paced on the "
                    "sensor clock (--rate-factor 1: real time; car480 then takes 480 s). "
                    "Ctrl-C or SIGTERM ends it with a summary of what was sent.")
    st.add_argument("--scenario", required=True, help="built-in name or path to a .toml file")
    st.add_argument("--transport", choices=["mavlink", "dronecan"], default="mavlink",
                    help="link to send on")
    st.add_argument("--rate-factor", type=float, default=1.0,
                    help="sensor seconds per wall second: 1 real time, 0 as fast as possible")
    st.add_argument("--target", default="udp:127.0.0.1:14560",
                    help="MAVLink: UDP destination udp:HOST:PORT")
    st.add_argument("--imu-message", default="HIGHRES_IMU",
                    choices=["HIGHRES_IMU", "SCALED_IMU"], help="MAVLink IMU message")
    st.add_argument("--gnss-message", default="GPS_INPUT",
                    choices=["GPS_INPUT", "GPS_RAW_INT", "HIL_GPS"],
                    help="MAVLink GNSS message")
    st.add_argument("--sysid", type=int, default=1, help="MAVLink source system ID")
    st.add_argument("--compid", type=int, default=1, help="MAVLink source component ID")
    st.add_argument("--interface", default="socketcan", help="DroneCAN: python-can interface")
    st.add_argument("--channel", default="vcan0", help="DroneCAN: python-can channel")
    st.add_argument("--node-id", type=int, default=42, help="DroneCAN: sensor node ID")
    st.add_argument("--seed", type=int, default=1, help="non-negative integer seed")
    st.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a scenario field, e.g. duration_s=60")
    st.add_argument("--truth-out", metavar="FILE",
                    help="write truth position/attitude CSV here before streaming")
    st.add_argument("--quiet", action="store_true", help="no start/summary lines")
    st.set_defaults(func=cmd_stream)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "seed", 0) < 0:
        print("firmware-sim: --seed must be >= 0", file=sys.stderr)
        return EXIT_USAGE
    try:
        rc: int = args.func(args)
    except ScenarioError as e:
        print(f"firmware-sim: {e}", file=sys.stderr)
        return EXIT_USAGE
    return rc


if __name__ == "__main__":
    sys.exit(main())
