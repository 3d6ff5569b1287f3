#!/usr/bin/env python3
"""A unit's profile: HDR+ gyro-only with the error model ``hdrd gap --gyro-out`` learned on an
earlier drive of the same unit, against static bias removal and a fresh HDR+.

    python bench/unit_profile.py --set tune|judge [--units N] [--workdir /tmp/hdrd-holds]
                            [--json PATH] [--no-write]

Each case is an earlier drive and a later one of one unit:

- *real, earlier drive*: a real unit's earlier and later drive, where a set has two long
  enough (the oan IMU: judge, the longer of its two tuning drives -> ``oan_20201121_152755``;
  the tune set's second oan drive is 1.7 minutes, too short to score);
- *real, first part*: each real drive of the set (bench/real.py's split) cut at a standstill:
  the first stop of at least :data:`CUT_STOP_S` (the speed held between fixes) that starts
  after :data:`FIRST_PART_MIN_S` and leaves at least :data:`LATER_MIN_S` after it; the part up
  to the stop's end is the earlier drive, the part from the stop's start the later one (its
  start-up calibration on that stop);
- *units*: bench/units.py's population of the set (what real units were measured to do: motion
  offsets, stop scatter, a phone's wander, 0.573 deg/s codes); the earlier drive is a simulated
  drive of 20 minutes of the same unit (another road type, seed + :data:`EARLIER_SEED`), the
  later one the unit's drive of the set.

On each earlier drive the command a user runs, ``hdrd gap EARLIER.csv --gyro-out unit.yaml``,
as a process; then the later drive is scored as ``hdrd evaluate LATER.csv --method hdr+
--config unit.yaml`` scores it (the same calls in-process): Eψ of ``none`` (static bias
removal after the drive's own calibration), of ``hdr+`` with the default configuration (a
fresh unit) and of ``hdr+`` with the profile. Per group: mean NEψ (deg/min), none / profile,
and the drives the profile harms (Eψ above max(1.1 x none's, none's + 0.5 deg)); per drive,
what the profile names (motion offset and its sd, bias instability).

Profiles are kept in ``--workdir``/profiles-SET (made again when the earlier drive or the gap
code changed). ``--set tune`` prints only; ``--set judge`` rewrites its section of
bench/RESULTS.md (the judging set is run once, to report). Some 15 minutes a set on this
machine (each ``hdrd gap`` 10-40 s).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from _common import fmt, hdrd_command, machine_line, put_section
from holds import HARM_DEG, HARM_FACTOR, real_logs, route_log
from real import JUDGING, MIN_SCORED_MIN, PLUS, TUNING
from units import DRIVES, FIRST_SEED, Unit, draw_unit, unit_logs, unit_model

from hdrd.analysis.evaluate import EvaluationError, evaluate_prepared
from hdrd.analysis.prepare import prepare_drive
from hdrd.config import ConfigError, method_setup
from hdrd.configload import load_config
from hdrd.core.grades import Grade
from hdrd.io.files.drivelog import DriveLog, write_drive
from hdrd.sim.drive import simulate_drive

SECTION = "## A unit's profile: gyro-only with what gap learned on an earlier drive"
PAIRS = {"judge": (("oan_20201104_091730", "oan_20201104_093418"), "oan_20201121_152755")}
"""Per set: the earlier drives of one real unit (the longest is used) and its later drive."""
CUT_STOP_S = 10.0
"""A cut is made at a stop of at least this, s (a start-up calibration fits in it)."""
FIRST_PART_MIN_S = 360.0
"""The earlier part is at least this long, s."""
LATER_MIN_S = 360.0
"""The later part is at least this long, s."""
STILL_MPS = 0.3
"""At or below this speed, m/s, the vehicle stands."""
EARLIER_SEED = 100_000
"""A unit's earlier drive: its seed + this."""
METHODS = ("none", "hdr+", "hdr+ profile")


@dataclass
class Case:
    """One unit's earlier drive and later drive; Eψ (deg) per method on the later one."""

    name: str
    group: str
    earlier: DriveLog
    later: DriveLog
    unit: Unit | None = None
    profile: dict[str, float] = field(default_factory=dict)
    td_min: float = math.nan
    e: dict[str, float] = field(default_factory=dict)
    note: str = ""


# -- the cases -----------------------------------------------------------------------------------


