"""The ``hdrd`` command line: argument parsing only.

Each subcommand names the function that implements it (``module:function``, taking the
parsed arguments and returning an exit status); the module is imported only when the
subcommand runs, so ``hdrd --help`` stays fast. Exit statuses: 0 success, 1 failure,
2 usage error (a malformed command line: unknown option, missing or malformed argument, a
choice not in its list, such as an unknown --drive), 78 configuration error (EX_CONFIG: a
value that fails the configuration's checks, from the file or from a flag that overrides
it, e.g. ``--heading0 400``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Iterator, Sequence

from hdrd import __version__
from hdrd.daemon.signals import command_of, hold_hangup
from hdrd.io.protocol import PROTOCOLS


class HelpFormatter(argparse.HelpFormatter):
    """Every option's help shows its default: an option with a value and a default (not None)
    whose help does not give it already gets `` (default: X)``, as
    ``argparse.ArgumentDefaultsHelpFormatter`` does, but not for a switch (off unless given)
    nor for a default of None (the option's help then says where the default comes from,
    e.g. a configuration key). An empty list shows as ``none``."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        d = action.default
        if (
            not action.option_strings
            or action.nargs == 0
            or d is None
            or d is argparse.SUPPRESS
            or "%(default)" in text
            or "default" in text
        ):
            return action.help
        shown = "none" if isinstance(d, (list, tuple)) and not d else "%(default)s"
        return f"{text} (default: {shown})"


Adder = Callable[[argparse.ArgumentParser], None]
COMMANDS: dict[str, tuple[str, str, Adder]] = {}


def command(name: str, target: str, help: str) -> Callable[[Adder], Adder]:
    def register(add: Adder) -> Adder:
        COMMANDS[name] = (target, help, add)
        return add

    return register


def _bias_group(p: argparse.ArgumentParser, calibrate_seconds: bool = True) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--bias",
        type=float,
        metavar="DPS",
        help="static bias eps0 to remove, deg/s (default: the bias file's, else measured at "
        "start over calibration.startup_s, 1 s)",
    )
    g.add_argument(
        "--bias-file",
        metavar="PATH",
        help="bias file written by `hdrd calibrate` (default calibration.bias_file, else "
        "$STATE_DIRECTORY or /var/lib/hdrd/bias.yaml when it exists)",
    )
    if calibrate_seconds:
        g.add_argument(
            "--calibrate-seconds",
            type=float,
            metavar="S",
            help="measure the bias over the first S seconds (the vehicle must stand still; "
            "default calibration.startup_s, 1 s, when there is no bias file)",
        )


class _LazyChoices:
    """Choices read from their home when argparse first needs them (to check a value or print
    a command's help): importing the method registry or the simulator up front would load
    numpy and slow ``hdrd --help``."""

    def __init__(self, load: Callable[[], Sequence[str]]) -> None:
        self._load = load

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __contains__(self, value: object) -> bool:
        return value in self._load()


def _method_names() -> Sequence[str]:
    from hdrd.core.methods import names

    return names()


def _drive_names() -> Sequence[str]:
    from hdrd.sim.vehicle import DRIVE_TYPES

    return tuple(DRIVE_TYPES)


DRIVES = _LazyChoices(_drive_names)
"""The simulated drives (:data:`hdrd.sim.vehicle.DRIVE_TYPES`)."""


def _method(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--method",
        choices=_LazyChoices(_method_names),
        metavar="METHOD",  # a metavar keeps argparse from listing the choices at parser set-up
        help="drift reduction, one of %(choices)s (none: static bias removal only; hdr: the "
        "paper's; see docs/evaluation.md); default hdr.method, hdr",
    )


def _config(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--config",
        metavar="PATH",
        help="YAML configuration (default /etc/hdrd/hdrd.yaml, else the built-in defaults)",
    )


def _port(p: argparse.ArgumentParser, required: bool = False) -> None:
    p.add_argument(
        "--port",
        metavar="URL",
        required=required,
        help="serial device or pyserial URL (/dev/ttyUSB0, /dev/serial/by-id/..., loop://, "
        "socket://host:port); default device.port, /dev/hdrd-gyro",
    )
    p.add_argument(
        "--baud", type=int, metavar="N", help="serial speed, baud (default device.baud, 115200)"
    )
    p.add_argument(
        "--protocol",
        choices=PROTOCOLS,
        help="frame format (default device.protocol, hdr-bin)",
    )


