"""tools/convert_real.py and tools/convert_shared.py: geodesy and the start-up standstill on
hand cases, and the real recordings (each skipped when its folder under ../shared/data, or
$HDRD_REAL_DATA, is absent; the public sources' when no clone is named by $HDRD_MIRRORS) with
their sign conventions checked against the reference."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from hdrd.core.angles import wrap180
from hdrd.io.files.drivelog import DriveLog, read_drive
from tools import convert_shared as shared

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
RTKLIB = cr.DATA / "rtklib_drive0708"
NDS = cr.DATA / "driveplotr_nds"


def absent(folder: Path) -> str:
    """The skip reason of a recording of ../shared/data that is not there."""
    return f"{folder} is absent (set HDRD_REAL_DATA to the folder holding the recordings)"


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
    lat, lon = shared.geodetic_lat_lon(shared.WGS84_A, 0.0, 0.0)
    assert lat == pytest.approx(0.0, abs=1e-12) and lon == pytest.approx(0.0, abs=1e-12)
    # 45 deg N, 90 deg E on the ellipsoid surface.
    phi, lam = math.radians(45.0), math.radians(90.0)
    n = shared.WGS84_A / math.sqrt(1 - shared.WGS84_E2 * math.sin(phi) ** 2)
    p = (
        n * math.cos(phi) * math.cos(lam),
        n * math.cos(phi) * math.sin(lam),
        n * (1 - shared.WGS84_E2) * math.sin(phi),
    )
    lat, lon = shared.geodetic_lat_lon(*p)
    assert math.degrees(lat) == pytest.approx(45.0, abs=1e-9) and math.degrees(
        lon
    ) == pytest.approx(90.0)


def test_course_from_positions_is_compass() -> None:
    origin = np.array([3785108.0, 899901.0, 5037234.0])  # Berlin
    east, north = shared.enu_axes(*shared.geodetic_lat_lon(*origin))
    t = np.arange(20.0)
    for course, (de, dn) in {90.0: (1, 0), 0.0: (0, 1), 225.0: (-1, -1)}.items():
        v = 10.0 * (de * east + dn * north) / math.hypot(de, dn)
        pos = origin + t[:, None] * v
        hdg, speed = shared.course_from_positions(t, pos)
        np.testing.assert_allclose(speed, 10.0, rtol=0.01)
        np.testing.assert_allclose(wrap180(hdg - course), 0.0, atol=1e-6)
    slow, _ = shared.course_from_positions(t, origin + t[:, None] * east)
    assert np.all(np.isnan(slow))  # 1 m/s < 2 m/s


@pytest.mark.skipif(not SMARTLOC.is_dir(), reason=absent(SMARTLOC))
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


@pytest.mark.skipif(not COMMA.is_dir(), reason=absent(COMMA))
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


def course_rate_correlation(log: DriveLog, min_speed: float = 3.0) -> tuple[float, int]:
    """(correlation of the gyro's mean rate between consecutive truth fixes with minus the
    truth's course rate, number of fix pairs used): positive for a CCW-positive gyro."""
    assert log.heading_truth is not None and log.speed is not None
    h, t, w = log.heading_truth, log.t, log.omega
    ok = np.flatnonzero(np.isfinite(h))
    angle = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))))
    i0, i1 = ok[:-1], ok[1:]
    dt = t[i1] - t[i0]
    sel = (dt < 1.5) & (log.speed[i0] > min_speed) & (log.speed[i1] > min_speed)
    course_rate = wrap180(h[i1] - h[i0]) / dt
    gyro_rate = (angle[i1] - angle[i0]) / dt
    return float(np.corrcoef(gyro_rate[sel], -course_rate[sel])[0, 1]), int(sel.sum())


