"""Training the Bézier Motion Model: its data, its loss and its jitted step.

``train_step(state, data) -> (state, metrics)`` is pure: it draws its batch (window
indices, timesteps, noise, conditions, dropout) from ``state.key``, so a run is fully
determined by its seed and resumes bit-identically from any checkpoint. Several seeds
train together by ``jax.vmap`` over a stacked state; with more than one local device
the batch is sharded over them (``jax.sharding``) and XLA all-reduces the gradients.

Paper settings (Table 4, §5.2): AdamW with AMSGrad, lr 1e-4, weight decay 1e-2, batch 64,
cosine schedule with T = 1000, conditions = both end control points of all joints plus
0–4 intermediate handles, Min-SNR-γ weighting (γ = 5), condition dropout 0.1 for
classifier-free guidance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jax.sharding import Mesh
from jaxtyping import Array, Bool, Float

from bezmotion.bezier import BezierLayout, PaddedLayout, fit_operator
from bezmotion.bmm.sampling import MAX_WINDOW_FRAMES
from bezmotion._src.linalg import exact_einsum
from bezmotion.data.characteristic import contact_labels
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import DEFAULT_OFFSET, CurveDataset, characteristic_windows
from bezmotion.diffusion.schedule import DiffusionSchedule, cosine_schedule
from bezmotion.bmm.augmentation import augment
from bezmotion.bmm.losses import LossWeights, bmm_loss_terms, min_snr_weight
from bezmotion.bmm.denoiser import BMMConfig, init_denoiser
from bezmotion.bmm.features import (
    MAX_INTERMEDIATE_HANDLES,
    FeatureStats,
    control_features,
    from_tokens,
    draw_handle_frames,
    draw_intermediate_slots,
    handle_positions,
    inbetween_conditions,
    normalize_conditions,
    predict_x0,
    split_features,
    to_tokens,
)
from bezmotion.training.loop import shard_batch
from bezmotion.training.optim import adamw_amsgrad_torch, warmup_then_decay
from bezmotion.training.state import TrainState, fresh_train_state, stack_seeds
from bezmotion.training.step import apply_gradients
from bezmotion.handles import Handles, grid_conditions


LR_SCHEDULES = ("constant", "cosine")


@dataclasses.dataclass(frozen=True)
class BMMTrainConfig:
    """Optimisation settings (defaults: the paper's).

    ``off_grid_handles`` (ours): the probability that an intermediate handle is drawn at a
    uniformly random intermediate frame (1 … 29) rather than on its control frame, its
    position the training curve there; ``0`` (default) keeps the paper's handles on
    control frames only, and the paper's random stream.

    Levers of ours, all off by default (the paper's constant rate, no augmentation):

    - ``lr_schedule="cosine"``: a linear warm-up over ``warmup_steps`` from 0, then a cosine
      decay to ``final_lr_fraction × learning_rate`` at ``total_steps``;
    - ``yaw_augmentation``: every example turned by a uniform random angle about the vertical;
    - ``mirror_augmentation``: the probability that an example is mirrored left/right, with
      ``rest_reflections`` the six joints' rest mirrors of the skeleton
      (:func:`bezmotion.bmm.augmentation.rest_reflections`; required then);
    - ``still_augmentation``: the probability that an example is one of its poses held still
      (:func:`bezmotion.bmm.augmentation.hold_still`), so that keys asking for no motion get none;
    - ``spans=(low, high)``: windows of many lengths. Each example's keys are drawn
      ``U{low … high}`` frames apart; its window is the first ``span + 1`` frames of a
      ``high + 1``-frame :class:`DenseWindows` window, fitted in the step
      (:func:`~bezmotion.bezier.fit_operator`, the cached datasets' fit) on the extended
      control grid sampling uses at that length, padded to ``high + 1`` frames
      (:class:`~bezmotion.bezier.PaddedLayout`: the padding is masked out of attention and
      losses). ``None`` (default): the :class:`CurveArrays` windows of the model's length.
    - ``native_span_fraction``: with ``spans``, the probability that an example's keys are
      the model's own window apart (``num_frames − 1``, 30) rather than a uniform draw, so
      that a model fine-tuned on many lengths keeps the one it was trained at.
    """

    batch_size: int = 64
    learning_rate: float = 1e-4
    weight_decay: float = 1e-2
    ema_decay: float = 0.999
    condition_dropout: float = 0.1
    min_snr_gamma: float | None = 5.0
    max_intermediate_handles: int = MAX_INTERMEDIATE_HANDLES
    off_grid_handles: float = 0.0
    weights: LossWeights = LossWeights()
    lr_schedule: str = "constant"
    warmup_steps: int = 0
    total_steps: int | None = None
    final_lr_fraction: float = 0.1
    yaw_augmentation: bool = False
    mirror_augmentation: float = 0.0
    rest_reflections: tuple[tuple[float, float, float], ...] | None = None
    still_augmentation: float = 0.0
    spans: tuple[int, int] | None = None
    native_span_fraction: float = 0.0

    def __post_init__(self):
        if self.batch_size < 1 or self.learning_rate <= 0 or self.weight_decay < 0:
            raise ValueError(f"invalid BMMTrainConfig: {self}")
        if not 0.0 <= self.condition_dropout < 1.0 or not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"condition_dropout and ema_decay must be in [0, 1), got {self}")
        if not 0.0 <= self.off_grid_handles <= 1.0:
            raise ValueError(f"off_grid_handles must be a probability in [0, 1], got {self.off_grid_handles}")
        for name in ("mirror_augmentation", "still_augmentation", "native_span_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], got {getattr(self, name)}")
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"unknown lr_schedule {self.lr_schedule!r}; known: {LR_SCHEDULES}")
        if self.lr_schedule == "cosine" and (self.total_steps is None or not 0 <= self.warmup_steps < self.total_steps):
            raise ValueError(
                f"a cosine schedule needs 0 <= warmup_steps < total_steps, got warmup_steps={self.warmup_steps}, total_steps={self.total_steps}"
            )
        if not 0.0 <= self.final_lr_fraction <= 1.0:
            raise ValueError(f"final_lr_fraction must be in [0, 1], got {self.final_lr_fraction}")
        if self.mirror_augmentation and self.rest_reflections is None:
            raise ValueError("mirror_augmentation needs rest_reflections (bezmotion.bmm.augmentation.rest_reflections)")
        for r in self.rest_reflections or ():
            if sorted(abs(x) for x in r) != [1.0, 1.0, 1.0] or sum(x < 0 for x in r) != 1:
                raise ValueError(f"rest_reflections must be six axis reflections such as (-1, 1, 1), got {self.rest_reflections}")
        if self.spans is not None and (
            len(self.spans) != 2 or not all(isinstance(x, int) for x in self.spans) or not 2 <= self.spans[0] <= self.spans[1] <= MAX_WINDOW_FRAMES - 1
        ):
            raise ValueError(f"spans must be (low, high) integers with 2 <= low <= high <= {MAX_WINDOW_FRAMES - 1}, got {self.spans!r}")
        if self.native_span_fraction and self.spans is None:
            raise ValueError(f"native_span_fraction={self.native_span_fraction} draws among spans: give spans too")
        if self.rest_reflections is not None and len(self.rest_reflections) != 6:
            raise ValueError(f"rest_reflections needs one reflection per characteristic joint (6), got {len(self.rest_reflections)}")

    def learning_rate_schedule(self) -> float | optax.Schedule:
        """The rate the optimiser scales by: the constant ``learning_rate`` or the warm-up + cosine schedule."""
        if self.lr_schedule == "constant":
            return self.learning_rate
        decay = optax.cosine_decay_schedule(self.learning_rate, self.total_steps - self.warmup_steps, alpha=self.final_lr_fraction)
        return warmup_then_decay(decay, init_value=0.0, peak_value=self.learning_rate, warmup_steps=self.warmup_steps)

    def optimizer(self) -> optax.GradientTransformation:
        """AdamW with AMSGrad as the paper's PyTorch code, at :meth:`learning_rate_schedule`."""
        return adamw_amsgrad_torch(self.learning_rate_schedule(), self.weight_decay)


class CurveArrays(NamedTuple):
    """A curve dataset as device arrays, the ``data`` argument of the step."""

    ctrl_pos: Float[Array, "windows controls joints 3"]
    ctrl_tangent: Float[Array, "windows controls joints 3"]
    ctrl_rot6d: Float[Array, "windows controls joints 6"]
    ctrl_contacts: Bool[Array, "windows controls 2"]
    dense_pos: Float[Array, "windows frames joints 3"]

    @classmethod
    def from_dataset(cls, dataset: CurveDataset) -> CurveArrays:
        return cls(*(jnp.asarray(getattr(dataset, f)) for f in cls._fields))


class DenseWindows(NamedTuple):
    """Unfitted windows of the six characteristic joints, the ``data`` of a step that trains
    on many lengths (``BMMTrainConfig.spans``): each example is a prefix of one of them.

    Attributes:
      dense_pos: ``(windows, frames, 6, 3)`` aligned positions (cm; hips start at the origin in XZ).
      dense_rot6d: ``(windows, frames, 6, 6)`` global 6D orientations.
      dense_contacts: ``(windows, frames, 2)`` left/right foot contacts.
    """

    dense_pos: Float[Array, "windows frames joints 3"]
    dense_rot6d: Float[Array, "windows frames joints 6"]
    dense_contacts: Bool[Array, "windows frames 2"]

    @classmethod
    def from_clips(cls, clips: MotionClips, mapping: str | Mapping[str, str], *, frames: int, offset: int = DEFAULT_OFFSET) -> DenseWindows:
        """Every ``frames``-frame window of ``clips`` (one every ``offset`` frames), aligned and
        labelled as the curve datasets' windows are (:func:`~bezmotion.data.curves.characteristic_windows`)."""
        pos, rot6d, _, _ = characteristic_windows(clips, mapping, window=frames, offset=offset)
        if not len(pos):
            raise ValueError(f"no windows of {frames} frames in {clips.num_clips} clips")
        contacts = np.concatenate([np.asarray(contact_labels(jnp.asarray(p), clips.fps)) for p in np.array_split(pos, max(1, len(pos) // 1024))])
        return cls(jnp.asarray(pos), jnp.asarray(rot6d), jnp.asarray(contacts))


def span_fit_operators(stride: int, low: int, high: int) -> Float[Array, "spans controls frames"]:
    """:func:`~bezmotion.bezier.fit_operator` of every window of ``low … high`` frames from key
    to key, zero-padded to ``BezierLayout(high + 1, stride)``'s controls and frames (float32)."""
    padded = BezierLayout(high + 1, stride)
    out = np.zeros((high - low + 1, padded.num_controls, padded.num_frames), np.float32)
    for i, span in enumerate(range(low, high + 1)):
        op = fit_operator(BezierLayout(span + 1, stride))
        out[i, : op.shape[0], : op.shape[1]] = op
    return jnp.asarray(out)


def init_bmm_train_state(
    model_config: BMMConfig, train_config: BMMTrainConfig, *, key: Array
) -> tuple[nnx.GraphDef, TrainState]:
    """Fresh parameters and optimiser state for one seed."""
    init = lambda k: init_denoiser(model_config, key=k)  # noqa: E731
    return fresh_train_state(init, train_config.optimizer(), key=key, ema=True)


def init_bmm_train_states(
    model_config: BMMConfig, train_config: BMMTrainConfig, seeds: list[int] | tuple[int, ...]
) -> tuple[nnx.GraphDef, TrainState]:
    """States for several seeds, stacked on a leading axis (for the vmapped step)."""
    return stack_seeds(lambda key: init_bmm_train_state(model_config, train_config, key=key), seeds)


def make_training_window(
    model_config: BMMConfig, train_config: BMMTrainConfig
) -> Callable[[tuple[Array, ...], Array], tuple[tuple[Array, ...], BezierLayout]]:
    """``window(batch_item, rng) -> ((pos, tangent, rot6d, contacts, dense), layout)``: one
    training example's curves and their layout. Fixed windows (``spans=None``): the
    :class:`CurveArrays` item as it is, on the model's layout. ``spans``: a length drawn
    from ``rng`` (a key folded off it, so the other draws are those of a fixed length), the
    :class:`DenseWindows` item's first ``span + 1`` frames fitted on its grid, padded
    (:class:`~bezmotion.bezier.PaddedLayout`; the padding's control points hold real frames
    past the window, which nothing of the window reads)."""
    stride = model_config.stride
    if train_config.spans is None:
        fixed = BezierLayout.from_controls(model_config.num_controls, stride)
        return lambda batch_item, rng: (tuple(batch_item), fixed)
    low, high = train_config.spans
    native = model_config.num_frames - 1
    if train_config.native_span_fraction and not low <= native <= high:
        raise ValueError(f"native_span_fraction draws the model's own span, {native} frames, outside spans {train_config.spans}")
    operators = span_fit_operators(stride, low, high)

    def window(batch_item, rng):
        dense, dense_rot6d, dense_contacts = batch_item
        if dense.shape[0] != high + 1:
            raise ValueError(f"spans {train_config.spans} need DenseWindows of {high + 1} frames, got {dense.shape[0]}")
        span = jax.random.randint(jax.random.fold_in(rng, 11), (), low, high + 1)
        if train_config.native_span_fraction:  # (a static branch: without it the draws are as before)
            span = jnp.where(jax.random.uniform(jax.random.fold_in(rng, 12)) < train_config.native_span_fraction, native, span)
        layout = PaddedLayout(span + 1, stride, high + 1)
        frames = jnp.minimum(layout.control_frames, high)
        tangent = exact_einsum("kf,fjd->kjd", operators[span - low], dense)
        return (dense[frames], tangent, dense_rot6d[frames], dense_contacts[frames], dense), layout

    return window


def make_bmm_example_loss(
    graphdef: nnx.GraphDef,
    model_config: BMMConfig,
    train_config: BMMTrainConfig,
    stats: FeatureStats,
    *,
    schedule: DiffusionSchedule | None = None,
) -> Callable[[nnx.State, tuple[Array, ...], Array], tuple[Array, dict[str, Array]]]:
    """``example_loss(params, batch_item, rng) -> (weighted loss, terms)`` of one example
    (``batch_item``: one window of the step's ``data``), as the step computes it."""
    schedule = cosine_schedule(model_config.num_timesteps) if schedule is None else schedule
    weights = train_config.weights
    k_joints, stride = model_config.num_joints, model_config.stride
    window = make_training_window(model_config, train_config)

    def example_loss(params, batch_item, rng):
        (pos, tangent, rot6d, contacts, dense), layout = window(batch_item, rng)
        k_ctrl = layout.num_controls
        t_key, noise_key, cond_key, drop_key, dropout_key = jax.random.split(rng, 5)
        # Augmentation draws from a key folded off rng, so without it the stream is the paper's.
        pos, tangent, rot6d, contacts, dense = augment(
            jax.random.fold_in(rng, 7), (pos, tangent, rot6d, contacts, dense), yaw=train_config.yaw_augmentation,
            mirror_probability=train_config.mirror_augmentation, reflections=train_config.rest_reflections,
            still_probability=train_config.still_augmentation,
        )  # fmt: skip
        t = jax.random.randint(t_key, (), 0, schedule.num_timesteps)
        x0 = to_tokens(stats.normalize(control_features(pos, tangent, rot6d)))
        x_t = schedule.add_noise(x0, t, jax.random.normal(noise_key, x0.shape, x0.dtype))
        control, joint, valid = draw_intermediate_slots(
            cond_key, k_ctrl, k_joints, train_config.max_intermediate_handles, last_control=layout.last_control
        )
        # Off-grid frames draw from a key folded off cond_key, so the paper's setting
        # (off_grid_handles = 0, nothing drawn) keeps its random stream.
        frame = draw_handle_frames(jax.random.fold_in(cond_key, 1), control, layout, train_config.off_grid_handles)
        position = handle_positions(layout, pos, tangent, joint, frame) if train_config.off_grid_handles else pos[control, joint]
        conditions = inbetween_conditions(layout.num_frames, pos[0], pos[layout.last_control], Handles(joint, frame, position, valid))
        # Classifier-free guidance: drop every condition of this example at once.
        conditions = conditions._replace(valid=conditions.valid & ~jax.random.bernoulli(drop_key, train_config.condition_dropout))
        mask, _ = grid_conditions(layout, conditions, k_joints)
        off_grid = None
        if train_config.off_grid_handles:
            n = 2 * k_joints  # the handles follow the start and end slots
            off_grid = Handles(joint, conditions.frame[n:], position, conditions.valid[n:] & (frame % stride != 0))
        conditions = normalize_conditions(stats, conditions)
        pred_tokens, contact_logits = predict_x0(
            nnx.merge(graphdef, params), stats, x_t, t, conditions, key=dropout_key, layout=layout
        )
        pred_pos, pred_tangent, pred_rot6d = split_features(stats.denormalize(from_tokens(pred_tokens)))
        terms = bmm_loss_terms(
            layout, pred_pos, pred_tangent, pred_rot6d, contact_logits, pos, tangent, rot6d, contacts, dense, mask,
            off_grid_conditions=off_grid,
        )  # fmt: skip
        weight = min_snr_weight(schedule.snr(t), train_config.min_snr_gamma)
        return weight * weights.total(terms), terms

    return example_loss


def make_bmm_train_step(
    graphdef: nnx.GraphDef,
    model_config: BMMConfig,
    train_config: BMMTrainConfig,
    stats: FeatureStats,
    *,
    schedule: DiffusionSchedule | None = None,
    mesh: Mesh | None = None,
) -> Callable[[TrainState, CurveArrays], tuple[TrainState, dict[str, Array]]]:
    """The (un-jitted) single-seed training step; see :func:`compile_train_step`."""
    optimizer = train_config.optimizer()
    example_loss = make_bmm_example_loss(graphdef, model_config, train_config, stats, schedule=schedule)

    def loss_fn(params, batch, rngs):
        losses, terms = jax.vmap(example_loss, in_axes=(None, 0, 0))(params, batch, rngs)
        return jnp.mean(losses), jax.tree.map(jnp.mean, terms)

    def step(state: TrainState, data: CurveArrays | DenseWindows) -> tuple[TrainState, dict[str, Array]]:
        key, index_key, example_key = jax.random.split(state.key, 3)
        index = jax.random.randint(index_key, (train_config.batch_size,), 0, data[0].shape[0])
        batch = jax.tree.map(lambda a: shard_batch(a[index], mesh), tuple(data))
        rngs = jax.random.split(example_key, train_config.batch_size)
        return apply_gradients(state, optimizer, loss_fn, batch, rngs, next_key=key, ema_decay=train_config.ema_decay)

    return step


__all__ = [
    "LR_SCHEDULES",
    "BMMTrainConfig",
    "CurveArrays",
    "DenseWindows",
    "span_fit_operators",
    "init_bmm_train_state",
    "init_bmm_train_states",
    "make_bmm_example_loss",
    "make_bmm_train_step",
    "make_training_window",
]
