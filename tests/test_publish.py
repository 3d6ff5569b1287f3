"""Publishers: JSON lines, NMEA 0183, UDP delivery and failures, stdout and its reader."""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.io.net.formats import (
    format_json,
    nmea_checksum,
    nmea_sentence,
    nmea_sentences,
    parse_nmea,
)
from hdrd.io.net.publish import (
    OutputClosed,
    StdoutPublisher,
    UdpJsonPublisher,
    UdpNmeaPublisher,
    UdpPublisher,
)
from hdrd.io.resolve import Resolver

RECV_TIMEOUT_S = 10.0  # a guard against hanging, not a timing assertion


def full_message(**over: Any) -> dict[str, Any]:
    msg: dict[str, Any] = {
        "class": "HDR",
        "v": 1,
        "time": 1700000000.25,
        "t": 125.0,
        "step": 125,
        "omega_raw": 0.7421,
        "omega": 0.5,
        "yaw": 12.5,
        "heading": 347.5,
        "I": -0.0422,
        "W": 1,
        "R": 0.745,
        "r": 2,
        "bias": 0.2421,
        "samples": 10,
        "bad_frames": 0,
        "status": "ok",
        "temp": 24.5,
    }
    msg.update(over)
    return msg


def strict_loads(line: bytes) -> Any:
    """json.loads that rejects NaN/Infinity, as RFC 8259 parsers (jq, browsers) do."""

    def reject(name: str) -> None:
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(line.decode("utf-8"), parse_constant=reject)


# -- format_json ----------------------------------------------------------------------------


def test_json_is_one_compact_utf8_line_in_the_given_order() -> None:
    msg = full_message()
    line = format_json(msg)
    assert line.endswith(b"\n") and line.count(b"\n") == 1
    assert b", " not in line and b": " not in line  # compact separators
    parsed = strict_loads(line)
    assert parsed == msg
    assert list(parsed) == list(msg)


def test_json_non_ascii_is_utf8() -> None:
    line = format_json({"class": "HDR", "status": "étalonnage°"})
    assert "étalonnage°".encode() in line
    assert strict_loads(line)["status"] == "étalonnage°"


def test_json_newline_in_a_value_stays_one_line() -> None:
    line = format_json({"class": "HDR", "note": "a\nb"})
    assert line.count(b"\n") == 1
    assert strict_loads(line)["note"] == "a\nb"


@pytest.mark.parametrize("missing", ["heading", "temp", "omega", "bias", "I"])
def test_unknown_value_is_absent_never_null_or_zero(missing: str) -> None:
    msg = full_message()
    del msg[missing]
    line = format_json(msg)
    parsed = strict_loads(line)
    assert missing not in parsed
    assert f'"{missing}"'.encode() not in line
    assert b"null" not in line


def test_none_value_is_dropped_not_null() -> None:
    parsed = strict_loads(format_json(full_message(heading=None, temp=None)))
    assert "heading" not in parsed and "temp" not in parsed
    assert parsed["yaw"] == 12.5


def test_zero_heading_is_kept() -> None:
    assert strict_loads(format_json(full_message(heading=0.0)))["heading"] == 0.0


@pytest.mark.parametrize(
    "bad", [math.nan, math.inf, -math.inf, np.float64("nan"), np.float32("inf")]
)
def test_non_finite_values_are_dropped(bad: float) -> None:
    line = format_json(full_message(omega=bad, gap_s=bad))
    parsed = strict_loads(line)  # raises on NaN/Infinity
    assert "omega" not in parsed and "gap_s" not in parsed
    assert parsed["heading"] == 347.5


def test_extra_keys_pass_through_in_order() -> None:
    msg = full_message(gap_s=5.25, mode="hdr+", zupt=True, aid={"src": "gpsd", "hdop": 0.9})
    parsed = strict_loads(format_json(msg))
    assert parsed["gap_s"] == 5.25 and parsed["mode"] == "hdr+" and parsed["zupt"] is True
    assert parsed["aid"] == {"src": "gpsd", "hdop": 0.9}
    assert list(parsed)[-4:] == ["gap_s", "mode", "zupt", "aid"]


