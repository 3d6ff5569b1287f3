"""gpsd's JSON protocol: the pure parser on gpsd's own examples and on real gpsd 3.22 output,
and the client edge against real TCP peers on 127.0.0.1 (partial and bad lines, a peer that
goes away and comes back, refused connections with backoff). The real gpsd and gpsfake are
in test_gpsd_nmea.py."""

from __future__ import annotations

import itertools
import json
import math
import socket
import time
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.daemon.aiding import GpsAiding
from hdrd.io.net.gpsd import GpsdClient
from hdrd.io.net.gpsdjson import (
    WATCH_COMMAND,
    Device,
    Devices,
    Fix,
    GpsdError,
    GpsdProtocolError,
    Version,
    Watch,
    parse_line,
    parse_time,
)

WAIT = 20.0  # upper bound for a poll loop; only a hung client reaches it

# Examples from gpsd_json(5) (gpsd 3.22), one line each.
DOC_TPV = (
    '{"class":"TPV","device":"/dev/pts/1","time":"2005-06-08T10:34:48.283Z","ept":0.005,'
    '"lat":46.498293369,"lon":7.567411672,"alt":1343.127,"eph":36.000,"epv":32.321,'
    '"track":10.3788,"speed":0.091,"climb":-0.085,"mode":3}'
)
DOC_SKY = (
    '{"class":"SKY","device":"/dev/pts/1","time":"2005-07-08T11:28:07.114Z",'
    '"xdop":1.55,"hdop":1.24,"pdop":1.99,"satellites":['
    '{"PRN":23,"el":6,"az":84,"ss":0,"used":false},{"PRN":28,"el":7,"az":160,"ss":0,"used":false},'
    '{"PRN":8,"el":66,"az":189,"ss":44,"used":true},{"PRN":29,"el":13,"az":273,"ss":0,"used":false},'
    '{"PRN":10,"el":51,"az":304,"ss":29,"used":true},{"PRN":4,"el":15,"az":199,"ss":36,"used":true},'
    '{"PRN":2,"el":34,"az":241,"ss":43,"used":true},{"PRN":27,"el":71,"az":76,"ss":43,"used":true}]}'
)
DOC_VERSION = '{"class":"VERSION","release":"2.40dev","rev":"06f62e14eae9886cde907dae61c124c53eb1101f","proto_major":3,"proto_minor":1}'
DOC_DEVICES = (
    '{"class":"DEVICES","devices":[{"class":"DEVICE","path":"/dev/pts/1","flags":1,"driver":"SiRF binary"},'
    '{"class":"DEVICE","path":"/dev/pts/3","flags":4,"driver":"AIVDM"}]}'
)
DOC_WATCH = '{"class":"WATCH","enable":true,"json":true,"nmea":false,"raw":0,"scaled":false,"timing":false,"split24":false,"pps":false}'
DOC_ATT = (
    '{"class":"ATT","time":1270938096.843,"heading":14223.00,"mag_st":"N","pitch":169.00,"pitch_st":"N",'
    '"roll":-43.00,"roll_st":"N","dip":13641.000,"mag_len":0.000,"mag_x":2805.000,"mag_y":-8.000,'
    '"mag_z":-12181.000,"acc_len":0.000,"acc_x":-23.000,"acc_y":-23.000,"acc_z":-51.000,'
    '"gyro_x":0.000,"gyro_y":0.000,"temp":-1.000,"depth":0.000}'
)
DOC_ERROR = '{"class":"ERROR","message":"Unrecognized request \'?FOO\'"}'

