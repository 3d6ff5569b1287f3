"""The package's layout, read from the source with ast (so lazy and TYPE_CHECKING imports
count): small modules, no import cycle, each layer importing only the layers below it, no
private name crossing a module, only the run command importing the daemon's loop, every
command a module of its own and reached only through the command line, every exception under
HdrdError, one home for each shared constant, and the command line's few light copies equal
to their homes."""

from __future__ import annotations

import ast
import functools
import importlib
import inspect
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "hdrd"
MAX_LINES = 600

# Known defects, each exempt from one rule. The lists may only shrink:
# test_each_exemption_is_still_needed fails once an entry no longer breaks its rule.
TOO_LONG: set[str] = set()
IN_A_CYCLE: set[str] = set()
PRIVATE_IMPORTERS: set[str] = set()


def module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


@functools.cache
def parsed(path: Path) -> ast.Module:
    """A source file's tree, parsed once for all the tests here (none changes a tree)."""
    return ast.parse(path.read_text(), str(path))


def modules() -> dict[str, ast.Module]:
    return {module_name(p): parsed(p) for p in sorted(PKG.rglob("*.py"))}


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


def test_no_module_is_over_600_lines() -> None:
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


def unexplained_inner_imports(name: str, text: str) -> list[str]:
    """hdrd imports inside a function without a comment on the line before (or on the line)
    saying why they are not at the module's top."""
    lines = text.splitlines()
    out = []
    for fn in ast.walk(ast.parse(text)):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("hdrd"):
                k = node.lineno - 2  # the comment may head a block of imports
                while k > 0 and lines[k].strip().startswith(("from ", "import ")):
                    k -= 1
                if "#" not in lines[node.lineno - 1] and not lines[k].strip().startswith("#"):
                    out.append(f"{name}:{node.lineno} {node.module}")
    return sorted(set(out))


def test_an_import_inside_a_function_says_why() -> None:
    """An hdrd module imported inside a function breaks a real cost (a fast path that must not
    load it) or a cycle, and says which; the others are at the module's top."""
    found = [
        x
        for p in sorted(PKG.rglob("*.py"))
        for x in unexplained_inner_imports(module_name(p), p.read_text())
    ]
    assert found == []
    bare = "def f():\n    x = 1\n    from hdrd.cli import main\n"
    said = "def f():\n    # why: a cycle\n    from hdrd.cli import main\n"
    assert unexplained_inner_imports("m", bare) == ["m:3 hdrd.cli"]
    assert unexplained_inner_imports("m", said) == []
    block = said.replace("main\n", "main\n    from hdrd.errors import HdrdError\n")
    assert unexplained_inner_imports("m", block) == []


def test_no_private_name_crosses_a_module() -> None:
    assert private_importers() - PRIVATE_IMPORTERS == set()


def test_each_exemption_is_still_needed() -> None:
    graph = import_graph()
    assert TOO_LONG <= too_long(), "a module is short now: remove it from TOO_LONG"
    assert all(graph[m] & IN_A_CYCLE for m in IN_A_CYCLE), "remove it from IN_A_CYCLE"
    assert PRIVATE_IMPORTERS <= private_importers(), "remove it from PRIVATE_IMPORTERS"


# The layers, lowest first, and what each may import besides itself and the modules every
# layer may use (docs/development.md draws them). A module's layer is its folder under hdrd/;
# the top-level modules are their own layers.
SHARED_MODULES = {"hdrd", "hdrd.errors"}
LAYERS: dict[str, set[str]] = {
    "core": set(),
    "io": {"core"},
    "sim": {"core", "io"},
    "config": {"core", "io", "sim"},
    # ... and reading one: each key's rule, a file, the command line's overrides
    "configload": {"core", "io", "sim", "config"},
    "daemon": {"core", "io", "sim", "config"},
    "analysis": {"core", "io", "sim", "config", "daemon"},
    "commands": {
        "core",
        "io",
        "sim",
        "config",
        "configload",
        "daemon",
        "analysis",
        "cli",
        "cliconfig",
    },
    # The command line: signals held from the start, the wire formats, and lazily the method
    # registry and the simulator's drives (for choices); a command only by name, when it runs.
    "cli": {"core", "sim", "daemon", "io", "commands", "cliargs", "clicommands"},
    # ... and its table of commands, each with its options (light, as the command line is)
    "clicommands": {"core", "sim", "io", "cliargs"},
    # ... and its shared option groups (light: choices read lazily)
    "cliargs": {"core", "sim", "io"},
    # ... and the one reading of a configuration from the flags, for every command
    "cliconfig": {"core", "io", "sim", "config", "configload", "daemon", "analysis"},
    "__main__": {"cli", "daemon"},
}


