"""Training the Δ-interpolator: the paper's losses, gap sampling and schedule, one jitted step.

``step(state, data) -> (state, metrics)`` is pure: it draws its batch (windows, gap
lengths, start frames, dropout) from ``state.key``, so a run is fully determined by its
seed and resumes bit-identically from a checkpoint. The generic pieces are
:mod:`bezmotion.training`'s: ``TrainState``, ``apply_gradients`` (the update),
``warmup_then_decay`` (the schedule), ``compile_train_step`` (several seeds vmapped over
a stacked state) and ``run_training`` (atomic orbax checkpoints, Ctrl-C / SIGTERM
handling). The trainer knows no corpus: it takes windows as arrays
(:class:`DeltaArrays`, :class:`DeltaPositionArrays`) of the skeleton the model was built
for (``DeltaConfig.parents``).

Paper settings (Oreshkin et al. 2023, Appendix B, Table 5): Adam, batch 64,
lr warmed linearly from 1e-6 to 2e-4 over 50 epochs, then ×0.1 every 200 epochs (300
in all); gap length ``n ∈ [5, 39]`` with ``p(n) ∝ 1/n``; 10 past frames and one target at
a uniformly random start in the 50-frame training window; loss
``10·L1(global quaternions) + 10·L1(FK positions)`` on the missing frames plus the same on
the key frames (reconstruction). The Δ-interpolator has no EMA: ``TrainState.ema`` is
``None``.

One compiled shape serves every gap length: each example has ``n_past + 1`` key slots
and ``max_gap`` missing slots, of which the first ``n`` are real; the others are
predicted (missing frames only attend to key frames, so they change nothing) and masked
out of the loss. We draw ``n`` per example (the reference draws one per batch), which
costs nothing here and mixes gap lengths within each gradient. The model sees frame
indices relative to the example's first past frame, as the reference code does
(``frame_indices = indices - start_frame``), so training and evaluation (which starts
at frame 0) read the same rows of the frame-index embedding.

**In-filling** (``keyframe_period``, the paper's Anidance training, §5.2): every
``keyframe_period``-th frame after the last past frame is given as a key frame too;
``max_gap // keyframe_period`` extra key slots hold them (padding when fewer).

**Positions only** (a model with ``representation="positions"``; Anidance): the data are
:class:`DeltaPositionArrays` and the loss is ``pos_weight·L1(global positions)`` on the
missing frames plus the same on the key frames (the reference's Anidance model).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jax.sharding import Mesh
from jaxtyping import Array, Bool, Float, Int

from bezmotion.geometry.skeleton import forward_kinematics
from bezmotion.delta.model import (
    DeltaConfig,
    DeltaOutput,
    DeltaPositionsOutput,
    KeyFrames,
    KeyPositions,
    apply_delta,
    apply_delta_positions,
    init_delta,
)
from bezmotion.training import (
    TrainState,
    apply_gradients,
    fresh_train_state,
    run_training,
    shard_batch,
    stack_seeds,
    warmup_then_decay,
)


@dataclasses.dataclass(frozen=True)
class DeltaTrainConfig:
    """Optimisation settings; the defaults are the paper's, with the schedule in steps.

    Attributes:
      batch_size: examples per step (64).
      learning_rate: peak learning rate after warm-up (2e-4).
      initial_learning_rate: learning rate at step 0 (1e-6).
      warmup_steps: linear warm-up length (paper: 50 epochs).
      decay_every: steps between ×``decay_factor`` drops after warm-up (paper: 200 epochs).
      decay_factor: the step schedule's factor (0.1).
      min_gap, max_gap: range of gap lengths ``n`` drawn with ``p(n) ∝ 1/n`` (5, 39).
      quat_weight, pos_weight: weights of the quaternion and position L1 terms (10, 10);
        the positions representation has the position term only.
      reconstruction: add the same losses on the key frames (the paper's Appendix A).
      keyframe_period: in-filling: every ``keyframe_period``-th frame after the last past
        frame is a key frame too (Anidance: 6); ``None``: one gap between the past context
        and the target (LaFAN1).
      infill_probability: with ``keyframe_period``, the fraction of examples drawn with
        the periodic key frames; the others are single gaps (1: the paper).
    """

    batch_size: int = 64
    learning_rate: float = 2e-4
    initial_learning_rate: float = 1e-6
    warmup_steps: int = 1000
    decay_every: int = 4000
    decay_factor: float = 0.1
    min_gap: int = 5
    max_gap: int = 39
    quat_weight: float = 10.0
    pos_weight: float = 10.0
    reconstruction: bool = True
    keyframe_period: int | None = None
    infill_probability: float = 1.0

    def __post_init__(self):
        for name in ("batch_size", "min_gap", "max_gap", "decay_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"DeltaTrainConfig.{name} must be a positive integer, got {value!r}")
        if not isinstance(self.warmup_steps, int) or self.warmup_steps < 0:
            raise ValueError(f"DeltaTrainConfig.warmup_steps must be a non-negative integer, got {self.warmup_steps!r}")
        if self.min_gap > self.max_gap:
            raise ValueError(f"DeltaTrainConfig.min_gap ({self.min_gap}) exceeds max_gap ({self.max_gap})")
        if not self.learning_rate > 0 or not self.initial_learning_rate > 0:
            raise ValueError(
                f"learning rates must be positive, got learning_rate={self.learning_rate}, "
                f"initial_learning_rate={self.initial_learning_rate}"
            )
        if not 0.0 < self.decay_factor <= 1.0:
            raise ValueError(f"DeltaTrainConfig.decay_factor must be in (0, 1], got {self.decay_factor}")
        if self.quat_weight < 0 or self.pos_weight < 0:
            raise ValueError(f"loss weights must be non-negative, got quat_weight={self.quat_weight}, pos_weight={self.pos_weight}")
        period = self.keyframe_period
        if period is not None and (not isinstance(period, int) or isinstance(period, bool) or period < 2):
            raise ValueError(f"DeltaTrainConfig.keyframe_period must be an integer >= 2 or None, got {period!r}")
        if not 0.0 <= self.infill_probability <= 1.0:
            raise ValueError(f"DeltaTrainConfig.infill_probability must be in [0, 1], got {self.infill_probability}")

    @classmethod
    def for_steps(cls, num_steps: int, **overrides) -> DeltaTrainConfig:
        """The paper's 300-epoch schedule squeezed into ``num_steps``: warm-up over the
        first 1/6 of the run, ×0.1 after 2/3 more (the paper's epochs 50 and 250)."""
        if not isinstance(num_steps, int) or num_steps < 1:
            raise ValueError(f"num_steps must be a positive integer, got {num_steps!r}")
        warmup = num_steps // 6
        return cls(**{"warmup_steps": warmup, "decay_every": max(1, (2 * num_steps) // 3), **overrides})


@runtime_checkable
class RotationWindows(Protocol):
    """Training windows of local rotations, e.g. LaFAN1's preprocessed windows (any corpus)."""

    @property
    def quat_local(self) -> Float[np.ndarray, "windows frames joints 4"]: ...
    @property
    def root_pos(self) -> Float[np.ndarray, "windows frames 3"]: ...
    @property
    def offsets(self) -> Float[np.ndarray, "windows joints 3"]: ...


@runtime_checkable
class PositionWindows(Protocol):
    """Training windows of global point positions, e.g. Anidance's (any corpus)."""

    @property
    def positions(self) -> Float[np.ndarray, "windows frames points 3"]: ...


class DeltaArrays(NamedTuple):
    """Training windows as device arrays, the ``data`` argument of the step (float32).

    Attributes:
      quat_local: ``(windows, frames, J, 4)`` local rotations (root: global).
      root_pos: ``(windows, frames, 3)`` root positions (cm).
      offsets: ``(windows, J, 3)`` each window's skeleton offsets (cm).
    """

    quat_local: Float[Array, "windows frames joints 4"]
    root_pos: Float[Array, "windows frames 3"]
    offsets: Float[Array, "windows joints 3"]

    @classmethod
    def from_windows(cls, windows: RotationWindows) -> DeltaArrays:
        """From windows with ``quat_local``, ``root_pos`` and ``offsets`` arrays (LaFAN1's
        training protocol: 50 frames, offset 20)."""
        return cls(*(jnp.asarray(a, jnp.float32) for a in (windows.quat_local, windows.root_pos, windows.offsets)))


class DeltaPositionArrays(NamedTuple):
    """Training windows of the positions representation as device arrays (float32).

    Attributes:
      positions: ``(windows, frames, P, 3)`` global point positions (cm), root first.
    """

    positions: Float[Array, "windows frames points 3"]

    @classmethod
    def from_windows(cls, windows: PositionWindows) -> DeltaPositionArrays:
        """From windows with a ``positions`` array (Anidance's protocol: 128 frames, offset 64)."""
        return cls(jnp.asarray(windows.positions, jnp.float32))


def learning_rate_schedule(config: DeltaTrainConfig) -> optax.Schedule:
    """Linear warm-up from ``initial_learning_rate`` to ``learning_rate``, then ×``decay_factor``
    every ``decay_every`` steps."""
    decay = optax.exponential_decay(config.learning_rate, config.decay_every, config.decay_factor, staircase=True)
    return warmup_then_decay(
        decay, init_value=config.initial_learning_rate, peak_value=config.learning_rate, warmup_steps=config.warmup_steps
    )


def make_optimizer(config: DeltaTrainConfig) -> optax.GradientTransformation:
    """Adam (PyTorch defaults: β = (0.9, 0.999), ε = 1e-8) on the warm-up + step schedule."""
    return optax.adam(learning_rate_schedule(config))


def sample_gap(key: Array, min_gap: int, max_gap: int) -> Int[Array, ""]:
    """A gap length ``n ∈ [min_gap, max_gap]`` with ``p(n) ∝ 1/n`` (int32)."""
    lengths = jnp.arange(min_gap, max_gap + 1)
    return (min_gap + jax.random.categorical(key, -jnp.log(lengths.astype(jnp.float32)))).astype(jnp.int32)


class ExampleLayout(NamedTuple):
    """Where one training example's slots come from in its window (fixed shapes).

    Attributes:
      key_frame: ``(n_past + extra + 1,)`` window frames of the past context, of the
        in-filling key frames (``extra = max_gap // keyframe_period`` slots, none without
        in-filling) and of the target; padding slots repeat the last past frame.
      missing_frame: ``(max_gap,)`` window frames of the missing slots, real ones first and
        in order; padding slots repeat a real frame so every index stays inside the window
        and the embeddings.
      missing_valid: ``(max_gap,)`` which missing slots are real.
      gap: the number of real missing frames (the gap-length embedding's index).
      key_valid: which key slots are real (all of them without in-filling).
    """

    key_frame: Int[Array, "keys"]
    missing_frame: Int[Array, "max_gap"]
    missing_valid: Bool[Array, "max_gap"]
    gap: Int[Array, ""]
    key_valid: Bool[Array, "keys"]


def example_layout(
    gap: Int[Array, ""],
    start: Int[Array, ""],
    n_past: int,
    max_gap: int,
    period: int | None = None,
    infill: bool | Bool[Array, ""] = True,
) -> ExampleLayout:
    """Past frames ``start … ref`` (``ref = start+n_past-1``), the target ``ref+gap+1``, and
    the ``gap`` frames between them missing — except, with ``period`` and ``infill``, the
    frames ``ref + k·period`` (``k ≥ 1``), which are key frames too (the Anidance in-filling
    layout: with one past frame, key frames every ``period`` frames from the first, plus
    the last). Frames are window indices, for gathering."""
    ref = start + n_past - 1
    offset = jnp.arange(1, max_gap + 1, dtype=jnp.int32)  # frames after the reference
    inside = offset <= gap
    interior = inside & (offset % period == 0) & infill if period is not None else jnp.zeros_like(inside)
    missing = inside & ~interior

    def compact(mask, slots):
        # Offsets where ``mask`` holds, in order, then padding: a stable sort on ~mask.
        order = jnp.argsort((~mask).astype(jnp.int32), stable=True)[:slots]
        valid = jnp.arange(slots) < jnp.sum(mask)
        return offset[order], valid

    missing_offset, missing_valid = compact(missing, max_gap)
    missing_frame = ref + jnp.where(missing_valid, missing_offset, 1)
    key_frame = [start + jnp.arange(n_past, dtype=jnp.int32)]
    key_valid = [jnp.ones(n_past, bool)]
    if period is not None:
        interior_offset, interior_valid = compact(interior, max_gap // period)
        key_frame.append(ref + jnp.where(interior_valid, interior_offset, 0))
        key_valid.append(interior_valid)
    key_frame.append(jnp.reshape(ref + gap + 1, (1,)).astype(jnp.int32))
    key_valid.append(jnp.ones(1, bool))
    return ExampleLayout(
        jnp.concatenate(key_frame), missing_frame, missing_valid, jnp.sum(missing).astype(jnp.int32), jnp.concatenate(key_valid)
    )


def draw_layout(
    key: Array,
    window_frames: int,
    n_past: int,
    min_gap: int,
    max_gap: int,
    period: int | None = None,
    infill_probability: float = 1.0,
) -> ExampleLayout:
    """Random gap (``p ∝ 1/n``, frames between the last past frame and the target), a
    uniformly random start that fits it in the window, and — with ``period`` — in-filling
    key frames with probability ``infill_probability``."""
    gap_key, start_key = jax.random.split(key)
    gap = sample_gap(gap_key, min_gap, max_gap)
    infill: bool | Array = True
    if period is not None:
        # Split only here, so single-gap training keeps its random stream.
        start_key, infill_key = jax.random.split(start_key)
        infill = jax.random.bernoulli(infill_key, infill_probability)
    start = jax.random.randint(start_key, (), 0, window_frames - (n_past + 1 + gap) + 1, dtype=jnp.int32)
    return example_layout(gap, start, n_past, max_gap, period, infill)


def _model_frames(layout: ExampleLayout) -> tuple[Int[Array, "keys"], Int[Array, "max_gap"]]:
    """Key and missing frames relative to the first past frame: the indices the model sees
    (the reference code's ``indices - start_frame``; evaluation windows start there)."""
    start = layout.key_frame[0]
    return layout.key_frame - start, layout.missing_frame - start


def hemisphere_aligned_l1(
    quat_pred: Float[Array, "*batch joints 4"], quat_true: Float[Array, "*batch joints 4"]
) -> Float[Array, "*batch"]:
    """L1 distance of quaternions summed over joints and components, each prediction first
    negated when it lies in the other hemisphere (``q`` and ``-q`` are one rotation)."""
    sign = jnp.where(jnp.sum(quat_pred * quat_true, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    return jnp.sum(jnp.abs(sign * quat_pred - quat_true), axis=(-2, -1))


def example_prediction(
    graphdef: nnx.GraphDef,
    params: nnx.State,
    quat_window: Float[Array, "frames joints 4"],
    root_window: Float[Array, "frames 3"],
    offsets: Float[Array, "joints 3"],
    layout: ExampleLayout,
    *,
    key: Array | None = None,
) -> DeltaOutput:
    """The model's prediction for one training example: it reads the window at the key
    frames only."""
    key_frame, missing_frame = _model_frames(layout)
    keys = KeyFrames(quat_window[layout.key_frame], root_window[layout.key_frame], key_frame, layout.key_valid)
    return apply_delta(graphdef, params, offsets, keys, missing_frame, layout.gap, key=key)


def example_position_prediction(
    graphdef: nnx.GraphDef,
    params: nnx.State,
    pos_window: Float[Array, "frames points 3"],
    layout: ExampleLayout,
    *,
    key: Array | None = None,
) -> DeltaPositionsOutput:
    """A positions model's prediction for one training example (reads the key frames only)."""
    key_frame, missing_frame = _model_frames(layout)
    keys = KeyPositions(pos_window[layout.key_frame], key_frame, layout.key_valid)
    return apply_delta_positions(graphdef, params, keys, missing_frame, layout.gap, key=key)


def _split_means(err, layout: ExampleLayout) -> tuple[Array, Array]:
    """Mean of per-frame errors ``(keys + max_gap,)`` over the real missing frames and over
    the real key frames."""
    n_keys = layout.key_frame.shape[0]
    missing = layout.missing_valid.astype(err.dtype) / jnp.maximum(layout.gap, 1).astype(err.dtype)
    keys = layout.key_valid.astype(err.dtype) / jnp.sum(layout.key_valid).astype(err.dtype)
    return jnp.sum(missing * err[n_keys:]), jnp.sum(keys * err[:n_keys])


def example_losses(
    graphdef: nnx.GraphDef,
    params: nnx.State,
    model_config: DeltaConfig,
    quat_window: Float[Array, "frames joints 4"],
    root_window: Float[Array, "frames 3"],
    offsets: Float[Array, "joints 3"],
    layout: ExampleLayout,
    *,
    key: Array | None = None,
) -> dict[str, Float[Array, ""]]:
    """Unweighted loss terms of one example: L1 of global quaternions and of FK positions
    (cm), summed over joints and components, averaged over the real missing frames
    (``quat``, ``pos``) and over the key frames (``rec_quat``, ``rec_pos``)."""
    out = example_prediction(graphdef, params, quat_window, root_window, offsets, layout, key=key)
    # Key and missing frames through one FK each (fewer scans to compile and run).
    frame = jnp.concatenate([layout.key_frame, layout.missing_frame])
    pred_quat = jnp.concatenate([out.key_quat, out.missing_quat])
    pred_root = jnp.concatenate([out.key_root, out.missing_root])
    true_q, true_p = forward_kinematics(model_config.parents, quat_window[frame], offsets, root_pos=root_window[frame])
    pred_q, pred_p = forward_kinematics(model_config.parents, pred_quat, offsets, root_pos=pred_root)
    quat, rec_quat = _split_means(hemisphere_aligned_l1(pred_q, true_q), layout)
    pos, rec_pos = _split_means(jnp.sum(jnp.abs(pred_p - true_p), axis=(-2, -1)), layout)
    return {"quat": quat, "pos": pos, "rec_quat": rec_quat, "rec_pos": rec_pos}


def example_position_losses(
    graphdef: nnx.GraphDef,
    params: nnx.State,
    pos_window: Float[Array, "frames points 3"],
    layout: ExampleLayout,
    *,
    key: Array | None = None,
) -> dict[str, Float[Array, ""]]:
    """Unweighted loss terms of one positions example: L1 of global positions (cm), summed
    over points and coordinates, averaged over the real missing frames (``pos``) and over
    the real key frames (``rec_pos``)."""
    out = example_position_prediction(graphdef, params, pos_window, layout, key=key)
    frame = jnp.concatenate([layout.key_frame, layout.missing_frame])
    pred = jnp.concatenate([out.key_pos, out.missing_pos])
    pos, rec_pos = _split_means(jnp.sum(jnp.abs(pred - pos_window[frame]), axis=(-2, -1)), layout)
    return {"pos": pos, "rec_pos": rec_pos}


def total_loss(config: DeltaTrainConfig, terms: dict[str, Float[Array, "*batch"]]) -> Float[Array, "*batch"]:
    """``quat_weight·(quat [+ rec_quat]) + pos_weight·(pos [+ rec_pos])``; a representation
    without rotations has no ``quat`` terms."""
    total = 0.0
    for name, weight in (("quat", config.quat_weight), ("pos", config.pos_weight)):
        if name in terms:
            term = terms[name] + terms["rec_" + name] if config.reconstruction else terms[name]
            total = total + weight * term
    return total


def init_delta_train_state(
    model_config: DeltaConfig, train_config: DeltaTrainConfig, *, key: Array
) -> tuple[nnx.GraphDef, TrainState]:
    """Fresh parameters and Adam state for one seed (``ema`` is ``None``)."""
    return fresh_train_state(lambda k: init_delta(model_config, key=k), make_optimizer(train_config), key=key, ema=False)


def init_delta_train_states(
    model_config: DeltaConfig, train_config: DeltaTrainConfig, seeds: list[int] | tuple[int, ...]
) -> tuple[nnx.GraphDef, TrainState]:
    """States for several seeds, stacked on a leading axis (for the vmapped step)."""
    return stack_seeds(lambda key: init_delta_train_state(model_config, train_config, key=key), seeds)


def make_delta_train_step(
    graphdef: nnx.GraphDef,
    model_config: DeltaConfig,
    train_config: DeltaTrainConfig,
    *,
    window_frames: int,
    mesh: Mesh | None = None,
) -> Callable[[TrainState, DeltaArrays | DeltaPositionArrays], tuple[TrainState, dict[str, Array]]]:
    """The (un-jitted) single-seed training step; compile it with
    :func:`bezmotion.training.compile_train_step`.

    Args:
      graphdef: from :func:`init_delta_train_state`.
      model_config, train_config: the model and the optimisation settings. The data the
        step takes follow the model's representation: :class:`DeltaArrays` (rotations) or
        :class:`DeltaPositionArrays` (positions).
      window_frames: frames per training window (LaFAN1 protocol: 50; Anidance: 128); the
        longest example, ``n_past + max_gap + 1`` frames, must fit in it, and its frame
        indices (relative to its first frame) must have embedding rows (``≤ max_frames``).
      mesh: split each batch over these devices (:func:`bezmotion.training.data_mesh`;
        several processes' when training data-parallel); ``None``: one device.
    """
    n_past, max_gap = model_config.n_past, train_config.max_gap
    span = n_past + max_gap + 1
    if span > window_frames:
        raise ValueError(
            f"max_gap={max_gap} does not fit {window_frames}-frame windows with {n_past} past frames and a target "
            f"(needs {span} frames)"
        )
    if span > model_config.max_frames:
        raise ValueError(
            f"examples of {n_past} past frames, up to {max_gap} missing frames and a target ({span} frames) "
            f"exceed the model's max_frames={model_config.max_frames}"
        )
    positions = model_config.representation == "positions"
    data_type = DeltaPositionArrays if positions else DeltaArrays
    # What one frame of the data must look like: the model's points, or its skeleton's joints.
    frame_shape = (model_config.num_joints, 3) if positions else (model_config.num_joints, 4)
    optimizer = make_optimizer(train_config)
    schedule = learning_rate_schedule(train_config)

    def example(params, window, rng):
        layout_key, dropout_key = jax.random.split(rng)
        layout = draw_layout(
            layout_key, window_frames, n_past, train_config.min_gap, max_gap,
            train_config.keyframe_period, train_config.infill_probability,
        )  # fmt: skip
        if positions:
            return example_position_losses(graphdef, params, *window, layout, key=dropout_key)
        return example_losses(graphdef, params, model_config, *window, layout, key=dropout_key)

    def loss_fn(params, batch, rngs):
        terms = jax.vmap(example, in_axes=(None, 0, 0))(params, batch, rngs)
        terms = jax.tree.map(jnp.mean, terms)
        return total_loss(train_config, terms), terms

    def step(state: TrainState, data: DeltaArrays | DeltaPositionArrays) -> tuple[TrainState, dict[str, Array]]:
        if not isinstance(data, data_type):
            raise ValueError(
                f"a {model_config.representation!r} model trains on {data_type.__name__}, got {type(data).__name__}"
            )
        if data[0].shape[1] != window_frames:
            raise ValueError(f"the step was built for {window_frames}-frame windows, got {data[0].shape[1]}")
        joints = model_config.num_joints
        if data[0].shape[2:] != frame_shape:
            what = "points" if positions else "joints (DeltaConfig.parents)"
            raise ValueError(f"windows of {data[0].shape[2:]} per frame do not fit the model's {joints} {what}: expected {frame_shape}")
        if not positions and data.offsets.shape[1:] != (joints, 3):
            raise ValueError(f"offsets of shape {data.offsets.shape} do not fit the model's {joints}-joint skeleton: expected (windows, {joints}, 3)")
        key, index_key, example_key = jax.random.split(state.key, 3)
        index = jax.random.randint(index_key, (train_config.batch_size,), 0, data[0].shape[0])
        batch = tuple(shard_batch(a[index], mesh) for a in data)
        rngs = jax.random.split(example_key, train_config.batch_size)
        learning_rate = schedule(state.step)
        state, metrics = apply_gradients(state, optimizer, loss_fn, batch, rngs, next_key=key)
        return state, {**metrics, "learning_rate": learning_rate}

    return step


def run_delta_training(
    step_fn: Callable[[TrainState, DeltaArrays | DeltaPositionArrays], tuple[TrainState, dict[str, Array]]],
    state: TrainState,
    data: DeltaArrays | DeltaPositionArrays,
    **kwargs: Any,
) -> tuple[TrainState, list[dict[str, float | int]]]:
    """:func:`bezmotion.training.run_training` for Δ-interpolator data (same keyword arguments:
    ``num_steps``, ``store``, ``checkpoint_every``, ``config``, ``progress``, ``log_every``)."""
    return run_training(step_fn, state, data, **kwargs)


__all__ = [
    "DeltaArrays",
    "DeltaPositionArrays",
    "DeltaTrainConfig",
    "ExampleLayout",
    "PositionWindows",
    "RotationWindows",
    "draw_layout",
    "example_layout",
    "example_losses",
    "example_position_losses",
    "example_position_prediction",
    "example_prediction",
    "hemisphere_aligned_l1",
    "init_delta_train_state",
    "init_delta_train_states",
    "learning_rate_schedule",
    "make_delta_train_step",
    "make_optimizer",
    "run_delta_training",
    "sample_gap",
    "total_loss",
]
