"""The command line's flags turned into what the commands hand on: the configuration, for
every command that reads one (``hdrd run``, ``calibrate``, ``replay``, ``convert``,
``evaluate``: :func:`config_from_args`, the one path), where the work runs
(:func:`where_from_args`), what a drive log may hold (:func:`read_limits_from_args`), and the
output files checked before the work (:func:`outputs_ok`). :mod:`hdrd.cli` parses the flags
(and stays light for ``hdrd --help``); this module, imported by the commands, turns them into
typed values: a bad configuration value is a :class:`hdrd.config.ConfigError` naming the flag
(exit 78). Nothing below commands/ sees an ``argparse.Namespace``.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hdrd.analysis.plots import plotting_unavailable
from hdrd.config import Config, ConfigError
from hdrd.configload import apply_overrides, load_config
from hdrd.io.files.access import shown_path, write_problem
from hdrd.io.files.drivecolumns import ReadLimits
from hdrd.io.net.gpsd import parse_address

if TYPE_CHECKING:
    from hdrd.analysis.fleet import Where
    from hdrd.io.files.drivecolumns import ReadLimits

__all__ = [
    "check_bias_arg",
    "config_from_args",
    "config_overrides",
    "drive_log_outputs_ok",
    "output_problem",
    "outputs_ok",
    "read_limits_from_args",
    "where_from_args",
]


def config_overrides(args: argparse.Namespace) -> dict[str, Any]:
    g = lambda name: getattr(args, name, None)  # noqa: E731
    o: dict[str, Any] = {
        "device.port": g("port"),
        "device.protocol": g("protocol"),
        "device.baud": g("baud"),
        "device.clock_rate": g("clock_rate"),
        "output.stdout": g("stdout"),
        "output.nmea_ths": g("nmea_ths"),
        "output.heading0_deg": g("heading0"),
        "hdr.method": g("method"),
        "log.format": g("log_format"),
        "log.level": g("log_level"),
        "simulate.drive": g("drive"),
        "simulate.speedup": g("speedup"),
        "calibration.bias_file": g("bias_file"),
    }
    if g("udp"):
        o["output.udp"] = tuple(args.udp)
    if g("nmea_udp"):
        o["output.nmea_udp"] = tuple(args.nmea_udp)
    if g("gpsd"):
        try:
            host, port = parse_address(args.gpsd)
        except ValueError as e:
            allowed = f"{e}; give HOST, HOST:PORT, [IPv6] or [IPv6]:PORT (port default 2947)"
            raise ConfigError("--gpsd", args.gpsd, allowed) from None
        o["gpsd.enabled"] = True
        o["gpsd.host"] = host
        o["gpsd.port"] = port
    return o


def config_from_args(args: argparse.Namespace) -> tuple[Config, str]:
    """Load --config (or the default) and apply the command-line overrides; ConfigError."""
    cfg, where = load_config(getattr(args, "config", None))
    try:
        cfg = apply_overrides(cfg, config_overrides(args))
    except ConfigError as e:
        raise e.with_source("command line") from None
    return cfg, where


def check_bias_arg(value: float | None, cfg: Config) -> None:
    """``--bias`` must be a finite rate within +/- ``calibration.max_bias_dps`` (deg/s): a
    NaN or infinite bias would leave the daemon with no rate, yaw or heading. ConfigError
    (exit 78) naming the flag, the value and what is allowed."""
    if value is None:
        return
    limit = cfg.calibration.max_bias_dps
    if not (math.isfinite(value) and abs(value) <= limit):
        raise ConfigError(
            "--bias",
            value,
            f"must be a finite number within +/-{limit:g} deg/s (calibration.max_bias_dps)",
            "command line",
        )


def where_from_args(args: argparse.Namespace, prog: str) -> Where:
    """Where the work runs (``--workers``, ``--scheduler``, ``--tls-*``; docs/fleet.md); a
    scheduler reached by plain TCP from another machine is warned about on stderr."""
    import os

    # asyncio comes with the cluster's modules: a replay's fast path loads none (test_fastpaths)
    from hdrd.analysis.cluster import FleetError, TlsFiles, scheduler_warning
    from hdrd.analysis.fleet import MIN_CLUSTER_WORK_S, MIN_WORK_ENV, Where

    g = lambda name: getattr(args, name, None)  # noqa: E731
    tls = TlsFiles(g("tls_ca_file"), g("tls_cert"), g("tls_key"))
    warning = scheduler_warning(g("scheduler"))
    if warning:
        print(f"{prog}: warning: {warning}", file=sys.stderr)
    text = os.environ.get(MIN_WORK_ENV, "")
    try:
        min_work = float(text) if text else MIN_CLUSTER_WORK_S
    except ValueError:
        min_work = math.nan
    if not (min_work >= 0 and math.isfinite(min_work)):
        raise FleetError(f"{MIN_WORK_ENV}={text!r}: give seconds, a finite number >= 0")
    return Where(g("workers"), g("scheduler"), tls, min_work)


TEMP_DECORATION = 24
"""Bytes an atomic writer adds to a file's name for its temporary file
(``.NAME.PID.RANDOM.tmp``, :func:`hdrd.io.files.access.atomic_write_text`)."""


FILE_SUFFIXES = frozenset((".yaml", ".yml", ".json", ".jsonl", ".csv", ".png", ".svg", ".pdf",
                           ".txt"))  # fmt: skip
"""Name endings of the files hdrd reads and writes: an output meant as a folder that does
not exist yet and is so named is a file's name given by mistake (``gap a b --out one.yaml``).
Not ``.parquet``: a Parquet dataset's folder is often named so."""


