"""Shared test set-up. Keep it small and generic; module-specific fixtures live in the modules."""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

# No per-example deadline: the suite runs on small, busy CI machines, and we never assert timings.
# 50 examples a property (hypothesis's default is 100): the codecs, parsers and fast paths are
# fuzzed at length by bench/fuzz.py, and HYPOTHESIS_PROFILE=thorough draws 2,000.
settings.register_profile(
    "hdrd", deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=50
)
settings.register_profile("thorough", parent=settings.get_profile("hdrd"), max_examples=2000)
# tools/mutation.py: the same examples on every run (a mutant's verdict must not depend on
# the draw) and no example database shared between mutants.
settings.register_profile(
    "mutation", parent=settings.get_profile("hdrd"), derandomize=True, database=None
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "hdrd"))

# The processes the tests start (hdrd commands, daemons, a fleet's workers: hundreds of them)
# each import hdrd afresh. Where the environment forbids writing bytecode
# (PYTHONDONTWRITEBYTECODE, set on some build machines) each of them compiled hdrd from source
# again, a large share of the suite's CPU, and each pytest process (one per xdist worker)
# rewrote and compiled every test module again. They keep it in a cache outside the tree.
if os.environ.pop("PYTHONDONTWRITEBYTECODE", None) is not None:
    _cache = os.environ.setdefault(
        "PYTHONPYCACHEPREFIX",
        os.path.join(tempfile.gettempdir(), f"hdrd-tests-pycache-{os.getuid()}"),
    )
    sys.pycache_prefix = sys.pycache_prefix or _cache  # this process: the test modules, hdrd
    sys.dont_write_bytecode = False


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--regen-golden",
        action="store_true",
        help="rewrite the expected output of the golden captures (tests/data/golden/) from "
        "what the code gives now, instead of comparing with it (docs/testing.md)",
    )


@pytest.fixture
def regen_golden(request: pytest.FixtureRequest) -> bool:
    """True under ``pytest --regen-golden``: golden tests write their expected files."""
    return bool(request.config.getoption("--regen-golden"))


LEAK_GRACE_S = 2.0
"""How long a test's threads may take to end, and its fds to close, after its teardown."""


def open_fds() -> dict[int, str]:
    """This process's open file descriptors and what each is (its /proc/self/fd link)."""
    fds: dict[int, str] = {}
    for name in os.listdir("/proc/self/fd"):
        try:
            fds[int(name)] = os.readlink(f"/proc/self/fd/{name}")
        except OSError:  # closed since the listing (e.g. the listing's own directory fd)
            pass
    return fds


# Files a library keeps open for the life of the process by design, not leaks: matplotlib's
# font cache (font_manager.get_font, an LRU of FreeType faces) holds each font it has used.
PROCESS_CACHES = (".ttf", ".otf", ".ttc", ".afm", ".pfb")


def leaks(fds_before: dict[int, str], threads_before: set[threading.Thread]) -> list[str]:
    """What is open now that was not before: fds (new, or the same number now another file)
    and live threads; one line each."""
    found = [
        f"fd {fd} -> {target}"
        for fd, target in sorted(open_fds().items())
        if fds_before.get(fd) != target and not target.endswith(PROCESS_CACHES)
    ]
    found += [
        f"thread {t.name!r} (daemon={t.daemon})"
        for t in threading.enumerate()
        if t not in threads_before and t.is_alive()
    ]
    return found


@pytest.fixture(autouse=True)
def no_leaked_fds_or_threads() -> Iterator[None]:
    """Fails (as an error at teardown) a test that leaves a file descriptor open or a thread
    running, as python-can's autouse fixture fails a test that leaves a bus open.

    Set up before the test's other function fixtures, so it looks after their teardown;
    module- and session-scoped fixtures are open before it looks first. Threads that are
    ending get LEAK_GRACE_S.
    """
    fds_before = open_fds()
    threads_before = set(threading.enumerate())
    yield
    deadline = time.monotonic() + LEAK_GRACE_S
    found = leaks(fds_before, threads_before)
    while found and time.monotonic() < deadline:
        time.sleep(0.01)
        found = leaks(fds_before, threads_before)
    if found:
        pytest.fail("the test leaked: " + "; ".join(found), pytrace=False)


@pytest.fixture
def fake_gyro() -> Iterator[Callable[..., Any]]:
    """Factory of opened :class:`hdrd.sim.fakegyro.FakeGyro` ptys, all closed after the test.

    ``g = fake_gyro(profile, speedup=0, ...)``; open the reader on ``g.path`` (or ``g.link``)
    before ``g.start()`` when the test needs every frame.
    """
    from hdrd.sim.fakegyro import FakeGyro

    made: list[FakeGyro] = []

    def make(*args: Any, **kwargs: Any) -> FakeGyro:
        g = FakeGyro(*args, **kwargs)
        made.append(g)
        g.open()
        return g

    yield make
    for g in made:
        g.close()
