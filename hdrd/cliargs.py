"""The command line's shared pieces (hdrd/cli.py registers the commands): the help format
and the option groups, argument types and choices that several commands take. Light: it
imports no numpy, so ``hdrd --help`` stays fast."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Sequence

from hdrd.io.wire.protocol import PROTOCOLS

__all__ = [
    "DRIVES",
    "HEADING_REFS",
    "HEADING_UNITS",
    "HelpFormatter",
    "LazyChoices",
    "OMEGA_UNITS",
    "SPEED_UNITS",
    "TIME_UNITS",
    "TLS_FILES",
    "address",
    "bias_group",
    "config",
    "delimiter",
    "drive_names",
    "fleet",
    "input_limits",
    "log_format",
    "log_level",
    "max_rate",
    "method",
    "method_names",
    "port",
    "positive_float",
    "positive_int",
    "strict",
]


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


def bias_group(
    p: argparse.ArgumentParser, calibrate_seconds: bool = True, state_fallback: bool = True
) -> None:
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
        + (
            "$STATE_DIRECTORY or /var/lib/hdrd/bias.yaml when it exists)"
            if state_fallback
            else "none: never this machine's $STATE_DIRECTORY or /var/lib/hdrd bias file)"
        ),
    )
    if calibrate_seconds:
        g.add_argument(
            "--calibrate-seconds",
            type=float,
            metavar="S",
            help="measure the bias over the first S seconds (the vehicle must stand still; "
            "default calibration.startup_s, 1 s, when there is no bias file)",
        )


class LazyChoices:
    """Choices read from their home when argparse first needs them (to check a value or print
    a command's help): importing the method registry or the simulator up front would load
    numpy and slow ``hdrd --help``."""

    def __init__(self, load: Callable[[], Sequence[str]]) -> None:
        self._load = load

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __contains__(self, value: object) -> bool:
        return value in self._load()


def method_names() -> Sequence[str]:
    # the command line stays light: `hdrd --help` loads no numpy
    from hdrd.core.methods import names

    return names()


def drive_names() -> Sequence[str]:
    # the command line stays light: `hdrd --help` loads no numpy
    from hdrd.sim.vehicle import DRIVE_TYPES

    return tuple(DRIVE_TYPES)


DRIVES = LazyChoices(drive_names)
"""The simulated drives (:data:`hdrd.sim.vehicle.DRIVE_TYPES`)."""


def method(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--method",
        choices=LazyChoices(method_names),
        metavar="METHOD",  # a metavar keeps argparse from listing the choices at parser set-up
        help="drift reduction, one of %(choices)s (none: static bias removal only; hdr: the "
        "paper's; see docs/evaluation.md); default hdr.method, hdr",
    )


def config(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--config",
        metavar="PATH",
        help="YAML configuration (default /etc/hdrd/hdrd.yaml, else the built-in defaults)",
    )


def port(p: argparse.ArgumentParser, required: bool = False) -> None:
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


def log_level(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--log-level",
        choices=("debug", "info", "warning", "error"),
        help="log level on stderr (default log.level, info)",
    )


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


TLS_FILES = {
    "ca-file": "tls:// scheduler: the CA certificate that signed the cluster's",
    "cert": "tls:// scheduler: this client's certificate",
    "key": "tls:// scheduler: this client's private key",
}


def fleet(p: argparse.ArgumentParser, progress: bool = True) -> None:
    """Where the work runs (docs/fleet.md): this process by default; a Dask cluster."""
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--workers",
        type=positive_int,
        metavar="N",
        help="run on a local Dask cluster of N worker processes (pip install 'hdrd[fleet]'); "
        "default: in this process",
    )
    g.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on the Dask cluster at ADDRESS (tls://HOST:8786; tcp:// is unencrypted): it "
        "runs code here, so only one you control (docs/fleet.md); default: in this process",
    )
    for flag, what in TLS_FILES.items():
        key = f"distributed.comm.tls.{flag if flag == 'ca-file' else 'client.' + flag}"
        p.add_argument(f"--tls-{flag}", metavar="FILE", help=f"{what} (PEM; default {key})")
    if progress:
        p.add_argument("--no-progress", action="store_true", help="no progress on stderr")


def positive_float(text: str, most: float = float("inf")) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if not (0 < v <= most and v != float("inf")):
        limit = f" and at most {most:g}" if most != float("inf") else ""
        raise argparse.ArgumentTypeError(f"must be a finite number > 0{limit}, got {text}")
    return v


def max_rate(text: str) -> float:
    return positive_float(text, 1e5)  # beyond, a block's sum of squares loses its meaning


def input_limits(p: argparse.ArgumentParser) -> None:
    """What a drive log may hold (docs/drive-format.md, "Limits")."""
    p.add_argument(
        "--max-rows",
        type=positive_int,
        metavar="N",
        help="most rows a drive may have (default 10000000; a Parquet file's counted before "
        "it is read)",
    )
    p.add_argument(
        "--max-rate",
        type=max_rate,
        metavar="DPS",
        help="largest |omega| a drive may hold, deg/s (default 1000, a gyro's range); a "
        "larger rate in a row that counts is refused",
    )
    p.add_argument(
        "--max-gap",
        type=positive_float,
        metavar="S",
        help="longest time gap a drive may have, s (default 3600); a longer one is refused",
    )


def strict(p: argparse.ArgumentParser) -> None:
    """What a drive that cannot be used does to a run of many (docs/evaluation.md)."""
    p.add_argument(
        "--strict",
        action="store_true",
        help="stop at the first drive that cannot be used (default: report it on stderr, "
        "skip it and go on with the others)",
    )


def log_format(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument(
        "--format",
        choices=("csv", "parquet", "dataset"),
        help=f"{what}: csv, parquet (one file) or dataset (OUT is a dataset partitioned by "
        "drive: OUT/drive=NAME/part-0.parquet); default: parquet if OUT ends in .parquet, "
        "else csv (docs/drive-format.md)",
    )


def address(p: argparse.ArgumentParser, flag: str, default: str, help: str) -> None:
    """A HOST:PORT to listen on; its default is hdrd.io's (test_layout keeps them equal)."""
    p.add_argument(flag, metavar="HOST:PORT", default=default, help=help)


TIME_UNITS = ("s", "ms", "us", "ns")
OMEGA_UNITS = ("deg/s", "rad/s")
HEADING_UNITS = ("deg", "rad")
HEADING_REFS = ("compass", "enu")
"""``hdrd import --heading-ref``: what the heading column is measured from (the choices of
:attr:`hdrd.io.files.csvimport.Mapping.heading_ref`)."""
SPEED_UNITS = ("m/s", "km/h", "mph")


def delimiter(text: str) -> str:
    d = {"tab": "\t", "\\t": "\t", "comma": ",", "semicolon": ";"}.get(text, text)
    if len(d) != 1 or d in '\r\n"' or d.isalnum():
        raise argparse.ArgumentTypeError(
            f"one character (or tab), not a letter, digit or quote, got {text!r}"
        )
    return d
