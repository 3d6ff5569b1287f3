#!/usr/bin/env python3
"""Mutation testing of hdrd's modules, each against its own tests (docs/testing.md).

    pip install mutmut        # not a dependency of hdrd: it brings textual, libcst, ...
    nice -n 10 python tools/mutation.py resample [hdr frames ...] [--max-children 1]
    nice -n 10 python tools/mutation.py frames --sample 200     # a seeded random sample

For each module named (a module of hdrd/core, hdrd/io or hdrd/daemon, by its name), mutmut
(3.x) mutates that module only (``hdrd/<layer>/<module>.py``) and runs only the module's own
test file (``tests/test_<module>.py``, and for a few the files in EXTRA) against each mutant,
in a copy of the tree under ``$TMPDIR/hdrd-mutation/<module>`` (the work tree is not
touched). Hypothesis runs derandomized and without its example database (the ``mutation``
profile in tests/conftest.py), so a run is reproducible. A test run that takes more than
TIMEOUT_MULTIPLIER times its clean duration plus TIMEOUT_CONSTANT_S is stopped and its
mutant counted as timed out.

``--sample N`` tests a seeded random sample of N of the module's mutants (all of them are
generated first) and reports the sample's kill rate with its 95 % interval (Wilson): for a
module whose full run would take hours on a small machine.

Prints, per module: mutants, killed, timed out, survived, with no test, and the kill rate
= (killed + timed out) / (all - skipped), mutmut's own score; ``--survivors`` lists the
mutants not killed (``mutmut show NAME`` in the module's work directory prints the diff).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import random
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# The layers whose modules have their own test file, tests/test_<module>.py (docs/development.md).
LAYERS = ("core", "io", "daemon")

# module -> test files run beside its own, and the mutants in scope (mutmut names, fnmatch
# patterns; None: all of the module). calibrate: the pure estimation only; its bias file's I/O
# (atomic writes, save_bias, load_bias) is hdrd/io/files/biasfile.py and hdrd/io/files/access.py's, tested
# through real files in tests/test_biasfile.py and tests/test_files.py.
EXTRA: dict[str, tuple[list[str], list[str] | None]] = {
    "clocks": (["tests/test_resample.py"], None),  # the device clock under the resampler
    "capture": (["tests/test_parser.py"], None),  # the decoder beside the push parser
    "standstill": (["tests/test_zupt.py"], None),  # the detector inside HDR+
    "calibrate": (
        [],
        [
            "hdrd.core.calibrate.x_estimate_bias__mutmut_*",
            "hdrd.core.calibrate.x_noise_sigma__mutmut_*",
            "hdrd.core.calibrate.x__check_noise_scaled__mutmut_*",
            "hdrd.core.calibrate.xǁStandstillLimitsǁ*",
            "hdrd.core.calibrate.xǁBiasRecordǁ*",
            "hdrd.core.calibrate.xǁStartupWindowǁ*",
        ],
    ),
}


def find_modules(root: Path = ROOT) -> dict[str, str]:
    """Module name -> its source file relative to the repository (``hdrd/core/hdr.py``), for
    every module of :data:`LAYERS` that has its own test file."""
    found: dict[str, str] = {}
    for layer in LAYERS:
        for src in sorted((root / "hdrd" / layer).rglob("*.py")):
            if src.stem != "__init__" and (root / "tests" / f"test_{src.stem}.py").exists():
                found[src.stem] = src.relative_to(root).as_posix()
    return found


MODULES = find_modules()


def tests_of(module: str) -> list[str]:
    """The test files run against the mutants of ``module``: its own, then :data:`EXTRA`'s."""
    return [f"tests/test_{module}.py", *EXTRA.get(module, ([], None))[0]]


def scope_of(module: str) -> list[str] | None:
    return EXTRA.get(module, ([], None))[1]


TIMEOUT_MULTIPLIER = 5.0
TIMEOUT_CONSTANT_S = 5.0


def mutmut_config(module: str) -> str:
    """The [tool.mutmut] section for one module's run."""
    tests = tests_of(module)
    lines = [
        "",
        "[tool.mutmut]",
        'source_paths = ["hdrd"]',
        f'only_mutate = ["{MODULES[module]}"]',
        f"pytest_add_cli_args_test_selection = {tests!r}",
        # -n0: in mutmut's own process, not on pytest-xdist workers (pyproject's addopts)
        'pytest_add_cli_args = ["-p", "no:cacheprovider", "-m", "not slow", "-n0"]',
        f"timeout_multiplier = {TIMEOUT_MULTIPLIER}",
        f"timeout_constant = {TIMEOUT_CONSTANT_S}",
        "use_git_change_detection = false",
    ]
    return "\n".join(lines).replace("'", '"') + "\n"


def prepare(module: str, base: Path) -> Path:
    """A fresh copy of the tree for one module's run: hdrd/, tests/, pyproject.toml + config."""
    work = base / module
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", ".hypothesis", "*.pyc")
    shutil.copytree(ROOT / "hdrd", work / "hdrd", ignore=ignore)
    shutil.copytree(ROOT / "tests", work / "tests", ignore=ignore)
    text = (ROOT / "pyproject.toml").read_text()
    (work / "pyproject.toml").write_text(text + mutmut_config(module))
    return work


