#!/usr/bin/env python3
"""The paper's Table II on the simulated benchmark, tuning (train vs test), real recordings.

    python bench/tables.py [--workdir /tmp/hdrd-tables] [--candidates 10000] [--seed 0]
                           [--repeats 3] [--no-write]

Runs, as processes, exactly the commands it lists in bench/RESULTS.md (so anyone can repeat
them one by one):

1. ``hdrd simulate --benchmark train|test`` -> the nine training and five test drives;
2. ``hdrd evaluate`` on both sets with the paper's Table III parameters (+ ``--plot``);
3. ``hdrd tune`` on the nine, checked on the five (``--candidates``, ``--seed``);
4. ``hdrd evaluate --config tuned.yaml`` on the five test drives;
5. ``python tools/convert_real.py all`` and ``hdrd evaluate --bias ...`` on the two real
   recordings of ../shared/data/ (skipped, and said so, if the folder is absent).

Then it times :func:`hdrd.analysis.tune.tune` in-process on the nine drives with 10,000
parameter sets (target: <= 30 s), computes the continuous-heading Eψ the paper's
Table II must have used, and rewrites its own section of bench/RESULTS.md
("## Table II analogue (simulated) and real recordings", in Accuracy: simulated drives),
leaving every other section as it is.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from _common import fmt, machine_line, put_section, run_recorded

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "RESULTS.md"
SECTION = CRS03_SECTION = "## Table II analogue (simulated) and real recordings"
DATA = REPO.parent / "shared" / "data"

# The paper's Table II (Borenstein & Ojeda 2009): Td min, Eψ without/with HDR (deg), NEψ
# without/with (deg/min), relative improvement as printed.
PAPER_TABLE_II: dict[str, tuple[float, float, float, float, float, float]] = {
    "city1": (19.4, 17, 3.1, 0.87, 0.16, 5.4),
    "suburbs": (24.3, 35, 10.4, 1.4, 0.43, 3.4),
    "mixed": (20.0, 44, 4.7, 2.2, 0.24, 9.4),
    "rural1": (12.9, 42, 5.5, 3.3, 0.42, 7.7),
    "rural2": (18.9, 56, 5.5, 3.0, 0.29, 10.2),
    "highway1": (52.1, 184, 6.4, 3.5, 0.12, 29.0),
    "highway2": (50.4, 63, 9.3, 1.3, 0.19, 6.8),
    "highwaymix": (47.6, 32, 7.1, 0.66, 0.15, 4.4),
    "city2": (21.6, 74, 11.3, 3.4, 0.52, 6.7),
}
PAPER_MEAN = (61.0, 7.0, 2.2, 0.28, 9.2, 7.57)  # Eψ raw, hdr, NEψ raw, hdr, improvement, σ
PAPER_TEST = (6.9, 3.44)  # improvement, σ on the five test drives (Sec. 5.2.3)
SMARTLOC_FIT_BIAS_DPS = 0.053  # least-squares bias of the whole smartLoc run (its README.txt)


def continuous_errors(
    paths: list[Path], bias: float | None = None
) -> dict[str, tuple[float, float]]:
    """Continuous-heading Eψ (raw, hdr) per drive, same steps and alignment as hdrd evaluate."""
    from hdrd.analysis.evaluate import method_yaw, prepare_drive
    from hdrd.analysis.metrics import e_psi_continuous
    from hdrd.io.files.drivelog import read_drive

    out = {}
    for p in paths:
        prep = prepare_drive(read_drive(p), bias)
        e = [e_psi_continuous(method_yaw(prep, m), prep.truth, prep.k) for m in ("none", "hdr")]
        out[prep.name] = (e[0], e[1])
    return out


def time_tune(candidates: int, seed: int, repeats: int) -> list[float]:
    """Seconds for tune() on the nine drives (generated in memory), excluding their generation."""
    from hdrd.analysis.evaluate import prepare_drive
    from hdrd.analysis.tune import tune
    from hdrd.sim.benchmark import generate_all

    logs = generate_all("train")
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        prepared = [prepare_drive(d) for d in logs]
        tune(prepared, (), candidates, seed)
        times.append(time.perf_counter() - t0)
    return times


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", default="/tmp/hdrd-tables", help="where drive logs and outputs go")
    ap.add_argument("--candidates", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3, help="timings of the in-process tune")
    ap.add_argument(
        "--no-write", action="store_true", help="print the section, do not edit RESULTS.md"
    )
    ap.add_argument(
        "--grade",
        default="crs03",
        help="gyro grade of the simulated drives (hdrd simulate --grade); a grade other than "
        "crs03 gets its own section, without the real recordings and the discussion",
    )
    return ap.parse_args()


def _simulated(
    a: argparse.Namespace, W: Path, cmds: list[str], tr_s: list[str], te_s: list[str]
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any], dict[str, Any]]:
    """Steps 1-4 (module doc) as recorded commands: the drives simulated, evaluated and
    tuned; their documents (train, test, test with the tuned set, tune)."""
    hdrd = ["hdrd"]
    grade_args = [] if a.grade == "crs03" else ["--grade", a.grade]
    run_recorded(
        hdrd + ["simulate", "--benchmark", "train", "--out", f"{W}/train", *grade_args], cmds
    )
    run_recorded(
        hdrd + ["simulate", "--benchmark", "test", "--out", f"{W}/test", *grade_args], cmds
    )
    run_recorded(
        hdrd + ["evaluate", *tr_s, "--json", f"{W}/train.json", "--plot", f"{W}/train.png"], cmds
    )
    run_recorded(
        hdrd + ["evaluate", *te_s, "--json", f"{W}/test.json", "--plot", f"{W}/test.png"], cmds
    )
    run_recorded(
        hdrd
        + [
            "tune",
            *tr_s,
            "--test",
            *te_s,
            "--candidates",
            str(a.candidates),
            "--seed",
            str(a.seed),
            "--out",
            f"{W}/tuned.yaml",
            "--json",
            f"{W}/tune.json",
            "--no-progress",
        ],
        cmds,
    )
    run_recorded(
        hdrd + ["evaluate", *te_s, "--config", f"{W}/tuned.yaml", "--json", f"{W}/test_tuned.json"],
        cmds,
    )
    docs = [json.loads((W / f"{n}.json").read_text()) for n in ("train", "test", "test_tuned")]
    return docs[0], docs[1], docs[2], json.loads((W / "tune.json").read_text())


def _real(W: Path, cmds: list[str]) -> list[tuple[str, str, dict[str, Any], str]]:
    """Step 5 (module doc): the real recordings converted and evaluated, each as (label, bias
    deg/s, its ``--json`` document, its printed table)."""
    hdrd = ["hdrd"]
    real: list[tuple[str, str, dict[str, Any], str]] = []
    run_recorded([sys.executable, "tools/convert_real.py", "all", "--out-dir", f"{W}/real"], cmds)
    from hdrd.io.files.drivelog import read_drive

    comma = W / "real" / "comma2k19.csv"
    android = float(read_drive(comma).meta["android_bias_dps"])
    smart = W / "real" / "smartloc_berlin.csv"
    cases = [
        (smart, "0", "smartLoc Berlin, bias 0 (the car's sensor taken as zeroed)"),
        (
            smart,
            f"{SMARTLOC_FIT_BIAS_DPS}",
            "smartLoc Berlin, bias +0.053 deg/s (best static bias in hindsight)",
        ),
        (comma, f"{android}", "comma2k19, bias = Android's estimate"),
    ]
    for i, (path, bias, label) in enumerate(cases):
        out = W / "real" / f"eval{i}.json"
        p = run_recorded(
            hdrd
            + ["evaluate", str(path), "--bias", bias, "--json", str(out)]
            + (["--plot", f"{W}/real/eval{i}.png"] if i != 1 else []),
            cmds,
        )
        real.append((label, bias, json.loads(out.read_text()), p.stdout))
    # A calibration over comma2k19's first second (the car moving) is refused now: the
    # start-up standstill test sees the rate's trend (docs/evaluation.md).
    return real


def main() -> int:
    a = _arguments()
    global SECTION
    paper_grade = a.grade == "crs03"
    if not paper_grade:
        SECTION = f"## Table II analogue (simulated, {a.grade} grade)"

    from hdrd.sim.benchmark import TEST_DRIVES, TRAIN_DRIVES

    W = Path(a.workdir)
    W.mkdir(parents=True, exist_ok=True)
    cmds: list[str] = []
    train = [W / "train" / f"{s.name}.csv" for s in TRAIN_DRIVES]  # the paper's order
    test = [W / "test" / f"{s.name}.csv" for s in TEST_DRIVES]
    tr_s = [str(p) for p in train]
    te_s = [str(p) for p in test]
    ev_train, ev_test, ev_test_tuned, tj = _simulated(a, W, cmds, tr_s, te_s)

    real: list[tuple[str, str, dict[str, Any], str]] = []
    if DATA.is_dir() and paper_grade:
        real = _real(W, cmds)
    else:
        print(f"no real recordings at {DATA}: skipped", file=sys.stderr)

    print("timing tune() in-process ...", flush=True)
    times = time_tune(10000, a.seed, a.repeats)
    cont_train = continuous_errors(train)
    cont_test = continuous_errors(test)
    section = render(
        a, W, cmds, ev_train, ev_test, ev_test_tuned, tj, real, times, cont_train, cont_test,
        tr_s, te_s,
    )  # fmt: skip
    print(section)
    if not a.no_write:
        put_section("sim", section)
        print(f"wrote {RESULTS.relative_to(REPO)} ({SECTION})")
    return 0


def _commands_and_definitions(
    W: Path, cmds: list[str], train_s: list[str], test_s: list[str]
) -> list[str]:
    """The section's head for the paper's grade: the commands it ran, and the definitions."""
    L = [
        f"Generated by `python bench/tables.py` ({time.strftime('%Y-%m-%d')}, on "
        f"{machine_line()}). It runs these commands (outputs in a scratch directory, here "
        f"`{W}`; drive files listed in the paper's order):",
        "",
        "```sh",
    ]
    L.append("W=/tmp/hdrd-tables")
    L.append(f'TRAIN="{" ".join(train_s)}"'.replace(str(W), "$W"))
    L.append(f'TEST="{" ".join(test_s)}"'.replace(str(W), "$W"))
    for c in cmds:
        c = c.replace(" ".join(train_s), "$TRAIN").replace(" ".join(test_s), "$TEST")
        L.append(c.replace(str(W), "$W"))
    L.append("```")
    L.append("")
    L.append(
        "Definitions (`hdrd/analysis/evaluate.py`, docs/evaluation.md): static bias from each "
        "log's 30 s standstill lead-in (`lead_in_s`), as the daemon's start-up window; the drive "
        "starts after it (Td excludes it); the gyro block-averaged to T = 1 s by the daemon's "
        "own block code and stepper (a step without samples is no step); yaw compared with the GPS-like truth at each step's end, aligned at the first "
        "step with truth; Eψ = mean |error| with each error wrapped to [-180°, 180°) (Eq. 12); "
        "NEψ = Eψ / Td (Eq. 13); improvement = Eψ without / Eψ with HDR per drive, averaged "
        "over drives (σ: sample standard deviation), as the paper does. Parameters: the paper's "
        "Table III."
    )
    L.append("")
    return L


def _training_rows(
    ev_train: dict[str, Any], cont_train: dict[str, tuple[float, float]]
) -> list[str]:
    """The nine training drives beside the paper's Table II, with the mean and the weak ones."""
    L = ["### The nine training drives (paper's Table III parameters)", ""]
    L.append(
        "| drive | Td min | paper Eψ without → with | ours Eψ without → with | paper NEψ | ours NEψ | "
        "paper impr. | ours impr. | ours, continuous Eψ without → with (impr.) |"
    )
    L.append("|---|---|---|---|---|---|---|---|---|")
    for d in ev_train["drives"]:
        p = PAPER_TABLE_II.get(d["name"])
        ce = cont_train.get(d["name"], (math.nan, math.nan))
        pe = f"{p[1]:g}° → {p[2]:g}°" if p else "–"
        pn = f"{p[3]:.2f} → {p[4]:.2f}" if p else "–"
        pi = f"{p[5]:g}×" if p else "–"
        L.append(
            f"| {d['name']} | {d['duration_min']:.1f} | {pe} | {fmt(d['E_psi_raw'], 1)}° → "
            f"{fmt(d['E_psi_hdr'], 1)}° | {pn} | {fmt(d['NE_psi_raw'], 2)} → {fmt(d['NE_psi_hdr'], 3)} | "
            f"{pi} | {fmt(d['improvement'], 1)}× | {ce[0]:.1f}° → {ce[1]:.1f}° ({ce[0] / ce[1]:.1f}×) |"
        )
    L.append(_training_mean(ev_train, cont_train))
    L.append("")
    L.append(_training_weak(ev_train))
    L.append("")
    return L


