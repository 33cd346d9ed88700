"""Research code, which the library itself never imports: the metrics
(:mod:`~bezmotion.evaluation.metrics`), the baselines (:mod:`~bezmotion.evaluation.baselines`),
the BMM's curve metrics (:mod:`~bezmotion.evaluation.curves`) and the paper's ablations
(:mod:`~bezmotion.evaluation.ablations`), the pipeline over a corpus
(:mod:`~bezmotion.evaluation.pipeline`, :mod:`~bezmotion.evaluation.window_figures`),
re-expressions of a clip (:mod:`~bezmotion.evaluation.skeleton_zoo`), and the benchmarks
of in-betweeners: the official LaFAN1 transition protocol
(:mod:`~bezmotion.evaluation.lafan1`) and Anidance (:mod:`~bezmotion.evaluation.anidance`);
naturalness metrics on motion embeddings (:mod:`~bezmotion.evaluation.naturalness`: FID,
diversity, multimodality) and our motion feature extractor that produces them
(:mod:`~bezmotion.evaluation.motion_features`, imported on its own: it needs the pipeline).

The benchmarks take any in-betweener as a function; the per-window metrics themselves
are :mod:`bezmotion.evaluation.metrics`.
"""

from bezmotion.evaluation.anidance import AnidanceBenchmark, anidance_benchmark, evaluate_anidance
from bezmotion.evaluation.lafan1 import TRANSITION_LENGTHS, Lafan1Benchmark, evaluate_transitions, lafan1_benchmark
from bezmotion.evaluation.naturalness import GaussianFit, diversity, fid, frechet_distance, gaussian_fit, multimodality

__all__ = [
    "TRANSITION_LENGTHS",
    "AnidanceBenchmark",
    "GaussianFit",
    "Lafan1Benchmark",
    "anidance_benchmark",
    "diversity",
    "evaluate_anidance",
    "evaluate_transitions",
    "fid",
    "frechet_distance",
    "gaussian_fit",
    "lafan1_benchmark",
    "multimodality",
]
