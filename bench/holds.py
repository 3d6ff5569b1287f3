#!/usr/bin/env python3
"""Heading that holds: gyro-only NEψ and GNSS outages on one set of the split, real drives and
simulated gyros on a real road, with the course-aided Kalman peer beside them.

    python bench/holds.py --set tune|judge [--seeds N] [--workdir /tmp/hdrd-holds]
                          [--json PATH] [--no-write] [--dry-run]

The drives of a set (docs/real-data.md, "The split"):

- *real*: bench/real.py's ``TUNING`` (or ``JUDGING``) drives, converted by
  ``tools/convert_real.py`` as bench/real.py converts them (../shared/data or
  ``$HDRD_REAL_DATA``; oan and psins where ``$HDRD_MIRRORS`` holds their clones);
- *roads*: the set's Boreas route (``boreas_20210805_1334`` tunes, ``boreas_20210902_1142``
  judges; ``tools/convert_real.py boreas``, ``$HDRD_MIRRORS``) carrying a simulated gyro of
  every grade (crs03, phone, automotive, tactical; :func:`hdrd.sim.roads.grade_on_road`: the
  grade's gyro of the seed at its own rate, a cabin temperature, 30 s of start-up standstill,
  a 1 Hz GPS course), ``--seeds`` seeds each (tune 101.., judge 201..), the k-th seed's drive
  starting at the k-th stop of the route (cycling through those with 11 minutes of road after
  them: each puts the outage elsewhere), each without and with a motion offset (:data:`MOTION_OFFSET_BI` x the grade's bias instability, its sign
  alternating with the seed: a bias a stop cannot see).

What is scored, per drive, exactly as ``hdrd evaluate`` scores it (the same calls, the default
configuration):

(a) *gyro-only*: Eψ and NEψ of ``none`` (static bias removal), ``hdr`` (paper HDR, Table III)
    and ``hdr+`` after each drive's own start-up calibration, with evaluate's alignment (an
    exact truth at its first value; a course over ground over the first 10 s of straight
    driving at speed); real drives whose scored part is under 5 minutes are left out, as in
    bench/real.py. Per group: mean NEψ, none / hdr+, and the drives *harmed*: Eψ above max(1.1
    x none's, none's + 0.5 deg).
(b) *outages* (``hdrd evaluate --outages``, :func:`hdrd.analysis.outages.run_outages`) of
    120 s at the end of every 10 minutes, every 5 minutes on a drive whose scored part is
    longer than 30 minutes, the grid run at 4 phases a quarter period apart (0, 150, 300,
    450 s; each a run of its own: bench/peer.py's :func:`peer.outage_plan`): each method
    through the daemon's GPS-aiding path, ``none`` being the bias frozen at the outage's
    start; per group the outages scored, the mean |heading error| at their ends (pooled over
    outages), frozen / hdr+, and the drives harmed: a drive's mean above max(1.1 x frozen's,
    frozen's + 0.5 deg).
(c) the *Kalman peer* (bench/peer.py, :func:`peer.kalman_peer`, its tuned defaults) on the
    same outages, harmed against frozen the same way.

Converted logs are kept in ``--workdir`` (converted again only when the converter or its
source list changed); the simulated gyros are made in memory (faster than reading them back),
``--write-logs`` also writes them there as drive logs (``hdrd evaluate`` reads them).
``--set tune`` prints only; ``--set judge`` rewrites its section of bench/RESULTS.md (Accuracy:
real drives; the
judging set is run once, to report; ``--no-write`` prints only). ``--dry-run`` converts and
simulates, lists the drives and their groups, and scores nothing. ``--json PATH`` writes every
drive's figures. About 1 minute a set on this machine.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from _common import fmt, machine_line, plus_with, put_section
from peer import plan_errors, plan_text
from real import JUDGING, MIN_SCORED_MIN, PLUS, TUNING, convert_all
from units import unit_logs

from hdrd.analysis.evaluate import EvaluationError, evaluate_prepared, method_settings
from hdrd.analysis.outages import FROZEN
from hdrd.analysis.prepare import prepare_drive
from hdrd.core import methods as registry
from hdrd.core.grades import Grade
from hdrd.io.files.drivelog import DriveLog, read_drive, write_drive
from hdrd.sim.roads import grade_on_road, route_stops

SECTION = "## Heading that holds: gyro-only and GNSS outages, real drives and real roads"
METHODS = ("none", "hdr", "hdr+")
PEER = "kalman peer"
GRADES = ("crs03", "phone", "automotive", "tactical")
ROUTES = {"tune": "boreas_20210805_1334", "judge": "boreas_20210902_1142"}
"""The Boreas route of each set (tools/real_sources.yaml, ``split``)."""
FIRST_SEED = {"tune": 101, "judge": 201}
"""The simulated gyros' seeds: FIRST_SEED .. FIRST_SEED + seeds - 1 (other seeds per set)."""
MOTION_OFFSET_BI = 2.0
"""The motion offset of a road drive, in units of its grade's bias instability (deg/s):
crs03 0.012, phone 0.0056, automotive 0.011, tactical 0.0011 deg/s; + for odd seeds, - for
even ones."""
ROUTE_AFTER_START_S = 660.0
"""A road drive starts where the route has at least this left, s: a 120 s outage ends 600 s
after the calibration."""
HARM_FACTOR, HARM_DEG = 1.1, 0.5
"""A drive is harmed when its figure exceeds max(HARM_FACTOR x the reference's, the
reference's + HARM_DEG), deg."""


