"""Motion data: BVH files, corpora behind one interface, the curve datasets BMM trains on and the
rotation windows the Δ-interpolator trains on.

Every corpus — LaFAN1, Bandai-Namco, Anidance, a folder of BVH files — is a
:class:`Corpus` (name, reference skeleton, labelled clips, official train/validation split,
frame rate); :func:`load_corpus` opens one by name or path.
"""

from bezmotion.data.bvh import BvhMotion, format_bvh, parse_bvh, read_bvh, write_bvh
from bezmotion.data.bvh_folder import BvhFolderCorpus, load_bvh_folder
from bezmotion.data.corpus import SPLITS, Corpus, MotionClips, motion_clips
from bezmotion.data.corpus_windows import MotionWindows, motion_windows
from bezmotion.data.curves import CurveDataset, build_curve_dataset, curve_dataset
from bezmotion.data.resample import TRAINED_FPS, resample_motion
from bezmotion.data.sources import CORPORA, data_dir, default_source, load_corpus

__all__ = [
    "CORPORA",
    "SPLITS",
    "TRAINED_FPS",
    "BvhFolderCorpus",
    "BvhMotion",
    "Corpus",
    "CurveDataset",
    "MotionClips",
    "MotionWindows",
    "build_curve_dataset",
    "curve_dataset",
    "data_dir",
    "default_source",
    "format_bvh",
    "load_bvh_folder",
    "load_corpus",
    "motion_clips",
    "motion_windows",
    "parse_bvh",
    "read_bvh",
    "resample_motion",
    "write_bvh",
]
