"""Bad configuration and state, as `hdrd run` and `hdrd calibrate` meet them.

Already covered elsewhere and not repeated: every config key with each kind of bad value
(wrong type, out of range, NaN/inf), unknown keys per section, empty file, YAML errors and a
missing file, through the parser and through `hdrd replay` (tests/test_config.py); every
truncation and many corruptions of a bias file, the 0644 mode whatever the umask, a failed
or interrupted write (tests/test_biasfile.py); a truncated bias file refused by `hdrd run`
(tests/test_daemon.py).

Here, as processes: `hdrd run` exits 78 with one line naming the key for a representative
subset and every file-level error; a corrupted bias file stops it with a clear error (exit
1), or with ``calibration.on_bad_bias_file: calibrate`` makes it measure the bias at start
(never a silently wrong bias); and a power cut (SIGKILL) at any moment of `hdrd calibrate`,
the writing of the bias file included, leaves the old file or a whole new one, and at most
one temporary file.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hdrd.core.calibrate import BiasRecord
from hdrd.io.files.biasfile import load_bias, save_bias
from hdrd.sim.profiles import builtin_profile

WAIT = 60.0


def env_with(state: Path | None = None) -> dict[str, str]:
    e = dict(os.environ)
    for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC"):
        e.pop(k, None)
    e["STATE_DIRECTORY"] = str(state) if state else "/nonexistent-hdrd-state"
    return e


def hdrd_all(
    cases: dict[str, tuple[list[str], dict[str, str]]],
) -> dict[str, subprocess.CompletedProcess[bytes]]:
    """Run several hdrd commands at once (each is mostly interpreter start-up)."""
    procs = {
        name: subprocess.Popen(
            [sys.executable, "-m", "hdrd", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
        )
        for name, (argv, env) in cases.items()
    }
    out = {}
    for name, p in procs.items():
        try:
            o, e = p.communicate(timeout=WAIT)
        finally:
            if p.poll() is None:
                p.kill()
                p.communicate()
        out[name] = subprocess.CompletedProcess(p.args, p.returncode, o, e)
    return out


# --------------------------------------------------------------------------- exit 78

# (file text, or None for no file at all; extra command-line arguments; what the line names)
CONFIG_CASES: dict[str, tuple[str | None, list[str], str]] = {
    "wrong type": ('device:\n  baud: "9600"\n', [], "device.baud = "),
    "NaN": ("hdr:\n  tau: .nan\n", [], "hdr.tau = "),
    "inf": ("hdr:\n  T: .inf\n", [], "hdr.T = "),
    "out of range": ("output:\n  heading0_deg: 360\n", [], "output.heading0_deg = "),
    "not allowed": (
        "calibration:\n  on_bad_bias_file: ignore\n",
        [],
        "calibration.on_bad_bias_file = ",
    ),
    "bad destination": ("output:\n  udp: [localhost]\n", [], "output.udp = "),
    "unknown key": ("device:\n  bogus: 1\n", [], "device.bogus = "),
    "unknown section": ("bogus:\n  x: 1\n", [], "bogus"),
    "empty file": ("", [], "empty"),
    "not a mapping": ("- device\n- hdr\n", [], "mapping"),
    "YAML syntax error": ("hdr: [\n", [], "line 2"),
    "missing file": (None, [], "no such file"),
    "bad override": ("", ["--heading0", "400"], "output.heading0_deg = "),
}


@pytest.mark.slow
def test_run_exits_78_with_one_line_naming_the_key(tmp_path: Path) -> None:
    cases = {}
    files = {}
    for name, (text, extra, _) in CONFIG_CASES.items():
        path = tmp_path / f"{name.replace(' ', '_')}.yaml"
        if text is not None and not name.startswith("bad override"):
            path.write_text(text)
        files[name] = path
        argv = ["run", "--port", str(tmp_path / "never-opened")]
        argv += [] if name.startswith("bad override") else ["--config", str(path)]
        cases[name] = (argv + extra, env_with())
    got = hdrd_all(cases)
    for name, (_, _, names) in CONFIG_CASES.items():
        r = got[name]
        err = r.stderr.decode()
        lines = err.splitlines()
        assert r.returncode == 78, (name, err)
        assert r.stdout == b"", name
        assert len(lines) == 1, (name, err)
        where = "command line" if name.startswith("bad override") else str(files[name])
        at = ", line 2, column 1" if name == "YAML syntax error" else ""  # where in the file
        assert lines[0].startswith(f"hdrd: config error in {where}{at}: "), (name, lines[0])
        assert names in lines[0], (name, lines[0])


# --------------------------------------------------------------------------- bias files


def good_bias_text(tmp_path: Path) -> str:
    p = tmp_path / "good.yaml"
    save_bias(p, BiasRecord(0.31, 0.02, 300, 30.0, 20.5, 1.7e9))
    return p.read_text()


@pytest.mark.slow
def test_corrupted_bias_file_is_a_clear_error(tmp_path: Path) -> None:
    good = good_bias_text(tmp_path)
    variants: dict[str, str | bytes | None] = {
        "truncated": good[: len(good) // 2],
        "empty": "",
        "binary": bytes(range(256)) * 4,
        "NaN bias": good.replace("bias_dps: 0.31", "bias_dps: .nan"),
        "missing key": good.replace("bias_dps: 0.31\n", ""),
        "not a mapping": "- 0.31\n# end\n",
        "a directory": None,
    }
    cases = {}
    for name, content in variants.items():
        path = tmp_path / f"{name.replace(' ', '_')}.yaml"
        if content is None:
            path.mkdir()
        elif isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
        cases[name] = (
            ["run", "--port", str(tmp_path / "never-opened"), "--bias-file", str(path)],
            env_with(),
        )
    cases["named but missing"] = (
        [
            "run",
            "--port",
            str(tmp_path / "never-opened"),
            "--bias-file",
            str(tmp_path / "nope.yaml"),
        ],
        env_with(),
    )
    # The default place, $STATE_DIRECTORY/bias.yaml, is checked the same way.
    state = tmp_path / "state"
    state.mkdir()
    (state / "bias.yaml").write_text(good[: len(good) - 10])
    cases["default path"] = (["run", "--port", str(tmp_path / "never-opened")], env_with(state))
    got = hdrd_all(cases)
    for name, r in got.items():
        err = r.stderr.decode()
        assert r.returncode == 1, (name, err)
        assert r.stdout == b"" and "Traceback" not in err, name
        plain = [line for line in err.splitlines() if line.startswith("hdrd: ")]
        assert len(plain) == 1 and plain[0].startswith("hdrd: bias file "), (name, err)
        logged = [json.loads(line) for line in err.splitlines() if line.startswith("{")]
        assert [e["event"] for e in logged] == ["bias_file_invalid"], (name, err)
    assert "not found" in got["named but missing"].stderr.decode()
    assert "truncated" in got["default path"].stderr.decode()


@pytest.mark.slow
def test_bad_bias_file_with_fallback_measures_the_bias_at_start(fake_gyro, tmp_path: Path) -> None:
    """calibration.on_bad_bias_file: calibrate: a truncated file that says 5 deg/s is not
    used; the daemon says it calibrates, then publishes the bias it measured (0.25)."""
    import socket

    bias_file = tmp_path / "bias.yaml"
    bias_file.write_text("bias_dps: 5.0\nstd_dps: 0.01\nn: 300\n")  # cut short: no '# end'
    before = bias_file.read_bytes()
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(f"calibration:\n  on_bad_bias_file: calibrate\n  bias_file: {bias_file}\n")
    g = fake_gyro(
        builtin_profile("standstill", minutes=1, bias_dps=0.25, noise_dps=0.05, lead_in_s=0),
        speedup=0,
    )
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(WAIT)
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hdrd",
            "run",
            "--clock-rate",
            "0",
            "--config",
            str(cfg),
            "--port",
            g.path,
            "--udp",
            f"127.0.0.1:{rx.getsockname()[1]}",
            "--log-format",
            "json",
        ],
        stderr=subprocess.PIPE,
        env=env_with(),
    )
    try:
        g.start()
        msgs = [json.loads(rx.recv(65536)) for _ in range(4)]
    finally:
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=WAIT)
        rx.close()
    assert p.returncode == 0
    assert msgs[0]["status"] == "calibrating" and "bias" not in msgs[0]
    assert all(m["bias"] == pytest.approx(0.25, abs=0.03) for m in msgs[1:])
    events = [json.loads(line) for line in err.decode().splitlines() if line.startswith("{")]
    rejected = [e for e in events if e["event"] == "bias_file_rejected"]
    assert (
        rejected
        and "truncated" in rejected[0]["error"]
        and rejected[0]["fallback"] == "startup calibration"
    )
    start = next(e for e in events if e["event"] == "start")
    assert start["bias"] == "startup"
    assert bias_file.read_bytes() == before  # the daemon never writes the bias file


# --------------------------------------------------------------------------- power cut during calibrate

# Runs `hdrd calibrate` and SIGKILLs itself at a chosen point of the bias file's writing,
# found through the interpreter's audit events (PEP 578), which come before each call, and for
# "after rename" the return of os.replace seen by a profile function: no change to the code
# under test. The writer works in its folder by descriptor: its temp file is opened by name
# relative to the folder (".bias.yaml.PID.RANDOM.tmp", O_CREAT), chmod'ed and renamed by
# descriptor.
KILLER = r"""
import os, signal, sys, threading
point, state = sys.argv[1], sys.argv[2]
armed, renamed = [], []
def hook(event, args):
    if (event == "open" and isinstance(args[0], str) and args[2] is not None
            and os.path.basename(args[0]).startswith(".bias.yaml.") and args[2] & os.O_CREAT):
        armed.append(args[0])  # raised just before the temp file is created
        return
    if event == "os.rename" and armed:
        renamed.append(args)
    hit = armed and (
        # the temp file's fd wrapped by os.fdopen: it exists, empty
        (point == "temp created" and event == "open" and isinstance(args[0], int))
        or (point == "temp written" and event == "os.chmod")  # written and fsync'd
        or (point == "before rename" and event == "os.rename")
    )
    if hit:
        os.kill(os.getpid(), signal.SIGKILL)
