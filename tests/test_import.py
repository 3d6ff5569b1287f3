"""``hdrd import``: a user's own CSV, its columns, units and signs named on the command line,
made into a drive log that ``hdrd evaluate`` scores as it scores the drive the CSV was made
from. Run as a user runs it: ``python -m hdrd import ...`` in a subprocess."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from hdrd.core.angles import wrap180
from hdrd.io.files.drivelog import DriveLog, read_drive, write_drive
from hdrd.sim.drive import simulate_drive
from tests.hdrd_process import hdrd


@pytest.fixture(scope="module")
def drive() -> DriveLog:
    return simulate_drive("city", 5.0, 4)


def _their_csv(path: Path, log: DriveLog, *, bom: bool = True, sep: str = ";") -> None:
    """The drive as a logger of its own writes it: epoch milliseconds, the rate in rad/s
    about a z axis pointing down (clockwise positive), the course, km/h, a column hdrd does
    not know, a byte-order mark."""
    assert log.heading_truth is not None and log.speed is not None and log.temp_c is not None
    t_ms = 1_700_000_000_000 + np.rint(log.t * 1000).astype(np.int64)
    lines = [sep.join(["time_ms", "gz", "course", "vel_kmh", "tempC", "note"])]
    for i in range(len(log)):
        h = log.heading_truth[i]
        lines.append(
            sep.join(
                [
                    str(t_ms[i]),
                    f"{-math.radians(log.omega[i]):.10f}",
                    "" if math.isnan(h) else f"{h:.3f}",
                    f"{log.speed[i] * 3.6:.4f}",
                    f"{log.temp_c[i]:.3f}",
                    "x",
                ]
            )
        )
    path.write_text(("\ufeff" if bom else "") + "\n".join(lines) + "\n", encoding="utf-8")


IMPORT = ("--t", "time_ms", "--time-unit", "ms", "--omega", "gz", "--omega-unit", "rad/s",
          "--omega-sign", "cw", "--heading", "course", "--speed", "vel_kmh", "--speed-unit",
          "km/h", "--temp", "tempC", "--delimiter", ";")  # fmt: skip


def _scores(cwd: Path, f: str) -> dict[str, float]:
    p = hdrd("evaluate", f, "--calibrate-seconds", "30", "--json", f + ".json", cwd=cwd)
    assert p.returncode == 0, p.stderr
    assert "warning" not in p.stderr, p.stderr
    return json.loads((cwd / (f + ".json")).read_text())["drives"][0]


@pytest.mark.slow
def test_their_csv_imported_scores_as_the_drive_it_came_from(
    drive: DriveLog, tmp_path: Path
) -> None:
    _their_csv(tmp_path / "their.csv", drive)
    # their CSV has no true rate, so the truth is scored as a course (prepare.alignment): the
    # drive it came from without its true rate scores the same way
    write_drive(tmp_path / "orig.csv", dataclasses.replace(drive, omega_truth=None))
    p = hdrd("import", "their.csv", "--out", "mine.csv", *IMPORT, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stderr == f"{len(drive)} rows, {drive.duration_s:.1f} s (t, omega, temp_c, " \
        "heading_truth, speed) -> mine.csv\n"  # fmt: skip
    mine = read_drive(tmp_path / "mine.csv")
    assert np.array_equal(mine.t, drive.t)  # epoch ms, exactly, from the first row
    assert np.max(np.abs(mine.omega - drive.omega)) < 1e-6
    assert mine.heading_truth is not None and drive.heading_truth is not None
    assert np.array_equal(np.isnan(mine.heading_truth), np.isnan(drive.heading_truth))
    assert mine.speed is not None and drive.speed is not None
    assert np.max(np.abs(mine.speed - drive.speed)) < 1e-3
    assert mine.meta["imported"].startswith("t=time_ms (ms, from the first row); omega=gz")
    a, b = _scores(tmp_path, "mine.csv"), _scores(tmp_path, "orig.csv")
    for k in ("E_psi_raw", "E_psi_hdr", "duration_min"):
        assert a[k] == pytest.approx(b[k], abs=0.01), k


def test_parquet_out_and_enu_heading_in_radians(drive: DriveLog, tmp_path: Path) -> None:
    """A yaw angle in an east-north-up frame, radians in (-pi, pi] (an unwrapped one, past a
    turn either way, is refused as a drive log refuses it); epoch ns."""
    assert drive.heading_truth is not None
    yaw = np.angle(np.exp(1j * np.radians(90.0 - drive.heading_truth)))
    t_ns = 1_700_000_000_123_456_789 + np.rint(drive.t * 1e9).astype(np.int64)
    rows = ["stamp,wz,yaw"] + [
        f"{t_ns[i]},{drive.omega[i]:.7f},{'' if math.isnan(yaw[i]) else f'{yaw[i]:.9f}'}"
        for i in range(len(drive))
    ]
    (tmp_path / "ros.csv").write_text("\n".join(rows) + "\n")
    p = hdrd("import", "ros.csv", "--out", "ros.parquet", "--t", "stamp", "--time-unit", "ns",
             "--omega", "wz", "--heading", "yaw", "--heading-unit", "rad", "--heading-ref", "enu",
             cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    from hdrd.io.files.parquetlog import read_parquet_drive

    got = read_parquet_drive(tmp_path / "ros.parquet")
    assert np.array_equal(got.t, drive.t)  # nanoseconds since 2023: every digit kept
    assert got.heading_truth is not None
    ok = np.isfinite(drive.heading_truth)
    diff = wrap180(got.heading_truth[ok] - drive.heading_truth[ok])
    assert np.max(np.abs(diff)) < 2e-3
    assert np.all((got.heading_truth[ok] >= 0) & (got.heading_truth[ok] < 360))


@pytest.mark.slow
def test_a_wrong_sign_or_unit_is_warned_with_the_option_that_fixes_it(
    drive: DriveLog, tmp_path: Path
) -> None:
    _their_csv(tmp_path / "their.csv", drive)
    no_sign = [x for x in IMPORT if x not in ("--omega-sign", "cw")]
    p = hdrd("import", "their.csv", "--out", "a.csv", *no_sign, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    warning = p.stderr.splitlines()[0]
    assert warning.startswith("hdrd import: warning: their: omega turns against heading_truth")
    assert warning.endswith("--omega-sign cw flips it")
    e = hdrd("evaluate", "a.csv", cwd=tmp_path)
    assert e.returncode == 0 and "hdrd evaluate: warning: a: omega turns against" in e.stderr
    no_unit = [x for x in IMPORT if x not in ("--omega-unit", "rad/s")]
    q = hdrd("import", "their.csv", "--out", "b.csv", *no_unit, cwd=tmp_path)
    assert q.returncode == 0, q.stderr
    assert "times as far as heading_truth" in q.stderr and "(--omega-unit)" in q.stderr
    ok = hdrd("import", "their.csv", "--out", "c.csv", *IMPORT, cwd=tmp_path)
    assert "warning" not in ok.stderr


def test_a_time_or_heading_in_another_unit_is_warned_naming_the_option(
    drive: DriveLog, tmp_path: Path
) -> None:
    # Milliseconds read as seconds (a sample every 100 s) and a heading in radians read as
    # degrees (it moves within 6.3 deg while the car turns): imported, each warned once with
    # the option that fixes it; with the options, no warning.
    assert drive.heading_truth is not None
    ms = np.rint(drive.t * 1000).astype(np.int64)
    rows = ["time,gz,hdg"] + [
        f"{ms[i]},{drive.omega[i]:.6f},{'' if math.isnan(h) else f'{math.radians(h):.6f}'}"
        for i, h in enumerate(drive.heading_truth)
    ]
    (tmp_path / "src.csv").write_text("\n".join(rows) + "\n")
    base = ("import", "src.csv", "--out", "o.csv", "--t", "time", "--omega", "gz", "--heading",
            "hdg")  # fmt: skip
    p = hdrd(*base, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    warned = [ln for ln in p.stderr.splitlines() if "warning" in ln]
    assert len(warned) == 2, p.stderr
    assert warned[0].startswith("hdrd import: warning: column 'time' (--t) gives a sample every ")
    assert warned[0].endswith("; is it in ms? --time-unit ms")
    assert "moves within 6" in warned[1] and warned[1].endswith("--heading-unit rad")
    q = hdrd(*base, "--time-unit", "ms", "--heading-unit", "rad", cwd=tmp_path)
    assert q.returncode == 0 and "warning" not in q.stderr, q.stderr


@pytest.mark.parametrize(
    ("row", "extra", "error"),
    # Every other row error, in process: tests/test_csvimport.py. Here what the command adds:
    # its prefix, exit 1, one line, nothing written; and the options reaching the import.
    [
        ("1000,abc,", (), "src.csv:4: column 'gz' (--omega): 'abc' is not a number"),
        ("1000,30,", ("--omega-unit", "rad/s"),
         "src.csv:4: column 'gz' (--omega): 1718.87 deg/s is beyond the +/-1000 deg/s"),
        ("1000.00001,1,", ("--time-unit", "s"), "src.csv:4: column 'time' (--t): 1000 s, 1e-05 s "
         "after the row before"),
        ("1000,1,180", ("--heading-unit", "rad"), "src.csv:4: column 'hdg' (--heading): 180 rad "
         "is outside +/-360 deg; a heading is a direction (not unwrapped, not a placeholder such "
         "as 999); is the column in degrees? --heading-unit deg"),
    ],
)  # fmt: skip
def test_errors_name_the_line_and_their_column(
    tmp_path: Path, row: str, extra: tuple[str, ...], error: str
) -> None:
    unit = "s" if "--time-unit" in extra else "ms"
    rest = [x for x in extra if x not in ("--time-unit", "s")]
    before = "500" if unit == "ms" else "1000"  # ms: 0.5 s before the row; s: 1000 s
    (tmp_path / "src.csv").write_text(f"time,gz,hdg\n0,1,\n{before},1,1\n{row}\n")
    p = hdrd("import", "src.csv", "--out", "o.csv", "--t", "time", "--time-unit", unit,
             "--omega", "gz", "--heading", "hdg", *rest, cwd=tmp_path)  # fmt: skip
    if not error:
        assert p.returncode == 0, p.stderr
        return
    assert p.returncode == 1, p.stderr
    assert p.stderr.startswith(f"hdrd import: error: {error}"), p.stderr
    assert p.stderr.count("\n") == 1
    assert not (tmp_path / "o.csv").exists()


def test_a_missing_column_lists_the_header(tmp_path: Path) -> None:
    (tmp_path / "s.csv").write_text("a,b\n0,1\n")
    p = hdrd("import", "s.csv", "--out", "o.csv", "--t", "a", "--omega", "gyro", cwd=tmp_path)
    assert p.returncode == 1
    assert p.stderr == "hdrd import: error: s.csv: no column 'gyro' (--omega); the header has " \
        "'a', 'b'\n"  # fmt: skip
    bad = hdrd("import", "s.csv", "--out", "o.csv", "--t", "a", "--omega", "b",
               "--delimiter", "ab", cwd=tmp_path)  # fmt: skip
    assert bad.returncode == 2 and "--delimiter" in bad.stderr
    binary = tmp_path / "b.csv"
    binary.write_bytes(b"t,w\n0,\xff\n")
    q = hdrd("import", "b.csv", "--out", "o.csv", "--t", "t", "--omega", "w", cwd=tmp_path)
    assert q.returncode == 1
    assert q.stderr == "hdrd import: error: b.csv:2: not UTF-8 text (byte 0xff at column 3); " \
        "save the CSV as UTF-8\n"  # fmt: skip


def test_a_file_name_cannot_put_a_metadata_line_in_the_log(tmp_path: Path) -> None:
    # A source named `city\n# lead_in_s: 3\n.csv`: its name is the `source` value, escaped on
    # its one line; evaluate would otherwise take the lead-in it names.
    name = "city\n# lead_in_s: 3\n.csv"
    (tmp_path / name).write_text("t,w\n0,0.1\n0.1,0.1\n0.2,0.2\n")
    p = hdrd("import", name, "--out", "d.csv", "--t", "t", "--omega", "w", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    log = read_drive(tmp_path / "d.csv")
    assert "lead_in_s" not in log.meta and log.meta["source"] == f"hdrd import {name}"
    meta_lines = [ln for ln in (tmp_path / "d.csv").read_text().splitlines() if ln[:1] == "#"]
    assert len(meta_lines) == 2  # source, imported


def test_the_command_lines_units_are_the_modules() -> None:
    from hdrd import cliargs
    from hdrd.io.files import csvimport as importcsv

    assert cliargs.TIME_UNITS == tuple(importcsv.TIME_UNITS)
    assert cliargs.OMEGA_UNITS == tuple(importcsv.OMEGA_UNITS)
    assert cliargs.HEADING_UNITS == tuple(importcsv.HEADING_UNITS)
    assert cliargs.SPEED_UNITS == tuple(importcsv.SPEED_UNITS)