def _log_level(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--log-level",
        choices=("debug", "info", "warning", "error"),
        help="log level on stderr (default log.level, info)",
    )


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def _fleet(p: argparse.ArgumentParser, progress: bool = True) -> None:
    """Where the work runs (docs/fleet.md): this process by default; a Dask cluster."""
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--workers",
        type=_positive_int,
        metavar="N",
        help="run on a local Dask cluster of N worker processes (pip install 'hdrd[fleet]'); "
        "default: in this process",
    )
    g.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on the Dask cluster whose scheduler is at ADDRESS (tcp://HOST:8786); "
        "default: in this process",
    )
    if progress:
        p.add_argument("--no-progress", action="store_true", help="no progress on stderr")


def _positive_float(text: str, most: float = float("inf")) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if not (0 < v <= most and v != float("inf")):
        limit = f" and at most {most:g}" if most != float("inf") else ""
        raise argparse.ArgumentTypeError(f"must be a finite number > 0{limit}, got {text}")
    return v


def _max_rate(text: str) -> float:
    return _positive_float(text, 1e5)  # beyond, a block's sum of squares loses its meaning


def _input_limits(p: argparse.ArgumentParser) -> None:
    """What a drive log may hold (docs/drive-format.md, "Limits")."""
    p.add_argument(
        "--max-rows",
        type=_positive_int,
        metavar="N",
        help="most rows a drive may have (default 10000000; a Parquet file's counted before "
        "it is read)",
    )
    p.add_argument(
        "--max-rate",
        type=_max_rate,
        metavar="DPS",
        help="largest |omega| a drive may hold, deg/s (default 1000, a gyro's range); a "
        "larger rate in a row that counts is refused",
    )
    p.add_argument(
        "--max-gap",
        type=_positive_float,
        metavar="S",
        help="longest time gap a drive may have, s (default 3600); a longer one is refused",
    )


def _strict(p: argparse.ArgumentParser) -> None:
    """What a drive that cannot be used does to a run of many (docs/evaluation.md)."""
    p.add_argument(
        "--strict",
        action="store_true",
        help="stop at the first drive that cannot be used (default: report it on stderr, "
        "skip it and go on with the others)",
    )