def returned(frame, event, arg):
    if point == "after rename" and renamed and event == "c_return" and arg is os.replace:
        os.kill(os.getpid(), signal.SIGKILL)
sys.addaudithook(hook)
sys.setprofile(returned)
threading.setprofile(returned)
from hdrd.cli import main
sys.exit(main(sys.argv[3:]))
"""

POINTS = ["temp created", "temp written", "before rename", "after rename"]


def simulated_standstill_config(tmp_path: Path, speedup: float) -> Path:
    cfg = tmp_path / f"sim-{speedup:g}.yaml"
    cfg.write_text(f"simulate:\n  drive: standstill\n  speedup: {speedup}\n  rate_hz: 10\n")
    return cfg


def temps(state: Path) -> list[str]:
    return [n for n in os.listdir(state) if n.endswith(".tmp")]


def check_whole(state: Path, old: bytes | None) -> str:
    """The bias file is the old one or a whole valid new one; at most one temp file."""
    assert len(temps(state)) <= 1, os.listdir(state)
    f = state / "bias.yaml"
    if not f.exists():
        assert old is None
        return "none"
    data = f.read_bytes()
    if data == old:
        return "old"
    load_bias(f)  # whole and valid, or BiasFileError
    assert (f.stat().st_mode & 0o777) == 0o644
    return "new"


OLD = BiasRecord(0.111, 0.01, 100, 10.0, None, 1.6e9)


def write_old(state: Path) -> bytes:
    save_bias(state / "bias.yaml", OLD)
    return (state / "bias.yaml").read_bytes()


@pytest.mark.slow
def test_power_cut_at_each_point_of_the_write(tmp_path: Path) -> None:
    """SIGKILL with the temp file just created, written (fsync'd, before chmod), right before
    the rename, right after it; with and without an old bias file."""
    cfg = simulated_standstill_config(tmp_path, 1000)
    procs = {}
    old: dict[tuple[str, bool], bytes | None] = {}
    for first in (True, False):
        for point in POINTS:
            state = tmp_path / f"{point.replace(' ', '_')}-{'first' if first else 'again'}"
            state.mkdir()
            old[(point, first)] = None if first else write_old(state)
            argv = [
                point,
                str(state),
                "calibrate",
                "--simulate",
                "--config",
                str(cfg),
                "--seconds",
                "2",
            ]
            procs[(point, first)] = (
                state,
                subprocess.Popen(
                    [sys.executable, "-c", KILLER, *argv],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.PIPE,
                    env=env_with(state),
                ),
            )
    for (point, first), (state, p) in procs.items():
        _, err = p.communicate(timeout=WAIT)
        assert p.returncode == -signal.SIGKILL, (point, first, err.decode())
        want = "new" if point == "after rename" else ("none" if first else "old")
        assert check_whole(state, old[(point, first)]) == want, (point, first, os.listdir(state))


@pytest.mark.slow
def test_repeated_power_cuts_leave_at_most_one_temp_file(tmp_path: Path) -> None:
    """Killed three times with its temporary file just created, then run to the end: the
    leftovers do not pile up, and a successful write leaves none."""
    cfg = simulated_standstill_config(tmp_path, 1000)
    state = tmp_path / "state"
    state.mkdir()
    old = write_old(state)
    argv = ["calibrate", "--simulate", "--config", str(cfg), "--seconds", "2"]
    for _ in range(3):
        p = subprocess.run(
            [sys.executable, "-c", KILLER, "temp created", str(state), *argv],
            capture_output=True,
            check=False,
            timeout=WAIT,
            env=env_with(state),
        )
        assert p.returncode == -signal.SIGKILL, p.stderr.decode()
        assert check_whole(state, old) == "old"
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", *argv],
        capture_output=True,
        check=False,
        timeout=WAIT,
        env=env_with(state),
    )
    assert p.returncode == 0, p.stderr.decode()
    assert check_whole(state, old) == "new" and temps(state) == []


@pytest.mark.slow
def test_power_cut_at_random_moments(tmp_path: Path) -> None:
    """SIGKILL at random moments of `hdrd calibrate` (start-up, measuring, writing, exiting):
    whatever the moment, the old file or a whole new one."""
    cfg = simulated_standstill_config(tmp_path, 20)  # 10 s of standstill in 0.5 s
    rng = random.Random(7)
    runs: list[tuple[Path, bytes, subprocess.Popen[bytes], float]] = []
    for i in range(8):
        state = tmp_path / f"run{i}"
        state.mkdir()
        old = write_old(state)
        p = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "hdrd",
                "calibrate",
                "--simulate",
                "--config",
                str(cfg),
                "--seconds",
                "10",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env_with(state),
        )
        runs.append((state, old, p, time.monotonic() + rng.uniform(0.2, 2.0)))
    outcomes = []
    try:
        for state, old, p, at in sorted(runs, key=lambda r: r[3]):
            time.sleep(max(0.0, at - time.monotonic()))
            p.kill()
            p.wait(timeout=WAIT)
            outcomes.append(check_whole(state, old))
    finally:
        for _, _, p, _ in runs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert set(outcomes) <= {"old", "new"}


# --------------------------------------------------------------------------- writers at once

# Writes the bias file N times, as `hdrd calibrate` does (hdrd.io.files.biasfile.save_bias).
WRITER = r"""
import sys
from hdrd.core.calibrate import BiasRecord
from hdrd.io.files.biasfile import save_bias
path, who, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
for k in range(n):
    save_bias(path, BiasRecord(0.001 * who, 0.01, k + 1, 10.0, None, 1.7e9))
"""


def test_concurrent_writers_of_the_bias_file_all_succeed(tmp_path: Path) -> None:
    """Four processes writing the same bias file at once (two `hdrd calibrate` runs
    finishing together, on two ports or --simulate). Each writer used to remove every temp
    file it found, the others' live ones too, whose rename then failed with "No such file
    or directory". Now every write succeeds, the file is one writer's whole record, and no
    temp file is left."""
    target = tmp_path / "bias.yaml"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", WRITER, str(target), str(who), "60"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=env_with(),
        )
        for who in range(1, 5)
    ]
    errors = [(p.wait(timeout=WAIT), p.stderr.read().decode()) for p in procs if p.stderr]
    assert all(rc == 0 for rc, _ in errors), [e[-300:] for rc, e in errors if rc]
    rec = load_bias(target)
    assert rec.n == 60 and round(rec.bias_dps * 1000) in (1, 2, 3, 4)
    assert temps(tmp_path) == []


def test_only_dead_writers_temp_files_are_removed(tmp_path: Path) -> None:
    """A temp file is removed only when its writer is gone: not while the pid in its name
    runs, nor while someone holds its lock (a writer in another pid namespace)."""
    import fcntl

    target = tmp_path / "bias.yaml"
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, check=True)  # fmt: skip
    dead = int(done.stdout)  # a pid that ran and is gone (reuse within the test: unlikely)
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        dead_one = tmp_path / f".bias.yaml.{dead}.aaaa.tmp"
        live_one = tmp_path / f".bias.yaml.{live.pid}.bbbb.tmp"
        locked = tmp_path / f".bias.yaml.{dead}.cccc.tmp"
        old_style = tmp_path / ".bias.yaml.dddd.tmp"  # an older hdrd's name: no pid
        for f in (dead_one, live_one, locked, old_style):
            f.write_text("partial")
        with locked.open() as held:
            fcntl.flock(held.fileno(), fcntl.LOCK_EX)
            save_bias(target, OLD)
            assert sorted(temps(tmp_path)) == sorted([live_one.name, locked.name])
        save_bias(target, OLD)
        assert temps(tmp_path) == [live_one.name]
    finally:
        live.kill()
        live.wait()
    save_bias(target, OLD)
    assert temps(tmp_path) == [] and load_bias(target) == OLD