def _training_mean(ev_train: dict[str, Any], cont_train: dict[str, tuple[float, float]]) -> str:
    m = ev_train["mean"]
    imps = [d["improvement"] for d in ev_train["drives"] if d["improvement"] is not None]
    sd = statistics.stdev(imps) if len(imps) > 1 else math.nan
    c_imps = [v[0] / v[1] for v in cont_train.values()]
    c_raw = statistics.mean(v[0] for v in cont_train.values())
    c_hdr = statistics.mean(v[1] for v in cont_train.values())
    return (
        f"| **mean** | {sum(d['duration_min'] for d in ev_train['drives']) / 60:.2f} h total | "
        f"{PAPER_MEAN[0]:g}° → {PAPER_MEAN[1]:.1f}° | {fmt(m['E_psi_raw'], 1)}° → {fmt(m['E_psi_hdr'], 1)}° | "
        f"{PAPER_MEAN[2]:.2f} → {PAPER_MEAN[3]:.2f} | {fmt(m['NE_psi_raw'], 2)} → {fmt(m['NE_psi_hdr'], 3)} | "
        f"{PAPER_MEAN[4]:g}× (σ {PAPER_MEAN[5]:g}) | {fmt(m['improvement'], 1)}× (σ {fmt(sd, 2)}) | "
        f"{c_raw:.1f}° → {c_hdr:.1f}° ({statistics.mean(c_imps):.1f}×, σ {statistics.stdev(c_imps):.2f}) |"
    )


