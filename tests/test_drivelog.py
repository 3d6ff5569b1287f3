"""Drive log CSV (hdrd/io/files/drivelog.py): round trip, empty cells = NaN, errors naming the line."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.io.files.drivecolumns import COLUMNS, OPTIONAL, DriveLogError
from hdrd.io.files.drivelog import DriveLog, read_drive, write_drive

DIGITS = {
    "t": 4,
    "omega": 7,
    "temp_c": 3,
    "heading_truth": 3,
    "omega_truth": 7,
    "speed": 3,
    "valid": 0,
    "gps_course": 3,
    "gps_speed": 3,
}


def same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(a, b, equal_nan=True))


def assert_same_log(a: DriveLog, b: DriveLog) -> None:
    for c in COLUMNS:
        assert same(getattr(a, c), getattr(b, c)), c
    assert a.meta == b.meta


@st.composite
def drive_logs(draw: st.DrawFn) -> DriveLog:
    """Logs whose values are exact at the precision the writer keeps (k / 10**digits)."""
    n = draw(st.integers(1, 40))
    steps = draw(st.lists(st.integers(1, 5000), min_size=n, max_size=n))
    t0 = draw(st.integers(0, 10**8))
    t = (t0 + np.cumsum(steps) - steps[0]) / 10**4
    cols: dict[str, np.ndarray] = {"t": t}
    for c in ("omega",) + tuple(o for o in OPTIONAL if draw(st.booleans())):
        d = DIGITS[c]
        if c == "valid":  # 0 or 1 in every row
            cols[c] = np.array(draw(st.lists(st.sampled_from([0.0, 1.0]), min_size=n, max_size=n)))
            continue
        bound = 360 * 10**d if c in ("heading_truth", "gps_course") else 10**9  # within +/-360
        if c == "temp_c":  # within the format's [-100, 200] deg C
            bound = 100 * 10**d
        low = 0 if c in ("speed", "gps_speed") else -bound  # a speed is a magnitude
        ks = draw(st.lists(st.integers(low, bound), min_size=n, max_size=n))
        v = np.array(ks, dtype=np.float64) / 10**d
        if c != "omega":
            holes = draw(st.lists(st.booleans(), min_size=n, max_size=n))
            v[np.array(holes, dtype=bool)] = np.nan
        cols[c] = v
    meta = draw(
        st.dictionaries(
            st.text("abcdefghij_", min_size=1, max_size=8),
            st.text("abc XYZ0123.-", min_size=1, max_size=12).map(str.strip).filter(bool),
            max_size=3,
        )
    )
    return DriveLog(meta=meta, **cols)  # type: ignore[arg-type]


@settings(deadline=None)
@given(log=drive_logs())
def test_write_read_round_trip(log: DriveLog) -> None:
    buf = io.StringIO()
    write_drive(buf, log)
    buf.seek(0)
    back = read_drive(buf)
    assert_same_log(back, log)
    assert back.columns() == log.columns()


@settings(deadline=None)
@given(meta=st.dictionaries(st.text(max_size=12), st.text(max_size=40), max_size=4))
def test_metadata_round_trips_whatever_it_holds(meta: dict[str, str]) -> None:
    # Line breaks, colons in keys, spaces at the ends, backslashes, control characters, lone
    # surrogates: each key and value on its own line, read back as it was.
    log = DriveLog(t=np.array([0.0, 0.1]), omega=np.zeros(2), meta=meta)
    buf = io.StringIO()
    write_drive(buf, log)
    text = buf.getvalue()
    assert text.count("\n") == len(meta) + 3  # a line per key, the header, two rows
    assert all(c.isprintable() for c in text.replace("\n", ""))  # nothing a terminal acts on
    buf.seek(0)
    assert read_drive(buf).meta == meta


def test_a_metadata_value_cannot_add_a_line(tmp_path: Path) -> None:
    from hdrd.io.files.drivelog import escape_meta, unescape_meta

    sneaky = "city\n# lead_in_s: 3\n.csv"
    log = DriveLog(t=np.array([0.0, 0.1]), omega=np.zeros(2), meta={"source": sneaky})
    write_drive(tmp_path / "d.csv", log)
    lines = (tmp_path / "d.csv").read_text().splitlines()
    assert lines[0] == "# source: city\\n# lead_in_s: 3\\n.csv" and lines[1] == "t,omega"
    assert read_drive(tmp_path / "d.csv").meta == {"source": sneaky}
    assert escape_meta("a:b", key=True) == "a\\x3ab" and escape_meta(" x ") == "\\x20x\\x20"
    assert unescape_meta("C:\\data\\q") == "C:\\data\\q"  # no escape: kept as written


def test_round_trip_through_a_file(tmp_path: Path) -> None:
    t = np.arange(50) / 10.0
    log = DriveLog(
        t=t,
        omega=np.sin(t).round(5),
        heading_truth=np.where(np.arange(50) % 10 == 0, np.round(t * 7 % 360, 3), np.nan),
        speed=np.full(50, 13.5),
        meta={"drive": "city", "gyro": "CRS03-04"},
    )
    p = tmp_path / "city-1.csv"
    write_drive(p, log)
    back = read_drive(p)
    assert_same_log(back, log)
    assert back.name == "city-1" and back.temp_c is None and back.omega_truth is None
    text = p.read_text().splitlines()
    assert text[:3] == ["# drive: city", "# gyro: CRS03-04", "t,omega,heading_truth,speed"]
    assert text[4] == "0.1000,0.09983,,13.500"  # an unknown heading is an empty cell


def test_empty_cells_are_nan_never_zero() -> None:
    text = "t,omega,heading_truth,temp_c\n0.0,0.1,,20\n0.1,0.2,90.5,\n0.2,0.3,nan,NaN\n"
    log = read_drive(io.StringIO(text))
    assert log.heading_truth is not None and log.temp_c is not None
    assert np.isnan(log.heading_truth[[0, 2]]).all() and log.heading_truth[1] == 90.5
    assert log.temp_c[0] == 20.0 and np.isnan(log.temp_c[1:]).all()


def test_columns_in_any_order_and_whitespace() -> None:
    log = read_drive(io.StringIO(" omega , t \n 1.5 , 0 \n2.5,1\n"))
    assert log.t.tolist() == [0.0, 1.0] and log.omega.tolist() == [1.5, 2.5]


def test_metadata_blank_lines_and_properties() -> None:
    text = "# drive: rural\n# a comment without a colon\n\nt,omega\n0,1\n\n0.1,1\n0.2,1\n0.3,1\n"
    log = read_drive(io.StringIO(text), name="r1")
    assert log.meta == {"drive": "rural"} and log.name == "r1"
    assert len(log) == 4
    assert log.duration_s == pytest.approx(0.3) and log.rate_hz == pytest.approx(10.0)
    part = log.slice(1, 3)
    assert part.t.tolist() == [0.1, 0.2] and part.meta == log.meta and len(part) == 2


# -- errors name the file and line ---------------------------------------------------------------


@pytest.mark.parametrize(
    "text, match",
    [
        ("t,omega,yaw\n0,1,2\n", r"<stream>:1: unknown column 'yaw' \(allowed: t, omega,"),
        ("# meta: x\n\nt,omega,yaw\n", r"<stream>:3: unknown column 'yaw'"),
        ("t,heading_truth\n0,1\n", r"<stream>:1: missing required column 'omega'"),
        ("omega\n1\n", r"<stream>:1: missing required column 't'"),
        ("t,omega,t\n0,1,0\n", r"<stream>:1: repeated column"),
        (
            "t,omega\n0,1\n1,2\n1,3\n",
            r"<stream>:4: column t is not strictly increasing \(1.0 after 1.0\)",
        ),
        (
            "# a: b\n\nt,omega\n0,1\n\n2,2\n1.5,3\n",
            r"<stream>:7: column t is not strictly increasing \(1.5 after 2.0\)",
        ),
        ("t,omega\n0,1\n0.1,abc\n", r"<stream>:3: column omega: 'abc' is not a number"),
        ("t,omega,speed\n0,1,2\n0.1,1,fast\n", r"<stream>:3: column speed: 'fast' is not a number"),
        ("t,omega,speed\n0,1,2\n0.1,1,-0.5\n", r"<stream>:3: column speed: -0.5 m/s is negative"),
        ("t,omega,gps_speed\n0,1,-1e-3\n", r"<stream>:2: column gps_speed: -0.001 m/s is negat"),
        ("t,omega\n0,1\n0.1,inf\n", r"<stream>:3: column omega: inf is not finite"),
        ("t,omega\n0,1\n0.1,1,2\n", r"<stream>:3: 3 fields, header has 2"),
        ("t,omega\n0,1\n0.1\n", r"<stream>:3: 1 fields, header has 2"),
        ("t,omega\n0,1\n,2\n", r"<stream>:3: column t is empty; it is required in every row"),
        ("t,omega\n0,1\n\n1,\n", r"<stream>:4: column omega is empty; it is required in every row"),
        ("", r"<stream>: empty file, expected a header line"),
        ("# only: metadata\n\n", r"<stream>: empty file"),
        ("t,omega\n", r"<stream>: no data rows"),
        ("t,omega,valid\n0,1,1\n0.1,1,2\n", r"<stream>:3: column valid: 2.0 is not 0 or 1"),
        (
            "t,omega,valid\n0,1,1\n0.1,1,\n",
            r"<stream>:3: column valid: is empty; every row needs 1",
        ),
    ],
)
def test_errors(text: str, match: str) -> None:
    with pytest.raises(DriveLogError, match=match) as ei:
        read_drive(io.StringIO(text))
    assert "\n" not in str(ei.value)


def test_error_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("t,omega\n0,1\n0.1,x\n")
    with pytest.raises(DriveLogError, match=rf"^{p}:3: column omega"):
        read_drive(p)


def test_line_numbers_count_quoted_multiline_cells() -> None:
    # A quoted cell spanning lines moves the following rows' line numbers accordingly.
    text = 't,omega\n0,1\n"1\n",2\n1,3\n'
    with pytest.raises(DriveLogError, match=r"<stream>:5: column t is not strictly increasing"):
        read_drive(io.StringIO(text))


def test_valid_column_round_trip() -> None:
    text = "t,omega,valid\n0,1,1\n0.1,2,0\n0.2,3,1\n"
    log = read_drive(io.StringIO(text))
    assert log.valid is not None and log.valid.tolist() == [1.0, 0.0, 1.0]
    buf = io.StringIO()
    write_drive(buf, log)
    assert buf.getvalue() == "t,omega,valid\n0.0000,1.00000,1\n0.1000,2.00000,0\n0.2000,3.00000,1\n"


@pytest.mark.parametrize("step", [0.00762939453125, 1.0 / 32.8])
def test_rates_keep_an_adc_step(step: float) -> None:
    """Values on an ADC step that is no round decimal (CRS03-04 on 16 bits; a +/-1000 deg/s
    MEMS) come back within 1e-5 of a step (they used to be rounded to 1e-5 deg/s); values
    with 5 decimals or fewer are written as they always were."""
    k = np.arange(-3000, 3000, 7).astype(np.float64)
    log = DriveLog(t=np.arange(k.shape[0]) / 10.0, omega=k * step, omega_truth=k * step)
    buf = io.StringIO()
    write_drive(buf, log)
    buf.seek(0)
    back = read_drive(buf)
    for col in (back.omega, back.omega_truth):
        assert col is not None
        assert np.max(np.abs(col / step - k)) < 1e-5
    buf = io.StringIO()
    write_drive(buf, DriveLog(t=np.array([0.0, 0.1]), omega=np.array([0.09983, -1.5])))
    assert buf.getvalue().splitlines()[1:] == ["0.0000,0.09983", "0.1000,-1.50000"]


@pytest.mark.parametrize(
    ("cell", "where"),
    [
        ("1_000", "1_000"),  # float() reads 1000: a digit separator, most likely a typo
        ("1_0.5", "1_0.5"),
        ("\u0661\u0662", "\u0661\u0662"),  # Arabic-Indic digits, which float() reads as 12
        ("\uff11", "\uff11"),  # a full-width 1
    ],
)
def test_a_cell_is_an_ascii_decimal_number(cell: str, where: str) -> None:
    for col in ("omega", "heading_truth"):
        text = (
            f"t,{col}\n0,1\n0.1,{cell}\n"
            if col == "omega"
            else f"t,omega,{col}\n0,1,2\n0.1,1,{cell}\n"
        )
        with pytest.raises(DriveLogError) as ei:
            read_drive(io.StringIO(text))
        msg = str(ei.value)
        assert msg.startswith(f"<stream>:3: column {col}: {where!r} is not a number"), msg
        assert msg.isprintable()


@pytest.mark.parametrize("h", [-360.0, -180.0, -0.001, 0.0, 359.999, 360.0])
def test_a_heading_within_a_turn_either_way_is_taken(h: float) -> None:
    log = read_drive(io.StringIO(f"t,omega,heading_truth\n0,1,10\n0.1,1,{h}\n"))
    assert log.heading_truth is not None and log.heading_truth[1] == h


@pytest.mark.parametrize("h", ["360.001", "-360.5", "720", "725", "999", "-721", "6.3e3"])
def test_a_heading_beyond_a_turn_is_refused_naming_row_and_column(h: str) -> None:
    """Values beyond +/-720 were once accepted silently (an unwrapped heading, a sentinel)."""
    text = f"# x: y\nt,omega,heading_truth\n0,1,10\n0.1,1,\n0.2,1,{h}\n"
    with pytest.raises(DriveLogError) as ei:
        read_drive(io.StringIO(text))
    assert str(ei.value).startswith(
        f"<stream>:5: column heading_truth: {float(h)!r} deg is outside [-360, 360]"
    )


@pytest.mark.parametrize("tc", [-100.0, -40.0, 0.0, 25.5, 85.0, 200.0])
def test_a_temperature_within_the_limits_is_taken(tc: float) -> None:
    log = read_drive(io.StringIO(f"t,omega,temp_c\n0,1,20\n0.1,1,{tc}\n0.2,1,\n"))
    assert log.temp_c is not None and log.temp_c[1] == tc and math.isnan(log.temp_c[2])


@pytest.mark.parametrize("tc", ["1e200", "-1e200", "999", "-999", "298.15", "250", "-100.5"])
def test_a_temperature_outside_the_limits_is_refused_naming_row_and_column(tc: str) -> None:
    """A temperature of 1e200 once reached hdrd gap's temperature statistics (an overflow
    warning on stderr, then an internal error for the drive)."""
    text = f"t,omega,temp_c\n0,1,20\n0.1,1,21\n0.2,1,{tc}\n"
    with pytest.raises(DriveLogError) as ei:
        read_drive(io.StringIO(text))
    msg = str(ei.value)
    assert msg.startswith(f"<stream>:4: column temp_c: {float(tc):.6g} deg C is outside"), msg
    assert msg.isprintable() and "\n" not in msg


def test_a_byte_order_mark_before_the_header_is_taken(tmp_path: Path) -> None:
    """Excel's "CSV UTF-8" starts with a byte-order mark; it was once an unknown column."""
    p = tmp_path / "excel.csv"
    p.write_bytes(b"\xef\xbb\xbft,omega\r\n0,1\r\n0.1,2\r\n")
    assert read_drive(p).omega.tolist() == [1.0, 2.0]
    q = tmp_path / "meta.csv"
    q.write_bytes(b"\xef\xbb\xbf# source: x\nt,omega\n0,1\n")
    log = read_drive(q)
    assert log.meta == {"source": "x"} and len(log) == 1
    r = tmp_path / "late.csv"  # a mark anywhere else is no mark: an unknown column
    r.write_bytes(b"t,\xef\xbb\xbfomega\n0,1\n")
    with pytest.raises(DriveLogError, match="unknown column"):
        read_drive(r)
