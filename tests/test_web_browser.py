"""``hdrd web`` in a real browser: Debian's chromium, driven by Playwright (never a browser
that Playwright downloads), against ``hdrd web`` as a process, fed datagrams as the daemon
sends them. The page loads without a console error, shows a datagram's heading on the dial,
shows the mode in words and colour, says "No data since HH:MM:SS" when the datagrams stop and
recovers when they come back, and shows a hostile string as text with no script run.

The server's own tests: tests/test_webserver.py and tests/test_webstate.py."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import pytest

from hdrd.io.net.formats import format_json

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
GUARD_MS = 30_000  # waits that only guard against a hang
SHOWN_MS = 2_000  # the page shows a datagram within 2 s (the promise, not a benchmark)

pytestmark = pytest.mark.slow

if not os.access(CHROMIUM, os.X_OK):
    pytest.skip(
        f"Debian's chromium is not installed ({CHROMIUM}; .ci/run installs it: "
        "apt-get install chromium chromium-driver)",
        allow_module_level=True,
    )
sync_api = pytest.importorskip(
    "playwright.sync_api", reason="playwright is not installed (pip install '.[test]')"
)


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class Web:
    """``hdrd web`` as a process, and a UDP sender playing the daemon."""

    def __init__(self, port: int | None = None, udp_port: int | None = None) -> None:
        self.port = port or free_port(socket.SOCK_STREAM)
        self.udp = ("127.0.0.1", udp_port or free_port(socket.SOCK_DGRAM))
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "hdrd",
                "web",
                "--listen",
                f"127.0.0.1:{self.port}",
                "--udp",
                f"127.0.0.1:{self.udp[1]}",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stderr is not None
        line = ""
        while "hdrd web: open" not in line:  # it serves once it says where
            line = self.proc.stderr.readline()
            assert line, "hdrd web ended at start"
        self.url = f"http://127.0.0.1:{self.port}/"
        self.sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.step = 0

    def send(self, via: socket.socket | None = None, **fields: Any) -> None:
        """A step's message as the daemon sends it, with ``fields`` over the defaults (from
        ``via``: another sender)."""
        self.step += 1
        msg: dict[str, Any] = {
            "class": "HDR",
            "v": 1,
            "step": self.step,
            "omega": 0.25,
            "heading": 45.0,
            "bias": 0.1234,
            "bad_frames": 2,
            "status": "ok",
            "bias_source": "calibration",
            "calib_age_s": 75.0,
            "frames": 1000 + self.step,
            "reconnects": 1,
        }
        msg.update(fields)
        (via or self.sender).sendto(format_json(msg), self.udp)

    def close(self) -> None:
        self.sender.close()
        self.proc.send_signal(signal.SIGTERM)
        assert self.proc.wait(30) == 0
        assert self.proc.stderr is not None
        self.proc.stderr.close()


@pytest.fixture(scope="module")
def web() -> Iterator[Web]:
    w = Web()
    try:
        yield w
    finally:
        w.close()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


class Page:
    """A tab on the page, with every console error and uncaught exception it had."""

    def __init__(self, browser: Any, url: str) -> None:
        self.page = browser.new_page()
        self.errors: list[str] = []
        self.page.on("console", self._console)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.goto(url)
        # connected: the server's hello has set the footer
        self.page.wait_for_function(
            "() => document.getElementById('source').textContent.includes('data from UDP')",
            timeout=GUARD_MS,
        )

    def _console(self, m: Any) -> None:
        if m.type == "error":
            self.errors.append(m.text)

    def text(self, element_id: str) -> str:
        return str(self.page.text_content(f"#{element_id}"))

    def wait_text(self, element_id: str, text: str, timeout: int = GUARD_MS) -> None:
        self.page.wait_for_function(
            "([id, text]) => document.getElementById(id).textContent === text",
            arg=[element_id, text],
            timeout=timeout,
        )

    def colour(self, element_id: str) -> str:
        return str(
            self.page.evaluate(
                "id => getComputedStyle(document.getElementById(id)).backgroundColor",
                element_id,
            )
        )


@pytest.fixture()
def page(browser: Any, web: Web) -> Iterator[Page]:
    p = Page(browser, web.url)
    try:
        yield p
    finally:
        p.page.close()


def test_the_page_loads_and_shows_a_step_without_a_console_error(page: Page, web: Web) -> None:
    web.send(heading=45.0)
    page.wait_text("heading", "45.0")
    assert page.text("omega") == "0.25 deg/s (left)"
    assert page.text("bias") == "0.1234 deg/s" and page.text("bias-source") == "calibration"
    assert page.text("calib-age") == "1 min 15 s ago"
    assert page.text("frames") == str(1000 + web.step) and page.text("bad-frames") == "2"
    assert page.text("reconnects") == "1"
    assert page.text("gps") == "no GPS aiding (hdrd run --gpsd)"
    assert page.errors == []


def test_the_dial_shows_a_datagrams_heading_within_two_seconds(page: Page, web: Web) -> None:
    page.wait_text("heading", "45.0")  # the latest, at connection
    web.send(heading=123.4)
    page.wait_text("heading", "123.4", timeout=SHOWN_MS)
    dial = page.page.locator("#dial")
    assert dial.get_attribute("data-heading") == "123.40"
    # the needle turns to it (the short way round, eased: the style says where it goes)
    assert page.page.locator("#needle").evaluate("n => n.style.transform") == "rotate(123.4deg)"
    assert page.errors == []


def test_the_mode_changes_words_and_colour_with_the_stream(page: Page, web: Web) -> None:
    seen: dict[str, str] = {}
    for fields, word in (
        ({"status": "calibrating"}, "calibrating"),
        ({"status": "ok"}, "ok"),
        ({"status": "turning", "mode": "aided", "gps_course": 44.0, "gps_age_s": 0.4}, "aided"),
        ({"status": "ok", "mode": "dead-reckoning", "gps_age_s": 30.0}, "dead-reckoning"),
        ({"status": "stale", "stale_s": 4.0}, "stale"),
    ):
        web.send(**fields)
        page.wait_text("mode", word)
        seen[word] = page.colour("mode")
    assert len(set(seen.values())) == len(seen), seen  # five modes, five colours
    web.send(status="ok", mode="aided", gps_course=44.0, gps_speed=14.2, gps_age_s=0.4)
    page.wait_text("gps", "44.0\u00b0 at 14.2 m/s")
    assert (
        page.text("gps-age") == "0 s ago" and page.text("mode-why") == "aligned to the GPS course"
    )
    assert page.errors == []


def test_no_data_since_appears_when_the_datagrams_stop_and_goes_when_they_resume(
    page: Page, web: Web
) -> None:
    web.send(heading=10.0)
    page.wait_text("heading", "10.0")
    banner = page.page.locator("#banner")
    banner.wait_for(state="hidden", timeout=GUARD_MS)
    # nothing more is sent: the page says since when
    banner.wait_for(state="visible", timeout=GUARD_MS)
    assert re.fullmatch(r"No data since \d\d:\d\d:\d\d", page.text("banner")), page.text("banner")
    assert page.text("mode") == "no data"
    # a daemon started again: a new sender, from another port
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as restarted:
        web.send(restarted, heading=11.0)
    banner.wait_for(state="hidden", timeout=GUARD_MS)
    assert page.text("heading") == "11.0" and page.text("mode") == "ok"
    assert page.errors == []


def test_a_hostile_string_is_shown_as_text_and_runs_nothing(page: Page, web: Web) -> None:
    hostile = "<img src=x onerror=\"window.__pwned=1;document.title='pwned'\">"
    web.send(status=hostile, model=hostile, bias_source=hostile, heading=77.0)
    page.wait_text("status", hostile)
    assert page.text("model") == hostile and page.text("bias-source") == hostile
    assert page.text("mode") == "unknown"  # a status it does not know: the rate not trusted
    page.page.wait_for_timeout(500)  # give an image's error handler the time to run, if any
    assert page.page.evaluate("document.querySelectorAll('img').length") == 0
    assert page.page.evaluate("typeof window.__pwned") == "undefined"
    assert page.page.title() == "hdrd: heading"
    assert page.errors == []


def test_the_page_reconnects_by_itself_when_hdrd_web_restarts(browser: Any) -> None:
    first = Web()
    p = Page(browser, first.url)
    try:
        first.send(heading=20.0)
        p.wait_text("heading", "20.0")
        first.close()
        p.page.locator("#banner").wait_for(state="visible", timeout=GUARD_MS)
        again = Web(first.port, first.udp[1])  # the same addresses, a new process
        try:
            again.send(heading=21.0)
            p.wait_text("heading", "21.0")
            again.send(heading=22.0)  # live again, not only the snapshot of a new connection
            p.wait_text("heading", "22.0")
            p.page.locator("#banner").wait_for(state="hidden", timeout=GUARD_MS)
        finally:
            again.close()
        # the browser logs its failed reconnection attempts while the server was down; nothing else
        assert [e for e in p.errors if "ERR_CONNECTION_REFUSED" not in e] == []
    finally:
        p.page.close()


def needle(page: Page) -> str:
    return str(page.page.locator("#needle").evaluate("n => n.style.transform"))


def test_an_absurd_heading_never_freezes_the_needle(browser: Any) -> None:
    web = Web()  # a server of its own: 1e20 is the first heading the page is sent
    page = Page(browser, web.url)
    try:
        web.send(heading=1e20)
        web.send(heading=90.0)
        page.wait_text("heading", "90.0")
        assert needle(page) == "rotate(90deg)"
        # The page on its own, as if a server let such a message through: not a heading.
        page.page.evaluate(
            "() => onMessage({data: JSON.stringify({rx: Date.now() / 1000, "
            "msg: {class: 'HDR', status: 'ok', heading: -1e20}})})"
        )
        assert page.text("heading") == "\u2013" and page.text("status") == "ok"
        web.send(heading=100.0)
        page.wait_text("heading", "100.0")
        assert needle(page) == "rotate(100deg)"
        assert page.errors == []
    finally:
        page.page.close()
        web.close()


def test_a_heading_that_rounds_to_360_is_shown_as_0(page: Page, web: Web) -> None:
    # hdrd tail shows 359.996 as 0.00, as NMEA does: the page wraps after rounding too.
    web.send(heading=359.96, mode="aided", gps_course=359.97, gps_speed=3.0, gps_age_s=0.2)
    page.wait_text("heading", "0.0")
    assert page.page.locator("#dial").get_attribute("data-heading") == "359.96"
    assert page.text("gps") == "0.0\u00b0 at 3.0 m/s"
    web.send(heading=359.996)
    # the heading already reads 0.0: wait for this message by the dial, which rounds it
    page.page.wait_for_function(
        "() => document.getElementById('dial').dataset.heading !== '359.96'", timeout=GUARD_MS
    )
    assert page.page.locator("#dial").get_attribute("data-heading") == "0.00"
    assert page.text("heading") == "0.0"
    assert page.errors == []


def test_the_heading_is_shown_with_its_sd_when_hdrd_knows_it(page: Page, web: Web) -> None:
    # HDR+ publishes heading_sd: the page shows "123.4° ± 2.1"; without it, the heading alone.
    web.send(heading=123.44, heading_sd=2.06)
    page.wait_text("heading", "123.4")
    page.wait_text("heading-sd", " \u00b1 2.1")
    web.send(heading=124.0)
    page.wait_text("heading", "124.0")
    page.wait_text("heading-sd", "")
    assert page.errors == []