# Captured from gpsd 3.22 (Debian 12) fed by gpsfake and by a udp:// NMEA source.
REAL_TPV = (
    '{"class":"TPV","device":"/dev/pts/1","mode":3,"time":"2013-11-06T12:00:01.000Z","ept":0.005,'
    '"lat":48.117300000,"lon":11.516666667,"altHAE":592.3000,"altMSL":545.4000,"alt":545.4000,'
    '"track":31.0000,"magtrack":34.3264,"magvar":3.3,"speed":10.289,"climb":0.000,'
    '"geoidSep":46.900,"eph":17.100}'
)
REAL_TPV_NOFIX = (
    '{"class":"TPV","device":"/dev/pts/1","mode":1,"time":"2033-06-22T12:00:09.000Z","ept":0.005}'
)
REAL_TPV_GGA_ONLY = (
    '{"class":"TPV","device":"/dev/pts/1","mode":3,"lat":48.117300000,"lon":11.516666667,'
    '"altHAE":592.3000,"altMSL":545.4000,"alt":545.4000,"magvar":3.3,"geoidSep":46.900,"eph":17.100}'
)
REAL_DEVICE = (
    '{"class":"DEVICE","path":"/dev/pts/1","driver":"NMEA0183","activated":"2026-11-21T20:08:20.212Z",'
    '"native":0,"bps":4800,"parity":"N","stopbits":1,"cycle":1.00}'
)
REAL_ATT = '{"class":"ATT","device":"udp://127.0.0.1:29481","heading":123.450}'
REAL_VERSION = '{"class":"VERSION","release":"3.22","rev":"3.22","proto_major":3,"proto_minor":14}'


# -- parser ------------------------------------------------------------------------------------


def test_doc_tpv():
    f = parse_line(DOC_TPV)
    assert isinstance(f, Fix)
    assert f.mode == 3 and f.has_fix
    assert f.time == pytest.approx(1118226888.283)  # 2005-06-08T10:34:48.283Z
    assert f.track_deg == pytest.approx(10.3788) and f.speed_mps == pytest.approx(0.091)
    assert f.lat == pytest.approx(46.498293369) and f.lon == pytest.approx(7.567411672)
    assert f.alt_m == pytest.approx(1343.127) and f.climb_mps == pytest.approx(-0.085)
    assert f.epd is None and f.eps is None  # not sent: unknown, not 0
    assert f.device == "/dev/pts/1"


def test_sky_and_att_are_not_read() -> None:
    """hdrd uses neither satellites (SKY) nor attitude (ATT): they read as classes hdrd does
    not use, whatever they hold."""
    for line in (DOC_SKY, DOC_ATT, REAL_ATT, '{"class":"SKY","satellites":{}}'):
        assert parse_line(line) is None


def test_doc_session_reports():
    assert parse_line(DOC_VERSION) == Version(
        "2.40dev", "06f62e14eae9886cde907dae61c124c53eb1101f", 3, 1
    )
    assert parse_line(REAL_VERSION) == Version("3.22", "3.22", 3, 14)
    assert parse_line(DOC_DEVICES) == Devices(
        (Device(path="/dev/pts/1", driver="SiRF binary"), Device(path="/dev/pts/3", driver="AIVDM"))
    )
    assert parse_line(DOC_WATCH) == Watch(enable=True, json=True)
    assert parse_line(DOC_ERROR) == GpsdError("Unrecognized request '?FOO'")
    assert parse_line(REAL_DEVICE) == Device(
        "/dev/pts/1", "NMEA0183", "2026-11-21T20:08:20.212Z", 4800
    )


def test_real_gpsd_tpv_variants():
    f = parse_line(REAL_TPV)
    assert isinstance(f, Fix)
    assert (f.mode, f.track_deg, f.speed_mps) == (3, 31.0, 10.289)
    assert f.alt_m == 545.4  # MSL preferred
    assert f.time == pytest.approx(1383739201.0)
    nofix = parse_line(REAL_TPV_NOFIX)
    assert isinstance(nofix, Fix) and nofix.mode == 1 and not nofix.has_fix
    assert nofix.track_deg is None and nofix.speed_mps is None
    gga = parse_line(REAL_TPV_GGA_ONLY)
    assert isinstance(gga, Fix) and gga.mode == 3 and gga.time is None and gga.track_deg is None


