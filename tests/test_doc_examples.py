"""The example outputs in the docs are what the commands print today.

A block after ``<!-- output of: CMD; CMD -->`` is the last command's whole stdout; after
``<!-- excerpt of: ... -->``, its lines appear in that stdout, in order, together. The
commands run as a user types them (``hdrd`` is ``python -m hdrd``) in an empty folder holding
the files the same page writes with ``cat > FILE <<'YAML'`` heredocs. Run with
``HDRD_UPDATE_DOCS=1`` to rewrite an ``output of`` block that no longer matches (after a
change that moves the numbers on purpose), then read the diff.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

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
