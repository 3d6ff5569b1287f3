"""``hdrd tail``: the table, --raw, --count, malformed data, signals, ``| head``."""

from __future__ import annotations

import errno
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.io.net.datagrams import TailFormatter
from hdrd.io.net.formats import format_json, nmea_sentences

GUARD_S = 30.0  # generous guards against a hang; no test asserts a duration


def hdr(step: int, **over: Any) -> dict[str, Any]:
    msg: dict[str, Any] = {
        "class": "HDR",
        "v": 1,
        "time": 1700000000.0 + step,
        "t": float(step),
        "step": step,
        "omega_raw": 0.3,
        "omega": 0.0581,
        "yaw": -1.25,
        "heading": 1.25,
        "I": -0.0422,
        "W": 1,
        "R": 1.0,
        "r": 1,
        "bias": 0.2419,
        "samples": 10,
        "bad_frames": 3,
        "status": "ok",
    }
    msg.update(over)
    return msg


# -- the formatter (pure) -------------------------------------------------------------------


def test_header_once_then_rows() -> None:
    f = TailFormatter()
    out, notes, n = f.lines(format_json(hdr(1)) + format_json(hdr(2)))
    assert n == 2 and notes == []
    assert out[0].split() == [
        "time",
        "step",
        "status",
        "heading",
        "yaw",
        "omega",
        "I",
        "W",
        "r",
        "bias",
        "samples",
        "bad",
        "mode",
    ]
    row = out[1].split()
    assert row[1:] == [
        "1",
        "ok",
        "1.25",
        "-1.25",
        "0.058",
        "-0.0422",
        "1",
        "1",
        "0.2419",
        "10",
        "3",
        "-",
    ]
    out2, _, _ = f.lines(format_json(hdr(3)))
    assert len(out2) == 1 and out2[0].split()[1] == "3"
    out3, _, _ = f.lines(format_json(dict(hdr(4), mode="dead-reckoning")))
    assert out3[0].split()[-1] == "dead-reckoning"


def test_missing_values_print_as_dash() -> None:
    msg = hdr(4, status="calibrating")
    for k in ("heading", "I", "bias"):
        del msg[k]
    out, _, _ = TailFormatter().lines(format_json(msg))
    assert out[1].split()[3] == "-" and out[1].split()[6] == "-" and out[1].split()[9] == "-"


def test_malformed_data_gives_notes_and_is_skipped() -> None:
    f = TailFormatter()
    data = b'not json\n{"class":\n[1,2]\n\xff\xfe\n$HNHDT,1.00,T*00\n' + format_json(hdr(5))
    out, notes, n = f.lines(data, sender="127.0.0.1:9")
    assert n == 1 and out[-1].split()[1] == "5"
    assert len(notes) == 5 and all("127.0.0.1:9" in note for note in notes)


def test_nmea_printed_raw_and_decoded() -> None:
    sentences = b"".join(nmea_sentences(hdr(6, omega=1.0, heading=90.0), ths=True))
    out, notes, n = TailFormatter().lines(sentences)
    assert n == 3 and notes == []
    assert out[0].startswith("$HNHDT,90.00,T*") and "heading 90.00" in out[0]
    assert out[1].startswith("$HNROT,-60.0,A*") and "-60.0 deg/min" in out[1]
    raw, _, _ = TailFormatter(raw=True).lines(sentences)
    assert [line.encode() + b"\r\n" for line in raw] == nmea_sentences(
        hdr(6, omega=1.0, heading=90.0), ths=True
    )


def test_raw_mode_passes_lines_through() -> None:
    lines = [format_json(hdr(7)), b'{"class":"ERROR","message":"x"}\n']
    out, _, n = TailFormatter(raw=True).lines(b"".join(lines))
    assert n == 2 and [o.encode() + b"\n" for o in out] == lines


def test_other_classes_print_as_received_in_table_mode() -> None:
    out, _, n = TailFormatter().lines(b'{"class":"VERSION","release":"0.1.0"}')
    assert n == 1 and out == ['{"class":"VERSION","release":"0.1.0"}']


# -- end to end, in a subprocess ------------------------------------------------------------


