"""The paper's ablations of the BMM without Bézier curves (BMM §5.3, §5.4, Table 1): the
same transformer denoiser, one token per *frame* instead of per control point.

- **BMM⁻ᴮ** (``variant="minus_b"``): "does not use Bézier points but predicts the dense
  3D trajectories for J_sub" (§5.3). A token is one frame of the six characteristic
  joints: position (cm) and, by default, ortho6D global orientation — what the learned IK
  reads, since the paper scores this row after IK ("For BMM and BMM⁻ᴮ, the metrics are
  computed after the IK-module", Table 1). 31 tokens of ``6·9`` features, where the BMM
  has 6 of ``6·12`` (position, tangent, orientation).
- **BMM⁻ᴵᴷ⁻ᴮ** (``variant="minus_ik_b"``): the full skeleton generated directly, no IK. A
  token is one frame of every joint of the corpus skeleton, positions only (``J·3``
  features), conditioned on the six characteristic joints (start, end, handles) like the
  BMM. The paper's version pairs every joint's position with its orientation (§5.3: "the
  data is represented as a pair of positions and orientation, where the constrained
  positions can be inpainted"); ours keeps the positions that Table 1's metrics read
  (handles error, skating, dense error). A pose for export would need the orientations,
  or an IK again.
- **CondMDIᴳ** (``variant="condmdi_g"``, :class:`CondMDIConfig`): the paper's baseline
  (§5.3, Appendix C.3), CondMDI (Cohan et al. 2024) in world coordinates: BMM⁻ᴵᴷ⁻ᴮ's data,
  losses, schedule, training and sampling, with another network and guidance. The network
  is a 1-D temporal UNet (:class:`~bezmotion.bmm.unet.CondUNet1D`, GMD's backbone) whose
  input channels are the noisy motion, the condition values and the condition mask
  (imputation-style conditioning) instead of condition tokens; classifier-free guidance
  (conditions dropped with p = 0.1 in training, :func:`drop_conditions`) is sampled at
  scale 2.5 by default (``CondMDIConfig.guidance``, CondMDI's and the paper's setting).
  Known entries are inpainted into x̂₀ at every DDIM step by :func:`sample_dense`'s
  ``overwrite``: CondMDI's imputation writes every known entry (``"all"``); the Table 1
  row uses ``"keys"`` (start and end poses) like BMM⁻ᴵᴷ⁻ᴮ, so that both rows are measured
  alike and the handles error measures what the network does with a handle (the paper
  reports CondMDIᴳ missing its handles by centimetres, which exact imputation at the last
  step would not). As for BMM⁻ᴵᴷ⁻ᴮ, ours generates positions only (the paper's pairs them
  with orientations). Its sizes are ours (``cpu``: 64 base channels, levels ×1, ×2, ×4,
  4.2 M parameters on the 22-joint Bandai-Namco skeleton); ``paper`` is GMD's UNet as we
  read it (512 base channels, four levels ×2: 224 M parameters, the paper's Table 7
  reports 224.6 M).

**The same as the BMM**, by reuse rather than copy: the denoiser
(:class:`~bezmotion.bmm.denoiser.BMMDenoiser`, whose token layout is its config's
``frame_features``: :class:`DenseBMMConfig` is a :class:`~bezmotion.bmm.denoiser.BMMConfig`
with a token per frame, stride 1, and the BMM's sizes and presets); the conditions (all
six joints at the first and last frame plus 0–4 handles, §5.2; condition tokens with the
joint embedding over the six joints; :func:`~bezmotion.bmm.features.inbetween_conditions`);
the normalisation per joint and feature (:class:`~bezmotion.bmm.features.FeatureStats`);
the diffusion (cosine schedule, x₀-prediction, Min-SNR-γ, condition dropout for
classifier-free guidance, :class:`~bezmotion.bmm.train.BMMTrainConfig`); the loop
(:mod:`bezmotion.training`); the loss weights (:class:`~bezmotion.bmm.losses.LossWeights`:
L_p, L_v, L_o, L_c, L_gc and L_skate, here at every frame; L_b and L_t have no analogue
without control points); DDIM (:func:`~bezmotion.diffusion.ddim.ddim_sample`, with the
BMM's guidance, :func:`~bezmotion.bmm.sampling.guided_denoiser`).

**What differs, and why.** Training handles may sit on any intermediate frame
(``handle_frames="any"``, default): a dense model has no control grid, and any frame is
one of its tokens (``"grid"`` keeps the BMM's control frames). And overwrite: the BMM
overwrites its conditions' control points, whose smoothness spreads the change over the
curve (Appendix A.3, Figure 9), whereas "when using dense 3D trajectories such a direct
overwrite cannot be done without introducing artifacts", and "overwriting cannot be
applied for BMM⁻ᴮ without introducing artifacts" (§5.4) — the paper reports the ablation
without it. :func:`sample_dense` therefore takes ``overwrite="keys"`` (the default: the
start and end poses, which in in-betweening *are* the output's first and last frames),
``"all"`` (the handles too, each only at its own frame: the spike the paper warns of) or
``"none"`` (the raw model).

Positions are centimetres, +Y up, aligned as the BMM's windows (the characteristic hips
start at the origin in XZ; :func:`sample_dense` aligns and moves back).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jax.sharding import Mesh
from jaxtyping import Array, Bool, Float

from bezmotion.bezier import BezierLayout
from bezmotion.bmm.denoiser import BMMConfig, init_denoiser
from bezmotion.handles import Handles
from bezmotion.bmm.features import (
    HANDLE_FRAMES,
    FeatureStats,
    draw_intermediate_frames,
    inbetween_conditions,
    normalize_conditions,
    predict_x0,
)
from bezmotion.bmm.losses import CM_PER_M, dense_velocity, min_snr_weight
from bezmotion.bmm.sampling import guided_denoiser, over_batch
from bezmotion.bmm.train import BMMTrainConfig
from bezmotion.bmm.unet import GROUPS, init_unet
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, FEET, HIPS, characteristic_indices, contact_labels
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import DEFAULT_OFFSET, DEFAULT_WINDOW, characteristic_windows, skeleton_windows
from bezmotion.diffusion.ddim import ddim_sample
from bezmotion.diffusion.schedule import DiffusionSchedule, cosine_schedule
from bezmotion.training.checkpoint import CheckpointStore, save_model_folder
from bezmotion.training.loop import shard_batch
from bezmotion.training.state import TrainState, fresh_train_state
from bezmotion.training.step import apply_gradients
from bezmotion._src.xla_options import inference_jit

ABLATIONS = ("minus_b", "minus_ik_b", "condmdi_g")
"""``minus_b``: BMM⁻ᴮ, dense six-joint trajectories; ``minus_ik_b``: BMM⁻ᴵᴷ⁻ᴮ, the dense full skeleton;
``condmdi_g``: CondMDIᴳ, the dense full skeleton from a 1-D UNet with classifier-free guidance."""

OVERWRITE_MODES = ("none", "keys", "all")
"""What :func:`sample_dense` writes into x̂₀: nothing, the start and end poses, or those and the handles."""

POSITION, POSE = 3, 9  # features per joint: position (cm); position and ortho6D orientation
_SIZES = ("cpu", "paper", "tiny")  # BMMConfig's size presets
_NUM_CHARACTERISTIC = len(CHARACTERISTIC_JOINTS)


@dataclasses.dataclass(frozen=True)
class DenseBMMConfig(BMMConfig):
    """The BMM denoiser over dense frames: one token per frame of ``token_joints`` joints.

    Shares :class:`~bezmotion.bmm.denoiser.BMMConfig`'s transformer sizes and presets
    (``DenseBMMConfig.cpu(...)``); build one with :meth:`minus_b`, :meth:`minus_ik_b` or
    :meth:`condmdi_g`.

    Attributes (beyond the BMM's; ``num_joints`` stays the six characteristic joints the
    conditions are on):
      num_controls: tokens per window = frames (31).
      stride: frames between tokens, 1.
      variant: ``"minus_b"``, ``"minus_ik_b"`` or ``"condmdi_g"`` (:data:`ABLATIONS`; the
        last only as a :class:`CondMDIConfig`, whose network is a UNet).
      token_joints: joints in a frame token: 6 (BMM⁻ᴮ) or the skeleton's ``J`` (BMM⁻ᴵᴷ⁻ᴮ).
      features_per_joint: 9 (``[position cm | ortho6D]``) or 3 (position); the full
        skeleton has positions only.
      characteristic: the token joint of each characteristic joint, in
        :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS` order (BMM⁻ᴮ: 0…5;
        BMM⁻ᴵᴷ⁻ᴮ: the skeleton's :func:`~bezmotion.data.characteristic.characteristic_indices`).
    """

    num_controls: int = DEFAULT_WINDOW
    stride: int = 1
    variant: str = "minus_b"
    token_joints: int = _NUM_CHARACTERISTIC
    features_per_joint: int = POSE
    characteristic: tuple[int, ...] = tuple(range(_NUM_CHARACTERISTIC))

    def __post_init__(self):
        super().__post_init__()
        if self.variant not in ABLATIONS:
            raise ValueError(f"DenseBMMConfig.variant must be one of {ABLATIONS}, got {self.variant!r}")
        if self.stride != 1:
            raise ValueError(f"DenseBMMConfig has one token per frame: stride must be 1, got {self.stride}")
        if self.prediction != "x0":
            raise ValueError(f"DenseBMMConfig predicts x0 (the residual prior is the BMM's Bézier reference), got {self.prediction!r}")
        if self.num_joints != _NUM_CHARACTERISTIC:
            raise ValueError(f"DenseBMMConfig.num_joints is the {_NUM_CHARACTERISTIC} characteristic joints, got {self.num_joints}")
        if isinstance(self.token_joints, bool) or not isinstance(self.token_joints, int) or self.token_joints < _NUM_CHARACTERISTIC:
            raise ValueError(f"DenseBMMConfig.token_joints must be an integer ≥ {_NUM_CHARACTERISTIC}, got {self.token_joints!r}")
        if self.features_per_joint not in (POSITION, POSE):
            raise ValueError(f"DenseBMMConfig.features_per_joint must be {POSITION} or {POSE}, got {self.features_per_joint!r}")
        c = self.characteristic
        if (
            not isinstance(c, tuple)
            or len(c) != _NUM_CHARACTERISTIC
            or len(set(c)) != len(c)
            or not all(isinstance(j, int) and not isinstance(j, bool) and 0 <= j < self.token_joints for j in c)
        ):
            raise ValueError(
                f"DenseBMMConfig.characteristic must be {_NUM_CHARACTERISTIC} distinct token joints in 0…{self.token_joints - 1}, got {c!r}"
            )
        if self.variant == "minus_b" and (self.token_joints != _NUM_CHARACTERISTIC or c != tuple(range(_NUM_CHARACTERISTIC))):
            raise ValueError(f"minus_b's tokens are the six characteristic joints in order, got token_joints={self.token_joints}, characteristic={c}")
        if self.full_skeleton and self.features_per_joint != POSITION:
            raise ValueError(f"{self.variant} generates positions only (features_per_joint={POSITION}), got {self.features_per_joint}")
        if (self.variant == "condmdi_g") != isinstance(self, CondMDIConfig):
            raise ValueError(f"variant 'condmdi_g' is a CondMDIConfig (its UNet's sizes), and only it: got {type(self).__name__}(variant={self.variant!r})")

    @property
    def frame_features(self) -> int:
        return self.token_joints * self.features_per_joint

    @property
    def full_skeleton(self) -> bool:
        """Whether a frame is every joint of the skeleton (BMM⁻ᴵᴷ⁻ᴮ, CondMDIᴳ), not the six joints."""
        return self.variant != "minus_b"

    @property
    def default_guidance(self) -> float:
        """The classifier-free guidance scale :func:`sample_dense` uses unless told (1: off)."""
        return 1.0

    @classmethod
    def from_dict(cls, saved: Mapping) -> DenseBMMConfig:
        """The config from ``dataclasses.asdict(config)`` as a checkpoint's JSON gives it back
        (lists for tuples; a CondMDIᴳ's as a :class:`CondMDIConfig`)."""
        tuples = {k: tuple(v) for k, v in saved.items() if k in ("characteristic", "unet_mults")}
        return (CondMDIConfig if saved.get("variant") == "condmdi_g" else DenseBMMConfig)(**{**saved, **tuples})

    @property
    def orientation(self) -> bool:
        """Whether tokens carry the joints' ortho6D orientations."""
        return self.features_per_joint == POSE

    @classmethod
    def minus_b(cls, size: str = "cpu", *, orientation: bool = True, **overrides) -> DenseBMMConfig:
        """BMM⁻ᴮ at a BMM size preset (``cpu``, ``paper``, ``tiny``); ``orientation=False``:
        positions only."""
        return _preset(cls, size)(variant="minus_b", features_per_joint=POSE if orientation else POSITION, **overrides)

    @classmethod
    def minus_ik_b(
        cls, joint_names: Sequence[str], mapping: str | Mapping[str, str], size: str = "cpu", **overrides
    ) -> DenseBMMConfig:
        """BMM⁻ᴵᴷ⁻ᴮ for a skeleton (its joint names and characteristic-joint map) at a BMM size preset."""
        return _preset(cls, size)(
            variant="minus_ik_b", token_joints=len(joint_names), features_per_joint=POSITION,
            characteristic=characteristic_indices(joint_names, mapping), **overrides,
        )  # fmt: skip

    @classmethod
    def condmdi_g(
        cls, joint_names: Sequence[str], mapping: str | Mapping[str, str], size: str = "cpu", **overrides
    ) -> CondMDIConfig:
        """CondMDIᴳ for a skeleton (its joint names and characteristic-joint map) at a size:
        ``tiny`` (16 base channels, 2 levels), ``cpu`` (64, 3 levels ×1, ×2, ×4) or
        ``paper`` (GMD's UNet as we read it: 512 base channels, 4 levels ×2)."""
        if size not in _SIZES:
            raise ValueError(f"unknown size {size!r}; the presets are {_SIZES}")
        width, mults = _UNET_SIZES[size]
        return CondMDIConfig(**{
            "width": width, "unet_mults": mults, "variant": "condmdi_g", "token_joints": len(joint_names),
            "features_per_joint": POSITION, "characteristic": characteristic_indices(joint_names, mapping), **overrides,
        })  # fmt: skip


_UNET_SIZES = {"tiny": (16, (1, 2)), "cpu": (64, (1, 2, 4)), "paper": (512, (2, 2, 2, 2))}


@dataclasses.dataclass(frozen=True)
class CondMDIConfig(DenseBMMConfig):
    """CondMDIᴳ: the dense full skeleton of BMM⁻ᴵᴷ⁻ᴮ from a 1-D temporal UNet
    (:class:`~bezmotion.bmm.unet.CondUNet1D`) with classifier-free guidance; build one with
    :meth:`DenseBMMConfig.condmdi_g`.

    The UNet reads ``width`` (its base channels and timestep-embedding width),
    ``num_timesteps`` and the dense layout; the transformer's ``ff_width``, ``num_heads``,
    ``num_layers`` and ``dropout`` are unused (the UNet has no dropout).

    Attributes (beyond :class:`DenseBMMConfig`'s):
      unet_mults: channels of each resolution level, as multiples of ``width``; a level
        halves the frames of the one before (31 frames are padded to a multiple of
        ``2^(levels−1)``).
      kernel_size: the temporal convolutions' kernel (frames; 5 as Diffuser's temporal UNet,
        whose blocks GMD's is built from).
      guidance: the classifier-free guidance scale sampled with by default (CondMDI's 2.5;
        ≥ 0, 1 = the conditional model alone, 0 = the unconditional one).
    """

    variant: str = "condmdi_g"
    features_per_joint: int = POSITION
    unet_mults: tuple[int, ...] = (1, 2, 4)
    kernel_size: int = 5
    guidance: float = 2.5

    def __post_init__(self):
        super().__post_init__()
        m = self.unet_mults
        if not isinstance(m, tuple) or not m or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 1 for x in m):
            raise ValueError(f"CondMDIConfig.unet_mults must be a non-empty tuple of positive integers, got {m!r}")
        if any((self.width * x) % GROUPS for x in m):
            raise ValueError(f"CondMDIConfig: every level's channels (width {self.width} × {m}) must be divisible by {GROUPS} (GroupNorm groups)")
        if isinstance(self.kernel_size, bool) or not isinstance(self.kernel_size, int) or self.kernel_size < 1 or self.kernel_size % 2 == 0:
            raise ValueError(f"CondMDIConfig.kernel_size must be an odd positive integer, got {self.kernel_size!r}")
        check_guidance(self.guidance)

    @property
    def default_guidance(self) -> float:
        return float(self.guidance)


def check_guidance(guidance: float | int) -> None:
    """Refuse a classifier-free guidance scale that is not a finite number ≥ 0, naming it."""
    if isinstance(guidance, bool) or not isinstance(guidance, (int, float)) or not 0.0 <= guidance < float("inf"):
        raise ValueError(f"classifier-free guidance must be a finite number ≥ 0, got {guidance!r}")


def init_dense_network(config: DenseBMMConfig, *, key: Array) -> tuple[nnx.GraphDef, nnx.State]:
    """The network of an ablation, split into ``(graphdef, params)``: the BMM's transformer
    (BMM⁻ᴮ, BMM⁻ᴵᴷ⁻ᴮ) or the 1-D UNet (CondMDIᴳ)."""
    if isinstance(config, CondMDIConfig):
        return init_unet(config, key=key)
    return init_denoiser(config, key=key)


def _preset(cls, size: str) -> Callable[..., DenseBMMConfig]:
    if size not in _SIZES:
        raise ValueError(f"unknown size {size!r}; the BMM's presets are {_SIZES}")
    return getattr(cls, size)


def characteristic_stats(config: DenseBMMConfig, stats: FeatureStats) -> FeatureStats:
    """The statistics of the six characteristic joints' tokens, indexed like the
    conditions' ``joint`` (0…5), so :func:`~bezmotion.bmm.features.normalize_conditions`
    normalises a condition as its token is normalised."""
    idx = jnp.asarray(config.characteristic)
    return FeatureStats(stats.mean[idx], stats.std[idx])


# ------------------------------------------------------------------------------------ data


class DenseArrays(NamedTuple):
    """Dense training windows, the ``data`` argument of the step (NumPy or device arrays).

    Attributes:
      features: ``(windows, frames, token_joints, features_per_joint)`` aligned positions
        (cm), then ortho6D global orientations when the config has them.
      contacts: ``(windows, frames, 2)`` left/right foot contact at every frame.
    """

    features: Float[Array | np.ndarray, "windows frames joints features"]
    contacts: Bool[Array | np.ndarray, "windows frames 2"]

    def characteristic_positions(self, config: DenseBMMConfig) -> Float[Array | np.ndarray, "windows frames 6 3"]:
        """The six characteristic joints' positions (cm)."""
        return self.features[..., list(config.characteristic), :3]


def dense_windows(
    clips: MotionClips, mapping: str | Mapping[str, str], config: DenseBMMConfig, *, offset: int = DEFAULT_OFFSET
) -> tuple[DenseArrays, np.ndarray, np.ndarray]:
    """Every ``config.num_frames``-frame window of ``clips``, ``offset`` frames apart, as the
    ablation's tokens (float32; the BMM's windows for the same window and offset, so the
    rows line up with a :class:`~bezmotion.data.curves.CurveDataset` of the same clips).

    Args:
      clips: the motion (e.g. ``motion_clips(corpus, "train")``).
      mapping: its characteristic-joint map (a preset name or dict).
      config: the ablation; BMM⁻ᴵᴷ⁻ᴮ's must be built for this skeleton.
      offset: frames between window starts (the BMM's 5).
    Returns:
      ``(arrays, clip_index (windows,), start_frame (windows,))``.
    Raises:
      ValueError: a BMM⁻ᴵᴷ⁻ᴮ config built for another skeleton (names both).
    """
    window = config.num_frames
    if config.variant == "minus_b":
        pos, rot6d, clip_index, start_frame = characteristic_windows(clips, mapping, window=window, offset=offset)
        features, six = (np.concatenate([pos, rot6d], axis=-1) if config.orientation else pos), pos
    else:
        indices = characteristic_indices(clips.joint_names, mapping)
        if len(clips.joint_names) != config.token_joints or indices != config.characteristic:
            raise ValueError(
                f"a minus_ik_b config for {config.token_joints} joints with characteristic joints {config.characteristic} "
                f"does not fit this skeleton: {len(clips.joint_names)} joints, characteristic joints {indices}"
            )
        features, clip_index, start_frame = skeleton_windows(clips, mapping, window=window, offset=offset)
        six = features[..., list(indices), :]
    contacts = np.asarray(contact_labels(jnp.asarray(six), clips.fps))
    return DenseArrays(features, contacts), clip_index, start_frame


# ------------------------------------------------------------------------------ the losses


def dense_loss_terms(
    config: DenseBMMConfig,
    pred: Float[Array, "frames joints features"],
    target: Float[Array, "frames joints features"],
    contact_logits: Float[Array, "frames 2"],
    target_contacts: Bool[Array, "frames 2"],
    conditions: Handles,
) -> dict[str, Float[Array, ""]]:
    """Unweighted loss terms of one motion, the BMM's dense ones at every frame (cm in, metres inside).

    Args:
      pred, target: denormalised features (positions cm, then orientations if any).
      contact_logits, target_contacts: per frame.
      conditions: the example's condition slots in cm (aligned), ``valid`` after the
        condition dropout: the condition term is the error at each valid slot's frame.
    Returns:
      ``{"dense_position", "velocity", "condition", "contact", "skate"}`` plus
      ``"orientation"`` with orientations (:class:`~bezmotion.bmm.losses.LossWeights` names).
    """
    to_m = 1.0 / CM_PER_M
    frames = pred.shape[0]
    char = jnp.asarray(config.characteristic)
    pred_pos, target_pos = pred[..., :3], target[..., :3]
    pred_vel = dense_velocity(pred_pos) * to_m
    contact = jax.nn.sigmoid(contact_logits)
    # Each frame's foot velocity towards the next frame (the last looks back), as the BMM's at its control frames.
    feet_vel = pred_vel[jnp.minimum(jnp.arange(frames), frames - 2)][:, char[jnp.asarray(FEET)]]  # (frames, 2, 3)
    joint = char[jnp.clip(conditions.joint, 0, _NUM_CHARACTERISTIC - 1)]
    err = jnp.sum(((pred_pos[jnp.clip(conditions.frame, 0, frames - 1), joint] - conditions.position) * to_m) ** 2, axis=-1)
    count = jnp.sum(conditions.valid.astype(pred.dtype))
    terms = {
        "dense_position": jnp.mean(((pred_pos - target_pos) * to_m) ** 2),
        "velocity": jnp.mean((pred_vel - dense_velocity(target_pos) * to_m) ** 2),
        "condition": jnp.sum(jnp.where(conditions.valid, err, 0.0)) / jnp.maximum(3.0 * count, 1.0),
        "contact": jnp.mean((contact - target_contacts.astype(contact.dtype)) ** 2),
        "skate": jnp.mean((contact[..., None] * feet_vel) ** 2),
    }
    if config.orientation:
        terms["orientation"] = jnp.mean((pred[..., 3:] - target[..., 3:]) ** 2)
    return terms


# ------------------------------------------------------------------------------- training


def init_dense_train_state(config: DenseBMMConfig, train_config: BMMTrainConfig, *, key: Array) -> tuple[nnx.GraphDef, TrainState]:
    """Fresh parameters, optimiser state (the BMM's) and EMA for one seed."""
    return fresh_train_state(lambda k: init_dense_network(config, key=k), train_config.optimizer(), key=key, ema=True)


def drop_conditions(key: Array, conditions: Handles, rate: float) -> Handles:
    """Classifier-free guidance's training-time dropout: with probability ``rate`` every
    condition of the example at once (``valid`` all false: the model's unconditional input).

    Raises:
      ValueError: ``rate`` outside [0, 1), naming it.
    """
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0.0 <= rate < 1.0:
        raise ValueError(f"condition dropout must be a probability in [0, 1), got {rate!r}")
    return conditions._replace(valid=conditions.valid & ~jax.random.bernoulli(key, rate))


def check_train_config(train_config: BMMTrainConfig) -> None:
    """Refuse the BMM training levers that act on Bézier examples (augmentation, off-grid
    handles — the ablations choose handle frames with ``handle_frames``), naming the value."""
    for name in ("yaw_augmentation", "mirror_augmentation", "off_grid_handles"):
        value = getattr(train_config, name)
        if value:
            raise ValueError(f"the dense ablations do not support BMMTrainConfig.{name} (got {value!r}); leave it at its default")


def make_dense_train_step(
    graphdef: nnx.GraphDef,
    config: DenseBMMConfig,
    train_config: BMMTrainConfig,
    stats: FeatureStats,
    *,
    handle_frames: str = "any",
    schedule: DiffusionSchedule | None = None,
    mesh: Mesh | None = None,
) -> Callable[[TrainState, DenseArrays], tuple[TrainState, dict[str, Array]]]:
    """The (un-jitted) single-seed training step of an ablation, ``step(state, data)``:
    pure, everything random drawn from ``state.key`` (the BMM step's contract); jit it
    with :func:`bezmotion.training.compile_train_step`.

    Args:
      config: the ablation.
      train_config: the BMM's optimisation settings (batch, rate, EMA, condition dropout,
        Min-SNR-γ, handles per window, loss weights, schedule); no augmentation.
      stats: normalisation of the tokens (:meth:`FeatureStats.from_features` of the training
        windows' features).
      handle_frames: where training handles sit: ``"any"`` intermediate frame (default),
        ``"grid"`` (the BMM's control frames) or ``"off_grid"``.
      schedule, mesh: the diffusion schedule (default cosine, ``config.num_timesteps``) and
        the data mesh (several devices).
    Raises:
      ValueError: an unsupported training lever, or ``handle_frames`` not one of
        :data:`~bezmotion.bmm.features.HANDLE_FRAMES`.
    """
    check_train_config(train_config)
    if handle_frames not in HANDLE_FRAMES:
        raise ValueError(f"handle_frames must be one of {HANDLE_FRAMES}, got {handle_frames!r}")
    schedule = cosine_schedule(config.num_timesteps) if schedule is None else schedule
    grid = BezierLayout(config.num_frames)  # the BMM's control frames: what "grid" handles mean
    optimizer = train_config.optimizer()
    weights = train_config.weights
    cond_stats = characteristic_stats(config, stats)
    char = jnp.asarray(config.characteristic)
    frames, joints = config.num_frames, config.token_joints

    def example_loss(params, item, rng):
        features, contacts = item
        t_key, noise_key, cond_key, drop_key, dropout_key = jax.random.split(rng, 5)
        t = jax.random.randint(t_key, (), 0, schedule.num_timesteps)
        x0 = stats.normalize(features).reshape(frames, -1)
        x_t = schedule.add_noise(x0, t, jax.random.normal(noise_key, x0.shape, x0.dtype))
        six = features[:, char, :3]  # (frames, 6, 3)
        frame, joint, valid = draw_intermediate_frames(
            cond_key, grid, _NUM_CHARACTERISTIC, train_config.max_intermediate_handles, frames=handle_frames
        )
        conditions = inbetween_conditions(frames, six[0], six[-1], Handles(joint, frame, six[frame, joint], valid))
        conditions = drop_conditions(drop_key, conditions, train_config.condition_dropout)
        pred, logits = predict_x0(
            nnx.merge(graphdef, params), stats, x_t, t, normalize_conditions(cond_stats, conditions), key=dropout_key
        )
        terms = dense_loss_terms(config, stats.denormalize(pred.reshape(frames, joints, -1)), features, logits, contacts, conditions)
        return min_snr_weight(schedule.snr(t), train_config.min_snr_gamma) * weights.total(terms), terms

    def loss_fn(params, batch, rngs):
        losses, terms = jax.vmap(example_loss, in_axes=(None, 0, 0))(params, batch, rngs)
        return jnp.mean(losses), jax.tree.map(jnp.mean, terms)

    def step(state: TrainState, data: DenseArrays) -> tuple[TrainState, dict[str, Array]]:
        key, index_key, example_key = jax.random.split(state.key, 3)
        index = jax.random.randint(index_key, (train_config.batch_size,), 0, data.features.shape[0])
        batch = jax.tree.map(lambda a: shard_batch(jnp.asarray(a)[index], mesh), tuple(data))
        rngs = jax.random.split(example_key, train_config.batch_size)
        return apply_gradients(state, optimizer, loss_fn, batch, rngs, next_key=key, ema_decay=train_config.ema_decay)

    return step


# ------------------------------------------------------------------------------- sampling


@functools.partial(jax.tree_util.register_dataclass, data_fields=("params", "stats"), meta_fields=("graphdef", "config"))
@dataclasses.dataclass(frozen=True)
class DenseMotionModel:
    """A trained ablation: parameters and token statistics (arrays) plus structure (static)."""

    params: nnx.State
    stats: FeatureStats
    graphdef: nnx.GraphDef
    config: DenseBMMConfig


class DenseMotion(NamedTuple):
    """An ablation's output (world frame, cm).

    Attributes:
      pos: ``(*batch, frames, token_joints, 3)`` positions of the token joints at every
        frame: the six characteristic joints (BMM⁻ᴮ) or the whole skeleton (BMM⁻ᴵᴷ⁻ᴮ).
      rot6d: ``(*batch, frames, token_joints, 6)`` global ortho6D orientations, or ``None``
        for a positions-only model.
      contacts: ``(*batch, frames, 2)`` left/right foot-contact probabilities.
    """

    pos: Float[Array, "*batch frames joints 3"]
    rot6d: Float[Array, "*batch frames joints 6"] | None
    contacts: Float[Array, "*batch frames 2"]

    def characteristic_positions(self, config: DenseBMMConfig) -> Float[Array, "*batch frames 6 3"]:
        """``(*batch, frames, 6, 3)``: the six characteristic joints (what the BMM's curves are)."""
        return self.pos[..., list(config.characteristic), :]


def _sample_dense_one(model: DenseMotionModel, start, end, handles: Handles, key, *, steps, guidance, overwrite) -> DenseMotion:
    cfg, stats = model.config, model.stats
    frames, joints = cfg.num_frames, cfg.token_joints
    translation = start[HIPS] * jnp.asarray([1.0, 0.0, 1.0], start.dtype)
    world = inbetween_conditions(frames, start, end, handles)
    normalized = normalize_conditions(characteristic_stats(cfg, stats), world, translation)
    # The slots written into x̂₀: the start and end poses (the first 2·6), and with "all" the handles.
    chosen = world.valid & (jnp.arange(world.valid.shape[0]) < 2 * _NUM_CHARACTERISTIC if overwrite == "keys" else True)
    frame = jnp.where(chosen, world.frame, frames)  # other slots scatter out of range and are dropped
    joint = jnp.asarray(cfg.characteristic)[jnp.clip(world.joint, 0, _NUM_CHARACTERISTIC - 1)]

    def fix(x0):
        feats = x0.reshape(frames, joints, -1)
        return feats.at[frame, joint, :3].set(normalized.position, mode="drop").reshape(frames, -1)

    denoise = guided_denoiser(functools.partial(predict_x0, nnx.merge(model.graphdef, model.params), stats), normalized, guidance)
    x_T = jax.random.normal(key, (frames, cfg.frame_features))
    x0, logits = ddim_sample(
        denoise, cosine_schedule(cfg.num_timesteps), x_T, steps=steps, overwrite=None if overwrite == "none" else fix, has_aux=True
    )
    feats = stats.denormalize(x0.reshape(frames, joints, -1))
    pos = feats[..., :3] + translation
    if overwrite != "none":  # the conditions themselves, not through a normalise/denormalise round trip
        pos = pos.at[frame, joint].set(world.position, mode="drop")
    return DenseMotion(pos, feats[..., 3:] if cfg.orientation else None, jax.nn.sigmoid(logits))


def sample_dense(
    model: DenseMotionModel,
    start: Float[Array, "*batch joints 3"],
    end: Float[Array, "*batch joints 3"],
    handles: Handles,
    *,
    key: Array,
    steps: int = 10,
    guidance: float | None = None,
    overwrite: str = "keys",
) -> DenseMotion:
    """Sample an ablation's dense motion between a start and an end pose through sparse handles.

    The inputs are :func:`~bezmotion.bmm.sampling.sample_curves`' (the six characteristic
    joints' positions at the first and last frame, handles on any frame 1 … 29), aligned
    and moved back the same way; DDIM with the BMM's schedule and guidance.

    Args:
      model: the trained ablation.
      start, end: ``(*batch, 6, 3)`` world positions of the characteristic joints (cm).
      handles: intermediate handles, batched like ``start``.
      key: PRNG key; split per motion when batched.
      steps: DDIM steps (the paper's 10).
      guidance: classifier-free guidance scale, ``out_uncond + guidance · (out_cond −
        out_uncond)`` (1: the conditional model alone; 0: the unconditional one); ``None``
        (default): the model's ``config.default_guidance`` (1 for BMM⁻ᴮ and BMM⁻ᴵᴷ⁻ᴮ,
        CondMDIᴳ's 2.5).
      overwrite: :data:`OVERWRITE_MODES`: ``"keys"`` (default) writes the start and end
        positions into x̂₀ at every step and exactly into the output; ``"all"`` also each
        handle, at its own frame only (§5.4: not without artifacts for dense
        trajectories); ``"none"`` writes nothing (the raw model, no condition hit exactly).
    Returns:
      :class:`DenseMotion` in the world frame; the overwritten positions equal their
      conditions exactly.
    Raises:
      ValueError: an unknown ``overwrite``, a negative ``guidance``, or inputs of the wrong
        shapes (naming them).
    """
    guidance = model.config.default_guidance if guidance is None else guidance
    check_guidance(guidance)
    if overwrite not in OVERWRITE_MODES:
        raise ValueError(f"overwrite must be one of {OVERWRITE_MODES}, got {overwrite!r}")
    if start.shape[-2:] != (_NUM_CHARACTERISTIC, 3) or end.shape != start.shape:
        raise ValueError(f"start and end must both be (..., {_NUM_CHARACTERISTIC}, 3), got {start.shape}, {end.shape}")
    batch = start.shape[:-2]
    if handles.position.shape[:-2] != batch:
        raise ValueError(f"handles must be batched like start {batch}, got {handles.position.shape[:-2]}")
    return _sample_dense(model, start, end, handles, key=key, steps=steps, guidance=guidance, overwrite=overwrite)


@functools.partial(inference_jit, static_argnames=("steps", "guidance", "overwrite"))
def _sample_dense(model, start, end, handles, *, key, steps, guidance, overwrite) -> DenseMotion:
    one = functools.partial(_sample_dense_one, model, steps=steps, guidance=guidance, overwrite=overwrite)
    return over_batch(one, start.shape[:-2], key, start, end, handles)


# ------------------------------------------------------------------------------- storage

_FORMAT = "bezmotion-dense-bmm-1"


def save_dense_model(directory: str | os.PathLike, model: DenseMotionModel) -> None:
    """Write a trained ablation (parameters, statistics, config) to ``directory``, atomically."""
    save_model_folder(directory, {"params": model.params, "stats": model.stats}, {"format": _FORMAT, "model": dataclasses.asdict(model.config)})


def load_dense_model(directory: str | os.PathLike) -> DenseMotionModel:
    """Read an ablation written by :func:`save_dense_model` (its config says how to rebuild it).

    Raises:
      FileNotFoundError: no saved ablation there (naming the folder).
    """
    try:
        store = CheckpointStore(directory, max_to_keep=1, read_only=True)
    except FileNotFoundError:
        raise FileNotFoundError(f"{directory}: not a saved ablation (no such folder)") from None
    saved = store.config()
    if saved is None or saved.get("format") != _FORMAT or store.latest_step() is None:
        raise FileNotFoundError(f"{directory}: not a saved ablation (config.json of format {_FORMAT} and a checkpoint expected)")
    config = DenseBMMConfig.from_dict(saved["model"])
    graphdef, params = init_dense_network(config, key=jax.random.key(0))
    shape = (config.token_joints, config.features_per_joint)
    restored = store.restore({"params": params, "stats": FeatureStats(jnp.zeros(shape), jnp.ones(shape))})
    store.close()
    return DenseMotionModel(restored["params"], restored["stats"], graphdef, config)


__all__ = [
    "ABLATIONS",
    "OVERWRITE_MODES",
    "CondMDIConfig",
    "DenseArrays",
    "DenseBMMConfig",
    "DenseMotion",
    "DenseMotionModel",
    "check_guidance",
    "check_train_config",
    "characteristic_stats",
    "dense_loss_terms",
    "dense_windows",
    "drop_conditions",
    "init_dense_network",
    "init_dense_train_state",
    "load_dense_model",
    "make_dense_train_step",
    "sample_dense",
    "save_dense_model",
]