def test_nested_non_finite_is_dropped() -> None:
    parsed = strict_loads(
        format_json({"class": "HDR", "aid": {"a": math.nan, "b": 1.0}, "l": [1.0, math.inf]})
    )
    assert parsed == {"class": "HDR", "aid": {"b": 1.0}}


def test_numpy_scalars_become_json_numbers() -> None:
    msg = {"class": "HDR", "step": np.int64(7), "omega": np.float32(0.5), "W": np.int8(1)}
    assert strict_loads(format_json(msg)) == {"class": "HDR", "step": 7, "omega": 0.5, "W": 1}


def test_non_mapping_is_a_clear_error() -> None:
    with pytest.raises(TypeError):
        format_json([1, 2])  # type: ignore[arg-type]


json_values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**53), 2**53),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
)


@given(st.dictionaries(st.text(min_size=1, max_size=10), json_values, max_size=20))
def test_json_property_valid_one_line_only_known_values(msg: dict[str, Any]) -> None:
    line = format_json(msg)
    assert line.endswith(b"\n") and line.count(b"\n") == 1
    parsed = strict_loads(line)
    expected = {
        k: v
        for k, v in msg.items()
        if v is not None and not (isinstance(v, float) and not math.isfinite(v))
    }
    assert parsed == expected
    assert list(parsed) == list(expected)


# -- NMEA -----------------------------------------------------------------------------------


def test_checksum_by_hand() -> None:
    assert nmea_checksum("A") == "41"  # 'A' = 0x41
    assert nmea_checksum("AB") == "03"  # 0x41 ^ 0x42
    assert nmea_checksum("HNHDT,0.00,T") == format(
        0x48 ^ 0x4E ^ 0x48 ^ 0x44 ^ 0x54 ^ 0x2C ^ 0x30 ^ 0x2E ^ 0x30 ^ 0x30 ^ 0x2C ^ 0x54, "02X"
    )


@pytest.mark.parametrize(
    "sentence",
    [
        # The classic examples of the NMEA 0183 references (gpsinformation.org, Wikipedia).
        "$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A",
        "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47",
        "$GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,*76",
    ],
)
def test_checksum_of_published_sentences(sentence: str) -> None:
    body, _, cs = sentence[1:].partition("*")
    assert nmea_checksum(body) == cs
    assert parse_nmea(sentence)[0] == body.split(",")[0]


def test_parse_nmea_rejects_bad_checksum_and_garbage() -> None:
    with pytest.raises(ValueError, match="checksum"):
        parse_nmea("$HNHDT,10.00,T*00")
    with pytest.raises(ValueError):
        parse_nmea("HNHDT,10.00,T*00")
    with pytest.raises(ValueError):
        parse_nmea("$HNHDT,10.00,T")


def decode(sentences: list[bytes]) -> dict[str, list[str]]:
    out = {}
    for s in sentences:
        assert s.endswith(b"\r\n") and s.startswith(b"$HN")
        kind, fields = parse_nmea(s)
        out[kind] = fields
    return out


def test_hdt_and_rot_of_a_left_turn() -> None:
    s = nmea_sentences(full_message(heading=123.456, omega=2.0))
    assert s[0] == nmea_sentence("HNHDT,123.46,T")
    d = decode(s)
    assert d == {"HNHDT": ["123.46", "T"], "HNROT": ["-120.0", "A"]}  # left turn = to port = -


def test_rot_of_a_right_turn_is_positive() -> None:
    assert decode(nmea_sentences(full_message(omega=-1.5, status="turning")))["HNROT"] == [
        "90.0",
        "A",
    ]


def test_rot_of_straight_driving_has_no_negative_zero() -> None:
    assert decode(nmea_sentences(full_message(omega=0.0001)))["HNROT"] == ["0.0", "A"]


@pytest.mark.parametrize("status", ["stale", "calibrating", "error", None])
def test_rot_invalid_status_says_v(status: str | None) -> None:
    msg = full_message(status=status)
    if status is None:
        del msg["status"]
    assert decode(nmea_sentences(msg))["HNROT"][1] == "V"


@pytest.mark.parametrize("status", ["ok", "turning", "standstill", "aided", "dead-reckoning"])
def test_rot_valid_status_says_a(status: str) -> None:
    assert decode(nmea_sentences(full_message(status=status)))["HNROT"][1] == "A"


