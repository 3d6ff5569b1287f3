"""Structured mutation for tools/fuzz: valid documents made hostile, and bytes made worse.

A document is a tree of dicts, lists and scalars in which any node may be a :class:`Tok`,
text emitted verbatim: so a mutated document can hold what no serialiser would write (an
integer of 5,000 digits, ``NaN``, a lone surrogate, nesting 100,000 deep). :func:`emit_json`
and :func:`emit_yaml` write a tree as text; :func:`mutate_tree` changes a few of its nodes
(huge numbers, NaN/inf, wrong types, deep nesting, control bytes, unicode, giant strings,
unknown or missing keys, and for YAML anchors, aliases, tags, timestamps); :func:`mutate_bytes`
damages the text (truncation, bit flips, inserted, deleted or repeated runs, line breaks,
invalid UTF-8, random bytes).

Everything draws from a :class:`random.Random` the caller seeds per input, so every input is
reproducible from (seed, surface, index). Sizes are bounded (:data:`MAX_GIANT`).
"""

from __future__ import annotations

import json
import math
import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = [
    "MAX_GIANT",
    "Tok",
    "emit_json",
    "emit_yaml",
    "hostile_value",
    "mutate_bytes",
    "mutate_tree",
    "random_bytes",
]

MAX_GIANT = 200_000
"""Longest giant string or run made by a mutator, characters."""


@dataclass(frozen=True)
class Tok:
    """Text emitted as is, in place of a value or a key."""

    text: str


# -- emitting ---------------------------------------------------------------------------------


def _json_str(s: str, rng: random.Random | None = None) -> str:
    # With ensure_ascii a lone surrogate is written as the escape \udXXX, as JSON allows;
    # without, it stays in the text (the caller encodes with surrogatepass: invalid UTF-8).
    ascii_only = rng.random() < 0.5 if rng is not None else False
    return json.dumps(s, ensure_ascii=ascii_only)


def _json_float(v: float) -> str:
    if math.isnan(v):
        return "NaN"
    if math.isinf(v):
        return "Infinity" if v > 0 else "-Infinity"
    return repr(v)


def emit_json(node: Any, rng: random.Random | None = None) -> str:
    """A tree as JSON text (Tok nodes verbatim; NaN and infinities as Python writes them)."""
    if isinstance(node, Tok):
        return node.text
    if isinstance(node, dict):
        return (
            "{"
            + ",".join(f"{_json_key(k, rng)}:{emit_json(v, rng)}" for k, v in node.items())
            + "}"
        )
    if isinstance(node, list):
        return "[" + ",".join(emit_json(v, rng) for v in node) + "]"
    if node is None:
        return "null"
    if isinstance(node, bool):
        return "true" if node else "false"
    if isinstance(node, int):
        return _int_text(node)
    if isinstance(node, float):
        return _json_float(node)
    return _json_str(str(node), rng)


def _json_key(k: Any, rng: random.Random | None) -> str:
    if isinstance(k, Tok):
        return k.text
    return _json_str(str(k), rng)


def _int_text(v: int) -> str:
    try:
        return str(v)
    except ValueError:  # beyond the str-conversion limit: built as text in the first place
        return hex(v)


def _yaml_scalar(v: Any) -> str:
    if isinstance(v, Tok):
        return v.text
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return _int_text(v)
    if isinstance(v, float):
        return _yaml_float(v)
    s = str(v)
    if s and all(c.isalnum() or c in "_-./:" for c in s) and s[0].isalpha() and ":" not in s:
        return s  # a plain scalar, as a person writes it
    # A JSON string is a YAML double-quoted scalar (\uXXXX escapes included).
    return json.dumps(s)


def _yaml_float(v: float) -> str:
    if math.isnan(v):
        return ".nan"
    if math.isinf(v):
        return ".inf" if v > 0 else "-.inf"
    return repr(v)


def _yaml_flow(node: Any) -> str:
    if isinstance(node, dict):
        return "{" + ", ".join(f"{_yaml_scalar(k)}: {_yaml_flow(v)}" for k, v in node.items()) + "}"
    if isinstance(node, list):
        return "[" + ", ".join(_yaml_flow(v) for v in node) + "]"
    return _yaml_scalar(node)


