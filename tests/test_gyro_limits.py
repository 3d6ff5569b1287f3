"""A gyro error model read from a file (``simulate --model``, ``gap --model``, the fitted
errors of ``simulate --errors-from``) holds only what a gyro can have: every parameter within
a bound (hdrd.sim.gyrolimits), else one line naming the effect, the parameter, the value and
what is allowed, exit 78, and nothing written. A scale factor error of 1e308 once made a log
of overflowed rates that ``hdrd evaluate`` then refused."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from hdrd.cli import main
from tests.hdrd_process import ENV

ABSURD = [
    ("time_offset", "delay_s", -1e9, {}),
    ("scale_factor", "error", 1e308, {}),
    ("scale_asymmetry", "pos_error", 1e6, {"neg_error": 0.0}),
    ("static_bias", "bias_dps", 1e300, {}),
    ("static_bias", "bias_dps", -5000.0, {}),
    ("warmup_transient", "amplitude_dps", 1e200, {"tau_s": 60.0}),
    ("warmup_transient", "tau_s", 1e300, {"amplitude_dps": 0.1}),
    ("temperature_bias", "coeff_dps_per_c", 1e10, {"ref_temp_c": 25.0}),
    ("temperature_bias", "ref_temp_c", 1e6, {"coeff_dps_per_c": 0.01}),
    ("temperature_bias", "quad_dps_per_c2", 50.0, {"coeff_dps_per_c": 0.01, "ref_temp_c": 25.0}),
    ("motion_offset", "offset_dps", 1e300, {}),
    ("motion_offset", "moving_mps", 1e9, {"offset_dps": 0.1}),
    ("motion_offset", "coeff_dps_per_mps", 1e5, {"offset_dps": 0.1}),
    ("bias_instability", "sigma_dps", 1e300, {"tau_s": 300.0}),
    ("bias_instability", "tau_s", 1e300, {"sigma_dps": 0.01}),
    ("rate_random_walk", "k_dps_per_sqrt_s", 1e100, {}),
    ("white_noise", "density_dps_per_rthz", 1e100, {}),
    ("bandwidth", "cutoff_hz", 1e300, {}),
    ("bandwidth", "output_noise_dps_per_rthz", 1e9, {"cutoff_hz": 10.0}),
    ("saturation", "limit_dps", 1e300, {}),
    ("quantization", "step_dps", 1e300, {}),
    ("quantization", "step_dps", 1e-320, {}),
]


def _model_yaml(effect: str, param: str, value: float, others: dict[str, float]) -> str:
    params = {param: value, **others}
    inner = ", ".join(f"{k}: {v:.17e}" for k, v in params.items())  # YAML 1.1 floats
    return f"effects:\n- {{name: {effect}, {inner}}}\n"


@pytest.mark.parametrize(
    ("effect", "param", "value", "others"), ABSURD, ids=[f"{e}.{p}={v:g}" for e, p, v, _ in ABSURD]
)
def test_simulate_refuses_an_error_no_gyro_has(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    effect: str,
    param: str,
    value: float,
    others: dict[str, float],
) -> None:
    # Before: exit 0, an overflow warning, and a log of inf or 1e300 deg/s.
    model = tmp_path / "absurd.yaml"
    model.write_text(_model_yaml(effect, param, value, others))
    out = tmp_path / "d.csv"
    rc = main(["simulate", "--drive", "city", "--minutes", "1", "--model", str(model),
               "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 78, err
    assert len(err.splitlines()) == 1, err
    assert f"{effect}.{param}: {value!r} is beyond what a gyro has" in err, err
    assert "allowed" in err and not out.exists()


def test_simulate_errors_from_refuses_an_error_no_gyro_has(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    report = {
        "log": {"name": "real-1"},
        "final_params": [
            {"name": "static_bias", "bias_dps": 0.4},
            {"name": "scale_factor", "error": 1e308},
        ],
    }
    path = tmp_path / "gap.json"
    path.write_text(json.dumps({"drives": [report], "skipped": []}))
    out = tmp_path / "train"
    rc = main(["simulate", "--benchmark", "train", "--errors-from", str(path), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 78, err
    assert len(err.splitlines()) == 1 and "scale_factor.error: 1e+308 is beyond" in err, err
    assert "real-1" in err and not out.exists()


def test_every_limit_admits_every_built_in_gyro_and_says_its_unit() -> None:
    from dataclasses import fields

    from hdrd.core.grades import GRADES
    from hdrd.sim.effects import EFFECTS
    from hdrd.sim.grades import grade_model
    from hdrd.sim.gyro import DEFAULT_START_MODEL, crs03_default_model
    from hdrd.sim.gyrolimits import LIMITS, limit_problem

    every = {(name, f.name) for name, cls in EFFECTS.items() for f in fields(cls)}
    assert set(LIMITS) == every  # every parameter has its bound
    for (effect, param), (lo, hi, unit) in LIMITS.items():
        assert lo < hi and unit, (effect, param)
        assert limit_problem(effect, param, hi) is None  # the bound itself is allowed
        assert limit_problem(effect, param, math.nextafter(hi, math.inf)) is not None
    models = [grade_model(g, s) for g in GRADES for s in range(3)]
    models += [crs03_default_model(), DEFAULT_START_MODEL]
    for m in models:
        for e in m.to_dict()["effects"]:
            for k, v in e.items():
                if k != "name":
                    assert limit_problem(e["name"], k, v) is None, (e, k)


def test_the_docs_state_every_limit() -> None:
    from hdrd.sim.gyrolimits import LIMITS

    text = (Path(__file__).resolve().parents[1] / "docs" / "gyro-model.md").read_text()
    for (effect, param), (_lo, hi, unit) in LIMITS.items():
        row = next((x for x in text.splitlines() if x.startswith(f"| `{effect}.{param}` |")), "")
        assert row, f"docs/gyro-model.md has no row for {effect}.{param}"
        assert f"{hi:g}" in row and unit in row, row


# -- what an hdrd gap report may hold (simulate --errors-from) ---------------------------------


def test_a_report_of_empty_objects_is_refused_before_it_is_built(tmp_path: Path) -> None:
    # A 60 MB report of `{}`s took gigabytes (6.6 GB for 256 MiB) to say "not an hdrd gap
    # report": json built every object first. Under a 1 GiB address-space limit that was a
    # MemoryError; now it is refused from a count of its values, before any is built.
    import resource
    import subprocess
    import sys

    from hdrd.sim.recordings import MAX_GAP_REPORT_BYTES

    big = tmp_path / "gap.json"
    n = 20_000_000
    with big.open("wb") as f:
        f.write(b'{"drives": [')
        for _ in range(n // 1_000_000):
            f.write(b"{}," * 1_000_000)
        f.write(b"{}]}")
    assert big.stat().st_size < MAX_GAP_REPORT_BYTES  # the size alone does not refuse it

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))

    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "simulate", "--benchmark", "train", "--errors-from",
         str(big), "--out", str(tmp_path / "train")],
        capture_output=True, text=True, preexec_fn=limited, timeout=300,
        env=ENV,
    )  # fmt: skip
    assert p.returncode == 78, p.stderr
    assert len(p.stderr.splitlines()) == 1, p.stderr
    assert f"{big}: holds about 20,000,004 JSON values, more than the 4,000,000" in p.stderr


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ('{"final_params": [{"name": "static_bias", "bias_dps": ' + "1" * 5000 + "}]}",
         "not JSON (a number of more than 4300 digits)"),
        ('{"final_params": [{"name": ["static_bias"], "bias_dps": 1}]}',
         "unknown effect name(s): ['static_bias']"),
        ('{"final_params": [{"name": {"a": 1}}]}', "unknown effect name(s): {'a': 1}"),
        ("[{}, {}]", "not an hdrd gap report (a JSON object: one drive's report, or "),
        ('{"drives": {}}', "no drive's report in it"),
    ],
    ids=["5000 digits", "a list as a name", "a mapping as a name", "a list", "no drives"],
)  # fmt: skip
def test_a_report_that_is_not_one_says_so_naming_its_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, why: str
) -> None:
    # Was: the 5000-digit number's "Exceeds the limit (4300 digits) ..." without the file's
    # name; "unhashable type: 'list'".
    path = tmp_path / "gap.json"
    path.write_text(text)
    out = tmp_path / "d.csv"
    assert main(["simulate", "--errors-from", str(path), "--out", str(out)]) == 78
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith(f"hdrd simulate: {path}"), err
    assert why in err, err
    assert "unhashable" not in err and "Exceeds" not in err
