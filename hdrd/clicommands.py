"""The ``hdrd`` commands: each one's name, the function that implements it (``module:function``,
imported only when the command runs) and its options, registered in :data:`COMMANDS` for
:mod:`hdrd.cli` to build its parser from. Light, like the command line: a default that lives
in a heavy module is repeated here, and a test keeps the two equal.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

from hdrd.cliargs import (
    DRIVES,
    HEADING_REFS,
    HEADING_UNITS,
    OMEGA_UNITS,
    SPEED_UNITS,
    TIME_UNITS,
    address,
    bias_group,
    config,
    delimiter,
    fleet,
    input_limits,
    log_format,
    log_level,
    method,
    port,
    strict,
)
from hdrd.io.wire.protocol import PROTOCOLS

Adder = Callable[[argparse.ArgumentParser], None]
COMMANDS: dict[str, tuple[str, str, Adder]] = {}


def command(name: str, target: str, help: str) -> Callable[[Adder], Adder]:
    def register(add: Adder) -> Adder:
        COMMANDS[name] = (target, help, add)
        return add

    return register


@command("run", "hdrd.commands.run:main", "run the daemon: gyro -> HDR -> publishers")
def _run(p: argparse.ArgumentParser) -> None:
    """Long because it is a flat list of the daemon's options, read best in one place."""
    config(p)
    port(p)
    bias_group(p, calibrate_seconds=False)
    p.add_argument(
        "--udp",
        action="append",
        metavar="HOST:PORT",
        help="send JSON lines here (repeatable; IPv6 as [::1]:PORT); default output.udp, none",
    )
    p.add_argument(
        "--nmea-udp",
        action="append",
        metavar="HOST:PORT",
        help="send NMEA 0183 here (repeatable); default output.nmea_udp, none",
    )
    p.add_argument(
        "--nmea-ths",
        action="store_true",
        default=None,
        help="also send $HNTHS (default output.nmea_ths, off)",
    )
    p.add_argument(
        "--stdout",
        action="store_true",
        default=None,
        help="print JSON lines to stdout, rounded on a terminal (default output.stdout, off; on "
        "when no UDP destination is configured)",
    )
    p.add_argument(
        "--simulate", action="store_true", help="read the built-in simulated gyro, no hardware"
    )
    p.add_argument(
        "--drive",
        choices=DRIVES,
        metavar="DRIVE",
        help="with --simulate: the drive (default simulate.drive, mixed)",
    )
    p.add_argument(
        "--speedup",
        type=float,
        metavar="X",
        help="with --simulate: play the drive X times faster (default simulate.speedup, 1)",
    )
    p.add_argument(
        "--clock-rate",
        type=float,
        metavar="X",
        help="the device clock keeps X device seconds per wall second: 1 for the gyro, X for "
        "`hdrd fakegyro --speedup X`, 0 = not checked (default device.clock_rate, 1)",
    )
    p.add_argument(
        "--heading0",
        type=float,
        metavar="DEG",
        help="compass heading at start, deg (default output.heading0_deg, 0)",
    )
    method(p)
    p.add_argument(
        "--gpsd",
        metavar="HOST[:PORT]",
        nargs="?",
        const="127.0.0.1:2947",
        help="aid with GPS from gpsd (default: gpsd.enabled, off; given alone: 127.0.0.1:2947; "
        "IPv6 as [::1]:2947)",
    )
    p.add_argument(
        "--log-format",
        choices=("auto", "json", "console"),
        help="log format on stderr (default log.format, auto: JSON when stderr is not a terminal)",
    )
    log_level(p)


@command("calibrate", "hdrd.commands.calibrate:main", "measure the static bias at standstill")
def _calibrate(p: argparse.ArgumentParser) -> None:
    config(p)
    port(p)
    p.add_argument(
        "--seconds",
        type=float,
        metavar="S",
        help="averaging time Tbias, s (default calibration.t_bias_s, 30, the paper's)",
    )
    p.add_argument(
        "--bias-file",
        metavar="PATH",
        help="where to write (default calibration.bias_file, else $STATE_DIRECTORY or "
        "/var/lib/hdrd)/bias.yaml",
    )
    p.add_argument(
        "--simulate", action="store_true", help="calibrate on the built-in simulated gyro"
    )
    log_level(p)