def layer_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "hdrd"


def test_every_module_has_a_layer() -> None:
    assert {layer_of(m) for m in modules()} - set(LAYERS) - {"hdrd", "errors"} == set()


def test_each_layer_imports_only_the_layers_below_it() -> None:
    wrong = []
    for name, deps in import_graph().items():
        here = layer_of(name)
        allowed = LAYERS.get(here, set()) | {here}
        for d in deps - SHARED_MODULES:
            if layer_of(d) not in allowed:
                wrong.append(f"{name} -> {d}")
    assert wrong == []


def test_the_layer_rules_are_not_empty_words() -> None:
    # The rule above sees each kind of import: a core module reaching for the daemon, lazily,
    # would be caught.
    tree = ast.parse("def f():\n    from hdrd.daemon.pipeline import Pipeline\n")
    assert "hdrd.daemon.pipeline" in imports(tree, set(modules()))
    assert layer_of("hdrd.daemon.pipeline") not in LAYERS["core"]


# io/'s rooms, lowest first: each imports only the rooms before it and io's shared modules,
# which import no room (docs/development.md draws them).
IO_ROOMS = ("wire", "files", "net", "web")
IO_SHARED = {"hdrd.io", "hdrd.io.logs", "hdrd.io.resolve"}


def room_of(module: str) -> str | None:
    """A module's room of io/ ("" for io's shared modules); None outside io/."""
    parts = module.split(".")
    if parts[:2] != ["hdrd", "io"]:
        return None
    return parts[2] if len(parts) > 3 or parts[2:] and parts[2] in IO_ROOMS else ""


def test_every_io_module_is_in_a_room_or_shared() -> None:
    io = {m for m in modules() if room_of(m) is not None}
    assert {m for m in io if room_of(m) == ""} == IO_SHARED
    assert {room_of(m) for m in io} - {""} == set(IO_ROOMS)
    assert {
        p.name for p in (PKG / "io").iterdir() if p.is_dir() and p.name != "__pycache__"
    } == set(IO_ROOMS)


def rooms_climbing(graph: dict[str, set[str]]) -> list[str]:
    floor = {"": 0, **{r: i + 1 for i, r in enumerate(IO_ROOMS)}}
    wrong = []
    for name, deps in graph.items():
        here = room_of(name)
        for d in deps:
            there = room_of(d)
            if here is not None and there is not None and floor[there] > floor[here]:
                wrong.append(f"{name} -> {d}")
    return sorted(wrong)


def test_each_room_of_io_imports_only_the_rooms_below_it() -> None:
    graph = import_graph()
    assert rooms_climbing(graph) == []
    # the rule sees an arrow up, lazy or not: the wire reaching for the web page, the shared
    # logging for a file format
    lazy = ast.parse("def f():\n    from hdrd.io.web.webserver import WebServer\n")
    graph["hdrd.io.wire.parser"] = imports(lazy, set(graph))
    graph["hdrd.io.logs"] = {"hdrd.io.files.access"}
    assert rooms_climbing(graph) == [
        "hdrd.io.logs -> hdrd.io.files.access",
        "hdrd.io.wire.parser -> hdrd.io.web.webserver",
    ]


def analysis_climbing(graph: dict[str, set[str]]) -> list[str]:
    """Arrows from analysis/'s shared modules (the package and the modules directly in it) to a
    module of one of its sub-folders (gap/, which sits above them)."""
    subs = {f"hdrd.analysis.{p.name}" for p in (PKG / "analysis").iterdir() if p.is_dir()}
    subs.discard("hdrd.analysis.__pycache__")
    wrong = []
    for name, deps in graph.items():
        shared = name.count(".") == 2 and name.startswith("hdrd.analysis.") and name not in subs
        if name == "hdrd.analysis" or shared:
            up = {d for d in deps if any(d == s or d.startswith(s + ".") for s in subs)}
            wrong += [f"{name} -> {d}" for d in up]
    return sorted(wrong)


