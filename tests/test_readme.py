"""Every ```python block of README.md and of the documentation site's pages runs as written.

Each block is self-contained (its own imports) and runs in a fresh namespace inside a
working directory of its own, so files it writes land in a temporary folder and a block
never leans on another's variables. That directory holds ``my_walk.bvh``, a user's own clip
as the examples name it: the bundled clip with Mixamo's joint names, a skeleton no preset
knows. The test id names the file and the block's first line.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.evaluation.skeleton_zoo import renamed

# The bundled clip's joints as Mixamo names them.
MIXAMO_NAMES = {
    "joint_Root": "Root", "Hips": "mixamorig:Hips", "Spine": "mixamorig:Spine", "Chest": "mixamorig:Spine2",
    "Neck": "mixamorig:Neck", "Head": "mixamorig:Head",
    **{f"{part}_{s}": f"mixamorig:{side}{name}" for s, side in (("L", "Left"), ("R", "Right")) for part, name in (
        ("Shoulder", "Shoulder"), ("UpperArm", "Arm"), ("LowerArm", "ForeArm"), ("Hand", "Hand"),
        ("UpperLeg", "UpLeg"), ("LowerLeg", "Leg"), ("Foot", "Foot"), ("Toes", "ToeBase"),
    )},
}  # fmt: skip

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
# The README and the site's pages (docs/*.md); not docs/notebook/, whose dated entries are
# records of what was run then, not examples kept runnable.
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```python\n(.*?)^```$", re.MULTILINE | re.DOTALL)


def python_blocks() -> list[tuple[Path, int, str]]:
    """``(page, line of the block's first code line, code)`` for each ```python block; a
    block repeated word for word on another page (Getting started repeats the README's) is
    run once, where it first appears."""
    blocks, seen = [], set()
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for m in FENCE.finditer(text):
            if m.group(1) not in seen:
                seen.add(m.group(1))
                blocks.append((page, text.count("\n", 0, m.start(1)) + 1, m.group(1)))
    return blocks


BLOCKS = python_blocks()


def test_the_readme_has_python_examples():
    assert len(BLOCKS) >= 4, f"found {len(BLOCKS)} python blocks in {[p.name for p in PAGES]}"
    assert any(page == README for page, _, _ in BLOCKS), "the README has no Python example"


@pytest.mark.parametrize(("page", "line", "code"), BLOCKS, ids=[f"{page.relative_to(ROOT)}:{line}" for page, line, _ in BLOCKS])
def test_readme_block_runs(page, line, code, tmp_path, monkeypatch):
    write_bvh(tmp_path / "my_walk.bvh", renamed(read_bvh(DEMO_CLIP), MIXAMO_NAMES), precision=9)
    monkeypatch.chdir(tmp_path)
    # Padding the source with blank lines makes tracebacks point at the page's own lines.
    exec(compile("\n" * (line - 1) + code, str(page), "exec"), {"__name__": f"readme_line_{line}"})


def test_the_readme_in_betweens_a_users_own_bvh_in_six_lines():
    """The README's Python example: a foreign-named BVH, one handle, a BVH written, in at most
    six lines after the import (``test_readme_block_runs`` runs it on ``my_walk.bvh``)."""
    (code,) = [code for page, _, code in BLOCKS if page == README]
    lines = [line for line in code.splitlines() if line.strip() and not line.startswith("import ")]
    assert len(lines) <= 6, lines
    assert "my_walk.bvh" in code and "Inbetweener.from_bvh" in code and "handles(" in code and "write_bvh" in code
