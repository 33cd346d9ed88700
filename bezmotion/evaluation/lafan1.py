"""The official LaFAN1 transition benchmark, for any in-betweener.

An in-betweener is a function
``inbetween(past_quat, past_root, target_quat, target_root, n) -> (quat, root)``
that sees only the past context (``(B, 10, 22, 4)`` local rotations, ``(B, 10, 3)`` root
positions), the target key frame (``(B, 22, 4)``, ``(B, 3)``) and the transition length
``n``, and returns the ``n`` transition frames (``(B, n, 22, 4)``, ``(B, n, 3)``).
Ground truth and prediction go through FK with the real root position and the constant
offsets, and L2Q, L2P and NPSS are computed in float64, as the official Ubisoft La Forge
evaluator does (github.com/ubisoft/ubisoft-laforge-animation-dataset: ``evaluate.py``,
``lafan1/benchmarks.py``).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp

from bezmotion.data.lafan1 import (
    N_PAST,
    PARENTS,
    TEST_SUBJECTS,
    Lafan1Statistics,
    Lafan1Windows,
    lafan1_statistics,
    lafan1_windows,
    load_lafan1,
)
from bezmotion.geometry.skeleton import forward_kinematics
from bezmotion.evaluation.metrics import align_to_context, l2p, l2q, npss
from bezmotion.evaluation.baselines import interpolation_inbetweener, zero_velocity_inbetweener

TRANSITION_LENGTHS: tuple[int, ...] = (5, 15, 30, 45)
TEST_WINDOW, TEST_OFFSET = 65, 40
METRIC_VARIANTS: tuple[str, ...] = ("official", "delta")
InBetweener = Callable[..., tuple[jax.Array, jax.Array]]


@dataclasses.dataclass(frozen=True)
class Lafan1Benchmark:
    """The test windows (subject 5, 65 frames, offset 40) and the training statistics."""

    windows: Lafan1Windows
    stats: Lafan1Statistics

    @property
    def num_windows(self) -> int:
        return self.windows.num_windows


def lafan1_benchmark(source: str | os.PathLike, *, use_cache: bool = True) -> Lafan1Benchmark:
    """Build the official benchmark from the LaFAN1 zip or a directory of its BVH files."""
    corpus = load_lafan1(source, use_cache=use_cache)
    test = lafan1_windows(corpus, TEST_SUBJECTS, TEST_WINDOW, TEST_OFFSET)
    return Lafan1Benchmark(test, lafan1_statistics(corpus))


@functools.partial(jax.jit, static_argnames="variant")
def _score(pred_quat, pred_root, true_quat, true_root, offsets, x_std, variant):
    """Metrics of one transition length. ``true_*`` hold the last past frame, then the
    ``n`` ground-truth transition frames; ``pred_*`` the ``n`` predicted frames."""
    true_g, true_p = forward_kinematics(PARENTS, true_quat, offsets, root_pos=true_root)
    pred_q, pred_p = forward_kinematics(PARENTS, pred_quat, offsets, root_pos=pred_root)
    last_q, true_q, true_p = true_g[:, 0], true_g[:, 1:], true_p[:, 1:]
    if variant == "delta":
        true_q = align_to_context(true_q, last_q)
        pred_q = align_to_context(pred_q, last_q)
    batch, n = pred_quat.shape[:2]
    return {
        "l2q": l2q(pred_q, true_q),
        "l2p": l2p(pred_p, true_p, x_std),
        "npss": npss(pred_q.reshape(batch, n, -1), true_q.reshape(batch, n, -1)),
    }


def evaluate_transitions(
    bench: Lafan1Benchmark,
    inbetween: InBetweener,
    lengths: Sequence[int] = TRANSITION_LENGTHS,
    *,
    variant: str = "official",
) -> dict[str, dict[str, float]]:
    """L2Q, L2P and NPSS of ``inbetween`` for each transition length.

    Args:
      bench: from :func:`lafan1_benchmark`.
      inbetween: see the module docstring; called once per length on all windows.
      lengths: transition lengths; frames ``10 … 9+n`` are predicted from frames 0–9 and
        the target frame ``10+n``.
      variant: ``"official"`` (the La Forge evaluator) or ``"delta"`` (the Δ-interpolator
        code: L2Q and NPSS on quaternions hemisphere-aligned to the last past frame).
    Returns:
      ``{"l2q": {"5": …}, "l2p": {…}, "npss": {…}}`` as Python floats.
    """
    if variant not in METRIC_VARIANTS:
        raise ValueError(f"unknown metric variant {variant!r}; expected 'official' or 'delta'")
    w = bench.windows
    window_frames = w.quat_local.shape[1]
    results: dict[str, dict[str, float]] = {"l2q": {}, "l2p": {}, "npss": {}}
    with jax.enable_x64(True):
        offsets = jnp.asarray(bench.stats.offsets)
        x_std = jnp.asarray(bench.stats.x_std)
        quat = jnp.asarray(w.quat_local)
        root = jnp.asarray(w.root_pos)
        # One compilation per length instead of one per primitive (eager dispatch).
        inbetween_jit = jax.jit(inbetween, static_argnums=4)
        for n in lengths:
            target = N_PAST + n
            if not (isinstance(n, int) and 1 <= n and target < window_frames):
                raise ValueError(f"transition length {n} does not fit {window_frames}-frame windows with {N_PAST} past frames")
            pred_quat, pred_root = inbetween_jit(quat[:, :N_PAST], root[:, :N_PAST], quat[:, target], root[:, target], n)
            expected = (w.num_windows, n)
            if pred_quat.shape != (*expected, 22, 4) or pred_root.shape != (*expected, 3):
                raise ValueError(
                    f"in-betweener returned shapes {pred_quat.shape} and {pred_root.shape}, expected {(*expected, 22, 4)} and {(*expected, 3)}"
                )
            scores = _score(
                jnp.asarray(pred_quat, jnp.float64), jnp.asarray(pred_root, jnp.float64),
                quat[:, N_PAST - 1 : target], root[:, N_PAST - 1 : target], offsets, x_std, variant,
            )  # fmt: skip
            for name, value in scores.items():
                results[name][str(n)] = float(value)
    return results


def evaluate_baselines(
    bench: Lafan1Benchmark, lengths: Sequence[int] = TRANSITION_LENGTHS, *, variant: str = "official"
) -> dict:
    """Both baselines (:mod:`bezmotion.evaluation.baselines`) on the benchmark, in the experiment's JSON layout."""
    return {
        "n_windows": bench.num_windows,
        "zerov": evaluate_transitions(bench, zero_velocity_inbetweener, lengths, variant=variant),
        "interp": evaluate_transitions(bench, interpolation_inbetweener, lengths, variant=variant),
    }


def format_table(results: dict, lengths: Sequence[int] = TRANSITION_LENGTHS) -> str:
    """A Markdown table of ``evaluate_baselines``-style results (rows: metric × method)."""
    methods = [k for k in results if isinstance(results[k], dict) and "l2q" in results[k]]
    header = "| metric | method | " + " | ".join(f"n={n}" for n in lengths) + " |"
    lines = [header, "|" + "---|" * (len(lengths) + 2)]
    for metric in ("l2q", "l2p", "npss"):
        for m in methods:
            vals = " | ".join(f"{results[m][metric][str(n)]:.4f}" for n in lengths)
            lines.append(f"| {metric.upper()} | {m} | {vals} |")
    return "\n".join(lines)


__all__ = [
    "TRANSITION_LENGTHS",
    "Lafan1Benchmark",
    "evaluate_baselines",
    "evaluate_transitions",
    "format_table",
    "lafan1_benchmark",
]
