"""What a new user meets first, met as a user meets it: a real ``hdrd`` process in a real
pipe, a drive log handed to the capture tools, a configuration that is missing or broken, a
port another program holds. Each ends in one plain line (or, for a reader that goes away,
in silence), never in words of hdrd's insides."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.hdrd_process import ENV, hdrd

# -- a reader that goes away (`| head`) -------------------------------------------------------


@pytest.mark.parametrize(
    "args",
    [
        ("simulate", "--drive", "city", "--minutes", "20", "--out", "-"),
        ("simulate", "--drive", "city", "--minutes", "20"),
    ],
)
def test_a_reader_that_goes_away_ends_the_command_cleanly(
    tmp_path: Path, args: tuple[str, ...]
) -> None:
    # `hdrd simulate --out - | head` said "cannot write -: Broken pipe" and exited 1 (its
    # 700 kB fill the pipe: the write meets the closed end).
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdrd", *args], cwd=tmp_path, env=ENV,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.readline()  # as `head -1` does: one line, then the pipe closed
    proc.stdout.close()
    with proc.stderr:
        err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0, err
    assert err == "", err


# -- a drive log given to the tools of captures ----------------------------------------------


@pytest.mark.parametrize("command", ["replay", "convert"])
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_a_drive_log_given_as_a_capture_is_named_so(
    tmp_path: Path, command: str, suffix: str
) -> None:
    # `hdrd replay city.csv` said "no valid frames in city.csv (0 bad frames, 541450 bytes of
    # garbage as hdr-bin); is it a capture ...?"
    if suffix == ".parquet":
        pytest.importorskip("pyarrow")
    log = f"city{suffix}"
    assert hdrd("simulate", "--drive", "city", "--minutes", "2", "--out", log,
                cwd=tmp_path).returncode == 0  # fmt: skip
    args = ["--out", "again.csv"] if command == "convert" else []
    p = hdrd(command, log, *args, cwd=tmp_path)
    assert p.returncode == 1 and p.stdout == "", p.stderr
    assert len(p.stderr.splitlines()) == 1, p.stderr
    kind = "CSV" if suffix == ".csv" else "Parquet"
    assert p.stderr.startswith(f"hdrd {command}: {log} is a drive log ({kind}), not a capture"), (
        p.stderr
    )
    assert f"hdrd evaluate {log}" in p.stderr and "garbage" not in p.stderr
    assert not (tmp_path / "again.csv").exists()


# -- a configuration that is missing or broken -----------------------------------------------


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (None, "config error in {p}: no such file"),
        ("hdr:\n  method: [\n", "config error in {p}, line 3, column 1: YAML syntax error: "),
        ("", "config error in {p}: the file is empty; expected a mapping of sections"),
        ("- hdr\n", "config error in {p}: the file holds [hdr], not a mapping of sections"),
        ("dir", "config error in {p}: cannot be read: is a directory, not a regular file"),
    ],
    ids=["missing", "syntax", "empty", "a list", "a directory"],
)
def test_a_configuration_that_cannot_be_read_is_said_in_plain_words(
    tmp_path: Path, text: str | None, said: str
) -> None:
    # Was: "config error in nope.yaml: (file) = 'nope.yaml': not found" and
    # "... (yaml) = 'line 3, column 1': YAML syntax error: ...".
    path = tmp_path / "hdrd.yaml"
    if text == "dir":
        path.mkdir()
    elif text is not None:
        path.write_text(text)
    p = hdrd("replay", "none.cap", "--config", str(path), cwd=tmp_path)
    assert p.returncode == 78, p.stderr
    assert len(p.stderr.splitlines()) == 1, p.stderr
    assert said.format(p=path) in p.stderr, p.stderr
    assert "(file)" not in p.stderr and "(yaml)" not in p.stderr


# -- a port another program holds ------------------------------------------------------------


def _free_port(kind: socket.SocketKind) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _bound(port: int, deadline_s: float = 30.0) -> bool:
    """Whether something holds UDP 127.0.0.1:PORT (tried by binding it), waiting up to the
    deadline for it to."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return True
        time.sleep(0.05)
    return False


def test_tail_on_a_port_another_program_holds_says_which(tmp_path: Path) -> None:
    # Was: "hdrd tail: cannot listen on 127.0.0.1:10110: Address already in use", with no word
    # of who holds it (there: `hdrd web`, started earlier and forgotten).
    if not os.path.isdir("/proc/net"):
        pytest.skip("no /proc/net here: who holds a port is looked up there")
    port, page = _free_port(socket.SOCK_DGRAM), _free_port(socket.SOCK_STREAM)
    web = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "web", "--listen", f"127.0.0.1:{page}", "--udp",
         f"127.0.0.1:{port}"],
        cwd=tmp_path, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        if not _bound(port):
            pytest.fail("hdrd web did not take its UDP port")
        p = hdrd("tail", "--listen", f"127.0.0.1:{port}", cwd=tmp_path, timeout=30)
    finally:
        web.terminate()
        web.wait(timeout=30)
    assert p.returncode == 1, p.stderr
    assert len(p.stderr.splitlines()) == 1, p.stderr
    assert f"cannot listen on 127.0.0.1:{port}: the address is in use" in p.stderr, p.stderr
    assert f"held by pid {web.pid} (" in p.stderr and "hdrd web" in p.stderr, p.stderr
