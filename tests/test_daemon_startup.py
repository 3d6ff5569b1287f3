"""``hdrd run``'s start-up, configuration reload and bias choice under hostile input: real
processes, real ptys, real signals, real sockets (hdrd/daemon/run.py, hdrd/io/wire/serialport.py).

No timings are asserted; the waits are generous bounds that only fail a hung daemon.
"""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from hdrd.sim.profiles import builtin_profile
from tests.test_daemon import WAIT, Daemon, daemon, events, udp  # noqa: F401 - fixtures

STANDSTILL = builtin_profile("standstill", minutes=10, bias_dps=0.2, lead_in_s=0)


def _maps(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return ""


@pytest.mark.slow
def test_sighup_during_start_up_does_not_kill_the_daemon(fake_gyro, daemon, udp) -> None:  # noqa: F811
    # SIGHUP's default action ends a process; hdrd run used to take it over only when its loop
    # began (~0.3 s after start), so a reload sent early killed it. Sent here while the
    # daemon is importing numpy (its shared object just mapped), long before the loop.
    g = fake_gyro(STANDSTILL, speedup=5)
    u = udp()
    d = daemon("--clock-rate", "5", "--port", g.path, "--bias", "0.2", "--udp", u.addr)
    deadline = time.monotonic() + WAIT
    while "_multiarray_umath" not in _maps(d.proc.pid):
        assert d.proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.001)
    d.signal(signal.SIGHUP)
    g.start()
    got = u.messages(lambda ms: len(ms) >= 2)
    assert d.proc.poll() is None
    d.signal(signal.SIGHUP)  # and once running, as always
    more = u.messages(lambda ms: len(ms) >= 2)
    rc, _, err = d.stop()
    assert rc == 0, err.decode()
    assert more[-1]["step"] > got[-1]["step"]
    reloads = [e for e in events(err) if e["event"] == "config_reloaded"]
    assert 1 <= len(reloads) <= 2  # the held one (if it came after the handler) and the later


# Starts `hdrd` the way ENTRY says (python -m hdrd, or the console script's import of the
# entry point pyproject.toml names) and sends itself SIGHUP when hdrd.cli is first imported:
# the earliest moment after hdrd's own first statement, long before the argument parser and
# the daemon. Found through the interpreter's audit events (PEP 578).
HUP_AT_CLI_IMPORT = r"""
import os, runpy, signal, sys
entry, argv = sys.argv[1], sys.argv[2:]
def hook(event, args):
    if event == "import" and args[0] == "hdrd.cli":
        os.kill(os.getpid(), signal.SIGHUP)
sys.addaudithook(hook)
sys.argv = ["hdrd", *argv]
if entry == "-m":
    runpy.run_module("hdrd", run_name="__main__", alter_sys=True)
else:
    module, _, func = entry.partition(":")
    sys.exit(getattr(__import__(module, fromlist=[func]), func)())
"""


def _console_entry() -> str:
    """The ``hdrd`` console script's entry point, ``module:function``, from pyproject.toml."""
    import re

    text = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    m = re.search(r'^\[project\.scripts\]\s*\nhdrd = "([\w.]+:\w+)"', text, flags=re.MULTILINE)
    assert m, "no hdrd entry in pyproject.toml's [project.scripts]"
    return m.group(1)


@pytest.mark.slow
@pytest.mark.parametrize("entry", ["-m", "console script"])
def test_sighup_at_hdrds_first_import_is_a_reload(entry: str, udp, tmp_path: Path) -> None:  # noqa: F811
    """SIGHUP in the first few hundredths of a second of `hdrd run` (sent here the moment
    hdrd.cli is imported, before argument parsing) used to end the daemon: the hold came
    after parsing. It is the entry point's first statement now: the daemon lives, reloads."""
    u = udp()
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("simulate:\n  drive: standstill\n  speedup: 20\n")
    env = dict(os.environ, STATE_DIRECTORY=str(tmp_path))
    for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC"):
        env.pop(k, None)
    target = "-m" if entry == "-m" else _console_entry()
    argv = ["run", "--simulate", "--config", str(cfg), "--udp", u.addr, "--log-format", "json"]
    proc = subprocess.Popen(
        [sys.executable, "-c", HUP_AT_CLI_IMPORT, target, *argv],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
    )
    try:
        got = u.messages(lambda ms: len(ms) >= 3)
    except (AssertionError, OSError):
        proc.kill()
        _, err = proc.communicate(timeout=WAIT)
        raise AssertionError(
            f"no messages; exit {proc.returncode}: {err.decode()[-800:]}"
        ) from None
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=WAIT)
    assert proc.returncode == 0, err.decode()[-800:]
    assert got[-1]["step"] >= 2
    reloads = [e for e in events(err) if e["event"] == "config_reloaded"]
    assert len(reloads) == 1, err.decode()[-800:]  # the held SIGHUP, taken as a reload


