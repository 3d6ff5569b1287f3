#!/usr/bin/env python3
"""The USB ADC in simavr: 10 simulated minutes of the firmware on a drive, timed and measured.

    python bench/firmware.py [--repeats 3] [--minutes 9.5] [--workdir /tmp/hdrd-bench-fw]
                             [--no-write]

Takes about a minute. Builds the firmware (firmware/, default options: hdr-bin at 100 Hz with
the supply monitor; and REF=0) and the simavr harness (firmware/sim), writes the waveform
tests/test_firmware.py uses (hdrd's city drive, seed 7, through hdrd's CRS03-04-like gyro
model, 30 s standstill + 9.5 min, its own 5 V supply wandering inside 4.75 .. 5.25 V), and:

- times the harness on it (wall from spawn to exit, best and median of the runs, and the
  child's CPU time; multiple of real time), with and without the per-conversion ADC log;
- measures what the board sent, as the test checks it: frames, CRC errors, lost frames, the
  t_us step and its lag behind the simulator's clock, the decoded rate against the waveform
  per frame and per 1 s step (`hdrd replay --bias 0 --method none` with docs/firmware.md's
  configuration), the heading error after the run; the same for wiring A (the gyro on the
  board's 5 V, which is the ADC's reference, REF=0).

Nothing is tuned here: the converter noise (0.5 LSB rms) is the harness's default, an
assumption about the real chip, not fitted to any data. Prints the figures and
writes its section of bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import argparse
import math
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import REPO, machine_line, time_process, write_section

from tests import test_firmware as tf  # the test's own checks, so bench and test agree

SEED = 7


def build(workdir: Path, name: str, *options: str) -> Path:
    out = workdir / name
    r = tf.make(tf.FW, f"BUILD={out}", "WERROR=1", *options)
    if r.returncode:
        raise SystemExit(r.stdout + r.stderr)
    return out / "hdrd-adc.elf"


def measure(run: tf.BoardRun, ref_wired: bool) -> dict[str, Any]:
    """The test's quantities, as numbers."""
    f, st, sensor = run.frames, run.stats, run.sensor
    t_us = f["t_us"].astype(np.int64)
    started = run.slots["cycle"][:, 0].astype(np.float64) / (tf.F_CPU / 1e6)
    lag = (started - started[0]) - (t_us - t_us[0])
    starts = tf.window_starts(run.slots)
    truth = tf.mean_rate(run.wave, starts, tf.FRAME_US / 1e6, sensor)
    err = sensor.to_dps_array(f["rate"], f["ref"]) - truth
    t, v, vs = run.wave
    sigma = tf.frame_sigma_dps(np.interp(starts, t, v), np.interp(starts, t, vs), sensor, ref_wired)
    full = [m for m in run.messages if m["samples"] == 100]
    steps = len(full)
    step_truth = tf.mean_rate(run.wave, starts[0] + np.arange(steps, dtype=np.float64), 1.0, sensor)
    step_err = np.array([m["omega"] for m in full]) - step_truth
    truth_yaw = tf.integral(run.wave, float(starts[0]), float(starts[0]) + steps, sensor)
    rate_sums, ref_sums = tf.sums_from_log(run.slots)
    return {
        "frames": int(f.shape[0]),
        "bad": int(st.bad_frames),
        "lost": int(st.lost_frames),
        "dt_us": sorted({int(x) for x in np.diff(t_us)}),
        "lag_us": (float(lag.min()), float(lag.max())),
        "sums_equal": bool(
            np.array_equal(f["rate"], rate_sums) and np.array_equal(f["ref"], ref_sums)
        ),
        "err_max": float(np.max(np.abs(err))),
        "err_rms": float(np.sqrt(np.mean(err**2))),
        "err_mean": float(err.mean()),
        "predicted_rms": float(np.sqrt(np.mean(sigma**2))),
        "step_rms": float(np.sqrt(np.mean(step_err**2))),
        "step_max": float(np.max(np.abs(step_err))),
        "steps": steps,
        "yaw": float(full[-1]["yaw"]),
        "yaw_err": float(full[-1]["yaw"]) - truth_yaw,
    }


def _speed_lines(repeats: int, header: str, sim_s: float, timings: dict[str, Any]) -> list[str]:
    """How fast the harness ran the default build: simulated time / wall time and CPU time."""
    lines = [
        f"`python bench/firmware.py --repeats {repeats}` on {header}.",
        "",
        f"The default build (hdr-bin, 100 Hz, supply monitor) in simavr {_simavr_version()} on "
        f"{sim_s / 60:.1f} simulated minutes (hdrd's city drive, seed {SEED}, through its "
        "CRS03-04-like gyro model; 0.5 LSB rms converter noise). Harness wall time from spawn "
        "to exit, best and median of the runs, the child's CPU time, and simulated time / wall "
        "time (from the best wall time, and from the CPU time, which moves less with the "
        "machine's load):",
        "",
        "| run | best wall | median wall | CPU | x real time (wall) | x real time (CPU) |",
        "|---|---|---|---|---|---|",
    ]
    for label, tm in timings.items():
        lines.append(
            f"| {label} | {tm.best_wall:.2f} s | {statistics.median(tm.wall):.2f} s | "
            f"{tm.best_cpu:.2f} s | {sim_s / tm.best_wall:.0f}x | {sim_s / tm.best_cpu:.0f}x |"
        )
    return lines