def test_line_endings_bytes_and_unknown_classes():
    assert parse_line((REAL_TPV + "\r\n").encode()) == parse_line(REAL_TPV)
    assert parse_line('{"class":"PPS","device":"/dev/pps0","real_sec":1}') is None
    assert parse_line('{"class":"GST","device":"/dev/ttyS0"}') is None


def test_track_is_normalised_to_compass_range():
    f = parse_line('{"class":"TPV","mode":2,"track":360.0,"speed":5}')
    assert isinstance(f, Fix) and f.track_deg == 0.0 and f.speed_mps == 5.0


@pytest.mark.parametrize(
    ("line", "why"),
    [
        ("", "empty"),
        ("   \r", "empty"),
        ("not json", "not JSON"),
        ('{"class":"TPV","mode":3', "not JSON"),
        ("[1, 2]", "not a JSON object"),
        ('{"mode":3}', "no 'class'"),
        ('{"class":3}', "no 'class'"),
        ('{"class":"TPV","mode":"3"}', "'mode' is not a number"),
        ('{"class":"TPV","mode":3,"track":true}', "'track' is not a number"),
        ('{"class":"TPV","mode":3,"device":5}', "'device' is not a string"),
        ('{"class":"DEVICES","devices":[1]}', "'devices' is not a list of objects"),
        ('{"class":"WATCH","enable":1}', "'enable' is not true/false"),
        (b"\xff\xfe{}", "not UTF-8"),
    ],
)
def test_bad_lines_raise_a_clear_error(line, why):
    with pytest.raises(GpsdProtocolError, match=why):
        parse_line(line)


REPORT_OF = {
    "TPV": Fix,
    "VERSION": Version,
    "DEVICES": Devices,
    "DEVICE": Device,
    "WATCH": Watch,
    "ERROR": GpsdError,
}
"""The report each class of gpsd_json(5) hdrd reads is parsed to; any other class is None."""


def json_class(line: bytes | str) -> str | None:
    """The ``class`` of a line that is a JSON object with a string one (an independent
    reading: the json module on the UTF-8 text), else None."""
    try:
        text = line.decode("utf-8") if isinstance(line, bytes) else line
        obj = json.loads(text.strip())
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None
    cls = obj.get("class") if isinstance(obj, dict) else None
    return cls if isinstance(cls, str) else None


def check_parsed(line: bytes | str) -> Any:
    """parse_line(line) as the module says: a line that is not a JSON object with a string
    ``class`` is a GpsdProtocolError with a one-line reason; else the report of its class
    (None for a class hdrd does not read), or a GpsdProtocolError. Returns the report, or the
    error."""
    cls = json_class(line)
    try:
        rep = parse_line(line)
    except GpsdProtocolError as e:
        assert str(e) and "\n" not in str(e)
        return e
    assert cls is not None, (line, rep)
    assert type(rep) is REPORT_OF.get(cls, type(None)), (cls, rep)
    if isinstance(rep, Fix):
        assert rep.speed_mps is None or 0.0 <= rep.speed_mps < math.inf
        assert rep.track_deg is None or 0.0 <= rep.track_deg < 360.0
    return rep


_class_names = st.sampled_from([*REPORT_OF, "SKY", "ATT", "XYZ"])
_lines = st.binary(max_size=200) | st.builds(
    lambda cls, extra: json.dumps({"class": cls, **extra}).encode(),
    _class_names,
    st.dictionaries(st.sampled_from(["mode", "track", "release", "message"]), st.integers()),
)


@given(_lines)
def test_any_bytes_give_a_report_none_or_a_protocol_error(data):
    got = check_parsed(data)
    if json_class(data) is None:
        assert isinstance(got, GpsdProtocolError)


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


@given(
    st.sampled_from(["TPV", "SKY", "ATT", "VERSION", "DEVICES", "DEVICE", "WATCH", "ERROR", "XYZ"]),
    st.dictionaries(
        st.sampled_from(
            [
                "mode",
                "time",
                "track",
                "speed",
                "epd",
                "satellites",
                "devices",
                "enable",
                "heading",
                "path",
                "release",
                "nSat",
            ]
        ),
        _json,
        max_size=5,
    ),
)
def test_any_object_of_a_known_class_parses_or_fails_cleanly(cls, attrs):
    check_parsed(json.dumps({"class": cls, **attrs}))


