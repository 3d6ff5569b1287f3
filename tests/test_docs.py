"""README.md and docs/: every relative link resolves, README stays a short guide, every page
is listed in docs/index.md, no issue numbers, and CI runs the README's test command."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
README_MAX_LINES = 250
CI = ROOT / ".ci" / "run"
TEST_COMMAND = "pip install '.[test]' && python -m pytest"

FENCE = re.compile(r"^```.*?^```", flags=re.MULTILINE | re.DOTALL)
CODE_SPAN = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"\[[^\]\n]*\]\(([^)\s]+)\)")


def pages() -> list[Path]:
    return [README, ROOT / "bench" / "README.md", *sorted(DOCS.glob("*.md"))]


def links(text: str) -> list[str]:
    """Link targets outside code (a fenced block or a code span is text, not a link)."""
    prose = CODE_SPAN.sub("", FENCE.sub("", text))
    return LINK.findall(prose)


def slug(heading: str) -> str:
    """A heading's anchor as GitHub makes it: lower case, punctuation dropped, spaces -> '-'."""
    text = CODE_SPAN.sub(lambda m: m.group(0).strip("`"), heading.strip()).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = FENCE.sub("", path.read_text())
    return {slug(h) for h in re.findall(r"^#{1,6} (.+)$", text, flags=re.MULTILINE)}


def test_the_link_finder_finds_links_and_skips_code() -> None:
    text = "see [a](docs/a.md) and [b](b.md#x)\n`[c](c.md)`\n```sh\n[d](d.md)\n```\n"
    assert links(text) == ["docs/a.md", "b.md#x"]
    assert slug("The `hdrd run` command: what, why") == "the-hdrd-run-command-what-why"


@pytest.mark.parametrize("page", pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page: Path) -> None:
    broken = []
    for target in links(page.read_text()):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto: ...
            continue
        path, _, fragment = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif fragment and dest.suffix == ".md" and fragment not in anchors(dest):
            broken.append(f"{target}: no heading '{fragment}' in {dest.name}")
    assert not broken, f"{page.relative_to(ROOT)}: " + "; ".join(broken)


def test_readme_is_a_short_guide() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md has {len(lines)} lines; it is a guide of at most {README_MAX_LINES}: "
        "move reference material to docs/"
    )


def test_every_docs_page_is_listed_in_the_index() -> None:
    index = (DOCS / "index.md").read_text()
    missing = [p.name for p in DOCS.glob("*.md") if p.name != "index.md" and p.name not in index]
    assert not missing, f"docs/index.md does not list {missing}: add a line for each"


@pytest.mark.parametrize("page", pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_issue_numbers(page: Path) -> None:
    found = re.findall(r"\bissues? \d+", page.read_text(), flags=re.IGNORECASE)
    assert not found, f"{page.relative_to(ROOT)} mentions {found}: docs carry no project history"


def test_ci_runs_the_readme_test_command() -> None:
    assert TEST_COMMAND in README.read_text()
    # .ci/run may quieten pip (-q); the command is otherwise the README's, word for word.
    ci = [
        line.strip().replace("pip install -q ", "pip install ")
        for line in CI.read_text().splitlines()
    ]
    assert TEST_COMMAND in ci, f".ci/run does not run the README's test command: {TEST_COMMAND}"
