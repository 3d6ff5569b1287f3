"""Shared test set-up. Keep it small and generic; module-specific fixtures live in the modules."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

# No per-example deadline: the suite runs on small, busy CI machines, and we never assert timings.
settings.register_profile("hdrd", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", parent=settings.get_profile("hdrd"), max_examples=2000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "hdrd"))


@pytest.fixture
def fake_gyro() -> Iterator[Callable[..., Any]]:
    """Factory of opened :class:`hdrd.fakegyro.FakeGyro` ptys, all closed after the test.

    ``g = fake_gyro(profile, speedup=0, ...)``; open the reader on ``g.path`` (or ``g.link``)
    before ``g.start()`` when the test needs every frame.
    """
    from hdrd.fakegyro import FakeGyro

    made: list[FakeGyro] = []

    def make(*args: Any, **kwargs: Any) -> FakeGyro:
        g = FakeGyro(*args, **kwargs)
        made.append(g)
        g.open()
        return g

    yield make
    for g in made:
        g.close()