def _training_weak(ev_train: dict[str, Any]) -> str:
    """The drives HDR made worse, and those it improved less than 2.5×."""
    worse = [
        d["name"]
        for d in ev_train["drives"]
        if d["improvement"] is not None and d["improvement"] < 1
    ]
    weak = [
        f"{d['name']} ({d['improvement']:.1f}×)"
        for d in ev_train["drives"]
        if d["improvement"] is not None and 1 <= d["improvement"] < 2.5
    ]
    return (
        f"- HDR worse than no HDR on: {', '.join(worse) if worse else 'none of the nine'}; "
        f"less than 2.5× better on: {', '.join(weak) if weak else 'none'}."
    )


def _test_rows(
    ev_test: dict[str, Any],
    ev_test_tuned: dict[str, Any],
    cont_test: dict[str, tuple[float, float]],
) -> list[str]:
    """The five test drives with the paper's parameters and the tuned ones."""
    L = ["### The five test drives, and tuning on the nine", ""]
    L.append(
        "| drive | Td min | Eψ without | Eψ HDR (Table III) | Eψ HDR (tuned) | NEψ without | "
        "NEψ Table III | NEψ tuned | impr. Table III | impr. tuned | continuous Eψ without → Table III |"
    )
    L.append("|---|---|---|---|---|---|---|---|---|---|---|")
    tuned_by = {d["name"]: d for d in ev_test_tuned["drives"]}
    for d in ev_test["drives"]:
        t = tuned_by[d["name"]]
        ce = cont_test.get(d["name"], (math.nan, math.nan))
        L.append(
            f"| {d['name']} | {d['duration_min']:.1f} | {fmt(d['E_psi_raw'], 1)}° | {fmt(d['E_psi_hdr'], 1)}° | "
            f"{fmt(t['E_psi_hdr'], 1)}° | {fmt(d['NE_psi_raw'], 2)} | {fmt(d['NE_psi_hdr'], 3)} | "
            f"{fmt(t['NE_psi_hdr'], 3)} | {fmt(d['improvement'], 1)}× | {fmt(t['improvement'], 1)}× | "
            f"{ce[0]:.1f}° → {ce[1]:.1f}° |"
        )
    m, mt = ev_test["mean"], ev_test_tuned["mean"]
    L.append(
        f"| **mean** | | {fmt(m['E_psi_raw'], 1)}° | {fmt(m['E_psi_hdr'], 1)}° | {fmt(mt['E_psi_hdr'], 1)}° | "
        f"{fmt(m['NE_psi_raw'], 2)} | {fmt(m['NE_psi_hdr'], 3)} | {fmt(mt['NE_psi_hdr'], 3)} | "
        f"{fmt(m['improvement'], 1)}× | {fmt(mt['improvement'], 1)}× | |"
    )
    L.append("")
    return L


