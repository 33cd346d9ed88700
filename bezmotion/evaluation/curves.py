"""Evaluating Bézier curves before IK: the BMM paper's Table 1/3/6 protocol on curve datasets.

Every evaluation window gets the in-betweening conditions — all six joints at the first
and last control point — plus 1 to 4 intermediate handles drawn like the training
conditions (BMM §5.2) from a fixed key, so every method sees the same handles. Handles
are the ground-truth control positions (in distribution) or those plus uniform noise of
±16 cm per axis (out of distribution, §5.1; start and end stay exact). Metrics:

- handles error (cm): intermediate handles only, as the paper measures it;
- dense position error (cm) of the six joints' evaluated curves against the mocap;
- foot-skating ratio of the evaluated curves' feet (see :func:`~bezmotion.evaluation.metrics.foot_skating_ratio`);
- contact accuracy of predicted contacts at control points (learned models only).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from bezmotion.bezier import BezierLayout, evaluate
from bezmotion.data.characteristic import FEET
from bezmotion.data.curves import CurveDataset
from bezmotion.evaluation.metrics import contact_accuracy, foot_skating_ratio, handles_error, mean_position_error
from bezmotion.evaluation.baselines import interpolation_through_points
from bezmotion.bmm.features import (
    HANDLE_FRAMES,
    MAX_INTERMEDIATE_HANDLES,
    draw_intermediate_frames,
    handle_positions,
    inbetween_conditions,
)
from bezmotion.bmm.sampling import Handles, SampledCurves

OOD_NOISE_CM = 16.0  # BMM §5.1: uniform noise of ±16 cm per axis on the handles


class EvalSet(NamedTuple):
    """Conditions and ground truth of the evaluation windows (all arrays batched by window).

    Attributes:
      start, end: ``(windows, 6, 3)`` joint positions at the first and last frame (cm).
      handles: in-distribution intermediate handles (``(windows, 4)`` slots with validity).
      handles_ood: the same handles with uniform ±16 cm noise.
      ctrl_contacts: ``(windows, controls, 2)`` ground-truth contacts at control points.
      dense_pos: ``(windows, frames, 6, 3)`` the mocap.
      ctrl_pos, ctrl_tangent: ``(windows, controls, 6, 3)`` the curves fitted to the mocap.
      rows: ``(windows,)`` which dataset windows these are.
    """

    start: Array
    end: Array
    handles: Handles
    handles_ood: Handles
    ctrl_contacts: Array
    dense_pos: Array
    ctrl_pos: Array
    ctrl_tangent: Array
    rows: np.ndarray


def make_eval_set(
    dataset: CurveDataset,
    *,
    key: Array,
    num_windows: int | None = None,
    max_handles: int = MAX_INTERMEDIATE_HANDLES,
    ood_noise: float = OOD_NOISE_CM,
    handle_frames: str = "grid",
    per_window: bool = False,
    rows: np.ndarray | None = None,
) -> EvalSet:
    """Draw the evaluation conditions (deterministic given ``key``).

    Args:
      dataset: the evaluation curves (e.g. LaFAN1 subject 5).
      key: PRNG key for the window subset, the handles and the OOD noise.
      num_windows: evaluate a random subset of this many windows (``None``: all).
      max_handles: intermediate handles per window are 1…max_handles.
      handle_frames: ``"grid"`` (the paper): handles on control frames; ``"off_grid"``:
        on frames between control frames; ``"any"``: on any intermediate frame (1 … 29);
        see :func:`~bezmotion.bmm.features.draw_intermediate_frames`. Windows, handle
        counts and OOD noise are the same draws for all three; positions are the fitted
        curves at the handles' frames (on control frames, the control points).
      per_window: draw each window's handles and OOD noise from its own key,
        ``fold_in(key, dataset row)``, and take the windows as a prefix of one fixed
        permutation of the dataset (in that order, not sorted): a window's handles then
        depend on the window alone, never on ``num_windows``, and the first ``n`` windows
        of a larger set are exactly an ``n``-window set. ``False`` (the default) keeps the
        original draws (sorted subset, one batch of draws), so earlier results reproduce.
      rows: evaluate exactly these dataset windows, in this order (repeats allowed), with
        ``per_window`` draws: each window's handles and noise are those it gets in any
        ``per_window`` set of the same ``key`` (e.g. the windows of chained segments).
        Needs ``per_window=True`` and no ``num_windows``.

    Raises:
      ValueError: ``max_handles`` or ``handle_frames`` out of range, or ``rows`` without
        ``per_window``, beside ``num_windows`` or outside the dataset.
    """
    n_total, k, j = dataset.ctrl_pos.shape[:3]
    if max_handles < 1 or max_handles > (k - 2) * j:
        raise ValueError(f"max_handles must be in 1…{(k - 2) * j}, got {max_handles}")
    if handle_frames not in HANDLE_FRAMES:
        raise ValueError(f"handle_frames must be one of {HANDLE_FRAMES}, got {handle_frames!r}")
    subset_key, slot_key, noise_key = jax.random.split(key, 3)
    if rows is not None:
        if not per_window or num_windows is not None:
            raise ValueError(f"rows= needs per_window=True and num_windows=None, got per_window={per_window}, num_windows={num_windows}")
        rows = np.asarray(rows)
        if rows.ndim != 1 or not np.issubdtype(rows.dtype, np.integer) or ((rows < 0) | (rows >= n_total)).any():
            raise ValueError(f"rows must be dataset windows 0 … {n_total - 1}, got {rows.tolist()}")
    elif per_window:
        rows = np.asarray(jax.random.permutation(subset_key, n_total))[:num_windows]
    elif num_windows is not None and num_windows < n_total:
        rows = np.sort(np.asarray(jax.random.choice(subset_key, n_total, (num_windows,), replace=False)))
    else:
        rows = np.arange(n_total)
    n = len(rows)
    ctrl_pos = jnp.asarray(dataset.ctrl_pos[rows])
    draw = functools.partial(
        draw_intermediate_frames, layout=dataset.layout, num_joints=j, max_handles=max_handles, min_handles=1, frames=handle_frames
    )
    if per_window:  # one key per window, from its dataset row
        row_keys = lambda base: jax.vmap(lambda r: jax.random.fold_in(base, r))(jnp.asarray(rows))  # noqa: E731
        slot_keys, noise_keys = row_keys(slot_key), row_keys(noise_key)
    else:
        slot_keys = jax.random.split(slot_key, n)
    frame, joint, valid = jax.vmap(lambda key: draw(key))(slot_keys)
    ctrl_tangent = jnp.asarray(dataset.ctrl_tangent[rows])
    position = jax.vmap(functools.partial(handle_positions, dataset.layout))(ctrl_pos, ctrl_tangent, joint, frame)
    if per_window:
        uniform = lambda k: jax.random.uniform(k, position.shape[1:], minval=-ood_noise, maxval=ood_noise)  # noqa: E731
        noise = jax.vmap(uniform)(noise_keys)
    else:
        noise = jax.random.uniform(noise_key, position.shape, minval=-ood_noise, maxval=ood_noise)
    handles = Handles(joint, frame, position, valid)
    return EvalSet(
        start=ctrl_pos[:, 0],
        end=ctrl_pos[:, -1],
        handles=handles,
        handles_ood=handles._replace(position=position + noise),
        ctrl_contacts=jnp.asarray(dataset.ctrl_contacts[rows]),
        dense_pos=jnp.asarray(dataset.dense_pos[rows]),
        ctrl_pos=ctrl_pos,
        ctrl_tangent=ctrl_tangent,
        rows=rows,
    )


@dataclasses.dataclass(frozen=True)
class CurveMetricsConfig:
    """Fixed settings of the curve metrics.

    Attributes:
      layout: the curves' layout (31 frames, stride 6).
      fps: frame rate of the data.
      floor_height: ankle height with the foot flat (cm), see :func:`floor_height_from`.
    """

    layout: BezierLayout
    fps: float
    floor_height: float


def floor_height_from(dataset: CurveDataset, percentile: float = 5.0) -> float:
    """The ankle height of a foot flat on the floor: a low percentile of all ankle heights."""
    return float(np.percentile(dataset.dense_pos[:, :, list(FEET), 1], percentile))


def dense_positions(layout: BezierLayout, ctrl_pos: Array, ctrl_tangent: Array) -> Array:
    """``(…, controls, 6, 3)`` curves → ``(…, frames, 6, 3)`` positions."""
    return jnp.moveaxis(evaluate(layout, jnp.moveaxis(ctrl_pos, -2, -3), jnp.moveaxis(ctrl_tangent, -2, -3)), -3, -2)


def curve_metrics(
    config: CurveMetricsConfig, curves: SampledCurves, eval_set: EvalSet, handles: Handles
) -> dict[str, float]:
    """Handles error against ``handles`` plus dense error, skating and contacts."""
    dense = dense_positions(config.layout, curves.ctrl_pos, curves.ctrl_tangent)
    return trajectory_metrics(config, dense, curves.contacts, eval_set, handles)


def trajectory_metrics(
    config: CurveMetricsConfig, dense: Array, contacts: Array, eval_set: EvalSet, handles: Handles
) -> dict[str, float]:
    """The metrics of :func:`curve_metrics` for dense six-joint trajectories of any origin
    (evaluated curves, or a dense model's frames: :mod:`bezmotion.evaluation.ablations`).

    Args:
      dense: ``(windows, frames, 6, 3)`` positions (cm), :data:`CHARACTERISTIC_JOINTS` order.
      contacts: ``(windows, controls, 2)`` foot-contact probabilities at the control frames.
    """
    feet = dense[..., list(FEET), :]
    return {
        # The trajectories at each handle's frame (curves on a control frame: its control position, exactly).
        "handles_error_cm": float(handles_error(dense, handles)),
        "dense_error_cm": float(mean_position_error(dense, eval_set.dense_pos)),
        "foot_skating_ratio": float(foot_skating_ratio(feet, config.fps, floor_height=config.floor_height)),
        "contact_accuracy": float(contact_accuracy(contacts, eval_set.ctrl_contacts)),
    }


def reference_curves(eval_set: EvalSet, handles: Handles, layout: BezierLayout, *, off_grid: str = "linear") -> SampledCurves:
    """The non-learned reference for every window: interpolation through the start, end and
    handles, each met exactly (:func:`~bezmotion.evaluation.baselines.interpolation_through_points`;
    ``off_grid="projection"``: a reference that reaches a handle between control frames with a
    bump); no orientations, contacts all 0.5 (unknown)."""
    pos, tangent = _reference_controls(eval_set.start, eval_set.end, handles, layout=layout, off_grid=off_grid)
    n, k = pos.shape[:2]
    return SampledCurves(pos, tangent, jnp.zeros((*pos.shape[:-1], 6)), jnp.full((n, k, 2), 0.5))


@functools.partial(jax.jit, static_argnames=("layout", "off_grid"))
def _reference_controls(start, end, handles: Handles, *, layout: BezierLayout, off_grid: str):
    """Both ends and the valid handles as condition slots → interpolated curves, per window."""
    j = start.shape[-2]

    def one(start, end, h):
        c = inbetween_conditions(layout.num_frames, start, end, h)
        pos, tangent, _ = interpolation_through_points(layout, c, j, off_grid=off_grid)
        return pos, tangent

    return jax.vmap(one)(start, end, handles)


def ground_truth_metrics(config: CurveMetricsConfig, eval_set: EvalSet) -> dict[str, float | dict[str, float]]:
    """The mocap's own foot-skating ratio (the paper's "GT" row), and the dense error and
    skating of the curves fitted to it: what the Bézier representation itself costs, the
    floor a model of these curves cannot go below."""
    feet = eval_set.dense_pos[..., list(FEET), :]
    fitted = dense_positions(config.layout, eval_set.ctrl_pos, eval_set.ctrl_tangent)
    return {
        "foot_skating_ratio": float(foot_skating_ratio(feet, config.fps, floor_height=config.floor_height)),
        "fitted_curves": {
            "dense_error_cm": float(mean_position_error(fitted, eval_set.dense_pos)),
            "foot_skating_ratio": float(foot_skating_ratio(fitted[..., list(FEET), :], config.fps, floor_height=config.floor_height)),
        },
    }


def map_in_chunks(fn: Callable[[Any, Array], Any], inputs: Any, *, key: Array, chunk: int = 256) -> Any:
    """Run ``fn(inputs_chunk, key)`` over the leading axis of the pytree ``inputs``, ``chunk``
    rows at a time (the last chunk padded so one compilation serves all), one folded key
    per chunk; outputs are concatenated back to the full length."""
    n = jax.tree.leaves(inputs)[0].shape[0]
    chunk = min(chunk, n)
    parts = []
    for i, lo in enumerate(range(0, n, chunk)):
        idx = np.arange(lo, lo + chunk) % n
        out = fn(jax.tree.map(lambda a: a[idx], inputs), jax.random.fold_in(key, i))
        parts.append(jax.tree.map(lambda a: np.asarray(a)[: min(chunk, n - lo)], out))
    return jax.tree.map(lambda *xs: jnp.asarray(np.concatenate(xs)), *parts)


def sample_in_chunks(
    sample: Callable[[Array, Array, Handles, Array], SampledCurves],
    eval_set: EvalSet,
    handles: Handles,
    *,
    key: Array,
    chunk: int = 256,
) -> SampledCurves:
    """Run ``sample(start, end, handles, key)`` over the windows ``chunk`` at a time."""
    return map_in_chunks(lambda x, k: sample(*x, k), (eval_set.start, eval_set.end, handles), key=key, chunk=chunk)
