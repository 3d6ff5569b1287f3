"""hdrd's errors: one base class, and the exit statuses the commands return.

Every exception hdrd raises derives from :class:`HdrdError` (as pyubx2's from
``UBXMessageError``'s base), so a caller can catch them all at once. Each module keeps its own
error class next to the code that raises it (:class:`hdrd.config.ConfigError`,
:class:`hdrd.io.wire.codec.FrameError`, ...); each also derives from the built-in exception it has
always been (most are ValueErrors), so ``except ValueError`` keeps working.

Light on purpose: the command line imports it (``hdrd --help`` loads no numpy).
"""

from __future__ import annotations

__all__ = ["EX_CONFIG", "EX_FAILURE", "EX_OK", "EX_USAGE", "HdrdError", "clipped"]

EX_OK = 0
"""Success."""
EX_FAILURE = 1
"""The command failed (a device, a file, a measurement); one line on stderr says why."""
EX_USAGE = 2
"""A malformed command line (argparse's status)."""
EX_CONFIG = 78
"""sysexits.h EX_CONFIG: a configuration value failed its checks (from the file or a flag)."""


class HdrdError(Exception):
    """The base of every exception hdrd raises; ``str()`` is the one line for the user."""


def clipped(text: str, limit: int) -> str:
    """``text`` cut to at most ``limit`` characters, ending in "..." when cut: a value, a key
    or a quoted problem of any length stays within one readable error line."""
    return text if len(text) <= limit else text[: limit - 3] + "..."
