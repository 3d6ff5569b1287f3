"""``hdrd gap LOG --gyro-out unit.yaml``: the unit's profile, every parameter the fit named that
the profile has a key for (docs/model-gap.md, "The unit's profile"), the motion offset first
with its standard error, in a file usable as a whole ``--config`` file.

The drive of the command test is tests/gap_standins.py's ``span_drive``: a unit in 0.01 rad/s
codes, undithered at rest, reading -0.085 deg/s off while driving, beside an INS that gives its
rate only while moving. The standard error is checked against the scatter of the fitted
offset over drive seeds (city drives from the simulator, their true rate or only the GPS
course as the truth)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from hdrd.analysis.gap import fit_model, prepare
from hdrd.analysis.gap.fit import Fitter
from hdrd.analysis.gap.report import PROFILE_ORDER, gyro_section
from hdrd.core.gyronoise import NOISE_KEYS, GyroNoise
from hdrd.core.plusparams import Hypothesis
from hdrd.io.files.drivelog import write_drive
from hdrd.sim import DEFAULT_START_MODEL, simulate_drive
from hdrd.sim.effects import (
    Bandwidth,
    BiasInstability,
    MotionOffset,
    Quantization,
    RateRandomWalk,
    StaticBias,
    TemperatureBias,
    WhiteNoise,
)
from hdrd.sim.gyro import GyroModel
from tests.gap_standins import RAD_CODE_DPS, span_drive

ROOT = Path(__file__).resolve().parents[1]
OFFSET_DPS = -0.085
"""The unit's driving bias minus its rest bias (a real unit read -0.088 on a whole drive)."""


def profile(text: str) -> GyroNoise:
    """The profile file's gyro section, as the heading estimator takes it; the file holds a
    gyro section and nothing else."""
    doc = yaml.safe_load(text)
    assert list(doc) == ["gyro"], text
    return GyroNoise.from_mapping(doc["gyro"] or {})


@pytest.mark.slow  # a whole model-gap search, in a process
def test_gyro_out_holds_the_motion_offset_with_its_sd(tmp_path: Path) -> None:
    """Through the command, as a user runs it: the profile has the motion offset the drive
    names, within two of its standard errors of the truth, then the ADC step, the white
    noise, and says the ADC is undithered at rest (before: no motion offset in the file)."""
    write_drive(tmp_path / "unit.csv", span_drive(21, OFFSET_DPS))
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "gap", "unit.csv", "--gyro-out", "unit.yaml"]
        + ["--report", "r.json", "--no-progress"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        cwd=tmp_path,
        timeout=900,
        stdin=subprocess.DEVNULL,
    )
    assert p.returncode == 0, p.stderr
    assert "motion_offset (offset_dps=" in p.stdout, p.stdout
    text = (tmp_path / "unit.yaml").read_text()
    keys = [ln.split(":")[0].strip() for ln in text.splitlines() if ln.startswith("  ")]
    assert keys[:2] == ["motion_offset_dps", "motion_offset_sd_dps"], text
    noise = profile(text)
    sd = noise.motion_offset_sd_dps
    assert 0.0 < sd < 0.25 * abs(OFFSET_DPS), text
    assert abs(noise.motion_offset_dps - OFFSET_DPS) <= 2.0 * sd, text
    assert noise.quant_step_dps == pytest.approx(RAD_CODE_DPS, rel=0.01), text
    assert noise.white_dps_per_rthz > 0.0, text
    assert "# UNDITHERED at rest" in text, text


