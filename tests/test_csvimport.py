"""hdrd.io.files.csvimport: a user's own CSV made into a drive log, each mapped column converted to
hdrd's units and signs (t s from the first row, omega deg/s + = CCW, heading compass degrees
in [0, 360), speed m/s), every error naming the source's line and column and the option that
named it. In process, on real files.

``hdrd import`` as a user runs it (a subprocess; a drive imported, then scored as the drive
it came from; the sign and unit warnings): test_import.py.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hdrd.io.files.csvimport import (
    HEADING_UNITS,
    OMEGA_UNITS,
    SPEED_UNITS,
    TIME_UNITS,
    Mapping,
    import_csv,
)
from hdrd.io.files.drivecolumns import DriveLogError, ReadLimits

NO_GAP_LIMIT = ReadLimits(max_gap_s=math.inf)


def source(tmp_path: Path, text: str, name: str = "logger.csv") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_units_and_signs_become_hdrds(tmp_path: Path) -> None:
    p = source(
        tmp_path,
        "timestamp_ms,gyro_z,yaw,vel_kmh,board_c,unused\n"
        "1000,0.1,0.0,36,20.5,x\n"
        "1100,-0.2,1.5707963267948966,72,21,y\n"
        "1200,0,3.141592653589793,0,21.5,z\n",
    )
    m = Mapping(
        t="timestamp_ms", omega="gyro_z", heading="yaw", speed="vel_kmh", temp="board_c",
        time_unit="ms", omega_unit="rad/s", omega_sign="cw", heading_unit="rad",
        heading_ref="enu", speed_unit="km/h",
    )  # fmt: skip
    log = import_csv(p, m)
    assert log.t.tolist() == pytest.approx([0.0, 0.1, 0.2])
    # rad/s clockwise-positive (z down) -> deg/s counter-clockwise-positive
    assert log.omega.tolist() == pytest.approx([-0.1 * 180 / math.pi, 0.2 * 180 / math.pi, 0.0])
    # ENU yaw (CCW from east) -> compass (CW from north): east 90, north 0, west 270
    assert log.heading_truth is not None
    assert log.heading_truth.tolist() == pytest.approx([90.0, 0.0, 270.0], abs=1e-9)
    assert log.speed is not None and log.speed.tolist() == pytest.approx([10.0, 20.0, 0.0])
    assert log.temp_c is not None and log.temp_c.tolist() == [20.5, 21.0, 21.5]
    assert log.name == "logger" and log.meta["source"] == "hdrd import logger.csv"
    assert log.meta["imported"] == (
        "t=timestamp_ms (ms, from the first row); omega=gyro_z (rad/s, cw); "
        "heading_truth=yaw (rad, enu); speed=vel_kmh (km/h); temp_c=board_c (deg C)"
    )


def test_the_unit_tables() -> None:
    assert TIME_UNITS == {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
    assert OMEGA_UNITS["rad/s"] == pytest.approx(57.29577951308232)
    assert HEADING_UNITS["rad"] == OMEGA_UNITS["rad/s"] and HEADING_UNITS["deg"] == 1.0
    assert SPEED_UNITS["km/h"] * 3.6 == pytest.approx(1.0)
    assert SPEED_UNITS["mph"] == 0.44704


def test_a_heading_is_wrapped_into_0_to_360(tmp_path: Path) -> None:
    p = source(tmp_path, "t,w,h\n0,0,-90\n1,0,-355\n2,0,-1e-15\n3,0,360\n")
    log = import_csv(p, Mapping(t="t", omega="w", heading="h"))
    assert log.heading_truth is not None
    assert log.heading_truth.tolist() == pytest.approx([270.0, 5.0, 0.0, 0.0])
    assert (log.heading_truth < 360.0).all()


@pytest.mark.parametrize(
    ("h", "unit", "said"),
    [
        ("999", "deg", "999 deg is outside +/-360 deg; a heading is a direction (not unwrapped, "
         "not a placeholder such as 999)"),  # was taken as 279
        ("-1e300", "deg", "-1e+300 deg is outside"),  # was taken as 0
        ("725", "rad", "725 rad is outside +/-360 deg"),
        ("180", "rad", "180 rad is outside +/-360 deg; a heading is a direction (not unwrapped, "
         "not a placeholder such as 999); is the column in degrees? --heading-unit deg"),
    ],
)  # fmt: skip
def test_a_heading_beyond_a_turn_is_refused_not_wrapped(
    tmp_path: Path, h: str, unit: str, said: str
) -> None:
    p = source(tmp_path, f"t,w,h\n0,0,1\n1,0,{h}\n", "x.csv")
    with pytest.raises(DriveLogError) as e:
        import_csv(p, Mapping(t="t", omega="w", heading="h", heading_unit=unit))
    assert str(e.value).startswith(f"{p}:3: column 'h' (--heading): {said}"), str(e.value)


def test_a_negative_speed_is_refused(tmp_path: Path) -> None:
    p = source(tmp_path, "t,w,v\n0,0,3\n1,0,-2.5\n", "x.csv")
    with pytest.raises(DriveLogError, match=r"x\.csv:3: column 'v' \(--speed\): -2.5 m/s is "
                       "negative; a speed is a magnitude"):  # fmt: skip
        import_csv(p, Mapping(t="t", omega="w", speed="v"))


def test_integer_times_keep_every_digit(tmp_path: Path) -> None:
    # Nanoseconds since 1970: 1.7e18 has more digits than a float64 holds; subtracted as
    # integers before scaling, 0.1 ms steps stay exact.
    t0 = 1_700_000_000_123_456_789
    rows = "".join(f"{t0 + k * 100_000},0.5\n" for k in range(5))
    log = import_csv(source(tmp_path, "ns,w\n" + rows), Mapping(t="ns", omega="w", time_unit="ns"))
    assert log.t.tolist() == pytest.approx([0.0, 1e-4, 2e-4, 3e-4, 4e-4], abs=1e-12)
    decimal = import_csv(
        source(tmp_path, "s,w\n100.5,0\n100.75,0\n", "d.csv"), Mapping(t="s", omega="w")
    )
    assert decimal.t.tolist() == [0.0, 0.25]


def test_integer_times_that_wrap_are_not_laundered(tmp_path: Path) -> None:
    # An int64 counter that wrapped: its difference wraps too (to +1, "0.001 s"); the time
    # went back, and is refused as such.
    p = source(tmp_path, "ms,w\n9223372036854775807,0\n-9223372036854775808,0\n", "x.csv")
    with pytest.raises(DriveLogError, match=r"x\.csv:3: column 'ms' \(--t\) is not strictly incr"):
        import_csv(p, Mapping(t="ms", omega="w", time_unit="ms"))
    far = source(tmp_path, "ms,w\n-9223372036854775807,0\n9223372036854775806,0\n", "y.csv")
    apart = import_csv(far, Mapping(t="ms", omega="w", time_unit="ms"), limits=NO_GAP_LIMIT)
    assert apart.t[1] == pytest.approx(1.8446744073709552e16)  # beyond an int64: right sign


def test_the_header_may_follow_comments_a_bom_and_blank_lines(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    p.write_bytes("\ufeff# exported by a logger\n\n t ; w \n0;1\n\n1;2\n".encode())
    log = import_csv(p, Mapping(t="t", omega="w"), delimiter=";")
    assert log.t.tolist() == [0.0, 1.0] and log.omega.tolist() == [1.0, 2.0]


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("", "x.csv: empty file, expected a header line naming the columns"),
        ("# only a comment\n", "x.csv: empty file"),
        ("t,w\n", "x.csv: no data rows"),
        ("a,b\n0,1\n", "x.csv: no column 't' (--t); the header has 'a', 'b'"),
        ("t,w,w\n0,1,2\n", "x.csv: column 'w' (--omega) appears twice"),
        ("t,w\n0,1\n1,2,3\n", "x.csv:3: 3 fields, the header has 2"),
        ("t,w\n0,1\n1,fast\n", "x.csv:3: column 'w' (--omega): 'fast' is not a number"),
        ("t,w\n0,1\n0.00001,1\n", "x.csv:3: column 't' (--t): 1e-05 s, 1e-05 s after the row"),
        ("t,w\n0,1\n1,2000\n", "x.csv:3: column 'w' (--omega): 2000 deg/s is beyond"),
    ],
)
def test_errors_name_the_line_the_column_and_the_option(
    tmp_path: Path, text: str, error: str
) -> None:
    with pytest.raises(DriveLogError) as e:
        import_csv(source(tmp_path, text, "x.csv"), Mapping(t="t", omega="w"))
    said = str(e.value).removeprefix(f"{tmp_path}/")
    assert said.startswith(error), said
    assert "\n" not in said


def test_the_row_limit_is_kept(tmp_path: Path) -> None:
    p = source(tmp_path, "t,w\n" + "".join(f"{k},0\n" for k in range(11)), "x.csv")
    assert len(import_csv(p, Mapping(t="t", omega="w"), limits=ReadLimits(max_rows=11)).t) == 11
    with pytest.raises(DriveLogError, match=r"x\.csv:12: more than the 10 rows .*--max-rows"):
        import_csv(p, Mapping(t="t", omega="w"), limits=ReadLimits(max_rows=10))


def test_only_the_mapped_columns_are_read(tmp_path: Path) -> None:
    # A column nobody mapped may hold anything; a mapped optional one left empty is unknown.
    p = source(tmp_path, "t,w,notes,v\n0,1,hello,\n1,1,,3.5\n")
    log = import_csv(p, Mapping(t="t", omega="w", speed="v"))
    assert log.speed is not None and np.isnan(log.speed[0]) and log.speed[1] == 3.5
    assert log.heading_truth is None and log.temp_c is None


def test_a_missing_file_is_an_os_error(tmp_path: Path) -> None:
    with pytest.raises(OSError):
        import_csv(tmp_path / "missing.csv", Mapping(t="t", omega="w"))


@pytest.mark.parametrize(
    ("row", "extra", "error"),
    [
        ("1000,abc,", {}, "src.csv:4: column 'gz' (--omega): 'abc' is not a number"),
        ("1000,1_000,", {}, "src.csv:4: column 'gz' (--omega): '1_000' is not a number"),
        ("1000,,", {}, "src.csv:4: column 'gz' (--omega) is empty; it is required in every row"),
        (",1,", {}, "src.csv:4: column 'time' (--t) is empty; it is required in every row"),
        ("100,1,", {}, "src.csv:4: column 'time' (--t) is not strictly increasing"),
        ("1000,1,", {}, ""),
        ("1000,30,", {"omega_unit": "rad/s"},
         "src.csv:4: column 'gz' (--omega): 1718.87 deg/s is beyond the +/-1000 deg/s"),
        ("1000,1,725", {"heading_unit": "rad"},
         "src.csv:4: column 'hdg' (--heading): 725 rad is outside +/-360 deg"),
        ("1000,1,x", {}, "src.csv:4: column 'hdg' (--heading): 'x' is not a number"),
        ("1000.00001,1,", {"time_unit": "s"}, "src.csv:4: column 'time' (--t): 1000 s, 1e-05 s "
         "after the row before"),
        ("1000,1", {}, "src.csv:4: 2 fields, the header has 3"),
    ],
)  # fmt: skip
def test_each_row_error_names_its_line_and_column(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, row: str, extra: dict[str, str], error: str
) -> None:
    """The rows ``hdrd import`` refuses (its command line, test_import.py, takes a few of
    them through the process): a file named as a user names it, relative to the folder."""
    monkeypatch.chdir(tmp_path)
    unit = extra.get("time_unit", "ms")
    before = "500" if unit == "ms" else "1000"  # ms: 0.5 s before the row; s: 1000 s
    Path("src.csv").write_text(f"time,gz,hdg\n0,1,\n{before},1,1\n{row}\n")
    m = Mapping(t="time", omega="gz", heading="hdg", **{"time_unit": unit, **extra})
    if not error:
        assert len(import_csv("src.csv", m).t) == 3
        return
    with pytest.raises(DriveLogError) as e:
        import_csv("src.csv", m)
    assert str(e.value).startswith(error), str(e.value)
    assert "\n" not in str(e.value)
