"""The command line's flags applied to the configuration, for the commands that read one
(``hdrd run``, ``calibrate``, ``replay``, ``convert``). :mod:`hdrd.cli` parses the flags (and
stays light for ``hdrd --help``); this module, imported by the commands, turns them into a
validated :class:`hdrd.config.Config`: a bad value is a :class:`hdrd.config.ConfigError`
naming the flag (exit 78).
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from hdrd.config import Config, ConfigError, apply_overrides, load_config

__all__ = ["check_bias_arg", "config_from_args"]


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
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
        from hdrd.io.gpsd import parse_address

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
        cfg = apply_overrides(cfg, _overrides(args))
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
