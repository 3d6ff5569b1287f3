"""Host names to addresses without waiting: lookups run on worker threads, callers poll.

The daemon's loop never waits on a resolver (docs/operations.md, "Names and DNS"): a lookup
(``getaddrinfo``, which may wait on DNS for tens of seconds, or for ever on a resolver that
never answers) runs on a thread of its own, and :meth:`Resolver.lookup` returns at once with
what is known: the address found last (kept while a new lookup runs, so that a SIGHUP or a
reconnection never loses a working address), or none yet. A numeric address is converted on
the spot, without DNS.

A lookup that has not answered within :data:`DEADLINE_S` is **slow**: it is counted, logged
(``resolve_slow``) and reported to the caller as a failure (``Lookup.error``), while the
caller goes on with the old address, if any; its thread is left to finish (``getaddrinfo``
cannot be cancelled), and no second lookup of the same name starts meanwhile, so a dead
resolver costs one thread per name, never one per attempt. A lookup that fails is counted and
logged (``resolve_failed``, once per run of failures) and tried again after
:data:`RETRY_MIN_S`, doubling up to :data:`RETRY_MAX_S`. A name that resolves after failing,
or to a new address, is logged (``resolved``).

One :class:`Resolver` per process (:func:`default_resolver`) shares the addresses between the
publishers, the gpsd client and a ``socket://`` device; tests pass their own, with a
``getaddrinfo`` of theirs.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hdrd.io.logs import log

__all__ = [
    "DEADLINE_S",
    "RETRY_MAX_S",
    "RETRY_MIN_S",
    "AddrInfo",
    "Lookup",
    "Resolver",
    "default_resolver",
]

DEADLINE_S = 5.0
"""A lookup not answered within this long is slow: counted, logged, and the caller told."""
RETRY_MIN_S = 5.0
"""A name that failed to resolve is looked up again after this long, s, doubling..."""
RETRY_MAX_S = 300.0
"""... up to this, s."""
REFRESH_MIN_S = 30.0
"""A name is looked up again on a caller's request (``refresh``) at most this often, s."""

AddrInfo = tuple[int, int, int, str, tuple[Any, ...]]
"""One ``getaddrinfo`` answer: family, socket type, protocol, canonical name, address."""
GetAddrInfo = Callable[..., list[Any]]


@dataclass(frozen=True, slots=True)
class Lookup:
    """What is known of a name now. ``infos``: its addresses (IPv4 and IPv6 only), the last
    found, None while none has been found. ``pending``: a lookup is running; ``slow``: it has
    passed its deadline. ``error``: why the last lookup failed, or that the running one is
    slow (None: no trouble). ``failures``: lookups that failed or were slow, since the name
    was first asked for."""

    infos: tuple[AddrInfo, ...] | None
    pending: bool
    error: str | None
    failures: int
    slow: bool = False


class _Name:
    """One name's state (guarded by the resolver's lock)."""

    __slots__ = (
        "error",
        "failures",
        "host",
        "infos",
        "last_start",
        "logged_error",
        "pending_since",
        "port",
        "retry_at",
        "retry_wait",
        "slow_counted",
        "socktype",
    )

    def __init__(self, host: str, port: int, socktype: int) -> None:
        self.host, self.port, self.socktype = host, port, socktype
        self.infos: tuple[AddrInfo, ...] | None = None
        self.error: str | None = None
        self.failures = 0
        self.pending_since: float | None = None
        self.last_start = -math.inf
        self.retry_at = -math.inf
        self.retry_wait = 0.0
        self.slow_counted = False
        self.logged_error = False


def _family_ok(infos: list[Any]) -> tuple[AddrInfo, ...]:
    return tuple(i for i in infos if i[0] in (socket.AF_INET, socket.AF_INET6))


