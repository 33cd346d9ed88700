"""Error messages a person reads in one line: lists shown in part with a count, length bounded."""

from __future__ import annotations

from collections.abc import Iterable

MESSAGE_CHARS = 300
"""About the longest error line: longer ones are cut in the middle (:func:`one_line`)."""


def listed(items: Iterable[object], shown: int = 6, sep: str = ", ") -> str:
    """``items`` joined by ``sep``, at most ``shown`` of them and then how many more.

    >>> listed(range(10), shown=3)
    '0, 1, 2, … (7 more)'
    """
    items = [str(x) for x in items]
    if len(items) <= shown:
        return sep.join(items)
    return f"{sep.join(items[:shown])}{sep}… ({len(items) - shown} more)"


def one_line(message: object, limit: int = MESSAGE_CHARS) -> str:
    """``message`` on one line (whitespace runs become one space), cut in the middle past
    ``limit`` characters so both its start (what failed) and end (why) stay readable."""
    text = " ".join(str(message).split())
    if len(text) <= limit:
        return text
    head = (limit - 3) * 2 // 3
    tail = limit - 3 - head
    return f"{text[:head]} … {text[len(text) - tail:]}"