def _log_format(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument(
        "--format",
        choices=("csv", "parquet", "dataset"),
        help=f"{what}: csv, parquet (one file) or dataset (OUT is a dataset partitioned by "
        "drive: OUT/drive=NAME/part-0.parquet); default: parquet if OUT ends in .parquet, "
        "else csv (docs/drive-format.md)",
    )


@command("run", "hdrd.commands.run:main", "run the daemon: gyro -> HDR -> publishers")
def _run(p: argparse.ArgumentParser) -> None:
    """Long because it is a flat list of the daemon's options, read best in one place."""
    _config(p)
    _port(p)
    _bias_group(p, calibrate_seconds=False)
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
    _method(p)
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
    _log_level(p)


@command("calibrate", "hdrd.commands.calibrate:main", "measure the static bias at standstill")
def _calibrate(p: argparse.ArgumentParser) -> None:
    _config(p)
    _port(p)
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
    _log_level(p)


@command("tail", "hdrd.commands.tail:main", "print what the daemon publishes (like gpspipe -w)")
def _tail(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--listen",
        metavar="HOST:PORT",
        default="127.0.0.1:10110",
        help="UDP address to listen on (default 127.0.0.1:10110)",
    )
    p.add_argument(
        "--raw",
        action="store_true",
        help="print the JSON lines as received (on a terminal, numbers rounded)",
    )
    p.add_argument(
        "--count", type=int, metavar="N", help="exit after N messages (default: until stopped)"
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
    _bias_group(p)
    _config(p)
    _method(p)
    p.add_argument("--heading0", type=float, metavar="DEG", help="compass heading at start, deg")


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
    _log_format(p, "the drive log's format")
    _config(p)


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
    p.add_argument(
        "--out",
        metavar="FILE",
        help="drive log to write, .csv or .parquet (- or none: CSV to stdout; with --benchmark "
        "or --format dataset: a directory)",
    )
    _log_format(p, "the drive log's format (with --benchmark: each drive's)")
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
    # the units are hdrd.io.csvimport's (not imported here: it needs numpy; a test keeps them equal)
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
        choices=("compass", "enu"),
        default="compass",
        help="compass: clockwise from north (a GPS course; default); enu: counter-clockwise "
        "from east (a yaw in an east-north-up frame)",
    )
    p.add_argument("--speed", metavar="COL", help="the column of the vehicle's speed")
    p.add_argument("--speed-unit", choices=SPEED_UNITS, default="m/s", help="default m/s")
    p.add_argument("--temp", metavar="COL", help="the column of the temperature, deg C")
    p.add_argument(
        "--delimiter",
        type=_delimiter,
        default=",",
        metavar="CHAR",
        help="the character between cells: , (default), ; or tab",
    )
    _log_format(p, "the drive log's format")
    _input_limits(p)


TIME_UNITS = ("s", "ms", "us", "ns")
OMEGA_UNITS = ("deg/s", "rad/s")
HEADING_UNITS = ("deg", "rad")
SPEED_UNITS = ("m/s", "km/h", "mph")


def _delimiter(text: str) -> str:
    d = {"tab": "\t", "\\t": "\t", "comma": ",", "semicolon": ";"}.get(text, text)
    if len(d) != 1 or d in '\r\n"' or d.isalnum():
        raise argparse.ArgumentTypeError(
            f"one character (or tab), not a letter, digit or quote, got {text!r}"
        )
    return d


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
    g.add_argument("--bias", type=float, metavar="DPS", help="static bias, deg/s")
    p.add_argument("--json", metavar="FILE", help="write the table as JSON")
    p.add_argument(
        "--plot",
        metavar="FILE.png",
        help="heading vs time and error bars; beyond 12 drives, the distribution of NEpsi per "
        "method (needs matplotlib)",
    )
    p.add_argument(
        "--outages",
        metavar="SPEC",
        help="also drive each log through the daemon's GPS aiding with GNSS outages of "
        "DURATION every PERIOD of driving (e.g. 120s/10min) and report each method's "
        "heading error at their ends (docs/evaluation.md)",
    )
    _config(p)
    _method(p)
    _input_limits(p)
    _strict(p)
    _fleet(p)


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
    _input_limits(p)
    _strict(p)
    _fleet(p)


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
        "--plus-out",
        metavar="PLUS.yaml",
        help="write the fitted model as HDR+'s error model, a `plus:` configuration section "
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
    _input_limits(p)
    _strict(p)
    _fleet(p)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hdrd",
        description="Heuristic Drift Reduction daemon and tools for a vehicle yaw-rate gyro "
        "(Borenstein & Ojeda, SPIE 7305, 2009). Rates in deg/s, + = counter-clockwise.",
    )
    parser.add_argument("--version", action="version", version=f"hdrd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (target, help_, add) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_, formatter_class=HelpFormatter)
        add(p)
        p.set_defaults(_target=target, _parser=p)
    return parser


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The parsed command line; on a usage error exit 2 with the usage of the subcommand
    the error is in (argparse's subparsers hand unknown options up to the top-level parser,
    whose usage would not help: ``hdrd run --simualte``)."""
    args, extra = build_parser().parse_known_args(argv)
    if extra:
        args._parser.error("unrecognized arguments: " + " ".join(extra))
    return args


def main(argv: Sequence[str] | None = None) -> int:
    if command_of(list(sys.argv[1:] if argv is None else argv)) == "run":
        # SIGHUP's default action ends the process: hold it from here (the entry point,
        # hdrd.__main__, already has), before parsing, the slow imports and the config,
        # until the daemon installs its reload handler (which takes a held one as a reload).
        hold_hangup()
    args = parse_args(argv)
    module, _, func = args._target.partition(":")
    impl = getattr(importlib.import_module(module), func)
    try:
        return int(impl(args) or 0)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader went away (`hdrd replay ... | head`): not an error worth a traceback.
        _silence_stdout()
        return 0


def _silence_stdout() -> None:
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
