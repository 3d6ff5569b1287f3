"""hdrd.sim.profiles: the built-in drives, a drive by name, a drive's ADC frames, and the
limits on what a generated drive may be."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from hdrd.core.sensor import SensorModel
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.profiles import ProfileError, builtin_profile, load_profile, profile_frames


def test_builtin_profiles() -> None:
    s = builtin_profile("standstill", minutes=1.0, hz=10, seed=1, bias_dps=0.3, noise_dps=0.05)
    assert len(s) == 900 and s.rate_hz == pytest.approx(10.0)
    assert np.all(s.omega_truth == 0) and s.omega.mean() == pytest.approx(0.3, abs=0.01)
    c = builtin_profile(
        "constant", minutes=1.0, hz=10, rate_dps=-20.0, noise_dps=0.0, lead_in_s=10.0
    )
    assert c.omega_truth is not None
    assert np.all(c.omega_truth[:100] == 0) and np.all(c.omega_truth[100:] == -20.0)
    assert np.allclose(c.omega - c.omega_truth, 0.2)
    again = builtin_profile("standstill", minutes=1.0, hz=10, seed=1, bias_dps=0.3, noise_dps=0.05)
    assert np.array_equal(again.omega, s.omega)  # seeded
    for bad in (dict(drive="loop"), dict(hz=0.0), dict(minutes=-1.0), dict(minutes=float("nan"))):
        with pytest.raises(ProfileError):
            builtin_profile(**bad)


def test_profile_frames_counts_time_and_temperature() -> None:
    sensor = SensorModel()
    log = DriveLog(
        t=np.array([0.0, 0.1, 0.2, 0.3]),
        omega=np.array([0.0, 10.0, -10.0, 500.0]),
        temp_c=np.array([25.0, np.nan, -12.345, 400.0]),
    )
    arr = profile_frames(log, sensor, t0_us=2**32 - 150_000, seq0=65535)
    assert arr["seq"].tolist() == [65535, 0, 1, 2]
    assert arr["t_us"].tolist() == [2**32 - 150_000, 2**32 - 50_000, 50_000, 150_000]
    assert arr["rate"].tolist() == sensor.to_counts(log.omega).tolist()
    assert arr["rate"][3] == sensor.full_scale  # clipped at the rail
    assert arr["temp"].tolist() == [2500, -32768, -1234, 32767]
    assert arr["ref"].tolist() == [0] * 4
    assert profile_frames(log, sensor, supply_v=5.0)["ref"][0] == sensor.ref_counts_for(5.0)
    assert profile_frames(DriveLog(t=log.t, omega=log.omega))["temp"].tolist() == [-32768] * 4


@pytest.mark.parametrize(
    "kw, why",
    [
        ({"minutes": 1e308}, "is inf samples; at most 50,000,000 are made"),
        ({"minutes": 1e6}, "is 6e+08 samples"),
        ({"hz": 1e308}, "is inf samples"),
        ({"rate_dps": math.nan}, "rate_dps must be a finite number, got nan"),
        ({"rate_dps": math.inf}, "rate_dps must be a finite number, got inf"),
    ],
)
def test_a_drive_too_long_or_not_finite_is_a_profile_error(kw: dict, why: str) -> None:
    # Was an OverflowError (1e308 minutes), a memory exhaustion (1e6 minutes), or NaN counts.
    for drive in ("constant", "mixed"):
        if drive == "mixed" and "rate_dps" in kw:
            continue
        with pytest.raises(ProfileError, match=re.escape(why)):
            load_profile(drive, **kw)