def test_lead_in_seconds_hand_cases() -> None:
    t = np.arange(20.0)
    speed = np.where(t < 10, 0.0, 5.0)
    assert cr.lead_in_seconds(t, speed, margin_s=1.0) == 9.0  # first moving row at 10 s
    assert cr.lead_in_seconds(t, speed, margin_s=3.0) == 7.0
    assert cr.lead_in_seconds(t, np.full(20, 5.0)) is None  # starts moving
    assert cr.lead_in_seconds(t, np.where(t < 3, 0.0, 5.0)) is None  # 2 s: under 3 s
    assert cr.lead_in_seconds(t, np.where(t < 1, np.nan, 0.0)) is None  # unknown speed
    # A lagging speed says "still" but the gyro turns from 6 s: the lead-in ends before it.
    omega = np.where((t >= 6) & (t < 10), 15.0, 0.1)
    assert cr.lead_in_seconds(t, speed, omega, margin_s=1.0) == 5.0
    # 100 Hz: a vibration spike of single samples is not motion; a 1 s turn is.
    t100 = np.arange(0.0, 20.0, 0.01)
    sp100 = np.where(t100 < 10, 0.0, 5.0)
    w100 = np.full(t100.shape, 0.2)
    w100[500:503] = 3.0
    assert cr.lead_in_seconds(t100, sp100, w100, margin_s=1.0) == 9.0
    w100[700:800] = 3.0
    assert cr.lead_in_seconds(t100, sp100, w100, margin_s=1.0) == 5.0


@pytest.mark.skipif(not RTKLIB.is_dir(), reason=absent(RTKLIB))
def test_rtklib(tmp_path: Path) -> None:
    out = tmp_path / "r.csv"
    assert cr.main(["rtklib", "--out", str(out)]) == 0
    log = read_drive(out)
    assert log.columns() == ["t", "omega", "heading_truth", "speed"]
    assert log.rate_hz == pytest.approx(100.0, rel=0.01)
    assert 540.0 < log.duration_s < 560.0  # README: about 9 minutes
    lead = float(log.meta["lead_in_s"])
    assert 25.0 <= lead <= 35.0  # the car pulls away ~35 s after the IMU's first sample
    assert float(log.meta["imu_tilt_deg"]) == pytest.approx(7.0, abs=0.5)  # README: ~7 deg
    assert log.speed is not None
    assert np.nanmax(log.speed[log.t < lead]) < 0.3
    bias = float(np.mean(log.omega[log.t < lead]))
    assert bias == pytest.approx(0.17, abs=0.01)  # README: static bias about 0.17 deg/s
    # CCW positive: the gyro turns against the compass course, at zero lag, nearly 1:1.
    corr, pairs = course_rate_correlation(log)
    assert corr > 0.95 and pairs > 1000
    mean_ok, _ = mean_heading_error(log, bias)
    mean_flipped, _ = mean_heading_error(log, bias, sign=-1.0)
    assert mean_ok < 3.0 and mean_flipped > 100.0


@pytest.mark.skipif(not NDS.is_dir(), reason=absent(NDS))
def test_driveplotr(tmp_path: Path) -> None:
    assert cr.main(["driveplotr", "--out-dir", str(tmp_path)]) == 0
    files = sorted(tmp_path.glob("nds_drive*.csv"))
    assert len(files) == 28  # README: 28 drives
    logs = [read_drive(f) for f in files]
    assert sum(1 for lg in logs if lg.duration_s >= 600.0) >= 9
    assert all(lg.rate_hz == pytest.approx(1.0) for lg in logs)
    # gyro_z is quantised in 1/16 deg/s (printed with 2 decimals).
    codes = np.concatenate([lg.omega for lg in logs]) * 16.0
    assert np.max(np.abs(codes - np.round(codes))) < 0.2
    long_ones = []
    for lg in logs:
        assert lg.heading_truth is not None and lg.speed is not None
        h = lg.heading_truth[np.isfinite(lg.heading_truth)]
        assert h.min() >= 0.0 and h.max() < 360.0
        assert np.all(lg.speed[np.isfinite(lg.heading_truth)] > 2.0)
        if "lead_in_s" in lg.meta:
            lead = float(lg.meta["lead_in_s"])
            assert lead >= 3.0 and np.all(lg.speed[lg.t < lead] <= 0.3)
        corr, pairs = course_rate_correlation(lg)
        if pairs > 100:
            long_ones.append(corr)
    # CCW positive on every drive with enough motion (README: correlation 0.60-0.83).
    assert len(long_ones) >= 20 and min(long_ones) > 0.5
    by_name = {lg.name: lg for lg in logs}
    assert "lead_in_s" not in by_name["nds_drive01"].meta  # starts at 30 mph
    # Drive 8 stands ~10 min, then turns out of its parking space while the GPS speed still
    # reads ~0.1 m/s (at ~600 s): the lead-in ends before that turn.
    assert 560.0 <= float(by_name["nds_drive08"].meta["lead_in_s"]) < 600.0