def test_analysis_shared_modules_never_import_a_sub_folder() -> None:
    graph = import_graph()
    assert any(m.startswith("hdrd.analysis.gap.") for m in graph)
    assert (PKG / "analysis" / "gap").is_dir()
    assert analysis_climbing(graph) == []
    # the rule sees an arrow up, lazy or not: a fleet job reaching for gap's search
    lazy = ast.parse("def f():\n    from hdrd.analysis.gap.search import run_gap\n")
    graph["hdrd.analysis.fleet_jobs"] = imports(lazy, set(graph))
    assert analysis_climbing(graph) == ["hdrd.analysis.fleet_jobs -> hdrd.analysis.gap.search"]


def test_the_web_page_ships_as_package_data() -> None:
    """pyproject.toml's package data names every file of the page the server reads."""
    import tomllib

    from hdrd.io.web.webserver import ASSETS

    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    shipped = {p for pattern in data["package-data"]["hdrd"] for p in PKG.glob(pattern)}
    page = PKG / "io" / "web" / "webpage"
    assert {page / name for name, _ in ASSETS.values()} <= shipped
    assert all(p.is_file() for p in shipped)


NO_COMMAND_LINE = ("core", "io", "sim", "daemon", "analysis")
"""Layers that never see the command line: they take typed values (commands/ turns the flags
into them), so none imports argparse, even lazily."""


def test_argparse_stays_in_the_command_line_layers() -> None:
    found = []
    for layer in NO_COMMAND_LINE:
        for p in sorted((PKG / layer).rglob("*.py")):
            for node in ast.walk(parsed(p)):
                names = (
                    [a.name for a in node.names]
                    if isinstance(node, ast.Import)
                    else [node.module or ""]
                    if isinstance(node, ast.ImportFrom)
                    else []
                )
                if any(n == "argparse" or n.startswith("argparse.") for n in names):
                    found.append(str(p.relative_to(ROOT)))
    assert found == []
    assert any((PKG / layer).is_dir() for layer in NO_COMMAND_LINE)
    # the rule sees a lazy import too
    lazy = ast.parse("def f():\n    from argparse import Namespace\n")
    assert any(isinstance(n, ast.ImportFrom) and n.module == "argparse" for n in ast.walk(lazy))


# These drive the daemon's run loop itself in-process (a reload with a hostile configuration, a
# bias choice, a whole run on the simulated gyro); nothing offline (replay, evaluate, tune, gap) may reach it.
DAEMON_TESTERS = [
    "hdrd/commands/run.py",
    "tests/test_hardening.py",
    "tests/test_run.py",  # the run loop's own tests
    "tools/fuzz/filetargets.py",  # the fuzzer: a daemon built from a fuzzed file, reloaded
    "tools/fuzz/targets.py",  # the fuzzer: the run loop's frame edge
]


def test_only_the_run_command_imports_the_run_loop() -> None:
    importers = []
    for top in ("hdrd", "bench", "tools", "tests"):
        for p in sorted((ROOT / top).rglob("*.py")):
            tree = parsed(p)
            for node in ast.walk(tree):
                names = (
                    [node.module or ""]
                    if isinstance(node, ast.ImportFrom)
                    else [a.name for a in node.names]
                    if isinstance(node, ast.Import)
                    else []
                )
                if isinstance(node, ast.ImportFrom) and node.module == "hdrd.daemon":
                    names += [f"hdrd.daemon.{a.name}" for a in node.names]
                if "hdrd.daemon.run" in names:
                    importers.append(str(p.relative_to(ROOT)))
    assert sorted(set(importers)) == DAEMON_TESTERS
    # The command line reaches it by name, when `hdrd run` runs.
    from hdrd.clicommands import COMMANDS

    assert COMMANDS["run"][0] == "hdrd.commands.run:main"


# commands/ only parses and calls: the package, bench/ and tests/ reach a command through the
# command line (hdrd.cli.main, or a subprocess), never by importing it. Known exemptions, each
# file with the command modules it still imports; the list may only shrink.
COMMAND_IMPORTERS: dict[str, set[str]] = {}


def command_importers() -> dict[str, set[str]]:
    """File (relative to the repository) -> the hdrd.commands modules it imports, for every
    file of hdrd/ outside commands/, bench/ and tests/."""
    found: dict[str, set[str]] = {}
    for top in ("hdrd", "bench", "tests"):
        for p in sorted((ROOT / top).rglob("*.py")):
            rel = p.relative_to(ROOT).as_posix()
            if rel.startswith("hdrd/commands/"):
                continue
            names: set[str] = set()
            for node in ast.walk(parsed(p)):
                if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    if node.module == "hdrd.commands":
                        names.update(f"hdrd.commands.{a.name}" for a in node.names)
                    elif node.module.startswith("hdrd.commands."):
                        names.add(node.module)
                elif isinstance(node, ast.Import):
                    names.update(a.name for a in node.names if a.name.startswith("hdrd.commands"))
            if names:
                found[rel] = names
    return found


