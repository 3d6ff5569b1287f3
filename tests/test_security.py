"""Security: what the daemon exposes, runs as, executes and writes.

- A running `hdrd run`, with every output configured, holds no listening socket: its sockets
  (found through /proc/<pid>/fd) are looked up in /proc/<pid>/net/{tcp,tcp6,udp,udp6,unix}:
  no TCP socket in LISTEN, no Unix socket accepting or bound to a path, and no UDP socket
  bound to a chosen port (a send socket is unbound until its first datagram, then has a
  kernel-chosen ephemeral port; nothing reads from it).
- `hdrd tail`, the one command that listens, binds 127.0.0.1 by default.
- No shell and no evaluation ever gets data from the configuration or the wire: a static scan
  of hdrd/ (AST) for os.system/popen/exec*/spawn*, subprocess with shell or a command string,
  eval/exec, pickle/marshal, and YAML loaders other than the safe one.
- The unit runs unprivileged: DynamicUser, dialout as its only extra group, no User=/Group=,
  no capabilities, no privileged ExecStart prefix, the state directory its own and the only
  place it may write.

Covered elsewhere and not repeated: the unit's hardening directives, `systemd-analyze verify`
and the `systemd-analyze security --offline=true` exposure kept at "OK" and recorded in
docs/operations.md (tests/test_systemd.py); the bias file's mode 0644 whatever the umask (tests/test_biasfile.py)
and as written by `hdrd calibrate` into $STATE_DIRECTORY (tests/test_rel_daemon.py).
"""

from __future__ import annotations

import ast
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hdrd.sim.profiles import builtin_profile

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "hdrd"
UNIT = ROOT / "systemd" / "hdrd.service"
WAIT = 30.0


# --------------------------------------------------------------------------- sockets of a process


def socket_inodes(pid: int) -> set[int]:
    out = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            link = os.readlink(fd)
        except OSError:
            continue
        if link.startswith("socket:["):
            out.add(int(link[8:-1]))
    return out


def _hex_addr(text: str) -> tuple[str, int]:
    addr, port = text.split(":")
    raw = bytes.fromhex(addr)
    if len(raw) == 4:
        ip = socket.inet_ntop(socket.AF_INET, raw[::-1])
    else:  # four little-endian 32-bit words
        ip = socket.inet_ntop(
            socket.AF_INET6, b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
        )
    return ip, int(port, 16)


def inet_sockets(pid: int) -> list[dict[str, Any]]:
    """The process's TCP/UDP sockets: proto, local (ip, port), state (hex, as the kernel says)."""
    mine = socket_inodes(pid)
    found = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        path = Path(f"/proc/{pid}/net/{proto}")
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            f = line.split()
            if int(f[9]) in mine:
                found.append(
                    {
                        "proto": proto,
                        "local": _hex_addr(f[1]),
                        "remote": _hex_addr(f[2]),
                        "state": f[3],
                    }
                )
    return found


def unix_sockets(pid: int) -> list[dict[str, Any]]:
    mine = socket_inodes(pid)
    found = []
    for line in Path(f"/proc/{pid}/net/unix").read_text().splitlines()[1:]:
        f = line.split()
        if int(f[6]) in mine:
            found.append({"flags": int(f[3], 16), "path": f[7] if len(f) > 7 else ""})
    return found


TCP_LISTEN = "0A"
SO_ACCEPTCON = 0x10000


def ephemeral_range() -> range:
    lo, hi = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
    return range(int(lo), int(hi) + 1)


