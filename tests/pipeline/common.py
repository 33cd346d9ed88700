"""Constants and helpers shared by the pipeline test modules (``from pipeline.common import …``):
the tiny BMM's window layout, and an IK module written here (the hips where the targets put
them, every other joint fixed), never the rig or the learned IK.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from bmm.common import TINY  # the BMM tests' tiny configuration (width 32, one layer)

from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
from bezmotion.geometry.rotations import quat_from_rot6d
from bezmotion.ik.protocol import Character, IKTargets, Pose
from bezmotion.evaluation.pipeline import full_body_handles_error
from bezmotion.pipeline import Inbetweener

FRAMES, STRIDE, K = TINY.num_frames, TINY.stride, TINY.num_controls  # 31, 6, 6
STEPS = 2  # DDIM steps: plumbing, not quality
LEFT_HAND = CHARACTERISTIC_JOINTS.index("left_hand")
handles_error = jax.jit(full_body_handles_error, static_argnums=3)


def hips_only_ik(character: Character):
    """The cheapest IK: the hips where and how the targets say, every other joint at
    ``params`` (local rotations). It records each trace in ``.traces`` (Python runs only
    while JAX traces), so tests can count compilations."""

    def ik(params: jax.Array, targets: IKTargets) -> Pose:
        ik.traces.append(1)
        hips_rot = quat_from_rot6d(targets.rot6d[HIPS])  # ancestors are identity: local == global
        return Pose(targets.position[HIPS], params.at[character.hips].set(hips_rot))

    ik.traces = []
    return ik


def identity_quats(joints: int) -> jax.Array:
    return jnp.zeros((joints, 4), jnp.float32).at[:, 0].set(1.0)


def two_keys(start: Pose, end: Pose) -> Pose:
    """A window's start and end pose as the keys ``(2, …)`` of an in-between."""
    return jax.tree.map(lambda a, b: jnp.stack([a, b]), start, end)


def model_of(bmm, ik, params, character: Character, transfer=None) -> Inbetweener:
    return Inbetweener(bmm, ik, params, character, transfer)