def test_commands_are_reached_only_through_the_command_line() -> None:
    found = command_importers()
    assert found.pop("hdrd/cli.py", None) is None  # the command line names them, lazily
    wrong = {f: n - COMMAND_IMPORTERS.get(f, set()) for f, n in found.items()}
    assert {f: n for f, n in wrong.items() if n} == {}
    # the rule sees each kind of import
    tree = ast.parse("def f():\n    from hdrd.commands import replay\n")
    assert "hdrd.commands.replay" in imports(tree, set(modules()))


def test_each_command_importer_exemption_is_still_needed() -> None:
    found = command_importers()
    stale = {f: n - found.get(f, set()) for f, n in COMMAND_IMPORTERS.items()}
    assert {f: n for f, n in stale.items() if n} == {}, "remove it from COMMAND_IMPORTERS"


def test_every_command_is_a_module_of_its_own() -> None:
    from hdrd.clicommands import COMMANDS

    for name, (target, _, _) in COMMANDS.items():
        module, _, func = target.partition(":")
        assert module.startswith("hdrd.commands."), name
        assert callable(getattr(importlib.import_module(module), func)), name


def all_modules() -> list[str]:
    return sorted(module_name(p) for p in PKG.rglob("*.py") if p.name != "__main__.py")


@pytest.mark.parametrize("name", all_modules())
def test_every_exception_derives_from_hdrd_error(name: str) -> None:
    from hdrd.errors import HdrdError

    mod = importlib.import_module(name)
    for _, cls in inspect.getmembers(mod, inspect.isclass):
        # (a KeyboardInterrupt carrying what was done is not an error: not an Exception)
        if cls.__module__ == name and issubclass(cls, Exception):
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
    """hdrd/cli.py and its table of commands, hdrd/clicommands.py, import nothing heavy
    (``hdrd --help`` loads no numpy), so the table repeats a few defaults instead of importing
    their modules; they must stay equal."""
    from hdrd.cli import build_parser
    from hdrd.io.net import datagrams, gpsd
    from hdrd.io.web import webserver

    parser = build_parser()
    assert parser.parse_args(["run", "--gpsd"]).gpsd == f"{gpsd.DEFAULT_HOST}:{gpsd.DEFAULT_PORT}"
    assert parser.parse_args(["tail"]).listen == datagrams.DEFAULT_TAIL_LISTEN
    web = parser.parse_args(["web"])
    assert web.listen == webserver.DEFAULT_WEB_LISTEN and web.udp == datagrams.DEFAULT_TAIL_LISTEN
    assert web.max_clients == webserver.DEFAULT_MAX_CLIENTS


# Function size: at most 60 lines (def to last line) and a cyclomatic complexity of at most 15,
# counted as radon counts it, unless the docstring gives the reason ("Long because ...",
# "Complex because ..."); in the package, and in bench/ and tools/ beside it.
MAX_FUNCTION_LINES = 60
MAX_COMPLEXITY = 15
SCRIPTS = (ROOT / "bench", ROOT / "tools")
# Files whose functions are not held to the limits (none: every file is).
SIZE_EXEMPT: set[str] = set()
# Functions still to split, as "path:name"; the list may only shrink.
UNSPLIT: set[str] = set()