def emit_yaml(node: Any, indent: int = 0, block_depth: int = 2) -> str:
    """A tree as YAML: block style for the first ``block_depth`` levels of mappings (as a
    configuration file is written), flow style below."""
    pad = " " * indent
    if isinstance(node, dict) and node and block_depth > 0:
        out = []
        for k, v in node.items():
            key = _yaml_scalar(k)
            if isinstance(v, dict) and v and block_depth > 1:
                out.append(f"{pad}{key}:\n" + emit_yaml(v, indent + 2, block_depth - 1))
            else:
                out.append(f"{pad}{key}: {_yaml_flow(v)}\n")
        return "".join(out)
    return pad + _yaml_flow(node) + "\n"


# -- hostile values ---------------------------------------------------------------------------

_CONTROL = "".join(chr(c) for c in range(32)) + "\x7f\x85\x9b\x9c\x9d"
_UNICODE = (
    "\u202e\u202d\u2066\u200b\u200d\ufeff\u2028\u2029\u00a0\u0301\u0345\ufffd\uffff"
    "\U0001f600\U0010ffff\u0430\u0435\u0391\u4e2d\u00e9"
)
_ESCAPES = ("\x1b[2J", "\x1b]0;owned\x07", "\x1b[31m", "\x9b6n", "\x07", "\r", "\x08\x08\x08")


def _huge_digits(rng: random.Random) -> str:
    n = rng.choice((20, 310, 400, 4299, 4300, 4301, 5000, 20_000, rng.randint(1, 9000)))
    return rng.choice(("", "-")) + "1" + "0" * (n - 1)


def _random_text(rng: random.Random, n: int) -> str:
    pools = (
        _CONTROL,
        _UNICODE,
        "abcdefghijklmnopqrstuvwxyz0123456789",
        "{}[]\":,#&*!|>'%@`-?\\ \t\n",
    )
    out = []
    for _ in range(n):
        p = rng.choice(pools)
        out.append(rng.choice(p))
    return "".join(out)


