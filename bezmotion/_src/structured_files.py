"""JSON and TOML files from users, read with bounds: a file nested thousands deep, not UTF-8
or not valid gives one ``ValueError``, never a ``RecursionError`` from the parsers."""

from __future__ import annotations

import json
import os
import re
import tomllib
from pathlib import Path
from typing import Any

from bezmotion._src.messages import one_line

MAX_NESTING = 32
"""How deep the lists and tables of a JSON or TOML file (:func:`read_structured_file`) may
nest: a handles file or a mapping is 4 deep at most. Python's JSON and TOML parsers recurse,
so a file nested thousands deep would otherwise end in a ``RecursionError``."""

# What may hold a bracket that opens or closes nothing: strings (and TOML's comments). An
# unterminated string matches to the end of the text, so that a scan never backtracks.
_SKIPPED = {
    "JSON": [r'"(?:[^"\\]|\\.)*"?'],
    "TOML": [r'"""(?:[^\\]|\\.)*?(?:"""|\Z)', r"'''.*?(?:'''|\Z)", r'"(?:[^"\\\n]|\\.)*"?', r"'[^'\n]*'?", r"#[^\n]*"],
}
_BRACKETS = {kind: re.compile("|".join([*skipped, r"[\[\]{}]"]), re.DOTALL) for kind, skipped in _SKIPPED.items()}


def _nesting_line(text: str, kind: str) -> int | None:
    """The line where ``text``'s brackets first nest deeper than :data:`MAX_NESTING`, or ``None``."""
    depth = 0
    for match in _BRACKETS[kind].finditer(text):
        bracket = match.group()
        if bracket in ("[", "{"):
            depth += 1
            if depth > MAX_NESTING:
                return text.count("\n", 0, match.start()) + 1
        elif bracket in ("]", "}"):
            depth = max(depth - 1, 0)
    return None


def _nesting(value: Any) -> int:
    """How deep ``value``'s lists and dicts nest (``[[1]]``: 2), counted without recursion up
    to one past :data:`MAX_NESTING` (TOML's dotted keys nest tables without brackets)."""
    deepest, stack = 0, [(value, 1)]
    while stack and deepest <= MAX_NESTING:
        item, depth = stack.pop()
        children = item.values() if isinstance(item, dict) else item if isinstance(item, list) else None
        if children is not None:
            deepest = max(deepest, depth)
            stack.extend((child, depth + 1) for child in children)
    return deepest


def read_structured_file(path: str | os.PathLike) -> Any:
    """A JSON or TOML file's contents (TOML by the ``.toml`` suffix, JSON otherwise).

    Raises:
      ValueError: not UTF-8, not valid JSON / TOML (the parser's message), or lists and
        tables nested deeper than :data:`MAX_NESTING`.
    """
    path = Path(path)
    kind = "TOML" if path.suffix.lower() == ".toml" else "JSON"
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        raise ValueError(f"not UTF-8 text ({error.reason} at byte {error.start})") from None
    line = _nesting_line(text, kind)
    if line is not None:
        raise ValueError(f"lists and tables nested more than {MAX_NESTING} deep (line {line})")
    try:
        data = tomllib.loads(text) if kind == "TOML" else json.loads(text)
    except (ValueError, RecursionError) as error:  # JSONDecodeError, TOMLDecodeError, an integer of 5,000 digits…
        raise ValueError(f"not valid {kind} ({one_line(error, 200)})") from None
    if _nesting(data) > MAX_NESTING:
        raise ValueError(f"lists and tables nested more than {MAX_NESTING} deep")
    return data
