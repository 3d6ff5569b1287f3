"""hdrd.io.web.webstate (pure): what ``hdrd web`` keeps and pushes. The server around it:
tests/test_webserver.py; the page in a real browser: tests/test_web_browser.py."""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.io.net.formats import format_json, nmea_sentences
from hdrd.io.web.webstate import (
    HISTORY_S,
    MAX_EVENT_BYTES,
    TRACE_STEP_S,
    LiveState,
    sse_event,
    trace_point,
)


def hdr(**over: Any) -> dict[str, Any]:
    msg: dict[str, Any] = {"class": "HDR", "v": 1, "step": 7, "omega": 1.5, "heading": 90.0}
    msg.update(over)
    return msg


def events(blob: bytes) -> list[tuple[str, Any]]:
    """(name, data) of each event in ``blob``; each must be one event line and one data line."""
    out = []
    for block in blob.decode("ascii").split("\n\n"):
        if not block:
            continue
        lines = block.split("\n")
        assert len(lines) == 2 and lines[0].startswith("event: ") and lines[1].startswith("data: ")
        out.append((lines[0][7:], json.loads(lines[1][6:])))
    return out


def test_an_hdr_message_is_pushed_as_received_with_its_time_of_arrival() -> None:
    s = LiveState("127.0.0.1:10110", "9.9")
    (event,) = s.take(format_json(hdr()), "127.0.0.1:5", 1000.25)
    assert events(event) == [("msg", {"rx": 1000.25, "msg": hdr()})]
    assert s.latest == event and s.received == 1 and s.ignored == 0
    # one datagram may hold several lines; each HDR object is an event
    assert len(s.take(format_json(hdr(step=8)) + format_json(hdr(step=9)), "x", 1001.0)) == 2


def test_what_tail_refuses_and_what_is_not_an_hdr_message_is_ignored() -> None:
    s = LiveState()
    bad = [
        b"\xff\xfe not utf-8",
        b"{not json",
        b"[1, 2, 3]",
        b'{"class":"VERSION","release":"1"}',
        b'{"class":"HDR","heading":' + b"9" * 5000 + b"}",  # an integer of 5,000 digits
        b'{"class":"HDR","heading":NaN}',  # Python reads NaN; a browser's JSON does not
        b'{"class":"HDR","heading":1e999}',
        b"[" * 100_000 + b"]" * 100_000,
        b"".join(nmea_sentences(hdr())),
        format_json(hdr(model="x" * MAX_EVENT_BYTES)),
    ]
    for data in bad:
        assert s.take(data, "127.0.0.1:9", 1.0) == [], data[:40]
    assert s.latest is None and s.received == 0 and not s.trace
    assert s.ignored >= len(bad) and s.last_reason.startswith("hdrd web: ignored")
    assert s.take(format_json(hdr()), "127.0.0.1:9", 2.0)  # and the next good one is taken


@given(st.text(max_size=50))
def test_no_string_can_break_the_streams_framing(text: str) -> None:
    # Every string reaches the page JSON-escaped, as ASCII: one data line per event.
    s = LiveState()
    msg = hdr(status=text, model=text + "\n\r\n\u2028<script>")
    (event,) = s.take(
        json.dumps(msg, ensure_ascii=False).encode("utf-8", "surrogatepass"), "x", 1.0
    )
    ((name, data),) = events(event)
    assert name == "msg" and data["msg"]["status"] == text


def test_the_trace_is_thinned_and_keeps_ten_minutes() -> None:
    s = LiveState()
    rx = 1000.0
    for k in range(int(2 * HISTORY_S / 0.05)):  # 20 minutes at 20 Hz (a replay, a speed-up)
        s.take(format_json(hdr(step=k)), "x", rx + 0.05 * k)
    times = [p[0] for p in s.trace]
    assert len(times) <= HISTORY_S / TRACE_STEP_S + 1
    assert times[-1] - times[0] <= HISTORY_S and times[-1] >= rx + 2 * HISTORY_S - 1
    assert min(b - a for a, b in zip(times, times[1:])) >= TRACE_STEP_S - 1e-9
    s.take(format_json(hdr()), "x", rx)  # the clock went back: the old trace is dropped
    assert [p[0] for p in s.trace] == [rx]