def _block_hangup() -> None:
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})


@pytest.mark.slow
def test_a_sighup_the_parent_blocked_is_a_reload_once_the_daemon_runs(udp, tmp_path: Path) -> None:  # noqa: F811
    """Before hdrd's first statement the interpreter starts, and no handler can exist yet:
    a sender that must not kill a starting daemon starts it with SIGHUP blocked (the mask
    passes through exec). Here a SIGHUP is sent at once, before the interpreter has started.
    hdrd used to leave SIGHUP blocked: no reload, ever. Now it unblocks it once its handler
    is in place: the waiting SIGHUP is a reload, and so is a later one."""
    u = udp()
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("simulate:\n  drive: standstill\n  speedup: 20\n")
    env = dict(os.environ, STATE_DIRECTORY=str(tmp_path))
    for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC"):
        env.pop(k, None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "run", "--simulate", "--config", str(cfg),
         "--udp", u.addr, "--log-format", "json"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
        preexec_fn=_block_hangup,
    )  # fmt: skip
    proc.send_signal(signal.SIGHUP)  # pending until hdrd unblocks it
    try:
        u.messages(lambda ms: len(ms) >= 3)
        proc.send_signal(signal.SIGHUP)  # and once running
        u.messages(lambda ms: len(ms) >= 3)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=WAIT)
    assert proc.returncode == 0, err.decode()[-800:]
    reloads = [e for e in events(err) if e["event"] == "config_reloaded"]
    assert len(reloads) == 2, err.decode()[-800:]


@pytest.mark.slow
def test_sighup_with_a_file_the_yaml_parser_cannot_take_keeps_the_old_config(
    fake_gyro,
    daemon,  # noqa: F811
    udp,  # noqa: F811
    tmp_path: Path,
) -> None:
    # A number of 5,000 digits, nesting 2,000 deep, a FIFO (was: the daemon died, or hung
    # reading the FIFO), /dev/zero's worth: each is refused and the daemon carries on.
    u = udp()
    cfg = tmp_path / "hdrd.yaml"
    good = f"output:\n  udp: ['{u.addr}']\n"
    cfg.write_text(good)
    g = fake_gyro(STANDSTILL, speedup=5)
    d = daemon("--clock-rate", "5", "--config", str(cfg), "--port", g.path, "--bias", "0.2")
    g.start()
    u.messages(lambda ms: len(ms) >= 1)

    def fifo() -> None:
        cfg.unlink()
        os.mkfifo(cfg)

    def too_big() -> None:
        cfg.unlink()
        cfg.write_text(good + "#" * (2 << 20) + "\n")

    breakages = [
        ("digits", lambda: cfg.write_text(good + "hdr:\n  c2: " + "1" * 5000 + "\n")),
        ("depth", lambda: cfg.write_text(good + "x: " + "[" * 2000 + "]" * 2000 + "\n")),
        ("fifo", fifo),
        ("big", too_big),
    ]
    for _, breakage in breakages:
        breakage()
        d.signal(signal.SIGHUP)
        u.messages(lambda ms: len(ms) >= 3)  # still publishing, to the same place
        assert d.proc.poll() is None
    rc, _, err = d.stop()
    assert rc == 0, err.decode()
    failed = [e["error"] for e in events(err) if e["event"] == "config_reload_failed"]
    assert len(failed) == 4 and all("\n" not in f for f in failed)
    assert "YAML value cannot be converted" in failed[0]
    assert "nested deeper than 32 levels" in failed[1]
    assert "is a FIFO, not a regular file" in failed[2]
    assert "larger than the 1 MiB allowed" in failed[3]
    assert b"Traceback" not in err


@pytest.mark.parametrize(
    "text, why",
    [
        ("hdr:\n  c2: " + "1" * 5000 + "\n", "YAML value cannot be converted"),
        ("a: " + "[" * 2000 + "]" * 2000 + "\n", "nested deeper than 32 levels"),
        ("hdr:\n  c2: 1000\n", "hdr.c2 = 1000.0: must be a finite number >= 0 and <= 10"),
        ("calibration:\n  startup_s: 1.0e+308\n", "calibration.startup_s = 1e+308"),
    ],
)
def test_a_bad_config_at_start_is_exit_78_with_one_line(
    tmp_path: Path, text: str, why: str
) -> None:
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(text)
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "run", "--simulate", "--config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 78, p.stderr
    assert len(p.stderr.splitlines()) == 1 and why in p.stderr and p.stdout == ""


