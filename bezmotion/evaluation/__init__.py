"""Benchmarks of in-betweeners: the official LaFAN1 transition protocol
(:mod:`~bezmotion.evaluation.lafan1`) and Anidance (:mod:`~bezmotion.evaluation.anidance`).

Both take any in-betweener as a function; the metrics themselves are
:mod:`bezmotion.metrics`.
"""

from bezmotion.evaluation.anidance import AnidanceBenchmark, anidance_benchmark, evaluate_anidance
from bezmotion.evaluation.lafan1 import TRANSITION_LENGTHS, Lafan1Benchmark, evaluate_transitions, lafan1_benchmark

__all__ = [
    "TRANSITION_LENGTHS",
    "AnidanceBenchmark",
    "Lafan1Benchmark",
    "anidance_benchmark",
    "evaluate_anidance",
    "evaluate_transitions",
    "lafan1_benchmark",
]