def _tuning_rows(tj: dict[str, Any]) -> list[str]:
    """``hdrd tune``'s answer, training and test side by side."""
    tr, te = tj["train"], tj["test"]
    L = [
        f"`hdrd tune` ({tj['candidates']} parameter sets, seed {tj['seed']}, "
        f"{tj['seconds']:.1f} s for the whole command) — training and test side by side; the "
        "paper's own answer to this question was 9.2× on its training drives and "
        f"{PAPER_TEST[0]:g}× (σ {PAPER_TEST[1]:g}) on its five test drives:"
    ]
    L.append("")
    L.append(
        "| parameters | i_c | τ | Θw | c1 | c2 | train mean NEψ | train impr. | test mean NEψ | test impr. |"
    )
    L.append("|---|---|---|---|---|---|---|---|---|---|")
    L.append(
        f"| without HDR | | | | | | {tr['none']['mean_NE_psi']:.3f} | – | {te['none']['mean_NE_psi']:.3f} | – |"
    )
    for label, key in (("paper Table III", "baseline"), ("tuned on the nine", "tuned")):
        pp = tj["params"][key]
        L.append(
            f"| {label} | {pp['i_c']:g} | {pp['tau']:g} | {pp['theta_w']:g} | {pp['c1']:g} | {pp['c2']:g} | "
            f"{tr[key]['mean_NE_psi']:.3f} | {tr[key]['improvement']:.2f}× (σ {fmt(tr[key]['improvement_std'], 2)}) | "
            f"{te[key]['mean_NE_psi']:.3f} | {te[key]['improvement']:.2f}× (σ {fmt(te[key]['improvement_std'], 2)}) |"
        )
    L.append("")
    return L


