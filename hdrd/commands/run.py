"""``hdrd run``: the configuration from the command line, the static bias, then the daemon's
run loop (:class:`hdrd.daemon.run.Daemon`)."""

from __future__ import annotations

import argparse
import os
import sys

from hdrd.cliconfig import check_bias_arg, config_from_args
from hdrd.config import Config, ConfigError
from hdrd.daemon.run import Daemon, choose_bias
from hdrd.daemon.signals import Signals
from hdrd.errors import EX_CONFIG, EX_FAILURE
from hdrd.io.files.biasfile import BiasFileError
from hdrd.io.logs import log, setup_logging

__all__ = ["main"]


def main(args: argparse.Namespace) -> int:
    """``hdrd run``."""
    # First of all: from here on SIGHUP reloads and SIGTERM stops, even during start-up
    # (hdrd.cli holds SIGHUP from argument parsing until here).
    signals = Signals()
    signals.install()
    try:
        cfg, where = config_from_args(args)
        check_bias_arg(getattr(args, "bias", None), cfg)
    except ConfigError as e:
        print(f"hdrd: {e}", file=sys.stderr)
        signals.restore()
        return EX_CONFIG
    problem = _closed_stdio(cfg)
    if problem:
        print(f"hdrd: {problem}", file=sys.stderr)
        signals.restore()
        return EX_FAILURE
    setup_logging(cfg.log.level, cfg.log.format)
    try:
        bias = choose_bias(cfg, getattr(args, "bias", None))
    except BiasFileError as e:
        log.error("bias_file_invalid", error=str(e))
        print(f"hdrd: {e}", file=sys.stderr)
        signals.restore()
        return EX_FAILURE
    simulate = bool(getattr(args, "simulate", False))
    return Daemon(cfg, where, lambda: config_from_args(args), bias, signals, simulate).run()


def _closed_stdio(cfg: Config) -> str | None:
    """Started with stdout or stderr closed (``hdrd run >&-``): Python leaves sys.stdout
    None. Publishing to stdout is then impossible (the message says so); otherwise the
    descriptor is pointed at /dev/null, so that no port or socket opened later becomes
    fd 1 or 2 and receives stray output. stderr likewise, for the log."""
    o = cfg.output
    if sys.stdout is None and (o.stdout or not (o.udp or o.nmea_udp)):
        return (
            "stdout is closed and is the only output configured; give --udp or --nmea-udp "
            "(or output.udp / output.nmea_udp), or start hdrd with stdout open"
        )
    for fd, name in ((1, "stdout"), (2, "stderr")):
        if getattr(sys, name) is not None:
            continue
        try:
            os.fstat(fd)
            continue  # the number is taken already (not ours to close)
        except OSError:
            pass
        null = os.open(os.devnull, os.O_WRONLY | os.O_CLOEXEC)
        if null != fd:
            os.dup2(null, fd, inheritable=False)
            os.close(null)
        setattr(sys, name, open(fd, "w", closefd=False))  # noqa: SIM115 - for the process
    return None