@pytest.fixture
def daemon_publishing(
    fake_gyro: Any, tmp_path: Path
) -> Iterator[tuple[subprocess.Popen[bytes], Any]]:
    """`hdrd run` with JSON and NMEA over UDP (IPv4 and IPv6), stdout and a NOTIFY_SOCKET,
    publishing: yields the process once its send sockets exist."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(WAIT)
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify.sock"))
    g = fake_gyro(builtin_profile("constant", minutes=5, rate_dps=1.0, lead_in_s=0), speedup=4)
    env = dict(
        os.environ, STATE_DIRECTORY=str(tmp_path), NOTIFY_SOCKET=str(tmp_path / "notify.sock")
    )
    env.pop("WATCHDOG_USEC", None)
    args = [
        "--clock-rate",
        "4",
        "--port",
        g.path,
        "--bias",
        "0",
        "--stdout",
        "--udp",
        f"127.0.0.1:{rx.getsockname()[1]}",
        "--nmea-udp",
        "127.0.0.1:9",
    ]
    if socket.has_ipv6:
        args += ["--udp", "[::1]:9"]
    p = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "run", "--log-format", "json", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
    )
    try:
        g.start()
        for _ in range(3):
            json.loads(rx.recv(65536))  # sent, so its sockets are made (and autobound)
        yield p, g
    finally:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        p.communicate(timeout=WAIT)
        rx.close()
        notify.close()


@pytest.mark.slow
def test_the_daemon_listens_on_nothing(
    daemon_publishing: tuple[subprocess.Popen[bytes], Any],
) -> None:
    p, _ = daemon_publishing
    inet = inet_sockets(p.pid)
    unix = unix_sockets(p.pid)
    udp = [s for s in inet if s["proto"].startswith("udp")]
    assert udp, "found none of the daemon's UDP send sockets: the check would be vacuous"
    assert unix, "found not even the daemon's sd_notify socket: the check would be vacuous"
    assert not [s for s in inet if s["proto"].startswith("tcp") and s["state"] == TCP_LISTEN]
    ephemeral = ephemeral_range()
    for s in udp:
        port = s["local"][1]
        # unbound (port 0), or bound by the kernel at the first send to a port it chose
        assert port == 0 or port in ephemeral, s
    for s in unix:
        assert not s["flags"] & SO_ACCEPTCON and not s["path"], s


def test_hdrd_tail_binds_loopback_by_default() -> None:
    tail_on_the_default_port()


@pytest.mark.slow
def test_a_taken_default_port_skips_and_leaves_nothing_behind(tmp_path: Path) -> None:
    """With the default port taken (a running ``hdrd tail``), the test above skips, and its
    teardown finds nothing left behind: pytest, run on it as a user would, reports one skip
    and no error."""
    from hdrd.io.net.datagrams import DEFAULT_TAIL_LISTEN

    port = int(DEFAULT_TAIL_LISTEN.rsplit(":", 1)[1])
    test = f"{Path(__file__).resolve()}::test_hdrd_tail_binds_loopback_by_default"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        try:
            holder.bind(("127.0.0.1", port))
        except OSError:
            pass  # taken already: the case this test is about, either way
        run = subprocess.run(
            [sys.executable, "-m", "pytest", "-n0", "-q", "-p", "no:cacheprovider", "-rs", test],
            capture_output=True,
            cwd=tmp_path,
            timeout=4 * WAIT,
        )
    out = run.stdout.decode(errors="replace")
    assert run.returncode == 0, out
    assert "1 skipped" in out and "error" not in out.lower(), out


def tail_on_the_default_port() -> None:
    """``hdrd tail`` with no --listen binds 127.0.0.1 on the default port and prints what it
    receives; skips (leaving nothing behind) when that port is taken on this machine."""
    from hdrd.cli import build_parser
    from hdrd.io.net.datagrams import DEFAULT_TAIL_LISTEN

    assert DEFAULT_TAIL_LISTEN.startswith("127.0.0.1:")
    assert build_parser().parse_args(["tail"]).listen == DEFAULT_TAIL_LISTEN
    port = int(DEFAULT_TAIL_LISTEN.rsplit(":", 1)[1])
    # As a context manager: its pipes are closed and it is waited for on every way out,
    # a skip included.
    with subprocess.Popen(
        [sys.executable, "-m", "hdrd", "tail", "--count", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    ) as p:
        try:
            deadline = time.monotonic() + WAIT
            bound: list[dict[str, Any]] = []
            while not bound and time.monotonic() < deadline:
                if p.poll() is not None:
                    err = p.stderr.read().decode() if p.stderr else ""
                    if "in use" in err:
                        pytest.skip(
                            f"the default port {port} is taken on this machine: {err.strip()}"
                        )
                    raise AssertionError(err)
                bound = [s for s in inet_sockets(p.pid) if s["local"][1] == port]
                time.sleep(0.02)
            assert bound, "hdrd tail bound nothing"
            assert [s["local"] for s in bound] == [("127.0.0.1", port)]
            assert bound[0]["proto"] == "udp"
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(b'{"class":"HDR","v":1,"step":0,"status":"ok"}\n', ("127.0.0.1", port))
            out, _ = p.communicate(timeout=WAIT)
            assert p.returncode == 0 and b"ok" in out
        finally:
            if p.poll() is None:
                p.kill()
                p.communicate()


# --------------------------------------------------------------------------- no shell, no eval

SHELL_CALLS = {
    "os.system",
    "os.popen",
    "subprocess.getoutput",
    "subprocess.getstatusoutput",
    "pty.spawn",
    "commands.getoutput",
}
SUBPROCESS = {
    "subprocess.Popen",
    "subprocess.run",
    "subprocess.call",
    "subprocess.check_call",
    "subprocess.check_output",
}
UNSAFE_YAML = {
    "yaml.load",
    "yaml.load_all",
    "yaml.unsafe_load",
    "yaml.unsafe_load_all",
    "yaml.full_load",
    "yaml.full_load_all",
}
UNSAFE_MODULES = {"pickle", "cPickle", "marshal", "shelve", "dill"}


def _dotted(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return ""


def dangerous_calls(source: str, filename: str = "<src>") -> list[str]:
    """Every place in ``source`` that runs a shell or a program, evaluates code, unpickles or
    loads YAML unsafely; ``from os import system``-style imports are resolved."""
    tree = ast.parse(source, filename)
    aliases: dict[str, str] = {}
    found: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            for a in node.names:
                aliases[a.asname or a.name] = f"{node.module}.{a.name}"
            if node.module.split(".")[0] in UNSAFE_MODULES:
                found.append(f"{filename}:{node.lineno}: imports {node.module}")
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in UNSAFE_MODULES:
                    found.append(f"{filename}:{node.lineno}: imports {a.name}")
                if a.asname:
                    aliases[a.asname] = a.name
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _dotted(node.func)
        head, _, rest = name.partition(".")
        name = f"{aliases[head]}.{rest}".rstrip(".") if head in aliases else name
        where = f"{filename}:{node.lineno}: {name}"
        kw = {k.arg: k.value for k in node.keywords}
        runs_code = name in ("eval", "exec", "builtins.eval", "builtins.exec", "compile")
        if (
            runs_code
            or name in SHELL_CALLS
            or name.startswith(("os.exec", "os.spawn", "os.posix_spawn"))
        ):
            found.append(where)
        elif name in SUBPROCESS:
            shell = kw.get("shell")
            if shell is not None and not (isinstance(shell, ast.Constant) and shell.value is False):
                found.append(f"{where} with shell=")
            first = node.args[0] if node.args else kw.get("args")
            if isinstance(first, (ast.JoinedStr, ast.BinOp)) or (
                isinstance(first, ast.Constant) and isinstance(first.value, str)
            ):
                found.append(f"{where} with a command string")
        elif name in UNSAFE_YAML:
            loader = kw.get("Loader") or (node.args[1] if len(node.args) > 1 else None)
            if loader is None or _dotted(loader).split(".")[-1] not in (
                "SafeLoader",
                "CSafeLoader",
                "BaseLoader",
            ):
                found.append(f"{where} without a safe Loader")
    return found


def test_no_shell_eval_or_unsafe_loading_in_hdrd() -> None:
    found = []
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) > 15
    for f in files:
        found += dangerous_calls(f.read_text(encoding="utf-8"), str(f.relative_to(ROOT)))
    assert found == []


def test_the_scan_finds_what_it_looks_for() -> None:
    bad = """