def _real_rows(grade: str, real: list[tuple[str, str, dict[str, Any], str]]) -> list[str]:
    """The real recordings (crs03 only), each from its ``--json`` or else its printed table."""
    L = ["### Real recordings (`../shared/data/`, converted by `tools/convert_real.py`)", ""]
    if grade != "crs03":
        L.append("Not part of a grade's run: see the crs03 section and bench/real.py's.")
    elif not real:
        L.append("Skipped: the recordings were not found.")
    else:
        L.append(
            "| recording | bias | Td min | Eψ without | Eψ with HDR | NEψ without | NEψ with | improvement |"
        )
        L.append("|---|---|---|---|---|---|---|---|")
        L += [row for label, bias, doc, text in real for row in _real_row(label, bias, doc, text)]
    L.append("")
    return L


def _real_row(label: str, bias: str, doc: dict[str, Any], text: str) -> list[str]:
    """One recording's row, or none when neither its document nor its text has one."""
    if doc:
        d = doc["drives"][0]
        return [
            f"| {label} | {bias} | {d['duration_min']:.1f} | {fmt(d['E_psi_raw'], 2)}° | "
            f"{fmt(d['E_psi_hdr'], 2)}° | {fmt(d['NE_psi_raw'], 2)} | {fmt(d['NE_psi_hdr'], 2)} | "
            f"{fmt(d['improvement'], 1)}× |"
        ]
    row = [ln for ln in text.splitlines() if ln.startswith("comma2k19")]
    cells = row[0].split() if row else []
    if len(cells) < 8:
        return []
    return [
        f"| {label} | {cells[2]} | {cells[1]} | {cells[3]}° | {cells[4]}° | {cells[5]} | "
        f"{cells[6]} | {cells[7].replace('x', '×')} |"
    ]


