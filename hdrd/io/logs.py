"""Logging set-up of the long-running commands (``hdrd run``, ``hdrd calibrate``): structlog
events on stderr, JSON lines for journald when stderr is not a terminal.

Events are state changes (start, calibrated, device_lost, device_back, config_reloaded, stop,
...) with their counters, never one per sample.
"""

from __future__ import annotations

import logging
import sys
from typing import Any

__all__ = ["log", "setup_logging"]


class _LazyLogger:
    """``structlog.get_logger("hdrd")``, structlog imported on first use. Why: importing it
    costs ~30 ms (it brings asyncio), which a command that ends before it logs (a usage or
    configuration error) need not pay."""

    def __getattr__(self, name: str) -> Any:
        import structlog

        return getattr(structlog.get_logger("hdrd"), name)


log: Any = _LazyLogger()
"""The ``hdrd`` logger of the long-running commands (structured events, see the module doc)."""


def setup_logging(level: str = "info", fmt: str = "auto") -> None:
    """structlog to stderr: JSON lines when not on a terminal (journald), console otherwise."""
    import structlog

    use_json = fmt == "json" or (fmt == "auto" and not sys.stderr.isatty())
    renderer: Any = (
        structlog.processors.JSONRenderer()
        if use_json
        else structlog.dev.ConsoleRenderer(colors=False)
    )
    structlog.configure(
        processors=[
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso", utc=True),
            renderer,
        ],
        wrapper_class=structlog.make_filtering_bound_logger(getattr(logging, level.upper())),
        logger_factory=structlog.PrintLoggerFactory(file=sys.stderr),
        cache_logger_on_first_use=False,
    )
