"""The Δ-interpolator (Oreshkin et al. 2023): a transformer that in-betweens as a residual
over a non-learned interpolator, with inputs relative to the last past frame.

Tokens, for one example with ``K`` key-frame slots and ``M`` missing-frame slots:

- a **key-frame token** per known frame: per joint its global position and 6D rotation
  (root: global; other joints: local), minus the reference ``X_ref`` — the root position
  and root 6D rotation of the last past frame — when ``input_delta="last"``
  (9 numbers per joint: 198 for LaFAN1's 22 joints);
- a **missing-frame token** per frame to predict: no content (zeros).

Each token is concatenated with two learned 32-d embeddings, of its frame index in the
window and of the number of missing frames, and linearly projected to the model width.
``R`` residual blocks follow; block ``ℓ`` updates the key-frame stream by self-attention
and then the missing-frame stream by cross-attention to the key-frame stream it just
produced, **with the same weights** (attention, LayerNorm and MLP):

    e_ℓᴷ = MLP_ℓ(ReLU(LN_ℓ(MHA_ℓ(e_{ℓ-1}ᴷ, e_{ℓ-1}ᴷ, e_{ℓ-1}ᴷ) + e_{ℓ-1}ᴷ)))
    e_ℓᴹ = MLP_ℓ(ReLU(LN_ℓ(MHA_ℓ(e_{ℓ-1}ᴹ, e_ℓᴷ, e_ℓᴷ) + e_{ℓ-1}ᴹ)))

Missing frames never attend to each other, so the padding slots of a fixed-size layout
cannot change the real ones. Linear heads decode every token to a ``J × 6`` rotation
(root global, others local) and a root position, *added* to a baseline per
``output_delta``: the interpolator (lerp root, slerp local rotations between the key
frames around each missing frame; known frames are their own baseline), the last past
frame, or nothing. 6D → quaternion; FK with the predicted root gives positions.

With both Δ-modes on, a constant translation of the input cancels in the features and
reappears through the baseline's root: the output moves with the input (the paper's
robustness claim, §4.2). The model is written for one example; ``jax.vmap`` it over a
batch. It is a flax NNX module used functionally: :func:`init_delta` returns
``(graphdef, params)``, :func:`apply_delta` merges them inside whatever ``jax.jit``
calls it, and :func:`delta_inbetweener` wraps trained parameters as an in-betweener for
:func:`bezmotion.evaluation.lafan1.evaluate_transitions`.

**Any skeleton.** The skeleton's topology is part of the model: ``DeltaConfig.parents``
(saved with the config) fixes the joints, the heads' sizes and the FK; the offsets come
with the data (each training window's, or the :class:`~bezmotion.geometry.Skeleton`
given to :func:`delta_inbetweener`, which must have the same parents). The non-learned
bases the residuals are added to live in :mod:`bezmotion.interpolation`.

**Positions only** (``representation="positions"``, for corpora without rotations such as
Anidance, the paper's §5): a key-frame token holds the ``P × 3`` global
point positions, minus the root (point 0) of the last past frame when
``input_delta="last"``; one linear head decodes ``P × 3`` positions added to the same
kinds of baseline (lerp between the key frames around each missing frame, the last past
frame, or nothing). Same blocks, embeddings and weight sharing; no FK. Call it with
:meth:`DeltaInterpolator.positions` / :func:`apply_delta_positions`, and evaluate it
with :func:`delta_position_inbetweener`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from bezmotion.interpolation import KeyFrames, KeyPositions, keyframe_interpolation, keyframe_position_interpolation
from bezmotion.geometry.rotations import quat_fix_continuity, quat_from_rot6d, rot6d_from_quat
from bezmotion.geometry.skeleton import Skeleton, forward_kinematics

REPRESENTATIONS: tuple[str, ...] = ("rotations", "positions")
INPUT_DELTAS: tuple[str, ...] = ("last", "none")
OUTPUT_DELTAS: tuple[str, ...] = ("interpolation", "last", "none")
#: The paper's Table 3 rows as ``(input_delta, output_delta)``; the first is the Δ-interpolator.
TABLE3_MODES: tuple[tuple[str, str], ...] = (
    ("last", "interpolation"),
    ("last", "last"),
    ("none", "none"),
    ("none", "interpolation"),
    ("none", "last"),
)
FEATURES_PER_JOINT = 9  # global position (3), 6D rotation (6)
FEATURES_PER_POINT = 3  # positions representation: global position only


@dataclasses.dataclass(frozen=True)
class DeltaConfig:
    """Sizes and Δ-modes of the Δ-interpolator (paper Table 5: width 1024, 6 blocks,
    8 heads, 3-layer block MLPs, 32-d embeddings, dropout 0.2).

    Attributes:
      parents: the skeleton's parent indices, root first (``Skeleton.parents``; LaFAN1:
        ``bezmotion.data.lafan1.PARENTS``), for the rotations representation: it fixes
        the joints and the FK. Saved with the config (read back with :meth:`from_dict`).
        ``None`` for the positions representation, which has no skeleton.
      n_past: past context frames; key slot ``n_past - 1`` is the last past frame, the
        reference of both Δ-modes (LaFAN1 benchmark: 10).
      width, num_blocks, num_heads: transformer sizes.
      mlp_layers: linear layers of each block's residual MLP.
      embedding_dim: size of each of the two learned embeddings.
      dropout: dropout rate after the hidden layers of the block MLPs.
      max_frames: rows of both embedding tables: frame indices and gap lengths must be
        below it (65: the benchmark's test windows).
      input_delta: ``"last"`` (features relative to the last past frame's root) or
        ``"none"`` (absolute features).
      output_delta: ``"interpolation"`` (residual over lerp/slerp), ``"last"`` (over the
        last past frame) or ``"none"`` (absolute rotations and root position).
      position_scale: network units per centimetre for positions, in the features and
        the root head (0.01: metres), so positions and 6D rotations have similar ranges.
      representation: ``"rotations"`` (6D rotations + root position, FK; LaFAN1) or
        ``"positions"`` (global point positions only; Anidance).
      num_points: points per frame of the positions representation, the root first
        (Anidance: 24); ``None`` for rotations, whose joints ``parents`` defines.
    """

    parents: tuple[int, ...] | None = None
    n_past: int = 10
    width: int = 1024
    num_blocks: int = 6
    num_heads: int = 8
    mlp_layers: int = 3
    embedding_dim: int = 32
    dropout: float = 0.2
    max_frames: int = 65
    input_delta: str = "last"
    output_delta: str = "interpolation"
    position_scale: float = 0.01
    representation: str = "rotations"
    num_points: int | None = None

    def __post_init__(self):
        if self.representation not in REPRESENTATIONS:
            raise ValueError(f"DeltaConfig.representation must be one of {REPRESENTATIONS}, got {self.representation!r}")
        for name in ("n_past", "width", "num_blocks", "num_heads", "mlp_layers", "embedding_dim", "max_frames"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"DeltaConfig.{name} must be a positive integer, got {value!r}")
        if self.width % self.num_heads:
            raise ValueError(f"DeltaConfig.width ({self.width}) must be divisible by num_heads ({self.num_heads})")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"DeltaConfig.dropout must be in [0, 1), got {self.dropout}")
        if self.max_frames < self.n_past + 2:
            raise ValueError(
                f"DeltaConfig.max_frames ({self.max_frames}) must leave room for {self.n_past} past frames, "
                "one missing frame and the target"
            )
        if self.input_delta not in INPUT_DELTAS:
            raise ValueError(f"DeltaConfig.input_delta must be one of {INPUT_DELTAS}, got {self.input_delta!r}")
        if self.output_delta not in OUTPUT_DELTAS:
            raise ValueError(f"DeltaConfig.output_delta must be one of {OUTPUT_DELTAS}, got {self.output_delta!r}")
        if not (isinstance(self.position_scale, float | int) and self.position_scale > 0):
            raise ValueError(f"DeltaConfig.position_scale must be positive, got {self.position_scale!r}")
        if self.representation == "positions":
            n = self.num_points
            if not isinstance(n, int) or isinstance(n, bool) or n < 1:
                raise ValueError(f"DeltaConfig.num_points must be a positive integer for the positions representation, got {n!r}")
        elif self.num_points is not None:
            raise ValueError(
                f"DeltaConfig.num_points={self.num_points!r} is only for the positions representation; "
                "with rotations the skeleton (parents) fixes the joints"
            )
        parents = self.parents
        if self.representation == "positions":
            if parents is not None:
                raise ValueError(
                    f"DeltaConfig.parents={parents!r} is only for the rotations representation; "
                    "positions have no skeleton (num_points fixes the points)"
                )
        elif parents is None:
            raise ValueError(
                "DeltaConfig.parents is required for the rotations representation: pass the skeleton's "
                "parent indices (e.g. DeltaConfig.cpu(parents=skeleton.parents))"
            )
        elif (
            not isinstance(parents, tuple) or not parents or parents[0] != -1
            or any(not isinstance(p, int) or not 0 <= p < j for j, p in enumerate(parents) if j > 0)
        ):  # fmt: skip
            raise ValueError(f"DeltaConfig.parents must be a tuple starting with -1 whose parents precede their children, got {parents!r}")

    @property
    def num_joints(self) -> int:
        """Joints (rotations) or points (positions) per frame."""
        return self.num_points if self.representation == "positions" else len(self.parents)

    @property
    def frame_features(self) -> int:
        per_joint = FEATURES_PER_POINT if self.representation == "positions" else FEATURES_PER_JOINT
        return self.num_joints * per_joint

    @property
    def output_features(self) -> int:
        """Head outputs per token: ``J·6`` rotation + 3 root, or ``P·3`` positions."""
        return self.num_joints * 3 if self.representation == "positions" else self.num_joints * 6 + 3

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> DeltaConfig:
        """The config from ``dataclasses.asdict(config)`` as a checkpoint's ``config.json``
        holds it (JSON has made ``parents`` a list)."""
        parents = values.get("parents")
        return cls(**{**values, "parents": None if parents is None else tuple(parents)})

    @classmethod
    def paper(cls, **overrides) -> DeltaConfig:
        """The paper's size (44.5 M parameters on LaFAN1's skeleton; ≈ 44.9 M are quoted
        for the original code)."""
        return cls(**overrides)

    @classmethod
    def cpu(cls, **overrides) -> DeltaConfig:
        """A size that trains in minutes on a 2-core CPU (0.4 M parameters)."""
        return cls(**{"width": 128, "num_blocks": 3, "num_heads": 4, **overrides})

    @classmethod
    def tiny(cls, **overrides) -> DeltaConfig:
        """A size for smoke tests: the CPU size at width 32, one block of two heads, 8-d embeddings."""
        return cls.cpu(**{"width": 32, "num_blocks": 1, "num_heads": 2, "embedding_dim": 8, **overrides})


class DeltaPositionsOutput(NamedTuple):
    """Predicted global positions (cm) of the key frames (their reconstruction) and of the
    missing frames. Entries of padding key slots mean nothing."""

    key_pos: Float[Array, "*batch keys points 3"]
    missing_pos: Float[Array, "*batch missing points 3"]


class DeltaOutput(NamedTuple):
    """Predicted local rotations (unit quaternions, ``w ≥ 0``) and root positions (cm) of
    the key frames (their reconstruction) and of the missing frames. Entries of padding
    key slots mean nothing."""

    key_quat: Float[Array, "*batch keys joints 4"]
    key_root: Float[Array, "*batch keys 3"]
    missing_quat: Float[Array, "*batch missing joints 4"]
    missing_root: Float[Array, "*batch missing 3"]


# ---------------------------------------------------------------------------- network


class _Attention(nnx.Module):
    """Multi-head attention from query tokens to context tokens, masked on the context."""

    def __init__(self, width: int, num_heads: int, *, rngs: nnx.Rngs):
        self.num_heads = num_heads
        self.query = nnx.Linear(width, width, rngs=rngs)
        self.key = nnx.Linear(width, width, rngs=rngs)
        self.value = nnx.Linear(width, width, rngs=rngs)
        self.out = nnx.Linear(width, width, rngs=rngs)

    def __call__(self, queries, context, context_valid):
        width = queries.shape[-1]
        head = width // self.num_heads
        q = self.query(queries).reshape(queries.shape[0], self.num_heads, head)
        k = self.key(context).reshape(context.shape[0], self.num_heads, head)
        v = self.value(context).reshape(context.shape[0], self.num_heads, head)
        logits = jnp.einsum("qhd,khd->hqk", q, k) / math.sqrt(head)
        logits = jnp.where(context_valid[None, None, :], logits, jnp.finfo(logits.dtype).min)
        weights = jax.nn.softmax(logits, axis=-1)
        return self.out(jnp.einsum("hqk,khd->qhd", weights, v).reshape(queries.shape[0], width))


class _Block(nnx.Module):
    """One residual block: attention → residual + LayerNorm → ReLU → residual MLP. The
    same block serves the key-frame (self-attention) and missing-frame (cross-attention)
    streams."""

    def __init__(self, config: DeltaConfig, *, rngs: nnx.Rngs):
        w = config.width
        self.attention = _Attention(w, config.num_heads, rngs=rngs)
        self.norm = nnx.LayerNorm(w, rngs=rngs)
        self.mlp = nnx.List([nnx.Linear(w, w, rngs=rngs) for _ in range(config.mlp_layers)])
        self.dropout = nnx.Dropout(config.dropout)

    def __call__(self, tokens, context, context_valid, key):
        h = jax.nn.relu(self.norm(self.attention(tokens, context, context_valid) + tokens))
        x = h
        keys = [None] * len(self.mlp) if key is None else list(jax.random.split(key, len(self.mlp)))
        for i, layer in enumerate(self.mlp):
            x = layer(x)
            if i < len(self.mlp) - 1:
                x = self.dropout(jax.nn.relu(x), deterministic=key is None, rngs=keys[i])
        return h + x


class DeltaInterpolator(nnx.Module):
    """The Δ-interpolator for one example (see the module docstring)."""

    def __init__(self, config: DeltaConfig, *, rngs: nnx.Rngs):
        self.config = config
        e, w, j = config.embedding_dim, config.width, config.num_joints
        self.frame_embedding = nnx.Embed(config.max_frames, e, rngs=rngs)
        self.gap_embedding = nnx.Embed(config.max_frames, e, rngs=rngs)
        self.input = nnx.Linear(config.frame_features + 2 * e, w, rngs=rngs)
        self.blocks = nnx.List([_Block(config, rngs=rngs) for _ in range(config.num_blocks)])
        # Residual heads start at zero, i.e. at the baseline itself (an untrained model is
        # the interpolator, or zero velocity). Absolute heads keep the default init: a
        # zero 6D vector is no rotation.
        zero = {"kernel_init": nnx.initializers.zeros_init()} if config.output_delta != "none" else {}
        if config.representation == "positions":
            self.position_head = nnx.Linear(w, j * 3, rngs=rngs, **zero)
        else:
            self.rotation_head = nnx.Linear(w, j * 6, rngs=rngs, **zero)
            self.root_head = nnx.Linear(w, 3, rngs=rngs, **zero)

    def _decode(self, tokens):
        if self.config.representation == "positions":
            return self.position_head(tokens)
        return jnp.concatenate([self.rotation_head(tokens), self.root_head(tokens)], axis=-1)

    def network(
        self,
        key_features: Float[Array, "keys features"],
        key_frame: Int[Array, "keys"],
        key_valid: Bool[Array, "keys"],
        missing_frame: Int[Array, "missing"],
        gap: Int[Array, ""],
        *,
        key: Array | None = None,
    ) -> tuple[Float[Array, "keys out"], Float[Array, "missing out"]]:
        """The transformer alone: raw head outputs per token, ``[J·6 rotation | 3 root]``
        (rotations) or ``P·3`` positions (positions representation).

        Args:
          key_features: ``(keys, J·9)`` per-joint ``[position · position_scale | 6D]``, or
            ``(keys, P·3)`` positions · position_scale.
          key_frame, missing_frame: frame indices in the window (``< max_frames``).
          key_valid: which key slots are real; padding slots are neither attended to nor
            read (their content may be anything, NaN included).
          gap: number of missing frames (``< max_frames``).
          key: dropout key; ``None`` runs deterministically.
        """
        gap_code = jnp.broadcast_to(self.gap_embedding(gap), (1, self.config.embedding_dim))

        def embed(content, frame):
            codes = [content, self.frame_embedding(frame), jnp.repeat(gap_code, frame.shape[0], axis=0)]
            return self.input(jnp.concatenate(codes, axis=-1))

        # Padding keys become zero tokens whatever they hold: masked attention weights are
        # 0, but 0 × NaN would still poison the output.
        key_features = jnp.where(key_valid[:, None], key_features, 0.0)
        key_tokens = jnp.where(key_valid[:, None], embed(key_features, jnp.where(key_valid, key_frame, 0)), 0.0)
        missing_tokens = embed(jnp.zeros((missing_frame.shape[0], key_features.shape[1]), key_features.dtype), missing_frame)
        n = 2 * len(self.blocks)  # one dropout key per block and stream
        stream_keys = [None] * n if key is None else list(jax.random.split(key, n))
        for i, block in enumerate(self.blocks):
            key_tokens = block(key_tokens, key_tokens, key_valid, stream_keys[2 * i])
            # Cross-attention to the key-frame stream this block just produced, same weights.
            missing_tokens = block(missing_tokens, key_tokens, key_valid, stream_keys[2 * i + 1])
        return self._decode(key_tokens), self._decode(missing_tokens)

    def __call__(
        self,
        offsets: Float[Array, "joints 3"],
        keys: KeyFrames,
        missing_frame: Int[Array, "missing"],
        gap: Int[Array, ""],
        *,
        key: Array | None = None,
    ) -> DeltaOutput:
        """In-between one example: Δ-features in, baseline + residual out.

        Args:
          offsets: ``(J, 3)`` skeleton offsets (cm), for the key frames' global positions.
          keys: the known frames; slot ``n_past - 1`` is the reference (last past frame).
          missing_frame: ``(missing,)`` frame indices to predict.
          gap: the number of missing frames (the gap-length embedding's index).
          key: dropout key; ``None`` runs deterministically (evaluation).
        Returns:
          :class:`DeltaOutput` for the key slots and the missing slots.
        """
        cfg = self.config
        if cfg.representation != "rotations":
            raise ValueError(f"this model has the {cfg.representation!r} representation: call .positions(...) instead")
        j = cfg.num_joints
        if offsets.shape[-2:] != (j, 3) or keys.quat_local.shape[-2:] != (j, 4):
            raise ValueError(
                f"offsets of shape {offsets.shape} and key rotations of shape {keys.quat_local.shape} do not fit the "
                f"model's {j}-joint skeleton (DeltaConfig.parents), which needs ({j}, 3) and (keys, {j}, 4)"
            )
        ref = cfg.n_past - 1
        dtype = keys.root_pos.dtype
        rot6d = rot6d_from_quat(keys.quat_local)
        _, pos = forward_kinematics(cfg.parents, keys.quat_local, offsets.astype(dtype), root_pos=keys.root_pos)
        if cfg.input_delta == "last":
            # X − X_ref with X_ref broadcast over joints: the root's 6D is subtracted from
            # every joint's (the reference code's features), the root position from every
            # joint's global position.
            rot6d = rot6d - rot6d[ref, 0]
            pos = pos - keys.root_pos[ref]
        features = jnp.concatenate([pos * cfg.position_scale, rot6d], axis=-1).reshape(rot6d.shape[0], -1)
        key_out, missing_out = self.network(features, keys.frame, keys.valid, missing_frame, gap, key=key)

        base6d, base_root = _baselines(cfg, keys, missing_frame)
        # Key and missing frames in one pass (one 6D → quaternion conversion to compile).
        out = jnp.concatenate([key_out, missing_out], axis=0)
        quat = quat_from_rot6d(base6d + out[:, : cfg.num_joints * 6].reshape(base6d.shape))
        root = base_root + out[:, cfg.num_joints * 6 :] / cfg.position_scale
        n_keys = key_out.shape[0]
        return DeltaOutput(quat[:n_keys], root[:n_keys], quat[n_keys:], root[n_keys:])

    def positions(
        self,
        keys: KeyPositions,
        missing_frame: Int[Array, "missing"],
        gap: Int[Array, ""],
        *,
        key: Array | None = None,
    ) -> DeltaPositionsOutput:
        """In-between one example of the positions representation.

        Args:
          keys: the known frames; slot ``n_past - 1`` is the reference (last past frame).
          missing_frame: ``(missing,)`` frame indices to predict.
          gap: the number of missing frames (the gap-length embedding's index).
          key: dropout key; ``None`` runs deterministically (evaluation).
        Returns:
          :class:`DeltaPositionsOutput`: global positions (cm) of the key and missing slots.
        """
        cfg = self.config
        if cfg.representation != "positions":
            raise ValueError(f"this model has the {cfg.representation!r} representation: call it with offsets and KeyFrames")
        if keys.pos.shape[-2:] != (cfg.num_joints, 3):
            raise ValueError(f"keys.pos has shape {keys.pos.shape}, expected (keys, {cfg.num_joints}, 3)")
        pos = keys.pos
        if cfg.input_delta == "last":
            # Relative to the reference frame's root: a constant translation of the input
            # cancels here and comes back through the baseline.
            pos = pos - keys.pos[cfg.n_past - 1, 0]
        features = (pos * cfg.position_scale).reshape(pos.shape[0], -1)
        key_out, missing_out = self.network(features, keys.frame, keys.valid, missing_frame, gap, key=key)
        out = jnp.concatenate([key_out, missing_out], axis=0).reshape(-1, cfg.num_joints, 3)
        pos = _position_baselines(cfg, keys, missing_frame) + out / cfg.position_scale
        n_keys = key_out.shape[0]
        return DeltaPositionsOutput(pos[:n_keys], pos[n_keys:])


def _baselines(config: DeltaConfig, keys: KeyFrames, missing_frame):
    """``(6D (keys + missing, J, 6), root (keys + missing, 3))``, key slots first: what the
    heads' outputs are added to (:func:`bezmotion.interpolation.keyframe_interpolation`, the
    last past frame, or zeros; known frames are their own interpolation baseline)."""
    n_keys, n_missing, j = keys.frame.shape[0], missing_frame.shape[0], config.num_joints
    dtype = keys.root_pos.dtype
    if config.output_delta == "interpolation":
        quat, root = keyframe_interpolation(keys, missing_frame)
        quat = jnp.concatenate([keys.quat_local, quat], axis=0)
        return rot6d_from_quat(quat), jnp.concatenate([keys.root_pos, root], axis=0)
    if config.output_delta == "last":
        ref = config.n_past - 1
        n = n_keys + n_missing
        return jnp.broadcast_to(rot6d_from_quat(keys.quat_local[ref]), (n, j, 6)), jnp.broadcast_to(keys.root_pos[ref], (n, 3))
    return jnp.zeros((n_keys + n_missing, j, 6), dtype), jnp.zeros((n_keys + n_missing, 3), dtype)


def _position_baselines(config: DeltaConfig, keys: KeyPositions, missing_frame):
    """``(keys + missing, P, 3)`` positions, key slots first: what the position head's
    output is added to (known frames are their own interpolation baseline)."""
    n = keys.frame.shape[0] + missing_frame.shape[0]
    if config.output_delta == "interpolation":
        return jnp.concatenate([keys.pos, keyframe_position_interpolation(keys, missing_frame)], axis=0)
    if config.output_delta == "last":
        return jnp.broadcast_to(keys.pos[config.n_past - 1], (n, *keys.pos.shape[1:]))
    return jnp.zeros((n, *keys.pos.shape[1:]), keys.pos.dtype)


# ------------------------------------------------------------------------ functional API


def init_delta(config: DeltaConfig, *, key: Array) -> tuple[nnx.GraphDef, nnx.State]:
    """Build a Δ-interpolator and split it into ``(graphdef, params)`` for functional use."""
    return nnx.split(DeltaInterpolator(config, rngs=nnx.Rngs(params=key)))


def apply_delta(
    graphdef: nnx.GraphDef,
    params: nnx.State,
    offsets: Float[Array, "joints 3"],
    keys: KeyFrames,
    missing_frame: Int[Array, "missing"],
    gap: Int[Array, ""],
    *,
    key: Array | None = None,
) -> DeltaOutput:
    """Pure call of the model on one example (see :meth:`DeltaInterpolator.__call__`)."""
    return nnx.merge(graphdef, params)(offsets, keys, missing_frame, gap, key=key)


def apply_delta_positions(
    graphdef: nnx.GraphDef,
    params: nnx.State,
    keys: KeyPositions,
    missing_frame: Int[Array, "missing"],
    gap: Int[Array, ""],
    *,
    key: Array | None = None,
) -> DeltaPositionsOutput:
    """Pure call of a positions-representation model on one example (see
    :meth:`DeltaInterpolator.positions`)."""
    return nnx.merge(graphdef, params).positions(keys, missing_frame, gap, key=key)


def transition_layout(n_past: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(key_frame, missing_frame)`` of the benchmark layout: past frames ``0 … n_past-1``,
    the target at ``n_past + n``, the ``n`` transition frames in between (int32)."""
    keys = np.append(np.arange(n_past), n_past + n).astype(np.int32)
    return keys, np.arange(n_past, n_past + n, dtype=np.int32)


def delta_inbetweener(
    graphdef: nnx.GraphDef,
    params: nnx.State,
    skeleton: Skeleton,
    *,
    batch_size: int | None = None,
) -> Callable[..., tuple[Array, Array]]:
    """The trained model as an in-betweener of motion on ``skeleton``, for example for
    :func:`bezmotion.evaluation.lafan1.evaluate_transitions`.

    ``inbetween(past_quat (B, n_past, J, 4), past_root (B, n_past, 3), target_quat (B, J, 4),
    target_root (B, 3), n) -> (quat (B, n, J, 4), root (B, n, 3))`` with ``n`` a Python int.
    Inputs are cast to the parameters' dtype. The output quaternions are made
    sign-continuous over time starting from the last past frame, as the LaFAN1 reader
    makes the data (the official L2Q compares signs).

    Args:
      graphdef, params: from :func:`init_delta` (or training).
      skeleton: the motion's skeleton: its parents must be the model's
        (``DeltaConfig.parents``) and its ``(J, 3)`` offsets (cm) place the key frames'
        joints for their features (the LaFAN1 benchmark: one constant skeleton).
      batch_size: examples per vectorised chunk (``jax.lax.map``), bounding memory; ``None``
        runs the whole batch at once.
    """
    if batch_size is not None and (not isinstance(batch_size, int) or batch_size < 1):
        raise ValueError(f"batch_size must be a positive integer or None, got {batch_size!r}")
    _check_skeleton(nnx.merge(graphdef, params).config, skeleton)
    dtype = jax.tree.leaves(params)[0].dtype

    def inbetween(past_quat, past_root, target_quat, target_root, n):
        model = nnx.merge(graphdef, params)
        cfg = model.config
        if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            raise ValueError(f"the transition length must be a positive Python int, got {n!r}")
        if cfg.n_past + n + 1 > cfg.max_frames:
            raise ValueError(
                f"a transition of {n} frames after {cfg.n_past} past frames needs frame index {cfg.n_past + n}, "
                f"beyond the model's max_frames={cfg.max_frames}"
            )
        if past_quat.shape[-3:] != (cfg.n_past, cfg.num_joints, 4):
            raise ValueError(f"past_quat has shape {past_quat.shape}, expected (batch, {cfg.n_past}, {cfg.num_joints}, 4)")
        key_frame, missing_frame = (jnp.asarray(a) for a in transition_layout(cfg.n_past, n))
        valid = jnp.ones(key_frame.shape, bool)
        gap = jnp.asarray(n, jnp.int32)
        offs = jnp.asarray(skeleton.offsets, dtype)
        key_quat = jnp.concatenate([past_quat, target_quat[:, None]], axis=1).astype(dtype)
        key_root = jnp.concatenate([past_root, target_root[:, None]], axis=1).astype(dtype)

        def one(example):
            out = model(offs, KeyFrames(example[0], example[1], key_frame, valid), missing_frame, gap)
            return out.missing_quat, out.missing_root

        if batch_size is None:
            quat, root = jax.vmap(one)((key_quat, key_root))
        else:
            quat, root = jax.lax.map(one, (key_quat, key_root), batch_size=batch_size)
        quat = quat_fix_continuity(jnp.concatenate([key_quat[:, cfg.n_past - 1 : cfg.n_past], quat], axis=1), axis=1)
        return quat[:, 1:], root

    return inbetween


def delta_position_inbetweener(
    graphdef: nnx.GraphDef, params: nnx.State, *, batch_size: int | None = None
) -> Callable[..., Array]:
    """A trained positions-representation model as an in-betweener for
    :func:`bezmotion.evaluation.anidance.evaluate_anidance`.

    ``inbetween(key_pos (B, K, P, 3), key_frame, missing_frame) -> (B, M, P, 3)`` with
    ``key_frame`` (``K``) and ``missing_frame`` (``M``) tuples of Python ints: the frames
    of the window that are known (the first ``n_past`` are the past context) and those to
    predict. Inputs are cast to the parameters' dtype.

    Args:
      graphdef, params: from :func:`init_delta` (or training) with ``representation="positions"``.
      batch_size: examples per vectorised chunk (``jax.lax.map``), bounding memory; ``None``
        runs the whole batch at once.
    """
    if batch_size is not None and (not isinstance(batch_size, int) or batch_size < 1):
        raise ValueError(f"batch_size must be a positive integer or None, got {batch_size!r}")
    dtype = jax.tree.leaves(params)[0].dtype

    def inbetween(key_pos, key_frame, missing_frame):
        model = nnx.merge(graphdef, params)
        cfg = model.config
        if cfg.representation != "positions":
            raise ValueError(f"delta_position_inbetweener needs a positions model, got representation={cfg.representation!r}")
        _check_frames(cfg, key_frame, missing_frame)
        if key_pos.shape[-3:] != (len(key_frame), cfg.num_joints, 3):
            raise ValueError(f"key_pos has shape {key_pos.shape}, expected (batch, {len(key_frame)}, {cfg.num_joints}, 3)")
        frames = jnp.asarray(key_frame, jnp.int32)
        valid = jnp.ones(frames.shape, bool)
        missing = jnp.asarray(missing_frame, jnp.int32)
        gap = jnp.asarray(len(missing_frame), jnp.int32)

        def one(pos):
            return model.positions(KeyPositions(pos, frames, valid), missing, gap).missing_pos

        pos = key_pos.astype(dtype)
        return jax.vmap(one)(pos) if batch_size is None else jax.lax.map(one, pos, batch_size=batch_size)

    return inbetween


def _check_skeleton(config: DeltaConfig, skeleton: Skeleton) -> None:
    """A rotations model in-betweens motion of the skeleton it was built for, one offsets set."""
    if config.representation != "rotations":
        raise ValueError(f"delta_inbetweener needs a rotations model, got representation={config.representation!r}")
    if skeleton.parents != config.parents:
        raise ValueError(
            f"the skeleton's parents {skeleton.parents} differ from the model's DeltaConfig.parents {config.parents}: "
            "a Δ-interpolator in-betweens the skeleton it was trained on"
        )
    if tuple(skeleton.offsets.shape) != (skeleton.num_joints, 3):
        raise ValueError(f"the skeleton's offsets have shape {tuple(skeleton.offsets.shape)}, expected ({skeleton.num_joints}, 3)")


def _check_frames(config: DeltaConfig, key_frame, missing_frame) -> None:
    """Validate a static key / missing frame layout before tracing."""
    ints = all(isinstance(f, int | np.integer) and not isinstance(f, bool) for f in (*key_frame, *missing_frame))
    if not ints or not missing_frame:
        raise ValueError(f"key_frame and missing_frame must be non-empty tuples of ints, got {key_frame!r} and {missing_frame!r}")
    if len(key_frame) < config.n_past + 1 or any(b <= a for a, b in zip(key_frame, key_frame[1:])):
        raise ValueError(f"key_frame must hold {config.n_past} past frame(s) and a target, strictly increasing, got {key_frame!r}")
    if set(key_frame) & set(missing_frame):
        raise ValueError(f"frames {sorted(set(key_frame) & set(missing_frame))} are both key and missing frames")
    frames = (*key_frame, *missing_frame)
    if min(frames) < 0 or max(frames) >= config.max_frames or len(missing_frame) >= config.max_frames:
        raise ValueError(
            f"frame indices must lie in [0, {config.max_frames}) and fewer than {config.max_frames} frames be missing "
            f"(the model's max_frames), got frames {min(frames)}…{max(frames)} with {len(missing_frame)} missing"
        )


__all__ = [
    "INPUT_DELTAS",
    "OUTPUT_DELTAS",
    "REPRESENTATIONS",
    "TABLE3_MODES",
    "DeltaConfig",
    "DeltaInterpolator",
    "DeltaOutput",
    "DeltaPositionsOutput",
    "KeyFrames",
    "KeyPositions",
    "apply_delta",
    "apply_delta_positions",
    "delta_inbetweener",
    "delta_position_inbetweener",
    "init_delta",
    "transition_layout",
]