@pytest.mark.parametrize("bias", ["nan", "inf", "1e308", "-5"])
def test_run_bias_must_be_finite_and_within_the_limit(bias: str) -> None:
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "run", "--simulate", f"--bias={bias}"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 78, p.stderr
    assert p.stderr == (
        f"hdrd: config error in command line: --bias = {float(bias)!r}: must be a finite "
        "number within +/-3 deg/s (calibration.max_bias_dps)\n"
    )


@pytest.mark.parametrize(
    "body",
    [
        "bias_dps: " + "1" * 5000 + "\n",  # more digits than Python converts
        "bias_dps: " + "[" * 2000 + "]" * 2000 + "\n",  # nested too deep
        "bias_dps: 1.0e+308\n",  # finite, but no gyro's bias
    ],
    ids=["digits", "depth", "1e308"],
)
@pytest.mark.slow
def test_a_bias_file_the_daemon_cannot_take(tmp_path: Path, body: str) -> None:
    bias_file = tmp_path / "bias.yaml"
    bias_file.write_text(body + "std_dps: 0.01\nn: 10\nduration_s: 1.0\ntime: 0.0\n# end\n")
    cmd = [sys.executable, "-m", "hdrd", "run", "--simulate", "--bias-file", str(bias_file)]
    # on_bad_bias_file: error (the default): exit 1, one line naming the file.
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert p.returncode == 1 and "Traceback" not in p.stderr
    assert f"hdrd: bias file {bias_file}: " in p.stderr
    # on_bad_bias_file: calibrate: the daemon measures the bias itself instead.
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(
        "calibration:\n  on_bad_bias_file: calibrate\n"
        "simulate:\n  drive: standstill\n  speedup: 50\n"
    )
    proc = subprocess.Popen(
        [*cmd, "--config", str(cfg), "--stdout", "--log-format", "json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert '"status":"calibrating"' in first
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=WAIT)
    assert proc.returncode == 0 and "bias_file_rejected" in err and "Traceback" not in err


def test_run_with_stdout_closed(tmp_path: Path) -> None:
    # `hdrd run >&-`: was a traceback. With stdout the only output it is one clear line...
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "run", "--simulate"],
        stderr=subprocess.PIPE,
        text=True,
        timeout=60,
        preexec_fn=lambda: os.close(1),
    )
    assert p.returncode == 1 and "Traceback" not in p.stderr
    assert p.stderr.startswith("hdrd: stdout is closed and is the only output configured;")
    assert len(p.stderr.splitlines()) == 1


@pytest.mark.slow
def test_run_with_stdout_closed_publishes_elsewhere(udp) -> None:  # noqa: F811
    # ... and with another output it runs (fd 1 pointed at /dev/null, not at a port).
    u = udp()
    cfg_speed = ["--simulate", "--speedup", "50", "--bias", "0.2", "--udp", u.addr]
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "run", *cfg_speed, "--log-format", "json"],
        stderr=subprocess.PIPE,
        preexec_fn=lambda: os.close(1),
    )
    try:
        got = u.messages(lambda ms: len(ms) >= 3)
        assert [m["step"] for m in got] == [0, 1, 2]
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=WAIT)
    assert proc.returncode == 0 and b"Traceback" not in err