def complexity(func: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """McCabe's cyclomatic complexity of one function, by radon's rules (``radon cc``): 1, plus
    1 for each if, conditional expression, loop, loop's else, except clause, try's else, assert,
    comprehension and comprehension's if, match case other than the wildcard, and each operand
    of a boolean operator past the first. Nested functions and classes count on their own; a
    lambda counts in the function it is written in; radon looks no further into an assert."""
    total = 1
    todo: list[ast.AST] = list(func.body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            continue
        if isinstance(node, ast.Assert):
            total += 1
            continue
        if isinstance(node, ast.Try):
            total += len(node.handlers) + bool(node.orelse)
        elif isinstance(node, ast.BoolOp):
            total += len(node.values) - 1
        elif isinstance(node, (ast.If, ast.IfExp)):
            total += 1
        elif isinstance(node, ast.Match):
            wildcard = any(getattr(c.pattern, "pattern", False) is None for c in node.cases)
            total += max(0, len(node.cases) - wildcard)
        elif isinstance(node, (ast.For, ast.AsyncFor, ast.While)):
            total += 1 + bool(node.orelse)
        elif isinstance(node, ast.comprehension):
            total += 1 + len(node.ifs)
        todo.extend(ast.iter_child_nodes(node))
    return total


def oversized(tree: ast.Module) -> list[str]:
    """Each function over the line or complexity limit whose docstring does not say why."""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        doc = ast.get_docstring(node) or ""
        lines = (node.end_lineno or node.lineno) - node.lineno + 1
        cc = complexity(node)
        if lines > MAX_FUNCTION_LINES and "Long because" not in doc:
            found.append(f"{node.name}:{node.lineno} is {lines} lines")
        if cc > MAX_COMPLEXITY and "Complex because" not in doc:
            found.append(f"{node.name}:{node.lineno} has complexity {cc}")
    return found


def held_to_size() -> list[Path]:
    """The files whose functions are held to the size rule: the package's, bench/'s, tools/'."""
    files = [p for d in (PKG, *SCRIPTS) for p in sorted(d.rglob("*.py"))]
    rel = {p.relative_to(ROOT).as_posix() for p in files}
    # the walk reaches each folder (a moved folder would otherwise pass as empty)
    assert {"hdrd/cli.py", "bench/tables.py", "tools/fuzz/drivelog.py"} <= rel
    return files


def oversized_everywhere() -> dict[str, list[str]]:
    found = {}
    for p in held_to_size():
        rel = p.relative_to(ROOT).as_posix()
        if rel not in SIZE_EXEMPT and (bad := oversized(ast.parse(p.read_text(), rel))):
            found[rel] = bad
    return found


def test_no_function_is_too_long_or_too_complex_without_a_reason() -> None:
    found = {
        f"{path}:{what}"
        for path, bad in oversized_everywhere().items()
        for what in bad
        if f"{path}:{what.partition(':')[0]}" not in UNSPLIT
    }
    assert found == set()


def test_each_unsplit_function_is_still_oversized() -> None:
    found = {f"{p}:{w.partition(':')[0]}" for p, bad in oversized_everywhere().items() for w in bad}
    assert UNSPLIT <= found, "a function is within the limits now: remove it from UNSPLIT"


# A module of bench/ or tools/ (a script, or a piece of one) is at most 600 lines.
MAX_SCRIPT_LINES = 600


def scripts_too_long(folders: tuple[Path, ...]) -> dict[str, int]:
    """The Python files under ``folders`` over :data:`MAX_SCRIPT_LINES`, with their lengths."""
    sizes = {p: len(p.read_text().splitlines()) for d in folders for p in d.rglob("*.py")}
    return {p.name: n for p, n in sizes.items() if n > MAX_SCRIPT_LINES}


def test_no_bench_or_tools_module_is_over_600_lines() -> None:
    assert sum(1 for d in SCRIPTS for _ in d.rglob("*.py")) > 40  # the walk finds the scripts
    assert scripts_too_long(SCRIPTS) == {}


def test_the_script_size_rule_sees_a_long_file(tmp_path: Path) -> None:
    (tmp_path / "ok.py").write_text("x = 1\n" * MAX_SCRIPT_LINES)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "long.py").write_text("x = 1\n" * (MAX_SCRIPT_LINES + 1))
    assert scripts_too_long((tmp_path,)) == {"long.py": MAX_SCRIPT_LINES + 1}


def test_the_size_rule_counts_as_radon_does() -> None:
    source = '''
def f(xs, y):
    """Complex because it is a sample."""
    for x in xs:                      # +1
        if x and y or not x:          # +1, +1 +1
            continue
    else:                             # +1
        pass
    try:
        z = [a for a in xs if a if y]  # +1 +2
    except ValueError:                # +1
        z = None
    except KeyError:                  # +1
        z = 1 if y else 2             # +1
    else:                             # +1
        pass
    assert y and xs                   # +1 (radon does not look inside)
    while y:                          # +1
        y = lambda: 3 if xs else 4    # +1
    def g():                          # counts on its own
        if y:
            pass
    match y:
        case 1:                       # +1
            pass
        case [2, 3]:                  # +1
            pass
        case _:
            pass
    with open(y):
        pass
    return z
'''
    tree = ast.parse(source)
    f = tree.body[0]
    assert isinstance(f, ast.FunctionDef)
    assert complexity(f) == 18
    assert oversized(tree) == []
    f.body[0] = ast.Expr(ast.Constant("no reason"))
    assert oversized(tree) == ["f:2 has complexity 18"]
