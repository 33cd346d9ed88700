"""The Anidance in-betweening benchmark, for any positions in-betweener.

The benchmark of Duan et al. (2022) as the Δ-interpolator paper runs it (§5.1, appendix E,
Table 2; frame layout and metric as in the Δ-interpolator's public evaluation code,
github.com/boreshkinai/delta-interpolator ``src/evaluation/anidance_benchmark.py``):

- **Test windows**: the split's validation files, 128 frames every 64, positions exactly
  as stored (no centring, no rotation).
- **Statistics**: ``x_std`` of the 72 flattened coordinates over every (window, frame)
  of the training windows (:func:`~bezmotion.data.anidance.anidance_statistics`).
- **Transition length n** ∈ {5, 15, 30}, counted in frames from the one past key frame to
  the target: the key frames are window frames 0 and ``n`` and the ``n − 1`` frames
  between are predicted (protocol ``"gap"``; the reference's
  ``MiddleFramesRemover(past_context=1, future_context=1, middle_frames=n-1)``).
- **In-filling** (protocol ``"infill"``, the paper's "one key-frame every 6 frames"):
  frames ``6, 12, … < n`` are key frames too and the others of ``1 … n−1`` are predicted
  (the reference's ``PeriodicFramesRemover(1, 1, n-1, period=6)``). For ``n = 5`` both
  protocols are the same.
- **L2P** (:func:`bezmotion.evaluation.metrics.l2p`, in float64): mean over (window, predicted
  frame) of ``‖(p̂ − p) / x_std‖₂`` over the 72 coordinates (the mean cancels).

An in-betweener is ``inbetween(key_pos, key_frame, missing_frame) -> pos``: ``key_pos``
``(B, K, 24, 3)`` holds the window's key frames (cm), ``key_frame`` and ``missing_frame``
are tuples of window frame indices (static: one compilation per layout), and it returns
``(B, M, 24, 3)`` positions of the missing frames. The zero-velocity (copy the nearest key
frame before) and LERP (piecewise linear through the key frames) baselines are two.

**The stored layout.** The files hold the center (point 0) in world coordinates and the
23 bones *relative to the center*, in all three axes: over a dance, the distance from the
center to a spine or hip point varies by ~3 cm (std) read that way and by ~140 cm read as
world positions. The benchmark scores the stored coordinates; a model that wants world
positions (the Δ-interpolator's root-relative input is only translation-invariant there)
converts with :func:`anidance_to_world` / :func:`anidance_from_world`, or is wrapped by
:func:`in_stored_layout`. Both baselines give the same result in either layout (the
conversion is linear and per frame).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion.data.anidance import (
    AnidanceStatistics,
    AnidanceWindows,
    anidance_statistics,
    anidance_windows,
    load_anidance,
)
from bezmotion.evaluation.metrics import l2p
from bezmotion.evaluation.baselines import PositionInBetweener, interpolation_position_inbetweener, zero_velocity_position_inbetweener

ANIDANCE_LENGTHS: tuple[int, ...] = (5, 15, 30)
KEYFRAME_PERIOD = 6
PROTOCOLS: tuple[str, ...] = ("gap", "infill")


@dataclasses.dataclass(frozen=True)
class AnidanceBenchmark:
    """The test windows (validation files, 128 frames, offset 64), the training statistics
    and the split entries absent from the source (dropped)."""

    windows: AnidanceWindows
    stats: AnidanceStatistics
    missing_files: tuple[str, ...] = ()

    @property
    def num_windows(self) -> int:
        return self.windows.num_windows


def anidance_benchmark(source: str | os.PathLike, *, use_cache: bool = True, progress: bool = False) -> AnidanceBenchmark:
    """Build the benchmark from ``anidance.tar.xz`` or its extracted folder (see
    :func:`~bezmotion.data.anidance.load_anidance`; warns about absent split files)."""
    corpus = load_anidance(source, use_cache=use_cache, progress=progress)
    return AnidanceBenchmark(anidance_windows(corpus, validation=True), anidance_statistics(corpus), corpus.missing)


def anidance_layout(n: int, protocol: str = "gap", *, period: int = KEYFRAME_PERIOD) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """``(key_frame, missing_frame)`` window frames of transition length ``n``.

    ``"gap"``: keys ``(0, n)``, missing ``1 … n−1``. ``"infill"``: keys ``0``, every
    ``period``-th frame before ``n``, and ``n``; missing: the rest of ``1 … n−1``.
    """
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown Anidance protocol {protocol!r}; expected one of {PROTOCOLS}")
    if not (isinstance(n, int) and not isinstance(n, bool) and n >= 2):
        raise ValueError(f"the transition length must be an integer >= 2 (one missing frame at least), got {n!r}")
    if not (isinstance(period, int) and period >= 2):
        raise ValueError(f"the key-frame period must be an integer >= 2, got {period!r}")
    interior = range(period, n, period) if protocol == "infill" else ()
    keys = (0, *interior, n)
    return keys, tuple(t for t in range(1, n) if t not in keys)


def anidance_to_world(
    pos_stored: Float[Array, "*batch points 3"] | Float[np.ndarray, "*batch points 3"],
) -> Float[Array, "*batch points 3"]:
    """World positions of all points from the stored layout (bones relative to point 0)."""
    root = pos_stored[..., :1, :]
    return jnp.concatenate([root, pos_stored[..., 1:, :] + root], axis=-2)


def anidance_from_world(
    pos_world: Float[Array, "*batch points 3"] | Float[np.ndarray, "*batch points 3"],
) -> Float[Array, "*batch points 3"]:
    """The stored layout (bones relative to point 0) from world positions."""
    root = pos_world[..., :1, :]
    return jnp.concatenate([root, pos_world[..., 1:, :] - root], axis=-2)


def in_stored_layout(inbetween_world: PositionInBetweener) -> PositionInBetweener:
    """Run an in-betweener that works on world positions on the benchmark's stored layout."""

    def inbetween(key_pos, key_frame, missing_frame):
        return anidance_from_world(inbetween_world(anidance_to_world(key_pos), key_frame, missing_frame))

    return inbetween