import os, subprocess, yaml, pickle
from os import system as run_it
import subprocess as sp
os.system("ls " + name)
run_it(cmd)
os.popen(cmd)
os.execvp("sh", ["sh"])
subprocess.run(f"gpsd {port}", check=True)
subprocess.check_output(["x"], shell=True)
sp.Popen(cmd, shell=flag)
eval(text)
exec(text)
yaml.load(text)
yaml.load(text, Loader=yaml.Loader)
"""
    found = dangerous_calls(bad)
    assert len(found) == 12, found
    good = """
import subprocess, yaml
subprocess.run(["systemd-analyze", "verify", path], check=False)
subprocess.run(argv, shell=False)
yaml.safe_load(text)
yaml.load(text, Loader=yaml.SafeLoader)
"""
    assert dangerous_calls(good) == []


# --------------------------------------------------------------------------- who it runs as


def unit_directives() -> list[tuple[str, str]]:
    out = []
    section = ""
    for line in UNIT.read_text().splitlines():
        line = line.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        if section == "Service":
            out.append((key.strip(), value.strip()))
    return out


def test_the_unit_runs_unprivileged_and_writes_only_its_state_directory() -> None:
    d = unit_directives()
    keys = [k for k, _ in d]
    one = dict(d)
    assert one["DynamicUser"] == "yes"
    assert [v for k, v in d if k == "SupplementaryGroups"] == ["dialout"]  # the only extra group
    assert "User" not in keys and "Group" not in keys  # no fixed (let alone root) identity
    assert one.get("AmbientCapabilities", "") == "" and one["CapabilityBoundingSet"] == ""
    assert one["NoNewPrivileges"] == "yes"
    exec_lines = [v for k, v in d if k.startswith("Exec")]
    assert all(not v.startswith(("+", "!", "@")) for v in exec_lines)  # no privileged prefixes
    assert "PermissionsStartOnly" not in keys
    # It writes only $STATE_DIRECTORY (the bias file): the system is read-only, home hidden.
    assert one["ProtectSystem"] == "strict" and one["ProtectHome"] == "yes"
    assert not [
        k
        for k in keys
        if k in ("ReadWritePaths", "LogsDirectory", "CacheDirectory", "RuntimeDirectory")
    ]
    assert one["StateDirectory"] == "hdrd" and one["StateDirectoryMode"] == "0755"
    assert one["UMask"] == "0022"


def test_the_daemon_finds_its_bias_in_the_units_state_directory(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from hdrd.io.files.access import default_bias_path

    monkeypatch.setenv("STATE_DIRECTORY", f"{tmp_path}/hdrd")
    assert default_bias_path() == tmp_path / "hdrd" / "bias.yaml"
    monkeypatch.setenv("STATE_DIRECTORY", f"{tmp_path}/a:{tmp_path}/b")  # systemd lists several
    assert default_bias_path() == tmp_path / "a" / "bias.yaml"
    monkeypatch.delenv("STATE_DIRECTORY")
    assert default_bias_path() == Path("/var/lib/hdrd/bias.yaml")  # StateDirectory=hdrd's path


def test_hdrd_web_listens_on_loopback_by_default() -> None:
    from hdrd.cli import build_parser
    from hdrd.io.web.http import is_loopback
    from hdrd.io.web.webserver import DEFAULT_WEB_LISTEN

    args = build_parser().parse_args(["web"])
    for address in (args.listen, args.udp, DEFAULT_WEB_LISTEN):
        assert is_loopback(address.rsplit(":", 1)[0]), address
