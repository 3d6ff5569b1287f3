"""``hdrd`` run as a user runs it, for the tests that meet it so: this checkout's code (its
folder first on PYTHONPATH) through this Python, in a folder of the test's, stdin closed;
stdout and stderr kept as text. A command that hangs fails its test at ``timeout`` instead of
hanging it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def hdrd(*args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """``hdrd ARGS`` run in ``cwd``, to its end."""
    return subprocess.run(
        [sys.executable, "-m", "hdrd", *args],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=cwd,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )
