"""hdrd.io.web.webserver without a browser: the page and nothing else (read only), the stream,
validation of what reaches it, the bound on clients, a stalled client, and ``hdrd web`` as a
process. The server runs on real sockets (in a thread of this process, or as ``hdrd web``);
clients are plain sockets. The page in a real browser: tests/test_web_browser.py."""

from __future__ import annotations

import asyncio
import json
import re
import resource
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from hdrd.io.net.formats import format_json
from hdrd.io.web.http import host_allowed, parse_request, peer_key
from hdrd.io.web.webserver import (
    ASSETS,
    DEFAULT_MAX_CLIENTS,
    EXTRA_CONNECTIONS,
    PEER_PENDING,
    WebServer,
    WebSettings,
    fitted_max_clients,
)
from hdrd.io.web.webstate import TRACE_STEP_S

GUARD_S = 30.0  # a guard against a hang; no test asserts a duration
PAGE = Path(__file__).resolve().parents[1] / "hdrd" / "io" / "web" / "webpage"


def hdr(step: int, **over: Any) -> dict[str, Any]:
    msg: dict[str, Any] = {"class": "HDR", "v": 1, "step": step, "heading": 12.5, "status": "ok"}
    msg.update(over)
    return msg


class Served:
    """A WebServer on loopback sockets in a thread, and a UDP sender to it."""

    def __init__(self, server: WebServer) -> None:
        self.server = server
        self.port = server.http_sock.getsockname()[1]
        self.udp_addr = server.udp_sock.getsockname()
        self.sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def send(self, msg: dict[str, Any] | bytes) -> None:
        self.sender.sendto(msg if isinstance(msg, bytes) else format_json(msg), self.udp_addr)

    def connect(self) -> socket.socket:
        return socket.create_connection(("127.0.0.1", self.port), timeout=GUARD_S)

    def get(self, request: bytes) -> tuple[int, dict[str, str], bytes]:
        """One request as given; the status, headers (lower-case names) and body."""
        return self.get_from(self.port, request)

    @staticmethod
    def get_from(port: int, request: bytes) -> tuple[int, dict[str, str], bytes]:
        """:meth:`get` of a server on ``port`` of 127.0.0.1."""
        with socket.create_connection(("127.0.0.1", port), timeout=GUARD_S) as c:
            c.sendall(request)
            data = b""
            while chunk := c.recv(65536):
                data += chunk
        head, _, body = data.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        headers = dict((k.lower(), v.strip()) for k, _, v in (x.partition(":") for x in lines[1:]))
        return int(lines[0].split()[1]), headers, body


@contextmanager
def serving(local: bool = True, **settings: Any) -> Iterator[Served]:
    http = socket.create_server(("127.0.0.1", 0))
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    server = WebServer(
        http, udp, local, f"127.0.0.1:{udp.getsockname()[1]}", WebSettings(**settings), "test"
    )
    thread = threading.Thread(target=asyncio.run, args=(server.serve(),), daemon=True)
    thread.start()
    wait_for(lambda: server._stop is not None, "the server to start")
    served = Served(server)
    try:
        yield served
    finally:
        server.stop()
        thread.join(GUARD_S)
        served.sender.close()
        http.close()
        udp.close()
    assert not thread.is_alive()


def wait_for(cond: Any, what: str) -> None:
    deadline = time.monotonic() + GUARD_S
    while not cond():
        assert time.monotonic() < deadline, f"waited {GUARD_S} s for {what}"
        time.sleep(0.01)