def test_rot_without_omega_is_empty_and_invalid() -> None:
    msg = full_message()
    del msg["omega"]
    assert decode(nmea_sentences(msg))["HNROT"] == ["", "V"]


def test_no_heading_no_heading_sentences() -> None:
    msg = full_message()
    del msg["heading"]
    assert set(decode(nmea_sentences(msg, ths=True))) == {"HNROT"}
    assert set(decode(nmea_sentences(full_message(heading=math.nan), ths=True))) == {"HNROT"}


def test_ths_option() -> None:
    assert "HNTHS" not in decode(nmea_sentences(full_message()))
    d = decode(nmea_sentences(full_message(heading=10.0), ths=True))
    assert d["HNTHS"] == ["10.00", "E"]
    assert decode(nmea_sentences(full_message(status="stale"), ths=True))["HNTHS"][1] == "V"


def test_heading_rounding_stays_below_360() -> None:
    assert decode(nmea_sentences(full_message(heading=359.999)))["HNHDT"][0] == "0.00"


@given(
    st.floats(-500, 500, allow_nan=False),
    st.floats(-1000, 1000, allow_nan=False),
    st.booleans(),
)
def test_nmea_property(omega: float, heading: float, ths: bool) -> None:
    d = decode(nmea_sentences(full_message(omega=omega, heading=heading), ths=ths))
    h = float(d["HNHDT"][0])
    assert 0.0 <= h < 360.0
    assert math.isclose(h, heading % 360.0, abs_tol=0.006) or math.isclose(
        abs(h - heading % 360.0), 360.0, abs_tol=0.006
    )
    rot = float(d["HNROT"][0])
    assert math.isclose(rot, -omega * 60.0, abs_tol=0.051)
    if abs(omega * 60.0) >= 0.05:
        assert math.copysign(1.0, rot) == -math.copysign(1.0, omega)
    assert ("HNTHS" in d) == ths


def _pipeline_messages(method: str, speed: float | None) -> list[dict[str, Any]]:
    """Real pipeline messages: 40 s of a parked car at 10 Hz, eps0 known."""
    from hdrd.daemon.pipeline import Pipeline
    from hdrd.daemon.stepper import PipelineConfig
    from tests.test_pipeline import make_frames, run_live

    rng = np.random.default_rng(7)
    p = Pipeline(PipelineConfig(setup=MethodSetup(method=method, bias=given_bias(0.5))))
    p.set_speed(speed)
    msgs = run_live(p, make_frames(0.5 + rng.normal(0, 0.05, 400)))
    msgs.append(p.stale_message(1e9, silent_s=4.0))  # then the cable is pulled
    return msgs


@pytest.mark.parametrize("ths", [False, True])
def test_a_held_heading_is_never_sent_as_a_fresh_one(ths: bool) -> None:
    """While the gyro is silent (status stale) the message repeats the held heading; NMEA
    must not: no HDT (it has no validity field), THS and ROT say V."""
    stale = _pipeline_messages("hdr", None)[-1]
    assert stale["status"] == "stale" and "heading" in stale
    d = decode(nmea_sentences(stale, ths=ths))
    assert "HNHDT" not in d
    assert d["HNROT"] == ["", "V"]
    if ths:
        assert d["HNTHS"] == [f"{stale['heading']:.2f}", "V"]
    else:
        assert "HNTHS" not in d


@pytest.mark.parametrize("status", ["stale", "calibrating", "error", None])
def test_no_hdt_unless_the_heading_is_current(status: str | None) -> None:
    msg = full_message(status=status)
    if status is None:
        del msg["status"]
    d = decode(nmea_sentences(msg, ths=True))
    assert "HNHDT" not in d and d["HNTHS"][1] == "V" and d["HNROT"][1] == "V"


@pytest.mark.parametrize("aided", [False, True])
def test_a_standstill_rate_is_known_zero_and_valid(aided: bool) -> None:
    """HDR+'s zero-rate update: the rate is exactly 0 and the heading current, so ROT and
    THS are valid (A; THS A while GPS-aided, E otherwise) and HDT is sent."""
    still = [m for m in _pipeline_messages("hdr+", 0.0) if m.get("zupt") == 1]
    assert len(still) > 20
    for m in still:
        if aided:
            m = m | {"mode": "aided"}
        d = decode(nmea_sentences(m, ths=True))
        assert d["HNROT"] == ["0.0", "A"]
        assert d["HNTHS"] == [f"{m['heading']:.2f}", "A" if aided else "E"]
        assert d["HNHDT"] == [f"{m['heading']:.2f}", "T"]