def test_cli_multi_needs_out_dir(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        cr.main(["driveplotr", "--out", str(tmp_path / "x.csv")])
    assert cr.main(["rtklib", "--data", str(tmp_path), "--out", str(tmp_path / "x.csv")]) == 1


# -- command line: 'all' and absent folders --------------------------------------------------


def test_cli_all_takes_data_root(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 'all --data ROOT' reads ROOT/<folder>, not the default folders.
    assert cr.main(["all", "--data", str(tmp_path), "--out-dir", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert f"{tmp_path / 'smartloc_berlin'} is absent" in err
    assert "--data" not in err  # the user's own folder: no hint about the default
    with pytest.raises(SystemExit):
        cr.main(["all", "--data", str(tmp_path)])
    assert "--out-dir" in capsys.readouterr().err  # the option that is missing
    with pytest.raises(SystemExit):
        cr.main(["all", "--out", str(tmp_path / "x.csv")])
    assert "--out-dir" in capsys.readouterr().err


def test_cli_absent_default_folder_hints(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(cr, "DATA", tmp_path / "no-shared-data")
    assert cr.main(["rtklib", "--out", str(tmp_path / "x.csv")]) == 1
    err = capsys.readouterr().err
    assert "no-shared-data/rtklib_drive0708 is absent" in err and "--data" in err
    assert cr.main(["all", "--out-dir", str(tmp_path)]) == 1
    assert "HDRD_REAL_DATA" in capsys.readouterr().err
    monkeypatch.setattr(cr, "MIRRORS", tmp_path / "no-mirrors")
    assert cr.main(["psins", "--out", str(tmp_path / "p.csv")]) == 1
    err = capsys.readouterr().err
    assert "no-mirrors/WangShanpeng+PSINS/repo is absent" in err
    clone = "git clone https://github.com/WangShanpeng/PSINS PSINS && git -C PSINS checkout "
    assert clone + "c1706f136d1a8dc64245e851cc77c8cac00a94b6" in err
    assert not (tmp_path / "p.csv").exists()


def test_no_folder_of_snapshots_is_assumed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # Without $HDRD_MIRRORS (a folder of clones the user keeps) or --data, a public source is
    # named with the command that clones it: no machine's folder is a default.
    monkeypatch.setitem(sys.modules, "convert_real", cr)  # back to this module's after
    monkeypatch.delenv("HDRD_MIRRORS", raising=False)
    fresh = _load()
    assert fresh.MIRRORS is None and fresh.default_clone("oan") is None
    assert fresh.main(["oan", "--out-dir", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "HDRD_MIRRORS" in err and "--data" in err
    assert "git clone https://github.com/fedorbaklanov/open-aided-navigation " in err
    with pytest.raises(ValueError, match="git -C PSINS checkout c1706f136d1a"):
        fresh.psins_to_drive()
    monkeypatch.setenv("HDRD_MIRRORS", str(tmp_path))
    assert _load().default_clone("psins") == tmp_path / "WangShanpeng+PSINS" / "repo"


@pytest.mark.skipif(not cr.DATA.is_dir(), reason=absent(cr.DATA))
def test_cli_all_with_explicit_root(tmp_path: Path) -> None:
    assert cr.main(["all", "--data", str(cr.DATA), "--out-dir", str(tmp_path)]) == 0
    names = {f.stem for f in tmp_path.glob("*.csv")}
    assert {"smartloc_berlin", "comma2k19", "rtklib_drive0708", "nds_drive01"} <= names
    assert not any(n.startswith(("oan_", "psins")) for n in names)  # 'all': shared/data only


# -- public repositories (tools/real_sources.yaml) ---------------------------------------------

OAN = cr.default_clone("oan")
PSINS = cr.default_clone("psins")


def no_clone(key: str, clone: Path | None) -> str:
    """The skip reason of a public source without a clone: where it was looked for and how
    to make one."""
    where = "no $HDRD_MIRRORS" if clone is None else f"{clone} is absent"
    return f"{where}: {cr.clone_hint(key)}"


def wrapped_heading_error(log: DriveLog, bias_dps: float, sign: float = 1.0) -> float:
    """Mean |error| (deg, each wrapped to +-180) of heading0 - integral(sign * (omega - bias))
    against the truth: a course with gaps may not unwrap."""
    assert log.heading_truth is not None
    u = sign * (log.omega - bias_dps)
    yaw = np.concatenate(([0.0], np.cumsum(0.5 * (u[1:] + u[:-1]) * np.diff(log.t))))
    ok = np.isfinite(log.heading_truth)
    h = log.heading_truth[ok]
    err = wrap180(h[0] - (yaw[ok] - yaw[ok][0]) - h)
    return float(np.mean(np.abs(err)))


def test_source_file_is_checked(tmp_path: Path) -> None:
    (tmp_path / "LICENSE.md").write_text("not the MIT text\n", encoding="utf-8")
    with pytest.raises(ValueError, match="sha256"):
        cr.read_source_file(tmp_path, "oan", "LICENSE.md")
    with pytest.raises(ValueError, match="not listed"):
        cr.read_source_file(tmp_path, "oan", "README.md")
    with pytest.raises(ValueError, match="clone github.com/fedorbaklanov/open-aided-navigation"):
        cr.read_source_file(
            tmp_path, "oan", "data/nsr/drive/20201104_093418/20201104_093418_Gyro.csv"
        )
    meta = cr.public_source("psins")
    assert len(meta["commit"]) == 40 and all(len(f["sha256"]) == 64 for f in meta["files"])


def test_semicolon_table_hand_case() -> None:
    text = (
        b"Sensor: X Gyroscope\nVendor: Y\n"
        b"TimestampGyro [ns]; GyroX [rad/s]; GyroY [rad/s]; GyroZ [rad/s]\n"
        b"1000;0.1;0.2;0.3;\n2000;0.4;0.5;x;\n3000;0.7;0.8;\n4000;1.0;1.1;1.2;\n"
    )
    rows = cr._semicolon_table(text, "g.csv", ("TimestampGyro", "GyroZ"))
    np.testing.assert_array_equal(rows, [[1000.0, 0.3], [4000.0, 1.2]])  # bad rows skipped
    with pytest.raises(ValueError, match="no column Speed"):
        cr._semicolon_table(text, "g.csv", ("TimestampGyro", "Speed"))
    with pytest.raises(ValueError, match="no header"):
        cr._semicolon_table(b"1;2;3\n", "g.csv", ("TimestampGyro",))


@pytest.mark.skipif(OAN is None or not OAN.exists(), reason=no_clone("oan", OAN))
def test_oan(tmp_path: Path) -> None:
    assert cr.main(["oan", "--data", str(OAN), "--out-dir", str(tmp_path)]) == 0
    logs = {f.stem: read_drive(f) for f in sorted(tmp_path.glob("oan_*.csv"))}
    assert sorted(logs) == ["oan_20201104_091730", "oan_20201104_093418", "oan_20201121_152755"]
    durations = [lg.duration_s for lg in logs.values()]
    assert durations == pytest.approx([1000.0, 100.0, 1455.5], abs=1.0)
    leads = {n: float(lg.meta["lead_in_s"]) for n, lg in logs.items() if "lead_in_s" in lg.meta}
    # Drive 1 turns out of its space ~6.5 s in; the city drive stands ~270 s, the phone handled
    # at ~122 s (beyond 1,000 deg/s): it starts after that, with ~140 s left standing; the 100 s
    # drive starts moving.
    assert 4.0 <= leads["oan_20201104_091730"] <= 6.0
    assert 130.0 <= leads["oan_20201121_152755"] <= 150.0
    assert max(float(np.abs(lg.omega).max()) for lg in logs.values()) < 200.0
    assert "oan_20201104_093418" not in leads
    for name, lg in logs.items():
        assert lg.rate_hz == pytest.approx(50.0, rel=0.01)
        assert lg.heading_truth is not None and lg.speed is not None
        h = lg.heading_truth[np.isfinite(lg.heading_truth)]
        assert h.min() >= 0.0 and h.max() < 360.0  # no -3000 placeholder
        assert np.all(lg.speed[np.isfinite(lg.heading_truth)] > 2.0)
        assert 80.0 < float(lg.meta["phone_tilt_deg"].split()[0]) < 90.0  # phone upright
        # CCW positive: the gyro turns against the compass course, at zero lag.
        corr, pairs = course_rate_correlation(lg)
        assert corr > 0.9 and pairs > 90, name
        bias = float(np.mean(lg.omega[lg.t < leads[name]])) if name in leads else 0.0
        assert abs(bias) < 0.1
        ok, flipped = wrapped_heading_error(lg, bias), wrapped_heading_error(lg, bias, -1.0)
        assert ok < 20.0 and flipped > 50.0 and flipped > 3 * ok, name


@pytest.mark.skipif(OAN is None or not OAN.exists(), reason=no_clone("oan", OAN))
def test_source_file_from_a_work_tree(tmp_path: Path) -> None:
    # The same bytes from a bare git directory (the fetched snapshot) and from a work tree.
    from_git = cr.read_source_file(OAN, "oan", "LICENSE.md")
    assert b"Permission is hereby granted" in from_git
    (tmp_path / "LICENSE.md").write_bytes(from_git)
    assert cr.read_source_file(tmp_path, "oan", "LICENSE.md") == from_git


@pytest.mark.skipif(PSINS is None or not PSINS.exists(), reason=no_clone("psins", PSINS))
def test_psins(tmp_path: Path) -> None:
    out = tmp_path / "p.csv"
    assert cr.main(["psins", "--src", str(PSINS), "--out", str(out)]) == 0
    log = read_drive(out)
    assert log.columns() == ["t", "omega", "heading_truth", "omega_truth", "speed"]
    assert len(log) == 10001 and log.rate_hz == pytest.approx(100.0)
    assert log.duration_s == pytest.approx(100.0) and "lead_in_s" not in log.meta
    assert float(log.meta["imu_tilt_deg"]) == pytest.approx(2.3, abs=0.3)
    assert log.heading_truth is not None and log.omega_truth is not None
    assert log.speed is not None and 11.0 < np.nanmin(log.speed) and np.nanmax(log.speed) < 16.0
    assert np.isfinite(log.heading_truth).sum() == 1000  # every 10 Hz epoch
    # Heading north (compass = minus PSINS's counter-clockwise yaw): within a few degrees of 0.
    h = log.heading_truth[np.isfinite(log.heading_truth)]
    assert np.all(np.abs(wrap180(h)) < 5.0)
    # CCW positive: 1 s means of the gyro follow the INS yaw rate (slope ~0.93), and the gyro
    # turns against the INS velocity's compass course.
    sec = np.floor(log.t).astype(int)
    g = np.bincount(sec, log.omega) / np.bincount(sec)
    ok = np.isfinite(log.omega_truth)
    r = np.bincount(sec[ok], log.omega_truth[ok]) / np.bincount(sec[ok])
    assert np.corrcoef(g, r)[0, 1] > 0.8
    assert np.polyfit(r, g, 1)[0] == pytest.approx(0.93, abs=0.1)
    corr, pairs = course_rate_correlation(log)
    assert corr > 0.5 and pairs > 900
    bias = float(np.nanmean(log.omega - log.omega_truth))
    assert bias == pytest.approx(0.028, abs=0.005)
    mean_ok, _ = mean_heading_error(log, bias)
    mean_flipped, _ = mean_heading_error(log, bias, sign=-1.0)
    assert mean_ok < 0.6 and mean_flipped > mean_ok


BOREAS = cr.default_clone("boreas")


def test_boreas_table_refuses_what_is_not_a_pose_file() -> None:
    head = ",".join(cr.BOREAS_COLUMNS) + "\n"
    row = ",".join(["1"] * 13) + "\n"
    with pytest.raises(ValueError, match="header"):
        cr._boreas_table(b"t,x\n1,2\n", "p.csv")
    with pytest.raises(ValueError, match="fewer than 2 rows"):
        cr._boreas_table((head + row).encode(), "p.csv")
    with pytest.raises(ValueError, match="does not increase"):
        cr._boreas_table((head + row + row).encode(), "p.csv")
    two = head + row + row.replace("1", "2", 1)
    assert cr._boreas_table(two.encode(), "p.csv").shape == (2, 13)


@pytest.mark.skipif(BOREAS is None or not BOREAS.exists(), reason=no_clone("boreas", BOREAS))
def test_boreas(tmp_path: Path) -> None:
    assert cr.main(["boreas", "--data", str(BOREAS), "--out-dir", str(tmp_path)]) == 0
    logs = {f.stem: read_drive(f) for f in sorted(tmp_path.glob("boreas_*.csv"))}
    assert sorted(logs) == ["boreas_20210805_1334", "boreas_20210902_1142"]
    assert [lg.duration_s for lg in logs.values()] == pytest.approx([1118.9, 1033.5], abs=0.2)
    assert [lg.meta["lead_in_s"] for lg in logs.values()] == ["8", "3"]
    for name, lg in logs.items():
        assert lg.columns() == ["t", "omega", "heading_truth", "omega_truth", "speed"]
        assert "route" in lg.meta and lg.rate_hz == pytest.approx(9.64, abs=0.05)
        assert lg.omega_truth is not None and lg.heading_truth is not None
        np.testing.assert_array_equal(lg.omega, lg.omega_truth)  # a route: a perfect gyro
        assert np.isfinite(lg.heading_truth).all()  # an INS heading, standing too
        # CCW positive about up: the rate turns against the compass heading, at zero lag, and
        # integrated follows it within a few degrees over ~3,000 deg of turning; flipped, not.
        h = np.degrees(np.unwrap(np.radians(lg.heading_truth)))
        assert np.corrcoef(lg.omega, -np.gradient(h, lg.t))[0, 1] > 0.999
        assert course_rate_correlation(lg)[0] > 0.95
        ok, flipped = mean_heading_error(lg, 0.0), mean_heading_error(lg, 0.0, -1.0)
        assert ok[1] < 3.0 and flipped[0] > 100.0, name
    # The heading offset: the compass course of the Applanix velocities on straight road.
    path = "pyboreas/test/demo/gt/boreas-2021-08-05-13-34/applanix/lidar_poses.csv"
    a = cr._boreas_table(cr.read_source_file(BOREAS, "boreas", path), path)
    course = np.degrees(np.arctan2(a[:, 4], a[:, 5]))
    straight = (np.hypot(a[:, 4], a[:, 5]) > 5.0) & (np.abs(np.degrees(a[:, 10])) < 1.0)
    log = logs["boreas_20210805_1334"]
    assert log.heading_truth is not None
    d = np.radians(course - log.heading_truth)[straight]
    assert math.degrees(math.atan2(np.sin(d).mean(), np.cos(d).mean())) == pytest.approx(0, abs=0.1)