def evaluate_anidance(
    bench: AnidanceBenchmark,
    inbetween: PositionInBetweener,
    lengths: Sequence[int] = ANIDANCE_LENGTHS,
    *,
    protocol: str = "gap",
    period: int = KEYFRAME_PERIOD,
) -> dict[str, float]:
    """L2P of ``inbetween`` on the test windows for each transition length.

    Args:
      bench: from :func:`anidance_benchmark`.
      inbetween: see the module docstring; called once per length on all windows.
      lengths: transition lengths ``n`` (frames from the past key frame to the target).
      protocol: ``"gap"`` or ``"infill"`` (key frames every ``period`` frames too).
    Returns:
      ``{"5": …, "15": …, "30": …}`` as Python floats.
    """
    positions = np.asarray(bench.windows.positions, np.float64)
    window_frames, points = positions.shape[1], positions.shape[2]
    if bench.stats.x_std.shape != (points * 3,):
        raise ValueError(f"x_std has shape {bench.stats.x_std.shape}, expected ({points * 3},) for {points} points")
    results: dict[str, float] = {}
    with jax.enable_x64(True):
        x_std = jnp.asarray(bench.stats.x_std, jnp.float64)
        # One compilation per length instead of one per primitive (eager dispatch).
        inbetween_jit = jax.jit(inbetween, static_argnums=(1, 2))
        for n in lengths:
            key_frame, missing_frame = anidance_layout(n, protocol, period=period)
            if n >= window_frames:
                raise ValueError(f"transition length {n} does not fit {window_frames}-frame windows")
            # Frames are gathered on the host: the layouts are static.
            pred = inbetween_jit(jnp.asarray(positions[:, list(key_frame)]), key_frame, missing_frame)
            expected = (bench.num_windows, len(missing_frame), points, 3)
            if pred.shape != expected:
                raise ValueError(f"in-betweener returned shape {pred.shape}, expected {expected}")
            results[str(n)] = float(_l2p_jit(jnp.asarray(pred, jnp.float64), jnp.asarray(positions[:, list(missing_frame)]), x_std))
    return results


_l2p_jit = jax.jit(l2p)


def evaluate_anidance_baselines(bench: AnidanceBenchmark, lengths: Sequence[int] = ANIDANCE_LENGTHS) -> dict:
    """Zero-velocity and LERP (:mod:`bezmotion.evaluation.baselines`) under both protocols: ``{protocol: {"zerov": …, "interp": …}}``."""
    return {
        protocol: {
            "zerov": evaluate_anidance(bench, zero_velocity_position_inbetweener, lengths, protocol=protocol),
            "interp": evaluate_anidance(bench, interpolation_position_inbetweener, lengths, protocol=protocol),
        }
        for protocol in PROTOCOLS
    }


def format_anidance_table(rows: dict[str, dict[str, float]], lengths: Sequence[int] = ANIDANCE_LENGTHS) -> str:
    """A Markdown table in the paper's Table 2 layout: one row per method, L2P per length."""
    lines = ["| Length | " + " | ".join(f"L2P {n}" for n in lengths) + " |", "|" + "---|" * (len(lengths) + 1)]
    for name, values in rows.items():
        lines.append(f"| {name} | " + " | ".join(f"{values[str(n)]:.3f}" for n in lengths) + " |")
    return "\n".join(lines)


__all__ = [
    "ANIDANCE_LENGTHS",
    "KEYFRAME_PERIOD",
    "PROTOCOLS",
    "AnidanceBenchmark",
    "anidance_benchmark",
    "anidance_from_world",
    "anidance_layout",
    "anidance_to_world",
    "evaluate_anidance",
    "evaluate_anidance_baselines",
    "format_anidance_table",
    "in_stored_layout",
]
