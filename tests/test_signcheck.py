"""A yaw rate of the wrong sign or unit does not go unnoticed: its turns against the truth
heading's (hdrd.analysis.signcheck), a warning from ``hdrd evaluate``, a refusal with
``--strict``."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hdrd.analysis.signcheck import MIN_TURNS, check_sign, sign_warning
from hdrd.io.files.drivelog import DriveLog, write_drive
from hdrd.sim.drive import simulate_drive

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


@pytest.fixture(scope="module")
def city() -> DriveLog:
    return simulate_drive("city", 8.0, 5)


def _check(log: DriveLog, scale: float = 1.0) -> tuple[int, float, float]:
    assert log.heading_truth is not None
    c = check_sign(log.t, scale * log.omega, log.heading_truth)
    return c.turns, c.agreement, c.ratio


def test_the_right_sign_agrees_and_the_flipped_one_is_named(city: DriveLog) -> None:
    turns, agree, ratio = _check(city)
    assert turns >= MIN_TURNS and agree > 0.95 and 0.8 < ratio < 1.2
    assert sign_warning("c", check_sign(city.t, city.omega, city.heading_truth)) is None  # type: ignore[arg-type]
    flipped = check_sign(city.t, -city.omega, city.heading_truth)  # type: ignore[arg-type]
    assert flipped.flipped and flipped.agreement < -0.95
    w = sign_warning("c", flipped)
    assert w is not None and w.startswith("c: omega turns against heading_truth over ")
    assert "its sign looks flipped" in w


def test_a_rate_in_radians_is_named_by_its_scale(city: DriveLog) -> None:
    c = check_sign(city.t, np.radians(city.omega), city.heading_truth)  # type: ignore[arg-type]
    assert c.scaled and not c.flipped and 0.015 < c.ratio < 0.02
    w = sign_warning("c", c)
    assert w is not None and "57.3 times" in w


def test_a_drive_without_turns_is_not_judged() -> None:
    log = simulate_drive("highway", 3.0, 1)
    c = check_sign(log.t, -log.omega, log.heading_truth)  # type: ignore[arg-type]
    assert not c.judged and sign_warning("h", c) is None
    t = np.arange(100.0)
    assert check_sign(t, np.zeros(100), np.full(100, math.nan)).turns == 0
    assert check_sign(t[:1], np.zeros(1), np.zeros(1)).turns == 0


@pytest.mark.slow
def test_evaluate_warns_of_a_flipped_rate_and_strict_refuses_it(
    city: DriveLog, tmp_path: Path
) -> None:
    """A sign-flipped drive scored dozens of degrees with no word about why."""
    write_drive(tmp_path / "right.csv", city)
    write_drive(tmp_path / "flipped.csv", replace(city, omega=-city.omega))

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "hdrd", "evaluate", *args],
            capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=300,
        )  # fmt: skip

    p = run("right.csv", "flipped.csv", "--json", "t.json")
    assert p.returncode == 0, p.stderr
    lines = p.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        "hdrd evaluate: warning: flipped: omega turns against heading_truth over "
    ), p.stderr
    doc = json.loads((tmp_path / "t.json").read_text())
    assert "warnings" not in doc["drives"][0]
    assert doc["drives"][1]["warnings"] == [lines[0].removeprefix("hdrd evaluate: warning: ")]
    assert doc["drives"][1]["E_psi_raw"] > 10 * doc["drives"][0]["E_psi_raw"]
    s = run("right.csv", "flipped.csv", "--strict")
    assert s.returncode == 1
    assert s.stderr.startswith("hdrd evaluate: error: flipped: omega turns against")
    assert s.stderr.count("\n") == 1
    assert run("right.csv", "--strict").returncode == 0