# -- UDP ------------------------------------------------------------------------------------


@pytest.fixture
def receiver() -> Iterator[socket.socket]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(RECV_TIMEOUT_S)
    yield s
    s.close()


def closed_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return int(port)


def test_udp_json_delivers_one_datagram_per_message(receiver: socket.socket) -> None:
    port = receiver.getsockname()[1]
    with UdpJsonPublisher([("127.0.0.1", port)]) as pub:
        msgs = [full_message(step=i) for i in range(3)]
        for m in msgs:
            pub.on_message(m)
        got = [receiver.recv(65535) for _ in msgs]
        assert got == [format_json(m) for m in msgs]
        (st_,) = pub.stats()
        assert st_.sent == 3 and st_.errors == 0 and st_.address == "127.0.0.1"


def test_udp_to_several_destinations(receiver: socket.socket) -> None:
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    other.settimeout(RECV_TIMEOUT_S)
    try:
        with UdpJsonPublisher(
            [("127.0.0.1", receiver.getsockname()[1]), ("127.0.0.1", other.getsockname()[1])]
        ) as pub:
            pub.on_message(full_message())
            assert receiver.recv(65535) == other.recv(65535) == format_json(full_message())
    finally:
        other.close()


def test_udp_nmea_one_sentence_per_datagram(receiver: socket.socket) -> None:
    with UdpNmeaPublisher([("127.0.0.1", receiver.getsockname()[1])], ths=True) as pub:
        pub.on_message(full_message(omega=1.0, heading=90.0))
        got = [receiver.recv(65535) for _ in range(3)]
    assert decode(got) == {
        "HNHDT": ["90.00", "T"],
        "HNROT": ["-60.0", "A"],
        "HNTHS": ["90.00", "E"],
    }


def test_udp_ipv6_destination() -> None:
    try:
        r = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        r.bind(("::1", 0))
    except OSError:
        pytest.skip("no IPv6 loopback on this machine")
    r.settimeout(RECV_TIMEOUT_S)
    try:
        with UdpJsonPublisher([("::1", r.getsockname()[1])]) as pub:
            pub.on_message(full_message())
            assert r.recv(65535) == format_json(full_message())
    finally:
        r.close()


def resolved(pub: UdpPublisher, until: Any = lambda d: d.address is not None) -> Any:
    """The publisher's destinations once ``until`` holds for the first (names are looked up
    on a thread: the publisher never waits for them)."""
    deadline = time.monotonic() + RECV_TIMEOUT_S
    while not until(pub.stats()[0]) and time.monotonic() < deadline:
        time.sleep(0.01)
    return pub.stats()


def test_localhost_name_goes_to_ipv4(receiver: socket.socket) -> None:
    # "localhost" often resolves to ::1 first; hdrd tail listens on 127.0.0.1 by default.
    with UdpJsonPublisher([("localhost", receiver.getsockname()[1])]) as pub:
        assert resolved(pub)[0].address == "127.0.0.1"
        pub.on_message(full_message())
        assert receiver.recv(65535) == format_json(full_message())