def cut_at_stop(log: DriveLog) -> tuple[DriveLog, DriveLog] | None:
    """(earlier part, later part) of a drive cut at a standstill (module docstring); None
    without a stop to cut at."""
    if log.speed is None:
        return None
    t = log.t - log.t[0]
    speed = np.asarray(log.speed, dtype=float)
    known = np.flatnonzero(np.isfinite(speed))
    if known.shape[0] == 0:
        return None
    speed = speed[known[np.maximum(np.searchsorted(known, np.arange(len(speed)), "right") - 1, 0)]]
    still = np.concatenate(([False], speed <= STILL_MPS, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(still))
    stops = [(t[a], t[b - 1]) for a, b in zip(edges[0::2], edges[1::2], strict=True)]
    stops = [(a, b) for a, b in stops if b - a >= CUT_STOP_S]
    first = FIRST_PART_MIN_S
    for a, b in stops:
        if a >= first and log.duration_s - a >= LATER_MIN_S:
            head = log.slice(0, int(np.searchsorted(t, b, side="right")))
            tail = log.slice(int(np.searchsorted(t, a)))
            # the later part starts at the stop: that is its lead-in, not the drive's
            meta = {**tail.meta, "lead_in_s": repr(float(b - a))}
            later = replace(tail, name=f"{log.name}-later", meta=meta)
            return replace(head, name=f"{log.name}-first"), later
    return None


def real_cases(work: Path, which: str) -> list[Case]:
    """The set's real cases: its unit's earlier and later drive, each drive cut at a stop."""
    logs = {log.name: log for log in real_logs(work, which)}
    if which == "judge":  # the earlier drives of the judged unit are tuning drives
        logs |= {log.name: log for log in real_logs(work, "tune")}
    earlier_names, later_name = PAIRS.get(which, ((), ""))
    out = []
    earlier = [logs[n] for n in earlier_names if n in logs]
    if earlier and later_name in logs:
        e = max(earlier, key=lambda g: g.duration_s)
        out.append(Case(f"{e.name} -> {later_name}", "real, earlier drive", e, logs[later_name]))
    names = TUNING if which == "tune" else JUDGING
    for name in sorted(n for n in logs if n in names):
        parts = cut_at_stop(logs[name])
        if parts is not None:
            out.append(Case(name, "real, first part", *parts))
    return out


def unit_cases(work: Path, which: str, n: int) -> list[Case]:
    """The set's units (bench/units.py), each with an earlier simulated drive."""
    out = []
    for k, (u, later) in enumerate(unit_logs(which, n, route_log(work, which))):
        seed = FIRST_SEED[which] + k
        assert draw_unit(seed, k) == u
        drive = DRIVES[(k + 2) % len(DRIVES)]
        rate = Grade.from_table(u.grade).rate_hz
        early = simulate_drive(drive, 20.0, seed + EARLIER_SEED, hz=rate, model=unit_model(u, seed))
        if not u.temperature:
            early = replace(early, temp_c=None)
        early = replace(early, name=f"{later.name}-earlier")
        out.append(Case(later.name, f"unit: {u.kind}", early, later, unit=u))
    return out


# -- the profile ---------------------------------------------------------------------------------


def _gap_stamp() -> bytes:
    h = hashlib.sha256()
    for p in sorted((REPO / "hdrd").rglob("*.py")):
        if "gap" in p.parts or p.parent.name in ("sim", "core"):
            h.update(p.read_bytes())
    return h.digest()


def learn_profile(case: Case, folder: Path, stamp: bytes) -> Path | None:
    """``hdrd gap EARLIER.csv --gyro-out unit.yaml`` as a process (kept while the drive and the
    code are the same); the profile's path, None when gap could not fit the drive."""
    folder.mkdir(parents=True, exist_ok=True)
    log_path = folder / f"{case.earlier.name}.csv"
    write_drive(log_path, case.earlier)
    digest = hashlib.sha256(stamp + log_path.read_bytes()).hexdigest()
    out, mark = folder / f"{case.earlier.name}.unit.yaml", folder / f"{case.earlier.name}.stamp"
    if out.is_file() and mark.is_file() and mark.read_text() == digest:
        return out
    cmd = [*hdrd_command(), "gap", str(log_path), "--gyro-out", str(out), "--no-progress"]
    p = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if p.returncode != 0 or not out.is_file():
        case.note = "gap: " + (p.stderr.strip().splitlines() or ["no profile"])[-1][:120]
        return None
    mark.write_text(digest)
    return out


def score(case: Case, profile: Path | None) -> None:
    """Eψ of each method on the later drive, as ``hdrd evaluate --config`` computes them."""
    try:
        prep = prepare_drive(case.later)
    except EvaluationError as e:
        case.note = str(e).replace(f"{case.later.name}: ", "").split(";")[0]
        return
    if prep.duration_min < (MIN_SCORED_MIN if case.group.startswith("real") else 0.0):
        case.note = f"{prep.duration_min:.1f} min scored < {MIN_SCORED_MIN:g}"
        return
    case.td_min = prep.duration_min
    fresh = evaluate_prepared(prep, methods=("none", "hdr+"), setup=PLUS).e_psi
    case.e = {"none": fresh["none"], "hdr+": fresh["hdr+"]}
    if profile is None:
        return
    try:
        cfg, _ = load_config(profile)
    except ConfigError as e:
        case.note = f"profile refused: {e}"
        return
    case.profile = {k: float(v) for k, v in asdict(cfg.gyro).items() if k != "grade" and v}
    learned = evaluate_prepared(prep, methods=("none", "hdr+"), setup=method_setup(cfg)).e_psi
    case.e["hdr+ profile"] = learned["hdr+"]


# -- tables --------------------------------------------------------------------------------------


def harmed(value: float, ref: float) -> bool:
    return value > max(HARM_FACTOR * ref, ref + HARM_DEG)


def _groups(cases: list[Case]) -> dict[str, list[Case]]:
    out: dict[str, list[Case]] = {}
    for c in cases:
        out.setdefault(c.group, []).append(c)
    units = [c for c in cases if c.group.startswith("unit: ")]
    if units:
        out["units (all)"] = units
    return out


def table(cases: list[Case]) -> str:
    head = (
        "| group | drives | "
        + " | ".join(f"NEψ {m}" for m in METHODS)
        + " | none / hdr+ | none / profile | harmed hdr+ | harmed profile |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for g, cs in _groups(cases).items():
        cs = [c for c in cs if len(c.e) == len(METHODS)]
        if not cs:
            continue
        ne = {m: float(np.mean([c.e[m] / c.td_min for c in cs])) for m in METHODS}
        harm = {m: sum(harmed(c.e[m], c.e["none"]) for c in cs) for m in METHODS[1:]}
        lines.append(
            f"| {g} | {len(cs)} | "
            + " | ".join(fmt(ne[m]) for m in METHODS)
            + f" | {fmt(ne['none'] / ne['hdr+'], 2)}x | {fmt(ne['none'] / ne['hdr+ profile'], 2)}x"
            + f" | {harm['hdr+']} | {harm['hdr+ profile']} |"
        )
    return "\n".join(lines)


def _named(c: Case) -> str:
    p = c.profile
    parts = []
    if "motion_offset_dps" in p:
        parts.append(
            f"offset {p['motion_offset_dps']:+.3f} ± {p.get('motion_offset_sd_dps', 0.0):.3f}"
        )
    if "bias_instability_dps" in p:
        parts.append(f"BI {p['bias_instability_dps']:.4f} τ {p.get('bias_tau_s', 0.0):.0f} s")
    return ", ".join(parts) or "–"


def drive_table(cases: list[Case]) -> str:
    lines = [
        "| drive | group | Td min | Eψ none | Eψ hdr+ | Eψ profile | true offset | gap named |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        true = f"{c.unit.motion_offset_dps:+.3f}" if c.unit else "?"
        if len(c.e) < len(METHODS):
            lines.append(f"| {c.name} | {c.group} | – | – | – | – | {true} | {c.note or '–'} |")
            continue
        star = " *" if harmed(c.e["hdr+ profile"], c.e["none"]) else ""
        lines.append(
            f"| {c.name} | {c.group} | {c.td_min:.1f} | {fmt(c.e['none'], 2)} | "
            f"{fmt(c.e['hdr+'], 2)} | {fmt(c.e['hdr+ profile'], 2)}{star} | {true} | {_named(c)} |"
        )
    return "\n".join(lines)


def report(cases: list[Case], which: str) -> str:
    return f"""Gyro-only on the later drive: mean NEψ (deg/min) per group of static bias removal
(`none`), a fresh HDR+ (default configuration) and HDR+ with the unit's profile from `hdrd gap
--gyro-out` on the earlier drive; *harmed*: Eψ above max(1.1 x none's, none's + 0.5°).

{table(cases)}

Per drive ({which} set; * harmed; *true offset*: the simulated unit's motion offset, deg/s;
*gap named*: the profile's motion offset ± its sd and bias instability, deg/s):

{drive_table(cases)}"""


def to_json(cases: list[Case]) -> dict[str, Any]:
    return {
        c.name: {"group": c.group, "td_min": c.td_min, "e_psi": c.e, "profile": c.profile}
        | ({"note": c.note} if c.note else {})
        for c in cases
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", choices=("tune", "judge"), required=True, dest="which")
    ap.add_argument("--units", type=int, default=32, help="units of bench/units.py (default 32)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/hdrd-holds"))
    ap.add_argument("--json", type=Path, help="write every case's figures here")
    ap.add_argument("--no-write", action="store_true", help="print, leave RESULTS.md alone")
    ap.add_argument("--jobs", type=int, default=2, help="gap processes at once (default 2)")
    a = ap.parse_args(argv)
    cases = real_cases(a.workdir, a.which) + unit_cases(a.workdir, a.which, a.units)
    folder, stamp = a.workdir / f"profiles-{a.which}", _gap_stamp()
    with ThreadPoolExecutor(max(1, a.jobs)) as pool:
        profiles = list(pool.map(lambda c: learn_profile(c, folder, stamp), cases))
    for c, p in zip(cases, profiles, strict=True):
        score(c, p)
    text = report(cases, a.which)
    print(text)
    if a.json is not None:
        a.json.write_text(json.dumps(to_json(cases), indent=1))
    if a.which == "judge" and not a.no_write:
        body = (
            f"{SECTION} (judge)\n\nGenerated by `python bench/unit_profile.py --set judge` "
            f"({machine_line()}); the script's docstring says what is scored.\n\n" + text + "\n"
        )
        put_section("real", body)
        print(f"wrote the section {SECTION!r} (judge) of bench/RESULTS.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