def _speed_rows(times: list[float], tj: dict[str, Any]) -> list[str]:
    """How long ``tune()`` and ``hdrd tune`` took (s)."""
    best = min(times)
    return [
        "### Tuning speed",
        "",
        f"`tune()` with 10,000 parameter sets on the nine drives (4.45 h, "
        f"{round(sum(PAPER_TABLE_II[k][0] for k in PAPER_TABLE_II) * 60)} steps of 1 s), "
        f"in-process, {len(times)} runs: best {best:.1f} s, median {statistics.median(times):.1f} s "
        f"(target ≤ 30 s: {30 / best:.1f}× inside it). Most of it (about 70 % in a profile) is "
        "`hdrd.core.hdr.run_many` stepping all sets together, the rest is Eψ of every set. "
        f"`hdrd tune` as a command, reading the nine and five CSV files and evaluating the "
        f"winner on both: {tj['seconds']:.1f} s.",
        "",
    ]


def render(
    a: argparse.Namespace,
    W: Path,
    cmds: list[str],
    ev_train: dict[str, Any],
    ev_test: dict[str, Any],
    ev_test_tuned: dict[str, Any],
    tj: dict[str, Any],
    real: list[tuple[str, str, dict[str, Any], str]],
    times: list[float],
    cont_train: dict[str, tuple[float, float]],
    cont_test: dict[str, tuple[float, float]],
    train_s: list[str],
    test_s: list[str],
) -> str:
    """The section: how it was made, the training nine, the test five and tuning, the real
    recordings, the speed, and (crs03) the discussion."""
    L: list[str] = [SECTION, ""]
    if a.grade != "crs03":  # the commands and definitions are the crs03 section's: said once
        L.append(
            f"Generated by `python bench/tables.py --grade {a.grade}` ({time.strftime('%Y-%m-%d')}, "
            f'on {machine_line()}). It runs the commands of "{CRS03_SECTION[3:]}" with '
            f"`--grade {a.grade}` on `hdrd simulate` and without the real recordings (outputs in "
            f"`{W}`); the definitions are that section's."
        )
        L.append("")
    else:
        L += _commands_and_definitions(W, cmds, train_s, test_s)
    L += _training_rows(ev_train, cont_train)
    L += _test_rows(ev_test, ev_test_tuned, cont_test)
    L += _tuning_rows(tj)
    L += _real_rows(a.grade, real)
    L += _speed_rows(times, tj)
    if a.grade == "crs03":
        L.append(DISCUSSION.strip())
        L.append("")
    return "\n".join(L) + "\n"


