"""Tuning HDR on small synthetic drives, and `hdrd tune`."""

from __future__ import annotations

import io
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from hdrd.analysis.evaluate import evaluate_prepared, prepare_drive
from hdrd.analysis.progress import ProgressBar
from hdrd.analysis.tune import (
    PARAM_NAMES,
    RANGES,
    params_yaml,
    refine_candidates,
    sample_candidates,
    score_candidates,
    tune,
)
from hdrd.cli import main as cli_main
from hdrd.configload import parse_config
from hdrd.core.hdr import HdrParams
from hdrd.core.methods import MethodSetup
from hdrd.io.files.drivelog import write_drive
from tests.test_evaluate import CITY_TURNS, make_drive


def _drives(n: int, seed0: int, minutes: float = 5.0) -> list:
    drifts = (0.12, -0.07, 0.2, 0.05, -0.15)
    return [
        make_drive(
            minutes,
            drifts[i % len(drifts)],
            turns=CITY_TURNS,
            sway_dps=0.4,
            seed=seed0 + i,
            name=f"d{seed0 + i}",
        )
        for i in range(n)
    ]


@pytest.fixture(scope="module")
def train() -> list:
    return [prepare_drive(d) for d in _drives(3, 0)]


@pytest.fixture(scope="module")
def held_out() -> list:
    return [prepare_drive(d) for d in _drives(2, 50)]


def test_candidates_are_log_uniform_in_range_with_three_digits() -> None:
    c = sample_candidates(np.random.default_rng(1), 2000)
    for name in PARAM_NAMES:
        lo, hi = RANGES[name]
        v = c[name]
        assert v.shape == (2000,)
        assert np.all(v >= lo * 0.995) and np.all(v <= hi * 1.005)
        assert all(float(f"{x:.3g}") == x for x in v[:50].tolist())
        # log-uniform: about half below the geometric middle
        assert 0.4 < np.mean(v < math.sqrt(lo * hi)) < 0.6
    r = refine_candidates(
        np.random.default_rng(2), {k: np.array([1.0]) for k in PARAM_NAMES}, 500, 1.2
    )
    assert np.all(r["tau"] > 0.3) and np.all(r["tau"] < 3.0)
    assert abs(np.median(np.log(r["tau"]))) < 0.05


def test_vectorised_scores_agree_with_the_scalar_evaluation(train: list) -> None:
    c = sample_candidates(np.random.default_rng(5), 7)
    e = score_candidates(train, c)
    assert e.shape == (3, 7)
    for j in (0, 3, 6):
        p = HdrParams(
            i_c=float(c["i_c"][j]),
            tau=float(c["tau"][j]),
            theta_w=float(c["theta_w"][j]),
            c1=float(c["c1"][j]),
            c2=float(c["c2"][j]),
        )
        for i, d in enumerate(train):
            assert e[i, j] == pytest.approx(
                evaluate_prepared(d, setup=MethodSetup(hdr=p)).e_psi["hdr"], rel=1e-9, abs=1e-9
            )


def test_chunking_does_not_change_scores(train: list, monkeypatch: pytest.MonkeyPatch) -> None:
    import hdrd.analysis.tune as tune_mod

    c = sample_candidates(np.random.default_rng(6), 40)
    whole = score_candidates(train, c)
    monkeypatch.setattr(tune_mod, "CHUNK_ELEMENTS", 300 * 16)  # 16 sets per block
    assert np.array_equal(score_candidates(train, c), whole)


def test_tune_is_no_worse_than_its_start_and_reports_both(train: list, held_out: list) -> None:
    r = tune(train, held_out, n_candidates=300, seed=3)
    assert r.n_evaluated == 300
    assert r.objective_best <= r.objective_baseline
    base_ne = np.mean([d.ne_psi["hdr"] for d in r.train["baseline"]])
    best_ne = np.mean([d.ne_psi["hdr"] for d in r.train["tuned"]])
    assert best_ne <= base_ne + 1e-9
    assert best_ne == pytest.approx(r.objective_best, rel=1e-9)
    assert base_ne == pytest.approx(r.objective_baseline, rel=1e-9)
    assert r.baseline == HdrParams()
    assert [d.name for d in r.test["tuned"]] == ["d50", "d51"]
    assert r.top[0][1] == r.objective_best


def test_tune_is_reproducible_by_seed(train: list) -> None:
    a = tune(train, (), n_candidates=120, seed=11)
    b = tune(train, (), n_candidates=120, seed=11)
    assert a.best == b.best and a.objective_best == b.objective_best
    c = tune(train, (), n_candidates=120, seed=12)
    assert [p for p, _ in c.top] != [p for p, _ in a.top]


def test_tune_starting_point_only(train: list) -> None:
    r = tune(train, (), n_candidates=1, seed=0, base=HdrParams(i_c=0.03))
    assert r.best == HdrParams(i_c=0.03) and r.n_evaluated == 1
    with pytest.raises(ValueError):
        tune(train, (), n_candidates=0)
    with pytest.raises(ValueError):
        tune([], (), n_candidates=5)


