"""Our motion feature extractor: embeddings of 31-frame six-joint windows for FID,
diversity and multimodality (:mod:`bezmotion.evaluation.naturalness`).

The BMM paper embeds motion with HumanML3D's extractor (Guo et al. 2022), which reads
22-joint SMPL motion at 20 fps; our corpora are LaFAN1 and Bandai-Namco skeletons at
30 fps, so we train our own on what every row of Table 1 produces: the six
characteristic joints (hips, head, hands, feet) over one 31-frame window.

**Input: a canonical window** (:func:`canonical_windows`), invariant to where the motion
happens, which way it faces and which character performs it:

- *root-relative*: the hips as a trajectory from their own first-frame position, every
  other joint relative to the hips of its frame;
- *heading-canonical*: rotated about +Y so the character's first-frame facing
  (:func:`~bezmotion.pipeline.transfer.facing_yaw`, from the left-right spread of hands
  and feet) is +Z — an exact yaw invariance, built in rather than learned;
- *character-agnostic*: divided by the skeleton's standing hip height (the character
  profile's ``height``, :mod:`bezmotion.assets.profiles`), so 1.0 is one hip height.

**Model: an autoencoder**, a small MLP. Its input is the canonical window's positions
``(31, 6, 3)`` and frame-to-frame velocities ``(30, 6, 3)``, each coordinate normalised
by its training mean and std, flattened and concatenated; hidden layers lead to an
``embed_dim`` bottleneck — the embedding — and back, and the loss is the mean squared
error of both parts. Why an autoencoder rather than a contrastive encoder: it needs no
labels and, above all, no choice of "views" — a contrastive encoder becomes invariant to
whatever its positive pairs differ by (noise, time shifts, small perturbations), which
would blind FID to exactly the artefacts it must see (jitter, wrong timing, a limb out
of place). Reconstruction forces the embedding to keep everything needed to redraw the
window — posture, path, speed, limb swing — so a shift of the distribution in any of
them moves its Gaussian fit. Velocities are inputs and targets of their own, normalised
by their own (small) spread, so frame-to-frame motion — jitter, stiffness, speed — is as
visible to the embedding as posture, instead of vanishing as centimetre-sized residue
of the positions. (Reconstructing velocities only through differences of the
reconstructed positions made the loss ill-conditioned: it barely moved in 300 steps.)
The invariances we do want are in the input, so the encoder spends no capacity on them.

The network is written for one window and ``vmap``-ped; it is a flax NNX module used
functionally (:func:`init_motion_autoencoder` → ``(graphdef, params)``) and trains with
:mod:`bezmotion.training` (:func:`make_motion_feature_train_step`).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jaxtyping import Array, ArrayLike, Float

from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
from bezmotion.geometry.rotations import quat_conjugate, quat_rotate
from bezmotion.pipeline.transfer import facing_yaw
from bezmotion.training import CheckpointStore, TrainState, apply_gradients, fresh_train_state, save_model_folder, warmup_then_decay

NUM_JOINTS = len(CHARACTERISTIC_JOINTS)
_FORMAT = "bezmotion-motion-features-1"
_STD_FLOOR = 1e-2  # hip heights (≈ 0.8 cm): coordinates that never move (the first-frame hips) stay 0


# --------------------------------------------------------------------------- the input


def canonical_windows(
    pos_cm: Float[Array, "*batch frames 6 3"], hip_height_cm: Float[ArrayLike, "*#batch"] | float
) -> Float[Array, "*batch frames 6 3"]:
    """Six-joint windows in the extractor's canonical frame: root-relative, first-frame
    facing along +Z, in units of the standing hip height.

    Args:
      pos_cm: ``(*batch, frames, 6, 3)`` world positions of the characteristic joints
        (cm, +Y up; any translation and heading).
      hip_height_cm: the skeleton's standing hip height (cm; the character profile's
        ``height``), a scalar or one per window.
    Returns:
      ``(*batch, frames, 6, 3)``: row ``HIPS`` the hips' displacement from their first
      frame, the other rows each joint minus the hips of its frame; all rotated by the
      inverse of the first frame's facing and divided by ``hip_height_cm``. Unchanged by
      any rotation about +Y and translation of the input.
    """
    hips = pos_cm[..., HIPS : HIPS + 1, :]  # (*batch, frames, 1, 3)
    relative = pos_cm - hips
    relative = relative.at[..., HIPS, :].set(pos_cm[..., HIPS, :] - pos_cm[..., :1, HIPS, :])
    unturn = quat_conjugate(facing_yaw(pos_cm[..., 0, :, :]))  # (*batch, 4)
    turned = quat_rotate(unturn[..., None, None, :], relative)
    return turned / jnp.asarray(hip_height_cm, pos_cm.dtype)[..., None, None, None]


class WindowStats(NamedTuple):
    """Normalisation of canonical windows and their velocities, measured on the training set.

    Attributes:
      pos_mean, pos_std: ``(frames, 6, 3)`` per-coordinate mean and (floored) std.
      vel_mean, vel_std: ``(frames − 1, 6, 3)`` the same of the frame-to-frame differences.
    """

    pos_mean: Float[Array, "frames 6 3"]
    pos_std: Float[Array, "frames 6 3"]
    vel_mean: Float[Array, "frames1 6 3"]
    vel_std: Float[Array, "frames1 6 3"]

    @classmethod
    def from_windows(cls, canonical: Float[ArrayLike, "windows frames 6 3"]) -> WindowStats:
        """Statistics of canonical windows (float64 accumulation, float32 result).

        Raises:
          ValueError: not ``(windows ≥ 2, frames ≥ 2, 6, 3)``.
        """
        x = np.asarray(canonical, np.float64)
        if x.ndim != 4 or x.shape[0] < 2 or x.shape[1] < 2 or x.shape[2:] != (NUM_JOINTS, 3):
            raise ValueError(f"canonical windows must be (windows ≥ 2, frames ≥ 2, {NUM_JOINTS}, 3), got shape {x.shape}")
        v = np.diff(x, axis=1)
        floor = lambda s: jnp.asarray(np.maximum(s, _STD_FLOOR), jnp.float32)  # noqa: E731
        as32 = lambda m: jnp.asarray(m, jnp.float32)  # noqa: E731
        return cls(as32(x.mean(0)), floor(x.std(0)), as32(v.mean(0)), floor(v.std(0)))

    def to_vector(self, canonical: Float[Array, "*batch frames 6 3"]) -> Float[Array, "*batch input"]:
        """The network's input: normalised positions and velocities, flattened and concatenated."""
        batch = canonical.shape[:-3]
        pos = (canonical - self.pos_mean) / self.pos_std
        vel = (jnp.diff(canonical, axis=-3) - self.vel_mean) / self.vel_std
        return jnp.concatenate([pos.reshape(*batch, -1), vel.reshape(*batch, -1)], axis=-1)

    def positions_from_vector(self, vector: Float[Array, "*batch input"]) -> Float[Array, "*batch frames 6 3"]:
        """The (denormalised) position part of a network vector: canonical windows."""
        frames = self.pos_mean.shape[0]
        pos = vector[..., : frames * NUM_JOINTS * 3].reshape(*vector.shape[:-1], frames, NUM_JOINTS, 3)
        return pos * self.pos_std + self.pos_mean