class Stream:
    """A client of /events on a plain socket: the response's status, then its events."""

    def __init__(self, served: Served | int, rcvbuf: int | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if rcvbuf is not None:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.settimeout(GUARD_S)
        self.sock.connect(("127.0.0.1", served if isinstance(served, int) else served.port))
        self.sock.sendall(
            b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\nAccept: text/event-stream\r\n\r\n"
        )
        self.buf = b""

    def status(self) -> int:
        while b"\r\n\r\n" not in self.buf:
            chunk = self.sock.recv(65536)
            assert chunk, "closed before the response's head"
            self.buf += chunk
        head, _, self.buf = self.buf.partition(b"\r\n\r\n")
        return int(head.split(b" ")[1])

    def event(self) -> tuple[str, Any]:
        """The next event (comments and the retry line skipped)."""
        while True:
            while b"\n\n" not in self.buf:
                chunk = self.sock.recv(65536)
                assert chunk, "the stream ended"
                self.buf += chunk
            block, _, self.buf = self.buf.partition(b"\n\n")
            fields = dict(
                line.split(": ", 1)
                for line in block.decode().split("\n")
                if not line.startswith((":", "retry"))
            )
            if fields:
                return fields["event"], json.loads(fields["data"])

    def close(self) -> None:
        self.sock.close()


# -- pure parts ------------------------------------------------------------------------------


def test_requests_are_parsed_strictly() -> None:
    r = parse_request(b"GET /events?x=1 HTTP/1.1\r\nHost: 127.0.0.1:8080\r\nAccept: */*")
    assert r is not None and (r.method, r.path, r.host) == ("GET", "/events", "127.0.0.1:8080")
    for bad in (
        b"GET / HTTP/2.0",
        b"GET http://evil/ HTTP/1.1",
        b"GET  / HTTP/1.1",
        b"get / HTTP/1.1",
        b"GET / HTTP/1.1\r\nno colon",
        b"GET / HTTP/1.1\r\nHost : x",
        b"GET / HTTP/1.1\r\nHost: a\r\nHost: b",
        b"\x00\xff",
    ):
        assert parse_request(bad) is None, bad


@pytest.mark.parametrize(
    ("host", "local", "ok"),
    [
        ("127.0.0.1:8080", True, True),
        ("localhost:8080", True, True),
        ("LOCALHOST", True, True),
        ("[::1]:8080", True, True),
        ("127.9.9.9", True, True),
        (None, True, True),
        ("evil.example:8080", True, False),
        ("192.168.1.5:8080", True, False),
        ("[::1", True, False),
        ("evil.example", False, True),  # listening beyond loopback: any name the user uses
    ],
)
def test_a_local_server_answers_to_loopback_names_only(
    host: str | None, local: bool, ok: bool
) -> None:
    assert host_allowed(host, local) is ok


@pytest.mark.parametrize(
    ("address", "key"),
    [
        ("192.168.1.5", "192.168.1.5"),
        ("::ffff:192.168.1.5", "192.168.1.5"),
        ("2001:db8::1", "2001:db8::/64"),
        ("2001:db8::ffff:1%eth0", "2001:db8::/64"),  # one host may hold its whole /64
        ("fe80::1%eth0", "fe80::/64"),
        ("?", "?"),
    ],
)
def test_a_peer_is_its_address_or_its_ipv6_64(address: str, key: str) -> None:
    assert peer_key(address) == key


def test_the_page_loads_nothing_from_elsewhere_and_never_parses_markup() -> None:
    for name, _ in ASSETS.values():
        text = (PAGE / name).read_text()
        urls = re.findall(r"(?:https?:)?//[\w.-]+", text)
        assert set(urls) <= {"http://www.w3.org"}, (name, urls)  # SVG's namespace, not a fetch
    js = (PAGE / "app.js").read_text()
    for sink in (
        "innerHTML",
        "outerHTML",
        "insertAdjacentHTML",
        "document.write",
        "eval(",
        "Function(",
    ):
        assert sink not in js, sink
    html = (PAGE / "index.html").read_text()
    assert "<script>" not in html and not re.search(r"\s(style|on\w+)\s*=", html)


# -- the server ------------------------------------------------------------------------------


def test_get_serves_the_page_and_its_assets_with_a_strict_policy() -> None:
    with serving() as s:
        for path, (name, ctype) in ASSETS.items():
            status, headers, body = s.get(
                f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode()
            )
            assert status == 200 and headers["content-type"] == ctype
            assert body == (PAGE / name).read_bytes()
            assert "script-src 'self'" in headers["content-security-policy"]
            assert "default-src 'none'" in headers["content-security-policy"]
            assert headers["x-content-type-options"] == "nosniff"


def test_nothing_but_get_of_the_page_and_the_stream() -> None:
    with serving(head_timeout_s=0.5) as s:
        for method in ("POST", "PUT", "DELETE", "PATCH", "HEAD", "OPTIONS"):
            status, headers, _ = s.get(f"{method} / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
            assert status == 405 and headers["allow"] == "GET", method
        for path in ("/index.html", "/../etc/passwd", "/events/", "/app.js/x"):
            assert s.get(f"GET {path} HTTP/1.1\r\n\r\n".encode())[0] == 404, path
        assert s.get(b"GARBAGE\r\n\r\n")[0] == 400
        assert s.get(b"GET / HTTP/1.1\r\nX: " + b"a" * 10_000)[0] == 431
        assert s.get(b"GET / HTTP/1.1\r\n")[0] == 408  # the rest never comes
        assert s.get(b"GET / HTTP/1.1\r\nHost: evil.example\r\n\r\n")[0] == 403
        assert s.get(b"GET / HTTP/1.0\r\n\r\n")[0] == 200


def test_the_stream_pushes_each_message_and_a_new_client_gets_the_latest() -> None:
    with serving() as s:
        a = Stream(s)
        assert a.status() == 200
        assert a.event()[0] == "hello" and a.event() == ("history", {"points": []})
        s.send(hdr(1))
        name, data = a.event()
        assert name == "msg" and data["msg"] == hdr(1) and data["rx"] > 1e9
        s.send(hdr(2, heading=200.0))
        assert a.event()[1]["msg"] == hdr(2, heading=200.0)
        b = Stream(s)
        assert b.status() == 200 and b.event()[0] == "hello"
        assert [p[0:2] for p in b.event()[1]["points"]] != []
        assert b.event()[1]["msg"] == hdr(2, heading=200.0)
        a.close()
        b.close()


def test_only_what_tail_accepts_and_only_hdr_messages_reach_the_stream() -> None:
    with serving() as s:
        a = Stream(s)
        assert a.status() == 200 and a.event()[0] == "hello" and a.event()[0] == "history"
        for bad in (
            b"\xff",
            b"{",
            b"[]",
            b'{"class":"TPV"}',
            b'{"class":"HDR","x":NaN}',
            b"$HNHDT,1.00,T*00",
        ):
            s.send(bad)
        s.send(hdr(3))
        assert a.event()[1]["msg"] == hdr(3)  # the first event after them is the good one
        assert s.server.state.ignored == 6
        a.close()


def test_clients_beyond_the_limit_are_refused_until_one_leaves() -> None:
    with serving(max_clients=2) as s:
        a, b = Stream(s), Stream(s)
        assert a.status() == 200 and b.status() == 200
        c = Stream(s)
        assert c.status() == 503 and s.server.refused == 1
        c.close()
        a.close()
        wait_for(lambda: len(s.server.clients) == 1, "the server to see a client leave")
        d = Stream(s)
        assert d.status() == 200
        b.close()
        d.close()


def closed_by_the_server(sock: socket.socket) -> bool:
    """Whether the server closed ``sock`` without an answer (it asked for nothing)."""
    try:
        return sock.recv(100) == b""
    except ConnectionResetError:
        return True


def test_a_peer_keeps_few_connections_waiting_its_oldest_are_closed() -> None:
    with serving() as s:

        def connect() -> socket.socket:
            return socket.create_connection(("127.0.0.1", s.port), GUARD_S, ("127.0.0.2", 0))

        idle = [connect() for _ in range(PEER_PENDING + 4)]
        try:
            assert all(closed_by_the_server(sock) for sock in idle[:4])
            wait_for(lambda: s.server.connections == PEER_PENDING, "the oldest closed")
            with connect() as viewer:  # the same address asks for the page: it is served
                viewer.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                assert viewer.recv(12) == b"HTTP/1.1 200"
            idle += [connect() for _ in range(4)]
            assert all(closed_by_the_server(sock) for sock in idle[4:8])
            assert s.server.connections <= PEER_PENDING and s.server.closed_waiting == 8
        finally:
            for sock in idle:
                sock.close()


def test_connections_waiting_are_bounded_in_total_the_busiest_peer_gives_way() -> None:
    with serving() as s:
        idle = [
            socket.create_connection(("127.0.0.1", s.port), GUARD_S, (f"127.0.0.{k}", 0))
            for k in (2, 3, 4, 5)
            for _ in range(PEER_PENDING)
        ]
        try:
            status, _, body = s.get(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            assert status == 200 and body == (PAGE / "index.html").read_bytes()
            wait_for(lambda: s.server.connections <= EXTRA_CONNECTIONS, "the bound in total")
            assert s.server.closed_waiting == 4 * PEER_PENDING - EXTRA_CONNECTIONS
        finally:
            for sock in idle:
                sock.close()


def test_a_stalled_client_is_dropped_and_never_delays_the_others() -> None:
    """One client stops reading. Each datagram is sent once the live client has its
    predecessor, so were the server to wait for the stalled one, this test would hang (and
    fail at the guard)."""
    with serving(queue_bytes=8192, send_buffer=4096) as s:
        stalled = Stream(s, rcvbuf=4096)
        live = Stream(s)
        assert stalled.status() == 200 and live.status() == 200
        assert live.event()[0] == "hello" and live.event()[0] == "history"
        pad = "x" * 500  # ~600-byte events: the stalled client's buffers fill in ~100 of them
        step = 0
        while s.server.dropped == 0:
            assert step < 10_000, "the stalled client was never dropped"
            s.send(hdr(step, model=pad))
            assert live.event()[1]["msg"]["step"] == step
            step += 1
        s.send(hdr(step))  # and the live one goes on
        assert live.event()[1]["msg"]["step"] == step
        assert s.server.dropped == 1 and len(s.server.clients) == 1
        stalled.sock.settimeout(GUARD_S)
        try:  # what it had queued is dropped with it: its stream ends (EOF or reset)
            while stalled.sock.recv(65536):
                pass
        except ConnectionResetError:
            pass
        stalled.close()
        live.close()


# -- hdrd web as a process -------------------------------------------------------------------


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def start_web(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "hdrd", "web", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_hdrd_web_serves_until_sigterm_and_warns_when_not_local() -> None:
    port, uport = free_port(), free_port(socket.SOCK_DGRAM)
    p = start_web("--listen", f"0.0.0.0:{port}", "--udp", f"0.0.0.0:{uport}")
    try:
        assert p.stderr is not None
        seen = ""
        while "hdrd web: open" not in seen:
            line = p.stderr.readline()
            assert line, seen
            seen += line
        assert "web_listen_not_local" in seen and "web_udp_not_local" in seen
        with socket.create_connection(("127.0.0.1", port), timeout=GUARD_S) as c:
            c.sendall(b"GET / HTTP/1.1\r\nHost: vehicle.lan\r\n\r\n")  # not local: any name
            assert c.recv(12) == b"HTTP/1.1 200"
        p.send_signal(signal.SIGTERM)
        assert p.wait(GUARD_S) == 0
        assert "Traceback" not in p.stderr.read()
    finally:
        p.kill()
        p.communicate()


def test_hdrd_web_says_why_it_cannot_start() -> None:
    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "hdrd", "web", *args],
            capture_output=True,
            text=True,
            timeout=GUARD_S,
        )

    r = run("--listen", "localhost")
    assert r.returncode == 2 and "hdrd web: bad --listen 'localhost'" in r.stderr
    r = run("--listen", f"127.0.0.1:{free_port()}", "--udp", "[::1")
    assert r.returncode == 2 and "bad --udp" in r.stderr
    r = run("--max-clients", "0")
    assert r.returncode == 2 and "--max-clients" in r.stderr
    with socket.create_server(("127.0.0.1", 0)) as taken:
        r = run("--listen", f"127.0.0.1:{taken.getsockname()[1]}")
        assert r.returncode == 1 and "cannot listen on" in r.stderr
    for out in (r.stdout, r.stderr):
        assert "Traceback" not in out


def started(p: subprocess.Popen[str]) -> str:
    """What ``hdrd web`` said on stderr up to its "open" line (it serves from then on)."""
    assert p.stderr is not None
    seen = ""
    while "hdrd web: open" not in seen:
        line = p.stderr.readline()
        assert line, seen
        seen += line
    return seen


def latest_step(port: int) -> int:
    """The step of the latest message a new viewer of ``hdrd web`` on ``port`` gets (its
    ``hello`` and ``history`` first; -1: none yet). Its heading must be 12.5 (:func:`hdr`)."""
    viewer = Stream(port)
    try:
        assert viewer.status() == 200 and viewer.event()[0] == "hello"
        assert viewer.event()[0] == "history"
        viewer.sock.settimeout(0.2)
        try:
            name, data = viewer.event()
        except TimeoutError:
            return -1
    finally:
        viewer.close()
    assert name == "msg" and data["msg"]["heading"] == 12.5, data
    return int(data["msg"]["step"])


def wait_for_step(port: int, step: int) -> None:
    for _ in range(1000):  # until the server has taken it (no duration asserted)
        if latest_step(port) == step:
            return
        time.sleep(0.01)
    raise AssertionError(f"hdrd web never showed step {step}")


def test_one_absurd_datagram_never_keeps_new_viewers_out() -> None:
    port, uport = free_port(), free_port(socket.SOCK_DGRAM)
    p = start_web("--listen", f"127.0.0.1:{port}", "--udp", f"127.0.0.1:{uport}")
    try:
        started(p)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as daemon:
            daemon.sendto(format_json(hdr(1)), ("127.0.0.1", uport))
            wait_for_step(port, 1)
            time.sleep(2 * TRACE_STEP_S)  # the next message makes a trace point of its own
            daemon.sendto(
                b'{"class":"HDR","status":"ok","mode":"aided","heading":1e308,'
                b'"gps_course":-1e308}\n',
                ("127.0.0.1", uport),
            )
            time.sleep(0.01)  # not in the same millisecond (a trace point's resolution)
            daemon.sendto(format_json(hdr(2)), ("127.0.0.1", uport))
        wait_for_step(port, 2)  # every viewer meanwhile got its page: never the absurd one
        status, _, body = Served.get_from(port, b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert status == 200 and body == (PAGE / "index.html").read_bytes()
        p.send_signal(signal.SIGTERM)
        assert p.wait(GUARD_S) == 0
        err = p.stderr.read() if p.stderr else ""
        assert "Traceback" not in err and "web_datagrams_ignored" in err and "heading" in err
    finally:
        p.kill()
        p.communicate()


class Slowloris:
    """Sockets from the given source addresses of 127/8 that never finish a request (half of
    them send the start of one), reopened as soon as the server closes them, in a thread."""

    def __init__(self, port: int, sources: list[str], per_source: int) -> None:
        self.port = port
        self.socks: dict[socket.socket, str] = {}
        self.reopened = 0
        for src in sources:
            for k in range(per_source):
                self._open(src, k)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _open(self, src: str, k: int) -> None:
        sock = socket.create_connection(
            ("127.0.0.1", self.port), timeout=GUARD_S, source_address=(src, 0)
        )
        if k % 2:
            sock.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never the blank line
        self.socks[sock] = src

    def _run(self) -> None:
        import select

        while not self._stop.is_set():
            readable, _, _ = select.select(list(self.socks), [], [], 0.05)
            for sock in readable:  # the server closed it (or answered 408): open another
                src = self.socks.pop(sock)
                sock.close()
                self._open(src, self.reopened)
                self.reopened += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(GUARD_S)
        for sock in self.socks:
            sock.close()


def page_load(port: int) -> list[int]:
    """The statuses of the page's files and of its stream (0: closed without an answer)."""
    statuses = []
    for path in [*ASSETS, "/events"]:
        with socket.create_connection(("127.0.0.1", port), timeout=GUARD_S) as c:
            c.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
            try:
                head = c.recv(12)
            except ConnectionResetError:
                head = b""
            statuses.append(int(head[9:12]) if head.startswith(b"HTTP/1.1 ") else 0)
    return statuses


def test_idle_and_half_open_connections_never_keep_a_page_load_out() -> None:
    """32 connections (max_clients + 16) from four other addresses that never finish a request,
    each reopened as soon as it is closed, while a viewer loads the page."""
    port, uport = free_port(), free_port(socket.SOCK_DGRAM)
    p = start_web("--listen", f"127.0.0.1:{port}", "--udp", f"127.0.0.1:{uport}")
    attack = None
    try:
        started(p)
        attack = Slowloris(port, [f"127.0.0.{k}" for k in (2, 3, 4, 5)], 8)
        for _ in range(3):
            assert page_load(port) == [200] * (len(ASSETS) + 1)
        # the server closed some of them and the attack went on (its thread reopens what was
        # closed when it next runs: on a busy machine, after the page loads)
        wait_for(lambda: attack is not None and attack.reopened > 0, "a connection reopened")
        assert page_load(port) == [200] * (len(ASSETS) + 1)  # and the page still loads
        attack.close()
        attack = None
        p.send_signal(signal.SIGTERM)
        assert p.wait(GUARD_S) == 0
        err = p.stderr.read() if p.stderr else ""
        assert "Traceback" not in err and "web_connections_closed" in err
    finally:
        if attack is not None:
            attack.close()
        p.kill()
        p.communicate()


@pytest.mark.slow
def test_hdrd_web_fits_its_clients_to_its_descriptors_and_outlives_a_flood() -> None:
    """Started with 40 descriptors (as a unit's LimitNOFILE would allow), flooded with 300
    connections at once: one note that the viewers are fewer than asked, at most one warning
    per 10 s while descriptors run out (never a traceback per retry), and a page load once
    the flood is over."""
    port, uport = free_port(), free_port(socket.SOCK_DGRAM)

    def few_descriptors() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (40, 40))

    p = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "web", "--listen", f"127.0.0.1:{port}"]
        + ["--udp", f"127.0.0.1:{uport}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=few_descriptors,
    )
    flood: list[socket.socket] = []
    try:
        seen = started(p)
        assert "web_max_clients_clamped" in seen and '"max_clients": 1' in seen
        for _ in range(300):
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setblocking(False)
            sock.connect_ex(("127.0.0.1", port))
            flood.append(sock)
        time.sleep(2.0)  # held across the server's retries of accept (every 1 s)
        for sock in flood:
            sock.close()
        flood.clear()
        assert page_load(port) == [200] * (len(ASSETS) + 1)
        p.send_signal(signal.SIGTERM)
        assert p.wait(GUARD_S) == 0
        err = p.stderr.read() if p.stderr else ""
        assert "Traceback" not in err and len(err) < 2048, err[:3000]
        assert "web_descriptors_exhausted" in err
    finally:
        for sock in flood:
            sock.close()
        p.kill()
        p.communicate()


def test_streams_are_fitted_to_the_descriptors_the_unit_allows() -> None:
    assert fitted_max_clients(16, 1024, 8) == 16
    assert fitted_max_clients(10_000, 1024, 8) == 1024 - 8 - 16 - 2 * EXTRA_CONNECTIONS
    assert fitted_max_clients(16, 40, 6) == 1  # never none
    unit = (PAGE.parents[3] / "systemd" / "hdrd-web.service").read_text()
    m = re.search(r"^LimitNOFILE=(\d+)$", unit, re.MULTILINE)
    assert m, "systemd/hdrd-web.service sets no LimitNOFILE"
    # the unit's limit serves the default, with room for what systemd leaves open
    nofile = int(m.group(1))
    assert fitted_max_clients(DEFAULT_MAX_CLIENTS, nofile, 16) == DEFAULT_MAX_CLIENTS
    most = fitted_max_clients(10_000, nofile, 8)
    assert f"{nofile}\n# serves about {most // 10 * 10} viewers" in unit  # as its comment says
