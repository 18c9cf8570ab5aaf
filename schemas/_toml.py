"""Reading TOML with limits on size and nesting, for every TOML file the project reads.

``tomllib`` parses arrays and inline tables recursively: a file of 100 kB that opens 50 000
brackets is a ``RecursionError`` (a traceback, not a message). :func:`loads_toml` measures the
bracket and brace depth first (outside strings and comments) and refuses deep or oversized
text with :class:`TomlLimitError`, a ``tomllib.TOMLDecodeError``: every caller that already
reports invalid TOML in one line reports these the same way. The scan is written here because
no TOML library offers a depth limit.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ["MAX_TOML_BYTES", "MAX_TOML_DEPTH", "TomlLimitError", "load_toml", "loads_toml"]

#: Largest TOML file read. The project's files (topic maps with message definitions, catalogs
#: of a few hundred objects, rig configurations) are below 100 kB; 4 MB leaves room for any lab
#: and keeps a hostile file from costing more than a moment to scan.
MAX_TOML_BYTES = 4 * 1024 * 1024
#: Deepest nesting of arrays, inline tables and tables accepted. The project's files nest at
#: most 4 levels; tomllib recurses once per level and Python stops at ~1000 frames.
MAX_TOML_DEPTH = 32

#: What the depth scan skips: comments and the four kinds of strings; and the brackets it counts.
_TOKENS = re.compile(
    r"#[^\n]*"
    r'|"""(?:\\.|[^\\])*?"""'
    r"|'''.*?'''"
    r'|"(?:\\.|[^"\\\n])*"'
    r"|'[^'\n]*'"
    r"|[\[\]{}]",
    re.DOTALL,
)


class TomlLimitError(tomllib.TOMLDecodeError):
    """The TOML text is larger or nests deeper than the project reads."""


def _bracket_depth(text: str) -> int:
    """Return the deepest nesting of brackets and braces outside comments and strings.

    An unterminated string is scanned as text (its brackets count: a refusal, never a miss);
    a closing bracket never brings the depth below zero.
    """
    depth = deepest = 0
    for match in _TOKENS.finditer(text):
        bracket = match.group()
        if bracket in {"[", "{"}:
            depth += 1
            deepest = max(deepest, depth)
        elif bracket in {"]", "}"}:
            depth = max(depth - 1, 0)
    return deepest


def _value_depth(value: object) -> int:
    """Return how deep tables and arrays nest in a parsed value (dotted keys nest too)."""
    deepest = 0
    stack: list[tuple[object, int]] = [(value, 0)]
    while stack:  # a loop, not recursion: the value may nest deeper than Python recurses
        item, depth = stack.pop()
        children = (
            item.values() if isinstance(item, dict) else item if isinstance(item, list) else None
        )
        if children is None:
            continue
        deepest = max(deepest, depth)
        stack.extend((child, depth + 1) for child in children)
    return deepest


def loads_toml(text: str, *, parse_float: Callable[[str], Any] = float) -> dict[str, Any]:
    """Return ``tomllib.loads(text)`` for text within :data:`MAX_TOML_BYTES` and depth limits.

    Raises:
        TomlLimitError: The text is longer than :data:`MAX_TOML_BYTES` or nests deeper than
            :data:`MAX_TOML_DEPTH`.
        tomllib.TOMLDecodeError: The text is not valid TOML.
    """
    if len(text) > MAX_TOML_BYTES:
        msg = f"{len(text)} characters, more than the {MAX_TOML_BYTES} a TOML file may have"
        raise TomlLimitError(msg)
    if (depth := _bracket_depth(text)) > MAX_TOML_DEPTH:
        msg = f"arrays or tables nested {depth} deep, more than the {MAX_TOML_DEPTH} allowed"
        raise TomlLimitError(msg)
    table = tomllib.loads(text, parse_float=parse_float)
    if (depth := _value_depth(table)) > MAX_TOML_DEPTH:
        msg = f"keys nested {depth} deep, more than the {MAX_TOML_DEPTH} allowed"
        raise TomlLimitError(msg)
    return table


def load_toml(path: Path | str, *, parse_float: Callable[[str], Any] = float) -> dict[str, Any]:
    """Return the TOML file at ``path`` parsed by :func:`loads_toml`, refusing a large file unread.

    Raises:
        TomlLimitError: The file is larger than :data:`MAX_TOML_BYTES` or nests too deep.
        tomllib.TOMLDecodeError: The file is not valid TOML.
        OSError: The file cannot be read.
        UnicodeDecodeError: The file is not UTF-8.
    """
    with Path(path).open("rb") as file:
        data = file.read(MAX_TOML_BYTES + 1)
    if len(data) > MAX_TOML_BYTES:
        msg = f"the file is larger than the {MAX_TOML_BYTES} bytes a TOML file may have"
        raise TomlLimitError(msg)
    return loads_toml(data.decode("utf-8"), parse_float=parse_float)
