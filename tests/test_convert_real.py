"""tools/convert_real.py: geodesy on hand cases, and the two real recordings (skipped when
../shared/data is absent) with their sign conventions checked against the reference."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from hdrd.drivelog import DriveLog, read_drive

TOOL = Path(__file__).resolve().parents[1] / "tools" / "convert_real.py"


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location("convert_real", TOOL)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["convert_real"] = mod
    spec.loader.exec_module(mod)
    return mod


cr = _load()
SMARTLOC = cr.DATA / "smartloc_berlin"
COMMA = cr.DATA / "comma2k19_example"


def mean_heading_error(log: DriveLog, bias_dps: float, sign: float = 1.0) -> tuple[float, float]:
    """(mean, final) |error| of heading0 - integral(sign * (omega - bias)) against the truth, deg."""
    assert log.heading_truth is not None
    u = sign * (log.omega - bias_dps)
    yaw = np.concatenate(([0.0], np.cumsum(0.5 * (u[1:] + u[:-1]) * np.diff(log.t))))
    ok = np.isfinite(log.heading_truth)
    truth = np.degrees(np.unwrap(np.radians(log.heading_truth[ok])))
    gyro = truth[0] - (yaw[ok] - yaw[ok][0])
    return float(np.mean(np.abs(gyro - truth))), float(abs(gyro[-1] - truth[-1]))


def test_geodetic_hand_cases() -> None:
    lat, lon = cr.geodetic_lat_lon(cr._A, 0.0, 0.0)
    assert lat == pytest.approx(0.0, abs=1e-12) and lon == pytest.approx(0.0, abs=1e-12)
    # 45 deg N, 90 deg E on the ellipsoid surface.
    phi, lam = math.radians(45.0), math.radians(90.0)
    n = cr._A / math.sqrt(1 - cr._E2 * math.sin(phi) ** 2)
    p = (
        n * math.cos(phi) * math.cos(lam),
        n * math.cos(phi) * math.sin(lam),
        n * (1 - cr._E2) * math.sin(phi),
    )
    lat, lon = cr.geodetic_lat_lon(*p)
    assert math.degrees(lat) == pytest.approx(45.0, abs=1e-9) and math.degrees(
        lon
    ) == pytest.approx(90.0)


def test_course_from_positions_is_compass() -> None:
    origin = np.array([3785108.0, 899901.0, 5037234.0])  # Berlin
    east, north = cr.enu_axes(*cr.geodetic_lat_lon(*origin))
    t = np.arange(20.0)
    for course, (de, dn) in {90.0: (1, 0), 0.0: (0, 1), 225.0: (-1, -1)}.items():
        v = 10.0 * (de * east + dn * north) / math.hypot(de, dn)
        pos = origin + t[:, None] * v
        hdg, speed = cr.course_from_positions(t, pos)
        np.testing.assert_allclose(speed, 10.0, rtol=0.01)
        np.testing.assert_allclose(((hdg - course + 180) % 360) - 180, 0.0, atol=1e-6)
    slow, _ = cr.course_from_positions(t, origin + t[:, None] * east)
    assert np.all(np.isnan(slow))  # 1 m/s < 2 m/s


@pytest.mark.skipif(not SMARTLOC.is_dir(), reason="../shared/data/smartloc_berlin is absent")
def test_smartloc(tmp_path: Path) -> None:
    out = tmp_path / "s.csv"
    assert cr.main(["smartloc", "--out", str(out)]) == 0
    log = read_drive(out)
    assert len(log) == 1372 and log.rate_hz == pytest.approx(5.0, rel=0.01)
    assert log.columns() == ["t", "omega", "heading_truth", "speed"]
    assert np.isfinite(log.heading_truth).sum() > 1000  # type: ignore[arg-type]
    # CCW-positive yaw rate: with the README's ~0.05 deg/s bias the heading follows the truth
    # (the 190 deg of right turns) within a few degrees; the opposite sign is far off.
    mean_ok, _ = mean_heading_error(log, 0.0533)
    mean_flipped, _ = mean_heading_error(log, 0.0533, sign=-1.0)
    assert mean_ok < 3.0 and mean_flipped > 50.0
    assert mean_heading_error(log, 0.0)[1] == pytest.approx(17.8, abs=3.0)  # README: +17.8 deg


@pytest.mark.skipif(not COMMA.is_dir(), reason="../shared/data/comma2k19_example is absent")
def test_comma2k19(tmp_path: Path) -> None:
    out = tmp_path / "c.csv"
    assert cr.main(["comma2k19", "--out", str(out)]) == 0
    log = read_drive(out)
    assert log.omega_truth is not None and log.speed is not None
    assert len(log) == 6256 and log.rate_hz == pytest.approx(104.3, rel=0.01)
    assert np.mean(log.omega) == pytest.approx(-3.89, abs=0.05)  # raw phone bias, CCW convention
    ok = np.isfinite(log.omega_truth)
    assert np.corrcoef(log.omega[ok], log.omega_truth[ok])[0, 1] > 0.6  # same sign convention
    bias = float(log.meta["android_bias_dps"])
    _, final = mean_heading_error(log, bias)
    assert final < 4.0  # README: the Android-calibrated gyro ends 2.0 deg off
    assert mean_heading_error(log, 0.0)[1] == pytest.approx(232.7, rel=0.02)  # README: uncorrected
    speed = log.speed[np.isfinite(log.speed)]
    assert 7.5 < speed.min() and speed.max() < 20.5


def test_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cr.main(["smartloc", "--data", str(tmp_path), "--out", str(tmp_path / "x.csv")]) == 1
    assert "convert_real: smartloc:" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cr.main(["smartloc"])