@pytest.mark.slow
def test_log_level_flag(tmp_path: Path) -> None:
    # A rejected bias file is a warning: shown at --log-level warning, not at error.
    bias_file = tmp_path / "bias.yaml"
    bias_file.write_text("garbage\n")
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(
        "calibration:\n  on_bad_bias_file: calibrate\n"
        "simulate:\n  drive: standstill\n  speedup: 50\n"
    )
    base = [sys.executable, "-m", "hdrd", "run", "--simulate", "--config", str(cfg), "--stdout"]
    for level, shown in (("warning", True), ("error", False)):
        proc = subprocess.Popen(
            [*base, "--bias-file", str(bias_file), "--log-format", "json", "--log-level", level],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            assert proc.stdout is not None and proc.stdout.readline()
        finally:
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=WAIT)
        assert proc.returncode == 0
        assert ('"bias_file_rejected"' in err) is shown, err
        assert ('"start"' in err) is False  # info
    p = subprocess.run([*base, "--log-level", "loud"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "invalid choice: 'loud'" in p.stderr


@pytest.mark.slow
def test_a_socket_port_whose_listener_never_answers_does_not_stall_the_loop(
    daemon,  # noqa: F811
    udp,  # noqa: F811
    tmp_path: Path,
) -> None:
    # A listener whose backlog is full: a connect waits for an answer that never comes.
    # pyserial's socket:// open blocked 5 s per attempt, so the daemon's loop (stale reports,
    # signals, reloads) stood still; connecting now goes on in the background.
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(0)
    port = srv.getsockname()[1]
    fillers = []
    for _ in range(16):  # fill the accept queue and the SYN queue
        c = socket.socket()
        c.setblocking(False)
        c.connect_ex(("127.0.0.1", port))
        fillers.append(c)
    try:
        cfg = tmp_path / "hdrd.yaml"
        cfg.write_text("device:\n  stale_after_s: 0.2\nhdr:\n  T: 0.2\n")
        u = udp()
        d = daemon(
            "--config", str(cfg), "--port", f"socket://127.0.0.1:{port}", "--bias", "0",
            "--udp", u.addr,
        )  # fmt: skip
        # One stale report per T (0.2 s) while the connection is tried: 60 of them come in
        # ~12 s. A loop that stands 5 s in each attempt (pyserial's connect timeout; the
        # attempts 0.5, 1, 2, 4 ... s apart) is free a quarter of the time: it needs ~50 s,
        # beyond WAIT (30 s).
        got = u.messages(lambda ms: len(ms) >= 60)
        assert {m["status"] for m in got} == {"stale"}
        rc, _, err = d.stop()
        assert rc == 0 and b"Traceback" not in err
    finally:
        for c in fillers:
            c.close()
        srv.close()


class _Log:
    """The daemon's JSON log lines on its stderr, read as they come (never blocking past
    WAIT)."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stderr is not None
        self.fd = proc.stderr.fileno()
        self.buf = b""
        self.events: list[dict[str, Any]] = []

    def until(self, want: str) -> dict[str, Any]:
        """Read until an event named ``want`` (one not returned before); fail on EOF/WAIT."""
        seen = len(self.events)
        deadline = time.monotonic() + WAIT
        while True:
            for e in self.events[seen:]:
                if e.get("event") == want:
                    return e
            seen = len(self.events)
            left = deadline - time.monotonic()
            ready = select.select([self.fd], [], [], max(0.0, left))[0] if left > 0 else []
            chunk = os.read(self.fd, 65536) if ready else b""
            if not chunk:
                raise AssertionError(f"no {want}; got {[e.get('event') for e in self.events]}")
            self.buf += chunk
            *lines, self.buf = self.buf.split(b"\n")
            for line in lines:
                try:
                    self.events.append(json.loads(line))
                except json.JSONDecodeError:
                    pass


@pytest.mark.slow
def test_a_port_that_does_not_exist_is_said_at_once_and_waited_for(
    fake_gyro,
    udp,  # noqa: F811
    tmp_path: Path,
) -> None:
    """`hdrd run --port /dev/nonexistent` used to look like a silent gyro for ever (a
    "device_lost" with a long pyserial message, then only stale reports). At start it now
    says that the port does not exist and that it waits for it; when the device appears it
    is opened and the steps come."""
    u = udp()
    port = tmp_path / "hdrd-gyro"  # not there yet
    env = dict(os.environ, STATE_DIRECTORY=str(tmp_path))
    for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC"):
        env.pop(k, None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "run", "--port", str(port), "--bias", "0.2",
         "--udp", u.addr, "--log-format", "json"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
    )  # fmt: skip
    log = _Log(proc)
    try:
        waiting = log.until("device_waiting")
        assert waiting["level"] == "warning" and waiting["port"] == str(port)
        assert waiting["reason"] == f"{port} does not exist"
        assert f"hdrd opens {port} when it appears" in waiting["waiting"]
        assert "device_lost" not in [e.get("event") for e in log.events]
        g = fake_gyro(STANDSTILL, speedup=5, link=port)
        g.start()
        opened = log.until("device_open")
        assert opened["port"] == str(port) and opened["waited_s"] >= 0
        got = u.messages(lambda ms: sum(1 for m in ms if m["status"] != "stale") >= 2)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=WAIT)
    assert proc.returncode == 0, log.events[-5:]
    assert any(m["status"] == "ok" for m in got)
