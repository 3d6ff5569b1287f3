"""hdrd.sim.grades: the gyro grade presets, what the simulator makes of them, and the CLI."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import pytest

from hdrd.cli import build_parser, main
from hdrd.core.allan import allan_deviation, arw_from_adev
from hdrd.core.grades import GRADES, Grade
from hdrd.io.files.drivelog import read_drive
from hdrd.sim import simulate_drive
from hdrd.sim.effects import BiasInstability, StaticBias
from hdrd.sim.grades import grade_model
from hdrd.sim.gyro import crs03_default_model
from hdrd.sim.source import SimulatedSource


def test_crs03_is_todays_default_model() -> None:
    assert grade_model("crs03", 5).to_dict() == crs03_default_model().to_dict()
    g = Grade.from_table("crs03")
    gm = crs03_default_model().get("bias_instability")
    assert isinstance(gm, BiasInstability)
    assert g.bias_instability_dps == pytest.approx(0.62 * gm.sigma_dps)


def test_an_unknown_grade_is_refused_naming_the_known_ones() -> None:
    with pytest.raises(ValueError, match="unknown gyro grade 'adis'.*tactical"):
        grade_model("adis")


def test_startup_bias_is_drawn_from_the_seed() -> None:
    def bias(name: str, seed: int) -> float:
        e = grade_model(name, seed).get("static_bias")
        assert isinstance(e, StaticBias)
        return e.bias_dps

    assert bias("phone", 3) == bias("phone", 3)
    draws = np.array([bias("phone", s) for s in range(200)])
    assert np.std(draws) == pytest.approx(Grade.from_table("phone").startup_bias_sd_dps, rel=0.2)
    assert np.std([bias("tactical", s) for s in range(200)]) < 0.3


@pytest.mark.parametrize("name", ["phone", "automotive", "tactical"])
def test_standstill_reads_back_quantization_and_noise(name: str) -> None:
    g = Grade.from_table(name)
    log = simulate_drive("standstill", 10.0, 7, hz=g.rate_hz, model=grade_model(name, 7))
    codes = log.omega / g.quant_step_dps
    assert np.max(np.abs(codes - np.round(codes))) < 1e-6  # whole LSBs
    if g.white_dps_per_rthz * np.sqrt(g.rate_hz) > g.quant_step_dps:
        # Noise above one LSB: the Allan deviation at 1 s reads the white noise back, within
        # what the bandwidth, quantisation and the other terms add.
        taus, adev = allan_deviation(log.omega, g.rate_hz)
        n = arw_from_adev(taus, adev, tol=0.3)
        assert n == pytest.approx(g.white_dps_per_rthz, rel=0.35)
    else:
        # Noise below one LSB (the CAN yaw rate): 30 s of samples sit almost all on one or
        # two codes, so their mean can miss the bias by up to half a step.
        _, counts = np.unique(np.round(codes[: int(30 * g.rate_hz)]), return_counts=True)
        assert np.sort(counts)[-2:].sum() > 0.95 * counts.sum()


def test_grades_order_of_drift() -> None:
    """At constant temperature, without white noise and quantisation, the tactical IMU's bias
    wanders far less over 30 minutes than the phone's (datasheet order of bias stability)."""

    def wander(name: str) -> float:
        m = grade_model(name, 1).without("temperature_bias").without("white_noise")
        m = m.without("quantization")
        t = np.arange(0.0, 1800.0, 0.1)
        out = m.apply(t, np.zeros_like(t), None, np.random.default_rng(2))
        minute_means = out.reshape(30, 600).mean(axis=1)
        return float(np.std(minute_means))

    assert wander("tactical") < 0.5 * wander("phone")
    assert wander("phone") < wander("crs03")


def _args(argv: list[str]) -> argparse.Namespace:
    return build_parser().parse_args(["simulate", *argv])


def simulate(argv: list[str]) -> int:
    """``hdrd simulate ARGV`` through the command line's entry point, as the user runs it."""
    return main(["simulate", *argv])