def test_a_trace_point_is_the_yaw_rate_and_while_aided_heading_minus_course() -> None:
    assert trace_point(hdr(omega=-0.5), 5.0) == (5.0, -0.5, None)
    aided = hdr(mode="aided", heading=2.0, gps_course=358.0)
    assert trace_point(aided, 5.0) == (5.0, 1.5, 4.0)
    assert trace_point({**aided, "mode": "dead-reckoning"}, 5.0)[2] is None
    assert trace_point(hdr(omega="fast", heading=True), 5.0) == (5.0, None, None)
    assert trace_point({"class": "HDR", "status": "calibrating"}, 5.0) == (5.0, None, None)


def test_a_new_connection_gets_hello_the_history_and_the_latest() -> None:
    s = LiveState("127.0.0.1:10110", "9.9")
    assert [n for n, _ in events(s.snapshot(10.0))] == ["hello", "history"]
    s.take(format_json(hdr(step=1)), "x", 1.0)
    s.take(format_json(hdr(step=2)), "x", 2.0)
    got = events(s.snapshot(3.0))
    assert got[0] == (
        "hello",
        {"now": 3.0, "udp": "127.0.0.1:10110", "version": "9.9", "history_s": HISTORY_S},
    )
    assert got[1] == ("history", {"points": [[1.0, 1.5, None], [2.0, 1.5, None]]})
    assert got[2] == ("msg", {"rx": 2.0, "msg": hdr(step=2)})
    late = events(s.snapshot(1.5 + HISTORY_S))  # the first point is over ten minutes old
    assert late[1][1]["points"] == [[2.0, 1.5, None]]


def test_an_event_is_ascii_json_without_nan() -> None:
    assert sse_event("msg", {"a": "é"}) == b'event: msg\ndata: {"a":"\\u00e9"}\n\n'
    with pytest.raises(ValueError):
        sse_event("msg", {"a": float("nan")})


@given(st.binary(max_size=300))
def test_any_datagram_is_taken_or_ignored_never_a_crash(data: bytes) -> None:
    s = LiveState()
    for event in s.take(data, "127.0.0.1:9", 1.0):
        ((name, body),) = events(event)
        assert name == "msg" and isinstance(body["msg"], dict)
    assert s.received + s.ignored >= len([x for x in data.split(b"\n") if x.strip()])


@pytest.mark.parametrize(
    "over",
    [
        {"mode": "aided", "heading": 1e308, "gps_course": -1e308},  # their difference: inf
        {"heading": 1e20},
        {"heading": -0.5},
        {"heading": 360.5},
        {"mode": "aided", "gps_course": 720.0},
        {"omega": 1e300},
        {"omega": -1e16},
        {"step": 10**400},  # an integer beyond any float
        {"time": 1e200},
    ],
)
def test_absurd_values_never_enter_the_state(over: dict[str, Any]) -> None:
    s = LiveState()
    s.take(format_json(hdr(step=1)), "x", 1.0)
    before = (s.latest, list(s.trace), s.received)
    msg = json.dumps({**hdr(step=2), **over}).encode()
    assert s.take(msg, "127.0.0.1:9", 2.0) == []
    assert (s.latest, list(s.trace), s.received) == before
    key = next(iter(k for k in over if k != "mode"))
    assert s.ignored == 1 and f"{key} " in s.last_reason and "127.0.0.1:9" in s.last_reason
    got = events(s.snapshot(3.0))  # a new viewer gets its page, with the last good message
    assert [n for n, _ in got] == ["hello", "history", "msg"] and got[2][1]["msg"] == hdr(step=1)


def test_what_hdrd_sends_and_keys_not_known_are_not_judged() -> None:
    s = LiveState()
    for over in (
        {"heading": 0.0, "mode": "aided", "gps_course": 360.0},
        {"heading": 359.996, "omega": -1e4, "calib_age_s": -3.0, "yaw": -1e7},
        {"future_key": 1e300, "nested": {"a": -1e300}},
    ):
        assert len(s.take(format_json(hdr(**over)), "x", 1.0)) == 1, over
    assert s.ignored == 0


def test_messages_within_a_millisecond_never_look_like_a_clock_going_back() -> None:
    # Points keep rx to the millisecond: 1000.0006 is kept as 1000.001, and a message at
    # 1000.0007 is not earlier than it.
    s = LiveState()
    s.take(format_json(hdr(step=1)), "x", 999.0)
    s.take(format_json(hdr(step=2)), "x", 1000.0006)
    s.take(format_json(hdr(step=3)), "x", 1000.0007)
    assert [p[0] for p in s.trace] == [999.0, 1000.001]
