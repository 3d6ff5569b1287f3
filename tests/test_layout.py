"""The package's layout, read from the source with ast (so lazy and TYPE_CHECKING imports
count): small modules, no import cycle, no private name crossing a module, nothing but the
command line importing the daemon, every exception under HdrdError, one home for each shared
constant, and the command line's few light copies equal to their homes."""

from __future__ import annotations

import ast
import importlib
import inspect
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "hdrd"
MAX_LINES = 800

# Known defects, each exempt from one rule. The lists may only shrink:
# test_each_exemption_is_still_needed fails once an entry no longer breaks its rule.
TOO_LONG: set[str] = set()
IN_A_CYCLE = {"hdrd.gyronoise", "hdrd.sim.grades"}  # grade_noise <-> GyroNoise
PRIVATE_IMPORTERS: set[str] = set()


def module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def modules() -> dict[str, ast.Module]:
    return {module_name(p): ast.parse(p.read_text(), str(p)) for p in sorted(PKG.rglob("*.py"))}


def imports(tree: ast.Module, known: set[str]) -> set[str]:
    """The hdrd modules a module imports, anywhere in it (``from hdrd import x`` names the
    submodule x when there is one)."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                out.add(sub if sub in known else node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m in known and m != "hdrd"}


def too_long() -> set[str]:
    sizes = {module_name(p): len(p.read_text().splitlines()) for p in PKG.rglob("*.py")}
    assert len(sizes) > 40
    return {m for m, n in sizes.items() if n > MAX_LINES}


def import_graph() -> dict[str, set[str]]:
    mods = modules()
    return {name: imports(tree, set(mods)) - {name} for name, tree in mods.items()}


def private_importers() -> set[str]:
    found = set()
    for name, tree in modules().items():
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("hdrd"):
                if any(a.name.startswith("_") and not a.name.startswith("__") for a in node.names):
                    found.add(name)
    return found


def test_no_module_is_over_800_lines() -> None:
    assert too_long() - TOO_LONG == set()


def test_no_import_cycle() -> None:
    graph = import_graph()
    for m in IN_A_CYCLE:  # its edges among the exempt modules are left out
        graph[m] = graph[m] - IN_A_CYCLE
    # A package's __init__ may import its own modules; they must not import it back.
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(m: str, path: list[str]) -> list[str] | None:
        state[m] = 1
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                return [*path, m, d]
            if d not in state:
                found = visit(d, [*path, m])
                if found:
                    return found
        state[m] = 2
        return None

    cycles = [c for m in sorted(graph) if m not in state and (c := visit(m, [])) is not None]
    assert cycles == []


def test_no_private_name_crosses_a_module() -> None:
    assert private_importers() - PRIVATE_IMPORTERS == set()


def test_each_exemption_is_still_needed() -> None:
    graph = import_graph()
    assert TOO_LONG <= too_long(), "a module is short now: remove it from TOO_LONG"
    assert all(graph[m] & IN_A_CYCLE for m in IN_A_CYCLE), "remove it from IN_A_CYCLE"
    assert PRIVATE_IMPORTERS <= private_importers(), "remove it from PRIVATE_IMPORTERS"


# These drive the daemon object itself in-process (a reload with a hostile configuration, a
# bias choice); nothing offline (replay, evaluate, tune, gap) may reach it.
DAEMON_TESTERS = ["bench/fuzz_targets.py", "tests/test_hardening.py"]


def test_only_the_command_line_imports_the_daemon() -> None:
    importers = []
    for top in ("hdrd", "bench", "tools", "tests"):
        for p in sorted((ROOT / top).rglob("*.py")):
            tree = ast.parse(p.read_text(), str(p))
            for node in ast.walk(tree):
                names = (
                    [node.module or ""]
                    if isinstance(node, ast.ImportFrom)
                    else [a.name for a in node.names]
                    if isinstance(node, ast.Import)
                    else []
                )
                if isinstance(node, ast.ImportFrom) and node.module == "hdrd":
                    names += [f"hdrd.{a.name}" for a in node.names]
                if "hdrd.daemon" in names:
                    importers.append(str(p.relative_to(ROOT)))
    assert sorted(set(importers)) == DAEMON_TESTERS
    # The command line reaches it by name, when `hdrd run` runs.
    from hdrd.cli import COMMANDS

    assert COMMANDS["run"][0] == "hdrd.daemon:main"


def all_modules() -> list[str]:
    return sorted(module_name(p) for p in PKG.rglob("*.py") if p.name != "__main__.py")


@pytest.mark.parametrize("name", all_modules())
def test_every_exception_derives_from_hdrd_error(name: str) -> None:
    from hdrd.errors import HdrdError

    mod = importlib.import_module(name)
    for _, cls in inspect.getmembers(mod, inspect.isclass):
        if cls.__module__ == name and issubclass(cls, BaseException):
            assert issubclass(cls, HdrdError), f"{name}.{cls.__name__}"


SHARED = (
    "EX_CONFIG",
    "EX_USAGE",
    "SCHEMA_VERSION",
    "MESSAGE_CLASS",
    "PROTOCOLS",
    "NMEA_TALKER",
    "TEMP_NOT_FITTED",
    "CLOCK_WRAP_US",
    "RESET_THRESHOLD_US",
    "REGISTRY",
)


def test_each_shared_constant_is_defined_once() -> None:
    homes: dict[str, list[str]] = {k: [] for k in SHARED}
    for name, tree in modules().items():
        for node in tree.body:
            targets = (
                node.targets
                if isinstance(node, ast.Assign)
                else [node.target]
                if isinstance(node, ast.AnnAssign)
                else []
            )
            for t in targets:
                if isinstance(t, ast.Name) and t.id in homes:
                    homes[t.id].append(name)
    assert {k: v for k, v in homes.items() if len(v) != 1} == {}


def test_the_command_lines_light_copies_equal_their_homes() -> None:
    """hdrd/cli.py imports nothing heavy (``hdrd --help`` loads no numpy), so it repeats a
    few defaults instead of importing their modules; they must stay equal."""
    from hdrd import config, gpsd, tail
    from hdrd.cli import DRIVES, build_parser

    assert DRIVES == config.DRIVES
    parser = build_parser()
    assert parser.parse_args(["run", "--gpsd"]).gpsd == f"{gpsd.DEFAULT_HOST}:{gpsd.DEFAULT_PORT}"
    assert parser.parse_args(["tail"]).listen == tail.DEFAULT_TAIL_LISTEN
