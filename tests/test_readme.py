"""Every ```python block of README.md runs as written.

Each block is self-contained (its own imports) and runs in a fresh namespace inside an
empty working directory, so files it writes land in a temporary folder and a block never
leans on another's variables. The test id names the block's first line in README.md.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
FENCE = re.compile(r"^```python\n(.*?)^```$", re.MULTILINE | re.DOTALL)


def python_blocks() -> list[tuple[int, str]]:
    """``(line of the block's first code line, code)`` for each ```python block."""
    text = README.read_text(encoding="utf-8")
    return [(text.count("\n", 0, m.start(1)) + 1, m.group(1)) for m in FENCE.finditer(text)]


BLOCKS = python_blocks()


def test_the_readme_has_python_examples():
    assert len(BLOCKS) >= 4, f"found {len(BLOCKS)} python blocks in {README}"


@pytest.mark.parametrize(("line", "code"), BLOCKS, ids=[f"README.md:{line}" for line, _ in BLOCKS])
def test_readme_block_runs(line, code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    # Padding the source with blank lines makes tracebacks point at README.md's own lines.
    exec(compile("\n" * (line - 1) + code, str(README), "exec"), {"__name__": f"readme_line_{line}"})
