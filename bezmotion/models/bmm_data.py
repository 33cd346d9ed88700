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
from jaxtyping import Array, Bool, Float

from bezmotion.data.curves import CurveDataset
from bezmotion.models.bmm import FEATURES_PER_JOINT, Conditions

MAX_INTERMEDIATE_HANDLES = 4  # BMM §5.2: zero to four uniformly sampled intermediate handles
STD_FLOOR = 1e-3  # features that never vary (e.g. a constant) must not divide by zero


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FeatureStats:
    """Per-(joint, feature) normalisation of control-point features.

    Attributes:
      mean, std: ``(joints, 12)`` over all training windows and control points, in the
        features' own units (cm for positions and tangents).
    """

    mean: Float[Array, "joints 12"]
    std: Float[Array, "joints 12"]

    @classmethod
    def from_dataset(cls, dataset: CurveDataset) -> FeatureStats:
        feats = np.asarray(control_features(dataset.ctrl_pos, dataset.ctrl_tangent, dataset.ctrl_rot6d), np.float64)
        flat = feats.reshape(-1, *feats.shape[-2:])
        return cls(
            jnp.asarray(flat.mean(axis=0), jnp.float32),
            jnp.asarray(np.maximum(flat.std(axis=0), STD_FLOOR), jnp.float32),
        )

    def normalize(self, features: Float[Array, "*batch joints 12"]) -> Float[Array, "*batch joints 12"]:
        return (features - self.mean) / self.std

    def denormalize(self, features: Float[Array, "*batch joints 12"]) -> Float[Array, "*batch joints 12"]:
        return features * self.std + self.mean

    def normalize_positions(self, pos: Float[Array, "*batch 3"], joint) -> Float[Array, "*batch 3"]:
        """Normalise positions of the given joint indices with the position statistics."""
        return (pos - self.mean[joint, :3]) / self.std[joint, :3]


def control_features(
    ctrl_pos: Float[Array, "*batch controls joints 3"],
    ctrl_tangent: Float[Array, "*batch controls joints 3"],
    ctrl_rot6d: Float[Array, "*batch controls joints 6"],
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


def sample_condition_mask(
    key: Array, num_controls: int, num_joints: int, max_intermediate: int = MAX_INTERMEDIATE_HANDLES
) -> Bool[Array, "controls joints"]:
    """The training distribution of conditions (BMM §5.2), for one motion.

    All joints at the first and last control point, plus ``n ~ U{0, …, max_intermediate}``
    distinct (joint, intermediate control point) handles chosen uniformly.
    """
    count_key, slot_key = jax.random.split(key)
    n = jax.random.randint(count_key, (), 0, max_intermediate + 1)
    inner = (num_controls - 2) * num_joints
    # The n slots with the smallest random scores: a uniform n-subset without a permutation.
    rank = jnp.argsort(jnp.argsort(jax.random.uniform(slot_key, (inner,))))
    chosen = (rank < n).reshape(num_controls - 2, num_joints)
    ends = jnp.ones((1, num_joints), bool)
    return jnp.concatenate([ends, chosen, ends], axis=0)


def normalized_conditions(
    stats: FeatureStats, mask: Bool[Array, "controls joints"], ctrl_pos: Float[Array, "controls joints 3"]
) -> Conditions:
    """Condition slots for every (control, joint), valid where ``mask``, positions normalised."""
    conditions = Conditions.from_grid(mask, ctrl_pos)
    position = stats.normalize_positions(conditions.position, conditions.joint)
    # Padding slots carry zeros, never the ground truth they would otherwise reveal.
    return conditions._replace(position=jnp.where(conditions.valid[..., None], position, 0.0))
