"""Evaluation against ground truth (Table II) on small synthetic drives, and `hdrd evaluate`."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hdrd.analysis import evaluate as ev
from hdrd.analysis.evaluate import (
    EvaluationError,
    StepInputs,
    evaluate_drive,
    prepare_drive,
    summarize,
    to_json,
)
from hdrd.cli import main as cli_main
from hdrd.core import methods
from hdrd.core.angles import wrap180
from hdrd.core.hdr import HdrParams, run_batch
from hdrd.core.methods import MethodSetup
from hdrd.io.files.drivelog import DriveLog, read_drive, write_drive


def make_drive(
    minutes: float = 6.0,
    drift_dps: float = 0.0,
    *,
    bias0_dps: float = 0.8,
    noise_dps: float = 0.02,
    turns: Sequence[tuple[float, float, float]] = (),
    sway_dps: float = 0.0,
    hz: float = 10.0,
    calib_s: float = 30.0,
    heading0: float = 80.0,
    seed: int = 0,
    name: str = "synthetic",
) -> DriveLog:
    """A drive log: standstill for calib_s, then driving.

    The gyro reads true rate + bias0 + noise, and bias0 + drift_dps once the calibration
    window is over (a warmed-up gyro: the residual drift HDR must remove). turns: (start s,
    duration s, rate deg/s CCW). sway_dps: amplitude of a slow weave (period ~40 s). Truth
    heading: 1 Hz fixes (rows on whole seconds) while driving, empty elsewhere; omega_truth the
    true rate.
    """
    rng = np.random.default_rng(seed)
    n = round(minutes * 60 * hz)
    t = np.arange(n) / hz
    w = np.zeros(n)
    for start, dur, rate in turns:
        w[(t >= start) & (t < start + dur)] += rate
    w += sway_dps * np.sin(2 * np.pi * t / 40.0) * (t >= calib_s)
    omega = w + bias0_dps + np.where(t >= calib_s, drift_dps, 0.0) + rng.normal(0, noise_dps, n)
    yaw_true = np.cumsum(w) / hz  # rotation up to and including each sample
    truth = np.mod(heading0 - yaw_true, 360.0)
    whole = np.abs(t - np.round(t)) < 1e-6
    truth = np.where((t >= calib_s) & whole, truth, np.nan)
    # the exact truth of a simulation: with its true rate, aligned at its first value
    return DriveLog(t=t + 1000.0, omega=omega, heading_truth=truth, omega_truth=w, name=name)


CITY_TURNS = [(60, 9, 10.0), (120, 9, -10.0), (200, 18, 10.0), (260, 9, -10.0)]


def test_straight_drive_with_constant_drift_hdr_beats_no_hdr() -> None:
    log = make_drive(drift_dps=0.1)
    r = evaluate_drive(log)
    assert r.methods == ("none", "hdr")
    # Uncorrected, a residual 0.1 deg/s grows to 33 deg in 5.5 min: Eψ about 16 deg.
    assert 12.0 < r.e_psi["none"] < 18.0
    assert r.e_psi["hdr"] < r.e_psi["none"] / 5
    assert r.improvement > 5
    assert r.ne_psi["hdr"] == pytest.approx(r.e_psi["hdr"] / r.duration_min)


def test_drift_with_turns_hdr_still_helps() -> None:
    r = evaluate_drive(make_drive(drift_dps=-0.08, turns=CITY_TURNS, sway_dps=0.3))
    assert r.e_psi["hdr"] < r.e_psi["none"] / 3


def test_zero_drift_both_near_zero() -> None:
    r = evaluate_drive(make_drive(drift_dps=0.0, turns=CITY_TURNS))
    assert r.e_psi["none"] < 0.5
    assert r.e_psi["hdr"] < 1.5


def test_uncorrected_error_matches_hand_computation() -> None:
    # No noise, bias given exactly, a 0.05 deg/s residual: the error at step end j is
    # 0.05 * (t_j - t_k) deg, t_k the first step end with truth (t = 30 s). The last step
    # end (240 s) is after the last fix (239 s): not compared.
    log = make_drive(minutes=4.0, drift_dps=0.05, noise_dps=0.0)
    r = evaluate_drive(log, bias=0.8)
    t_ends = np.arange(30, 240, dtype=float)
    expected = np.mean(0.05 * (t_ends - 30.0))
    assert expected == pytest.approx(5.225)
    assert r.e_psi["none"] == pytest.approx(expected, rel=1e-9)
    assert r.n_compared == 210
    assert r.duration_min == 4.0  # the bias was given: the whole log is the drive
    assert r.bias_source == "given"


def test_calibrated_bias_is_the_mean_of_the_first_seconds() -> None:
    log = make_drive(drift_dps=0.1, noise_dps=0.05, seed=4)
    prep = prepare_drive(log, calibrate_seconds=20.0)
    assert prep.steps.bias_dps == pytest.approx(float(np.mean(log.omega[:200])), rel=1e-12)
    assert prep.bias_source == "first 20 s"
    # u is the block mean minus that bias (Eqs. 2, 11); the drive starts after 20 s.
    assert prep.start_s == 20.0 and prep.duration_min == pytest.approx(5 + 2 / 3)
    assert prep.steps.u[0] == pytest.approx(np.mean(log.omega[200:210]) - prep.steps.bias_dps)
    assert prep.steps.t_end[0] == 21.0


def test_hdr_column_is_run_batch() -> None:
    log = make_drive(drift_dps=0.1, turns=CITY_TURNS)
    p = HdrParams(i_c=0.03)
    prep = prepare_drive(log)
    r = ev.evaluate_prepared(prep, setup=MethodSetup(hdr=p))
    yaw = run_batch(prep.steps.u, p).yaw
    assert r.heading["hdr"][prep.k] == prep.truth[prep.k]
    assert r.heading["hdr"] == pytest.approx(prep.truth[prep.k] - (yaw - yaw[prep.k]))


def test_motion_at_the_start_the_bias_comes_from_the_standstill_found() -> None:
    # No lead-in in the metadata, no speed: the first window that passes the standstill test
    # on the gyro (the 6 s before the turn), as the daemon started there would measure it.
    log = make_drive(turns=[(6, 10, 15.0)])
    r = evaluate_drive(log)
    assert r.bias_source == "gyro standstill 6 s at 0 s"
    assert r.bias_dps == pytest.approx(float(np.mean(log.omega[:60])), rel=1e-12)
    # With the bias given the whole log is the drive.
    assert evaluate_drive(log, bias=0.8).n_steps == 360


def test_calibrate_seconds_retries_as_the_daemon_does() -> None:
    # The first 30 s hold a turn: the daemon's start-up window rejects them and measures the
    # next 30 s (here a straight drive: a gyro alone cannot tell it from a stop).
    log = make_drive(turns=[(6, 10, 15.0)])
    prep = prepare_drive(log, calibrate_seconds=30.0)
    assert prep.calibration_attempts == 2
    assert prep.start_s == 60.0
    assert prep.bias_source == "30 s to 60 s (1 rejected, first 30 s)"
    assert prep.steps.bias_dps == pytest.approx(float(np.mean(log.omega[300:600])), rel=1e-12)


# A slalom from the first second: a 3 s turn every 4 s, alternating left and right.
SLALOM = [(float(s), 3.0, 8.0 * (-1) ** k) for k, s in enumerate(range(0, 360, 4))]


def test_motion_in_every_window_is_reported() -> None:
    weaving = make_drive(minutes=3.0, calib_s=0.0, turns=SLALOM)
    with pytest.raises(EvaluationError, match="showed motion in all 6 attempts.*--bias"):
        prepare_drive(weaving, calibrate_seconds=30.0)
    with pytest.raises(EvaluationError, match="no standstill .* from the gyro.*--bias"):
        prepare_drive(weaving)


def test_calibration_window_longer_than_the_drive() -> None:
    with pytest.raises(EvaluationError, match="log ends before the 90 s start-up window"):
        prepare_drive(make_drive(minutes=1.0, calib_s=20.0), calibrate_seconds=90.0)
    with pytest.raises(EvaluationError, match="nothing left to evaluate"):
        prepare_drive(make_drive(minutes=1.0, calib_s=20.0), calibrate_seconds=59.5)


def test_no_truth_is_an_error() -> None:
    log = make_drive()
    no_truth = DriveLog(t=log.t, omega=log.omega, name="blind")
    with pytest.raises(EvaluationError, match="blind: no truth heading"):
        evaluate_drive(no_truth)
    empty = DriveLog(t=log.t, omega=log.omega, heading_truth=np.full(len(log), np.nan), name="e")
    with pytest.raises(EvaluationError, match="no truth heading"):
        evaluate_drive(empty)


def test_truth_outage_is_not_compared() -> None:
    log = make_drive(drift_dps=0.1)
    full = evaluate_drive(log)
    assert log.heading_truth is not None
    h = log.heading_truth.copy()
    rel = log.t - log.t[0]
    h[(rel > 100) & (rel < 160)] = np.nan  # a 60 s GPS outage
    cut = evaluate_drive(DriveLog(t=log.t, omega=log.omega, heading_truth=h, name="outage"))
    assert cut.n_compared == full.n_compared - 59
    assert np.isnan(cut.truth[120 - 30])


def test_gap_in_gyro_samples_is_no_step_and_the_yaw_holds() -> None:
    log = make_drive(drift_dps=0.1)
    rel = log.t - log.t[0]
    keep = ~((rel >= 100.0) & (rel < 103.0))
    assert log.heading_truth is not None
    holed = DriveLog(
        t=log.t[keep], omega=log.omega[keep], heading_truth=log.heading_truth[keep], name="holed"
    )
    prep = prepare_drive(holed)
    assert prep.missing_steps == 3
    assert prep.start_s == 30.0  # the drive starts after the calibration window
    assert prep.duration_min == 5.5  # Td: the drive's time span, gaps included
    # Steps 100-103 s had no samples: no step, not a repeated rate; the next one ends at 104 s.
    i = int(np.flatnonzero(prep.steps.t_end == 100.0)[0])
    assert prep.steps.t_end[i + 1] == 104.0
    assert prep.steps.u.shape[0] == 330 - 3 and prep.steps.n_samples.min() == 10
    r = ev.evaluate_prepared(prep)
    assert r.n_steps == 327


def test_summary_is_the_papers_bottom_line() -> None:
    rs = [
        evaluate_drive(make_drive(drift_dps=d, turns=CITY_TURNS, seed=i, name=f"d{i}"))
        for i, d in enumerate((0.1, -0.05, 0.2))
    ]
    s = summarize(rs)
    imps = [r.e_psi["none"] / r.e_psi["hdr"] for r in rs]
    assert s.improvement == pytest.approx(np.mean(imps))
    assert s.improvement_std == pytest.approx(np.std(imps, ddof=1))  # the paper's sigma
    assert s.ne_psi["hdr"] == pytest.approx(np.mean([r.ne_psi["hdr"] for r in rs]))
    # Td: the drive after the 30 s calibration window.
    assert s.total_min == pytest.approx(3 * 5.5)
    assert [r.duration_min for r in rs] == [5.5, 5.5, 5.5]


def test_json_shape_is_exactly_the_issues() -> None:
    rs = [
        evaluate_drive(make_drive(drift_dps=0.1, name="a")),
        evaluate_drive(make_drive(drift_dps=0.05, name="b")),
    ]
    doc = to_json(rs)
    keys = [
        "name",
        "duration_min",
        "E_psi_raw",
        "E_psi_hdr",
        "NE_psi_raw",
        "NE_psi_hdr",
        "improvement",
    ]
    assert list(doc) == ["drives", "mean"]
    assert [list(d) for d in doc["drives"]] == [keys, keys]
    assert list(doc["mean"]) == keys[1:]
    assert doc["drives"][1]["name"] == "b"
    assert doc["mean"]["E_psi_hdr"] == pytest.approx((rs[0].e_psi["hdr"] + rs[1].e_psi["hdr"]) / 2)
    json.dumps(doc, allow_nan=False)  # strict JSON


def test_a_registered_method_gets_its_own_keys(monkeypatch: pytest.MonkeyPatch) -> None:
    # A new drift reducer is one entry in hdrd.core.methods.REGISTRY; evaluate and the JSON pick
    # it up.
    class Perfect(type(methods.REGISTRY["hdr"])):  # type: ignore[misc]
        name = "perfect"
        summary = "knows the drift"

        def batch(self, steps: StepInputs, params: HdrParams) -> np.ndarray:
            return np.cumsum((steps.u - 0.1) * params.T)

    monkeypatch.setitem(methods.REGISTRY, "perfect", Perfect())
    r = evaluate_drive(make_drive(drift_dps=0.1, noise_dps=0.0), methods=("hdr", "perfect"))
    assert r.methods == ("none", "hdr", "perfect")
    assert r.e_psi["perfect"] < 1e-6 < r.e_psi["hdr"]
    doc = to_json([r])
    assert {
        "E_psi_raw",
        "E_psi_hdr",
        "E_psi_perfect",
        "NE_psi_perfect",
        "improvement_hdr",
        "improvement_perfect",
    } <= set(doc["drives"][0])
    with pytest.raises(EvaluationError, match="not available"):
        evaluate_drive(make_drive(), methods=("kalman",))


def test_method_none_alone_also_spells_its_keys_e_psi_none() -> None:
    r = evaluate_drive(make_drive(drift_dps=0.1), methods=("none",))
    d = to_json([r])["drives"][0]
    assert d["E_psi_none"] == d["E_psi_raw"] == pytest.approx(r.e_psi["none"])
    assert d["NE_psi_none"] == d["NE_psi_raw"]
    assert "E_psi_none" not in to_json([evaluate_drive(make_drive(drift_dps=0.1))])["drives"][0]


# -- the command line --------------------------------------------------------------------


def _write(tmp_path: Path, log: DriveLog, name: str) -> str:
    p = tmp_path / f"{name}.csv"
    write_drive(p, log)
    return str(p)


def test_cli_table_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = _write(tmp_path, make_drive(drift_dps=0.1, turns=CITY_TURNS), "city")
    b = _write(tmp_path, make_drive(drift_dps=-0.06, seed=2), "rural")
    out = tmp_path / "res.json"
    assert cli_main(["evaluate", a, b, "--json", str(out)]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert lines[0].split()[:3] == ["drive", "min", "bias"]
    assert any(line.startswith("city ") for line in lines)
    assert any(line.startswith("rural ") for line in lines)
    assert any(line.startswith("mean (2)") and "σ" in line for line in lines)
    doc = json.loads(out.read_text())
    assert [d["name"] for d in doc["drives"]] == ["city", "rural"]
    assert doc["drives"][0]["E_psi_hdr"] < doc["drives"][0]["E_psi_raw"]
    assert f"{doc['drives'][0]['E_psi_raw']:.2f}" in text


def test_cli_bias_and_calibrate_seconds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = _write(tmp_path, make_drive(drift_dps=0.1), "a")
    j1, j2 = tmp_path / "1.json", tmp_path / "2.json"
    assert cli_main(["evaluate", a, "--bias", "0.9", "--json", str(j1)]) == 0
    assert cli_main(["evaluate", a, "--calibrate-seconds", "10", "--json", str(j2)]) == 0
    capsys.readouterr()
    # Bias 0.9 = the true bias after warm-up: nothing left to correct.
    assert json.loads(j1.read_text())["drives"][0]["E_psi_raw"] < 1.0
    assert json.loads(j2.read_text())["drives"][0]["E_psi_raw"] > 10.0


def test_cli_method_none(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = _write(tmp_path, make_drive(drift_dps=0.1), "a")
    j = tmp_path / "n.json"
    assert cli_main(["evaluate", a, "--method", "none", "--json", str(j)]) == 0
    capsys.readouterr()
    d = json.loads(j.read_text())["drives"][0]
    assert list(d) == [
        "name",
        "duration_min",
        "E_psi_raw",
        "NE_psi_raw",
        "E_psi_none",
        "NE_psi_none",
        "improvement",
    ]
    assert d["improvement"] == 1.0


def test_cli_config_parameters_are_used(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = _write(tmp_path, make_drive(drift_dps=0.1, turns=CITY_TURNS), "a")
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("hdr:\n  method: hdr\n  i_c: 0.001\n")
    j0, j1 = tmp_path / "0.json", tmp_path / "1.json"
    assert cli_main(["evaluate", a, "--json", str(j0)]) == 0
    assert cli_main(["evaluate", a, "--config", str(cfg), "--json", str(j1)]) == 0
    capsys.readouterr()
    e0 = json.loads(j0.read_text())["drives"][0]["E_psi_hdr"]
    e1 = json.loads(j1.read_text())["drives"][0]["E_psi_hdr"]
    assert e1 > 2 * e0  # a 40x smaller increment cannot follow 0.1 deg/s of drift in time
    bad = tmp_path / "bad.yaml"
    bad.write_text("hdr:\n  i_c: -1\n")
    assert cli_main(["evaluate", a, "--config", str(bad)]) == 78
    assert "hdr.i_c" in capsys.readouterr().err


def _one_line_error(capsys: pytest.CaptureFixture[str], *parts: str) -> None:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("hdrd evaluate: error: ")
    for p in parts:
        assert p in err


def test_cli_bad_inputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(["evaluate", str(tmp_path / "nope.csv")]) == 1
    _one_line_error(capsys, "nope.csv", "no such file")
    bad = tmp_path / "bad.csv"
    bad.write_text("t,omega\n0.0,0.1\n0.1,zebra\n")
    assert cli_main(["evaluate", str(bad)]) == 1
    _one_line_error(capsys, "bad.csv:3", "zebra")
    log = make_drive()
    blind = _write(tmp_path, DriveLog(t=log.t, omega=log.omega, name="blind"), "blind")
    assert cli_main(["evaluate", blind]) == 1
    _one_line_error(capsys, "no truth heading")
    moving = _write(tmp_path, make_drive(calib_s=0.0, turns=SLALOM), "moving")
    assert cli_main(["evaluate", moving]) == 1
    _one_line_error(capsys, "moving", "no standstill", "--bias")
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli_main(["evaluate", str(empty)]) == 1
    _one_line_error(capsys, "empty", "directory without drive logs")


def test_cli_plot_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("matplotlib")
    a = _write(tmp_path, make_drive(drift_dps=0.1, turns=CITY_TURNS), "a")
    b = _write(tmp_path, make_drive(drift_dps=0.05, seed=3), "b")
    png = tmp_path / "fig.png"
    assert cli_main(["evaluate", a, b, "--plot", str(png)]) == 0
    capsys.readouterr()
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_cli_plot_without_matplotlib(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    a = _write(tmp_path, make_drive(drift_dps=0.1), "a")
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)
    js = tmp_path / "table.json"
    assert cli_main(["evaluate", a, "--plot", str(tmp_path / "x.png"), "--json", str(js)]) == 1
    out, err = capsys.readouterr()
    assert "matplotlib" in err and "pip install 'hdrd[plot]'" in err
    assert not (tmp_path / "x.png").exists()
    # Said before the work: no table evaluated and printed, no JSON written.
    assert out == "" and not js.exists()


def test_nonfinite_improvement_is_null_in_json() -> None:
    r = evaluate_drive(make_drive(drift_dps=0.1))
    perfect = dataclasses.replace(r, e_psi={"none": r.e_psi["none"], "hdr": 0.0})
    assert perfect.improvement == math.inf
    doc = to_json([perfect])
    assert doc["drives"][0]["improvement"] is None
    assert doc["mean"]["improvement"] is None
    json.dumps(doc, allow_nan=False)


def test_evaluate_applies_the_config_standstill_keys_to_hdr_plus(tmp_path: Path) -> None:
    # A downtown drive with stops: `standstill.enabled: false` in the config must change
    # what `hdrd evaluate --method hdr+` reports, exactly as HDR+ without stops would.
    from hdrd.config import method_setup
    from hdrd.configload import parse_config
    from hdrd.sim.benchmark import TRAIN_DRIVES, generate

    path = tmp_path / "city1.csv"
    write_drive(path, generate(next(s for s in TRAIN_DRIVES if s.name == "city1")))
    prep = ev.prepare_drive(read_drive(path))
    off = method_setup(parse_config({"standstill": {"enabled": False}}))
    assert not ev.method_settings(
        prep, "hdr+", setup=replace(off, hdr=HdrParams())
    ).standstill.enabled
    got_off = ev.evaluate_prepared(prep, methods=("hdr+",), setup=off).e_psi["hdr+"]
    got_on = ev.evaluate_prepared(prep, methods=("hdr+",)).e_psi["hdr+"]
    yaw = ev.method_yaw(prep, "hdr+", setup=replace(off, hdr=HdrParams()))
    assert got_off == pytest.approx(float(ev.e_psi(yaw, prep.truth, prep.k)), abs=0)
    assert got_off != got_on
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("standstill:\n  enabled: false\n")
    out = tmp_path / "out.json"
    args = [str(path), "--method", "hdr+", "--config", str(cfg), "--json", str(out)]
    assert cli_main(["evaluate", *args]) == 0
    assert json.loads(out.read_text())["drives"][0]["E_psi_hdr+"] == pytest.approx(got_off)


# -- per-drive calibration --------------------------------------------------------------------


def phone_drive(seed: int = 7) -> DriveLog:
    """A phone-like 1 Hz drive (bias 0.01 deg/s, noise 0.01 deg/s): 5 s standing, a left turn
    whose first second averages 0.37 deg/s (then 4, 9, 12, 12, 12, 9, 4 deg/s), a 20 s stop at
    a light, then 5 minutes of driving with right turns from 60 s on, the bias drifting by 0.05
    deg/s from then. Truth: the true heading at every second while moving."""
    rng = np.random.default_rng(seed)
    n = 5 + 8 + 20 + 300
    true = np.zeros(n)
    true[5:13] = [0.36, 4.0, 9.0, 12.0, 12.0, 12.0, 9.0, 4.0]
    for start in range(60, n - 20, 50):
        true[start : start + 9] = -10.0
    t = np.arange(n, dtype=np.float64)
    omega = true + 0.01 + 0.05 * (t >= 60) + 0.01 * rng.standard_normal(n)
    omega[:6] = 0.01 + 0.01 * rng.standard_normal(6)
    omega[5] += 0.36
    heading = np.mod(90.0 - np.cumsum(true), 360.0)
    moving = (t >= 5) & ((t < 13) | (t >= 33))
    return DriveLog(t=t, omega=omega, heading_truth=np.where(moving, heading, np.nan), name="phone")


def test_a_turns_first_second_at_1_hz_is_not_taken_for_the_start_up_standstill() -> None:
    log = phone_drive()
    # The first 6 s hold the turn's first second: rejected, as are the windows in the turn;
    # the daemon's start-up window measures at the stop that follows (18-24 s).
    prep = prepare_drive(log, calibrate_seconds=6.0)
    assert prep.calibration_attempts == 4
    assert prep.start_s == 24.0
    assert prep.steps.bias_dps == pytest.approx(float(np.mean(log.omega[18:24])), rel=1e-12)
    assert abs(prep.steps.bias_dps - 0.01) < 0.015  # the first 6 s measured 0.07 deg/s
    # Per drive, without --calibrate-seconds: 5 s before the turn are too few samples to
    # judge at 1 Hz; the stop after it is found from the gyro (with the straight road after it,
    # which a gyro cannot tell from a stop), and the drive starts after that window.
    prep = prepare_drive(log)
    assert prep.bias_source == "gyro standstill 30 s at 13 s"
    assert prep.start_s == 43.0
    assert prep.steps.bias_dps == pytest.approx(float(np.mean(log.omega[13:43])), rel=1e-12)
    assert abs(prep.steps.bias_dps - 0.01) < 0.01


def test_lead_in_and_speed_standstill_set_the_window(tmp_path: Path) -> None:
    log = make_drive(drift_dps=0.1, calib_s=20.0)
    lead = dataclasses.replace(log, meta={"lead_in_s": "20"})
    prep = prepare_drive(lead)
    assert prep.bias_source == "lead-in 20 s" and prep.start_s == 20.0
    # --calibrate-seconds overrides the lead-in; --bias overrides both.
    assert prepare_drive(lead, calibrate_seconds=10.0).bias_source == "first 10 s"
    assert prepare_drive(lead, bias=0.8, calibrate_seconds=10.0).bias_source == "given"
    # A log that starts moving and stops from 60 to 75 s: the daemon started then.
    rel = log.t - log.t[0]
    speed = np.where((rel >= 60.0) & (rel < 75.0), 0.0, 12.0)
    stopped = dataclasses.replace(log, speed=speed, name="stop")
    prep = prepare_drive(stopped)
    assert prep.bias_source == "speed standstill 15 s at 60 s"
    assert prep.start_s == 75.0 and prep.steps.t_end[0] == 76.0
    assert prep.duration_min == pytest.approx((360.0 - 75.0) / 60.0)
    never = dataclasses.replace(log, speed=np.full(len(log), 12.0))
    with pytest.raises(EvaluationError, match="no standstill .* from the speed"):
        prepare_drive(never)


def test_a_lead_in_that_shows_motion_gives_way_to_a_later_stop() -> None:
    """A phone handled while the car stood (its lead-in turns at 20 deg/s for 5 s): the lead-in
    cannot give the bias; the first later stop by the speed whose gyro is still does, and the
    drive is scored from there. A window the user gave is not second-guessed."""
    # driving: a short turn every 10 s (no start-up window the daemon would retry passes)
    weave = [(a, 3.0, 10.0 if a % 20 else -10.0) for a in range(25, 360, 10) if a != 65]
    log = make_drive(drift_dps=0.1, calib_s=20.0, turns=[(5.0, 5.0, 20.0), *weave])
    rel = log.t - log.t[0]
    speed = np.where((rel < 20.0) | ((rel >= 60.0) & (rel < 75.0)), 0.0, 12.0)
    handled = dataclasses.replace(log, speed=speed, meta={"lead_in_s": "20"}, name="handled")
    prep = prepare_drive(handled)
    assert prep.bias_source == "speed standstill 15 s at 60 s; the lead-in 20 s showed motion"
    assert prep.start_s == 75.0
    # the bias measured where the gyro was still: bias0 and the drift that started at 20 s
    assert prep.steps.bias_dps == pytest.approx(float(np.mean(handled.omega[600:750])), rel=1e-12)
    assert abs(prep.steps.bias_dps - 0.9) < 0.01
    with pytest.raises(EvaluationError, match="showed motion"):
        prepare_drive(handled, calibrate_seconds=20.0)
    # a stop whose gyro moves too (a car turning on the spot) is no better: the lead-in's error
    rel_turn = [(5.0, 5.0, 20.0), *weave, (62.0, 5.0, 20.0)]
    turning = dataclasses.replace(
        make_drive(drift_dps=0.1, calib_s=20.0, turns=rel_turn),
        speed=speed,
        meta={"lead_in_s": "20"},
    )
    with pytest.raises(EvaluationError, match="lead-in 20 s.*showed motion"):
        prepare_drive(turning)


def test_cli_directory_of_mixed_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sub = tmp_path / "phone"
    sub.mkdir()
    write_drive(tmp_path / "city.csv", make_drive(drift_dps=0.1, turns=CITY_TURNS))
    write_drive(sub / "p1.csv", phone_drive())
    write_drive(sub / "moving.csv", make_drive(calib_s=0.0, turns=SLALOM))
    (sub / "notes.txt").write_text("not a drive log")
    out = tmp_path / "r.json"
    assert cli_main(["evaluate", str(tmp_path), "--json", str(out)]) == 0
    cap = capsys.readouterr()
    assert [d["name"] for d in json.loads(out.read_text())["drives"]] == ["city", "phone/p1"]
    rows = {line.split()[0]: line for line in cap.out.splitlines()}
    assert rows["city"].endswith("gyro standstill 30 s at 0 s")
    assert rows["phone/p1"].endswith("gyro standstill 30 s at 13 s")
    assert cap.err.count("\n") == 1 and "skipped phone/moving: " in cap.err
    # A file and a directory together, with the bias given for all (p1, in both, scored once).
    assert cli_main(["evaluate", str(sub / "p1.csv"), str(sub), "--bias", "0.01"]) == 0
    cap = capsys.readouterr()
    assert cap.out.count(" given") == 2
    assert cap.err == "hdrd evaluate: warning: p1: named more than once; taken once\n"


def _course_truth_drive(first_fix_error_deg: float) -> DriveLog:
    """A simulated drive whose truth is made a course over ground (no omega_truth), its first
    fixes at walking pace in a turn first_fix_error_deg off (as a real course there can be)."""
    from hdrd.sim import simulate_legs
    from hdrd.sim.benchmark import VARIANTS

    log = simulate_legs([(VARIANTS["city"], 0.5), (VARIANTS["suburbs"], 0.5)], 12.0, 3)
    assert log.heading_truth is not None and log.speed is not None
    truth = log.heading_truth.copy()
    first = np.flatnonzero(np.isfinite(truth) & (log.t > 31.0))[:3]  # after the lead-in
    truth[first] = (truth[first] + first_fix_error_deg) % 360.0
    speed = log.speed.copy()
    speed[: first[-1] + 1] = np.minimum(speed[: first[-1] + 1], 2.0)
    return dataclasses.replace(log, heading_truth=truth, speed=speed, omega_truth=None)


def test_a_misaligned_first_course_no_longer_decides_the_score() -> None:
    """A course over ground is aligned over the first straight stretch at speed
    (prepare.alignment), so a first fix 25 deg off changes Eψ by little; an exact truth (a
    simulation's) keeps the first-sample alignment, where the 25 deg move Eψ by several deg."""
    clean, bad = _course_truth_drive(0.0), _course_truth_drive(25.0)
    r_clean, r_bad = evaluate_drive(clean), evaluate_drive(bad)
    assert abs(r_bad.e_psi["none"] - r_clean.e_psi["none"]) < 1.0
    prep = ev.prepare_drive(bad)
    assert prep.align_n == 10 and prep.k > 0
    truth_first = dataclasses.replace(bad, omega_truth=np.zeros(len(bad)))  # "exact" truth
    assert ev.prepare_drive(truth_first).align_n == 1
    assert abs(evaluate_drive(truth_first).e_psi["none"] - r_clean.e_psi["none"]) > 5.0


def test_calibrate_seconds_never_takes_a_sample_past_it() -> None:
    """29.4 s with T = 1 s is 29 whole steps: the car starting to move at 29.5 s is not in the
    bias; a window shorter than a step is refused, not stretched to one."""
    log = make_drive(
        minutes=3.0, calib_s=29.5, drift_dps=0.0, noise_dps=0.0, turns=[(29.5, 5, 20.0)]
    )
    prep = prepare_drive(log, calibrate_seconds=29.4)
    assert prep.bias_source == "first 29 s" and prep.start_s == 29.0
    assert prep.steps.bias_dps == pytest.approx(0.8, abs=1e-12)  # no turn sample in it
    with pytest.raises(EvaluationError, match="at least one step"):
        prepare_drive(log, calibrate_seconds=0.5)


def test_trace_writes_each_drives_headings_as_the_scores_see_them(tmp_path: Path) -> None:
    """--trace DIR: DIR/<drive>.csv, one row per step: t, heading_truth, speed and the compass
    heading of none, hdr and hdr+ (whatever --method), from which Eψ is computed again, and
    HDR+'s heading sd."""
    from hdrd.sim import simulate_legs
    from hdrd.sim.benchmark import VARIANTS

    log = simulate_legs([(VARIANTS["city"], 1.0)], 8.0, 4, name="city")
    write_drive(tmp_path / "city.csv", log)
    out = tmp_path / "doc.json"
    rc = cli_main(["evaluate", str(tmp_path / "city.csv"), "--trace", str(tmp_path / "tr"),
                   "--json", str(out)])  # fmt: skip
    assert rc == 0
    lines = (tmp_path / "tr" / "city.csv").read_text().splitlines()
    cols = lines[0].split(",")
    assert cols == ["t", "heading_truth", "speed", "heading_none", "heading_hdr", "heading_hdr+",
                    "heading_sd_hdr+"]  # fmt: skip
    rows = np.array([[float(v) if v else np.nan for v in ln.split(",")] for ln in lines[1:]])
    prep = prepare_drive(log)
    assert rows.shape == (prep.steps.u.shape[0], 7)
    assert np.array_equal(rows[:, 0], np.round(prep.steps.t_end, 3))
    assert np.all((rows[:, 3:6] >= 0.0) & (rows[:, 3:6] < 360.0))
    assert np.all(rows[:, 6] > 0.0) and rows[-1, 6] > 5 * rows[0, 6]  # it grows without GPS
    d = json.loads(out.read_text())["drives"][0]
    for k, m in ((3, "raw"), (4, "hdr")):  # Eψ again from the published headings
        ok = np.isfinite(rows[:, 1])
        err = np.abs(wrap180(rows[ok, k] - rows[ok, 1]))
        assert float(np.mean(err)) == pytest.approx(d[f"E_psi_{m}"], abs=1e-3)
    # a folder that is a file is refused before the work
    (tmp_path / "file").write_text("")
    assert (
        cli_main(["evaluate", str(tmp_path / "city.csv"), "--trace", str(tmp_path / "file")]) == 1
    )
