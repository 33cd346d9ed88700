"""What the BMM denoiser sees: normalised frame features and sampled conditions.

A motion's control points become ``(controls, joints, 12)`` features — position (cm),
tangent (cm) and ortho6D orientation of every characteristic joint — normalised per
(joint, feature) by the training set's mean and standard deviation (MDM does the same),
and flattened to ``(controls, joints·12)`` frame tokens. Conditions are positions and use
the position entries of the same statistics.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bezmotion.bezier import BezierLayout, basis
from bezmotion._src.linalg import exact_einsum
from bezmotion.data.curves import CurveDataset
from bezmotion.diffusion.projection import on_control_frame
from bezmotion.interpolation import interpolation_through_points
from bezmotion.bmm.denoiser import FEATURES_PER_JOINT, BMMDenoiser
from bezmotion.handles import Handles
from bezmotion.bmm.unet import CondUNet1D

MAX_INTERMEDIATE_HANDLES = 4  # BMM §5.2: zero to four uniformly sampled intermediate handles
STD_FLOOR = 1e-3  # features that never vary (e.g. a constant) must not divide by zero


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FeatureStats:
    """Per-(joint, feature) normalisation of control-point features (or of any per-joint
    features whose first three are a position: the dense frames of the ablations).

    Attributes:
      mean, std: ``(joints, 12)`` over all training windows and control points, in the
        features' own units (cm for positions and tangents).
    """

    mean: Float[Array, "joints features"]
    std: Float[Array, "joints features"]

    @classmethod
    def from_dataset(cls, dataset: CurveDataset) -> FeatureStats:
        return cls.from_features(control_features(dataset.ctrl_pos, dataset.ctrl_tangent, dataset.ctrl_rot6d))

    @classmethod
    def from_features(cls, features: Float[Array | np.ndarray, "*batch joints features"]) -> FeatureStats:
        """Mean and floored std per (joint, feature) over every leading axis (float64
        accumulation), e.g. ``(windows, controls, 6, 12)`` control features or the dense
        ``(windows, frames, joints, features)`` of :mod:`bezmotion.evaluation.ablations`."""
        feats = np.asarray(features, np.float64)
        flat = feats.reshape(-1, *feats.shape[-2:])
        return cls(
            jnp.asarray(flat.mean(axis=0), jnp.float32),
            jnp.asarray(np.maximum(flat.std(axis=0), STD_FLOOR), jnp.float32),
        )

    def normalize(self, features: Float[Array, "*batch joints features"]) -> Float[Array, "*batch joints features"]:
        return (features - self.mean) / self.std

    def denormalize(self, features: Float[Array, "*batch joints features"]) -> Float[Array, "*batch joints features"]:
        return features * self.std + self.mean

    def normalize_positions(self, pos: Float[Array, "*batch 3"], joint) -> Float[Array, "*batch 3"]:
        """Normalise positions of the given joint indices with the position statistics."""
        return (pos - self.mean[joint, :3]) / self.std[joint, :3]


def control_features(
    ctrl_pos: Float[Array | np.ndarray, "*batch controls joints 3"],
    ctrl_tangent: Float[Array | np.ndarray, "*batch controls joints 3"],
    ctrl_rot6d: Float[Array | np.ndarray, "*batch controls joints 6"],
) -> Float[Array, "*batch controls joints 12"]:
    """Stack position, tangent and orientation per joint: ``[P, T, O]``."""
    return jnp.concatenate([jnp.asarray(ctrl_pos), jnp.asarray(ctrl_tangent), jnp.asarray(ctrl_rot6d)], axis=-1)


def split_features(
    features: Float[Array, "*batch controls joints 12"],
) -> tuple[Float[Array, "*batch controls joints 3"], Float[Array, "*batch controls joints 3"], Float[Array, "*batch controls joints 6"]]:
    """Inverse of :func:`control_features`: ``(ctrl_pos, ctrl_tangent, ctrl_rot6d)``."""
    return features[..., :3], features[..., 3:6], features[..., 6:]


def to_tokens(features: Float[Array, "*batch controls joints 12"]) -> Float[Array, "*batch controls features"]:
    """Flatten the joint axis into the frame token: ``(controls, joints·12)``."""
    return features.reshape(*features.shape[:-2], -1)


def from_tokens(tokens: Float[Array, "*batch controls features"]) -> Float[Array, "*batch controls joints 12"]:
    return tokens.reshape(*tokens.shape[:-1], -1, FEATURES_PER_JOINT)


def draw_intermediate_slots(
    key: Array, num_controls: int, num_joints: int, max_handles: int, min_handles: int = 0, *, last_control: int | Int[Array, ""] | None = None
) -> tuple[Int[Array, "max_handles"], Int[Array, "max_handles"], Bool[Array, "max_handles"]]:
    """Random distinct intermediate (control, joint) slots: ``n ~ U{min_handles, …, max_handles}``
    of the ``(K−2)·J`` slots between the end control points, chosen uniformly (BMM §5.2).

    ``last_control``: the window's last control point (a layout's ``last_control``; traced
    for a :class:`~bezmotion.bezier.PaddedLayout`, whose later ones are padding): only the
    slots before it are drawn, and ``n`` is at most their number. ``K − 1`` (or ``None``)
    draws exactly what the paper's draw does.

    Returns:
      ``(control, joint, valid)``, each ``(max_handles,)``; the first ``n`` are valid.
    """
    count_key, order_key = jax.random.split(key)
    n = jax.random.randint(count_key, (), min_handles, max_handles + 1)
    draws = jax.random.uniform(order_key, ((num_controls - 2) * num_joints,))
    if last_control is not None:  # the padding's slots sort after every slot of the window
        inside = jnp.arange(draws.shape[0]) // num_joints + 1 < last_control
        draws = jnp.where(inside, draws, 2.0)
        n = jnp.minimum(n, jnp.sum(inside))
    # The first max_handles of a random order of all slots: distinct, uniformly chosen.
    order = jnp.argsort(draws)[:max_handles]
    control = (order // num_joints + 1).astype(jnp.int32)
    joint = (order % num_joints).astype(jnp.int32)
    return control, joint, jnp.arange(max_handles) < n


def draw_handle_frames(key: Array, control: Int[Array, "*shape"], layout: BezierLayout, off_grid: float) -> Int[Array, "*shape"]:
    """Frames for handles drawn on control points (training): each stays on its control
    frame, or with probability ``off_grid`` moves to a uniformly drawn intermediate frame
    (1 … last − 1). Two handles of one joint may land on one frame: their positions come
    from the same curve, so they agree.

    ``off_grid = 0`` returns ``control · stride`` without drawing anything (the paper's
    handles, and the random stream of a training without off-grid handles).
    """
    frame = jnp.asarray(layout.control_frames, jnp.int32)[control]
    if off_grid == 0.0:
        return frame
    move_key, frame_key = jax.random.split(key)
    anywhere = jax.random.randint(frame_key, frame.shape, 1, layout.num_frames - 1).astype(jnp.int32)
    return jnp.where(jax.random.bernoulli(move_key, off_grid, frame.shape), anywhere, frame)


HANDLE_FRAMES = ("grid", "off_grid", "any")


def handle_frame_choices(layout: BezierLayout, frames: str) -> np.ndarray:
    """The intermediate frames handles may sit on: ``"grid"`` the control frames,
    ``"off_grid"`` the frames between them, ``"any"`` all of 1 … last − 1."""
    inner = np.arange(1, layout.num_frames - 1)
    on_grid = np.isin(inner, layout.control_frames)
    choices = {"grid": inner[on_grid], "off_grid": inner[~on_grid], "any": inner}
    if frames not in choices:
        raise ValueError(f"handle frames must be one of {HANDLE_FRAMES}, got {frames!r}")
    return choices[frames]


def draw_intermediate_frames(
    key: Array, layout: BezierLayout, num_joints: int, max_handles: int, min_handles: int = 0, *, frames: str = "grid"
) -> tuple[Int[Array, "max_handles"], Int[Array, "max_handles"], Bool[Array, "max_handles"]]:
    """Random distinct (frame, joint) slots among ``handle_frame_choices(layout, frames)``:
    :func:`draw_intermediate_slots` over frames rather than control points, with the same
    draws — ``frames="grid"`` gives its slots exactly, and every choice of ``frames`` the
    same number of handles for one key. Distinct slots: never two handles on one joint and
    frame (noisy copies of them could not both be met).

    Returns:
      ``(frame, joint, valid)``, each ``(max_handles,)``; the first ``n`` are valid.
    """
    choices = handle_frame_choices(layout, frames)
    count_key, order_key = jax.random.split(key)
    n = jax.random.randint(count_key, (), min_handles, max_handles + 1)
    order = jnp.argsort(jax.random.uniform(order_key, (len(choices) * num_joints,)))[:max_handles]
    frame = jnp.asarray(choices, jnp.int32)[order // num_joints]
    joint = (order % num_joints).astype(jnp.int32)
    return frame, joint, jnp.arange(max_handles) < n


def handle_positions(
    layout: BezierLayout,
    ctrl_pos: Float[Array, "controls joints 3"],
    ctrl_tangent: Float[Array, "controls joints 3"],
    joint: Int[Array, "handles"],
    frame: Int[Array, "handles"],
) -> Float[Array, "handles 3"]:
    """Where the curves of one motion are at each (joint, frame): the control position
    itself on control frames (bit for bit), the evaluated curve between them."""
    on_grid, control = on_control_frame(layout, frame)
    w_pos, w_tan = basis(layout, frame.astype(ctrl_pos.dtype))
    between = exact_einsum("hk,khd->hd", w_pos.astype(ctrl_pos.dtype), ctrl_pos[:, joint]) + exact_einsum(
        "hk,khd->hd", w_tan.astype(ctrl_pos.dtype), ctrl_tangent[:, joint]
    )
    return jnp.where(on_grid[:, None], ctrl_pos[control, joint], between)


def inbetween_conditions(
    num_frames: int | Int[Array, ""],
    start: Float[Array, "joints 3"],
    end: Float[Array, "joints 3"],
    handles: Handles,
) -> Handles:
    """The in-betweening condition slots of one motion: every joint at the first and at the
    last frame (always valid), then the ``(handles,)`` handles. Positions as given (cm)."""
    j = start.shape[0]
    joints = jnp.arange(j, dtype=jnp.int32)
    return Handles(
        position=jnp.concatenate([start, end, handles.position]),
        joint=jnp.concatenate([joints, joints, handles.joint]),
        frame=jnp.concatenate([jnp.zeros(j, jnp.int32), jnp.full(j, num_frames - 1, jnp.int32), handles.frame]),
        valid=jnp.concatenate([jnp.ones(2 * j, bool), handles.valid]),
    )


def normalize_conditions(stats: FeatureStats, conditions: Handles, translation: Float[Array, "3"] | None = None) -> Handles:
    """Positions → the model's normalised space (after subtracting ``translation``, the
    start alignment); padding slots get zeros, never a value they would reveal."""
    position = conditions.position if translation is None else conditions.position - translation
    position = stats.normalize_positions(position, conditions.joint)
    return conditions._replace(position=jnp.where(conditions.valid[..., None], position, 0.0))


def interpolation_prior(
    stats: FeatureStats, conditions: Handles, layout: BezierLayout, *, off_grid: str = "linear"
) -> Float[Array, "controls features"]:
    """The reference curves through the conditions, as normalised frame tokens (one motion).

    Positions and tangents are :func:`~bezmotion.interpolation.interpolation_through_points` of
    the conditions (``off_grid``: how it reaches conditions between control frames;
    ``"linear"`` interpolates through them, ``"projection"``, the prior that models saved
    without ``off_grid_prior`` learned their residual over, bends the curve at such a condition alone);
    orientations are the training mean (0 once normalised). A joint whose first or last
    control point is not conditioned (e.g. all conditions dropped for classifier-free
    guidance) gets the mean everywhere.

    Args:
      conditions: normalised condition slots (:func:`normalize_conditions`).
      layout: the curves' layout (control points and stride).
      off_grid: ``"projection"`` or ``"linear"`` (:data:`~bezmotion.interpolation.OFF_GRID_REFERENCES`).
    Returns:
      ``(controls, joints·12)`` normalised features.
    """
    num_joints = stats.mean.shape[0]
    num_controls = layout.num_controls
    target_cm = conditions.position * stats.std[conditions.joint, :3] + stats.mean[conditions.joint, :3]
    ctrl_pos, ctrl_tangent, mask = interpolation_through_points(
        layout, conditions._replace(position=target_cm), num_joints, off_grid=off_grid
    )
    feats = stats.normalize(jnp.concatenate([ctrl_pos, ctrl_tangent, jnp.broadcast_to(stats.mean[:, 6:], (num_controls, num_joints, 6))], axis=-1))
    known = mask[0] & mask[layout.last_control]
    return to_tokens(jnp.where(known[None, :, None], feats, 0.0))


def predict_x0(
    denoiser: BMMDenoiser | CondUNet1D,
    stats: FeatureStats,
    x_t: Float[Array, "controls features"],
    t: Int[Array, ""],
    conditions: Handles,
    *,
    key: Array | None = None,
    layout: BezierLayout | None = None,
) -> tuple[Float[Array, "controls features"], Float[Array, "controls 2"]]:
    """x̂₀ and contact logits from a denoiser of either ``prediction`` kind (the BMM's
    transformer, or CondMDIᴳ's UNet, which predicts x₀): training and sampling both call
    this, so they cannot disagree on what the network outputs. ``layout``: a window of
    another length than the config's (the BMM's transformer only), its control points' frames;
    a :class:`~bezmotion.bezier.PaddedLayout` (training on many lengths) masks its padding."""
    cfg = denoiser.config
    if layout is None:
        layout = BezierLayout.from_controls(cfg.num_controls, cfg.stride)
        x0, logits = denoiser(x_t, t, conditions, key=key)
    else:
        x0, logits = denoiser(x_t, t, conditions, key=key, control_frames=layout.control_frames, control_valid=layout.control_valid)
    if cfg.prediction == "residual":
        x0 = x0 + interpolation_prior(stats, conditions, layout, off_grid=cfg.off_grid_prior)
    return x0, logits