# --------------------------------------------------------------------------- the model


@dataclasses.dataclass(frozen=True)
class MotionFeatureConfig:
    """Sizes of the autoencoder.

    Attributes:
      num_frames: frames per window (31).
      embed_dim: size of the embedding (the bottleneck).
      width: hidden width of the encoder and the decoder.
      depth: hidden layers on each side.
    """

    num_frames: int = 31
    embed_dim: int = 64
    width: int = 512
    depth: int = 2

    def __post_init__(self):
        for name in ("num_frames", "embed_dim", "width", "depth"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"MotionFeatureConfig.{name} must be a positive integer, got {value!r}")
        if self.num_frames < 2:
            raise ValueError(f"MotionFeatureConfig.num_frames must be ≥ 2 (velocities), got {self.num_frames}")

    @property
    def input_dim(self) -> int:
        """Positions of every frame and velocities between them, 6 joints × 3 each."""
        return (2 * self.num_frames - 1) * NUM_JOINTS * 3

    @classmethod
    def cpu(cls, **overrides) -> MotionFeatureConfig:
        """The size we train and ship: width 512, two hidden layers a side, 64-d embedding (≈ 1.2 M parameters)."""
        return cls(**overrides)

    @classmethod
    def tiny(cls, **overrides) -> MotionFeatureConfig:
        """A size for smoke tests."""
        return cls(**{"embed_dim": 16, "width": 64, "depth": 1, **overrides})