@pytest.mark.parametrize(
    ("text", "unix"),
    [
        ("1970-01-01T00:00:00Z", 0.0),
        ("2005-06-08T10:34:48.283Z", 1118226888.283),
        ("2016-12-31T23:59:60.000Z", 1483228800.0),  # a leap second maps onto the next
        ("2024-02-29T12:00:00.123456789Z", 1709208000.123456789),
        (1270938096.843, 1270938096.843),
        ("2024-13-01T00:00:00Z", None),
        ("yesterday", None),
        (True, None),
        (None, None),
    ],
)
def test_parse_time(text, unix):
    got = parse_time(text)
    assert got == (None if unix is None else pytest.approx(unix, abs=1e-6))


# -- client edge -----------------------------------------------------------------------------------


class Peer:
    """A TCP listener on 127.0.0.1 speaking as gpsd does (lines given by the test)."""

    def __init__(self) -> None:
        self.srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.srv.bind(("127.0.0.1", 0))
        self.srv.listen(4)
        self.port = self.srv.getsockname()[1]
        self.conn: socket.socket | None = None

    def accept(self, pump: Any = None) -> bytes:
        """Accept the client and return its first request line; ``pump()`` is called while
        waiting (the client only connects when polled)."""
        self.srv.settimeout(0.01)
        deadline = time.monotonic() + WAIT
        while True:
            try:
                self.conn, _ = self.srv.accept()
                break
            except TimeoutError:
                if time.monotonic() > deadline:
                    raise
                if pump is not None:
                    pump()
        self.conn.settimeout(WAIT)
        data = b""
        while not data.endswith(b"\n"):
            chunk = self.conn.recv(256)
            if not chunk:
                break
            data += chunk
        return data

    def send(self, data: bytes | str) -> None:
        assert self.conn is not None
        self.conn.sendall(data.encode() if isinstance(data, str) else data)

    def hangup(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None

    def close(self) -> None:
        self.hangup()
        self.srv.close()


@pytest.fixture
def peer() -> Iterator[Peer]:
    p = Peer()
    try:
        yield p
    finally:
        p.close()


def poll_until(client: GpsdClient, cond: Any, timeout: float = WAIT) -> list[Any]:
    got: list[Any] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got.extend(client.poll_reports())
        if cond(got):
            return got
        time.sleep(0.01)
    raise AssertionError(f"condition not met; got {got}")


def test_client_watches_buffers_partial_lines_and_skips_bad_ones(peer):
    with GpsdClient("127.0.0.1", peer.port) as c:
        assert c.poll() == []  # starts connecting; never blocks
        assert peer.accept() == WATCH_COMMAND
        poll_until(c, lambda _: c.connected)
        peer.send(REAL_VERSION + "\r\n" + DOC_WATCH + "\r\n" + REAL_TPV[:50])
        got = poll_until(c, lambda g: len(g) >= 2)
        assert got == [Version("3.22", "3.22", 3, 14), Watch(True, True)]
        assert c.version == Version("3.22", "3.22", 3, 14)
        peer.send(REAL_TPV[50:] + "\r\n{garbage\r\n" + REAL_TPV_NOFIX + "\r\n" + DOC_SKY + "\r\n")
        got = poll_until(c, lambda g: len(g) >= 2)
        assert [type(r) for r in got] == [Fix, Fix]  # SKY: not a report hdrd reads
        assert got[0] == parse_line(REAL_TPV) and got[1].mode == 1
        assert c.stats.bad_lines == 1 and "garbage" in c.stats.errors[-1]
        assert c.stats.fixes == 2
        # an over-long line without a newline is dropped, and what follows still parses
        peer.send(b"x" * 70000)
        poll_until(c, lambda _: c.stats.bad_lines == 2)
        peer.send(b"\n" + REAL_TPV.encode() + b"\n")
        fixes: list[Fix] = []
        deadline = time.monotonic() + WAIT
        while not fixes and time.monotonic() < deadline:
            fixes = c.poll()
        assert fixes == [parse_line(REAL_TPV)]
    assert c.closed and c.poll() == []
    c.close()  # idempotent


def test_client_survives_the_peer_going_away_and_reconnects(peer):
    c = GpsdClient("127.0.0.1", peer.port, reconnect_min_s=0.05, reconnect_max_s=0.2)
    try:
        c.poll()
        peer.accept()
        poll_until(c, lambda _: c.connected)
        peer.send(REAL_TPV + "\n")
        poll_until(c, lambda g: any(isinstance(r, Fix) for r in g))
        peer.hangup()
        poll_until(c, lambda _: not c.connected)
        assert c.stats.disconnects == 1
        # the listener is still there: the client comes back by itself and watches again
        assert peer.accept(pump=c.poll_reports) == WATCH_COMMAND
        poll_until(c, lambda _: c.connected)
        assert c.stats.connects == 2
        peer.send(REAL_TPV_NOFIX + "\n")
        got = poll_until(c, lambda g: any(isinstance(r, Fix) for r in g))
        assert got[-1].mode == 1
    finally:
        c.close()


class ManualClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_refused_connections_back_off_and_never_raise():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nobody listens there now
    clock = ManualClock()
    c = GpsdClient("127.0.0.1", port, reconnect_min_s=0.5, reconnect_max_s=4.0, clock=clock)
    tries: list[float] = []
    for k in range(600):  # 60 s of a 10 Hz loop
        clock.t = k * 0.1
        before = c.stats.attempts
        assert c.poll() == []
        if c.stats.attempts > before:
            tries.append(clock.t)
        if c._connecting:  # a refused non-blocking connect shows on the next poll
            time.sleep(0.01)
    c.close()
    gaps = [b - a for a, b in itertools.pairwise(tries)]
    assert not c.connected and c.stats.connects == 0
    assert 10 <= len(tries) <= 25, tries  # not 600: backed off
    assert gaps[0] < gaps[2] < gaps[4]  # doubling ...
    assert max(gaps) <= 4.0 + 0.25  # ... up to the maximum


# -- hostile input: anything that answers on the gpsd address -----------------------------------

HUGE_INT = "9" * 5000  # beyond Python's 4,300-digit int-from-string limit
BEYOND_FLOAT = "1" + "0" * 400  # a valid JSON integer no float can hold


@pytest.mark.parametrize(
    "line",
    [
        '{"class":"TPV","mode":3,"speed":' + HUGE_INT + "}",
        '{"class":"TPV","mode":' + HUGE_INT + "}",
        '{"class":"SKY","satellites":[{"PRN":' + HUGE_INT + "}]}",
        '{"class":"DEVICES","devices":[{"bps":' + HUGE_INT + "}]}",
        '{"class":"ATT","heading":-' + HUGE_INT + "}",
        "[" * 100_000 + "]" * 100_000,
        '{"class":"TPV","x":' + "[" * 50_000 + "]" * 50_000 + "}",
    ],
    ids=[
        "tpv-speed",
        "tpv-mode",
        "sky-prn",
        "devices-bps",
        "att-heading",
        "deep-list",
        "deep-attribute",
    ],
)
def test_lines_no_parser_can_use_are_protocol_errors(line):
    with pytest.raises(GpsdProtocolError) as e:
        parse_line(line)
    assert str(e.value) and "\n" not in str(e.value)  # a reason, one line


def test_a_time_with_a_fraction_of_5000_digits_is_read_to_float_precision():
    f = parse_line('{"class":"TPV","mode":3,"time":"2005-06-08T10:34:48.' + HUGE_INT + 'Z"}')
    assert isinstance(f, Fix) and f.time == 1118226889.0  # 48.999... s is 49 s


@pytest.mark.parametrize("key", ["mode", "speed", "track", "epd", "eps", "lat", "time", "status"])
@pytest.mark.parametrize("sign", ["", "-"])
def test_integers_beyond_float_range_read_as_absent(key, sign):
    f = parse_line(f'{{"class":"TPV","mode":3,"{key}":{sign}{BEYOND_FLOAT}}}')
    assert isinstance(f, Fix)
    field_of = {
        "mode": "mode",
        "speed": "speed_mps",
        "track": "track_deg",
        "epd": "epd",
        "eps": "eps",
        "lat": "lat",
        "time": "time",
        "status": "status",
    }
    assert getattr(f, field_of[key]) == (0 if key == "mode" else None)


def test_numbers_in_every_report_class_beyond_float_range():
    v = parse_line('{"class":"VERSION","release":"3.22","proto_major":' + BEYOND_FLOAT + "}")
    assert v == Version(release="3.22", proto_major=None)
    assert parse_line('{"class":"DEVICE","bps":' + BEYOND_FLOAT + "}") == Device(bps=None)


@pytest.mark.parametrize(
    ("value", "unix"),
    [
        ("0000-01-01T00:00:00Z", None),
        ("0000-12-31T23:59:60.999Z", None),
        (float("nan"), None),
        (1e308, 1e308),  # a (silly) finite UNIX time is a time
        (-1e308, -1e308),
    ],
)
def test_times_no_calendar_holds_are_unknown(value, unix):
    f = parse_line(json.dumps({"class": "TPV", "mode": 3, "time": value}))
    assert isinstance(f, Fix) and f.time == unix


@pytest.mark.parametrize("key", ["speed", "epd", "eps"])
def test_negative_magnitudes_read_as_absent(key):
    f = parse_line(f'{{"class":"TPV","mode":3,"track":90.0,"speed":12.0,"{key}":-2.5}}')
    assert isinstance(f, Fix)
    assert {"speed": f.speed_mps, "epd": f.epd, "eps": f.eps}[key] is None


def test_a_negative_speed_never_reaches_the_pipeline_as_a_standstill():
    """A negative speed would pass the zero-rate update's "speed at or below 0.3 m/s" test."""
    a = GpsAiding()
    f = parse_line('{"class":"TPV","mode":3,"track":90.0,"speed":-20.0}')
    assert isinstance(f, Fix)
    a.on_fix(f, 0.0)
    assert a.speed(0.1) is None and a.good_fix(0.1) is None
    # and should a Fix be built by hand with one, aiding ignores it the same way
    a.on_fix(Fix(mode=3, track_deg=90.0, speed_mps=-20.0), 1.0)
    assert a.speed(1.1) is None and a.good_fix(1.1) is None


_any_json = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(min_value=2**1024, max_value=10**4000).map(lambda x: x * (-1) ** (x % 2))
    | st.floats()
    | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


@given(
    st.sampled_from(["TPV", "SKY", "ATT", "VERSION", "DEVICES", "DEVICE", "WATCH", "ERROR"]),
    st.dictionaries(
        st.sampled_from(
            [
                "mode",
                "time",
                "track",
                "speed",
                "epd",
                "eps",
                "lat",
                "lon",
                "alt",
                "altMSL",
                "climb",
                "status",
                "satellites",
                "devices",
                "heading",
                "pitch",
                "roll",
                "bps",
                "nSat",
                "uSat",
                "hdop",
                "pdop",
                "proto_major",
                "release",
                "enable",
                "message",
            ]
        ),
        _any_json,
        max_size=8,
    ),
)
def test_any_values_of_any_size_parse_or_fail_cleanly(cls, attrs):
    check_parsed(json.dumps({"class": cls, **attrs}))


def test_client_counts_lines_it_cannot_use_and_carries_on(peer):
    with GpsdClient("127.0.0.1", peer.port) as c:
        c.poll()
        peer.accept()
        poll_until(c, lambda _: c.connected)
        peer.send(
            '{"class":"TPV","mode":3,"speed":' + HUGE_INT + "}\n"
            '{"class":"TPV","mode":3,"speed":'
            + BEYOND_FLOAT
            + "}\n"
            + "[" * 100_000
            + "\n"
            + REAL_TPV
            + "\n"
        )
        got = poll_until(c, lambda g: len(g) >= 2)
        assert got == [parse_line('{"class":"TPV","mode":3}'), parse_line(REAL_TPV)]
        assert c.stats.bad_lines == 2 and c.connected


def test_a_flooding_peer_gets_bounded_work_per_poll_and_loses_nothing(peer):
    """Each poll reads at most READ_CHUNK bytes and parses at most LINES_PER_POLL lines;
    the rest stays in the kernel (TCP flow control slows the peer) and comes in order."""
    from hdrd.io.net.gpsd import LINES_PER_POLL, READ_CHUNK

    n = 20_000
    lines = [f'{{"class":"TPV","mode":3,"speed":{k}}}\n'.encode() for k in range(n)]
    with GpsdClient("127.0.0.1", peer.port) as c:
        c.poll()
        peer.accept()
        poll_until(c, lambda _: c.connected)
        import threading

        sender = threading.Thread(target=peer.send, args=(b"".join(lines),), daemon=True)
        sender.start()
        speeds: list[float] = []
        deadline = time.monotonic() + WAIT
        while len(speeds) < n and time.monotonic() < deadline:
            got = c.poll()
            assert len(got) <= LINES_PER_POLL
            assert len(c._buf) <= READ_CHUNK + 65536
            speeds += [f.speed_mps for f in got if f.speed_mps is not None]
        sender.join(WAIT)
    assert speeds == [float(k) for k in range(n)]


@pytest.mark.parametrize(
    ("text", "addr"),
    [
        ("localhost", ("localhost", 2947)),
        ("gps.example:3000", ("gps.example", 3000)),
        ("127.0.0.1:2947", ("127.0.0.1", 2947)),
        (":2948", ("127.0.0.1", 2948)),
        ("[::1]:2947", ("::1", 2947)),
        ("[::1]", ("::1", 2947)),
        ("::1", ("::1", 2947)),
        ("fe80::1%eth0", ("fe80::1%eth0", 2947)),
    ],
)
def test_gpsd_address(text, addr):
    from hdrd.io.net.gpsd import parse_address

    assert parse_address(text) == addr


@pytest.mark.parametrize(
    "text",
    [
        "",
        " ",
        "host:",
        "host:0",
        "host:65536",
        "host:http",
        "[::1",
        "[::1]x",
        "a]:1",
        "[]:1",
        "host :1",
        "h\x1bst:1",
        "host:00000000002947",
    ],
)
def test_bad_gpsd_addresses_say_what_is_wrong(text):
    from hdrd.io.net.gpsd import parse_address

    with pytest.raises(ValueError):
        parse_address(text)


@pytest.mark.parametrize(
    ("arg", "host", "port"),
    [("localhost", "localhost", 2947), ("[::1]:2947", "::1", 2947), ("[::1]", "::1", 2947)],
)
def test_run_gpsd_option_is_the_address_gpsd_listens_on(arg, host, port, tmp_path):
    import argparse

    from hdrd.cliconfig import config_from_args

    empty = tmp_path / "hdrd.yaml"
    empty.write_text("{}\n")
    cfg, _ = config_from_args(argparse.Namespace(gpsd=arg, config=str(empty)))
    assert (cfg.gpsd.enabled, cfg.gpsd.host, cfg.gpsd.port) == (True, host, port)


def test_run_with_a_bad_gpsd_address_is_a_config_error(tmp_path):
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-m", "hdrd", "run", "--simulate", "--gpsd", "localhost:gps"],
        capture_output=True,
        timeout=WAIT,
    )
    err = r.stderr.decode()
    assert r.returncode == 78, err
    assert err.count("\n") == 1 and "--gpsd" in err and "localhost:gps" in err
