"""What the experiment scripts share beyond the package: where their trainings live.

Each script declares its options once, as an options class (:mod:`bezmotion.options`),
and writes its results with :func:`bezmotion.io.write_results` (JSON and a Markdown
report beside it).
"""

from __future__ import annotations

from pathlib import Path

from bezmotion.data.cache import cache_dir


def runs_dir(*parts: str) -> Path:
    """``<cache>/runs/<parts…>``: where trainings keep checkpoints and saved models.

    The cache is ``~/.cache/bezmotion`` unless ``BEZMOTION_CACHE`` names another folder;
    it is read at the call, so a test can move it.
    """
    return cache_dir().joinpath("runs", *parts)
