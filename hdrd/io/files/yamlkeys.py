"""A key given twice in one YAML mapping, found in the text and named with both lines.

YAML keeps the last of two equal keys without a word: ``hdr: {method: hdr+, method: none}``
runs ``none``, and of two ``hdr:`` sections the first is dropped. hdrd refuses such a file
instead (its configuration, a bias file, a gyro error model). YAML's merge key (``<<``)
overrides on purpose and is not a duplicate; an alias repeats a node, not a key.

Run on a text :func:`hdrd.io.files.access.load_yaml` has read (its size, nesting depth and
characters already checked): the text is composed again into nodes, which carry their lines.
Each node is looked at once, so aliases nested into a large graph (a "billion laughs") cost
what their few nodes cost.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["DuplicateKey", "duplicate_key"]

_MERGE = "tag:yaml.org,2002:merge"


@dataclass(frozen=True, slots=True)
class DuplicateKey:
    """A key given twice in one mapping: its path (``hdr.method``, ``output.udp[0]``) and the
    1-based lines of both."""

    path: str
    first_line: int
    second_line: int

    def __str__(self) -> str:
        return (
            f"{self.path} given twice (line {self.first_line} and line {self.second_line}); "
            "give each key once"
        )


def duplicate_key(text: str) -> DuplicateKey | None:
    """A key given twice in one mapping of the YAML document ``text`` (a mapping's own keys
    are looked at before the mappings inside it), or None. ``text`` must be one that :func:`hdrd.io.files.access.load_yaml` has read."""
    import yaml  # here, not at the top: as load_yaml's

    root = yaml.compose(text, Loader=yaml.SafeLoader)
    if root is None:
        return None
    seen: set[int] = set()
    stack: list[tuple[Any, str]] = [(root, "")]
    while stack:
        node, path = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        children: list[tuple[Any, str]] = []
        if isinstance(node, yaml.MappingNode):
            lines: dict[tuple[str, str], int] = {}
            for key, value in node.value:
                name = _key_name(key, yaml)
                if name is not None and key.tag != _MERGE:
                    line = key.start_mark.line + 1
                    ident = (key.tag, key.value)
                    if ident in lines:
                        return DuplicateKey(_join(path, name), lines[ident], line)
                    lines[ident] = line
                children.append((value, _join(path, name if name is not None else "?")))
        elif isinstance(node, yaml.SequenceNode):
            children = [(item, f"{path}[{i}]") for i, item in enumerate(node.value)]
        stack.extend(reversed(children))  # popped in document order
    return None


def _key_name(key: Any, yaml: Any) -> str | None:
    """A scalar key's text (None for a mapping or a sequence used as a key)."""
    return str(key.value) if isinstance(key, yaml.ScalarNode) else None


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name