@command("tail", "hdrd.commands.tail:main", "print what the daemon publishes (like gpspipe -w)")
def _tail(p: argparse.ArgumentParser) -> None:
    address(p, "--listen", "127.0.0.1:10110", "UDP address to listen on")
    p.add_argument(
        "--raw",
        action="store_true",
        help="print the JSON lines as received (on a terminal, numbers rounded)",
    )
    p.add_argument(
        "--count", type=int, metavar="N", help="exit after N messages (default: until stopped)"
    )


@command("web", "hdrd.commands.web:main", "a live page of heading, mode and health (read only)")
def _web(p: argparse.ArgumentParser) -> None:
    address(p, "--listen", "127.0.0.1:8080", "the page's address (not loopback: a warning)")
    address(
        p,
        "--udp",
        "127.0.0.1:10110",
        "UDP address to receive the daemon's JSON on (not loopback: a warning)",
    )
    p.add_argument(
        "--max-clients",
        type=int,
        default=16,
        metavar="N",
        help="viewers at once (fewer if the descriptor limit allows fewer: a warning)",
    )


@command("fakegyro", "hdrd.commands.fakegyro:main", "a fake gyro on a pty (for tests and demos)")
def _fakegyro(p: argparse.ArgumentParser) -> None:
    """Long because it is a flat list of the fake gyro's options, read best in one place."""
    p.add_argument(
        "--drive",
        default="mixed",
        help="drive profile: city|suburbs|rural|highway|mixed|standstill|constant (default mixed)",
    )
    p.add_argument(
        "--rate-dps",
        type=float,
        default=0.0,
        metavar="DPS",
        help="with --drive constant: true yaw rate",
    )
    p.add_argument(
        "--minutes",
        type=float,
        default=20.0,
        metavar="MIN",
        help="length of the drive, min (default 20)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=1,
        metavar="N",
        help="random seed of the drive, noise and injected faults (default 1)",
    )
    p.add_argument("--hz", type=float, default=10.0, help="frame rate, Hz (default 10)")
    p.add_argument(
        "--speedup",
        type=float,
        default=1.0,
        metavar="X",
        help="play the drive X times faster (default 1: real time; 0: as fast as the reader reads)",
    )
    p.add_argument(
        "--protocol",
        choices=PROTOCOLS,
        default="hdr-bin",
        help="frame format (default hdr-bin)",
    )
    p.add_argument(
        "--link",
        metavar="PATH",
        help="also make a symlink here to the pty (stable path across pulls; default: none)",
    )
    p.add_argument(
        "--garbage",
        type=float,
        default=0.0,
        metavar="P",
        help="probability of garbage bytes before a frame",
    )
    p.add_argument(
        "--crc-errors",
        type=float,
        default=0.0,
        metavar="P",
        help="probability of a corrupted frame",
    )
    p.add_argument(
        "--drop", type=float, default=0.0, metavar="P", help="probability of a dropped frame"
    )
    p.add_argument(
        "--pull-at",
        type=float,
        action="append",
        metavar="S",
        help="pull the cable at device time S (repeatable; default: never)",
    )
    p.add_argument(
        "--pull-for", type=float, default=5.0, metavar="S", help="how long a pull lasts, s"
    )
    p.add_argument(
        "--out",
        metavar="FILE",
        help="write the frames to a capture file instead of a pty (default: a pty)",
    )