def test_the_profile_holds_every_named_parameter_it_has_a_key_for() -> None:
    """In-process: a model with every effect the profile holds, and one with none."""
    model = GyroModel(
        (
            StaticBias(0.3),
            TemperatureBias(coeff_dps_per_c=-0.02, ref_temp_c=25.0),
            MotionOffset(offset_dps=-0.09),
            BiasInstability(sigma_dps=0.009, tau_s=36.0),
            RateRandomWalk(k_dps_per_sqrt_s=1.5e-4),
            WhiteNoise(density_dps_per_rthz=0.015),
            Bandwidth(cutoff_hz=0.2),
            Quantization(step_dps=1.0 / 16.4),
        )
    )
    report = {
        "final_standard_errors": {"motion_offset": {"offset_dps": 0.004}},
        "log": {"rate_hz": 50.0},
    }
    text = gyro_section(model, "drive.csv", report)
    keys = [ln.split(":")[0].strip() for ln in text.splitlines() if ln.startswith("  ")]
    assert keys == list(PROFILE_ORDER) and set(keys) <= set(NOISE_KEYS)
    noise = profile(text)
    assert noise.motion_offset_dps == -0.09 and noise.motion_offset_sd_dps == 0.004
    assert noise.bias_instability_dps == pytest.approx(0.62 * 0.009, rel=0.01)
    assert noise.bias_tau_s == 36.0 and noise.rrw_dps_per_sqrt_s == 1.5e-4
    assert noise.temp_coeff_dps_per_c == 0.02 and noise.quant_step_dps == pytest.approx(0.0609756)
    # 0.015 deg/s/sqrt(Hz) through 0.2 Hz: 0.012 deg/s per sample, a fifth of the 1/16.4 step.
    assert "# UNDITHERED at rest: its noise is 0.19 of a step" in text
    assert "UNDITHERED" not in gyro_section(model, "d.csv")  # no rate, no judgement
    # Without its standard error (an old report) the offset stays, its sd unknown.
    alone = profile(gyro_section(model, "d.csv", {"log": {"rate_hz": 50.0}}))
    assert alone.motion_offset_dps == -0.09 and math.isnan(alone.motion_offset_sd_dps)
    bare = gyro_section(GyroModel((StaticBias(0.1),)), "d.csv")
    profile(bare)
    assert yaml.safe_load(bare)["gyro"] == {}, bare


def test_the_profile_is_a_whole_config_file_that_hdr_plus_uses(tmp_path: Path) -> None:
    """``--config unit.yaml``: the profile loads as a whole configuration, and HDR+'s bank
    takes its motion offset as every member's mean, the steady member's sd the profile's
    together with how far an offset may move between drives (a negative offset too)."""
    from hdrd.config import Config, method_setup
    from hdrd.configload import load_config
    from hdrd.core.plusparams import FRESH_BANK, PROFILE_OFFSET_SD_DPS

    def bank(c: Config) -> tuple[Hypothesis, ...]:
        return method_setup(replace(c, hdr=replace(c.hdr, method="hdr+"))).settings().bank

    model = GyroModel((StaticBias(0.3), MotionOffset(offset_dps=-0.09), WhiteNoise(0.015)))
    report = {"final_standard_errors": {"motion_offset": {"offset_dps": 0.004}}}
    path = tmp_path / "unit.yaml"
    path.write_text(gyro_section(model, "drive.csv", report))
    cfg, _ = load_config(path)
    assert cfg.gyro.motion_offset_dps == -0.09 and cfg.gyro.motion_offset_sd_dps == 0.004
    learned = bank(cfg)
    assert [h.offset_dps for h in learned] == [-0.09] * len(FRESH_BANK)
    assert learned[0].offset_sd_dps == pytest.approx(math.hypot(0.004, PROFILE_OFFSET_SD_DPS))
    assert bank(Config()) == FRESH_BANK  # without the profile: a fresh unit


@pytest.mark.parametrize("truth", ["omega_truth", "gps_course"])
def test_the_motion_offset_s_standard_error_matches_its_scatter(truth: str) -> None:
    """The standard error is the scatter of the fitted offset over drives: over 10 seeds of
    a drive with a known offset (and a random walk of the bias, which the white-weighted fit
    does not whiten for), the errors in units of their sd scatter with an sd of 0.6-1.6 and
    at least half lie within one sd."""
    z = []
    model = (
        DEFAULT_START_MODEL.with_effect(MotionOffset(offset_dps=OFFSET_DPS))
        .with_effect(RateRandomWalk(k_dps_per_sqrt_s=0.002))
    )  # fmt: skip
    for seed in range(31, 41):
        log = simulate_drive("city", 8.0, seed, hz=5.0, model=model, lead_in_s=20.0)
        log = replace(log, heading_truth=None) if truth == "omega_truth" else log
        log = replace(log, omega_truth=None) if truth == "gps_course" else log
        data = prepare(log)
        fit = fit_model(data, model)
        se = Fitter(data).standard_errors(fit)["motion_offset"]["offset_dps"]
        mo = fit.model.get("motion_offset")
        assert isinstance(mo, MotionOffset)
        z.append((mo.offset_dps - OFFSET_DPS) / se)
    zs = np.asarray(z)
    assert 0.6 < float(np.std(zs, ddof=1)) < 1.6, zs
    assert float(np.mean(np.abs(zs) < 1.0)) >= 0.5, zs
