"""The 1-D temporal UNet of the CondMDIᴳ baseline (BMM §5.3, Appendix C.3): CondMDI
(Cohan et al. 2024) on GMD's UNet backbone (Karunratanakul et al. 2023), over dense frames.

The network convolves over the frame axis; the channels of a frame are, concatenated
(CondMDI's imputation-style conditioning, all in the motion's own normalised layout):

- the noisy motion ``x_t``: ``token_joints · features_per_joint`` numbers;
- the condition values: the normalised target position at each conditioned
  (frame, joint)'s position entries, zero elsewhere;
- the condition mask: one at those entries, zero elsewhere.

A dropped condition set (classifier-free guidance) is all-zero values and mask. Down path:
per level two residual blocks (Conv1d → GroupNorm → Mish, twice, the timestep embedding
added between them: Diffuser's ``ResidualTemporalBlock``, which GMD's UNet is built from)
and a stride-2 convolution; two residual blocks at the coarsest level; up path: a stride-2
transposed convolution, the down path's features of that level concatenated (the skip
connection), two residual blocks; a last Conv1d block and a 1×1 convolution to x̂₀ and two
foot-contact logits per frame. The timestep embedding is the transformer's sinusoid →
Linear → Mish → Linear.

Deviations, and why: the window (31 frames) is zero-padded at its end to a multiple of
``2^(levels−1)`` and cropped back, as the strided convolutions need an even length at every
level (GMD pads its motions too); every level's skip is used (Diffuser's leaves the finest
one unused); the timestep embedding is *added* per block, not GMD's optional AdaGN
scale-and-shift; no attention in the UNet. The module is written for one motion (``vmap``
it) and used functionally like :class:`~bezmotion.bmm.denoiser.BMMDenoiser`, whose call
signature it shares: ``(x_t, t, conditions, *, key) -> (x̂₀, contact logits)``, so
:func:`~bezmotion.bmm.features.predict_x0`, the dense training step and the sampler take
either. It has no dropout; ``key`` is accepted and unused.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float, Int

# Configs are typed as BMMConfig: CondMDIConfig (bezmotion.evaluation.ablations) subclasses it and imports this module.
from bezmotion.bmm.denoiser import NUM_CONTACTS, BMMConfig, sinusoidal_encoding
from bezmotion.handles import Handles

GROUPS = 8  # GroupNorm groups (Diffuser / GMD)


class _ConvBlock(nnx.Module):
    """Conv1d → GroupNorm → Mish over ``(1, frames, channels)``."""

    def __init__(self, cin: int, cout: int, kernel: int, *, rngs: nnx.Rngs):
        self.conv = nnx.Conv(cin, cout, (kernel,), padding="SAME", rngs=rngs)
        self.norm = nnx.GroupNorm(cout, num_groups=GROUPS, rngs=rngs)

    def __call__(self, x):
        return jax.nn.mish(self.norm(self.conv(x)))


class _ResBlock(nnx.Module):
    """Two conv blocks with the timestep embedding added between them, plus a (1×1) residual."""

    def __init__(self, cin: int, cout: int, embed: int, kernel: int, *, rngs: nnx.Rngs):
        self.block1 = _ConvBlock(cin, cout, kernel, rngs=rngs)
        self.block2 = _ConvBlock(cout, cout, kernel, rngs=rngs)
        self.time = nnx.Linear(embed, cout, rngs=rngs)
        self.residual = nnx.Conv(cin, cout, (1,), rngs=rngs) if cin != cout else None

    def __call__(self, x, embedding):
        h = self.block2(self.block1(x) + self.time(jax.nn.mish(embedding)))
        return h + (x if self.residual is None else self.residual(x))


class _Level(nnx.Module):
    def __init__(self, cin: int, cout: int, embed: int, kernel: int, *, rngs: nnx.Rngs):
        self.res1 = _ResBlock(cin, cout, embed, kernel, rngs=rngs)
        self.res2 = _ResBlock(cout, cout, embed, kernel, rngs=rngs)

    def __call__(self, x, embedding):
        return self.res2(self.res1(x, embedding), embedding)


def condition_channels(
    config: BMMConfig, conditions: Handles
) -> tuple[Float[Array, "frames features"], Float[Array, "frames features"]]:
    """CondMDI's condition inputs of one motion: ``(values, mask)``, each in the motion's
    layout ``(frames, token_joints · features_per_joint)``.

    Args:
      config: the model's :class:`~bezmotion.evaluation.ablations.CondMDIConfig` (its frames, token
        joints and characteristic joints).
      conditions: normalised condition slots (joint 0…5 a characteristic joint); padding
        and dropped slots leave no trace, whatever they hold.
    """
    frames, joints = config.num_frames, config.token_joints
    valid = conditions.valid
    # Invalid slots scatter out of range and are dropped.
    frame = jnp.where(valid, conditions.frame, frames)
    joint = jnp.asarray(config.characteristic)[jnp.clip(conditions.joint, 0, len(config.characteristic) - 1)]
    position = jnp.where(valid[:, None], conditions.position, 0.0)
    shape = (frames, joints, config.features_per_joint)
    values = jnp.zeros(shape, position.dtype).at[frame, joint, :3].set(position, mode="drop")
    mask = jnp.zeros(shape, position.dtype).at[frame, joint, :3].set(1.0, mode="drop")
    return values.reshape(frames, -1), mask.reshape(frames, -1)


class CondUNet1D(nnx.Module):
    """x₀-predicting 1-D temporal UNet with condition values and mask as input channels (one motion)."""

    def __init__(self, config: BMMConfig, *, rngs: nnx.Rngs):
        self.config = config
        features, embed, kernel = config.frame_features, config.width, config.kernel_size
        channels = [config.width * m for m in config.unet_mults]
        self.time_linear1 = nnx.Linear(embed, 4 * embed, rngs=rngs)
        self.time_linear2 = nnx.Linear(4 * embed, embed, rngs=rngs)
        downs, samplers = [], []
        cin = 3 * features  # x_t ⊕ condition values ⊕ condition mask
        for i, c in enumerate(channels):
            downs.append(_Level(cin, c, embed, kernel, rngs=rngs))
            if i < len(channels) - 1:
                samplers.append(nnx.Conv(c, c, (3,), strides=(2,), padding=((1, 1),), rngs=rngs))
            cin = c
        self.downs = nnx.List(downs)
        self.downsample = nnx.List(samplers)
        self.mid = _Level(cin, cin, embed, kernel, rngs=rngs)
        ups, upsamplers = [], []
        for i in reversed(range(len(channels) - 1)):
            upsamplers.append(nnx.ConvTranspose(cin, cin, (4,), strides=(2,), padding="SAME", rngs=rngs))
            ups.append(_Level(cin + channels[i], channels[i], embed, kernel, rngs=rngs))
            cin = channels[i]
        self.ups = nnx.List(ups)
        self.upsample = nnx.List(upsamplers)
        self.final_block = _ConvBlock(cin, cin, kernel, rngs=rngs)
        self.final = nnx.Conv(cin, features + NUM_CONTACTS, (1,), rngs=rngs)

    def __call__(
        self,
        x_t: Float[Array, "frames features"],
        t: Int[Array, ""],
        conditions: Handles,
        *,
        key: Array | None = None,
    ) -> tuple[Float[Array, "frames features"], Float[Array, "frames 2"]]:
        """Predict normalised x₀ and foot-contact logits.

        Args:
          x_t: ``(frames, token_joints · features_per_joint)`` the noisy normalised frames.
          t: the diffusion timestep (0…T−1).
          conditions: condition slots with normalised positions
            (:func:`~bezmotion.bmm.features.normalize_conditions`).
          key: unused (the UNet has no dropout); accepted for the denoiser's signature.
        Returns:
          ``(x̂₀ (frames, features), contact logits (frames, 2))``.
        """
        del key
        cfg = self.config
        frames, features = cfg.num_frames, cfg.frame_features
        values, mask = condition_channels(cfg, conditions)
        x = jnp.concatenate([x_t, values.astype(x_t.dtype), mask.astype(x_t.dtype)], axis=-1)
        multiple = 2 ** (len(cfg.unet_mults) - 1)
        padded = -(-frames // multiple) * multiple
        x = jnp.pad(x, ((0, padded - frames), (0, 0)))[None]  # (1, padded, 3·features): GroupNorm's batch axis
        embedding = self.time_linear2(jax.nn.mish(self.time_linear1(sinusoidal_encoding(t, cfg.width))))
        skips = []
        for i, level in enumerate(self.downs):
            x = level(x, embedding)
            if i < len(self.downsample):
                skips.append(x)
                x = self.downsample[i](x)
        x = self.mid(x, embedding)
        for upsample, level in zip(self.upsample, self.ups):
            x = level(jnp.concatenate([upsample(x), skips.pop()], axis=-1), embedding)
        out = self.final(self.final_block(x))[0, :frames]
        return out[:, :features], out[:, features:]


def init_unet(config: BMMConfig, *, key: Array) -> tuple[nnx.GraphDef, nnx.State]:
    """Build a :class:`CondUNet1D` and split it into ``(graphdef, params)`` for functional use."""
    return nnx.split(CondUNet1D(config, rngs=nnx.Rngs(params=key)))


__all__ = ["CondUNet1D", "condition_channels", "init_unet"]
