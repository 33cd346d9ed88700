"""The Bézier Motion Model denoiser (BMM §4.2, Figure 3, Appendix C): an MDM-style
transformer encoder over Bézier control points with one token per sparse condition.

Tokens, for one motion with ``K`` control points of ``J = 6`` joints:

- one **noise-level token**: a row of the sinusoidal table at the diffusion timestep
  ``t`` → Linear → SiLU → Linear (MDM);
- ``K`` **frame tokens** ``x_t^i = [P_j, T_j, O_j | j ∈ J_sub]`` (normalised, 12 numbers
  per joint) → one Linear encoder;
- ``S`` **condition tokens**, one per constrained (joint, frame): the target
  position (normalised like ``P``) → its own Linear, plus a learned joint-ID embedding
  (the paper's linear layer on a one-hot joint vector).

Frame and condition tokens get the sinusoidal encoding of the frame they represent
(control point ``k`` represents frame ``k · stride``; a condition between control points,
e.g. on frame 13, gets the encoding of frame 13 itself, a fractional control position);
the noise token, which represents no frame, gets none. Absent condition slots are masked out of attention as keys, so any
number of conditions, none to all ``K·J``, runs in one compiled shape. The encoder is
MDM's: post-LayerNorm layers with GELU feed-forward and dropout. The frame tokens'
outputs are decoded to x̂₀ (x₀-prediction) and two foot-contact logits per control point.

What a frame token is, is the config's: ``frame_features`` numbers per token, one token
per ``stride`` frames. :class:`BMMConfig` is the BMM's (a control point of the six
joints); :class:`~bezmotion.evaluation.ablations.DenseBMMConfig` makes a token one frame of 6 or
of all ``J`` joints (the paper's ablations BMM⁻ᴮ and BMM⁻ᴵᴷ⁻ᴮ) with this same module.

The model is written for one motion; ``jax.vmap`` it over a batch. It is a flax NNX
module used functionally: :func:`init_denoiser` returns ``(graphdef, params)`` and
:func:`apply_denoiser` merges them inside whatever ``jax.jit`` calls it.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from bezmotion.interpolation import OFF_GRID_REFERENCES
from bezmotion.handles import Handles
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.training.step import count_parameters  # noqa: F401 (its old home, re-exported)

FEATURES_PER_JOINT = 12  # position (3), tangent (3), ortho6D orientation (6)
NUM_CONTACTS = 2  # left foot, right foot
PREDICTIONS = ("x0", "residual")


@dataclasses.dataclass(frozen=True)
class BMMConfig:
    """Sizes of the denoiser (paper, Table 4: width 512, feed-forward 1024, 4 heads, 8 layers).

    Attributes:
      num_controls: control points per motion (31 frames at stride 6 → 6).
      stride: frames between control points (for the positional encoding).
      num_joints: characteristic joints (6).
      width, ff_width, num_heads, num_layers: transformer sizes.
      dropout: dropout rate in attention and feed-forward (MDM: 0.1).
      num_timesteps: diffusion steps ``T`` (for the noise-level table; 1000).
      prediction: what the decoder outputs. ``"x0"`` (the paper): x̂₀ itself.
        ``"residual"`` (ours, after the Δ-interpolator's residual over SLERP): x̂₀ minus
        the non-learned reference curves through the conditions
        (:func:`~bezmotion.bmm.features.interpolation_prior`), with the decoder
        zero-initialised so training starts from the reference.
      off_grid_prior: with ``"residual"``, how the reference curves reach conditions between
        control frames (:func:`~bezmotion.interpolation.interpolation_through_points`):
        ``"linear"`` (default) interpolates through them in frame, ``"projection"`` bends
        the curve at the condition alone. Models whose saved config has no such field
        learned their residual over ``"projection"`` and load as ``"linear"``: sampled over
        ``"linear"`` they meet any-frame handles with less error and grid handles
        identically; :func:`~bezmotion.bmm.sampling.with_off_grid_prior` switches a
        loaded model.
    """

    num_controls: int = 6
    stride: int = 6
    num_joints: int = len(CHARACTERISTIC_JOINTS)
    width: int = 512
    ff_width: int = 1024
    num_heads: int = 4
    num_layers: int = 8
    dropout: float = 0.1
    num_timesteps: int = 1000
    prediction: str = "x0"
    off_grid_prior: str = "linear"

    def __post_init__(self):
        for name in ("num_controls", "stride", "num_joints", "width", "ff_width", "num_heads", "num_layers", "num_timesteps"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"BMMConfig.{name} must be a positive integer, got {value!r}")
        if self.num_controls < 2:
            raise ValueError(f"BMMConfig.num_controls must be ≥ 2, got {self.num_controls}")
        if self.width % self.num_heads or self.width % 2:
            raise ValueError(f"BMMConfig.width ({self.width}) must be even and divisible by num_heads ({self.num_heads})")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"BMMConfig.dropout must be in [0, 1), got {self.dropout}")
        if self.prediction not in PREDICTIONS:
            raise ValueError(f"BMMConfig.prediction must be one of {PREDICTIONS}, got {self.prediction!r}")
        if self.off_grid_prior not in OFF_GRID_REFERENCES:
            raise ValueError(f"BMMConfig.off_grid_prior must be one of {OFF_GRID_REFERENCES}, got {self.off_grid_prior!r}")

    @property
    def frame_features(self) -> int:
        return self.num_joints * FEATURES_PER_JOINT

    @property
    def num_frames(self) -> int:
        return (self.num_controls - 1) * self.stride + 1

    @property
    def max_conditions(self) -> int:
        return self.num_controls * self.num_joints

    @classmethod
    def paper(cls, **overrides) -> BMMConfig:
        """The paper's size (≈17 M parameters)."""
        return cls(**overrides)

    @classmethod
    def cpu(cls, **overrides) -> BMMConfig:
        """A size that trains within one session on a 2-core CPU."""
        return cls(**{"width": 256, "ff_width": 512, "num_heads": 4, "num_layers": 4, **overrides})

    @classmethod
    def tiny(cls, **overrides) -> BMMConfig:
        """A size for smoke tests: the CPU size at width 32, one layer of two heads."""
        return cls.cpu(**{"width": 32, "ff_width": 64, "num_heads": 2, "num_layers": 1, **overrides})


def sinusoidal_encoding(
    position: Real[ArrayLike, "*shape"], width: int, max_period: float = 10000.0
) -> Float[Array, "*shape width"]:
    """Transformer sinusoidal encoding of (possibly fractional) positions, ``[sin | cos]`` halves."""
    half = width // 2
    freqs = jnp.exp(-math.log(max_period) * jnp.arange(half, dtype=jnp.float32) / half)
    angles = jnp.asarray(position, jnp.float32)[..., None] * freqs
    return jnp.concatenate([jnp.sin(angles), jnp.cos(angles)], axis=-1)


class _SelfAttention(nnx.Module):
    """Multi-head self-attention with one fused input projection (PyTorch's
    ``MultiheadAttention``: ``in_proj`` of 3·width, ``out_proj``), masked on keys."""

    def __init__(self, width: int, num_heads: int, dropout: float, *, rngs: nnx.Rngs):
        self.num_heads = num_heads
        self.in_proj = nnx.Linear(width, 3 * width, rngs=rngs)
        self.out_proj = nnx.Linear(width, width, rngs=rngs)
        self.dropout = nnx.Dropout(dropout)

    def __call__(self, x, key_valid, key, queries: slice = slice(None)):
        """Attend from the tokens ``x[queries]`` to all tokens ``x``."""
        tokens, width = x.shape
        head = width // self.num_heads
        # One (tokens × width) @ (width × 3·width) product instead of three: fewer, larger
        # matrix products, which is what bounds single-motion latency on a CPU.
        q, k, v = jnp.moveaxis(self.in_proj(x).reshape(tokens, 3, self.num_heads, head), 1, 0)
        q = q[queries]
        logits = jnp.einsum("qhd,khd->hqk", q, k) / math.sqrt(head)
        logits = jnp.where(key_valid[None, None, :], logits, jnp.finfo(logits.dtype).min)
        weights = self.dropout(jax.nn.softmax(logits, axis=-1), deterministic=key is None, rngs=key)
        return self.out_proj(jnp.einsum("hqk,khd->qhd", weights, v).reshape(q.shape[0], width))


class _EncoderLayer(nnx.Module):
    """Post-LayerNorm transformer encoder layer (PyTorch ``TransformerEncoderLayer``, as MDM)."""

    def __init__(self, config: BMMConfig, *, rngs: nnx.Rngs):
        w = config.width
        self.attention = _SelfAttention(w, config.num_heads, config.dropout, rngs=rngs)
        self.norm1 = nnx.LayerNorm(w, rngs=rngs)
        self.linear1 = nnx.Linear(w, config.ff_width, rngs=rngs)
        self.linear2 = nnx.Linear(config.ff_width, w, rngs=rngs)
        self.norm2 = nnx.LayerNorm(w, rngs=rngs)
        self.dropout = nnx.Dropout(config.dropout)

    def __call__(self, x, key_valid, key, outputs: slice = slice(None)):
        """Update all tokens, or only ``x[outputs]`` (every token still serves as a key):
        the last layer needs only the frame tokens, and computing just those is exact."""
        deterministic = key is None
        keys = [None] * 4 if deterministic else list(jax.random.split(key, 4))
        attended = self.attention(x, key_valid, keys[0], outputs)
        x = self.norm1(x[outputs] + self.dropout(attended, deterministic=deterministic, rngs=keys[1]))
        hidden = self.dropout(jax.nn.gelu(self.linear1(x)), deterministic=deterministic, rngs=keys[2])
        return self.norm2(x + self.dropout(self.linear2(hidden), deterministic=deterministic, rngs=keys[3]))


class BMMDenoiser(nnx.Module):
    """x₀-predicting denoiser over Bézier control points (one motion)."""

    def __init__(self, config: BMMConfig, *, rngs: nnx.Rngs):
        self.config = config
        w = config.width
        self.frame_encoder = nnx.Linear(config.frame_features, w, rngs=rngs)
        self.condition_encoder = nnx.Linear(3, w, rngs=rngs)
        self.joint_embedding = nnx.Embed(config.num_joints, w, rngs=rngs)
        self.time_linear1 = nnx.Linear(w, w, rngs=rngs)
        self.time_linear2 = nnx.Linear(w, w, rngs=rngs)
        self.layers = nnx.List([_EncoderLayer(config, rngs=rngs) for _ in range(config.num_layers)])
        # A residual decoder starts at zero, i.e. at the reference curves (as DiT's adaLN-zero).
        zero = {"kernel_init": nnx.initializers.zeros_init()} if config.prediction == "residual" else {}
        self.decoder = nnx.Linear(w, config.frame_features + NUM_CONTACTS, rngs=rngs, **zero)

    def __call__(
        self,
        x_t: Float[Array, "controls features"],
        t: Int[Array, ""],
        conditions: Handles,
        *,
        key: Array | None = None,
        control_frames: Real[ArrayLike, "controls"] | None = None,
        control_valid: Bool[ArrayLike, "controls"] | None = None,
    ) -> tuple[Float[Array, "controls features"], Float[Array, "controls 2"]]:
        """Predict normalised x₀ and foot-contact logits.

        Args:
          x_t: ``(controls, 6·12)`` the noisy normalised frame tokens; any number of
            control points, each at its frame of ``control_frames``.
          t: the diffusion timestep (original numbering, 0…T−1).
          conditions: condition slots with positions already normalised (see
            :class:`~bezmotion.bmm.features.FeatureStats`).
          key: dropout key; ``None`` runs deterministically (evaluation, sampling).
          control_frames: ``(controls,)`` the frame of each control point, for its positional
            encoding (a window of another length: :attr:`~bezmotion.bezier.BezierLayout.control_frames`);
            default every ``stride`` frames from 0.
          control_valid: ``(controls,)`` which control points are the window's; the others
            (padding: :class:`~bezmotion.bezier.PaddedLayout`) are masked out of attention as
            keys, so a window's outputs are those it gets unpadded. Default all.
        Returns:
          ``(x̂₀ (controls, features), contact logits (controls, 2))``; with
          ``prediction="residual"`` the first is x̂₀ minus the interpolation prior, and
          :func:`~bezmotion.bmm.features.predict_x0` adds the prior back.
        """
        cfg = self.config
        w = cfg.width
        controls = x_t.shape[0]
        if control_frames is None:
            frames = jnp.arange(controls, dtype=jnp.float32) * cfg.stride
        else:
            frames = jnp.asarray(control_frames, jnp.float32)
            if frames.shape != (controls,):
                raise ValueError(f"control_frames must be ({controls},), one per control point, got {frames.shape}")
        time_token = self.time_linear2(jax.nn.silu(self.time_linear1(sinusoidal_encoding(t, w))))
        frame_tokens = self.frame_encoder(x_t) + sinusoidal_encoding(frames, w)
        # Padding slots become zero tokens whatever they hold (NaN, out-of-range indices):
        # masked attention weights are 0, but 0 × NaN would still poison the output.
        valid_cond = conditions.valid
        joint = jnp.where(valid_cond, conditions.joint, 0)
        # The exact frame, fractional in control units (frame / stride) between control
        # points: the same sinusoid the frame tokens get, so a condition on a control frame
        # is encoded exactly as that control point's frame.
        cond_frames = jnp.where(valid_cond, conditions.frame, 0).astype(jnp.float32)
        cond_tokens = (
            self.condition_encoder(jnp.where(valid_cond[:, None], conditions.position, 0.0))
            + self.joint_embedding(joint)
            + sinusoidal_encoding(cond_frames, w)
        )
        cond_tokens = jnp.where(valid_cond[:, None], cond_tokens, 0.0)
        tokens = jnp.concatenate([time_token[None], frame_tokens, cond_tokens], axis=0)
        frames_valid = jnp.ones(controls, bool) if control_valid is None else jnp.asarray(control_valid, bool)
        valid = jnp.concatenate([jnp.ones(1, bool), frames_valid, conditions.valid])
        keys = [None] * cfg.num_layers if key is None else list(jax.random.split(key, cfg.num_layers))
        frames_only = slice(1, 1 + controls)
        for i, (layer, layer_key) in enumerate(zip(self.layers, keys)):
            tokens = layer(tokens, valid, layer_key, frames_only if i == cfg.num_layers - 1 else slice(None))
        out = self.decoder(tokens)
        return out[:, : cfg.frame_features], out[:, cfg.frame_features :]


def init_denoiser(config: BMMConfig, *, key: Array) -> tuple[nnx.GraphDef, nnx.State]:
    """Build a denoiser and split it into ``(graphdef, params)`` for functional use."""
    model = BMMDenoiser(config, rngs=nnx.Rngs(params=key))
    return nnx.split(model)


def apply_denoiser(
    graphdef: nnx.GraphDef,
    params: nnx.State,
    x_t: Float[Array, "controls features"],
    t: Int[Array, ""],
    conditions: Handles,
    *,
    key: Array | None = None,
    control_frames: Real[ArrayLike, "controls"] | None = None,
    control_valid: Bool[ArrayLike, "controls"] | None = None,
) -> tuple[Float[Array, "controls features"], Float[Array, "controls 2"]]:
    """Pure call of the denoiser on one motion (see :meth:`BMMDenoiser.__call__`)."""
    return nnx.merge(graphdef, params)(x_t, t, conditions, key=key, control_frames=control_frames, control_valid=control_valid)