def _board_lines(mb: dict[str, Any], ma: dict[str, Any]) -> list[str]:
    """What the board sent, wiring B beside wiring A, against the waveform."""
    lines: list[str] = []
    lines += [
        "",
        "What the board sent, decoded with docs/firmware.md's configuration (`hdrd replay "
        "--bias 0 --method none`: the heading is the plain integral of the decoded rate). "
        "Wiring B: the gyro on its own supply, wandering inside 4.75 .. 5.25 V, corrected "
        "through A1; wiring A: the gyro on the board's 5 V, which is also the ADC's reference "
        "and wanders the same way, `REF=0`. Errors against the waveform: per frame (10 ms), "
        "per hdrd step (1 s), and hdrd's yaw after its last full step against the waveform's "
        "integral.",
        "",
        "| | wiring B (default build) | wiring A (`REF=0`, `--vcc supply`) |",
        "|---|---|---|",
    ]

    def row(name: str, fmt: Any) -> None:
        lines.append(f"| {name} | {fmt(mb)} | {fmt(ma)} |")

    row("frames (CRC errors, lost)", lambda m: f"{m['frames']:,} ({m['bad']}, {m['lost']})")
    row("t_us step (all frames)", lambda m: ", ".join(f"{x} us" for x in m["dt_us"]))
    row(
        "first conversion's lag behind t_us (min .. max, vs the simulator's clock)",
        lambda m: f"{m['lag_us'][0]:.2f} .. {m['lag_us'][1]:.2f} us",
    )
    row("rate/ref fields = sums of the ADC's codes", lambda m: "all" if m["sums_equal"] else "NO")
    row("frame error, max (1 LSB = 0.488 deg/s)", lambda m: f"{m['err_max']:.3f} deg/s")
    row(
        "frame error, rms (predicted by the noise model)",
        lambda m: f"{m['err_rms']:.4f} ({m['predicted_rms']:.4f}) deg/s",
    )
    row("frame error, mean", lambda m: f"{m['err_mean']:+.5f} deg/s")
    row(
        "1 s step error, rms / max",
        lambda m: f"{m['step_rms']:.4f} / {m['step_max']:.4f} deg/s",
    )
    row(
        "yaw after the run (error vs the waveform)",
        lambda m: f"{m['yaw']:.2f} deg after {m['steps']} s ({m['yaw_err']:+.3f} deg)",
    )
    return lines


def _noise_lines(mb: dict[str, Any]) -> list[str]:
    """The ADC's noise as an angle random walk (wiring B), and what is assumed."""
    lines: list[str] = []
    arw = mb["predicted_rms"] * math.sqrt(tf.FRAME_US / 1e6)
    lines += [
        "",
        f"The ADC's noise as an angle random walk (wiring B): {arw:.4f} deg/sqrt(s) = "
        f"{arw * 60:.2f} deg/sqrt(h), beside the CRS03-04's own ~3 deg/sqrt(h). The heading "
        "errors are one draw of that random walk (about "
        f"{arw * math.sqrt(mb['steps']):.2f} deg rms over {mb['steps']} s).",
        "",
        "Nothing here is tuned. The converter noise (0.5 LSB rms) is the harness's default, an "
        "assumption about the real chip; the tolerances of tests/test_firmware.py come from "
        "the same noise model (4 to 5 sigma, plus the dither bias bound), not from these "
        "figures.",
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--minutes", type=float, default=tf.DRIVE_MINUTES, help="after the 30 s lead-in"
    )
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/hdrd-bench-fw"))
    ap.add_argument("--no-write", action="store_true", help="print only; do not write RESULTS.md")
    a = ap.parse_args(argv)
    if tf._MISSING:
        raise SystemExit(f"bench/firmware.py: {tf._MISSING}")
    header = machine_line()
    w = a.workdir
    w.mkdir(parents=True, exist_ok=True)
    default_elf, noref_elf = build(w, "fw"), build(w, "fw-noref", "REF=0")
    r = tf.make(tf.SIM, f"BUILD={w / 'sim'}", "WERROR=1")
    if r.returncode:
        raise SystemExit(r.stdout + r.stderr)
    harness = w / "sim" / "hdrd-adc-sim"
    wave = tf.wave_mod.drive_wave("city", a.minutes, seed=SEED, hz=100.0)
    csv = w / "wave.csv"
    tf.wave_mod.write_wave(str(csv), *wave)
    sim_s = float(wave[0][-1])

    timings = {}
    for label, extra in (
        ("capture only", []),
        ("capture + ADC log", ["--adc-log", str(w / "t.log")]),
    ):
        cmd = [str(harness), "--firmware", str(default_elf), str(csv), str(w / "t.bin"), *extra]
        timings[label] = time_process(cmd, a.repeats)

    b_dir, a_dir = w / "wiring-b", w / "wiring-a"
    b_dir.mkdir(exist_ok=True)
    a_dir.mkdir(exist_ok=True)
    run_b = tf.run_board(b_dir, harness, default_elf, wave)
    run_a = tf.run_board(a_dir, harness, noref_elf, wave, "--vcc", "supply", ref_wired=False)
    mb, ma = measure(run_b, True), measure(run_a, False)

    lines = _speed_lines(a.repeats, header, sim_s, timings)
    lines += _board_lines(mb, ma) + _noise_lines(mb)
    text = "\n".join(lines) + "\n"
    print(text)
    title = "The USB ADC in simavr: speed, and what the board sends"
    write_section("speed", title, text, write=not a.no_write)
    return 0


def _simavr_version() -> str:
    r = subprocess.run(
        ["dpkg-query", "-W", "-f", "${Version}", "libsimavr-dev"],
        capture_output=True,
        text=True,
        check=False,
        cwd=REPO,
    )
    return r.stdout.strip() if r.returncode == 0 and r.stdout.strip() else "(version unknown)"


if __name__ == "__main__":
    sys.exit(main())