def test_a_name_not_known_yet_costs_its_datagrams_never_a_wait(receiver: socket.socket) -> None:
    """A name is looked up on a thread: until its address is known its datagrams are dropped
    (counted), the other destinations served; a name known from before (the publishers rebuilt
    on SIGHUP, the same resolver) is used at once, while it is looked up again."""
    gate = threading.Event()

    def slow_dns(host: str, port: int, type: int = 0, flags: int = 0) -> list[Any]:  # noqa: A002
        if flags & socket.AI_NUMERICHOST:
            return socket.getaddrinfo(host, port, type=type, flags=flags)
        gate.wait(RECV_TIMEOUT_S)
        return [(socket.AF_INET, type, 0, "", ("127.0.0.1", port))]

    res = Resolver(slow_dns, refresh_min_s=0.0)
    good = receiver.getsockname()[1]
    pub = UdpJsonPublisher([("gyro-display.example", good), ("127.0.0.1", good)], resolver=res)
    pub.on_message(full_message(step=1))  # returns at once, the lookup still running
    assert receiver.recv(65535) == format_json(full_message(step=1))  # the numeric one
    named, numeric = pub.stats()
    assert named.dropped == 1 and named.address is None and numeric.sent == 1
    gate.set()
    resolved(pub)
    pub.on_message(full_message(step=2))
    assert [json.loads(receiver.recv(65535))["step"] for _ in range(2)] == [2, 2]
    pub.stop()
    gate.clear()  # the next lookup of the name waits again: the old address serves meanwhile
    again = UdpJsonPublisher([("gyro-display.example", good)], resolver=res)
    again.on_message(full_message(step=3))
    assert json.loads(receiver.recv(65535))["step"] == 3
    assert again.stats()[0].dropped == 0
    gate.set()
    again.stop()


def test_refusing_destination_is_counted_and_never_stops_the_others(
    receiver: socket.socket,
) -> None:
    dead = closed_udp_port()
    good = receiver.getsockname()[1]
    pub = UdpJsonPublisher([("127.0.0.1", dead), ("127.0.0.1", good)])
    n = 0
    # ICMP port unreachable arrives asynchronously: publish until it has been seen.
    while n < 200:
        pub.on_message(full_message(step=n))  # must never raise
        n += 1
        if n >= 5 and pub.stats()[0].errors > 0:
            break
    dead_stats, good_stats = pub.stats()
    assert dead_stats.errors > 0
    assert dead_stats.by_error.get("ECONNREFUSED", 0) > 0
    assert "ECONNREFUSED" in (dead_stats.last_error or "")
    # The pending error on the shared socket cost the good destination nothing.
    assert good_stats.errors == 0 and good_stats.sent == n
    got = [strict_loads(receiver.recv(65535))["step"] for _ in range(n)]
    assert got == list(range(n))
    pub.stop()
    pub.stop()  # idempotent
    pub.on_message(full_message())  # after stop: ignored, no error


def test_unresolvable_host_is_counted_and_not_fatal(receiver: socket.socket) -> None:
    # .invalid never resolves (RFC 6761).
    pub = UdpJsonPublisher(
        [("no-such-host.invalid", 10110), ("127.0.0.1", receiver.getsockname()[1])]
    )
    bad, _ = resolved(pub, lambda d: d.errors >= 1)
    assert bad.errors >= 1 and bad.by_error["resolve"] >= 1 and bad.address is None
    assert "no-such-host.invalid" in (bad.last_error or "")
    pub.on_message(full_message())
    pub.on_message(full_message())
    bad, good = pub.stats()
    assert bad.dropped == 2 and bad.sent == 0
    assert good.sent == 2
    assert receiver.recv(65535) == format_json(full_message())
    assert sum(d.errors for d in pub.stats()) >= 1
    assert bad.to_dict()["dest"] == "no-such-host.invalid:10110"
    pub.stop()


def test_unresolvable_host_is_retried_in_the_background() -> None:
    res = Resolver(retry_min_s=0.0)
    pub = UdpJsonPublisher([("no-such-host.invalid", 10110)], resolver=res)
    deadline = time.monotonic() + RECV_TIMEOUT_S
    while pub.stats()[0].by_error.get("resolve", 0) < 2 and time.monotonic() < deadline:
        pub.on_message(full_message())  # starts a retry when none is running; never blocks on it
        time.sleep(0.01)
    assert pub.stats()[0].by_error["resolve"] >= 2
    pub.stop()


def test_formatter_returning_a_list(receiver: socket.socket) -> None:
    with UdpPublisher([("127.0.0.1", receiver.getsockname()[1])], lambda m: [b"a", b"b"]) as pub:
        pub.on_message({})
        assert [receiver.recv(10), receiver.recv(10)] == [b"a", b"b"]


# -- stdout ---------------------------------------------------------------------------------


