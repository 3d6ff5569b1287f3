"""firmware/: the ATmega328P USB ADC, built with avr-gcc and run in simavr (docs/firmware.md).

The whole chain board -> bytes -> hdrd -> heading with a real AVR simulator: the firmware as
it would be flashed, the harness (firmware/sim) feeding its ADC from the analog waveform of a
simulated drive, and hdrd decoding the UART's bytes with the configuration docs/firmware.md
gives. Skipped, naming what is missing, only where the AVR toolchain or simavr's library is
not installed (.ci/run installs gcc-avr avr-libc simavr libsimavr-dev).
"""

from __future__ import annotations

import ctypes.util
import importlib.util
import json
import math
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from hdrd.configload import load_config
from hdrd.core.angles import wrap180
from hdrd.core.sensor import SensorModel
from hdrd.io.wire.capture import decode_capture, encode_array
from hdrd.io.wire.codec import Frame, encode_bin, encode_text

ROOT = Path(__file__).resolve().parent.parent
FW = ROOT / "firmware"
SIM = FW / "sim"
DOC = ROOT / "docs" / "firmware.md"

F_CPU = 16_000_000
FRAME_US = 10_000  # 100 Hz, the default build
SLOTS = 80  # conversion slots per frame: 64 of A0, 16 of A1 (every 5th)
SAMPLE_HOLD_CYCLES = 192  # the ADC samples 1.5 ADC clocks (128 CPU cycles each) after a start
NOISE_LSB = 0.5  # the harness's default converter noise, rms LSB
VCC = 5.0
LSB10_V = VCC / 1024  # one step of the 10-bit converter at the input, V
LOG_DTYPE = np.dtype([("cycle", "<u8"), ("chan", "<u2"), ("code", "<u2")])
WAIT = 60.0

FloatArray = npt.NDArray[np.float64]


# -- what is needed, and the skip when it is not there ----------------------------------------


def _compiles(cmd: list[str], source: str) -> bool:
    r = subprocess.run(cmd, input=source, capture_output=True, text=True, check=False)
    return r.returncode == 0


def missing_tools() -> str | None:
    """Why the firmware cannot be built and simulated here (None: it can)."""
    for exe, pkg in (
        ("make", "make"),
        ("cc", "gcc"),
        ("avr-gcc", "gcc-avr"),
        ("avr-objcopy", "binutils-avr"),
    ):
        if shutil.which(exe) is None:
            return f"{exe} is not installed (Debian package {pkg})"
    avr = ["avr-gcc", "-mmcu=atmega328p", "-fsyntax-only", "-x", "c", "-"]
    if not _compiles(avr, "#include <avr/io.h>\nint main(void) { return 0; }\n"):
        return "avr-libc is not installed (Debian package avr-libc)"
    host = ["cc", "-fsyntax-only", "-I/usr/include/simavr", "-x", "c", "-"]
    if not _compiles(host, "#include <sim_avr.h>\n#include <avr_adc.h>\n"):
        return "simavr's headers are not installed (Debian package libsimavr-dev)"
    if ctypes.util.find_library("simavr") is None:
        return "simavr's library is not installed (Debian packages libsimavr2, libsimavr-dev)"
    return None


_MISSING = missing_tools()
pytestmark = pytest.mark.skipif(_MISSING is not None, reason=f"firmware tests: {_MISSING}")


# -- building and running ---------------------------------------------------------------------


def make(directory: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["make", "-C", str(directory), *args],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )


@pytest.fixture(scope="module")
def builds(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    """build(**options) -> the firmware ELF built with -Werror and those Makefile options."""
    root = tmp_path_factory.mktemp("fw")
    made: dict[tuple[tuple[str, str], ...], Path] = {}

    def build(**options: str) -> Path:
        key = tuple(sorted(options.items()))
        if key not in made:
            out = root / f"b{len(made)}"
            r = make(FW, f"BUILD={out}", "WERROR=1", *(f"{k}={v}" for k, v in key))
            assert r.returncode == 0, r.stdout + r.stderr
            made[key] = out / "hdrd-adc.elf"
        return made[key]

    return build


@pytest.fixture(scope="module")
def harness(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    r = make(SIM, f"BUILD={out}", "WERROR=1")
    assert r.returncode == 0, r.stdout + r.stderr
    return out / "hdrd-adc-sim"


def _load_wave_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("hdrd_fw_wave", SIM / "wave.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


wave_mod = _load_wave_module()
Wave = tuple[FloatArray, FloatArray, FloatArray]


def documented_config(tmp_path: Path) -> tuple[Path, SensorModel]:
    """The ```yaml block of docs/firmware.md, written to a file, and its sensor model."""
    blocks = re.findall(r"```yaml\n(.*?)```", DOC.read_text(), re.S)
    (block,) = [b for b in blocks if "sensor:" in b]
    path = tmp_path / "hdrd-adc.yaml"
    path.write_text(block)
    cfg, _ = load_config(path)
    return path, cfg.sensor


def simulate(
    harness: Path,
    elf: Path,
    wave_csv: Path,
    out: Path,
    *args: str,
    adc_log: Path | None = None,
) -> str:
    """Run the firmware on the waveform; the harness's summary line (stderr)."""
    cmd = [str(harness), "--firmware", str(elf), str(wave_csv), str(out), *args]
    if adc_log is not None:
        cmd += ["--adc-log", str(adc_log)]
    r = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=600)
    assert r.returncode == 0, r.stderr
    return r.stderr


def replay(capture: Path, config: Path, *args: str) -> list[dict[str, Any]]:
    """`hdrd replay` of the capture: static bias 0, no drift reduction, so its heading is the
    plain integral of the decoded rate (paper Eqs. 3, 11)."""
    r = subprocess.run(
        [sys.executable, "-m", "hdrd", "replay", str(capture), "--config", str(config)]
        + ["--bias", "0", "--method", "none", *args],
        capture_output=True,
        text=True,
        check=False,
        timeout=WAIT,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr
    return [json.loads(line) for line in r.stdout.splitlines()]


# -- what the ADC should have produced --------------------------------------------------------


def frame_slots(
    log: npt.NDArray[np.void], n_frames: int, per_frame: int = SLOTS
) -> npt.NDArray[np.void]:
    """The conversion log cut into frames: (n_frames, per_frame), 80 conversions (64 without
    the supply monitor, whose slots then stay idle). The first conversion is the one the
    firmware makes at start-up and throws away (the ADC's longer first conversion)."""
    slots = log[1 : 1 + per_frame * n_frames]
    assert slots.shape[0] == per_frame * n_frames, "fewer conversions than frames"
    return slots.reshape(n_frames, per_frame)


def sums_from_log(cc: npt.NDArray[np.void]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """(rate, ref) each frame must carry: the sum of its A0 codes, 4 x the sum of its A1 codes."""
    codes = cc["code"].astype(np.int64)
    rate = np.where(cc["chan"] == 0, codes, 0).sum(axis=1)
    ref = 4 * np.where(cc["chan"] == 1, codes, 0).sum(axis=1)
    return rate, ref


def window_starts(cc: npt.NDArray[np.void]) -> FloatArray:
    """Simulated time (s) at which each frame's first sample is taken: its 10 ms begin."""
    return (cc["cycle"][:, 0].astype(np.float64) + SAMPLE_HOLD_CYCLES) / F_CPU


def mean_rate(wave: Wave, starts: FloatArray, length_s: float, sensor: SensorModel) -> FloatArray:
    """The waveform's yaw rate averaged over [start, start + length_s), deg/s (midpoints of
    200 sub-intervals: the waveform is piecewise linear, far smoother than that)."""
    sub = (np.arange(200) + 0.5) / 200 * length_s
    out = np.empty(starts.shape[0])
    for i in range(0, starts.shape[0], 4096):
        s = starts[i : i + 4096]
        out[i : i + 4096] = wave_mod.rate_at(s[:, None] + sub[None, :], wave, sensor).mean(axis=1)
    return out


def integral(wave: Wave, t0: float, t1: float, sensor: SensorModel) -> float:
    """Integral of the waveform's yaw rate over [t0, t1], deg (0.1 ms midpoint rule)."""
    n = int(round((t1 - t0) / 1e-4))
    total = 0.0
    for a in range(0, n, 1_000_000):
        k = np.arange(a, min(n, a + 1_000_000))
        total += float(wave_mod.rate_at(t0 + (k + 0.5) * 1e-4, wave, sensor).sum())
    return total * 1e-4


def frame_sigma_dps(
    v: FloatArray, vs: FloatArray, sensor: SensorModel, ref_wired: bool
) -> FloatArray:
    """The rms error of one frame's decoded rate that the converter noise predicts, deg/s.

    Each conversion errs by the noise (NOISE_LSB rms) plus rounding (1/12 LSB^2); 64 of them
    average the rate, 16 the supply. The supply's error moves the ratiometric correction k
    (= ref volts * 2 / 5): omega = (V/k - null) / scale, so d omega / dk = -V / (scale k^2).
    """
    per_conversion = math.sqrt(NOISE_LSB**2 + 1 / 12)
    k = vs / sensor.supply_nominal_v
    if not ref_wired:  # the reference is the supply itself: decoded volts = V * 5 / Vs
        return (
            per_conversion / 8 * (sensor.vref_v / 1024) / sensor.scale_v_per_dps * np.ones_like(v)
        )
    rate = per_conversion / 8 * LSB10_V / (sensor.scale_v_per_dps * k)
    dk = per_conversion / 4 * LSB10_V * sensor.ref_divider / sensor.supply_nominal_v
    ref = v / (sensor.scale_v_per_dps * k**2) * dk
    return np.sqrt(rate**2 + ref**2)


# A rounding quantiser with Gaussian noise of sigma LSB is biased by at most
# (1/pi) exp(-2 pi^2 sigma^2) LSB (the first term of its error's Fourier series): the residual
# systematic error oversampling leaves. In deg/s per frame, each channel scaled as in
# frame_sigma_dps.
DITHER_BIAS_LSB = math.exp(-2 * math.pi**2 * NOISE_LSB**2) / math.pi


def dither_bias_dps(
    v: FloatArray, vs: FloatArray, sensor: SensorModel, ref_wired: bool
) -> FloatArray:
    k = vs / sensor.supply_nominal_v
    if not ref_wired:
        return DITHER_BIAS_LSB * (sensor.vref_v / 1024) / sensor.scale_v_per_dps * np.ones_like(v)
    rate = DITHER_BIAS_LSB * LSB10_V / (sensor.scale_v_per_dps * k)
    dk = DITHER_BIAS_LSB * LSB10_V * sensor.ref_divider / sensor.supply_nominal_v
    return rate + v / (sensor.scale_v_per_dps * k**2) * dk


# -- the 10-minute drive: one simulation, several checks --------------------------------------


@dataclass
class BoardRun:
    wave: Wave
    capture: bytes
    frames: npt.NDArray[np.void]
    stats: Any
    slots: npt.NDArray[np.void]
    sensor: SensorModel
    messages: list[dict[str, Any]]
    summary: str


def run_board(
    tmp: Path,
    harness: Path,
    elf: Path,
    wave: Wave,
    *args: str,
    protocol: str = "hdr-bin",
    ref_wired: bool = True,
) -> BoardRun:
    csv = tmp / "wave.csv"
    wave_mod.write_wave(str(csv), *wave)
    cap, log = tmp / "board.bin", tmp / "adc.log"
    summary = simulate(harness, elf, csv, cap, *args, adc_log=log)
    config, sensor = documented_config(tmp)
    data = cap.read_bytes()
    frames, stats = decode_capture(data, protocol)
    per_frame = SLOTS if ref_wired else SLOTS * 4 // 5
    slots = frame_slots(np.fromfile(log, dtype=LOG_DTYPE), frames.shape[0], per_frame)
    messages = replay(cap, config, "--protocol", protocol)
    return BoardRun(wave, data, frames, stats, slots, sensor, messages, summary)


DRIVE_MINUTES = 9.5  # + hdrd's 30 s standstill lead-in: 10 simulated minutes


@pytest.fixture(scope="module")
def drive(
    tmp_path_factory: pytest.TempPathFactory, builds: Callable[..., Path], harness: Path
) -> BoardRun:
    """The default build (hdr-bin, 100 Hz, supply monitor) on 10 minutes of a city drive from
    hdrd's gyro model, its own 5 V supply wandering inside 4.75 .. 5.25 V (wiring B)."""
    wave = wave_mod.drive_wave("city", DRIVE_MINUTES, seed=7, hz=100.0)
    return run_board(tmp_path_factory.mktemp("drive"), harness, builds(), wave)


@pytest.mark.slow
def test_ten_minutes_of_frames_decode_without_crc_errors_or_losses(drive: BoardRun) -> None:
    st, n = drive.stats, drive.frames.shape[0]
    assert n >= 10 * 60 * 100 - 5
    assert st.bad_frames == 0
    # The run stops on a cycle count: at most one frame is cut short at the very end.
    assert st.garbage_bytes == len(drive.capture) - 16 * n < 16
    assert drive.capture[: 16 * n] == encode_array(drive.frames)  # nothing but whole frames
    assert (st.seq_gaps, st.lost_frames, st.seq_repeats, st.seq_resets) == (0, 0, 0, 0)
    assert np.array_equal(drive.frames["seq"], np.arange(n) % 65536)
    assert np.all(drive.frames["temp"] == -32768)  # no temperature sensor


@pytest.mark.slow
def test_t_us_advances_at_the_frame_rate_locked_to_the_board_clock(drive: BoardRun) -> None:
    t_us = drive.frames["t_us"].astype(np.int64)
    # No jitter at all in the timestamps: exactly one frame period apart.
    assert np.all(np.diff(t_us) == FRAME_US)
    # ... and they are the board's time: a frame's first conversion starts at the simulator's
    # cycle count / 16 MHz, give or take the slot interrupt's latency (a few us), with no drift
    # over 10 minutes (one timer tick too many per slot would drift 2.4 s).
    started_us = drive.slots["cycle"][:, 0].astype(np.float64) / (F_CPU / 1e6)
    lag = (started_us - started_us[0]) - (t_us - t_us[0])
    assert -8.0 <= lag.min() and lag.max() <= 8.0, (lag.min(), lag.max())
    # The samples are spread evenly over the frame: one conversion per 125 us slot.
    gaps_us = np.diff(drive.slots["cycle"].astype(np.float64), axis=1) / (F_CPU / 1e6)
    assert np.all(np.abs(gaps_us - FRAME_US / SLOTS) <= 8.0)


@pytest.mark.slow
def test_every_frame_carries_the_sums_of_the_codes_its_adc_produced(drive: BoardRun) -> None:
    chans = drive.slots["chan"]
    pattern = np.where(np.arange(SLOTS) % 5 == 4, 1, 0)  # A0 A0 A0 A0 A1 ...
    assert np.all(chans == pattern[None, :])
    rate, ref = sums_from_log(drive.slots)
    assert np.array_equal(drive.frames["rate"], rate)
    assert np.array_equal(drive.frames["ref"], ref)


@pytest.mark.slow
def test_decoded_rate_is_within_one_lsb_of_the_waveform(drive: BoardRun) -> None:
    starts = window_starts(drive.slots)
    truth = mean_rate(drive.wave, starts, FRAME_US / 1e6, drive.sensor)
    decoded = drive.sensor.to_dps_array(drive.frames["rate"], drive.frames["ref"])
    err = decoded - truth
    lsb_dps = LSB10_V / drive.sensor.scale_v_per_dps  # 0.49 deg/s: the converter's step
    assert np.max(np.abs(err)) < lsb_dps
    # Oversampling at work: the rms error is what 64 + 16 noisy conversions predict (the
    # 10-bit step alone would give ~0.14 deg/s rms), and the mean error has no bias.
    t, v, vs = drive.wave
    sigma = frame_sigma_dps(np.interp(starts, t, v), np.interp(starts, t, vs), drive.sensor, True)
    predicted = float(np.sqrt(np.mean(sigma**2)))
    rms = float(np.sqrt(np.mean(err**2)))
    assert 0.85 * predicted < rms < 1.15 * predicted, (rms, predicted)
    bias = dither_bias_dps(np.interp(starts, t, v), np.interp(starts, t, vs), drive.sensor, True)
    assert abs(err.mean()) < 5 * predicted / math.sqrt(err.size) + float(bias.mean())


def _check_heading(run: BoardRun, ref_wired: bool) -> float:
    """hdrd's heading after its last full step against the waveform's; returns the tolerance
    (deg) it was held to."""
    full = [m for m in run.messages if m["samples"] == 100]
    assert len(full) >= len(run.messages) - 1  # only the last step may be partial
    steps = len(full)
    assert [m["step"] for m in full] == list(range(steps))
    starts = window_starts(run.slots)
    t0 = float(starts[0])
    # Lossless: hdrd's yaw is the integral of exactly the frames the ADC's codes make.
    rate, ref = sums_from_log(run.slots)
    per_frame = run.sensor.to_dps_array(rate, ref)[: 100 * steps]
    assert full[-1]["yaw"] == pytest.approx(
        per_frame.reshape(steps, 100).mean(axis=1).sum(), abs=1e-9
    )
    # Each step's rate is the waveform's over that second, within the ADC's noise.
    step_truth = mean_rate(run.wave, t0 + np.arange(steps, dtype=np.float64), 1.0, run.sensor)
    t, v, vs = run.wave
    at = (np.interp(starts, t, v), np.interp(starts, t, vs))
    sigma = frame_sigma_dps(*at, run.sensor, ref_wired)
    sigma_step = float(np.sqrt(np.mean(sigma**2))) / 10  # 100 frames per step
    bias_frames = dither_bias_dps(*at, run.sensor, ref_wired)
    step_err = np.array([m["omega"] for m in full]) - step_truth
    assert np.max(np.abs(step_err)) < 5 * sigma_step + float(bias_frames.max())
    # The heading equals the waveform's integral: within 4 sigma of the random walk the ADC's
    # noise makes, plus the dither bias bound over the run.
    truth_yaw = integral(run.wave, t0, t0 + steps, run.sensor)
    truth_heading = (0.0 - truth_yaw) % 360.0  # heading0 0 (compass: clockwise)
    diff = wrap180(full[-1]["heading"] - truth_heading)
    tolerance = 4 * sigma_step * math.sqrt(steps) + float(bias_frames.mean()) * steps
    assert abs(diff) < tolerance, (diff, tolerance)
    return tolerance


@pytest.mark.slow
def test_heading_from_hdrd_replay_equals_the_integral_of_the_waveform(drive: BoardRun) -> None:
    tolerance = _check_heading(drive, ref_wired=True)
    # The drive turns (and the gyro's bias runs) through hundreds of degrees, so the tolerance
    # is under 1 % of the heading change: a 1 % error of clock or scale would not pass.
    assert tolerance < 0.01 * abs(drive.messages[-1]["yaw"])


# -- other builds and wirings -----------------------------------------------------------------


def short_wave(seconds: float, seed: int = 3) -> Wave:
    """30 s of standstill, then `seconds` of hdrd's mixed drive; the supply wandering."""
    wave: Wave = wave_mod.drive_wave("mixed", seconds / 60.0, seed=seed, hz=100.0)
    return wave


@pytest.mark.slow
def test_hdr_text_build(tmp_path: Path, builds: Callable[..., Path], harness: Path) -> None:
    run = run_board(
        tmp_path,
        harness,
        builds(PROTOCOL="text"),
        short_wave(30.0),
        "--seconds",
        "40",
        protocol="hdr-text",
    )
    st, n = run.stats, run.frames.shape[0]
    assert n >= 3995 and st.bad_frames == 0 and st.lost_frames == 0
    lines = run.capture.split(b"\r\n")
    assert lines[0].startswith(b"$HDRG,0,0,")
    assert all(re.fullmatch(rb"\$HDRG,\d+,\d+,\d+,\d+,\*[0-9A-F]{2}", x) for x in lines[:-1])
    rate, ref = sums_from_log(run.slots)
    assert np.array_equal(run.frames["rate"], rate) and np.array_equal(run.frames["ref"], ref)
    assert np.all(np.diff(run.frames["t_us"].astype(np.int64)) == FRAME_US)
    _check_heading(run, ref_wired=True)


@pytest.mark.slow
def test_wiring_a_gyro_on_the_boards_own_5v_is_ratiometric_by_construction(
    tmp_path: Path, builds: Callable[..., Path], harness: Path
) -> None:
    """REF=0 and the gyro on the board's 5 V, which is also the ADC's reference: the supply
    wanders and nothing corrects it, yet the decoded rate is right (ref = 0: hdrd's k = 1)."""
    run = run_board(
        tmp_path,
        harness,
        builds(REF="0"),
        short_wave(60.0),
        "--vcc",
        "supply",
        "--seconds",
        "70",
        ref_wired=False,
    )
    assert run.stats.bad_frames == 0 and np.all(run.frames["ref"] == 0)
    assert np.all(run.slots["chan"] == 0)  # no conversion of A1 at all
    assert np.ptp(run.wave[2]) > 0.2  # the supply did wander
    starts = window_starts(run.slots)
    truth = mean_rate(run.wave, starts, FRAME_US / 1e6, run.sensor)
    err = run.sensor.to_dps_array(run.frames["rate"], run.frames["ref"]) - truth
    assert np.max(np.abs(err)) < LSB10_V / run.sensor.scale_v_per_dps
    t, v, vs = run.wave
    sigma = frame_sigma_dps(np.interp(starts, t, v), np.interp(starts, t, vs), run.sensor, False)
    assert float(np.sqrt(np.mean(err**2))) < 1.15 * float(np.sqrt(np.mean(sigma**2)))
    _check_heading(run, ref_wired=False)


@pytest.mark.slow
def test_clock_and_seq_wrap_as_the_protocol_says(
    tmp_path: Path, builds: Callable[..., Path], harness: Path
) -> None:
    """Started 2 s before the 32-bit clock wraps and 100 frames before seq does."""
    t0, seq0 = 2**32 - 2_000_000, 65536 - 100
    elf = builds(T0_US=f"{t0}UL", SEQ0=f"{seq0}U")
    run = run_board(tmp_path, harness, elf, short_wave(10.0), "--seconds", "8")
    st, f = run.stats, run.frames
    assert int(f["t_us"][0]) == t0 and int(f["seq"][0]) == seq0
    assert st.clock_wraps == 1 and st.bad_frames == 0
    assert (st.seq_gaps, st.lost_frames, st.seq_resets, st.seq_clock_mismatch) == (0, 0, 0, 0)
    assert np.all(np.mod(np.diff(f["t_us"].astype(np.int64)), 2**32) == FRAME_US)
    assert np.all(np.mod(np.diff(f["seq"].astype(np.int64)), 65536) == 1)
    # hdrd unwraps it: its steps run on, one second apart, across the wrap.
    full = [m for m in run.messages if m["samples"] == 100]
    assert [m["t"] for m in full] == [float(i + 1) for i in range(len(full))]
    assert len(full) >= 7
    _check_heading(run, ref_wired=True)


@pytest.mark.slow
def test_live_daemon_on_the_harness_pty_publishes_what_replay_does(
    tmp_path: Path, builds: Callable[..., Path], harness: Path
) -> None:
    """`hdrd run --port` on the pty the harness writes the UART to: the same steps, bit for bit,
    as `hdrd replay` of the bytes the board sent."""
    csv, cap, link = tmp_path / "wave.csv", tmp_path / "board.bin", tmp_path / "gyro"
    wave_mod.write_wave(str(csv), *short_wave(20.0))
    config, _ = documented_config(tmp_path)
    env = dict(os.environ, STATE_DIRECTORY=str(tmp_path / "state"))
    env.pop("NOTIFY_SOCKET", None)
    sim = subprocess.Popen(
        [str(harness), "--firmware", str(builds()), str(csv), str(cap), "--pty", str(link)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    daemon: subprocess.Popen[str] | None = None
    try:
        assert sim.stdout is not None
        sim.stdout.readline()  # the pty is open (it prints the slave's name)
        assert link.is_symlink()
        daemon = subprocess.Popen(
            [sys.executable, "-m", "hdrd", "run", "--port", str(link), "--config", str(config)]
            + ["--bias", "0", "--method", "none", "--stdout", "--log-format", "json"]
            # simavr keeps the board's time, not the wall clock's: no wall-clock check
            + ["--clock-rate", "0"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            cwd=ROOT,
        )
        _, err = sim.communicate(timeout=WAIT)
        assert sim.returncode == 0, err
        expected = [m for m in replay(cap, config) if m["samples"] == 100]
        live = list(_read_steps(daemon, len(expected)))
    finally:
        for p in (sim, daemon):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGTERM)
                p.communicate(timeout=WAIT)
    assert len(expected) >= 49
    assert [{k: v for k, v in m.items() if k != "time"} for m in live] == expected


def _read_steps(daemon: subprocess.Popen[str], count: int) -> Iterator[dict[str, Any]]:
    """The daemon's first `count` step messages (stale reports skipped), read with a deadline."""
    lines: queue.Queue[str] = queue.Queue()
    stdout = daemon.stdout
    assert stdout is not None

    def pump() -> None:
        for line in stdout:
            lines.put(line)

    threading.Thread(target=pump, daemon=True).start()
    deadline = time.monotonic() + WAIT
    got = 0
    while got < count:
        try:
            line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            raise AssertionError(f"the daemon published {got} of {count} steps") from None
        msg = json.loads(line)
        if msg.get("status") == "stale":
            continue
        got += 1
        yield msg


# -- the build, the encoder, the harness's input checks ---------------------------------------


@pytest.mark.parametrize(
    "options",
    [[], ["PROTOCOL=text"], ["RATE_HZ=10", "REF=0"], ["F_CPU=8000000UL", "BAUD=57600"]],
    ids=["default", "text", "10Hz-noref", "8MHz"],
)
def test_build_is_warning_free_and_fits_beside_the_bootloader(
    tmp_path: Path, options: list[str]
) -> None:
    r = make(FW, f"BUILD={tmp_path}", *options)  # without -Werror: see every warning
    out = r.stdout + r.stderr
    assert r.returncode == 0, out
    assert not re.search(r"warning:|#warning", out, re.I), out  # gcc's and setbaud.h's
    assert "-Wall" in out and "-Wextra" in out
    m = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S+hdrd-adc\.elf$", out, re.M)
    assert m, out
    text, data, bss = (int(x) for x in m.groups())
    assert text + data <= 32 * 1024 - 512  # flash left by the Uno's 512-byte bootloader
    assert data + bss <= 512  # RAM: the 2 kB chip keeps most of it for the stack
    assert (tmp_path / "hdrd-adc.hex").read_text().startswith(":")


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["RATE_HZ=200"], "RATE_HZ too high"),
        (["RATE_HZ=7"], "RATE_HZ must divide"),
        (["PROTOCOL=json"], "PROTOCOL must be bin or text"),
        (["BAUD=9600", "PROTOCOL=text"], "BAUD too low for hdr-text"),
        (["F_CPU=8000000UL"], "cannot make that speed"),  # 115200 from 8 MHz is 3.5 % off
    ],
)
def test_impossible_options_do_not_build(tmp_path: Path, options: list[str], message: str) -> None:
    r = make(FW, f"BUILD={tmp_path}", *options)
    assert r.returncode != 0 and message in r.stdout + r.stderr


ENCODE_DRIVER = r"""
#include <stdio.h>
#include "frame.h"
int main(void) {
    unsigned long seq, t, rate, ref; long temp;
    while (scanf("%lu %lu %lu %lu %ld", &seq, &t, &rate, &ref, &temp) == 5) {
        hdr_sample_t s = {(uint16_t)seq, (uint32_t)t, (uint16_t)rate, (uint16_t)ref,
                          (int16_t)temp};
        uint8_t bin[HDR_BIN_LEN];
        char text[HDR_TEXT_MAX];
        uint8_t nb = hdr_encode_bin(&s, bin), nt = hdr_encode_text(&s, text);
        for (uint8_t i = 0; i < nb; i++) printf("%02x", bin[i]);
        printf(" ");
        for (uint8_t i = 0; i < nt; i++) printf("%02x", (unsigned char)text[i]);
        printf("\n");
    }
    return 0;
}
"""


def test_the_firmwares_encoder_writes_what_hdrd_frames_writes(tmp_path: Path) -> None:
    """firmware/src/frame.c, compiled for the host, against hdrd.io.wire.codec on the protocol's
    worked examples, the field limits and random frames (temperature included, which the
    board itself does not send)."""
    driver = tmp_path / "driver.c"
    driver.write_text(ENCODE_DRIVER)
    exe = tmp_path / "encode"
    subprocess.run(
        [
            "cc",
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            f"-I{FW / 'src'}",
            "-o",
            str(exe),
            str(driver),
            str(FW / "src" / "frame.c"),
        ],
        check=True,
        capture_output=True,
    )
    rng = np.random.default_rng(5)
    samples = [
        (258, 1_000_000, 33554, 32768, 2512),  # docs/protocol.md's worked examples
        (259, 1_100_000, 31982, 0, -32768),
        (0, 0, 0, 0, 0),
        (65535, 2**32 - 1, 65535, 65535, 32767),
        (1, 1, 1, 1, -32767),
        (2, 3, 4, 5, -5),
    ]
    for _ in range(300):
        samples.append(
            (
                int(rng.integers(0, 65536)),
                int(rng.integers(0, 2**32)),
                int(rng.integers(0, 65536)),
                int(rng.integers(0, 65536)),
                int(rng.integers(-32768, 32768)),
            )
        )
    r = subprocess.run(
        [str(exe)],
        input="".join(" ".join(map(str, s)) + "\n" for s in samples),
        capture_output=True,
        text=True,
        check=True,
    )
    out = r.stdout.splitlines()
    assert len(out) == len(samples)
    for s, line in zip(samples, out):
        f = Frame(s[0], s[1], s[2], s[3], None if s[4] == -32768 else s[4])
        b, t = line.split()
        assert bytes.fromhex(b) == encode_bin(f), s
        assert bytes.fromhex(t) == encode_text(f), s
    assert out[0].split()[0] == "a55a020140420f0012830080d009ae8a"


def test_harness_rejects_a_bad_waveform_in_one_line(
    tmp_path: Path, builds: Callable[..., Path], harness: Path
) -> None:
    csv = tmp_path / "bad.csv"
    csv.write_text("t,rate_volts,supply_volts\n0,2.5,5\n0.01,2.5,5\n0.005,2.5,5\n")
    r = subprocess.run(
        [str(harness), "--firmware", str(builds()), str(csv), str(tmp_path / "o.bin")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 2
    assert r.stderr.strip() == f"hdrd-adc-sim: {csv}:4: t must increase and values be finite"


def test_sim_run_script_builds_and_runs_the_default_firmware(tmp_path: Path) -> None:
    """The documented interface: firmware/sim/run WAVE.csv OUT.bin --seconds N."""
    csv, out = tmp_path / "wave.csv", tmp_path / "out.bin"
    t = np.arange(0, 3.001, 0.01)
    wave_mod.write_wave(str(csv), t, np.full_like(t, 2.5), np.full_like(t, 5.0))
    env = dict(os.environ, MAKEFLAGS="")
    r = subprocess.run(
        [str(SIM / "run"), str(csv), str(out), "--seconds", "2"],
        capture_output=True,
        text=True,
        check=False,
        env=env,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    frames, st = decode_capture(out.read_bytes())
    assert st.bad_frames == 0 and 195 <= frames.shape[0] <= 200
    # 2.5 V on A0 and 2.5 V on A1 (5 V through the divider): mid-scale, +-noise.
    assert np.all(np.abs(frames["rate"].astype(np.int64) - 32768) < 64)
    assert np.all(np.abs(frames["ref"].astype(np.int64) - 32768) < 128)
    assert "2.000 s simulated" in r.stderr