def output_problem(flag: str, path: str, folder: str | None = None) -> str | None:
    """Why ``FLAG PATH`` could not be written, found before any work: its name too long for
    the file system (with the temporary file's decoration), a folder on its way that is a
    file, a folder where the file should be, and what writing there tells (its missing
    folders are made and a temporary file made and removed: :func:`hdrd.io.files.access.write_problem`);
    None if it can be written.

    ``folder``: PATH is a folder the command writes files into, and this says so ("several
    drives write a folder of models, OUT/NAME.yaml each"): a file there, or a name that does
    not exist yet and ends like a file's (:data:`FILE_SUFFIXES`), is refused."""
    import os
    from pathlib import Path

    target = Path(path)
    shown = f"{flag} {shown_path(path)}"
    if folder is not None:
        if os.path.exists(target) and not os.path.isdir(target):
            return f"{shown}: is a file, but {folder}: name a folder"
        if not os.path.exists(target) and target.suffix.lower() in FILE_SUFFIXES:
            return (
                f"{shown}: looks like a file's name, but {folder}: name a folder "
                f"(e.g. {flag} {shown_path(target.with_suffix(''))}/)"
            )
    problem = _name_problem(target, flag == "--plot" or folder is not None)
    if problem is None and folder is None and os.path.isdir(target):
        problem = "is a directory"
    if problem is None:
        problem = write_problem(target, folder=folder is not None)
    return None if problem is None else f"{shown}: {problem}"


def _name_problem(target: Path, in_place: bool) -> str | None:
    """Why ``target``'s name cannot be made where it goes: a folder on its way that is a
    file, a name longer than the file system takes (with a temporary file's decoration,
    unless the file is written ``in_place``); None if it can."""
    import os

    def exists(p: Path) -> bool:
        try:
            os.stat(p)
        except OSError:  # missing, or a name too long to look up
            return False
        return True

    ancestor = target.parent
    while not exists(ancestor) and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not os.path.isdir(ancestor):
        return f"{shown_path(ancestor)} is not a directory"
    try:
        most = os.pathconf(ancestor, "PC_NAME_MAX")
    except (OSError, ValueError):
        most = 255
    for part in target.relative_to(ancestor).parts[:-1]:
        if len(os.fsencode(part)) > most:
            return f"a folder's name is over {most} bytes"
    size = len(os.fsencode(target.name))
    extra = 0 if in_place else TEMP_DECORATION
    if size + extra > most:
        return f"the file's name is {size} bytes; at most {most - extra} can be written here" + (
            f" (a temporary file's name takes {extra} more)" if extra else ""
        )
    return None


def outputs_ok(
    args: argparse.Namespace,
    err: Callable[[str], None],
    flags: tuple[str, ...],
    folders: dict[str, str] | None = None,
) -> bool:
    """Whether every output the command line names (``flags``, e.g. ``--json``; ``folders``:
    the flags that name a folder, each with what the command writes there, as
    :func:`output_problem`'s ``folder``) can be written, asked before any work (their missing
    folders made); what is wrong with the first that cannot is said through ``err``.
    ``--plot`` also needs matplotlib and a format it writes."""
    wanted = [(flag, None) for flag in flags] + list((folders or {}).items())
    for flag, folder in wanted:
        path = getattr(args, flag.lstrip("-").replace("-", "_"), None)
        if not path or path == "-":
            continue
        problem = None
        if flag == "--plot":  # said first: no folder made for a plot that cannot be drawn
            problem = plotting_unavailable(path)
        if problem is None:
            problem = output_problem(flag, path, folder)
        if problem is not None:
            err(problem)
            return False
    return True


def drive_log_outputs_ok(
    args: argparse.Namespace, err: Callable[[str], None], folder: bool
) -> bool:
    """:func:`outputs_ok` for a drive log's ``--out`` (``-``: stdout, nothing to check):
    a file, or with ``folder`` a folder (``--benchmark``'s drive logs, a dataset)."""
    if not folder:
        return outputs_ok(args, err, ("--out",))
    fmt = getattr(args, "format", None)
    what = (
        "--format dataset writes a folder (DIR/drive=NAME/part-0.parquet)"
        if fmt == "dataset"
        else "--benchmark writes a folder of drive logs (DIR/NAME.csv or .parquet each)"
    )
    return outputs_ok(args, err, (), {"--out": what})


def read_limits_from_args(args: argparse.Namespace) -> ReadLimits:
    """The :class:`~hdrd.io.files.drivecolumns.ReadLimits` a command line asks for (``--max-rows``,
    ``--max-rate``, ``--max-gap``); the defaults for what it does not give."""
    given = {
        "max_rows": getattr(args, "max_rows", None),
        "max_rate_dps": getattr(args, "max_rate", None),
        "max_gap_s": getattr(args, "max_gap", None),
    }
    return ReadLimits(**{k: v for k, v in given.items() if v is not None})
