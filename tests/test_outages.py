"""GNSS outages offline (hdrd/analysis/outages.py, `hdrd evaluate --outages`): the outages'
placement, the fixes a log gives, and each method through the daemon's aiding path.

Rates in deg/s, + = CCW; headings compass deg; times s since the log's first sample.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hdrd.analysis.outages import (
    FROZEN,
    OutageSpec,
    drive_fixes,
    format_outages,
    outage_windows,
    run_outages,
)
from hdrd.analysis.prepare import EvaluationError, prepare_drive
from hdrd.io.files.drivelog import DriveLog, write_drive

LEAD_S = 30.0


def drive(
    minutes: float = 32.0,
    bias: float = 0.3,
    step_at_s: float | None = None,
    step_dps: float = 0.0,
    hz: float = 10.0,
    seed: int = 1,
    gps_offset_deg: float | None = None,
) -> DriveLog:
    """A car standing LEAD_S s, then driving at 15 m/s with a 90 deg turn every 3 minutes; a
    gyro with noise 0.02 deg/s and a bias of ``bias`` that steps by ``step_dps`` at
    ``step_at_s``; the true course at 1 Hz while moving (and, with ``gps_offset_deg``, a GPS
    course that many degrees clockwise of it)."""
    rng = np.random.default_rng(seed)
    n = int((LEAD_S + minutes * 60.0) * hz)
    t = np.arange(n) / hz
    moving = t >= LEAD_S
    phase = (t - LEAD_S) % 180.0
    w_true = np.where(moving & (phase >= 60.0) & (phase < 69.0), 10.0, 0.0)  # 90 deg left
    heading = (40.0 - np.cumsum(w_true) / hz) % 360.0
    b = np.full(n, bias)
    if step_at_s is not None:
        b = b + np.where(t >= step_at_s, step_dps, 0.0)
    omega = w_true + b + rng.normal(0.0, 0.02, n)
    fix = moving & (np.round(t * hz) % int(hz) == 0)
    truth = np.where(fix, heading, np.nan)
    speed = np.where(moving, 15.0, 0.0)
    log = DriveLog(
        t=t, omega=omega, heading_truth=truth, speed=speed, name="d", meta={"lead_in_s": "30"}
    )
    if gps_offset_deg is not None:
        gps = np.where(fix, (heading + gps_offset_deg) % 360.0, np.nan)
        log = DriveLog(
            **{**log.__dict__, "gps_course": gps, "gps_speed": np.where(fix, 15.0, np.nan)}
        )
    return log


def test_a_spec_is_a_duration_every_period() -> None:
    assert OutageSpec.parse("120s/10min") == OutageSpec(120.0, 600.0)
    assert OutageSpec.parse("90/600") == OutageSpec(90.0, 600.0)
    assert OutageSpec.parse(" 2min / 1h ") == OutageSpec(120.0, 3600.0)
    assert OutageSpec.parse("0.5min/90s") == OutageSpec(30.0, 90.0)
    for bad in ("", "120s", "abc/10min", "120s/10days", "-1/10", "10min/2min", "0s/1min"):
        with pytest.raises(ValueError, match="outages"):
            OutageSpec.parse(bad)


def test_an_outage_shorter_than_a_step_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    # 0.000001s/0.000002s made billions of outages: 2.8 GB, then a MemoryError.
    with pytest.raises(ValueError, match=r"0\.5 s is shorter than a step \(1 s, hdr\.T\)"):
        OutageSpec.parse("0.5s/10s")
    assert OutageSpec.parse("0.5s/10s", step_s=0.5) == OutageSpec(0.5, 10.0)
    from hdrd.cli import main

    assert main(["evaluate", "any.csv", "--outages", "0.000001s/0.000002s"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "shorter than a step" in err and "--outages" in err


def test_outages_end_each_period_and_only_whole_ones_count() -> None:
    spec = OutageSpec(120.0, 600.0)
    assert outage_windows(spec, 30.0, 30.0 + 1800.0) == [
        (510.0, 630.0),
        (1110.0, 1230.0),
        (1710.0, 1830.0),
    ]
    assert outage_windows(spec, 30.0, 30.0 + 1799.0)[-1] == (1110.0, 1230.0)
    assert outage_windows(spec, 0.0, 599.0) == []


def test_a_phase_starts_the_grid_of_outages_later() -> None:
    # Benchmarks judge on several phases of the grid: the same drive, other instants.
    spec = OutageSpec(120.0, 600.0)
    assert outage_windows(spec, 30.0, 1830.0, phase_s=150.0) == [(660.0, 780.0), (1260.0, 1380.0)]
    assert outage_windows(spec, 30.0, 1830.0, phase_s=0.0) == outage_windows(spec, 30.0, 1830.0)
    assert outage_windows(spec, 30.0, 779.0, phase_s=150.0) == []
    log = drive()
    prep = prepare_drive(log)
    r = run_outages(prep, log, spec, (FROZEN,), phase_s=450.0)
    assert r.windows == ((960.0, 1080.0), (1560.0, 1680.0))
    assert r.scored == 2 and np.max(np.abs(r.errors[FROZEN])) < 1.0


def test_the_fixes_are_the_gps_columns_else_the_truth() -> None:
    log = drive(minutes=2.0)
    t, fixes = drive_fixes(log)
    with_course = [f for f in fixes if f.track_deg is not None]
    assert len(with_course) == 120  # 1 Hz while moving
    assert with_course[0].track_deg == pytest.approx(40.0) and with_course[0].speed_mps == 15.0
    assert all(f.mode == 3 and f.epd is None for f in fixes)
    # at the lead-in's standstill, where a course means nothing, the speed once a second
    bare = [(tt, f) for tt, f in zip(t.tolist(), fixes) if f.track_deg is None]
    assert len(bare) == 30 and all(f.speed_mps == 0.0 for _, f in bare)
    assert [tt for tt, _ in bare] == sorted({math.floor(tt) for tt, _ in bare})
    assert np.all(np.diff(t) >= 0.0)
    gps = drive(minutes=2.0, gps_offset_deg=10.0)
    _, fixes = drive_fixes(gps)
    assert [f for f in fixes if f.track_deg is not None][0].track_deg == pytest.approx(50.0)
    with pytest.raises(EvaluationError, match="no gps_course or heading_truth"):
        drive_fixes(DriveLog(t=log.t, omega=log.omega, name="bare"))


def test_a_bias_that_moves_in_an_outage_is_what_the_frozen_bias_carries_to_its_end() -> None:
    # The bias is right at the start (the lead-in measures it) and the aiding keeps the
    # heading on the course; 20 s into the second outage it steps by 0.05 deg/s: frozen at
    # the outage's start, the heading is off by 0.05 x 100 s = 5 deg (CCW: the compass
    # heading reads low) at its end, and right at the ends of the others.
    spec = OutageSpec(120.0, 600.0)
    quiet = drive()
    prep = prepare_drive(quiet)
    r = run_outages(prep, quiet, spec, (FROZEN,))
    assert len(r.windows) == 3 and r.scored == 3
    assert np.max(np.abs(r.errors[FROZEN])) < 1.0
    a, _ = r.windows[1]
    moved = drive(step_at_s=a + 20.0, step_dps=0.05)
    r2 = run_outages(prepare_drive(moved), moved, spec, (FROZEN, "hdr", "hdr+"))
    assert r2.errors[FROZEN][0] == pytest.approx(r.errors[FROZEN][0], abs=0.2)
    assert r2.errors[FROZEN][1] == pytest.approx(-5.0, abs=1.0)
    assert set(r2.errors) == {FROZEN, "hdr", "hdr+"} and r2.aided_steps[FROZEN] > 1000
    assert r2.mean_abs(FROZEN) == pytest.approx(np.mean(np.abs(r2.errors[FROZEN])))
    text = format_outages([r2])
    assert "frozen bias" in text and "3/3" in text


def test_the_heading_follows_the_gps_course_not_the_truth() -> None:
    # A receiver whose course reads 10 deg clockwise of the truth: the aligned heading is
    # the receiver's, so every outage ends about 10 deg off the truth.
    log = drive(gps_offset_deg=10.0)
    r = run_outages(prepare_drive(log), log, OutageSpec(120.0, 600.0), (FROZEN,))
    assert np.all(np.abs(r.errors[FROZEN] - 10.0) < 1.5)


def test_a_drive_without_an_outage_says_so() -> None:
    log = drive(minutes=5.0)
    with pytest.raises(EvaluationError, match="hold no outage"):
        run_outages(prepare_drive(log), log, OutageSpec(120.0, 600.0))


@pytest.mark.slow
def test_evaluate_outages_as_a_user_runs_it(tmp_path: Path) -> None:
    path = tmp_path / "d.csv"
    write_drive(path, drive())
    short = tmp_path / "short.csv"
    write_drive(short, drive(minutes=6.0))
    out = tmp_path / "out.json"
    cmd = [sys.executable, "-m", "hdrd", "evaluate", str(path), str(short), "--method", "hdr+"]
    p = subprocess.run(
        cmd + ["--outages", "120s/10min", "--json", str(out)], capture_output=True, text=True
    )
    assert p.returncode == 0, p.stderr
    assert "GNSS outages of 120 s at the end of every 600 s" in p.stdout
    assert "short: no outages scored" in p.stderr  # a warning, the drive still scored
    doc = json.loads(out.read_text())["outages"]
    assert doc["duration_s"] == 120.0 and doc["period_s"] == 600.0
    (d,) = doc["drives"]
    assert d["name"] == "d" and len(d["windows"]) == 3
    assert set(d) >= {"errors_none", "errors_hdr", "errors_hdr+", "mean_abs_hdr+"}
    assert doc["mean"]["outages"] == 3 and math.isfinite(doc["mean"]["mean_abs_none"])
    bad = subprocess.run(cmd + ["--outages", "10min/2min"], capture_output=True, text=True)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert "shorter than the period" in bad.stderr


def test_hdr_plus_owns_the_bias_the_courses_teach_it() -> None:
    """HDR+ through the aiding stage: the calibration misses the bias by 0.04 deg/s (the
    lead-in is measured 0.04 low); the courses teach HDR+'s own estimate (not eps0, which
    the baselines' windows move), so every outage ends within a degree, where paper HDR's
    binary controller and the baseline's windows do no better."""
    log = drive(minutes=32.0, bias=0.3, step_at_s=LEAD_S, step_dps=0.04, seed=2)
    prep = prepare_drive(log)
    r = run_outages(prep, log, OutageSpec(120.0, 600.0), (FROZEN, "hdr+"))
    assert r.scored == 3
    assert np.max(np.abs(r.errors["hdr+"])) < 1.0
    assert r.mean_abs("hdr+") <= r.mean_abs(FROZEN) + 0.2
