"""The one rate limit (hdrd.core.throttle): yes at most once per interval, a counter's growth
said only when due, and a counter that started again."""

from __future__ import annotations

import math

from hdrd.core.throttle import Throttle


def test_says_yes_at_most_once_per_interval() -> None:
    t = Throttle(10.0)
    assert t.last == -math.inf
    said = [now for now in (0.0, 3.0, 9.99, 10.0, 15.0, 20.5, 30.4, 30.5) if t.due(now)]
    assert said == [0.0, 10.0, 20.5, 30.5]


def test_a_start_time_holds_the_first_yes_back() -> None:
    t = Throttle(1.0, last=100.0)
    assert not t.due(100.5) and t.due(101.0)


def test_a_counter_is_said_when_it_grew_and_the_interval_passed() -> None:
    t = Throttle(10.0)
    # (now, total) -> what is said: nothing while the count stands still, the growth since
    # the last time it was said once the interval has passed
    seen = [t.count(total, now) for now, total in [(0, 0), (1, 3), (2, 5), (12, 5), (13, 9),
                                                    (20, 9), (23, 12), (40, 12)]]  # fmt: skip
    assert seen == [0, 3, 0, 2, 0, 0, 7, 0]
    assert t.said == 12 and t.last == 23


def test_standing_still_does_not_use_up_the_interval() -> None:
    t = Throttle(10.0)
    assert t.count(0, 0.0) == 0  # nothing new: the clock is not taken
    assert t.count(4, 1.0) == 4


def test_a_counter_that_started_again() -> None:
    t = Throttle(0.0)
    assert t.count(50, 0.0) == 50
    assert t.count(20, 1.0) == 0  # below what was said: not new until it passes 50
    t.restart()
    assert t.count(20, 2.0) == 20
