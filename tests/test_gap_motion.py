"""hdrd gap on drives whose gyro bias while moving is not its bias at rest (``motion_offset``,
docs/model-gap.md, sections 2 and 7): named, fitted and closing the gap where the log has a
speed, stops and driving with a known true rate; not named where the bias is the same; not a
candidate where the log cannot tell moving from standing.

The drives come from the simulator itself (hdrd.sim.drive) with the starting model, plus a
motion offset of 0.09 deg/s for the drive that has one. Over drive seeds 1-8 of these 8-minute
city drives the fitted offset was 0.083-0.098 deg/s, the gap fell to 0.11-0.40 of its start,
and without the offset nothing was named: the tolerances below are about twice that."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hdrd.analysis.gap import GapError, prepare, run_gap, summary
from hdrd.analysis.gap.candidates import not_identifiable
from hdrd.cli import main as cli_main
from hdrd.io.files.drivelog import DriveLog, write_drive
from hdrd.sim import DEFAULT_START_MODEL, simulate_drive
from hdrd.sim.effects import MotionOffset
from hdrd.sim.gyro import load_model

OFFSET_DPS = 0.09


def city(model_offset_dps: float) -> DriveLog:
    """Eight minutes of city driving at 5 Hz after a 20 s standstill (a fifth of it standing),
    its true yaw rate the truth, through the starting model (+ a motion offset if not 0)."""
    model = DEFAULT_START_MODEL
    if model_offset_dps:
        model = model.with_effect(MotionOffset(offset_dps=model_offset_dps))
    log = simulate_drive("city", 8.0, 1, hz=5.0, model=model, lead_in_s=20.0)
    return replace(log, heading_truth=None, name="city")


@pytest.mark.slow
def test_a_bias_while_moving_is_named_fitted_and_closes_the_gap(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Through the command, from a CSV drive log with its speed column: the summary, the
    report and the fitted model file name motion_offset with its value."""
    csv, report, fitted = tmp_path / "city.csv", tmp_path / "r.json", tmp_path / "fitted.yaml"
    write_drive(csv, city(OFFSET_DPS))
    rc = cli_main(["gap", str(csv), "--report", str(report), "--out", str(fitted)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "step 1: motion_offset (offset_dps=" in out, out
    assert "residual correlates with moving (against standing)" in out, out
    rep = json.loads(report.read_text())
    assert [s["effect"] for s in rep["steps"]] == ["motion_offset"], out
    assert rep["steps"][0]["params"]["offset_dps"] == pytest.approx(OFFSET_DPS, abs=0.015)
    assert rep["steps"][0]["ambiguous_with"] == []
    assert rep["steps"][0]["diagnostics"]["correlation"]["moving"] > 0.3
    assert rep["final_model"] == ["static_bias", "motion_offset", "white_noise"]
    assert rep["gap_final"] < 0.5 * rep["gap_initial"], out
    assert "motion_offset" not in rep["not_identifiable"]
    model = load_model(fitted)  # what `hdrd simulate --model` reads
    mo = model.get("motion_offset")
    assert isinstance(mo, MotionOffset)
    assert mo.offset_dps == pytest.approx(OFFSET_DPS, abs=0.015) and mo.moving_mps == 0.5


@pytest.mark.slow
def test_the_offset_s_sign_is_read() -> None:
    res = run_gap(city(-OFFSET_DPS))
    assert [s.effect for s in res.steps] == ["motion_offset"], summary(res)
    assert res.steps[0].params["offset_dps"] == pytest.approx(-OFFSET_DPS, abs=0.015)


def test_a_drive_without_it_names_nothing() -> None:
    res = run_gap(city(0.0))
    assert res.steps == (), summary(res)
    row = next(r for r in res.remaining if r["effect"] == "motion_offset")
    assert not row["significant"]
    assert "motion_offset" not in res.not_identifiable


def test_not_a_candidate_without_speed_stops_or_driving() -> None:
    log = city(OFFSET_DPS)
    why = not_identifiable(prepare(replace(log, speed=None)), DEFAULT_START_MODEL)
    assert why["motion_offset"] == "no speed column: moving and standing cannot be told apart"
    # A GPS course is the only truth: unknown at the stops, yet a stop is truth (the speed
    # says the car stands), so the bias at rest is seen (tests/test_gap_stops.py).
    gps = simulate_drive("city", 8.0, 1, hz=5.0, model=DEFAULT_START_MODEL, lead_in_s=20.0)
    course = replace(gps, omega_truth=None)
    assert "motion_offset" not in not_identifiable(prepare(course), DEFAULT_START_MODEL)
    # Standing only (a standstill log with a speed of zero): nothing is driven.
    n = 3000
    rest = DriveLog(
        t=np.arange(n) / 5.0,
        omega=np.random.default_rng(0).normal(0.5, 0.1, n),
        omega_truth=np.zeros(n),
        speed=np.zeros(n),
    )
    why = not_identifiable(prepare(rest), DEFAULT_START_MODEL)
    assert " and 0 moving " in why["motion_offset"]
    # A starting model with the effect needs the speed it reads.
    with pytest.raises(GapError, match="motion_offset, which needs the log's speed"):
        run_gap(replace(log, speed=None), DEFAULT_START_MODEL.with_effect(MotionOffset(0.1)))