def test_tune_reports_progress(train: list) -> None:
    seen: list[tuple[int, int]] = []
    tune(train, (), n_candidates=50, seed=0, progress=lambda d, t: seen.append((d, t)))
    assert seen[-1][0] == seen[-1][1]
    assert all(b[0] >= a[0] for a, b in itertools.pairwise(seen))


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_draws_to_the_stream() -> None:
    s = _Terminal()
    bar = ProgressBar("tune", stream=s, width=10)
    bar(5, 10)
    bar(10, 10)
    bar.close()
    out = s.getvalue()
    assert "\r" in out and "100.0%" in out and "##########" in out and out.endswith("\n")


def test_progress_off_a_terminal_is_plain_lines() -> None:
    # Into a log file or a pipe a carriage return only makes one endless line.
    s = io.StringIO()
    bar = ProgressBar("tune 50 sets", stream=s)
    for done in range(0, 1001):
        bar(done, 1000)
    bar.close()
    out = s.getvalue()
    lines = out.splitlines()
    assert "\r" not in out and out.endswith("\n")
    assert len(lines) == 11  # 0 %, 10 %, ..., 100 %
    assert lines[0].startswith("tune 50 sets:   0.0%") and "100.0%" in lines[-1]


def test_params_yaml_is_a_valid_config_section() -> None:
    p = HdrParams(i_c=0.0311, tau=1.25, theta_w=0.7, c1=0.2, c2=2.5)
    text = params_yaml(p, ["tuned on d0, d1"])
    assert text.startswith("# tuned on d0, d1\nhdr:\n")
    cfg = parse_config(yaml.safe_load(text))
    assert cfg.hdr.params == p and cfg.hdr.method == "hdr"


def test_cli_tune(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    paths = []
    for i, d in enumerate(_drives(3, 20, minutes=4.0)):
        p = tmp_path / f"drive{i}.csv"
        write_drive(p, d)
        paths.append(str(p))
    out, js = tmp_path / "tuned.yaml", tmp_path / "tune.json"
    rc = cli_main(
        [
            "tune",
            paths[0],
            paths[1],
            "--test",
            paths[2],
            "--candidates",
            "60",
            "--seed",
            "4",
            "--out",
            str(out),
            "--json",
            str(js),
        ]
    )
    assert rc == 0
    cap = capsys.readouterr()
    assert "100.0%" in cap.err  # the progress bar
    assert "paper Table III" in cap.out and "tuned" in cap.out and "test (1)" in cap.out
    cfg = parse_config(yaml.safe_load(out.read_text()))
    doc = json.loads(js.read_text())
    assert doc["params"]["tuned"] == {k: getattr(cfg.hdr.params, k) for k in PARAM_NAMES}
    assert doc["train"]["tuned"]["mean_NE_psi"] <= doc["train"]["baseline"]["mean_NE_psi"] + 1e-12
    assert doc["test"]["drives"] == ["drive2"]
    assert doc["candidates"] == 60 and doc["seed"] == 4
    # The snippet, used as a config, gives `hdrd evaluate` the reported training numbers.
    ej = tmp_path / "ev.json"
    assert cli_main(["evaluate", paths[0], paths[1], "--config", str(out), "--json", str(ej)]) == 0
    capsys.readouterr()
    ev = json.loads(ej.read_text())
    assert ev["mean"]["NE_psi_hdr"] == pytest.approx(
        doc["train"]["tuned"]["mean_NE_psi"], rel=1e-12
    )

    assert cli_main(["tune", paths[0], "--candidates", "5", "--no-progress"]) == 0
    cap = capsys.readouterr()
    assert cap.err == "" and "test (0)" in cap.out

    assert cli_main(["tune", str(tmp_path / "missing.csv"), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("hdrd tune: error: ") and "missing.csv" in err and err.count("\n") == 1


def test_run_many_steps_the_same_yaw_as_the_daemons_hdr_step() -> None:
    # Tuning scores its candidates with the vectorised run_many on the steps evaluate prepared
    # through the daemon's block code: for drives with gaps, at 1 Hz and at 100 Hz, each
    # candidate's yaw is the daemon's HDR step looped (to rounding: numpy's power vs math.pow).
    from hdrd.core import hdr
    from hdrd.core.methods import REGISTRY
    from tests.test_onepath import drive

    c = sample_candidates(np.random.default_rng(9), 5)
    logs = [
        drive(10.0, gaps=((100.0, 103.0), (150.2, 150.7))),
        drive(1.0, noise_dps=0.02, gaps=((80.0, 84.0),)),
        drive(100.0, minutes=2.0),
    ]
    for log in logs:
        prep = prepare_drive(log, calibrate_seconds=10.0)
        yaw = hdr.run_many(prep.steps.u, c["i_c"], c["tau"], c["theta_w"], c["c1"], c["c2"])
        assert yaw.shape == (prep.steps.u.shape[0], 5)
        for j in range(5):
            p = HdrParams(
                i_c=float(c["i_c"][j]),
                tau=float(c["tau"][j]),
                theta_w=float(c["theta_w"][j]),
                c1=float(c["c1"][j]),
                c2=float(c["c2"][j]),
            )
            state, stepped = REGISTRY["hdr"].initial_state(), []
            for i in range(prep.steps.u.shape[0]):
                state, out = REGISTRY["hdr"].step(state, prep.steps.input(i), p)
                stepped.append(out.yaw)
            np.testing.assert_allclose(yaw[:, j], stepped, rtol=1e-12, atol=1e-9)
