"""The examples in the docs work as shown.

``<!-- output of: ... -->`` blocks: the example outputs in the docs are what the commands print
today. A block after ``<!-- output of: CMD; CMD -->`` is the last command's whole stdout; after
``<!-- excerpt of: ... -->``, its lines appear in that stdout, in order, together. The
commands run as a user types them (``hdrd`` is ``python -m hdrd``) in an empty folder holding
the files the same page writes with ``cat > FILE <<'YAML'`` heredocs. Run with
``HDRD_UPDATE_DOCS=1`` to rewrite an ``output of`` block that no longer matches (after a
change that moves the numbers on purpose), then read the diff.

```` ```sh ```` blocks of README.md and docs/*.md: each runs verbatim, as one bash script
(``set -e``: every line must succeed), in an empty temporary folder holding the files its page
writes with such heredocs (the README: nothing; its examples make their own inputs), with
``hdrd`` on the PATH. A block that runs until Ctrl-C is interrupted after a while and must end
cleanly. Those that cannot run here are listed in :data:`NOT_RUN`, each with why (hardware,
sudo, the network, ...); a block neither run nor listed is a failure, as is an entry of the
list that names no block.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
MARKER = re.compile(r"<!-- (output|excerpt) of: (.*?) -->\n```[a-z]*\n(.*?)```", re.DOTALL)
HEREDOC = re.compile(r"cat > (\S+) <<'(\w+)'\n(.*?)\n\2\n", re.DOTALL)
SLOW_PAGES = {"model-gap.md"}  # a gap search of seconds per example
PAGES = ["evaluation.md", "model-gap.md"]


def _examples() -> list[tuple[str, int]]:
    out = []
    for page in PAGES:
        text = (ROOT / "docs" / page).read_text()
        out += [(page, i) for i, _ in enumerate(MARKER.finditer(text))]
    return out


def _run(page: str, commands: str, tmp_path: Path) -> str:
    for name, _, body in HEREDOC.findall((ROOT / "docs" / page).read_text()):
        (tmp_path / name).write_text(body + "\n")
    out = ""
    for cmd in commands.split("; "):
        argv = shlex.split(cmd)
        assert argv[0] == "hdrd", cmd
        p = subprocess.run(
            [sys.executable, "-m", "hdrd", *argv[1:]],
            capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=600,
        )  # fmt: skip
        assert p.returncode == 0, (cmd, p.stderr)
        out = p.stdout
    return out


@pytest.mark.parametrize(
    ("page", "index"),
    [
        pytest.param(p, i, marks=[pytest.mark.slow] if p in SLOW_PAGES else [])
        for p, i in _examples()
    ],
)
def test_a_documented_output_is_what_the_command_prints(
    page: str, index: int, tmp_path: Path
) -> None:
    doc = ROOT / "docs" / page
    text = doc.read_text()
    m = list(MARKER.finditer(text))[index]
    kind, commands, block = m.group(1), m.group(2), m.group(3)
    got = _run(page, commands, tmp_path)
    if kind == "excerpt":
        lines = block.rstrip("\n").splitlines()
        have = got.splitlines()
        starts = [i for i, x in enumerate(have) if x == lines[0]]
        assert any(have[i : i + len(lines)] == lines for i in starts), (
            f"docs/{page}: the excerpt after <!-- excerpt of: {commands} --> is not in what it "
            f"prints now:\n{got}"
        )
        return
    if got != block and os.environ.get("HDRD_UPDATE_DOCS") == "1":
        doc.write_text(text[: m.start(3)] + got + text[m.end(3) :])
        return
    assert got == block, (
        f"docs/{page}: the block after <!-- output of: {commands} --> is stale; it prints "
        f"now (HDRD_UPDATE_DOCS=1 rewrites it):\n{got}"
    )


def test_every_page_with_examples_has_some() -> None:
    assert {p for p, _ in _examples()} == set(PAGES)


# -- every ```sh block runs verbatim --------------------------------------------------------

SH_BLOCK = re.compile(r"^( *)```sh\n(.*?)^\1```", re.MULTILINE | re.DOTALL)
SH_PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

SUDO = "sudo: installs into the system"
HARDWARE = "hardware: the gyro's board on a serial port"
PIP = "network: pip downloads packages"
PORTS = (
    "network: binds fixed ports (10110, 8080, gpsd's) that another process on this machine "
    "may hold; the tests of tail, web and gpsd run the same on free ports"
)
NOT_RUN: dict[tuple[str, str], str] = {
    ("README.md", "pip install . && hdrd run --simulate"): PIP,
    ("README.md", "hdrd run --simulate --speedup 20 --udp 127.0.0.1:10110"): PORTS,
    ("README.md", "pip install '.[test]' && python -m pytest"): PIP + "; and the suite itself",
    ("README.md", "sudo apt-get install gcc-avr avr-libc avrdude make"): SUDO + "; " + HARDWARE,
    ("README.md", "sudo python3 -m venv /opt/hdrd && sudo /opt/hdrd/bin/pip install ."): SUDO,
    ("README.md", "sudo install -D -m 0644 config/hdrd.yaml /etc/hdrd/hdrd.yaml"): SUDO,
    ("README.md", "python3 - > drive.nmea <<'EOF'"): PORTS,
    ("commands.md", "hdrd fakegyro --drive city --speedup 5 --link /tmp/gyro &"): PORTS,
    ("commands.md", "hdrd calibrate --port /dev/hdrd-gyro"): HARDWARE,
    ("commands.md", "hdrd fakegyro --drive constant --rate-dps 10 --minutes 5 --link"): (
        "a stand-in for the hardware on the fixed link /tmp/hdrd-gyro, in real time until "
        "Ctrl-C; tests/test_fakegyro.py runs it on a link of its own"
    ),
    ("commands.md", "hdrd record --port /dev/hdrd-gyro"): HARDWARE,
    ("commands.md", "hdrd import their.csv"): "their.csv is the user's own logger's file",
    ("development.md", "pip install -e '.[test]' ruff mypy"): PIP + "; and the suite itself",
    ("drive-format.md", "hdrd import their.csv"): "their.csv is the user's own logger's file",
    ("drive-format.md", "python tools/convert_real.py smartloc"): (
        "network: downloads public recordings"
    ),
    ("evaluation.md", "hdrd evaluate DRIVE|DIR|GLOB..."): "a synopsis of the options",
    ("simulator.md", "python tools/convert_real.py all"): "network: downloads public recordings",
    ("firmware.md", "sudo apt-get install gcc-avr avr-libc avrdude make"): SUDO,
    ("firmware.md", "make -C firmware flash PORT=/dev/ttyACM0"): HARDWARE,
    ("firmware.md", "hdrd record --port /dev/hdrd-gyro"): HARDWARE,
    ("firmware.md", "python3 firmware/sim/wave.py /tmp/wave.csv"): (
        "the AVR toolchain and simavr, from a source checkout ([--seconds N] is optional); "
        "tests/test_firmware.py runs the same chain"
    ),
    ("fleet.md", "pip install 'hdrd[fleet]'"): PIP,
    ("fleet.md", "# on the scheduler's machine"): "network: a cluster on other machines",
    ("fleet.md", "hdrd evaluate /data/fleet --scheduler tls://"): (
        "network: a cluster on other machines, with its certificates"
    ),
    ("gps-aiding.md", "# a drive east at 15 m/s"): PORTS,
    ("model-gap.md", "$ cat fitted.yaml"): "a session's transcript: prompts and their output",
    ("model-gap.md", "$ jq -c"): "a session's transcript: prompts and their output",
    ("operations.md", "# 1. the program, in a virtual environment outside /home"): SUDO,
    ("protocol.md", "printf 'output:"): PORTS,
    ("reliability.md", "python -m pytest tests/test_rel_bytes.py"): (
        "the test suite itself, the fuzzers and soaks of minutes to hours"
    ),
    ("testing.md", "pip install '.[test]'"): PIP + "; and the suite itself",
    ("testing.md", "python -m pytest tests/test_golden.py --regen-golden"): (
        "the suite itself, rewriting the checkout's golden files"
    ),
    ("testing.md", "pip install mutmut"): PIP,
    ("web.md", "hdrd run --simulate --speedup 20 --udp 127.0.0.1:10110"): PORTS,
    ("web.md", "sudo install -m 0644 systemd/hdrd-web.service"): SUDO,
}
"""The blocks not run here, by (page, the start of their first line), and why."""

FIRST: dict[tuple[str, str], tuple[str, str]] = {
    # evaluation.md's first examples use the tuned set and the drives its tuning section makes
    ("evaluation.md", "hdrd simulate --drive city --minutes 20 --seed 3 --out city.csv"): (
        "evaluation.md",
        "hdrd simulate --benchmark train --out drives/train",
    ),
    ("evaluation.md", "hdrd evaluate drives/ --method hdr+ --outages"): (
        "evaluation.md",
        "hdrd simulate --benchmark train --out drives/train",
    ),
    # the simulator's list of forms uses model-gap.md's hidden.yaml and gap.json
    ("simulator.md", "hdrd simulate --drive city --minutes 20 --seed 3 --out city.csv"): (
        "model-gap.md",
        "cat > moving.yaml <<'YAML'",
    ),
}
"""Blocks that use what another block makes (each page says so): that one runs first, in the
same folder."""

UNTIL_CTRL_C = {("hdrplus.md", "printf 'method: hdr+"): 8.0}
"""Blocks that run until Ctrl-C: interrupted after this many seconds, they must end with
status 0, having printed, and without a traceback."""

SAYS = {
    ("README.md", "hdrd simulate --benchmark test --out drives/test"): (
        "hdrd evaluate: note: about 0.2 s of work: on a local cluster of 2 workers"
    ),
}
"""What a block must say on stderr: the README's Dask example shows the cluster it promises
(it once said "run in this process")."""

TOOLS = ("jq",)
"""Programs besides hdrd that blocks use; a block that needs a missing one is skipped."""


def _sh_blocks() -> list[tuple[str, int, str]]:
    """(page, line of the block's first command, the block dedented) of every sh block."""
    out = []
    for path in SH_PAGES:
        text = path.read_text()
        for m in SH_BLOCK.finditer(text):
            pad = len(m.group(1))
            body = "".join(line[pad:] + "\n" for line in m.group(2).splitlines())
            out.append((path.name, text.count("\n", 0, m.start(2)) + 1, body))
    return out


def _key(page: str, body: str, table: dict[tuple[str, str], Any]) -> tuple[str, str] | None:
    first = body.lstrip("\n").splitlines()[0]
    return next((k for k in table if k[0] == page and first.startswith(k[1])), None)


def _block(key: tuple[str, str]) -> str:
    found = [b for p, _, b in _sh_blocks() if _key(p, b, {key: 0}) == key]
    assert len(found) == 1, key
    return found[0]


def _run_block(page: str, body: str, cwd: Path, env: dict[str, str]) -> tuple[int, str, str]:
    """The block run as one bash script (``set -e``) in ``cwd``; (status, stdout, stderr)."""
    key = _key(page, body, UNTIL_CTRL_C)
    proc = subprocess.Popen(
        ["bash", "-e", "-o", "pipefail", "-c", body],
        cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        stdin=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        if key is not None:
            try:
                out, err = proc.communicate(timeout=UNTIL_CTRL_C[key])
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C, as a terminal sends it
                out, err = proc.communicate(timeout=60)
            return proc.returncode, out, err
        out, err = proc.communicate(timeout=1200)
        return proc.returncode, out, err
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.fixture
def sh_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The environment a block runs in: ``hdrd`` (this checkout's, through this Python) first
    on the PATH."""
    bin_dir = tmp_path_factory.mktemp("bin")
    shim = bin_dir / "hdrd"
    shim.write_text(f'#!/bin/sh\nexec {shlex.quote(sys.executable)} -m hdrd "$@"\n')
    shim.chmod(0o755)
    return {**ENV, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"}


def _heredoc_files(page: str, cwd: Path) -> None:
    path = ROOT / page if page == "README.md" else ROOT / "docs" / page
    for name, _, body in HEREDOC.findall(path.read_text()):
        (cwd / name).write_text(body + "\n")


RUN = [(p, line, b) for p, line, b in _sh_blocks() if _key(p, b, NOT_RUN) is None]


@pytest.mark.slow  # each a few seconds to a couple of minutes of real commands
@pytest.mark.parametrize(("page", "line", "body"), RUN, ids=[f"{p}:{n}" for p, n, _ in RUN])
def test_a_documented_example_runs_verbatim_in_an_empty_folder(
    page: str, line: int, body: str, tmp_path: Path, sh_env: dict[str, str]
) -> None:
    for tool in TOOLS:
        if re.search(rf"(^|[|;&]\s*){tool}\b", body, re.MULTILINE) and not shutil.which(tool):
            pytest.skip(f"{page}:{line} uses {tool}, which is not installed")
    steps = [(page, body)]
    while (before := _key(*steps[0], FIRST)) is not None:
        steps.insert(0, (FIRST[before][0], _block(FIRST[before])))
    for step_page, _ in steps:
        _heredoc_files(step_page, tmp_path)
    for step_page, step_body in steps:
        rc, out, err = _run_block(step_page, step_body, tmp_path, sh_env)
        assert rc == 0, f"{step_page}: this example fails (status {rc}):\n{step_body}\n{err}"
        assert "Traceback" not in err, err
    if _key(page, body, UNTIL_CTRL_C) is not None:
        assert out.strip(), f"{page}:{line}: printed nothing before Ctrl-C:\n{err}"
    if (said := _key(page, body, SAYS)) is not None:
        assert SAYS[said] in err.splitlines(), err


def test_every_sh_block_is_run_or_listed_with_why() -> None:
    blocks = _sh_blocks()
    assert len(blocks) > 40
    for table in (NOT_RUN, FIRST, UNTIL_CTRL_C, SAYS):
        for key in table:  # each entry names exactly one block
            named = [(p, n) for p, n, b in blocks if _key(p, b, {key: 0}) == key]
            assert len(named) == 1, f"{key} names {named}"
    for key, why in NOT_RUN.items():
        assert why.strip(), key