class _MLP(nnx.Module):
    def __init__(self, sizes: tuple[int, ...], *, rngs: nnx.Rngs):
        self.layers = nnx.List([nnx.Linear(a, b, rngs=rngs) for a, b in zip(sizes[:-1], sizes[1:])])

    def __call__(self, x: Array) -> Array:
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = jax.nn.gelu(x)
        return x


class MotionAutoencoder(nnx.Module):
    """MLP autoencoder of one window's network vector (:meth:`WindowStats.to_vector`)."""

    def __init__(self, config: MotionFeatureConfig, *, rngs: nnx.Rngs):
        hidden = (config.width,) * config.depth
        self.encoder = _MLP((config.input_dim, *hidden, config.embed_dim), rngs=rngs)
        self.decoder = _MLP((config.embed_dim, *hidden, config.input_dim), rngs=rngs)

    def encode(self, x: Float[Array, "input"]) -> Float[Array, "embed"]:
        return self.encoder(x)

    def __call__(self, x: Float[Array, "input"]) -> Float[Array, "input"]:
        return self.decoder(self.encoder(x))


def init_motion_autoencoder(config: MotionFeatureConfig, *, key: Array) -> tuple[nnx.GraphDef, nnx.State]:
    """Build the autoencoder and split it into ``(graphdef, params)`` for functional use."""
    return nnx.split(MotionAutoencoder(config, rngs=nnx.Rngs(params=key)))


@functools.partial(
    jax.tree_util.register_dataclass, data_fields=("params", "stats"), meta_fields=("graphdef", "config")
)
@dataclasses.dataclass(frozen=True)
class MotionFeatureExtractor:
    """A trained extractor: parameters and normalisation (arrays) plus structure (static)."""

    params: nnx.State
    stats: WindowStats
    graphdef: nnx.GraphDef
    config: MotionFeatureConfig


def _flat_apply(fn, x: Float[Array, "*batch input"]) -> Array:
    """``fn`` (one vector) vmapped over all leading axes of ``x``."""
    out = jax.vmap(fn)(x.reshape(-1, x.shape[-1]))
    return out.reshape(*x.shape[:-1], *out.shape[1:])


def embed_canonical(
    extractor: MotionFeatureExtractor, canonical: Float[Array, "*batch frames 6 3"]
) -> Float[Array, "*batch embed"]:
    """Embeddings of canonical windows (:func:`canonical_windows`); traceable."""
    model = nnx.merge(extractor.graphdef, extractor.params)
    return _flat_apply(model.encode, extractor.stats.to_vector(canonical))


def reconstruct_canonical(
    extractor: MotionFeatureExtractor, canonical: Float[Array, "*batch frames 6 3"]
) -> Float[Array, "*batch frames 6 3"]:
    """Canonical windows passed through the autoencoder (encode, decode, denormalise):
    how much of a window its embedding keeps; traceable."""
    model = nnx.merge(extractor.graphdef, extractor.params)
    return extractor.stats.positions_from_vector(_flat_apply(model, extractor.stats.to_vector(canonical)))


@jax.jit
def _embed(extractor: MotionFeatureExtractor, pos_cm: Array, hip_height_cm: Array) -> Array:
    return embed_canonical(extractor, canonical_windows(pos_cm, hip_height_cm))


