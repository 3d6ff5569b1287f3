# ruff: noqa: F811 - the fixtures hdrd and receivers come from test_rel_daemon by import
"""`hdrd run` whose resolver never answers: the main loop must not wait on DNS.

The daemon runs in a mount namespace of its own (``unshare -m``) with ``/etc/resolv.conf``
bound over by one that names a nameserver on a loopback address; there a UDP socket of this
test reads the queries and never replies (glibc then waits ``timeout`` x ``attempts`` per
lookup: minutes here). The daemon reads a fake gyro in real time and publishes to a real UDP
socket; sd_notify goes to a NOTIFY_SOCKET with a watchdog. What must hold while the lookups
hang (docs/operations.md, "Names and DNS"): steps keep coming and ``WATCHDOG=1`` keeps
arriving, for ``--gpsd gps.example.com`` (a reconnection attempt each backoff) and after a
SIGHUP to a configuration with host names in ``output.udp``.

Needs root (a mount namespace, port 53): skipped otherwise, saying why. The resolver itself,
with a getaddrinfo of the test's: tests/test_resolve.py. No timings are asserted.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.test_rel_daemon import (  # noqa: F401 - hdrd and receivers are fixtures
    WAIT,
    constant_turn,
    hdrd,
    receivers,
    run_args,
    steps_of,
    wait_port_open,
)

NAMESERVER = "127.0.0.53"  # a loopback address (all of 127/8 is local)


class DeadResolver(threading.Thread):
    """A UDP socket on port 53 that reads DNS queries and never answers them; ``names`` are
    the names asked for, in order."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((NAMESERVER, 53))
        self.sock.settimeout(0.1)
        self.names: list[str] = []
        self.cond = threading.Condition()
        self.done = threading.Event()
        self.start()

    def run(self) -> None:
        while not self.done.is_set():
            try:
                query = self.sock.recv(512)
            except TimeoutError:
                continue
            except OSError:
                return
            with self.cond:
                self.names.append(_qname(query))
                self.cond.notify_all()

    def wait_for(self, name: str) -> None:
        with self.cond:
            assert self.cond.wait_for(lambda: name in self.names, WAIT), self.names

    def close(self) -> None:
        self.done.set()
        self.join(timeout=5)
        self.sock.close()


def _qname(query: bytes) -> str:
    """The name asked for in a DNS query (the question after the 12-byte header)."""
    labels, i = [], 12
    while i < len(query) and query[i]:
        n = query[i]
        labels.append(query[i + 1 : i + 1 + n].decode("ascii", "replace"))
        i += 1 + n
    return ".".join(labels)


@pytest.fixture
def dead_dns(tmp_path: Path) -> Iterator[tuple[DeadResolver, tuple[str, ...]]]:
    """The dead resolver and the command prefix that runs a process with it as its only
    nameserver (skips, saying why, where that cannot be done)."""
    if os.geteuid() != 0:
        pytest.skip("needs root: a mount namespace (unshare -m) and a nameserver on port 53")
    if not shutil.which("unshare"):
        pytest.skip("needs unshare(1) (util-linux) for a mount namespace")
    conf = tmp_path / "resolv.conf"
    conf.write_text(f"nameserver {NAMESERVER}\noptions timeout:30 attempts:5\n")
    try:
        dns = DeadResolver()
    except OSError as e:
        pytest.skip(f"cannot listen on {NAMESERVER}:53: {e}")
    prefix = (
        "unshare",
        "-m",
        "sh",
        "-c",
        f'mount --bind "{conf}" /etc/resolv.conf && exec "$0" "$@"',
    )
    yield dns, prefix
    dns.close()


def run_under(make_proc: Any, prefix: tuple[str, ...], tmp_path: Path, *args: str) -> Any:
    return make_proc(
        *run_args(*args),
        env={"NOTIFY_SOCKET": str(tmp_path / "notify.sock"), "WATCHDOG_USEC": "1000000"},
        prefix=prefix,
    )


@pytest.mark.slow
def test_gpsd_by_a_name_the_resolver_never_answers_holds_up_no_step(
    hdrd, receivers, fake_gyro, dead_dns, tmp_path
):
    dns, prefix = dead_dns
    notify = receivers(tmp_path / "notify.sock")
    rx = receivers()
    g = fake_gyro(constant_turn(minutes=2), speedup=1)
    d = run_under(
        hdrd,
        prefix,
        tmp_path,
        "--port",
        g.path,
        "--bias",
        "0",
        "--udp",
        rx.addr,
        "--gpsd",
        "gps.example.com:2947",
    )
    wait_port_open(d, g.path)
    g.start()
    dns.wait_for("gps.example.com")  # the lookup is under way, and will never be answered
    n0, w0 = len(steps_of(rx.snapshot())), len(notify.snapshot())
    rx.wait(lambda ms: len(steps_of(ms)) >= n0 + 8, what="8 steps while the lookup hangs")
    notify.wait(lambda xs: xs[w0:].count("WATCHDOG=1") >= 4, what="WATCHDOG=1 meanwhile")
    d.wait_event("resolve_slow")
    assert "gps.example.com" in dns.names and not any(m["status"] == "stale" for m in rx.snapshot())
    assert d.stop() == 0 and not d.traceback


@pytest.mark.slow
def test_sighup_to_udp_names_the_resolver_never_answers_holds_up_no_step(
    hdrd, receivers, fake_gyro, dead_dns, tmp_path
):
    dns, prefix = dead_dns
    notify = receivers(tmp_path / "notify.sock")
    rx = receivers()
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(f"output:\n  udp: [{rx.addr}]\n")
    g = fake_gyro(constant_turn(minutes=2), speedup=1)
    d = run_under(hdrd, prefix, tmp_path, "--config", str(cfg), "--port", g.path, "--bias", "0")
    wait_port_open(d, g.path)
    g.start()
    rx.wait(lambda ms: len(steps_of(ms)) >= 3, what="3 steps")
    names = ("display-1.example", "display-2.example", "display-3.example")
    cfg.write_text(
        "output:\n  udp: [" + ", ".join([*(f"{n}:7000" for n in names), rx.addr]) + "]\n"
    )
    d.proc.send_signal(signal.SIGHUP)
    d.wait_event("config_reloaded")
    for n in names:
        dns.wait_for(n)  # every lookup under way, none answered
    n0, w0 = len(steps_of(rx.snapshot())), len(notify.snapshot())
    rx.wait(lambda ms: len(steps_of(ms)) >= n0 + 8, what="8 steps while the lookups hang")
    notify.wait(lambda xs: xs[w0:].count("WATCHDOG=1") >= 4, what="WATCHDOG=1 meanwhile")
    assert d.stop() == 0 and not d.traceback
    stats = {e["dest"]: e for e in d.named("output_udp_stats")}
    for n in names:
        assert stats[f"{n}:7000"]["sent"] == 0 and stats[f"{n}:7000"]["dropped"] > 0
    assert stats[rx.addr]["errors"] == 0