class Resolver:
    """Looks names up on worker threads (see the module doc). Thread-safe.

    getaddrinfo: the function that resolves (``socket.getaddrinfo``; a test's own).
    clock: monotonic seconds. deadline_s, retry_min_s, retry_max_s, refresh_min_s: as the
    module's constants.
    """

    def __init__(
        self,
        getaddrinfo: GetAddrInfo = socket.getaddrinfo,
        clock: Callable[[], float] = time.monotonic,
        *,
        deadline_s: float = DEADLINE_S,
        retry_min_s: float = RETRY_MIN_S,
        retry_max_s: float = RETRY_MAX_S,
        refresh_min_s: float = REFRESH_MIN_S,
    ) -> None:
        self._getaddrinfo = getaddrinfo
        self._clock = clock
        self.deadline_s = deadline_s
        self.retry_min_s, self.retry_max_s = retry_min_s, retry_max_s
        self.refresh_min_s = refresh_min_s
        self._lock = threading.Lock()
        self._names: dict[tuple[str, int, int], _Name] = {}
        self.lookups = 0
        """Lookups started on a thread."""
        self.slow = 0
        """Lookups that took longer than the deadline."""

    def lookup(
        self, host: str, port: int, socktype: int = socket.SOCK_DGRAM, refresh: bool = False
    ) -> Lookup:
        """What is known of ``host`` now (never waits): starts a lookup when there is no
        address yet (or, with ``refresh``, when the last lookup is older than refresh_min_s)
        and none is running or waiting for its retry time."""
        numeric = self._numeric(host, port, socktype)
        if numeric is not None:
            return Lookup(numeric, False, None, 0)
        now = self._clock()
        with self._lock:
            key = (host, port, socktype)
            name = self._names.get(key)
            if name is None:
                name = self._names[key] = _Name(host, port, socktype)
            start = self._due(name, now, refresh)
            if start:
                name.pending_since = now
                name.last_start = now
                name.slow_counted = False
                self.lookups += 1
            slow = self._check_slow(name, now)
            pending = name.pending_since is not None
            found = Lookup(
                name.infos, pending, name.error, name.failures, pending and name.slow_counted
            )
        if slow:
            log.warning(
                "resolve_slow",
                host=host,
                waited_s=round(now - (name.pending_since or now), 1),
                kept=_shown(found.infos),
                reason=f"no answer in {self.deadline_s:g} s; the lookup goes on in the background",
            )
        if start:
            threading.Thread(
                target=self._run, args=(name,), name="hdrd-resolve", daemon=True
            ).start()
        return found

    def _due(self, name: _Name, now: float, refresh: bool) -> bool:
        if name.pending_since is not None or now < name.retry_at:
            return False
        return name.infos is None or (refresh and now - name.last_start >= self.refresh_min_s)

    def _check_slow(self, name: _Name, now: float) -> bool:
        """The running lookup has passed its deadline (counted once): True the first time."""
        since = name.pending_since
        if since is None or name.slow_counted or now - since < self.deadline_s:
            return False
        name.slow_counted = True
        name.failures += 1
        name.error = f"cannot resolve {name.host}: no answer in {self.deadline_s:g} s"
        self.slow += 1
        return True

    def _numeric(self, host: str, port: int, socktype: int) -> tuple[AddrInfo, ...] | None:
        """The address of a numeric host (no DNS involved), else None."""
        try:
            infos = self._getaddrinfo(host, port, type=socktype, flags=socket.AI_NUMERICHOST)
        except (OSError, UnicodeError, ValueError):
            return None
        return _family_ok(infos) or None

    def _run(self, name: _Name) -> None:
        """The lookup, on its own thread."""
        try:
            infos = _family_ok(self._getaddrinfo(name.host, name.port, type=name.socktype))
            error = None if infos else f"no IPv4 or IPv6 address for {name.host}"
        except (OSError, UnicodeError, ValueError) as e:  # gaierror is an OSError
            infos, error = (), f"cannot resolve {name.host}: {e}"
        now = self._clock()
        with self._lock:
            was, slow = name.infos, name.slow_counted
            name.pending_since = None
            if error is None:
                name.infos, name.error, name.retry_wait = infos, None, 0.0
                name.retry_at = -math.inf
            else:
                if not slow:  # a slow lookup was counted when it passed its deadline
                    name.failures += 1
                name.error = error
                name.retry_wait = min(max(2 * name.retry_wait, self.retry_min_s), self.retry_max_s)
                name.retry_at = now + name.retry_wait
            logged, name.logged_error = name.logged_error, error is not None
            wait = name.retry_wait
        if error is not None:
            if not logged:
                log.warning(
                    "resolve_failed", host=name.host, error=error, retry_s=wait, kept=_shown(was)
                )
        elif was != infos or logged or slow:
            log.info("resolved", host=name.host, address=_shown(infos), previous=_shown(was))


def _shown(infos: tuple[AddrInfo, ...] | None) -> str | None:
    return None if not infos else str(infos[0][4][0])


_DEFAULT: Resolver | None = None
_DEFAULT_LOCK = threading.Lock()


def default_resolver() -> Resolver:
    """The process's resolver (made at the first call)."""
    global _DEFAULT
    with _DEFAULT_LOCK:
        if _DEFAULT is None:
            _DEFAULT = Resolver()
        return _DEFAULT