def motion_features(
    extractor: MotionFeatureExtractor,
    pos_cm: ArrayLike,
    hip_height_cm: float,
    *,
    chunk: int = 1024,
) -> Float[np.ndarray, "windows embed"]:
    """Embeddings of world-space six-joint windows, ready for FID, diversity and multimodality.

    Args:
      extractor: a trained extractor (:func:`load_motion_features`).
      pos_cm: ``(windows, frames, 6, 3)`` positions (cm, +Y up, any placement and
        heading), joints in :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS` order.
      hip_height_cm: the performing skeleton's standing hip height (cm).
      chunk: windows per compiled call (the last one is padded: one compilation).
    Returns:
      ``(windows, embed_dim)`` float32 embeddings.
    Raises:
      ValueError: a shape other than ``(windows, config.num_frames, 6, 3)``, a
        non-finite position (named with its index) or a non-positive hip height.
    """
    pos = np.asarray(pos_cm, np.float32)
    frames = extractor.config.num_frames
    if pos.ndim != 4 or pos.shape[1:] != (frames, NUM_JOINTS, 3):
        raise ValueError(f"pos_cm must be (windows, {frames}, {NUM_JOINTS}, 3), got shape {pos.shape}")
    if not np.isfinite(pos).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(pos))[0])
        raise ValueError(f"pos_cm holds a non-finite value ({pos[bad]}) at index {bad}")
    if not hip_height_cm > 0:  # also rejects NaN
        raise ValueError(f"hip_height_cm must be positive, got {hip_height_cm}")
    height = jnp.asarray(hip_height_cm, jnp.float32)
    out = [np.zeros((0, extractor.config.embed_dim), np.float32)]
    for lo in range(0, len(pos), chunk):
        part = pos[lo : lo + chunk]
        padded = np.concatenate([part, np.repeat(part[:1], chunk - len(part), axis=0)])
        out.append(np.asarray(_embed(extractor, jnp.asarray(padded), height))[: len(part)])
    return np.concatenate(out)


# ------------------------------------------------------------------------------ training


@dataclasses.dataclass(frozen=True)
class MotionFeatureTrainConfig:
    """Optimisation settings.

    Attributes:
      num_steps: length of the learning-rate schedule (steps).
      batch_size: windows per step.
      learning_rate, final_learning_rate, warmup_steps: Adam with a linear warm-up and a
        cosine decay to the final rate at ``num_steps``.
      velocity_weight: weight of the velocity reconstruction term.
    """

    num_steps: int = 3000
    batch_size: int = 256
    learning_rate: float = 1e-3
    final_learning_rate: float = 1e-5
    warmup_steps: int = 100
    velocity_weight: float = 1.0

    def __post_init__(self):
        for name in ("num_steps", "batch_size"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"MotionFeatureTrainConfig.{name} must be a positive integer, got {value!r}")
        if not isinstance(self.warmup_steps, int) or self.warmup_steps < 0:
            raise ValueError(f"MotionFeatureTrainConfig.warmup_steps must be a non-negative integer, got {self.warmup_steps!r}")
        if not (self.learning_rate > 0 and self.final_learning_rate > 0):
            raise ValueError(f"learning rates must be positive, got {self.learning_rate}, {self.final_learning_rate}")
        if not self.velocity_weight >= 0:
            raise ValueError(f"velocity_weight must be non-negative, got {self.velocity_weight}")

    def optimizer(self) -> optax.GradientTransformation:
        warmup = max(min(self.warmup_steps, self.num_steps - 1), 1)
        cosine = optax.cosine_decay_schedule(
            self.learning_rate, max(self.num_steps - warmup, 1), alpha=self.final_learning_rate / self.learning_rate
        )
        schedule = warmup_then_decay(cosine, init_value=0.01 * self.learning_rate, peak_value=self.learning_rate, warmup_steps=warmup)
        return optax.adam(schedule)


def reconstruction_terms(
    stats: WindowStats, recon: Float[Array, "*batch input"], canonical: Float[Array, "*batch frames 6 3"]
) -> dict[str, Float[Array, ""]]:
    """Unweighted losses of reconstructed network vectors against canonical windows.

    Returns:
      ``{"pos": mean squared error of the normalised positions, "vel": of the normalised
      velocities}`` (1 for a model that outputs the training mean).
    """
    split = stats.pos_mean.size
    error = recon - stats.to_vector(canonical)
    return {"pos": jnp.mean(error[..., :split] ** 2), "vel": jnp.mean(error[..., split:] ** 2)}