@dataclass
class Scored:
    """One drive's figures: Eψ (deg) per method and its Td (min) for gyro-only (empty when not
    scored), each method's and the peer's heading error at each outage's end (deg; empty
    without an outage), and why a part was not scored."""

    name: str
    group: str
    td_min: float = math.nan
    e: dict[str, float] = field(default_factory=dict)
    outages: dict[str, np.ndarray] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    cover: np.ndarray = field(default_factory=lambda: np.zeros(3, int))
    """HDR+'s heading sd gyro-only: steps with a truth, of them |error| within 1.96 sd, within 1 sd."""
    cover_ends: np.ndarray = field(default_factory=lambda: np.zeros(3, int))
    """The same at the outages' ends."""

    def out_mean(self, m: str) -> float:
        """Mean |error| over the outages scored for every method and the peer, deg."""
        e = np.abs(self.outages[m][self.scored_outages()])
        return float(np.mean(e)) if e.shape[0] else math.nan

    def scored_outages(self) -> np.ndarray:
        ok = np.ones(len(self.outages[FROZEN]), dtype=bool)
        for v in self.outages.values():
            ok &= np.isfinite(v)
        return ok


def harmed(value: float, ref: float) -> bool:
    return value > max(HARM_FACTOR * ref, ref + HARM_DEG)


def label(method: str) -> str:
    """A method's column heading: ``none`` through an outage is the frozen bias."""
    return "frozen bias" if method == FROZEN else method


# -- the drives ----------------------------------------------------------------------------------


def _stamp(paths: Sequence[Path]) -> str:
    """A digest of the files that make the converted logs (the converter, its sources)."""
    h = hashlib.sha256()
    for p in paths:
        h.update(p.read_bytes())
    return h.hexdigest()


def _cached(folder: Path, make: Any) -> None:
    """Run ``make(folder)`` unless ``folder`` holds logs made by today's converter."""
    tools = [REPO / "tools" / "convert_real.py", REPO / "tools" / "real_sources.yaml"]
    stamp, mark = _stamp(tools), folder / ".converted"
    if mark.is_file() and mark.read_text() == stamp:
        return
    folder.mkdir(parents=True, exist_ok=True)
    make(folder)
    mark.write_text(stamp)


def real_logs(work: Path, which: str) -> list[DriveLog]:
    """The real drives of the set, converted into ``work/real`` (kept)."""
    folder = work / "real"
    _cached(folder, lambda f: convert_all(f, []))
    names = TUNING if which == "tune" else JUDGING
    return [read_drive(p, p.stem) for p in sorted(folder.glob("*.csv")) if p.stem in names]


def route_log(work: Path, which: str) -> DriveLog:
    """The set's Boreas route, converted into ``work/routes`` (kept); SystemExit with the
    converter's reason when it cannot be (no $HDRD_MIRRORS and no clone)."""
    folder = work / "routes"

    def convert(f: Path) -> None:
        cmd = [sys.executable, "tools/convert_real.py", "boreas", "--out-dir", str(f)]
        p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=False)
        if p.returncode != 0:
            raise SystemExit(f"bench/holds.py: {p.stderr.strip()}")

    _cached(folder, convert)
    return read_drive(folder / f"{ROUTES[which]}.csv", ROUTES[which])


def motion_offset(grade: str, seed: int) -> float:
    """The motion offset of a road drive, deg/s (:data:`MOTION_OFFSET_BI`)."""
    sign = 1.0 if seed % 2 else -1.0
    return sign * MOTION_OFFSET_BI * Grade.from_table(grade).bias_instability_dps


