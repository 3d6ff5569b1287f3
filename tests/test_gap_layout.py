"""The model-gap package's layout: small modules, no private name crossing a module boundary,
no import cycle between its modules (read from the source with ast, so lazy imports count)."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "hdrd" / "analysis" / "gap"
PREFIX = "hdrd.analysis.gap"
MAX_LINES = 500


def modules() -> dict[str, ast.Module]:
    return {p.stem: ast.parse(p.read_text(), str(p)) for p in sorted(PKG.glob("*.py"))}


def sibling_imports(tree: ast.Module) -> list[tuple[str, list[str]]]:
    """(sibling module, names imported from it) for every import of the package's modules."""
    out: list[tuple[str, list[str]]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module == PREFIX:
                out.append(("__init__", [a.name for a in node.names]))
            elif node.module.startswith(PREFIX + "."):
                out.append((node.module[len(PREFIX) + 1 :], [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith(PREFIX + "."):
                    out.append((a.name[len(PREFIX) + 1 :], []))
    return out


def test_every_module_is_small() -> None:
    sizes = {p.name: len(p.read_text().splitlines()) for p in PKG.glob("*.py")}
    assert len(sizes) >= 8
    assert {k: v for k, v in sizes.items() if v > MAX_LINES} == {}


def test_no_private_name_crosses_a_module() -> None:
    crossing = []
    mods = modules()  # parsed once (not once per attribute node)
    for name, tree in mods.items():
        for target, names in sibling_imports(tree):
            crossing += [f"{name} imports {target}.{n}" for n in names if n.startswith("_")]
        for node in ast.walk(tree):  # module._private through an imported module object
            if (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and isinstance(node.value, ast.Name)
                and node.value.id in mods
            ):
                crossing.append(f"{name} uses {node.value.id}.{node.attr}")
    assert crossing == []


def test_no_import_cycle() -> None:
    mods = modules()
    graph = {name: {t for t, _ in sibling_imports(tree)} for name, tree in mods.items()}
    # Only the package's __init__ may import from the package itself.
    assert [m for m, deps in graph.items() if "__init__" in deps and m != "__init__"] == []
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(m: str, path: list[str]) -> list[str] | None:
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                return [*path, m, d]
            if d not in state:
                found = visit(d, [*path, m])
                if found:
                    return found
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            assert visit(m, []) is None