def init_motion_feature_train_state(
    model_config: MotionFeatureConfig, train_config: MotionFeatureTrainConfig, *, key: Array
) -> tuple[nnx.GraphDef, TrainState]:
    """Fresh parameters and Adam state for one seed (``ema`` is ``None``)."""
    return fresh_train_state(lambda k: init_motion_autoencoder(model_config, key=k), train_config.optimizer(), key=key, ema=False)


def make_motion_feature_train_step(graphdef: nnx.GraphDef, stats: WindowStats, train_config: MotionFeatureTrainConfig):
    """``step(state, canonical) -> (state, metrics)``: one Adam step on a random batch.

    ``canonical`` is ``(windows, frames, 6, 3)``, every training window in the canonical
    frame (:func:`canonical_windows`); the batch is drawn from ``state.key``, so a run is
    a pure function of its seed and resumes bit-identically. Metrics: ``loss``,
    ``grad_norm``, ``pos``, ``vel``.
    """
    optimizer = train_config.optimizer()

    def loss_fn(params, batch):
        recon = _flat_apply(nnx.merge(graphdef, params), stats.to_vector(batch))
        terms = reconstruction_terms(stats, recon, batch)
        return terms["pos"] + train_config.velocity_weight * terms["vel"], terms

    def step(state: TrainState, canonical: Array) -> tuple[TrainState, dict[str, Array]]:
        key, index_key = jax.random.split(state.key)
        index = jax.random.randint(index_key, (train_config.batch_size,), 0, canonical.shape[0])
        return apply_gradients(state, optimizer, loss_fn, canonical[index], next_key=key)

    return step


# ------------------------------------------------------------------------- save / load


def save_motion_features(directory: str | os.PathLike, extractor: MotionFeatureExtractor, **info) -> None:
    """Write a trained extractor (parameters and statistics; config and ``info`` as JSON) to ``directory``."""
    config = {"format": _FORMAT, "model": dataclasses.asdict(extractor.config), **info}
    save_model_folder(directory, {"params": extractor.params, "stats": extractor.stats}, config)


def load_motion_features(directory: str | os.PathLike) -> MotionFeatureExtractor:
    """Read an extractor written by :func:`save_motion_features`.

    Raises:
      FileNotFoundError: ``directory`` holds no saved extractor.
      ValueError: the saved description is not a motion feature extractor's.
    """
    try:
        store = CheckpointStore(directory, max_to_keep=1, read_only=True)
    except FileNotFoundError:
        raise FileNotFoundError(f"{directory}: not a saved motion feature extractor (no such folder)") from None
    try:
        saved = store.config()
        if saved is None or store.latest_step() is None:
            raise FileNotFoundError(f"{directory}: not a saved motion feature extractor (config.json and a checkpoint expected)")
        if saved.get("format") != _FORMAT:
            raise ValueError(f"{directory}: config.json has format {saved.get('format')!r}, expected {_FORMAT!r}")
        config = MotionFeatureConfig(**saved["model"])
        graphdef, params = init_motion_autoencoder(config, key=jax.random.key(0))
        frames = config.num_frames
        pos, vel = jnp.zeros((frames, NUM_JOINTS, 3)), jnp.zeros((frames - 1, NUM_JOINTS, 3))
        like = WindowStats(pos, pos, vel, vel)
        restored = store.restore({"params": params, "stats": like})
    finally:
        store.close()
    return MotionFeatureExtractor(restored["params"], WindowStats(*restored["stats"]), graphdef, config)


__all__ = [
    "MotionAutoencoder",
    "MotionFeatureConfig",
    "MotionFeatureExtractor",
    "MotionFeatureTrainConfig",
    "WindowStats",
    "canonical_windows",
    "embed_canonical",
    "init_motion_autoencoder",
    "init_motion_feature_train_state",
    "load_motion_features",
    "make_motion_feature_train_step",
    "motion_features",
    "reconstruct_canonical",
    "reconstruction_terms",
    "save_motion_features",
]
