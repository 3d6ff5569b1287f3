"""One path from samples to heading: ``hdrd evaluate`` steps a drive log through the daemon's
own block code, stepper and methods, so ``hdrd replay`` of a capture holding the same samples
publishes the same yaw at every step, for every method (hdrd/analysis/prepare.py).

Rates in deg/s, + = CCW; headings in compass degrees; times in s.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from hdrd.analysis.evaluate import evaluate_prepared, method_yaw, prepare_drive
from hdrd.analysis.metrics import e_psi
from hdrd.config import Config, method_setup
from hdrd.configload import parse_config
from hdrd.core.calibrate import BiasRecord, given_bias
from hdrd.core.methods import MethodSetup, names
from hdrd.core.sensor import SensorModel
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.replay import replay_capture
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.wire.capture import encode_array
from hdrd.io.wire.codec import FRAME_DTYPE

SENSOR = SensorModel()
T0_US = (1 << 32) - 45_000_000  # the device clock wraps 45 s into the capture


def drive(
    hz: float,
    minutes: float = 5.0,
    *,
    lead_in_s: float = 20.0,
    bias_dps: float = 0.4,
    drift_dps: float = 0.06,
    noise_dps: float = 0.05,
    gaps: tuple[tuple[float, float], ...] = (),
    seed: int = 0,
) -> DriveLog:
    """A drive at ``hz``: standstill for lead_in_s, then straights and turns (left and right,
    10-20 deg/s) with a gyro whose bias drifts by drift_dps after the lead-in; the cabin warms
    by 3 degC. Samples inside ``gaps`` ([start, end) s) are missing. Truth: 1 Hz fixes while
    moving. No speed column (a capture has none)."""
    rng = np.random.default_rng(seed)
    n = round(minutes * 60 * hz)
    t = np.arange(n) / hz
    w = np.zeros(n)
    for start in np.arange(lead_in_s + 15.0, t[-1] - 20.0, 35.0):
        w[(t >= start) & (t < start + 9.0)] = rng.choice([-1.0, 1.0]) * rng.uniform(10.0, 20.0)
    omega = w + bias_dps + drift_dps * (t >= lead_in_s) + rng.normal(0.0, noise_dps, n)
    yaw = np.cumsum(w) / hz
    truth = np.where(
        (t >= lead_in_s) & (np.abs(t - np.round(t)) < 1e-9), np.mod(70.0 - yaw, 360.0), np.nan
    )
    temp = 18.0 + 3.0 * (1.0 - np.exp(-t / 200.0))
    keep = np.ones(n, bool)
    for a, b in gaps:
        keep &= ~((t >= a) & (t < b))
    return DriveLog(
        t=t[keep] + 500.0,
        omega=omega[keep],
        temp_c=temp[keep],
        heading_truth=truth[keep],
        name=f"{hz:g}hz",
        meta={"lead_in_s": f"{lead_in_s:g}"},
    )


def capture(log: DriveLog) -> tuple[bytes, DriveLog]:
    """The hdr-bin capture of a log's samples (the CRS03-04 model's counts, the 0.01 degC
    temperature the frame carries, a device clock that wraps), and the log as the capture
    holds it: the same samples, bit for bit, as ``hdrd replay`` decodes them."""
    t_us = np.rint((log.t - log.t[0]) * 1e6).astype(np.int64)
    counts = SENSOR.to_counts(log.omega)
    assert log.temp_c is not None
    temp_cc = np.rint(log.temp_c * 100.0).astype(np.int64)
    a = np.zeros(len(log), FRAME_DTYPE)
    a["seq"] = np.arange(len(log)) & 0xFFFF
    a["t_us"] = (T0_US + t_us) % (1 << 32)
    a["rate"] = counts
    a["ref"] = 0
    a["temp"] = temp_cc
    held = replace(
        log,
        t=t_us / 1e6,
        omega=SENSOR.to_dps_array(counts, np.zeros_like(counts)),
        temp_c=temp_cc / 100,
    )
    return encode_array(a), held


def _config(method: str, from_gyro: bool = False) -> Config:
    return parse_config({"hdr": {"method": method}, "standstill": {"from_gyro": from_gyro}})


CASES: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    # name, drive(...) arguments, how the bias is had: {"bias": b} or {"calibrate_seconds": s}
    ("10 Hz with gaps", {"hz": 10.0, "gaps": ((100.0, 103.0), (150.2, 150.7))}, {"cal": 20.0}),
    ("1 Hz", {"hz": 1.0, "noise_dps": 0.02}, {"bias": 0.4}),
    ("1 Hz calibrated", {"hz": 1.0, "noise_dps": 0.02, "gaps": ((80.0, 84.0),)}, {"cal": 10.0}),
    ("100 Hz", {"hz": 100.0, "minutes": 3.0}, {"cal": 5.0}),
]


@pytest.mark.parametrize("method", names())
@pytest.mark.parametrize(("case", "kw", "how"), CASES, ids=[c[0] for c in CASES])
def test_replay_and_evaluate_give_the_same_yaw_at_every_step(
    case: str, kw: dict[str, Any], how: dict[str, Any], method: str
) -> None:
    data, log = capture(drive(**kw))
    for from_gyro in (False, True) if method == "hdr+" else (False,):
        cfg = _config(method, from_gyro)
        msgs = replay_capture(data, cfg, how.get("bias"), how.get("cal"))
        steps = [m for m in msgs if "yaw" in m]
        prep = prepare_drive(log, how.get("bias"), how.get("cal"), cfg.hdr.params.T)
        # evaluate reads a log's output step from the lattice of its values; the daemon knows
        # its ADC's LSB: the same step, to a rounding error (HDR+ fits its model to it)
        assert prep.quant_step_dps == pytest.approx(SENSOR.lsb_dps, rel=1e-6)
        prep = replace(prep, quant_step_dps=SENSOR.lsb_dps)
        yaw = method_yaw(prep, method, setup=replace(method_setup(cfg), hdr=cfg.hdr.params))
        assert len(steps) == prep.steps.u.shape[0] > 100
        assert [m["yaw"] for m in steps] == yaw.tolist()  # bit for bit
        assert [m["t"] for m in steps] == prep.steps.t_end.tolist()
        assert [m["samples"] for m in steps] == prep.steps.n_samples.tolist()
        if method != "hdr+":  # (HDR+ publishes eps0 plus its own correction)
            assert {m["bias"] for m in steps} == {prep.steps.bias_dps}
        # The steps before the drive are the start-up window's; gaps are no steps.
        calibrating = [m for m in msgs if m["status"] == "calibrating"]
        assert calibrating[-1]["t"] == prep.start_s if calibrating else prep.start_s == 0.0
        missing = sum(round(m.get("gap_s", 0.0)) for m in steps)
        assert missing == prep.missing_steps
        # And so the same heading error: Eψ from replay's yaw is evaluate's.
        r = evaluate_prepared(
            prep, methods=(method,), setup=replace(method_setup(cfg), hdr=cfg.hdr.params)
        )
        assert (
            float(e_psi(np.array([m["yaw"] for m in steps]), prep.truth, prep.k, prep.align_n))
            == (r.e_psi[method])
        )
    if "gaps" in kw:
        assert prep.missing_steps > 0


def test_a_1_hz_gyro_has_one_sample_per_step_in_the_daemon_and_in_evaluate() -> None:
    data, log = capture(drive(1.0, noise_dps=0.02))
    ctx = method_setup(_config("hdr+"))
    p = Pipeline(PipelineConfig(setup=replace(ctx, method="hdr+", bias=given_bias(0.4))))
    from hdrd.io.wire.capture import decode_capture

    frames, _ = decode_capture(data)
    p.feed_array(frames)
    assert p.stepper.settings.standstill.samples_per_step == 1.0
    assert prepare_drive(log, bias=0.4).samples_per_step == 1.0
    # ... and a 100 Hz one a hundred.
    assert prepare_drive(drive(100.0, minutes=1.0), bias=0.4).samples_per_step == 100.0


def test_a_bias_file_sets_hdr_plus_prior_in_the_daemon_as_in_evaluate() -> None:
    data, log = capture(drive(10.0, minutes=2.0))
    rec = BiasRecord(0.41, 0.05, 300, 30.0)
    msgs = replay_capture(data, _config("hdr+"), rec.bias_dps, None, rec)
    p = Pipeline(PipelineConfig(setup=MethodSetup(method="hdr+", bias=rec)))
    from hdrd.io.wire.capture import decode_capture

    p.feed_array(decode_capture(data)[0])
    assert p.stepper.settings.bias_p0 == 0.05 * 0.05 / 300
    without = replay_capture(data, _config("hdr+"), rec.bias_dps)
    assert [m["yaw"] for m in msgs] != [m["yaw"] for m in without]
    # evaluate measures its own record; with the one replay measured, the same prior.
    prep = prepare_drive(log, calibrate_seconds=20.0)
    assert prep.bias is not None and prep.bias.n == 200
    assert math.isclose(prep.steps.bias_var, prep.bias.std_dps**2 / 200)
