"""From real drives to training routes: the gyro errors ``hdrd gap --report`` fitted to a set of
drives as the distribution simulated routes draw their gyro from (hdrd.sim.recordings
``errors_from``, ``hdrd simulate --errors-from``; docs/model-gap.md, "From real drives to
training routes"). The whole chain, gap on drives then the training set, is the page's
example, run by tests/test_doc_examples.py."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdrd.cli import main as cli_main
from hdrd.io.files.drivelog import read_drive
from hdrd.sim.benchmark import TRAIN_DRIVES, generate, generate_all
from hdrd.sim.effects import MotionOffset, StaticBias, TimeOffset, WhiteNoise
from hdrd.sim.gyro import GyroModel
from hdrd.sim.recordings import FittedErrors, errors_from, gyro_error_draws


def report(name: str, model: GyroModel, truth: str = "omega_truth") -> dict[str, Any]:
    """The parts of an ``hdrd gap`` report the draws read."""
    return {
        "final_model": model.names(),
        "final_params": model.to_dict()["effects"],
        "log": {"name": name, "truth": truth},
    }


A = GyroModel((StaticBias(0.3), MotionOffset(offset_dps=-0.085), WhiteNoise(0.02)))
B = GyroModel((StaticBias(-0.1), WhiteNoise(0.05), TimeOffset(delay_s=-1.0)))


def test_a_fleet_report_is_one_model_per_drive(tmp_path: Path) -> None:
    path = tmp_path / "gap.json"
    path.write_text(
        json.dumps({"drives": [report("a", A), report("b", B, "heading_truth")], "skipped": []})
    )
    errors = errors_from(path)
    assert [n for n, _ in errors.drives] == ["a", "b"]
    assert errors.drives[0][1] == A
    # With a GPS course as truth a time_offset is the course's latency: not the gyro's.
    assert errors.drives[1][1] == B.without("time_offset")
    # One drive's report (what `hdrd gap DRIVE --report` writes) is a set of one.
    one = tmp_path / "one.json"
    one.write_text(json.dumps(report("a", A)))
    assert errors_from(one).drives == (("a", A),)


def test_routes_draw_whole_drives_by_their_seed() -> None:
    errors = FittedErrors((("a", A), ("b", B)), "test")
    draws = gyro_error_draws(errors, range(200))
    assert draws == gyro_error_draws(errors, range(200))  # fixed by the seed
    counts = Counter(m.get("static_bias") for m in draws)
    assert set(counts) == {A.get("static_bias"), B.get("static_bias")}
    assert min(counts.values()) > 70  # each drive equally likely
    # A benchmark route takes the model its seed draws; its route stays the spec's.
    spec = TRAIN_DRIVES[0]
    drawn = errors.draw(spec.seed)
    log = generate(spec, hz=5.0, errors=errors)
    ref = generate(spec, hz=5.0, model=drawn[1])
    np.testing.assert_array_equal(log.omega, ref.omega)
    np.testing.assert_array_equal(log.omega_truth, generate(spec, hz=5.0).omega_truth)
    assert log.meta["gyro_errors_from"] == f"{drawn[0]} (test)"
    assert len(generate_all("test", hz=1.0, errors=errors)) == 5


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("{", "not JSON"),
        ('{"drives": []}', "no drive's report"),
        ('{"drives": [{"final_params": [{"name": "warp"}]}]}', "unknown effect name"),
        ("[1, 2]", "not an hdrd gap report"),
        ('{"final_params": [{"name": "white_noise"}]}', "missing parameter"),
    ],
)
def test_a_bad_report_is_one_line_naming_the_file(tmp_path: Path, text: str, problem: str) -> None:
    path = tmp_path / "r.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=problem) as e:
        errors_from(path)
    assert "r.json" in str(e.value) and "\n" not in str(e.value)


def test_simulate_errors_from(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "gap.json"
    path.write_text(json.dumps({"drives": [report("a", A), report("b", B)], "skipped": []}))
    out = tmp_path / "city.csv"
    args = ["simulate", "--drive", "city", "--minutes", "2", "--seed", "5", "--hz", "5"]
    assert cli_main([*args, "--errors-from", str(path), "--out", str(out)]) == 0
    log = read_drive(out)
    name, model = errors_from(path).draw(5)
    assert log.meta["gyro_errors_from"].startswith(f"{name} (")
    assert json.loads(log.meta["gyro_model"]) == model.to_dict()["effects"]
    train = tmp_path / "train"
    assert cli_main(["simulate", "--benchmark", "train", "--hz", "1", "--errors-from",
                     str(path), "--out", str(train)]) == 0  # fmt: skip
    assert len(list(train.glob("*.csv"))) == len(TRAIN_DRIVES)
    capsys.readouterr()
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert cli_main([*args, "--errors-from", str(bad), "--out", str(out)]) == 78
    assert "not an hdrd gap report" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # one gyro source at a time
        cli_main([*args, "--errors-from", str(path), "--grade", "phone"])
