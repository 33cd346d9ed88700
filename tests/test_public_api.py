"""The public API: ``import bezmotion as bm`` and its ``__all__``."""

from __future__ import annotations

import ast
from pathlib import Path

import bezmotion as bm

PACKAGE = Path(bm.__file__).resolve().parent


def isort_key(name: str) -> tuple[int, str]:
    """The order of ``__all__``: CONSTANTS, then Classes, then functions (isort style)."""
    return (0 if name.isupper() else 1 if name[0].isupper() else 2, name)


def test_every_name_in_all_resolves():
    missing = [name for name in bm.__all__ if not hasattr(bm, name)]
    assert not missing, f"bezmotion.__all__ names that do not exist: {missing}"


def test_all_is_sorted_and_unique():
    assert len(set(bm.__all__)) == len(bm.__all__), "duplicates in bezmotion.__all__"
    assert bm.__all__ == sorted(bm.__all__, key=isort_key)


def test_the_public_surface_is_the_model_object_its_entry_point_and_files():
    surface = {
        "Inbetweener", "pretrained", "inbetween", "InbetweenOptions", "InbetweenResult", "Handles", "Pose",
        "read_bvh", "write_bvh", "BvhMotion", "write_glb", "DEMO_CLIP", "CHARACTERISTIC_JOINTS",
    }  # fmt: skip
    assert surface <= set(bm.__all__), sorted(surface - set(bm.__all__))
    assert len(bm.__all__) <= 30, "the top level is what a newcomer reads: keep it small"
    assert bm.DEMO_CLIP.is_file()


def test_no_module_inside_the_package_imports_the_top_level_package():
    """Modules import from subpackages only, so ``bezmotion/__init__`` can re-export anything
    without an import cycle."""
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module == "bezmotion" and node.level == 0:
                offenders.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
            elif isinstance(node, ast.Import) and any(alias.name == "bezmotion" for alias in node.names):
                offenders.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert not offenders, f"modules importing the top-level bezmotion package: {offenders}"


def test_the_library_imports_no_research_code():
    """``import bezmotion`` and its CLI load nothing of :mod:`bezmotion.evaluation` (metrics,
    baselines, ablations, evaluations): the core stands without the research code."""
    import subprocess
    import sys

    code = "import sys, bezmotion, bezmotion.pipeline, bezmotion.bmm, bezmotion.delta, bezmotion.ik; print(sorted(m for m in sys.modules if m.startswith('bezmotion.evaluation')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]", out


def test_no_library_error_names_a_command_line_flag():
    """Outside ``bezmotion/cli/`` no error is about a ``--flag`` (its message does not start
    with one, the way the commands' do); naming a whole command to run is fine."""
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] in ("cli", "_src") or rel.name == "blender_curves.py":  # the commands, the options parser, Blender's own script
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and node.exc.args and _starts_with_a_flag(node.exc.args[0]):
                offenders.append(f"{rel}:{node.lineno}")
    assert not offenders, offenders


def _starts_with_a_flag(message: ast.expr) -> bool:
    first = message.values[0] if isinstance(message, ast.JoinedStr) and message.values else message
    return isinstance(first, ast.Constant) and isinstance(first.value, str) and first.value.lstrip().startswith("--")


def test_no_code_line_carries_a_date_or_an_issue_number():
    """Code says why, not when: dates and issue numbers belong to commit messages and
    ``docs/notebook/``, not to code, comments or docstrings."""
    import re

    root = PACKAGE.parent
    pattern = re.compile(r"\b20\d\d-\d\d-\d\d\b|\b[Ii]ssue #?\d+")
    offenders = [
        f"{path.relative_to(root)}:{number}"
        for folder in ("bezmotion", "experiments", "benchmarks", "tests")
        for path in sorted((root / folder).rglob("*.py"))
        if path.resolve() != Path(__file__).resolve()
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if pattern.search(line)
    ]
    assert not offenders, offenders
