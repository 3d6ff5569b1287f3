#!/usr/bin/env python3
"""What ``hdrd gap`` names on the real tuning drives, stops as truth: per drive the effects, their
figures and the gap before and after; the fitted effects as the distribution the simulator's
training routes draw their gyro from (``hdrd simulate --errors-from``).

    HDRD_REAL_DATA=/path/to/data python bench/gap_tuning.py [--workdir DIR] [--no-write]

1. As processes, the commands a user runs: bench/real.py's conversion of every real recording
   (``tools/convert_real.py``: ../shared/data or ``$HDRD_REAL_DATA``, and the public oan and
   psins drives where their clones are, docs/real-data.md), then ``python -m hdrd gap
   DRIVE... --report gap.json --out models/`` on the *tuning* drives only (bench/real.py's
   ``TUNING``: DrivePlotR odd drive numbers, comma2k19, the first two oan drives, psins; the
   judging drives are not run: nothing here may inform a choice made on them).
2. Per drive, from the report: the truth, the samples and blocks at rest (section 1 of
   docs/model-gap.md), each step's effect with its main figure, the gap initial -> final; the
   drives the workflow skips, with its reason.
3. ``hdrd simulate --benchmark train --errors-from gap.json``: which tuning drive each training
   route draws.
4. Rewrites its own section of bench/RESULTS.md (Model gap).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from _common import machine_line, put_section
from real import TUNING, convert_all

from hdrd.io.files.drivelog import read_drive

SECTION = "## Model gap on the real tuning drives: stops as truth, and their errors for training"
MAIN = {
    "static_bias": "bias_dps",
    "temperature_bias": "coeff_dps_per_c",
    "warmup_transient": "amplitude_dps",
    "motion_offset": "offset_dps",
    "scale_factor": "error",
    "time_offset": "delay_s",
    "quantization": "step_dps",
    "bias_instability": "sigma_dps",
    "rate_random_walk": "k_dps_per_sqrt_s",
    "white_noise": "density_dps_per_rthz",
    "bandwidth": "cutoff_hz",
    "saturation": "limit_dps",
}
"""The figure shown for each effect named."""


def run(cmd: list[str], shown: list[str]) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}  # this tree's hdrd
    shown.append(" ".join(["python", *cmd[1:]]) if cmd[0] == sys.executable else " ".join(cmd))
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env=env, check=False)


def steps_text(rep: dict[str, Any]) -> str:
    parts = []
    for s in rep["steps"]:
        key = MAIN.get(s["effect"])
        v = s["params"].get(key) if key else None
        parts.append(s["effect"] + (f" ({key} {v:.4g})" if v is not None else ""))
    rej = sorted({r["effect"] for r in rep["rejected"]} - {s["effect"] for s in rep["steps"]})
    out = " -> ".join(parts) or "nothing"
    return out + (f"; significant, not added: {', '.join(rej)}" if rej else "")


def row(rep: dict[str, Any]) -> str:
    log = rep["log"]
    truth = str(log["truth"]).split(" ")[0]
    mo = next((s for s in rep["steps"] if s["effect"] == "motion_offset"), None)
    cand = next((c for c in rep["remaining_candidates"] if c["effect"] == "motion_offset"), None)
    if mo is not None:
        motion = f"named, {mo['params']['offset_dps']:+.3f} (dBIC {mo['delta_bic']:+.0f})"
    elif "motion_offset" in rep["not_identifiable"]:
        motion = "not identifiable"
    elif cand is not None:
        motion = (
            f"{cand['params'].get('offset_dps', float('nan')):+.3f}, dBIC {cand['delta_bic']:+.1f}"
        )
    else:
        motion = "-"
    return (
        f"| {log['name']} | {log['duration_s'] / 60:.1f} | {log['rate_hz']:g} | {truth} | "
        f"{log['standing_samples']} / {log['blocks_at_rest']} of {log['blocks_used']} | "
        f"{steps_text(rep)} | {motion} | {rep['gap_initial']:.3g} -> {rep['gap_final']:.3g} "
        f"(sd {rep['gap_noise']['gap_final_sd']:.2g}) |"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/hdrd-gap-tuning"))
    ap.add_argument("--no-write", action="store_true", help="print, do not touch RESULTS.md")
    args = ap.parse_args(argv)
    machine = machine_line()
    shown: list[str] = []
    real = args.workdir / "real"
    real.mkdir(parents=True, exist_ok=True)
    convert_all(real, shown)
    drives = sorted(p for p in real.glob("*.csv") if p.stem in TUNING)
    report, models = args.workdir / "gap.json", args.workdir / "models"
    cmd = [sys.executable, "-m", "hdrd", "gap", *map(str, drives), "--report", str(report)]
    p = run([*cmd, "--out", str(models), "--no-progress"], shown)
    print(p.stdout, p.stderr, sep="\n", flush=True)
    if p.returncode != 0:
        return 1
    doc = json.loads(report.read_text())
    train = args.workdir / "train"
    q = run([sys.executable, "-m", "hdrd", "simulate", "--benchmark", "train", "--errors-from",
             str(report), "--out", str(train)], shown)  # fmt: skip
    if q.returncode != 0:
        print(q.stderr, file=sys.stderr)
        return 1
    drawn = []
    for f in sorted(train.glob("*.csv")):
        drawn.append(f"{f.stem} <- {read_drive(f).meta['gyro_errors_from'].split(' (')[0]}")
    lines = [
        SECTION,
        "",
        f"Generated by `python bench/gap_tuning.py` ({machine}); it ran, as a user does: "
        + "; ".join(f"`{c}`" for c in shown)
        + ". Tuning drives only (bench/real.py's `TUNING`); no judging drive was run.",
        "",
        "| drive | min | Hz | truth | samples / blocks at rest of used | `hdrd gap` names | motion offset, deg/s | gap initial -> final |",
        "|---|---|---|---|---|---|---|---|",
        *(row(r) for r in doc["drives"]),
        "",
        "Not analysed: " + ("; ".join(doc["skipped"]) or "none") + ".",
        "",
        "Training routes drawn from these drives' fitted models (`hdrd simulate --benchmark train "
        "--errors-from gap.json`): " + ", ".join(drawn) + ".",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.no_write:
        put_section("gap", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
