"""What every fuzz target of tools/fuzz promises and how a broken promise is raised: the base
of tools/fuzz/targets.py, filetargets.py and drivelog.py (the module docs there say what each
surface checks)."""

from __future__ import annotations

__all__ = ["Broken", "Target", "check", "one_line"]


class Broken(AssertionError):
    """A promise the code under test did not keep (not an exception it raised)."""


def check(ok: bool, what: str) -> None:
    """Raise :class:`Broken` saying *what* unless *ok*."""
    if not ok:
        raise Broken(what)


def one_line(text: str, what: str) -> None:
    """A refusal is one printable line of reasonable length."""
    check(isinstance(text, str) and bool(text.strip()), f"{what}: empty message")
    check("\n" not in text and "\r" not in text, f"{what}: more than one line: {text[:200]!r}")
    check(text.isprintable(), f"{what}: not printable: {text[:200]!r}")
    check(len(text) <= 600, f"{what}: {len(text)} characters: {text[:200]!r}")


class Target:
    """One surface's target (see the module doc)."""

    surface = ""

    def run(self, data: bytes) -> str:
        raise NotImplementedError

    def close(self) -> None:
        pass