def test_cli_simulate_grade(tmp_path: Path) -> None:
    out = tmp_path / "a.csv"
    assert (
        simulate(
            ["--drive", "highway", "--minutes", "1", "--grade", "automotive", "--out", str(out)]
        )
        == 0
    )
    log = read_drive(out)
    assert log.meta["grade"] == "automotive"
    assert log.rate_hz == pytest.approx(Grade.from_table("automotive").rate_hz, rel=0.01)
    codes = log.omega / 0.244
    assert np.max(np.abs(codes - np.round(codes))) < 1e-3
    # crs03 is the default: the same log as without --grade (but for the grade line).
    a, b = tmp_path / "a1.csv", tmp_path / "b1.csv"
    assert simulate(["--minutes", "1", "--out", str(a)]) == 0
    assert simulate(["--minutes", "1", "--grade", "crs03", "--out", str(b)]) == 0
    strip = lambda p: [ln for ln in p.read_text().splitlines() if not ln.startswith("# grade")]  # noqa: E731
    assert strip(a) == strip(b)


def test_cli_simulate_benchmark_grade(tmp_path: Path) -> None:
    assert (
        simulate(
            ["--benchmark", "test", "--grade", "tactical", "--hz", "10", "--out", str(tmp_path)]
        )
        == 0
    )
    logs = [read_drive(p) for p in sorted(tmp_path.glob("*.csv"))]
    assert len(logs) == 5 and all(lg.meta["grade"] == "tactical" for lg in logs)
    biases = {
        lg.meta["gyro_model"].split('"static_bias", "bias_dps": ')[1].split("}")[0] for lg in logs
    }
    assert len(biases) == 5  # each drive's turn-on bias from its own seed


def test_cli_simulate_grade_errors(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert simulate(["--grade", "nope", "--out", str(tmp_path / "x.csv")]) == 2
    assert "unknown --grade 'nope'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _args(["--grade", "phone", "--model", "m.yaml"])


def test_simulated_source_takes_a_grade() -> None:
    src = SimulatedSource("highway", minutes=0.5, seed=2, hz=20.0, speedup=0.0, grade="automotive")
    codes = src.profile.omega / 0.244
    assert np.max(np.abs(codes - np.round(codes))) < 1e-6
    default = SimulatedSource("highway", minutes=0.5, seed=2, hz=20.0, speedup=0.0)
    assert not np.array_equal(default.profile.omega, src.profile.omega)


def test_grade_noise_for_hdrplus() -> None:
    from hdrd.core.gyronoise import grade_noise

    q = {g: grade_noise(g).bias_q() for g in GRADES}
    qnt = {g: grade_noise(g).bias_q_no_temp() for g in GRADES}
    assert all(v > 0 for v in q.values())
    assert q["tactical"] < q["phone"] < q["crs03"]  # bias stability, datasheet order
    assert qnt["tactical"] < qnt["automotive"] < qnt["crs03"] < qnt["phone"]  # + warm-up
    assert grade_noise("automotive").quant_step_dps == 0.244


def test_a_model_reads_back_as_its_grade_error_model() -> None:
    # A grade's effects, read as HDR+'s error model, give the grade's own parameters (what
    # `hdrd gap` needs to turn a fitted model into plus.* keys or a bias file's noise).
    from hdrd.core.grades import GRADES
    from hdrd.core.gyronoise import grade_noise
    from hdrd.sim.grades import grade_model, model_noise

    for name in GRADES:
        got = model_noise(grade_model(name, 1), source=f"grade {name}")
        want = grade_noise(name)
        for key in ("white_dps_per_rthz", "bias_tau_s", "rrw_dps_per_sqrt_s", "quant_step_dps"):
            assert getattr(got, key) == pytest.approx(getattr(want, key)), (name, key)
        assert got.bias_instability_dps == pytest.approx(want.bias_instability_dps, rel=1e-9)
        assert got.temp_coeff_dps_per_c == pytest.approx(want.temp_coeff_dps_per_c)
        assert got.bias_q() == pytest.approx(want.bias_q())
    from hdrd.sim.gyro import GyroModel

    empty = model_noise(GyroModel(()))
    assert not empty.known() and math.isnan(empty.white_dps_per_rthz)