def test_stdout_publisher_writes_lines() -> None:
    r, w = os.pipe()
    with os.fdopen(r, "rb") as rf, os.fdopen(w, "wb") as wf:
        pub = StdoutPublisher(wf)
        pub.on_message(full_message(step=1))
        pub.on_message(full_message(step=2))  # flushed per message: readable now
        assert rf.readline() == format_json(full_message(step=1))
        assert rf.readline() == format_json(full_message(step=2))
        pub.stop()
        assert pub.written == 2


def test_stdout_publisher_raises_output_closed_when_the_reader_goes_away() -> None:
    r, w = os.pipe()
    os.close(r)
    wf = os.fdopen(w, "wb")
    pub = StdoutPublisher(wf)
    pub.on_message(full_message())  # queued: the writer thread meets the closed pipe
    with pytest.raises(OutputClosed):
        pub.flush(RECV_TIMEOUT_S)
    assert pub.closed
    with pytest.raises(OutputClosed):
        pub.on_message(full_message())
    pub.stop()  # no error
    wf.close()  # nor here: the descriptor now points at /dev/null


def finishes(work: Any) -> bool:
    """Run *work* in a thread; False if it is still running after RECV_TIMEOUT_S (blocked:
    the thread is left behind, unblocked by the test closing the pipe)."""
    import threading

    t = threading.Thread(target=work, daemon=True)
    t.start()
    t.join(RECV_TIMEOUT_S)
    return not t.is_alive()


def stalled_pipe() -> tuple[int, Any]:
    """A real pipe whose reader never reads: (read fd, writable file), the pipe's buffer
    shrunk to one page so that it fills at once."""
    import fcntl

    r, w = os.pipe()
    fcntl.fcntl(w, 1031, 4096)  # F_SETPIPE_SZ: the smallest pipe Linux makes
    return r, os.fdopen(w, "wb")


def test_a_stalled_reader_never_blocks_the_caller_and_drops_are_counted() -> None:
    r, wf = stalled_pipe()
    try:
        pub = StdoutPublisher(wf, max_queue_bytes=16384, stop_wait_s=0.2)
        n = 5000  # about 2 MB of lines into a 4 KiB pipe nobody reads

        def publish() -> None:
            for i in range(n):
                pub.on_message(full_message(step=i))

        if not finishes(publish):
            os.close(r)  # unblock the write, so that the test fails rather than hangs
            raise AssertionError("on_message blocked on the stalled reader")
        assert pub.dropped > 0 and pub.written + pub.dropped <= n
        pub.stop()  # gives up after stop_wait_s: the reader still does not read
        assert pub.written + pub.dropped == n and pub.errors == 0 and not pub.closed
        # what did get through is whole lines, in order, from the first one
        os.set_blocking(r, False)
        got = os.read(r, 1 << 20)
        lines = got.split(b"\n")
        assert lines[0] == format_json(full_message(step=0)).rstrip(b"\n")
        steps = [json.loads(x)["step"] for x in lines[:-1]]
        assert steps == sorted(steps) and len(set(steps)) == len(steps)
    finally:
        try:
            os.close(r)
        except OSError:
            pass
        wf.close()


def test_other_publishers_go_on_while_stdout_is_stalled(receiver: socket.socket) -> None:
    """The daemon calls its publishers in turn: a stalled stdout reader must not hold up
    the UDP one (it used to block in write(2) for good)."""
    r, wf = stalled_pipe()
    port = receiver.getsockname()[1]
    stdout = StdoutPublisher(wf, stop_wait_s=0.2)
    pubs: list[Any] = [stdout, UdpJsonPublisher([("127.0.0.1", port)])]
    try:
        n = 3000  # 1 MB of JSON lines: far beyond the pipe and the stdout queue
        got: list[int] = []

        def publish() -> None:
            for i in range(n):
                for p in pubs:
                    p.on_message(full_message(step=i))
                if i % 100 == 99:  # read as we go: the receive buffer is not the subject here
                    while len(got) <= i:
                        got.append(json.loads(receiver.recv(65536))["step"])

        if not finishes(publish):
            os.close(r)  # unblock the write, so that the test fails rather than hangs
            raise AssertionError(f"UDP held up by the stalled stdout after {len(got)} steps")
        assert got == list(range(n))
        assert stdout.dropped > 0
    finally:
        for p in pubs:
            p.stop()
        try:
            os.close(r)
        except OSError:
            pass
        wf.close()