def road_starts(route: DriveLog) -> list[float]:
    """Where the road drives start on the route, s: the whole second after the start of each
    of its stops (the standing start first) that leaves at least :data:`ROUTE_AFTER_START_S`
    of route, so that each start puts the outage elsewhere on the road."""
    stops = route_stops(route)
    return [math.floor(a) + 1.0 for a, _ in stops if route.duration_s - a >= ROUTE_AFTER_START_S]


def road_logs(route: DriveLog, which: str, seeds: int) -> list[tuple[str, DriveLog]]:
    """(group, log) of every simulated gyro on the route: each grade, each seed (the k-th
    seed from the k-th start of :func:`road_starts`, cycling), without and with a motion
    offset."""
    starts = road_starts(route)
    out = []
    for grade in GRADES:
        for k in range(seeds):
            seed, at = FIRST_SEED[which] + k, starts[k % len(starts)]
            out.append((grade, grade_on_road(route, grade, seed, start_s=at)))
            mo = motion_offset(grade, seed)
            out.append((f"{grade} + offset", grade_on_road(route, grade, seed, mo, start_s=at)))
    return out


# -- scoring -------------------------------------------------------------------------------------


def score(log: DriveLog, group: str, min_td: float | None = 0.0) -> Scored:
    """One drive's figures (module docstring); ``min_td``: gyro-only only from this Td, min
    (None: outages only)."""
    s = Scored(log.name, group)
    try:
        prep = prepare_drive(log)
    except EvaluationError as e:
        s.notes.append(str(e).replace(f"{log.name}: ", "").split(";")[0])
        return s
    if min_td is not None and prep.duration_min >= min_td:
        r = evaluate_prepared(prep, methods=METHODS, setup=PLUS)
        s.td_min, s.e = prep.duration_min, dict(r.e_psi)
        sd = registry.get("hdr+").heading_sd(prep.steps, method_settings(prep, "hdr+", PLUS))
        if sd is not None:
            err = (r.heading["hdr+"] - prep.truth + 180.0) % 360.0 - 180.0
            s.cover = coverage(err, sd)
    elif min_td is not None:
        s.notes.append(f"gyro-only: {prep.duration_min:.1f} min < {min_td:g} after calibration")
    try:
        plan = plan_errors(prep, log, METHODS, PLUS, PEER)
        s.outages = plan.errors
        s.cover_ends = coverage(plan.errors["hdr+"], plan.sd)
    except EvaluationError as e:
        why = str(e).replace(f"{log.name}: ", "")
        s.notes.append(f"no outage in {prep.duration_min:.1f} min" if "no outage" in why else why)
    return s