DISCUSSION = """
### Discussion

Written by hand from the run above (the simulator and the search are seeded, so a re-run gives
the same tables unless the code changes; if it did, re-read the numbers before these words).

- **The Table II analogue has the paper's shape.** With the paper's Table III parameters,
  HDR takes the nine simulated drives from a mean NEψ of about 2.0 to 0.29 deg/min (paper: 2.2
  to 0.28) and Eψ from about 48° to 7° (paper: 61° to 7.0°), a mean improvement of about 9×
  (paper 9.2×). This is partly by construction: the benchmark's gyro model and cabin-warming
  profiles were chosen so that the *uncorrected* errors land where the paper's do; the *HDR*
  column is not tuned to anything and still lands near the paper's.
- **Wrapped vs continuous Eψ.** hdrd wraps each momentary error to ±180° (Eq. 12 as
  HDR-NOTES fixes it), so an error can never exceed 180°. The paper's Highway 1 (184° average
  without HDR) shows that the paper did not: its uncorrected headings were continuous. The
  two definitions agree on every drive whose uncorrected error stays below 180°; on Highway 1
  ours is ~73° wrapped but ~190° continuous (paper 184°), and its improvement 14× vs 38×
  (paper 29×). With continuous headings our mean uncorrected Eψ is ~61°, the paper's figure.
- **Where HDR helps little.** Curving roads: *suburbs* (1.8×; also the paper's weakest
  drive, 3.4×) and *suburbs2* in the test set (1.4×), and *city1* (2.8× vs the paper's 5.4×).
  On long arcs whose rate stays below Θw = 0.564 deg/s the turn switch lets the integrator
  run, so HDR "corrects" real curvature as if it were drift (the paper's Sec. 4.1 says as
  much). HDR never made a simulated drive worse than no HDR.
- **Training vs test, paper parameters.** The mean improvement on the five test drives is
  *higher* (~13×) than on the nine (~9×), but that mean is carried by two straight drives with
  big uncorrected errors (city3 ~31×, rural3 ~28×; σ ≈ 15). The duration-normalised error,
  which is what the paper minimised, goes the paper's way: mean NEψ 0.29 on the nine, 0.40 on
  the five. A mean of ratios is dominated by its largest ratio (as the paper's own 29×
  Highway 1), so the NEψ columns are the better comparison.
- **Tuning.** Minimising the mean NEψ of the nine found a set with a smaller increment
  (i_c ≈ 0.016 vs 0.042 deg/s) and a much flatter repetition attenuator (c2 ≈ 0.44): mean
  training NEψ 0.29 → 0.13 (2.2× lower), but on the held-out five only 0.40 → 0.28 (1.4×),
  and one test drive (city3) got worse with the tuned set. That is the paper's 9.2×-vs-6.9×
  question answered the same way: part of what tuning wins is specific to the drives it saw.
  Part of it is also specific to our simulator: Table III was tuned on real drives with a
  real CRS03-04, so beating it on simulated data says little about real ones.
- **Real recordings: HDR does not help on smartLoc Berlin.** With the car's yaw-rate sensor
  taken as zeroed, Eψ goes from 8.7° to 12.8° with HDR; with the best static bias in hindsight
  (+0.053 deg/s) from 1.8° to 10.3°. It is a slow (mean 5.5 m/s) 4.7-minute urban drive with
  one turn or curve after another, and an automotive sensor whose residual bias (~0.05 deg/s)
  is about one HDR increment: there is almost no drift to remove, while the integrator,
  chasing slow curves, swings between −0.31 and +0.21 deg/s. HDR's premise — most driving is
  straight, and the drift is larger than what it mistakes for drift — does not hold here.
- **comma2k19** (1 min, nearly straight, a phone gyro with a 3.9 deg/s raw bias): with
  Android's own bias estimate removed HDR cuts Eψ from 1.1° to 0.3° (3.6×); with the bias
  taken from the log's first second (the car is moving on a straight road; the standstill test
  cannot tell) from 4.7° to 0.8°. Without any bias removal HDR can do nothing (103° either
  way): a 3.9 deg/s offset is far above Θw, so the turn switch never lets I move. HDR reduces
  residual drift; it is no substitute for the static calibration (the paper's Eq. 2).
- Both real recordings are short (1 and 4.7 minutes) — too short for the slow drift HDR is
  for; they check conventions and the pipeline on real signals more than HDR's benefit.
"""


if __name__ == "__main__":
    sys.exit(main())
