"""hdrd.io.logs: the long-running commands' logging: structlog events on stderr, JSON lines
when stderr is not a terminal (journald) or when asked, a console line otherwise, filtered by
level; structlog imported only when something is logged. Each case in a fresh interpreter
(structlog's configuration is process-wide), stderr a real pipe or a real pty.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=ENV, timeout=60
    )


def test_json_lines_on_a_pipe_with_level_time_and_fields() -> None:
    p = run(
        "from hdrd.io.logs import log, setup_logging\n"
        "setup_logging('info')\n"
        "log.info('device_lost', reason='EIO', lost=1)\n"
        "log.warning('stale', seconds=2.5)\n"
    )
    assert p.returncode == 0 and p.stdout == ""
    lines = [json.loads(x) for x in p.stderr.splitlines()]
    assert [(x["event"], x["level"]) for x in lines] == [
        ("device_lost", "info"),
        ("stale", "warning"),
    ]
    assert lines[0]["reason"] == "EIO" and lines[0]["lost"] == 1 and lines[1]["seconds"] == 2.5
    assert all(x["timestamp"].endswith("Z") for x in lines)  # ISO 8601, UTC


def test_the_level_filters() -> None:
    p = run(
        "from hdrd.io.logs import log, setup_logging\n"
        "setup_logging('warning', 'json')\n"
        "log.debug('a'); log.info('b'); log.warning('c'); log.error('d')\n"
    )
    assert [json.loads(x)["event"] for x in p.stderr.splitlines()] == ["c", "d"]
    p = run(
        "from hdrd.io.logs import log, setup_logging\n"
        "setup_logging('debug', 'json')\n"
        "log.debug('a')\n"
    )
    assert json.loads(p.stderr)["level"] == "debug"


def test_console_lines_when_asked() -> None:
    p = run(
        "from hdrd.io.logs import log, setup_logging\n"
        "setup_logging('info', 'console')\n"
        "log.info('calibrated', bias_dps=0.25)\n"
    )
    (line,) = p.stderr.splitlines()
    assert "calibrated" in line and "bias_dps=0.25" in line and "[info" in line
    assert not line.startswith("{") and "\x1b[" not in line  # no colours: journald, files


def test_auto_is_console_on_a_terminal() -> None:
    """stderr a real pty (a user at a terminal): console lines, not JSON."""
    master, slave = os.openpty()
    try:
        with subprocess.Popen(
            [sys.executable, "-c",
             "from hdrd.io.logs import log, setup_logging\n"
             "setup_logging()\n"
             "log.info('start', port='/dev/ttyUSB0')\n"],
            stderr=slave, stdout=subprocess.DEVNULL, env=ENV,
        ) as proc:  # fmt: skip
            os.close(slave)
            slave = -1
            out = b""
            while True:
                try:
                    chunk = os.read(master, 4096)
                except OSError:  # EIO: the child closed its side
                    break
                if not chunk:
                    break
                out += chunk
            assert proc.wait(timeout=60) == 0
    finally:
        if slave >= 0:
            os.close(slave)
        os.close(master)
    text = out.decode()
    assert "start" in text and "port=/dev/ttyUSB0" in text and not text.lstrip().startswith("{")


def test_structlog_is_imported_only_when_something_is_logged() -> None:
    p = run(
        "import sys\n"
        "from hdrd.io.logs import log\n"
        "print('structlog' in sys.modules)\n"
        "log.bind\n"  # the first use of the logger
        "print('structlog' in sys.modules)\n"
    )
    assert p.stdout.split() == ["False", "True"], p.stderr