def statuses(work: Path, mutmut: str, env: dict[str, str]) -> dict[str, str]:
    """Mutant name -> status, from ``mutmut results --all true``."""
    p = subprocess.run(
        [mutmut, "results", "--all", "true"], cwd=work, env=env, capture_output=True, text=True
    )
    out: dict[str, str] = {}
    for line in p.stdout.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep and name:
            out[name] = status
    return out


def all_mutants(work: Path, module: str, mutmut: str, env: dict[str, str]) -> list[str]:
    """Every mutant name of the module: mutmut generates them all, then finds nothing to run
    for a name that matches none (and says so; that failure is expected here)."""
    subprocess.run(
        [mutmut, "run", "--max-children", "1", "no-such-mutant"],
        cwd=work,
        env=env,
        capture_output=True,
    )
    meta = work / "mutants" / f"{MODULES[module]}.meta"
    return sorted(json.loads(meta.read_text())["exit_code_by_key"])


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % interval of a proportion k/n (Wilson score)."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    mid = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return mid - half, mid + half


def _in_scope(names: list[str] | dict[str, str], scope: list[str]) -> list[str]:
    """The mutant names that match one of the scope's patterns."""
    return [k for k in names if any(fnmatch.fnmatch(k, p) for p in scope)]


def _scope(
    args: argparse.Namespace, module: str, work: Path, mutmut: str, env: dict[str, str]
) -> list[str] | None:
    """The mutants to run: the module's scope, or with ``--sample`` a seeded random sample of
    it (None: all)."""
    scope = scope_of(module)
    if not args.sample:
        return scope
    names = all_mutants(work, module, mutmut, env)
    if scope is not None:
        names = _in_scope(names, scope)
    return random.Random(args.seed).sample(names, min(args.sample, len(names)))


def _report(
    args: argparse.Namespace,
    module: str,
    work: Path,
    st: dict[str, str],
    scope: list[str] | None,
) -> None:
    """One module's counts and kill rate (%), other statuses, and the survivors if asked."""
    count: dict[str, int] = {}
    for status in st.values():
        count[status] = count.get(status, 0) + 1
    tested = len(st) - count.get("skipped", 0)
    killed = count.get("killed", 0) + count.get("timeout", 0)
    rate = 100.0 * killed / tested if tested else 0.0
    part = "" if scope is None else " (in scope)"
    if args.sample:
        lo, hi = wilson(killed, tested)
        part = (
            f" (a random sample, seed {args.seed}; 95 % interval {100 * lo:.0f}-{100 * hi:.0f} %)"
        )
    print(
        f"{module}: {len(st)} mutants{part}, {count.get('killed', 0)} killed, "
        f"{count.get('timeout', 0)} timed out, {count.get('survived', 0)} survived, "
        f"{count.get('no tests', 0)} with no test; kill rate {rate:.1f} %  ({work})",
        flush=True,
    )
    rest = {
        k: v for k, v in count.items() if k not in ("killed", "timeout", "survived", "no tests")
    }
    if rest:
        print(f"  also: {rest}")
    if args.survivors:
        for name, status in sorted(st.items()):
            if status not in ("killed", "timeout"):
                print(f"  {status}: {name}")


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("modules", nargs="+", choices=sorted(MODULES))
    ap.add_argument("--max-children", type=int, default=1, help="mutants tested at once")
    ap.add_argument("--survivors", action="store_true", help="list the mutants not killed")
    ap.add_argument("--sample", type=int, help="test a random sample of this many mutants")
    ap.add_argument("--seed", type=int, default=1, help="seed of --sample (default 1)")
    ap.add_argument(
        "--workdir",
        type=Path,
        default=Path(tempfile.gettempdir()) / "hdrd-mutation",
        help="where the copies are made (default: $TMPDIR/hdrd-mutation)",
    )
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    mutmut = shutil.which("mutmut")
    if mutmut is None:
        print("tools/mutation.py: mutmut is not installed (pip install mutmut)", file=sys.stderr)
        return 2
    env = dict(os.environ, HYPOTHESIS_PROFILE="mutation")
    env.pop("PYTHONPATH", None)  # the copy's hdrd, as mutmut sets up sys.path, nothing else
    for module in args.modules:
        work = prepare(module, args.workdir)
        scope = _scope(args, module, work, mutmut, env)
        run = subprocess.run(
            [mutmut, "run", "--max-children", str(args.max_children), *(scope or [])],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
        )
        if run.returncode != 0:
            print(run.stdout[-3000:], run.stderr[-3000:], sep="\n", file=sys.stderr)
            print(f"tools/mutation.py: mutmut run failed for {module}", file=sys.stderr)
            return 1
        st = statuses(work, mutmut, env)
        if scope is not None:
            st = {k: st[k] for k in _in_scope(st, scope)}
        _report(args, module, work, st, scope)
    return 0


if __name__ == "__main__":
    sys.exit(main())
