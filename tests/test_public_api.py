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


def test_the_verbs_of_the_method_are_public():
    verbs = {
        "read_bvh", "write_bvh", "BvhMotion", "Skeleton", "forward_kinematics", "inverse_kinematics",
        "Character", "Pose", "IKTargets", "Handles", "sample_curves", "inbetween", "InbetweenResult",
        "Transfer", "CharacterProfile", "pose_to_bvh", "pose_from_motion", "targets_from_pose",
        "load_model", "save_model", "load_ik_model", "protores_ik_fn", "protores_refined_ik_fn",
        "rig_ik", "make_rig", "BezierLayout", "fit_curves", "evaluate", "DEMO_CLIP", "BUNDLED_BMM", "BUNDLED_IK",
    }  # fmt: skip
    assert verbs <= set(bm.__all__), sorted(verbs - set(bm.__all__))
    assert bm.DEMO_CLIP.is_file() and (bm.BUNDLED_BMM / "config.json").is_file() and (bm.BUNDLED_IK / "config.json").is_file()


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