def giant_string(rng: random.Random) -> str:
    n = rng.choice((300, 1000, 1000, 4096, 4096, 70_000, MAX_GIANT))
    unit = rng.choice(("A", "\u00e9", "\U0001f600", "\x1b[2J", "%s", "\\", "9"))
    return (unit * (n // len(unit) + 1))[:n]


def deep_nesting(rng: random.Random, kind: str) -> Tok:
    """``[[[...]]]`` or ``{"a": {"a": ...}}`` as text, 2 .. 100,000 deep (bounded in size)."""
    depth = rng.choice((2, 31, 32, 33, 100, 999, 1000, 1001, 5000, 100_000))
    if kind == "yaml" and rng.random() < 0.5:
        return Tok("{a: " * depth + "1" + "}" * depth)
    if rng.random() < 0.5:
        return Tok("[" * depth + "]" * depth)
    key = '"a"' if kind == "json" else "a"
    return Tok(("{" + key + ":") * depth + "1" + "}" * depth)


def _huge_integer(rng: random.Random, kind: str) -> Any:
    return Tok(_huge_digits(rng))


def _huge_float(rng: random.Random, kind: str) -> Any:
    big = rng.choice(("1e308", "1.7976931348623157e308", "1.8e308", "1e400", "5e-324", "1e-400"))
    return Tok(rng.choice(("", "-")) + big)


def _not_a_number(rng: random.Random, kind: str) -> Any:
    if kind == "json":
        return Tok(rng.choice(("NaN", "Infinity", "-Infinity", "nan", "inf", "1e99999")))
    return Tok(rng.choice((".nan", ".NaN", ".inf", "-.inf", "+.inf", ".Inf", "nan", "inf")))


def _edge_integer(rng: random.Random, kind: str) -> Any:
    return rng.choice(
        (0, -1, 1, -0.0, 2**31, 2**32, 2**53 + 1, 2**63, 2**64, -(2**63) - 1, 65535, 65536)
    )


def _wrong_type(rng: random.Random, kind: str) -> Any:
    return rng.choice(([], {}, [1, 2], {"a": 1}, True, False, None, "", " ", "12", "1e3"))


def _text(rng: random.Random, kind: str) -> Any:
    return _random_text(rng, rng.randint(1, 40))


def _escape(rng: random.Random, kind: str) -> Any:
    return rng.choice(_ESCAPES) + _random_text(rng, rng.randint(0, 8))


def _giant(rng: random.Random, kind: str) -> Any:
    return giant_string(rng)


def _surrogate(rng: random.Random, kind: str) -> Any:
    """Lone surrogates and NUL, written as escapes."""
    return Tok(rng.choice(('"\\ud800"', '"\\udfff x"', '"a\\u0000b"', '"\\u001b[2J"')))


def _hostile_list(rng: random.Random, kind: str) -> Any:
    return [hostile_value(rng, kind) for _ in range(rng.randint(0, 5))]


def _hostile_map(rng: random.Random, kind: str) -> Any:
    return {_random_text(rng, rng.randint(0, 6)): hostile_value(rng, kind) for _ in range(3)}


_YAML_TRAPS = (
    "2024-13-45",
    "2024-02-30 25:61:61",
    "0x7fffffffffffffffffff",
    "0o777777777777777777777",
    "0b" + "1" * 200,
    "1_000_000",
    "190:20:30",
    "yes",
    "off",
    "~",
    "!!binary aGVsbG8=",
    "!!python/object/apply:os.system ['true']",
    "!!python/name:os.system",
    "!!float 'x'",
    "!!int '1e3'",
    "!!set {a, b}",
    "!!omap [a: 1, b: 2]",
    "!!timestamp 'not a time'",
    "!foo bar",
    "&a [*a]",
    "*undefined",
    "|\n  literal\n",
    "'unterminated",
    '"\\xff\\x00"',
    "? [complex] : key",
)
"""YAML's own traps: dates, bases, tags (Python's among them), anchors, block scalars."""


def _yaml_trap(rng: random.Random, kind: str) -> Any:
    return Tok(rng.choice(_YAML_TRAPS))


def _scaled_float(rng: random.Random, kind: str) -> Any:
    return rng.uniform(-1e6, 1e6) * rng.choice((1, 1e-300, 1e300))


def _big_integer(rng: random.Random, kind: str) -> Any:
    return rng.randint(-(2**70), 2**70)


def _odd_word(rng: random.Random, kind: str) -> Any:
    return rng.choice(("", "x", "\x00", "-", "0", "HN", "hdr+", "localhost:1", "[::1]:0"))


# By the draw 0..15 (12, YAML's traps, only for YAML: an odd word for JSON).
_HOSTILE: tuple[Callable[[random.Random, str], Any], ...] = (
    _huge_integer, _huge_float, _not_a_number, _edge_integer, _wrong_type, _text, _escape,
    _giant, deep_nesting, _surrogate, _hostile_list, _hostile_map, _yaml_trap, _scaled_float,
    _big_integer, _odd_word,
)  # fmt: skip


def hostile_value(rng: random.Random, kind: str) -> Any:
    """A value of the wrong size, type or shape; *kind* "json" or "yaml" picks the tokens."""
    r = rng.randrange(16)
    if r == 12 and kind != "yaml":
        r = 15
    return _HOSTILE[r](rng, kind)


# -- trees ------------------------------------------------------------------------------------


def _paths(
    node: Any, prefix: tuple[Any, ...] = (), out: list[tuple[Any, ...]] | None = None
) -> list[tuple[Any, ...]]:
    out = [] if out is None else out
    if isinstance(node, dict):
        for k, v in node.items():
            out.append((*prefix, k))
            _paths(v, (*prefix, k), out)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out.append((*prefix, i))
            _paths(v, (*prefix, i), out)
    return out


def _parent(root: Any, path: tuple[Any, ...]) -> Any:
    node = root
    for p in path[:-1]:
        node = node[p]
    return node


def _new_key(rng: random.Random, kind: str, key: Any) -> Any:
    """A key to add beside ``key``: random text, a huge number, null, a list, a merge key, or
    ``key`` again (a duplicate, as text)."""
    new_key: Any = rng.choice(
        (
            _random_text(rng, rng.randint(0, 12)),
            Tok(_huge_digits(rng)) if kind == "yaml" else "x",
            Tok("null") if kind == "yaml" else "",
            Tok("[a, b]") if kind == "yaml" else "class",
            Tok("<<") if kind == "yaml" else "__proto__",
            str(key),  # a duplicate, as text
        )
    )
    if isinstance(new_key, str) and new_key == str(key):
        new_key = Tok(_yaml_scalar(key) if kind == "yaml" else _json_str(str(key)))
    return new_key


def _mutate_node(root: Any, rng: random.Random, kind: str, paths: list[tuple[Any, ...]]) -> None:
    """One node replaced, removed, given a sibling, wrapped or turned into text."""
    path = rng.choice(paths)
    parent = _parent(root, path)
    key = path[-1]
    r = rng.random()
    if r < 0.6:
        parent[key] = hostile_value(rng, kind)
    elif r < 0.72:
        del parent[key]
    elif r < 0.84 and isinstance(parent, dict):
        new_key = _new_key(rng, kind, key)
        parent[new_key] = hostile_value(rng, kind)
    elif r < 0.92:
        parent[key] = [parent[key]] if rng.random() < 0.5 else {"v": parent[key]}
    else:
        v = parent[key]
        parent[key] = str(v) if not isinstance(v, (dict, list, Tok)) else None


def mutate_tree(root: Any, rng: random.Random, kind: str, n: int | None = None) -> Any:
    """*root* (changed in place and returned) with 1..4 nodes replaced, removed or added."""
    for _ in range(n if n is not None else rng.choice((1, 1, 1, 2, 3, 4))):
        paths = _paths(root)
        if not paths:
            return hostile_value(rng, kind)
        _mutate_node(root, rng, kind, paths)
    return root


# -- bytes ------------------------------------------------------------------------------------


def random_bytes(rng: random.Random, n: int) -> bytes:
    return rng.randbytes(n)


_INTERESTING = (0x00, 0x0A, 0x0D, 0x1B, 0x7F, 0x80, 0xA5, 0x5A, 0xC0, 0xFF, 0x24, 0x2A, 0x9B)


def _flip_bit(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    i = rng.randrange(len(b))
    b[i] ^= 1 << rng.randrange(8)


def _interesting_byte(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    b[rng.randrange(len(b))] = rng.choice(_INTERESTING)


def _insert_random(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    i = rng.randint(0, len(b))
    b[i:i] = rng.randbytes(rng.randint(1, 64))


def _delete_run(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    i = rng.randrange(len(b))
    del b[i : i + rng.randint(1, 64)]


def _repeat_run(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    n = len(b)
    i = rng.randrange(n)
    j = min(n, i + rng.randint(1, 256))
    b[j:j] = b[i:j] * rng.randint(1, 64)
    del b[MAX_GIANT * 4 :]


def _truncate(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    del b[rng.randint(0, len(b) - 1) :]


def _insert_token(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    i = rng.randint(0, len(b))
    tok = rng.choice(extra or (b"\n",)) if rng.random() < 0.7 else b"\r\n"
    b[i:i] = tok


def _insert_bad_utf8(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    i = rng.randint(0, len(b))
    b[i:i] = rng.choice((b"\xff\xfe", b"\xc3\x28", b"\xed\xa0\x80", b"\xef\xbb\xbf", b"\x00"))


def _stretch_byte(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    i = rng.randrange(len(b))
    b[i : i + 1] = bytes([b[i]]) * rng.randint(2, 4096)


def _insert_escape(rng: random.Random, b: bytearray, extra: tuple[bytes, ...]) -> None:
    i = rng.randint(0, len(b))
    b[i:i] = rng.choice(_ESCAPES).encode()


# By the draw 0..9, and whether the edit needs a byte to work on (else an escape is inserted).
_BYTE_EDITS: tuple[
    tuple[Callable[[random.Random, bytearray, tuple[bytes, ...]], None], bool], ...
] = (
    (_flip_bit, True),
    (_interesting_byte, True),
    (_insert_random, False),
    (_delete_run, True),
    (_repeat_run, True),
    (_truncate, True),
    (_insert_token, False),
    (_insert_bad_utf8, False),
    (_stretch_byte, True),
    (_insert_escape, False),
)


def mutate_bytes(data: bytes, rng: random.Random, extra: tuple[bytes, ...] = ()) -> bytes:
    """*data* damaged by 1..6 byte-level edits. *extra*: tokens worth inserting (sync
    patterns, separators of the format)."""
    b = bytearray(data)
    for _ in range(rng.choice((1, 1, 2, 3, 6))):
        edit, needs_bytes = _BYTE_EDITS[rng.randrange(10)]
        if needs_bytes and not b:
            edit = _insert_escape
        edit(rng, b, extra)
    return bytes(b)
