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
