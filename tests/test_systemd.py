"""systemd/hdrd.service and systemd/99-hdrd.rules: systemd-analyze verify and security, the
directives the daemon relies on, the udev rule, and the sandbox's effect on Python + numpy."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from hdrd.config import DeviceConfig

ROOT = Path(__file__).resolve().parent.parent
UNIT = ROOT / "systemd" / "hdrd.service"
RULES = ROOT / "systemd" / "99-hdrd.rules"
OPERATIONS = ROOT / "docs" / "operations.md"
MAX_EXPOSURE = 2.0  # systemd-analyze's "OK" band ends here

needs_analyze = pytest.mark.skipif(
    shutil.which("systemd-analyze") is None,
    reason="systemd-analyze is not installed on this machine",
)


def parse_unit(text: str) -> dict[str, list[tuple[str, str]]]:
    """Unit file -> {section: [(key, value), ...]}; keys may repeat, as systemd allows."""
    sections: dict[str, list[tuple[str, str]]] = {}
    current = None
    for line in text.splitlines():
        line = line.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], [])
            continue
        assert current is not None, f"directive outside a section: {line}"
        key, sep, value = line.partition("=")
        assert sep, f"not KEY=VALUE: {line}"
        current.append((key.strip(), value.strip()))
    return sections


def values(unit: dict[str, list[tuple[str, str]]], key: str, section: str = "Service") -> list[str]:
    return [v for k, v in unit[section] if k == key]


def hdrd_executable() -> str:
    found = shutil.which("hdrd") or str(Path(sys.executable).parent / "hdrd")
    if not os.access(found, os.X_OK):
        pytest.skip("the hdrd command is not installed (pip install -e .)")
    return str(Path(found).resolve())


def unit_copy(tmp_path: Path, exec_path: str) -> Path:
    """The unit with ExecStart pointing at *exec_path* (verify checks that it exists)."""
    text = UNIT.read_text()
    assert "ExecStart=/usr/local/bin/hdrd run\n" in text
    out = tmp_path / "hdrd.service"
    out.write_text(text.replace("ExecStart=/usr/local/bin/hdrd ", f"ExecStart={exec_path} "))
    return out


# -- the directives -------------------------------------------------------------------------


def test_unit_has_what_the_daemon_relies_on() -> None:
    unit = parse_unit(UNIT.read_text())
    one = {k: v for k, v in unit["Service"]}
    assert one["Type"] == "notify" and one["NotifyAccess"] == "main"
    assert one["WatchdogSec"] == "10"
    assert one["ExecStart"] == "/usr/local/bin/hdrd run"
    assert "-HUP" in one["ExecReload"] and "$MAINPID" in one["ExecReload"]
    assert one["Restart"] == "on-failure"
    assert "78" in one["RestartPreventExitStatus"]  # EX_CONFIG does not fix itself
    assert one["DynamicUser"] == "yes" and one["SupplementaryGroups"] == "dialout"
    assert one["StateDirectory"] == "hdrd" and one["ConfigurationDirectory"] == "hdrd"
    assert one["UMask"] == "0022"  # the bias file is 0644
    assert one["DevicePolicy"] == "closed"
    assert sorted(values(unit, "DeviceAllow")) == ["char-ttyACM rw", "char-ttyUSB rw"]
    assert "PrivateDevices" not in one  # it would hide the tty
    assert one["MemoryDenyWriteExecute"] == "yes" and one["NoNewPrivileges"] == "yes"
    assert one["CapabilityBoundingSet"] == ""
    assert set(one["RestrictAddressFamilies"].split()) == {"AF_UNIX", "AF_INET", "AF_INET6"}
    assert one["ProtectSystem"] == "strict"
    assert one["IPAddressDeny"] == "any" and "localhost" in one["IPAddressAllow"].split()
    assert values(unit, "WantedBy", "Install") == ["multi-user.target"]


# -- systemd-analyze ------------------------------------------------------------------------


@needs_analyze
def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    r = subprocess.run(
        ["systemd-analyze", "verify", str(unit_copy(tmp_path, hdrd_executable()))],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    complaints = [line for line in (r.stdout + r.stderr).splitlines() if "hdrd.service" in line]
    assert r.returncode == 0 and not complaints, r.stdout + r.stderr


@needs_analyze
def test_systemd_analyze_verify_really_checks(tmp_path: Path) -> None:
    # The same check fails for a unit whose program does not exist: the test above can fail.
    r = subprocess.run(
        ["systemd-analyze", "verify", str(unit_copy(tmp_path, str(tmp_path / "no-such-hdrd")))],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0


def exposure(tmp_path: Path) -> float:
    r = subprocess.run(
        [
            "systemd-analyze",
            "security",
            "--offline=true",
            str(unit_copy(tmp_path, hdrd_executable())),
        ],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    m = re.search(r"Overall exposure level for hdrd\.service:\s*([0-9.]+)", r.stdout)
    if m is None and "--offline" in r.stderr:
        pytest.skip(f"this systemd-analyze has no --offline: {r.stderr.strip()}")
    assert m, r.stdout + r.stderr
    return float(m.group(1))


@needs_analyze
def test_security_exposure_is_ok_and_recorded_in_the_docs(tmp_path: Path) -> None:
    score = exposure(tmp_path)
    assert score <= MAX_EXPOSURE
    # docs/operations.md records the score with the systemd version it was measured with.
    m = re.search(r"exposure \*\*([0-9.]+) OK\*\* \(systemd (\d+)\)", OPERATIONS.read_text())
    assert m, "docs/operations.md does not record the systemd-analyze security exposure"
    recorded, version = float(m.group(1)), int(m.group(2))
    assert recorded <= MAX_EXPOSURE
    v = subprocess.run(
        ["systemd-analyze", "--version"], check=False, capture_output=True, text=True, timeout=60
    )
    here = re.search(r"systemd (\d+)", v.stdout)
    if here and int(here.group(1)) == version:
        assert score == recorded, (
            f"docs/operations.md says {recorded}, systemd-analyze says {score}"
        )


# -- udev rule ------------------------------------------------------------------------------

UDEV_PAIR = re.compile(r'^\s*([A-Z_]+(?:\{[^}]+\})?)\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*$')


def udev_rules() -> list[dict[str, tuple[str, str]]]:
    rules = []
    for line in RULES.read_text().splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        rule = {}
        for part in line.split(","):
            m = UDEV_PAIR.match(part)
            assert m, f'not a udev KEY op "value": {part!r}'
            rule[m.group(1)] = (m.group(2), m.group(3))
        rules.append(rule)
    return rules


def test_udev_rules_name_the_default_port() -> None:
    rules = udev_rules()
    assert rules
    for rule in rules:
        assert rule["SUBSYSTEM"] == ("==", "tty")
        assert (
            re.fullmatch(r"[0-9a-f]{4}", rule["ATTRS{idVendor}"][1])
            and rule["ATTRS{idVendor}"][0] == "=="
        )
        assert (
            re.fullmatch(r"[0-9a-f]{4}", rule["ATTRS{idProduct}"][1])
            and rule["ATTRS{idProduct}"][0] == "=="
        )
        assert rule["SYMLINK"] == ("+=", "hdrd-gyro")
        assert DeviceConfig().port == "/dev/" + rule["SYMLINK"][1]
        assert rule["GROUP"] == ("=", "dialout") and rule["MODE"] == ("=", "0660")
        assert rule["ENV{SYSTEMD_WANTS}"][1] == UNIT.name and rule["TAG"] == ("+=", "systemd")
        # ModemManager would probe a ttyACM/ttyUSB port with AT commands at plug-in.
        assert rule["ENV{ID_MM_DEVICE_IGNORE}"] == ("=", "1")


# The USB-serial bridges of the boards the hdrd-adc firmware runs on (docs/firmware.md).
BOARD_BRIDGES = {
    ("1a86", "7523"): "WCH CH340 (Nano and Uno clones)",
    ("2341", "0043"): "ATmega16U2 of the Arduino Uno R3",
    ("0403", "6001"): "FTDI FT232R (original Nano, USB-serial ADC boards)",
}


def test_udev_rules_match_the_boards_users_plug_in() -> None:
    ids = [(r["ATTRS{idVendor}"][1], r["ATTRS{idProduct}"][1]) for r in udev_rules()]
    assert len(ids) == len(set(ids)), "a vendor:product pair is matched twice"
    missing = {k: v for k, v in BOARD_BRIDGES.items() if k not in ids}
    assert not missing, f"no active rule for {missing}"


def test_udev_commented_alternatives_are_valid_too() -> None:
    alternatives = [
        line.lstrip("#") for line in RULES.read_text().splitlines() if line.startswith("#SUBSYSTEM")
    ]
    assert alternatives
    for line in alternatives:
        for part in line.split(","):
            assert UDEV_PAIR.match(part), part


# -- the sandbox and Python -----------------------------------------------------------------

SANDBOXED = textwrap.dedent(
    """
    import ctypes, importlib, json, mmap, pkgutil, sys
    if sys.argv[1] == "mdwe":
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(65, 1, 0, 0, 0) != 0:  # PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN (Linux 6.3)
            sys.exit(77)
        try:
            mmap.mmap(-1, 4096, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
            sys.exit(3)  # the restriction is not in force: the test would prove nothing
        except PermissionError:
            pass
    import numpy as np
    rng = np.random.default_rng(0)
    a = rng.normal(size=(64, 64))
    checks = [float((a @ a).sum()), float(np.abs(np.fft.rfft(a[0])).sum()),
              float(np.linalg.solve(a + 64 * np.eye(64), a[0]).sum())]
    import hdrd, hdrd.core.hdr
    checks.append(float(hdrd.core.hdr.run_batch(rng.normal(0.1, 0.3, 600)).omega.sum()))
    failures = {}
    for m in pkgutil.walk_packages(hdrd.__path__, "hdrd."):
        try:
            importlib.import_module(m.name)
        except BaseException as e:
            failures[m.name] = type(e).__name__
    print(json.dumps({"checks": checks, "failures": failures}))
    """
)


@pytest.mark.slow
def test_numpy_and_hdrd_run_under_memory_deny_write_execute() -> None:
    """MemoryDenyWriteExecute=yes forbids W+X mappings. The kernel's PR_SET_MDWE applies the
    same rule to a process: numpy and every hdrd module must work the same under it."""
    if not sys.platform.startswith("linux"):
        pytest.skip("PR_SET_MDWE is Linux-only")
    runs = {}
    for mode in ("plain", "mdwe"):
        r = subprocess.run(
            [sys.executable, "-c", SANDBOXED, mode],
            check=False,
            capture_output=True,
            text=True,
            timeout=120,
            cwd=ROOT,
        )
        if r.returncode == 77:
            pytest.skip("this kernel has no PR_SET_MDWE (Linux >= 6.3)")
        assert r.returncode == 0, r.stderr
        runs[mode] = json.loads(r.stdout.splitlines()[-1])
    assert runs["mdwe"] == runs["plain"]


# -- resources: MemoryMax and friends -------------------------------------------------------

RESULTS = ROOT / "bench" / "RESULTS.md"


def _bytes(value: str) -> int:
    m = re.fullmatch(r"(\d+)([KMG]?)", value)
    assert m, f"not a size systemd takes here: {value!r}"
    return int(m.group(1)) << {"": 0, "K": 10, "M": 20, "G": 30}[m.group(2)]


def test_unit_bounds_memory_tasks_and_descriptors() -> None:
    unit = parse_unit(UNIT.read_text())
    one = {k: v for k, v in unit["Service"]}
    # A memory fault ends in an OOM kill inside the unit, the unit stopped, and a restart.
    limit = _bytes(one["MemoryMax"])
    assert one["MemorySwapMax"] == "0"  # else the runaway swaps instead of reaching the limit
    assert one["OOMPolicy"] == "stop" and one["Restart"] == "on-failure"
    assert "MemoryHigh" not in one  # throttling would only delay the restart
    # The limit keeps a margin over what was measured: the largest peak RSS of the daemon as
    # the unit runs it (on a serial port, reloaded by SIGHUP) in the process-level fuzz runs,
    # as bench/RESULTS.md records it.
    m = re.search(r"daemon as the unit runs it[^*]*: \*\*(\d+) MB\*\*", RESULTS.read_text())
    assert m, "bench/RESULTS.md does not record the fuzz runs' peak RSS"
    assert limit >= 3 * (int(m.group(1)) << 20)
    assert limit <= 1 << 30  # small enough to act before a small board's own OOM killer
    assert int(one["TasksMax"]) >= 16 and int(one["LimitNOFILE"]) >= 64
    assert "OPENBLAS_NUM_THREADS=1" in values(unit, "Environment")


def test_unit_says_what_the_watchdog_catches() -> None:
    # The watchdog follows progress: it catches a loop kept from its frames by other work,
    # not only a hung one (docs/operations.md, "The watchdog").
    text = UNIT.read_text()
    assert "so a hung loop is restarted" not in text
    comment = " ".join(
        text.split("WatchdogSec=10")[0].split("[Service]")[1].replace("#", " ").split()
    )
    assert "only after progress" in comment and "kept from its frames" in comment


@pytest.mark.slow
def test_the_daemon_runs_well_inside_the_units_limits(tmp_path: Path) -> None:
    """hdrd run with every kind of output and GPS aiding, environment as the unit sets it:
    its RSS, threads and descriptors leave the unit's limits a wide margin."""
    import socket
    import time

    unit = parse_unit(UNIT.read_text())
    one = {k: v for k, v in unit["Service"]}
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for item in values(unit, "Environment"):
        k, _, v = item.partition("=")
        env[k] = v
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    udp.settimeout(10)
    dest = f"127.0.0.1:{udp.getsockname()[1]}"
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hdrd",
            "run",
            "--simulate",
            "--speedup",
            "20",
            "--bias",
            "0.1",
            "--udp",
            dest,
            "--udp",
            "no-such-host.invalid:9",
            "--nmea-udp",
            dest,
            "--stdout",
            "--gpsd",
            "127.0.0.1:1",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    try:
        for _ in range(20):  # steps are coming: the daemon is past its start
            udp.recv(65535)
        time.sleep(1.0)
        status = Path(f"/proc/{p.pid}/status").read_text()
        hwm_kb = int(re.search(r"VmHWM:\s+(\d+) kB", status).group(1))  # type: ignore[union-attr]
        threads = int(re.search(r"Threads:\s+(\d+)", status).group(1))  # type: ignore[union-attr]
        fds = len(os.listdir(f"/proc/{p.pid}/fd"))
    finally:
        p.terminate()
        p.wait(10)
        udp.close()
    assert hwm_kb * 1024 * 3 <= _bytes(one["MemoryMax"]), hwm_kb
    assert threads * 4 <= int(one["TasksMax"]), threads
    assert fds * 4 <= int(one["LimitNOFILE"]), fds


# -- systemd/hdrd-web.service: the live page beside the daemon ------------------------------

WEB_UNIT = ROOT / "systemd" / "hdrd-web.service"
WEB_DOC = ROOT / "docs" / "web.md"
# What the daemon's unit sets for its devices and its state, which the page needs none of.
NOT_FOR_THE_PAGE = {
    "Type",
    "NotifyAccess",
    "WatchdogSec",
    "ExecReload",
    "Nice",
    "RestartPreventExitStatus",
    "MemoryMax",
    "Environment",
    "TasksMax",
    "LimitNOFILE",
    "SupplementaryGroups",
    "StateDirectory",
    "StateDirectoryMode",
    "ConfigurationDirectory",
    "UMask",
    "DeviceAllow",
    "ExecStart",
}


def web_unit_copy(tmp_path: Path, exec_path: str) -> Path:
    text = WEB_UNIT.read_text()
    assert "ExecStart=/usr/local/bin/hdrd web\n" in text
    out = tmp_path / "hdrd-web.service"
    out.write_text(text.replace("ExecStart=/usr/local/bin/hdrd ", f"ExecStart={exec_path} "))
    return out


def test_the_web_unit_is_sandboxed_as_the_daemons() -> None:
    daemon, web = parse_unit(UNIT.read_text()), parse_unit(WEB_UNIT.read_text())
    ours = {k: v for k, v in web["Service"]}
    for key, value in daemon["Service"]:
        if key not in NOT_FOR_THE_PAGE:
            assert value in values(web, key), (key, value)
    assert ours["ExecStart"] == "/usr/local/bin/hdrd web"  # its defaults: loopback only
    assert ours["PrivateDevices"] == "yes" and "DeviceAllow" not in ours
    assert ours["IPAddressDeny"] == "any" and ours["IPAddressAllow"] == "localhost"
    assert "2" in ours["RestartPreventExitStatus"].split()  # a bad --listen stays bad
    assert _bytes(ours["MemoryMax"]) <= _bytes(dict(daemon["Service"])["MemoryMax"])
    # the sockets hdrd web binds by default, and no other
    assert sorted(values(web, "SocketBindAllow")) == ["tcp:8080", "udp:10110"]
    assert values(web, "WantedBy", "Install") == ["multi-user.target"]


@needs_analyze
def test_systemd_analyze_verifies_the_web_unit_and_rates_it_as_the_docs_say(
    tmp_path: Path,
) -> None:
    unit = web_unit_copy(tmp_path, hdrd_executable())
    r = subprocess.run(
        ["systemd-analyze", "verify", str(unit)],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0 and "hdrd-web.service" not in r.stdout + r.stderr, r.stderr
    r = subprocess.run(
        ["systemd-analyze", "security", "--offline=true", str(unit)],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    m = re.search(r"Overall exposure level for hdrd-web\.service:\s*([0-9.]+)", r.stdout)
    if m is None and "--offline" in r.stderr:
        pytest.skip(f"this systemd-analyze has no --offline: {r.stderr.strip()}")
    assert m, r.stdout + r.stderr
    score = float(m.group(1))
    assert score <= MAX_EXPOSURE
    recorded = re.search(
        r"exposure \*\*([0-9.]+) [A-Z]+\*\* \(systemd (\d+)\)", WEB_DOC.read_text()
    )
    assert recorded, "docs/web.md does not record the unit's systemd-analyze security exposure"
    v = subprocess.run(
        ["systemd-analyze", "--version"], check=False, capture_output=True, text=True, timeout=60
    )
    here = re.search(r"systemd (\d+)", v.stdout)
    if here and int(here.group(1)) == int(recorded.group(2)):
        assert score == float(recorded.group(1))