def free_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def wait_bound(proc: subprocess.Popen[bytes], port: int) -> None:
    """Wait until the subprocess holds the UDP port (our bind then fails with EADDRINUSE)."""
    deadline = time.monotonic() + GUARD_S
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.bind(("127.0.0.1", port))
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                return
            raise
        finally:
            s.close()
        time.sleep(0.02)
    pytest.fail("hdrd tail did not bind its port")


def _interruptible() -> None:
    """In the child before exec: SIGINT as a terminal gives it. A test run started in the
    background by a shell inherits SIGINT ignored, and so would ``hdrd tail``."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_tail(*extra: str, stdout: int = subprocess.PIPE) -> tuple[subprocess.Popen[bytes], int]:
    port = free_port()
    env = dict(os.environ, TZ="UTC")
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "tail", "--listen", f"127.0.0.1:{port}", *extra],
        stdout=stdout,
        stderr=subprocess.PIPE,
        env=env,
        preexec_fn=_interruptible,
    )
    wait_bound(proc, port)
    return proc, port


@pytest.fixture
def sender() -> Iterator[socket.socket]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield s
    s.close()


def test_tail_table_end_to_end(sender: socket.socket) -> None:
    proc, port = start_tail("--count", "3")
    sender.sendto(b"garbage \x00\x01", ("127.0.0.1", port))
    for i in (1, 2, 3):
        sender.sendto(format_json(hdr(i)), ("127.0.0.1", port))
    out, err = proc.communicate(timeout=GUARD_S)
    assert proc.returncode == 0, err
    lines = out.decode().splitlines()
    assert lines[0].split()[:3] == ["time", "step", "status"]
    assert [line.split()[1] for line in lines[1:]] == ["1", "2", "3"]
    assert lines[1].split()[0] == time.strftime("%H:%M:%S", time.gmtime(1700000001.0))
    assert "malformed" in err.decode() and "Traceback" not in err.decode()


def _line_within(stream: Any, what: str) -> bytes:
    """One line from a pipe, failing (not hanging) when none comes within GUARD_S."""
    import select

    ready, _, _ = select.select([stream], [], [], GUARD_S)
    assert ready, f"no {what} within {GUARD_S} s"
    return bytes(stream.readline())


def test_tail_prints_its_header_and_where_it_waits_at_once() -> None:
    """Before any data: the header on stdout, "waiting on HOST:PORT" on stderr (it used to
    print nothing until the first message, which looks like a hang)."""
    proc, port = start_tail()
    try:
        assert proc.stdout is not None and proc.stderr is not None
        header = _line_within(proc.stdout, "header").decode()
        note = _line_within(proc.stderr, "note").decode()
    finally:
        proc.terminate()
        proc.communicate(timeout=GUARD_S)
    assert header.split()[:3] == ["time", "step", "status"]
    assert note.strip() == (
        f"hdrd tail: waiting on 127.0.0.1:{port} (hdrd run --udp 127.0.0.1:{port} sends there)"
    )


def _tail_on_a_terminal(sender: socket.socket, msg: dict[str, Any], *extra: str) -> list[str]:
    """Run ``hdrd tail`` with stdout on a pty (a terminal), send ``msg`` once; its lines."""
    master, slave = os.openpty()
    try:
        proc, port = start_tail("--count", "1", *extra, stdout=slave)
        os.close(slave)
        slave = -1
        sender.sendto(format_json(msg), ("127.0.0.1", port))
        proc.wait(timeout=GUARD_S)
        out = b""
        while True:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: the terminal's other side has closed
                break
            if not chunk:
                break
            out += chunk
    finally:
        os.close(master)
        if slave >= 0:
            os.close(slave)
    assert proc.returncode == 0
    return out.decode().replace("\r\n", "\n").splitlines()


NOISY = {"time": 1700000001.123456, "omega": 0.058123456789, "yaw": -0.0025271484375000014,
         "heading": 359.99747285156, "bias": 0.24190000000000003, "gap_s": 2.0000000001}  # fmt: skip


def test_tail_raw_on_a_terminal_rounds_numbers_to_what_they_mean(sender: socket.socket) -> None:
    """On a terminal the JSON's digits beyond a value's meaning are noise; piped, they are
    kept (test_tail_raw_end_to_end: exactly as received)."""
    (line,) = _tail_on_a_terminal(sender, dict(hdr(1), **NOISY), "--raw")
    shown = json.loads(line)
    assert list(shown) == list(dict(hdr(1), **NOISY))  # every key, in order
    assert (shown["time"], shown["omega"], shown["yaw"], shown["heading"]) == (
        1700000001.12, 0.0581, 0.0, 0.0,  # -0.0 shows as 0.0, 359.997 as 0.0 (as NMEA)
    )  # fmt: skip
    assert (shown["bias"], shown["gap_s"], shown["status"]) == (0.2419, 2.0, "ok")
    assert '"yaw":0.0,' in line and not re.search(r"\.[0-9]{5}", line), line


def test_tail_table_on_a_terminal(sender: socket.socket) -> None:
    header, row = _tail_on_a_terminal(sender, dict(hdr(7), **NOISY))
    assert header.split()[:2] == ["time", "step"]
    assert row.split()[1:6] == ["7", "ok", "0.00", "0.00", "0.058"]  # no "-0.00"


def test_tail_raw_end_to_end(sender: socket.socket) -> None:
    proc, port = start_tail("--raw", "--count", "4")
    sent = [format_json(hdr(i)) for i in (1, 2)]
    for d in sent:
        sender.sendto(d, ("127.0.0.1", port))
    nmea = nmea_sentences(hdr(3))
    sender.sendto(nmea[0], ("127.0.0.1", port))
    sender.sendto(nmea[1], ("127.0.0.1", port))
    out, err = proc.communicate(timeout=GUARD_S)
    assert proc.returncode == 0, err
    lines = out.splitlines(keepends=True)
    assert lines[:2] == sent
    assert [json.loads(line) for line in lines[:2]] == [hdr(1), hdr(2)]
    assert [line.rstrip(b"\n") + b"\r\n" for line in lines[2:]] == nmea


def test_tail_count_stops_mid_datagram(sender: socket.socket) -> None:
    proc, port = start_tail("--raw", "--count", "2")
    sender.sendto(b"".join(format_json(hdr(i)) for i in (1, 2, 3)), ("127.0.0.1", port))
    out, _ = proc.communicate(timeout=GUARD_S)
    assert proc.returncode == 0
    assert [json.loads(line)["step"] for line in out.splitlines()] == [1, 2]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_tail_signal_exits_zero(sig: int, sender: socket.socket) -> None:
    proc, port = start_tail()
    sender.sendto(format_json(hdr(1)), ("127.0.0.1", port))
    assert proc.stdout is not None
    proc.stdout.readline()  # header: it is running its loop
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=GUARD_S)
    assert proc.returncode == 0, err
    assert b"Traceback" not in err


def test_tail_into_head_exits_zero_without_traceback(sender: socket.socket) -> None:
    proc, port = start_tail("--raw")
    assert proc.stdout is not None and proc.stderr is not None
    sender.sendto(format_json(hdr(1)), ("127.0.0.1", port))
    assert json.loads(proc.stdout.readline())["step"] == 1
    proc.stdout.close()  # the reader went away, like `| head -1`
    deadline = time.monotonic() + GUARD_S
    step = 2
    while proc.poll() is None and time.monotonic() < deadline:
        sender.sendto(format_json(hdr(step)), ("127.0.0.1", port))
        step += 1
        time.sleep(0.01)
    rc = proc.wait(timeout=GUARD_S)
    err = proc.stderr.read()
    proc.stderr.close()
    assert rc == 0, err
    assert b"Traceback" not in err and b"Exception ignored" not in err


def test_tail_bad_listen_address() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "hdrd", "tail", "--listen", "nonsense"],
        check=False,
        capture_output=True,
        timeout=GUARD_S,
    )
    assert r.returncode == 2 and b"--listen" in r.stderr and b"Traceback" not in r.stderr


def test_tail_port_in_use() -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    try:
        r = subprocess.run(
            [sys.executable, "-m", "hdrd", "tail", "--listen", f"127.0.0.1:{s.getsockname()[1]}"],
            check=False,
            capture_output=True,
            timeout=GUARD_S,
        )
    finally:
        s.close()
    assert r.returncode == 1 and b"cannot listen" in r.stderr and b"Traceback" not in r.stderr


def test_row_never_prints_heading_360():
    from hdrd.io.net.datagrams import TailFormatter

    row = TailFormatter.row({"class": "HDR", "step": 1, "status": "ok", "heading": 359.996})
    assert "360.00" not in row and "0.00" in row


@pytest.mark.parametrize(
    "key, value",
    [("yaw", 1e300), ("yaw", -1e300), ("omega", 1e300), ("bias", -1e30), ("I", 5e20),
     ("step", 10**300), ("samples", -(10**400)), ("bad_frames", 10**20)],
    ids=lambda v: v if isinstance(v, str) else f"{len(str(int(abs(v))))}digits",
)  # fmt: skip
def test_a_huge_number_fits_its_column(key: str, value: float) -> None:
    """A yaw of 1e300 used to print as 301 digits, the rest of the row pushed off the line."""
    f = TailFormatter()
    out, _, n = f.lines(format_json(dict(hdr(1), **{key: value})))
    header, row = out
    assert n == 1 and len(row) <= len(header) + 1, row
    cells = row.split()
    col = {"bad_frames": "bad"}.get(key, key)
    shown = cells[header.split().index(col)]
    assert "e+" in shown, shown
    if key == "yaw":
        assert shown == ("1e+300" if value > 0 else "-1e+300")


@given(st.floats(allow_nan=False, allow_infinity=False), st.integers(-(10**500), 10**500))
def test_any_number_fits_every_column(x: float, i: int) -> None:
    """Each cell within its column, or (a column too narrow for any exponent form, W's one
    character) within the 7 characters of ``-1e+300``."""
    from hdrd.io.net.datagrams import _COLUMNS

    msg = dict(hdr(1), yaw=x, omega=x, I=x, bias=x, heading=x, step=i, r=i, samples=i, W=i)
    header, row = TailFormatter().lines(format_json(msg))[0]
    cells = row.split()
    assert len(cells) == len(_COLUMNS)
    assert all(len(c) <= max(w, 7) for c, (_, _, w, _) in zip(cells, _COLUMNS)), row


# -- hostile datagrams: nothing kills tail, nothing reaches the terminal raw ----------------

HUGE_INT = "9" * 5000  # beyond Python's 4,300-digit int-from-string limit
ESC_SEQUENCES = ["\x1b[2J", "\x1b]0;owned\x07", "\x07", "\u009b31m", "\x1b[31m", "\r", "\u202e"]


def _terminal_safe(lines: list[str]) -> bool:
    return all(line.isprintable() for line in lines)


def test_a_huge_integer_is_a_note_not_a_crash() -> None:
    f = TailFormatter()
    for data in (
        b'{"class":"HDR","step":' + HUGE_INT.encode() + b"}",
        b'{"class":"X","n":-' + HUGE_INT.encode() + b"}",
        b"[" * 100_000,
    ):
        out, notes, n = f.lines(data)
        assert (out, n) == ([], 0) and len(notes) == 1 and _terminal_safe(notes)
    # numbers that do load but fit no column print as "?" or in full, never a traceback
    out, notes, n = f.lines(
        format_json(hdr(1) | {"step": 10**400, "heading": 10**400, "time": -(10**400)})
    )
    assert n == 1 and notes == [] and "?" in out[1]


@pytest.mark.parametrize("seq", ESC_SEQUENCES)
@pytest.mark.parametrize("raw", [False, True])
def test_control_sequences_in_any_field_are_escaped(seq: str, raw: bool) -> None:
    f = TailFormatter(raw=raw)
    datagrams = [
        format_json(hdr(1, status=f"ok{seq}", mode=f"aided{seq}")),
        format_json({"class": f"X{seq}", "note": seq}),
        json.dumps({"class": "HDR", "status": seq}, ensure_ascii=False).encode(),
        # NMEA: in a field (valid checksum), and in the checksum field
        f"$HNHDT,1{seq}2.00,T*".encode() + nmea_checksum_of(f"HNHDT,1{seq}2.00,T") + b"\r\n",
        f"$HNHDT,12.00,T*{seq}\r\n".encode(),
        f"{{garbage{seq}".encode(),
    ]
    for d in datagrams:
        out, notes, _ = f.lines(d, sender="127.0.0.1:1")
        assert _terminal_safe(out) and _terminal_safe(notes), (out, notes)


def nmea_checksum_of(body: str) -> bytes:
    """The XOR checksum over the UTF-8 bytes of *body* (what a sender would compute)."""
    x = 0
    for b in body.encode():
        x ^= b
    return f"{x:02X}".encode()


def test_raw_json_stays_the_same_json_when_escaped() -> None:
    """--raw prints JSON as received; made printable, it must still parse to the same value."""
    f = TailFormatter(raw=True)
    for text in (
        '{"class":"HDR",\t"status":"ok\\u001b[2J"}',
        '{"class":"HDR",\r"note":"\u009b31m \u202e x"}',
    ):
        (line,), _, _ = f.lines(text.encode())
        assert line.isprintable() and json.loads(line) == json.loads(text)


@given(st.binary(max_size=300))
def test_any_datagram_gives_printable_lines(data: bytes) -> None:
    for raw in (False, True):
        out, notes, _ = TailFormatter(raw=raw).lines(data, sender="127.0.0.1:1")
        assert _terminal_safe(out) and _terminal_safe(notes)


@given(
    st.dictionaries(
        st.sampled_from(["class", "step", "status", "mode", "heading", "time", "W", "omega"]),
        st.none()
        | st.booleans()
        | st.text()
        | st.floats()
        | st.integers(min_value=-(10**4000), max_value=10**4000)
        | st.lists(st.integers(), max_size=3),
    )
)
def test_any_json_object_gives_printable_lines(obj: dict[str, Any]) -> None:
    obj.setdefault("class", "HDR")
    data = json.dumps(obj, ensure_ascii=False).encode("utf-8", "surrogatepass")
    out, notes, _ = TailFormatter().lines(data)
    assert _terminal_safe(out) and _terminal_safe(notes)


def test_tail_survives_hostile_datagrams_end_to_end(sender: socket.socket) -> None:
    proc, port = start_tail("--count", "2")
    sender.sendto(b'{"class":"HDR","step":' + HUGE_INT.encode() + b"}", ("127.0.0.1", port))
    sender.sendto(format_json(hdr(1, status="ok\x1b[2J\x07")), ("127.0.0.1", port))
    sender.sendto(format_json(hdr(2)), ("127.0.0.1", port))
    out, err = proc.communicate(timeout=GUARD_S)
    assert proc.returncode == 0, err
    assert b"Traceback" not in err and b"\x1b" not in out + err and b"\x07" not in out + err
    lines = out.decode().splitlines()
    assert [line.split()[1] for line in lines[1:]] == ["1", "2"]
    assert "ok\\u001b[2J\\u0007" in lines[1]
    assert "a number too long" in err.decode()


@pytest.mark.slow
def test_the_readmes_run_and_tail_commands_work(tmp_path: Any) -> None:
    """README.md, "Two commands": ``hdrd run --simulate --speedup 20 --udp 127.0.0.1:10110``
    in one terminal and ``hdrd tail`` in another. Run as written, on a free port in place of
    10110 (which is tail's default: the substitution changes nothing else)."""
    from pathlib import Path

    from hdrd.io.net.datagrams import DEFAULT_TAIL_LISTEN

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    run_cmd = "hdrd run --simulate --speedup 20 --udp 127.0.0.1:10110"
    assert f"\n{run_cmd}\nhdrd tail\n" in readme
    assert run_cmd.endswith(DEFAULT_TAIL_LISTEN)
    tail, port = start_tail("--count", "5")
    env = dict(os.environ, STATE_DIRECTORY=str(tmp_path))
    for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC"):
        env.pop(k, None)
    argv = run_cmd.split()[1:-1] + [f"127.0.0.1:{port}"]
    run = subprocess.Popen(
        [sys.executable, "-m", "hdrd", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        env=env,
    )  # fmt: skip
    try:
        out, err = tail.communicate(timeout=GUARD_S)
    finally:
        run.terminate()
        run_out, _ = run.communicate(timeout=GUARD_S)
    assert tail.returncode == 0, err
    header, *rows = out.decode().splitlines()
    assert header.split()[:3] == ["time", "step", "status"] and len(rows) == 5
    assert rows[0].split()[2] == "calibrating" and rows[-1].split()[2] in ("ok", "turning")
    assert run.returncode == 0 and run_out == b""  # --udp given: nothing on stdout