def test_stdout_closed_by_head_exits_without_traceback() -> None:
    code = textwrap.dedent(
        """
        import sys
        from hdrd.io.net.publish import OutputClosed, StdoutPublisher
        pub = StdoutPublisher()
        try:
            for i in range(1_000_000):
                pub.on_message({"class": "HDR", "step": i})
        except OutputClosed:
            pub.stop()
            sys.exit(0)
        sys.exit(3)
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    proc.stdout.close()  # what `| head -1` does
    rc = proc.wait(timeout=60)
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert strict_loads(first) == {"class": "HDR", "step": 0}
    assert rc == 0, err
    assert "Traceback" not in err and "Exception ignored" not in err


# -- docs/protocol.md, "Published messages" ---------------------------------------------------


def published_section() -> str:
    from pathlib import Path

    text = (Path(__file__).resolve().parent.parent / "docs" / "protocol.md").read_text()
    heading = "\n## Published messages\n"
    assert heading in text
    section = text.split(heading, 1)[1]
    return section.split("\n## ", 1)[0]


def test_documented_json_example_is_what_format_json_writes() -> None:
    examples = [
        line for line in published_section().splitlines() if line.startswith('{"class":"HDR"')
    ]
    assert examples
    for line in examples:
        msg = strict_loads(line.encode())
        assert format_json(msg) == line.encode() + b"\n"


def test_documented_nmea_examples_are_what_nmea_sentences_writes() -> None:
    examples = [line for line in published_section().splitlines() if line.startswith("$HN")]
    assert len(examples) == 2
    assert [e.encode() + b"\r\n" for e in examples] == nmea_sentences(
        {"heading": 123.456, "omega": 2.0, "status": "turning"}
    )


# -- stdout on a terminal: numbers as a person reads them ------------------------------------


def _run_stdout(tmp_path: Any, on_tty: bool, steps: int = 6) -> list[dict[str, Any]]:
    """``hdrd run --simulate --stdout`` with stdout on a pty (a terminal) or a pipe, until
    ``steps`` steps with a rate are out; its messages."""
    import re

    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("simulate:\n  drive: city\n  speedup: 50\n")
    env = dict(os.environ)
    for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC"):
        env.pop(k, None)
    env["STATE_DIRECTORY"] = str(tmp_path)  # no bias file: measured at start
    argv = [sys.executable, "-m", "hdrd", "run", "--simulate", "--config", str(cfg), "--stdout"]
    master, slave = os.openpty() if on_tty else os.pipe()  # (read, write) both
    proc = subprocess.Popen(argv, stdout=slave, stderr=subprocess.DEVNULL, env=env)
    os.close(slave)
    text = ""
    try:
        deadline = time.monotonic() + 60
        while text.count('"omega":') < steps and time.monotonic() < deadline:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                break
            if not chunk:
                break
            text += chunk.decode()
    finally:
        proc.terminate()
        proc.wait(timeout=60)
        os.close(master)
    lines = [x for x in re.split(r"\r?\n", text) if x.startswith("{")]
    assert sum('"omega":' in x for x in lines) >= steps, text[-500:]
    return [json.loads(x) for x in lines if x.endswith("}")]


def _decimals(v: float) -> int:
    text = repr(v)
    return len(text.split(".", 1)[1]) if "." in text and "e" not in text else 0


@pytest.mark.slow
def test_run_stdout_on_a_terminal_rounds_numbers_and_a_pipe_keeps_them(tmp_path: Any) -> None:
    """A yaw of -0.0025271484375000014 is noise on a terminal: there hdrd run --stdout shows
    each number to what it means; a pipe (a program, a file) gets every digit."""
    from hdrd.io.net.display import DECIMALS

    shown = _run_stdout(tmp_path, on_tty=True)
    for m in shown:
        for k, v in m.items():
            if isinstance(v, float) and k in DECIMALS:
                assert _decimals(v) <= DECIMALS[k], (k, v)
    piped = _run_stdout(tmp_path, on_tty=False)
    assert any(
        _decimals(v) > DECIMALS[k]
        for m in piped
        for k, v in m.items()
        if isinstance(v, float) and k in DECIMALS
    ), piped[-1]
