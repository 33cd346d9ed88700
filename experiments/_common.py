"""What the experiment scripts share beyond the package: which corpus, where trainings live.

Each script declares its options once, as an options class (:mod:`bezmotion._src.options`),
and writes its results with :func:`bezmotion._src.io.write_results` (JSON and a Markdown
report beside it).
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
from pathlib import Path

import numpy as np

from bezmotion.data.cache import cache_dir
from bezmotion.data.corpus import Corpus
from bezmotion.data.curves import CurveDataset
from bezmotion.data.resample import TRAINED_FPS
from bezmotion.data.sources import CORPORA, load_corpus

#: ``--corpus`` help shared by the scripts that train on any corpus.
CORPUS_HELP = f"one of {', '.join(CORPORA)}, or a folder of BVH files of one skeleton (your own clips)"
#: ``--characteristic`` help: how a folder's six characteristic joints are named.
CHARACTERISTIC_HELP = (
    "for a BVH folder: its six characteristic joints, a preset (lafan1, bandai_namco) or a JSON file "
    '{"hips": …, "head": …, "left_hand": …, "right_hand": …, "left_foot": …, "right_foot": …}'
)


PARAMETER_CHOICES = ("ema", "raw")
PARAMETERS_HELP = (
    "which trained parameters are evaluated and saved: their moving average (the paper; <run-dir>/model) or the raw "
    "ones (<run-dir>/model_raw; a short run's average at decay 0.999 is still mostly its initialisation)"
)


def trained_parameters(state, which: str):
    """The parameters ``--parameters`` names (``"ema"`` or ``"raw"``) of a train state, and the
    run-folder name they are saved under (``model`` or ``model_raw``)."""
    if which not in PARAMETER_CHOICES:
        raise ValueError(f"--parameters must be one of {PARAMETER_CHOICES}, got {which!r}")
    return (state.ema, "model") if which == "ema" else (state.params, "model_raw")


def runs_dir(*parts: str) -> Path:
    """``<cache>/runs/<parts…>``: where trainings keep checkpoints and saved models.

    The cache is ``~/.cache/bezmotion`` unless ``BEZMOTION_CACHE`` names another folder;
    it is read at the call, so a test can move it.
    """
    return cache_dir().joinpath("runs", *parts)


def open_corpus(name_or_path: str, *, data: str | None = None, characteristic: str | None = None, progress: bool = True) -> Corpus:
    """A published corpus by name (from ``data`` or its default archive), or a folder of BVH files.

    Args:
      name_or_path: ``lafan1``, ``bandai_namco``, ``anidance`` or a folder path (its
        files resampled to :data:`~bezmotion.data.resample.TRAINED_FPS` if at another rate).
      data: the published corpus's archive or folder (names only).
      characteristic: a folder's characteristic joints: a preset name or a JSON file
        mapping each role to a joint name (folders only).
    Raises:
      ValueError: ``characteristic`` given for a published corpus, or an unreadable map.
    """
    if name_or_path in CORPORA:
        if characteristic is not None:
            raise ValueError(f"--characteristic is for BVH folders; {name_or_path} knows its joints")
        return load_corpus(name_or_path, source=data, progress=progress)
    if data is not None:
        raise ValueError(f"--data is for the published corpora {CORPORA}; {name_or_path!r} is a folder already")
    mapping: str | dict[str, str] | None = characteristic
    if characteristic is not None and characteristic.endswith(".json"):
        try:
            mapping = json.loads(Path(characteristic).read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise ValueError(f"--characteristic {characteristic}: not a readable JSON map ({error})") from error
    # At the rate bezmotion inbetween resamples every clip to: a model trained here fits it.
    return load_corpus(name_or_path, progress=progress, characteristic=mapping, fps=TRAINED_FPS)


def corpus_label(name_or_path: str) -> str:
    """A corpus's short name for run folders: the name itself, or a folder's base name."""
    return name_or_path if name_or_path in CORPORA else Path(os.path.normpath(name_or_path)).name


def clip_label(labels: dict) -> str:
    """A clip's content / action: Bandai-Namco's ``content``, LaFAN1's sequence or a file stem without its number."""
    if "content" in labels:
        return str(labels["content"])
    name = str(labels.get("sequence", labels.get("file", "?")))
    return re.sub(r"[\d_\-\s]+$", "", name) or name


def window_labels(corpus: Corpus, dataset: CurveDataset, split: str, rows: np.ndarray | None = None) -> np.ndarray:
    """The content / action label (:func:`clip_label`) of each window of ``dataset``, one split's curves.

    Args:
      corpus: the corpus the curves were fitted from.
      dataset: ``curve_dataset(corpus, split)``.
      split: ``"train"`` or ``"validation"``.
      rows: only these windows (default: all, in order).
    """
    clips = corpus.split(split)
    rows = np.arange(len(dataset)) if rows is None else rows
    return np.asarray([clip_label(corpus.labels(int(clips[dataset.clip_index[r]]))) for r in rows])


def matches_any(labels: np.ndarray, patterns: tuple[str, ...]) -> np.ndarray:
    """``(n,)`` bool: labels matching any shell pattern (``wave-*``, ``run``)."""
    return np.asarray([any(fnmatch.fnmatchcase(str(label), p) for p in patterns) for label in labels], bool)