def coverage(err: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """(values with both known, |err| <= 1.96 sd among them, |err| <= sd among them)."""
    ok = np.isfinite(err) & np.isfinite(sd)
    e, d = np.abs(err[ok]), sd[ok]
    return np.array([ok.sum(), (e <= 1.96 * d).sum(), (e <= d).sum()], dtype=int)


# -- tables --------------------------------------------------------------------------------------


UNIT = "unit: "
"""The group prefix of the population's units (bench/units.py)."""


def _groups(rows: Sequence[Scored], pooled: str = "roads (all)") -> dict[str, list[Scored]]:
    """Rows by group, in order of first appearance; the grades on the route as ``pooled``, the
    units as ``units (all)``."""
    out: dict[str, list[Scored]] = {}
    for r in rows:
        out.setdefault(r.group, []).append(r)
    roads = [r for r in rows if r.group != "real" and not r.group.startswith(UNIT)]
    if roads:
        out[pooled] = roads
    units = [r for r in rows if r.group.startswith(UNIT)]
    if units:
        out["units (all)"] = units
    return out


def coverage_table(rows: Sequence[Scored]) -> str:
    """HDR+'s published heading sd against its errors, per group: gyro-only at every step
    with a truth, and at the outages' ends."""
    lines = [
        "| group | steps | within 1.96 sd | within 1 sd | outage ends | within 1.96 sd | within 1 sd |",
        "|---|---|---|---|---|---|---|",
    ]
    for g, rs in _groups(rows).items():
        a = sum((r.cover for r in rs), np.zeros(3, int))
        b = sum((r.cover_ends for r in rs), np.zeros(3, int))

        def share(c: np.ndarray, i: int) -> str:
            return f"{c[i] / c[0]:.0%}" if c[0] else "–"

        lines.append(
            f"| {g} | {a[0]} | {share(a, 1)} | {share(a, 2)} | {b[0]} | {share(b, 1)} | {share(b, 2)} |"
        )
    return "\n".join(lines)


def gyro_table(rows: Sequence[Scored]) -> str:
    """(a): per group mean NEψ of each method, none / hdr+, drives harmed."""
    head = (
        "| group | drives | "
        + " | ".join(f"NEψ {m}" for m in METHODS)
        + " | none / hdr+ | harmed hdr | harmed hdr+ |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for g, rs in _groups(rows).items():
        rs = [r for r in rs if r.e]
        if not rs:
            continue
        ne = {m: float(np.mean([r.e[m] / r.td_min for r in rs])) for m in METHODS}
        harm = {m: sum(harmed(r.e[m], r.e["none"]) for r in rs) for m in ("hdr", "hdr+")}
        lines.append(
            f"| {g} | {len(rs)} | "
            + " | ".join(fmt(ne[m]) for m in METHODS)
            + f" | {fmt(ne['none'] / ne['hdr+'], 2)}x | {harm['hdr']} | {harm['hdr+']} |"
        )
    return "\n".join(lines)


def outage_table(rows: Sequence[Scored], together: str = "roads (all)") -> str:
    """(b), (c): per group the mean |error| at the outages' ends of each method and the peer
    (pooled), frozen / hdr+, drives harmed against frozen; the drives not real together as
    ``together``."""
    cols = (*METHODS, PEER)
    head = (
        "| group | drives | outages | "
        + " | ".join(label(m) for m in cols)
        + " | frozen / hdr+ | "
        + " | ".join(f"harmed {m}" for m in cols[1:])
        + " |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for g, rs in _groups(rows, together).items():
        rs = [r for r in rs if r.outages and r.scored_outages().any()]
        if not rs:
            continue
        pooled = {
            m: np.concatenate([np.abs(r.outages[m][r.scored_outages()]) for r in rs]) for m in cols
        }
        mean = {m: float(np.mean(v)) for m, v in pooled.items()}
        harm = {m: sum(harmed(r.out_mean(m), r.out_mean(FROZEN)) for r in rs) for m in cols[1:]}
        lines.append(
            f"| {g} | {len(rs)} | {pooled[FROZEN].shape[0]} | "
            + " | ".join(fmt(mean[m], 2) for m in cols)
            + f" | {fmt(mean[FROZEN] / mean['hdr+'], 2)}x | "
            + " | ".join(str(harm[m]) for m in cols[1:])
            + " |"
        )
    return "\n".join(lines)


def real_table(rows: Sequence[Scored]) -> str:
    """The real drives one by one: Td, Eψ per method (harmed marked *), outages scored and
    each one's mean |error| at their ends (harmed against frozen marked *); the drives left
    out, with why."""
    cols = (*METHODS, PEER)
    head = (
        "| drive | Td min | "
        + " | ".join(f"Eψ {m}" for m in METHODS)
        + " | outages | "
        + " | ".join(f"out {'frozen' if m == FROZEN else m}" for m in cols)
        + " |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    real = [r for r in rows if r.group == "real"]
    lines += [_real_row(r, cols) for r in real if r.e or r.outages]
    notes = [f"{r.name} ({'; '.join(r.notes)})" for r in real if r.notes]
    if notes:
        lines += ["", "Left out, or in part: " + "; ".join(notes) + "."]
    return "\n".join(lines)


def _real_row(r: Scored, cols: tuple[str, ...]) -> str:
    """One real drive's row: Td, Eψ per method, the outages scored and their ends' mean
    |error| per method (harmed marked *; "–" where the drive has none)."""
    e = ["–"] * len(METHODS)
    if r.e:
        e = [fmt(r.e[m], 2) + ("*" if harmed(r.e[m], r.e["none"]) else "") for m in METHODS]
    o = ["–"] * (len(cols) + 1)
    if r.outages:
        ok, f = r.scored_outages(), r.out_mean(FROZEN)
        o = [f"{int(ok.sum())}/{ok.shape[0]}"] + [
            fmt(r.out_mean(m), 2) + ("*" if harmed(r.out_mean(m), f) else "") for m in cols
        ]
    return f"| {r.name} | {fmt(r.td_min, 1)} | " + " | ".join(e) + " | " + " | ".join(o) + " |"


def to_json(rows: Sequence[Scored]) -> dict[str, Any]:
    def num(v: float) -> float | None:
        return float(v) if math.isfinite(v) else None

    return {
        "drives": [
            {
                "name": r.name,
                "group": r.group,
                "td_min": num(r.td_min),
                "e_psi": {m: num(v) for m, v in r.e.items()},
                "outage_errors": {m: [num(float(x)) for x in v] for m, v in r.outages.items()},
                "notes": r.notes,
            }
            for r in rows
        ]
    }


# -- the run -------------------------------------------------------------------------------------


def drives(
    work: Path, which: str, seeds: int, write_logs: bool, units: int = 0
) -> tuple[list[tuple[str, DriveLog]], list[float]]:
    """(group, log) of every drive of the set, the real ones, then the roads; the roads'
    starts on the route, s."""
    out = [("real", log) for log in real_logs(work, which)]
    route = route_log(work, which)
    roads = road_logs(route, which, seeds)
    roads += [(UNIT + u.kind, log) for u, log in unit_logs(which, units, route)]
    if write_logs:
        folder = work / f"roads-{which}"
        folder.mkdir(parents=True, exist_ok=True)
        for _, log in roads:
            write_drive(folder / f"{log.name}.csv", log)
    return out + roads, road_starts(route)[:seeds]


def report(rows: Sequence[Scored], which: str, seeds: int, starts: Sequence[float]) -> str:
    return f"""Gyro-only (a): mean NEψ (deg/min) per group; *harmed*: Eψ above max(1.1 x none's,
none's + 0.5°).

{gyro_table(rows)}

GNSS outages (b, c): {plan_text()}; *outages*: those scored (a truth at the end); mean
|heading error| at their ends (deg, pooled over the outages); *frozen bias*: the daemon's aiding
with the bias frozen at the outage's start (``none``); *harmed*: a drive's mean above max(1.1 x
frozen's, frozen's + 0.5°).

{outage_table(rows)}

HDR+'s heading sd (`heading_sd`) against its errors: the share of steps with a truth whose
|error| is within 1.96 sd and within 1 sd, gyro-only and at the outages' ends (calibrated:
88-98 % and 55-80 %).

{coverage_table(rows)}

The real drives ({which} set; * harmed):

{real_table(rows)}

Roads: {ROUTES[which]} with each grade's gyro, seeds {FIRST_SEED[which]}-{FIRST_SEED[which] + seeds - 1}
from its stops at {", ".join(f"{a:.0f}" for a in starts)} s (cycling), each also with a motion offset of
±{MOTION_OFFSET_BI:g} x the grade's bias instability. Units: bench/units.py's population of
the set (what real units were measured to do), grouped by what is most telling of each."""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", choices=("tune", "judge"), required=True, dest="which")
    ap.add_argument("--seeds", type=int, default=5, help="simulated gyros per grade (default 5)")
    ap.add_argument("--units", type=int, default=32, help="units of bench/units.py (default 32)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/hdrd-holds"))
    ap.add_argument("--json", type=Path, help="write every drive's figures here")
    ap.add_argument("--write-logs", action="store_true", help="write the road drives' logs too")
    ap.add_argument("--no-write", action="store_true", help="print, leave RESULTS.md alone")
    ap.add_argument("--dry-run", action="store_true", help="list the drives, score nothing")
    ap.add_argument(
        "--plus",
        type=json.loads,
        default={},
        help="HDR+ settings overridden by name, as JSON (tune set only: an experiment)",
    )
    a = ap.parse_args(argv)
    if a.plus:
        if a.which == "judge":
            ap.error("--plus is an experiment: the tune set only")
        global PLUS
        PLUS = replace(PLUS, plus=plus_with(PLUS.plus, **a.plus))
    if a.seeds < 1:
        ap.error("--seeds must be at least 1")
    todo, starts = drives(a.workdir, a.which, a.seeds, a.write_logs, a.units)
    if a.dry_run:
        for group, log in todo:
            print(
                f"{group:<22} {log.name:<36} {log.duration_s / 60:6.1f} min {log.rate_hz:6.1f} Hz"
            )
        print(f"{len(todo)} drives of the {a.which} set; --dry-run: nothing scored")
        return 0
    rows = [score(log, g, MIN_SCORED_MIN if g == "real" else 0.0) for g, log in todo]
    text = report(rows, a.which, a.seeds, starts)
    print(text)
    if a.json is not None:
        a.json.write_text(json.dumps(to_json(rows), indent=1))
    if a.which == "judge" and not a.no_write:
        body = (
            f"{SECTION} (judge)\n\nGenerated by `python bench/holds.py --set judge` "
            f"({machine_line()}). Every figure as `hdrd evaluate` (and `--outages`) "
            'computes it, on the judging set only (docs/real-data.md, "The split"); the '
            "script's docstring says what is scored.\n\n" + text + "\n"
        )
        put_section("real", body)
        print(f"wrote the section {SECTION!r} (judge) of bench/RESULTS.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