@command("record", "hdrd.commands.record:main", "record raw bytes from the gyro to a capture file")
def _record(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", metavar="URL", required=True, help="serial device or pyserial URL")
    p.add_argument(
        "--baud", type=int, default=115200, metavar="N", help="serial speed, baud (default 115200)"
    )
    p.add_argument("--out", metavar="FILE", required=True, help="capture file to write")
    p.add_argument(
        "--seconds",
        type=float,
        metavar="S",
        help="stop after S seconds (default: until interrupted)",
    )


@command(
    "replay",
    "hdrd.commands.replay:main",
    "run the daemon's pipeline on a capture, as fast as possible",
)
def _replay(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "capture", metavar="FILE", help="capture file (from `hdrd record` or `hdrd fakegyro --out`)"
    )
    p.add_argument("--protocol", choices=PROTOCOLS, help="frame format (default hdr-bin)")
    bias_group(p, state_fallback=False)  # a replay gives the same lines on any machine
    config(p)
    method(p)
    p.add_argument(
        "--heading0",
        type=float,
        metavar="DEG",
        help="compass heading at start, deg (default output.heading0_deg, 0)",
    )


@command(
    "convert",
    "hdrd.commands.replay:convert_main",
    "convert a capture into a drive log (CSV, Parquet)",
)
def _convert(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "capture", metavar="FILE", help="capture file (from `hdrd record` or `hdrd fakegyro --out`)"
    )
    p.add_argument("--protocol", choices=PROTOCOLS, help="frame format (default hdr-bin)")
    p.add_argument(
        "--out",
        metavar="FILE",
        required=True,
        help="drive log to write (raw rates, deg/s): .csv, .parquet, or a dataset directory",
    )
    log_format(p, "the drive log's format")
    config(p)


@command(
    "simulate",
    "hdrd.commands.simulate:simulate_main",
    "simulate a drive and its gyro into a drive log",
)
def _simulate(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--drive",
        default="mixed",
        help="city|suburbs|rural|highway|mixed|standstill (default mixed)",
    )
    p.add_argument(
        "--minutes",
        type=float,
        default=20.0,
        metavar="MIN",
        help="length of the drive after its standstill lead-in, min (default 20)",
    )
    p.add_argument(
        "--seed", type=int, default=1, metavar="N", help="random seed of drive and gyro (default 1)"
    )
    p.add_argument(
        "--hz",
        type=float,
        help="gyro sample rate, Hz (default: the grade's; crs03: 10, as the paper)",
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--model", metavar="MODEL.yaml", help="gyro error model (default: the grade's)")
    g.add_argument(
        "--grade",
        metavar="NAME",
        help="gyro grade preset: crs03 (default), phone, automotive, tactical (docs/gyro-model.md)",
    )
    g.add_argument(
        "--errors-from",
        metavar="GAP.json",
        help="draw each drive's gyro from the errors `hdrd gap --report` fitted to real drives "
        "(one drive per simulated drive, by its seed; docs/model-gap.md)",
    )
    p.add_argument(
        "--out",
        metavar="FILE",
        help="drive log to write, .csv or .parquet (- or none: CSV to stdout; with --benchmark "
        "or --format dataset: a directory)",
    )
    log_format(p, "the drive log's format (with --benchmark: each drive's)")
    p.add_argument(
        "--benchmark",
        choices=("train", "test"),
        help="write the paper-like nine (train) or five (test) drives",
    )


@command(
    "import",
    "hdrd.commands.importcsv:main",
    "make a drive log of your own CSV: its columns, units and signs mapped",
)
def _import(p: argparse.ArgumentParser) -> None:
    # the units are hdrd.io.files.csvimport's (not imported here: it needs numpy; a test keeps them equal)
    p.add_argument("source", metavar="SOURCE.csv", help="your CSV: a header line, then rows")
    p.add_argument("--out", metavar="FILE", required=True, help="drive log to write")
    p.add_argument("--t", required=True, metavar="COL", help="the column of sample times")
    p.add_argument("--time-unit", choices=TIME_UNITS, default="s", help="unit of --t (default s)")
    p.add_argument("--omega", required=True, metavar="COL", help="the column of the yaw rate")
    p.add_argument("--omega-unit", choices=OMEGA_UNITS, default="deg/s", help="default deg/s")
    p.add_argument(
        "--omega-sign",
        choices=("ccw", "cw"),
        default="ccw",
        help="the turn the rate counts positive, seen from above: ccw, a left turn (hdrd's; a "
        "z axis pointing up; default) or cw (a z axis pointing down)",
    )
    p.add_argument("--heading", metavar="COL", help="the column of the true heading")
    p.add_argument("--heading-unit", choices=HEADING_UNITS, default="deg", help="default deg")
    p.add_argument(
        "--heading-ref",
        choices=HEADING_REFS,
        default="compass",
        help="compass: clockwise from north (a GPS course; default); enu: counter-clockwise "
        "from east (a yaw in an east-north-up frame)",
    )
    p.add_argument("--speed", metavar="COL", help="the column of the vehicle's speed")
    p.add_argument("--speed-unit", choices=SPEED_UNITS, default="m/s", help="default m/s")
    p.add_argument("--temp", metavar="COL", help="the column of the temperature, deg C")
    p.add_argument(
        "--delimiter",
        type=delimiter,
        default=",",
        metavar="CHAR",
        help="the character between cells: , (default), ; or tab",
    )
    log_format(p, "the drive log's format")
    input_limits(p)


@command(
    "evaluate",
    "hdrd.commands.evaluate:main",
    "heading error without and with HDR (paper Table II)",
)
def _evaluate(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "drives",
        nargs="+",
        metavar="DRIVE|DIR|GLOB",
        help="drive logs with a true heading (.csv, .parquet, a dataset partitioned by drive), "
        "directories of them, or quoted globs ('fleet/**/*.parquet')",
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--calibrate-seconds",
        type=float,
        metavar="S",
        help="bias from the first S seconds, as the daemon's start-up window (default: each "
        "log's lead-in, else its first standstill found from the speed or the gyro)",
    )
    g.add_argument(
        "--bias", type=float, metavar="DPS", help="static bias, deg/s (default: each drive's own)"
    )
    p.add_argument("--json", metavar="FILE", help="write the table as JSON (default: none)")
    p.add_argument(
        "--plot",
        metavar="FILE.png",
        help="heading vs time and error bars; beyond 12 drives, NEpsi's distribution (default: none)",
    )
    p.add_argument(
        "--outages",
        metavar="SPEC",
        help="also drive each log through the daemon's GPS aiding with GNSS outages of "
        "DURATION every PERIOD of driving (e.g. 120s/10min) and report each method's "
        "heading error at their ends (docs/evaluation.md; default: none)",
    )
    p.add_argument(
        "--trace",
        metavar="DIR",
        help="write DIR/<drive>.csv: per step t, heading_truth, speed and the compass heading "
        "of none, hdr and hdr+ (docs/evaluation.md; default: none)",
    )
    config(p)
    method(p)
    input_limits(p)
    strict(p)
    fleet(p)


@command(
    "tune",
    "hdrd.commands.tune:main",
    "tune HDR parameters on training drives, check on test drives",
)
def _tune(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "train", nargs="+", metavar="TRAIN", help="drive logs to tune on (files, DIR, GLOB)"
    )
    p.add_argument(
        "--test",
        nargs="+",
        metavar="TEST",
        default=[],
        help="held-out drive logs, scored with the tuned parameters (never tuned on)",
    )
    p.add_argument(
        "--candidates",
        type=int,
        default=2000,
        metavar="N",
        help="parameter sets to try (default 2000)",
    )
    p.add_argument(
        "--seed", type=int, default=0, metavar="N", help="random seed of the search (default 0)"
    )
    p.add_argument(
        "--calibrate-seconds",
        type=float,
        metavar="S",
        help="bias from the first S seconds (default: per drive, as `hdrd evaluate`)",
    )
    p.add_argument("--out", metavar="YAML", help="write the best parameters as a config snippet")
    p.add_argument("--json", metavar="FILE", help="write the result as JSON")
    input_limits(p)
    strict(p)
    fleet(p)


@command(
    "gap", "hdrd.commands.gap:main", "find the gyro effects a model misses (model-gap workflow)"
)
def _gap(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "measured",
        nargs="+",
        metavar="MEASURED",
        help="drive log of the real gyro (raw rates, deg/s); several, directories or globs: "
        "each drive analysed on its own",
    )
    p.add_argument(
        "--model",
        metavar="MODEL.yaml",
        help="starting error model (default static_bias + white_noise)",
    )
    p.add_argument(
        "--out",
        metavar="FITTED.yaml",
        help="write the fitted model (several drives: a directory, DIR/NAME.yaml each)",
    )
    p.add_argument(
        "--report",
        metavar="REPORT.json",
        help='write the report (several drives: {"drives": [report, ...], "skipped": [...]})',
    )
    p.add_argument(
        "--gyro-out",
        metavar="PLUS.yaml",
        help="write the fitted model as HDR+'s error model, a `gyro:` configuration section "
        "to paste into hdrd.yaml (one drive)",
    )
    p.add_argument(
        "--plot", metavar="FILE.png", help="measured vs simulated, before and after (one drive)"
    )
    p.add_argument(
        "--standstill", action="store_true", help="the log was taken at rest: true rate is zero"
    )
    p.add_argument(
        "--exclude",
        action="append",
        default=[],
        metavar="T0:T1",
        help="leave out the samples with T0 <= t <= T1 (s, the log's t; repeatable), e.g. "
        "while the device was handled; rows with valid = 0 are left out too",
    )
    p.add_argument(
        "--seed", type=int, default=0, metavar="N", help="random seed of the simulation (default 0)"
    )
    input_limits(p)
    strict(p)
    fleet(p)
