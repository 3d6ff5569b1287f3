"""hdrd.io.resolve: names looked up on worker threads, the caller never waiting; the old address
kept while a new lookup runs; slow and failed lookups counted and retried. The resolver here
is driven by a getaddrinfo of the test's (each lookup waits until the test answers it) and a
manual clock; the daemon against a real resolver that never answers: test_rel_dns.py."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from hdrd.io.resolve import Resolver


class Dns:
    """A getaddrinfo whose answers the test gives: each lookup of a name waits for
    :meth:`answer` (an address, or an error). Numeric hosts are refused as the real one
    refuses them with AI_NUMERICHOST... except real numeric addresses, answered at once."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.answers: dict[str, list[Any]] = {}
        self.asked: list[str] = []

    def __call__(self, host: str, port: int, type: int = 0, flags: int = 0) -> list[Any]:  # noqa: A002
        if flags & socket.AI_NUMERICHOST:
            return socket.getaddrinfo(host, port, type=type, flags=flags)  # numeric, or raises
        with self.cond:
            self.asked.append(host)
            self.cond.notify_all()
            self.cond.wait_for(lambda: self.answers.get(host))
            ans = self.answers[host].pop(0)
        if isinstance(ans, BaseException):
            raise ans
        return [(socket.AF_INET, type, 0, "", (ans, port))]

    def answer(self, host: str, ans: Any) -> None:
        with self.cond:
            self.answers.setdefault(host, []).append(ans)
            self.cond.notify_all()

    def wait_asked(self, n: int) -> None:
        with self.cond:
            assert self.cond.wait_for(lambda: len(self.asked) >= n, 10.0), self.asked


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def dns() -> Iterator[Dns]:
    d = Dns()
    yield d
    with d.cond:  # let every lookup still waiting end (no thread outlives the test)
        for host in set(d.asked):
            d.answers.setdefault(host, []).extend(OSError("test over") for _ in range(10))
        d.cond.notify_all()


def settle(r: Resolver, host: str, port: int = 9, **kw: Any) -> Any:
    """Look ``host`` up until no lookup is running (the worker has finished)."""
    deadline = time.monotonic() + 10.0
    while True:
        got = r.lookup(host, port, **kw)
        if not got.pending or time.monotonic() > deadline:
            return got
        time.sleep(0.005)


def test_a_numeric_address_needs_no_lookup(dns: Dns) -> None:
    r = Resolver(dns, Clock())
    got = r.lookup("127.0.0.1", 7400)
    assert got.infos is not None and got.infos[0][4] == ("127.0.0.1", 7400)
    assert not got.pending and r.lookups == 0 and dns.asked == []
    assert r.lookup("::1", 7400).infos is not None


def test_a_name_is_looked_up_on_a_thread_and_the_caller_never_waits(dns: Dns) -> None:
    r = Resolver(dns, Clock())
    got = r.lookup("gps.example.com", 2947, socket.SOCK_STREAM)
    assert got.infos is None and got.pending and got.error is None  # returned at once
    dns.wait_asked(1)
    assert r.lookup("gps.example.com", 2947, socket.SOCK_STREAM).pending  # no second lookup
    dns.answer("gps.example.com", "192.0.2.7")
    got = settle(r, "gps.example.com", 2947, socktype=socket.SOCK_STREAM)
    assert got.infos is not None and got.infos[0][4] == ("192.0.2.7", 2947)
    assert dns.asked == ["gps.example.com"] and r.lookups == 1


def test_a_slow_lookup_is_counted_once_and_never_doubled(dns: Dns) -> None:
    clock = Clock()
    r = Resolver(dns, clock, deadline_s=5.0)
    r.lookup("slow.example", 9)
    dns.wait_asked(1)
    clock.now += 4.9
    assert r.lookup("slow.example", 9).error is None
    clock.now += 0.2
    got = r.lookup("slow.example", 9)
    assert got.pending and got.failures == 1 and "no answer in 5 s" in (got.error or "")
    clock.now += 100.0
    for _ in range(5):
        assert r.lookup("slow.example", 9).failures == 1  # counted once per lookup
    assert r.slow == 1 and r.lookups == 1 and dns.asked == ["slow.example"]
    dns.answer("slow.example", "192.0.2.8")  # the late answer is still used
    got = settle(r, "slow.example")
    assert got.infos is not None and got.error is None and got.failures == 1


def test_a_failed_lookup_is_retried_after_its_wait_doubling(dns: Dns) -> None:
    clock = Clock()
    r = Resolver(dns, clock, retry_min_s=5.0, retry_max_s=12.0)
    for wait in (5.0, 10.0, 12.0):
        dns.answer("nx.example", socket.gaierror(-2, "Name or service not known"))
        n = len(dns.asked)
        r.lookup("nx.example", 9)
        got = settle(r, "nx.example")
        assert got.infos is None and "Name or service not known" in (got.error or "")
        assert len(dns.asked) == n + 1
        clock.now += wait - 0.1
        assert not r.lookup("nx.example", 9).pending  # not before its time
        clock.now += 0.1
    assert r.lookup("nx.example", 9).failures == 3


def test_the_old_address_is_kept_while_the_name_is_looked_up_again(dns: Dns) -> None:
    clock = Clock()
    r = Resolver(dns, clock, refresh_min_s=30.0)
    dns.answer("udp.example", "192.0.2.1")
    r.lookup("udp.example", 9)
    assert settle(r, "udp.example").infos[0][4][0] == "192.0.2.1"
    assert not r.lookup("udp.example", 9, refresh=True).pending  # refreshed at most every 30 s
    clock.now += 30.0
    got = r.lookup("udp.example", 9, refresh=True)  # a SIGHUP, a reconnection
    assert got.pending and got.infos is not None and got.infos[0][4][0] == "192.0.2.1"
    dns.wait_asked(2)
    dns.answer("udp.example", OSError("the resolver went away"))
    got = settle(r, "udp.example")
    assert got.infos is not None and got.infos[0][4][0] == "192.0.2.1"  # a failure keeps it
    clock.now += 60.0
    r.lookup("udp.example", 9, refresh=True)
    dns.answer("udp.example", "192.0.2.2")
    assert settle(r, "udp.example").infos[0][4][0] == "192.0.2.2"


def test_a_resolver_that_never_answers_holds_up_no_caller(dns: Dns) -> None:
    """The daemon's loop asks every turn: each call returns at once however long the lookup
    takes (here: until the test ends)."""
    clock = Clock()
    r = Resolver(dns, clock)

    def loop() -> None:
        for _ in range(1000):
            r.lookup("dead.example", 9)
            clock.now += 0.1

    t = threading.Thread(target=loop)
    t.start()
    t.join(30.0)  # an upper bound only a caller held up by the lookup reaches
    assert not t.is_alive()
    assert r.lookups == 1 and r.slow == 1 and dns.asked == ["dead.example"]
