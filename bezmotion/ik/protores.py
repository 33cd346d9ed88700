"""A learned frame IK in the spirit of ProtoRes (Oreshkin et al. 2022): any subset of
joints in, a full pose of one character out (BMM §4.3, Appendix A.1).

For one frame, the network reads a variable set of **effectors** — a joint of the
skeleton with its world position and, optionally, its global orientation — and returns
the hips position and the local rotation of every joint; the pose's joint positions
then follow by forward kinematics (:func:`~bezmotion.ik.protocol.pose_fk`).

Architecture (written for one frame; ``jax.vmap`` it over a batch):

1. **Canonical frame** from the inputs alone: the origin is the mean XZ of the given
   effector positions (height is kept), and the heading turns the horizontal
   left-minus-right vector of the given hands and feet onto +X. Positions and
   orientations are expressed in it, so the network never sees where the character
   stands or which way it faces; the predicted hips position and rotation are mapped
   back. The model is therefore *exactly* equivariant to horizontal translation and
   yaw, by construction. Without a given left and a given right hand or foot the
   heading is the identity (translation equivariance remains).
2. **Effector embedding**: ``[position · position_scale | 6D orientation or zeros |
   has-orientation flag | learned joint-id embedding]`` → linear → width.
3. **Two encoder stages** of pre-LayerNorm residual MLP blocks applied to every
   effector; each stage ends with a **masked mean-pool** over the valid effectors — a
   prototype that does not depend on their order, their number or the padding slots.
   The second stage reads each effector's first-stage encoding beside the first
   prototype broadcast back to it, and its prototype is added to the first
   (proto-residual).
4. **Decoder**: residual MLP blocks on the prototype → hips position and a 6D *local*
   rotation (Gram–Schmidt, :func:`~bezmotion.geometry.rotations.matrix_from_rot6d`) of
   every joint; joints above the hips are held at identity (the :class:`Pose` convention).

Two options of ours (:class:`ProtoResConfig`; both on in the shipped ``cpu`` preset, both
off in ``paper`` and the defaults, which are ProtoRes as published):

- ``output_rotations="global"``: the head outputs every joint's orientation in the
  canonical frame, converted to local rotations (``R_parentᵀ R_joint``);
- ``effector_skip=True``: the decoder also reads the given effectors scattered onto their
  joints, and its outputs are residuals over them (the given hips position, the given
  orientations), so an untrained network already reproduces its inputs.

With the same 8000 training steps they cut LaFAN1 subject-5 MPJPE from 2.97 cm to 0.08 cm
with all joints given and from 3.21 cm to 2.15 cm with the six characteristic joints
(``experiments/ik_subsets.py`` on either model).

Padding (``valid=False``) effectors may hold anything, NaN included: every read of them
goes through ``jnp.where``, never a multiplication by a mask.

Functional use, like the other models: :func:`init_protores` returns ``(graphdef,
params)``, :func:`apply_protores` merges them inside whatever ``jax.jit`` calls it. A
trained network plus its :class:`~bezmotion.ik.protocol.Character` is a
:class:`ProtoResModel`; :func:`protores_ik_fn` makes it an ``ik_fn(params, targets) ->
pose`` of the IK protocol, and :func:`save_ik_model` / :func:`load_ik_model` store it
self-describingly (config and character as JSON beside the orbax state).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from bezmotion.training.checkpoint import cast_floating, open_model_folder, save_model_folder
from bezmotion.training.step import count_parameters  # its old home, re-exported (__all__)
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.geometry.rotations import matrix_from_rot6d, quat_from_matrix, rot6d_from_matrix, safe_norm
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.protocol import Character, IKTargets, Pose
from bezmotion.ik.rig import Rig, refine_limbs

LEFT_ROLES: tuple[str, str] = ("left_hand", "left_foot")
RIGHT_ROLES: tuple[str, str] = ("right_hand", "right_foot")
FEATURES_PER_EFFECTOR = 10  # position (3), 6D orientation (6), has-orientation flag (1)
_IDENTITY_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
_FORMAT = "bezmotion.ik.protores/1"
OUTPUT_ROTATIONS: tuple[str, ...] = ("local", "global")


@dataclasses.dataclass(frozen=True)
class ProtoResConfig:
    """Sizes of the learned IK.

    Attributes:
      num_joints: joints of the character the network poses (its output size).
      encoder_width: width of the per-effector encoder.
      stage_blocks: residual blocks in each of the two encoder stages.
      decoder_width: width of the decoder acting on the prototype.
      decoder_blocks: residual blocks of the decoder.
      embedding_dim: size of the learned joint-id embedding.
      position_scale: network units per centimetre (0.01: metres), so positions and 6D
        orientations have similar ranges.
      output_rotations: what the head's 6D rotations are. ``"local"`` (ProtoRes):
        parent-from-joint rotations, posed by FK. ``"global"`` (ours): every joint's
        orientation in the canonical frame, turned into local rotations by
        ``R_local = R_parentᵀ R_joint`` — an error in one joint then no longer rotates
        everything below it, and a given orientation can be passed straight through.
      effector_skip: ``False`` (ProtoRes): the decoder sees the prototype alone. ``True``
        (ours): it also reads the given effectors scattered onto their joints, and its
        outputs are residuals over them — the hips position over the given hips, every
        rotation the network outputs as global over its given orientation — so an
        untrained network already reproduces its inputs.
    """

    num_joints: int
    encoder_width: int = 128
    stage_blocks: int = 2
    decoder_width: int = 320
    decoder_blocks: int = 2
    embedding_dim: int = 16
    position_scale: float = 0.01
    output_rotations: str = "local"
    effector_skip: bool = False

    def __post_init__(self):
        for name in ("num_joints", "encoder_width", "stage_blocks", "decoder_width", "decoder_blocks", "embedding_dim"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"ProtoResConfig.{name} must be a positive integer, got {value!r}")
        if not (isinstance(self.position_scale, float | int) and self.position_scale > 0):
            raise ValueError(f"ProtoResConfig.position_scale must be positive, got {self.position_scale!r}")
        if self.output_rotations not in OUTPUT_ROTATIONS:
            raise ValueError(f"ProtoResConfig.output_rotations must be one of {OUTPUT_ROTATIONS}, got {self.output_rotations!r}")

    @classmethod
    def paper(cls, num_joints: int, **overrides) -> ProtoResConfig:
        """A ProtoRes-scale network as published (local rotations, no effector skip;
        width 1024, 3 blocks per stage and in the decoder, ≈ 22 M parameters for 22
        joints), for a GPU. BMM (C.4.1) trains ProtoRes "without modifications" and lists
        no sizes; the widths are our reading of its scale."""
        sizes = {"encoder_width": 1024, "stage_blocks": 3, "decoder_width": 1024, "decoder_blocks": 3, "embedding_dim": 32}
        return cls(num_joints, **{**sizes, **overrides})

    @classmethod
    def cpu(cls, num_joints: int, **overrides) -> ProtoResConfig:
        """The shipped model (≈ 0.75 M parameters, ≈ 3 MB saved; trains in minutes on a
        2-core CPU): global rotations and the effector skip, which make a short training
        run far more accurate (``experiments/train_ik.py`` comparisons in the notes)."""
        return cls(num_joints, **{"output_rotations": "global", "effector_skip": True, **overrides})

    @classmethod
    def tiny(cls, num_joints: int, **overrides) -> ProtoResConfig:
        """A size for tests (≈ 40 k parameters), the shipped variant."""
        sizes = {"encoder_width": 32, "stage_blocks": 1, "decoder_width": 64, "decoder_blocks": 1, "embedding_dim": 8}
        return cls(num_joints, **{**sizes, "output_rotations": "global", "effector_skip": True, **overrides})


class Effectors(NamedTuple):
    """Constraints for one frame: which joints are where (add leading axes to batch).

    Attributes:
      joint: ``(E,)`` skeleton joint index of each effector.
      position: ``(E, 3)`` world positions (cm).
      rot6d: ``(E, 6)`` global orientations (ortho6D); read only where ``has_rotation``.
      has_rotation: ``(E,)`` whether the orientation is given.
      valid: ``(E,)`` which slots are effectors; the others are padding and may hold
        anything (NaN included).
    """

    joint: Int[Array, "*batch E"]
    position: Float[Array, "*batch E 3"]
    rot6d: Float[Array, "*batch E 6"]
    has_rotation: Bool[Array, "*batch E"]
    valid: Bool[Array, "*batch E"]

    @classmethod
    def from_names(
        cls,
        character: Character,
        names: Sequence[str],
        position: Float[Array | np.ndarray, "..."],
        rot6d: Float[Array | np.ndarray, "..."] | None = None,
    ) -> Effectors:
        """Effectors on the named joints of ``character`` (orientations given when ``rot6d`` is).

        Args:
          character: the skeleton.
          names: ``E`` joint names.
          position: ``(E, 3)`` world positions (cm).
          rot6d: ``(E, 6)`` global orientations, or ``None`` for positions only.

        Raises:
          ValueError: an unknown joint name, a joint given twice, or arrays of the wrong shape.
        """
        names = list(names)
        joints = [character.skeleton.index(n) for n in names]  # raises on unknown names
        if len(set(joints)) != len(joints):
            raise ValueError(f"each joint may be an effector once, got {names}")
        position = jnp.asarray(position, jnp.float32)
        if position.shape != (len(names), 3):
            raise ValueError(f"position must be ({len(names)}, 3) for joints {names}, got {position.shape}")
        if rot6d is None:
            rot = jnp.zeros((len(names), 6), jnp.float32)
        else:
            rot = jnp.asarray(rot6d, jnp.float32)
            if rot.shape != (len(names), 6):
                raise ValueError(f"rot6d must be ({len(names)}, 6) for joints {names}, got {rot.shape}")
        flags = jnp.full((len(names),), rot6d is not None)
        return cls(jnp.asarray(joints, jnp.int32), position, rot, flags, jnp.ones((len(names),), bool))

    @classmethod
    def from_targets(cls, character: Character, targets: IKTargets) -> Effectors:
        """The six characteristic joints with positions and orientations (the IK protocol's input)."""
        batch = targets.position.shape[:-2]
        joint = jnp.broadcast_to(jnp.asarray(character.characteristic, jnp.int32), (*batch, len(CHARACTERISTIC_JOINTS)))
        flags = jnp.ones(joint.shape, bool)
        return cls(joint, targets.position, targets.rot6d, flags, flags)


# ---------------------------------------------------------------------- canonical frame


def side_joints(character: Character) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """``(left, right)`` joint indices (hand, foot) whose horizontal difference sets the heading."""
    left = tuple(character.characteristic[CHARACTERISTIC_JOINTS.index(r)] for r in LEFT_ROLES)
    right = tuple(character.characteristic[CHARACTERISTIC_JOINTS.index(r)] for r in RIGHT_ROLES)
    return left, right


def _yaw_matrix(cos: Array, sin: Array) -> Float[Array, "3 3"]:
    """Rotation about +Y taking +X to ``(cos, 0, -sin)``."""
    zero, one = jnp.zeros_like(cos), jnp.ones_like(cos)
    return jnp.stack(
        [jnp.stack([cos, zero, sin]), jnp.stack([zero, one, zero]), jnp.stack([-sin, zero, cos])]
    )


def canonical_frame(
    effectors: Effectors, left: Sequence[int], right: Sequence[int]
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """The frame the network works in, from the valid effectors of one frame alone.

    Args:
      effectors: one frame's effectors (unbatched).
      left, right: joint indices of the left and right hand and foot.
    Returns:
      ``(origin (3,), yaw (3, 3))``: world = ``yaw @ canonical + origin``. ``origin`` is the
      mean XZ of the valid effector positions (y = 0); ``yaw`` turns +X onto the horizontal
      direction from the mean of the given right hand/foot to that of the given left ones
      (identity when a side is missing or the two coincide horizontally).
    """
    valid = effectors.valid
    dtype = effectors.position.dtype
    pos = jnp.where(valid[:, None], effectors.position, 0.0)
    count = jnp.sum(valid).astype(dtype)
    origin = jnp.sum(pos, axis=0) / jnp.maximum(count, 1.0) * jnp.asarray([1.0, 0.0, 1.0], dtype)

    def side_mean(joints):
        on = valid & jnp.isin(effectors.joint, jnp.asarray(joints, effectors.joint.dtype))
        n = jnp.sum(on)
        return jnp.sum(jnp.where(on[:, None], pos, 0.0), axis=0) / jnp.maximum(n, 1).astype(dtype), n > 0

    left_mean, has_left = side_mean(left)
    right_mean, has_right = side_mean(right)
    across = (left_mean - right_mean) * jnp.asarray([1.0, 0.0, 1.0], dtype)
    norm = safe_norm(across)
    ok = has_left & has_right & (norm > 1e-6)
    # Double where: the division only ever sees a safe norm.
    direction = jnp.where(ok, across / jnp.where(ok, norm, 1.0), jnp.asarray([1.0, 0.0, 0.0], dtype))
    return origin, _yaw_matrix(direction[0], -direction[2])


def _rotate_rot6d(rotation: Float[Array, "3 3"], rot6d: Float[Array, "*batch 6"]) -> Float[Array, "*batch 6"]:
    """``rotation @ R`` in ortho6D (both columns rotated; exact, no re-orthonormalisation)."""
    a, b = rot6d[..., :3], rot6d[..., 3:]
    return jnp.concatenate([a @ rotation.T, b @ rotation.T], axis=-1)


# ------------------------------------------------------------------------------ network


class _ResidualBlock(nnx.Module):
    """``x + W₂ ReLU(W₁ LN(x))``."""

    def __init__(self, width: int, *, rngs: nnx.Rngs):
        self.norm = nnx.LayerNorm(width, rngs=rngs)
        self.hidden = nnx.Linear(width, width, rngs=rngs)
        self.out = nnx.Linear(width, width, rngs=rngs)

    def __call__(self, x):
        return x + self.out(jax.nn.relu(self.hidden(self.norm(x))))


def _masked_mean(x: Float[Array, "E width"], valid: Bool[Array, "E"]) -> Float[Array, "width"]:
    count = jnp.sum(valid).astype(x.dtype)
    return jnp.sum(jnp.where(valid[:, None], x, 0.0), axis=0) / jnp.maximum(count, 1.0)


class ProtoRes(nnx.Module):
    """The network for one frame, in the canonical frame (see the module docstring)."""

    def __init__(self, config: ProtoResConfig, *, rngs: nnx.Rngs):
        self.config = config
        w, d = config.encoder_width, config.decoder_width
        self.joint_embedding = nnx.Embed(config.num_joints, config.embedding_dim, rngs=rngs)
        self.stage1_in = nnx.Linear(FEATURES_PER_EFFECTOR + config.embedding_dim, w, rngs=rngs)
        self.stage1 = nnx.List([_ResidualBlock(w, rngs=rngs) for _ in range(config.stage_blocks)])
        self.stage2_in = nnx.Linear(2 * w, w, rngs=rngs)
        self.stage2 = nnx.List([_ResidualBlock(w, rngs=rngs) for _ in range(config.stage_blocks)])
        given = config.num_joints * (FEATURES_PER_EFFECTOR + 1) if config.effector_skip else 0
        self.decoder_in = nnx.Linear(w + given, d, rngs=rngs)
        self.decoder = nnx.List([_ResidualBlock(d, rngs=rngs) for _ in range(config.decoder_blocks)])
        self.decoder_norm = nnx.LayerNorm(d, rngs=rngs)
        # Zero-initialised head: an untrained network outputs identity rotations.
        self.head = nnx.Linear(d, 3 + 6 * config.num_joints, kernel_init=nnx.initializers.zeros_init(), rngs=rngs)

    def prototype(
        self, features: Float[Array, "E 10"], joint: Int[Array, "E"], valid: Bool[Array, "E"]
    ) -> Float[Array, "width"]:
        """The pose prototype of one frame's canonical effector features (order- and padding-invariant)."""
        features = jnp.where(valid[:, None], features, 0.0)
        code = self.joint_embedding(jnp.where(valid, joint, 0))
        h = self.stage1_in(jnp.concatenate([features, code], axis=-1))
        for block in self.stage1:
            h = block(h)
        proto1 = _masked_mean(h, valid)
        h = self.stage2_in(jnp.concatenate([h, jnp.broadcast_to(proto1, h.shape)], axis=-1))
        for block in self.stage2:
            h = block(h)
        return proto1 + _masked_mean(h, valid)

    def __call__(
        self, features: Float[Array, "E 10"], joint: Int[Array, "E"], valid: Bool[Array, "E"], hips: int
    ) -> tuple[Float[Array, "3"], Float[Array, "joints 6"]]:
        """Canonical-frame hips position (network units) and raw 6D rotations (local or
        global per ``config.output_rotations``) of every joint; ``hips`` is the hips' index."""
        cfg = self.config
        features = jnp.where(valid[:, None], features, 0.0)
        z = self.prototype(features, joint, valid)
        identity = jnp.broadcast_to(jnp.asarray(_IDENTITY_6D, features.dtype), (cfg.num_joints, 6))
        base_root, base6d = jnp.zeros(3, features.dtype), identity
        if cfg.effector_skip:
            # The given effectors scattered onto their joints (zeros where none is given):
            # the decoder reads them directly, and outputs are residuals over them.
            on = valid[:, None] & (joint[:, None] == jnp.arange(cfg.num_joints)[None, :])  # (E, joints)
            given = jnp.einsum("ej,ef->jf", on.astype(features.dtype), features)  # (joints, 10)
            given_mask = jnp.any(on, axis=0)
            z = jnp.concatenate([z, given.reshape(-1), given_mask.astype(features.dtype)])
            base_root = given[hips, :3]
            has_rotation = given[:, 9] > 0.5
            if cfg.output_rotations == "local":  # only the hips' local rotation is a global one
                has_rotation = has_rotation & (jnp.arange(cfg.num_joints) == hips)
            base6d = jnp.where(has_rotation[:, None], given[:, 3:9], identity)
        z = self.decoder_in(z)
        for block in self.decoder:
            z = block(z)
        out = self.head(jax.nn.relu(self.decoder_norm(z)))
        return base_root + out[:3], base6d + out[3:].reshape(cfg.num_joints, 6)


class ProtoResOutput(NamedTuple):
    """What the learned IK predicts for one frame, in the world frame.

    Attributes:
      root_pos: ``(3,)`` hips position (cm).
      rot6d_local: ``(joints, 6)`` orthonormalised 6D local rotations (hips: global;
        joints above the hips: identity).
    """

    root_pos: Float[Array, "*batch 3"]
    rot6d_local: Float[Array, "*batch joints 6"]


def init_protores(config: ProtoResConfig, *, key: Array) -> tuple[nnx.GraphDef, nnx.State]:
    """Build the network and split it into ``(graphdef, params)`` for functional use."""
    return nnx.split(ProtoRes(config, rngs=nnx.Rngs(params=key)))


def _check_effectors(config: ProtoResConfig, character: Character, effectors: Effectors) -> None:
    """Shape checks before tracing (one frame)."""
    if character.num_joints != config.num_joints:
        raise ValueError(f"the network poses {config.num_joints} joints, the character {character.name!r} has {character.num_joints}")
    e = effectors.joint.shape
    expected = {"joint": e, "position": (*e, 3), "rot6d": (*e, 6), "has_rotation": e, "valid": e}
    got = {name: tuple(getattr(effectors, name).shape) for name in expected}
    if len(e) != 1 or got != expected:
        raise ValueError(f"Effectors of one frame must be joint (E,), position (E, 3), rot6d (E, 6), has_rotation (E,), valid (E,); got {got}")


def apply_protores(
    graphdef: nnx.GraphDef, params: nnx.State, character: Character, effectors: Effectors
) -> ProtoResOutput:
    """The learned IK on one frame: effectors in, hips position and local rotations out.

    Args:
      graphdef, params: from :func:`init_protores` (or training).
      character: the skeleton the network was trained for (sets the heading's hands and
        feet and the joints above the hips).
      effectors: one frame's effectors (unbatched; ``jax.vmap`` over frames).
    Returns:
      :class:`ProtoResOutput` in the world frame.
    """
    model = nnx.merge(graphdef, params)
    cfg = model.config
    _check_effectors(cfg, character, effectors)
    origin, yaw = canonical_frame(effectors, *side_joints(character))
    dtype = effectors.position.dtype
    valid = effectors.valid
    position = (jnp.where(valid[:, None], effectors.position, 0.0) - origin) @ yaw  # yawᵀ (p − o), row vectors
    has_rotation = valid & effectors.has_rotation
    rot6d = jnp.where(has_rotation[:, None], _rotate_rot6d(yaw.T, jnp.where(has_rotation[:, None], effectors.rot6d, 0.0)), 0.0)
    features = jnp.concatenate([position * cfg.position_scale, rot6d, has_rotation[:, None].astype(dtype)], axis=-1)
    root, raw6d = model(features, effectors.joint, valid, character.hips)
    matrix = matrix_from_rot6d(raw6d)
    hips = character.hips
    above = list(character.ancestors_of_hips())
    if cfg.output_rotations == "global":
        world = yaw @ matrix  # every joint's orientation, world frame
        if above:
            world = world.at[np.asarray(above)].set(jnp.eye(3, dtype=dtype))
        parents = np.asarray(character.skeleton.parents)
        parent_world = jnp.where((parents >= 0)[:, None, None], world[np.maximum(parents, 0)], jnp.eye(3, dtype=dtype))
        matrix = jnp.swapaxes(parent_world, -1, -2) @ world
    else:
        matrix = matrix.at[hips].set(yaw @ matrix[hips])
    if above:
        matrix = matrix.at[np.asarray(above)].set(jnp.eye(3, dtype=dtype))
    root_pos = yaw @ (root / cfg.position_scale) + origin
    return ProtoResOutput(root_pos, rot6d_from_matrix(matrix))


def pose_from_output(output: ProtoResOutput) -> Pose:
    """The :class:`~bezmotion.ik.protocol.Pose` of a prediction (quaternions, w ≥ 0)."""
    return Pose(output.root_pos, quat_from_matrix(matrix_from_rot6d(output.rot6d_local)))


# ------------------------------------------------------------------------ trained model


@functools.partial(
    jax.tree_util.register_dataclass, data_fields=("params", "character"), meta_fields=("graphdef", "config")
)
@dataclasses.dataclass(frozen=True)
class ProtoResModel:
    """A trained learned IK: parameters and character (pytree leaves) plus structure (static).

    Pass it as the ``params`` of :func:`protores_ik_fn`.
    """

    params: nnx.State
    character: Character
    graphdef: nnx.GraphDef
    config: ProtoResConfig

    def __post_init__(self):
        if self.config.num_joints != self.character.num_joints:
            raise ValueError(
                f"the network poses {self.config.num_joints} joints, the character {self.character.name!r} has "
                f"{self.character.num_joints}"
            )


def solve_effectors(model: ProtoResModel, effectors: Effectors) -> Pose:
    """The pose for one frame's effectors (any subset of joints; ``vmap`` over frames)."""
    return pose_from_output(apply_protores(model.graphdef, model.params, model.character, effectors))


def protores_ik_fn(model: ProtoResModel, targets: IKTargets) -> Pose:
    """``ik_fn(params, targets) -> pose`` of the IK protocol (:class:`~bezmotion.ik.protocol.IKFn`):
    the six characteristic joints with positions and orientations, one frame.

    Raises:
      ValueError: ``targets`` are not ``(6, 3)`` positions and ``(6, 6)`` orientations.
    """
    n = len(CHARACTERISTIC_JOINTS)
    if targets.position.shape != (n, 3) or targets.rot6d.shape != (n, 6):
        raise ValueError(
            f"protores_ik_fn takes one frame of IKTargets, position ({n}, 3) and rot6d ({n}, 6); got "
            f"{targets.position.shape} and {targets.rot6d.shape} (vmap over frames)"
        )
    return solve_effectors(model, Effectors.from_targets(model.character, targets))


def protores_refined_ik_fn(params: tuple[ProtoResModel, Rig], targets: IKTargets) -> Pose:
    """The learned IK, then the rig's exact two-bone arms and legs (ours; :func:`~bezmotion.ik.rig.refine_limbs`).

    ``params`` is ``(model, rig)`` for the same character. The learned pose keeps its
    hips, spine, head and the sides its elbows and knees bend to; hands and feet land on
    their targets exactly when reachable, which a frame-based network alone does not do.
    """
    model, rig = params
    return refine_limbs(rig, protores_ik_fn(model, targets), targets)


# ---------------------------------------------------------------------------- save/load


def character_to_json(character: Character) -> dict[str, Any]:
    """A JSON-able description of a character (everything :func:`character_from_json` needs)."""
    skeleton = character.skeleton
    return {
        "name": character.name,
        "parents": list(skeleton.parents),
        "names": list(skeleton.names),
        "offsets": np.asarray(skeleton.offsets, np.float64).tolist(),
        "characteristic": list(character.characteristic),
        "end_sites": [[int(p), [float(v) for v in o]] for p, o in character.end_sites],
    }


def character_from_json(data: dict[str, Any]) -> Character:
    """Inverse of :func:`character_to_json` (float32 offsets)."""
    try:
        skeleton = Skeleton(tuple(data["parents"]), tuple(data["names"]), np.asarray(data["offsets"], np.float32))
        end_sites = tuple((int(p), tuple(float(v) for v in o)) for p, o in data.get("end_sites", []))
        return Character(skeleton, tuple(data["characteristic"]), str(data["name"]), end_sites)
    except KeyError as e:
        raise ValueError(f"a saved character needs {e.args[0]!r}; got keys {sorted(data)}") from None


def save_ik_model(directory: str | os.PathLike, model: ProtoResModel, *, storage_dtype: str = "float32") -> None:
    """Write a trained learned IK (parameters; config and character as JSON; the checksums
    of their files) to ``directory``, atomically.

    ``storage_dtype="float16"`` halves the file (to bring a large model back from a GPU
    machine, or to bundle one); :func:`load_ik_model` casts the parameters back to float32.
    """
    config = {
        "format": _FORMAT, "model": dataclasses.asdict(model.config), "character": character_to_json(model.character),
        "storage_dtype": storage_dtype,
    }  # fmt: skip
    save_model_folder(directory, {"params": cast_floating(model.params, storage_dtype)}, config)


def load_ik_model(directory: str | os.PathLike, *, verify: bool = True) -> ProtoResModel:
    """Read a learned IK written by :func:`save_ik_model` (its JSON says how to rebuild it).

    Args:
      directory: the saved model's folder.
      verify: check its files against the checksums :func:`save_ik_model` wrote first.
        ``False`` (it warns) loads a folder without them, saved before models carried them.

    Raises:
      FileNotFoundError: ``directory`` holds no saved model.
      ChecksumError: its files differ from their checksums (naming them), or it has none.
      ValueError: the saved description is not a learned IK's, or its parameters hold
        NaN or inf (naming them).
    """
    store = open_model_folder(directory, "learned IK", verify=verify)
    try:
        saved = store.config()
        if saved.get("format") != _FORMAT:
            raise ValueError(f"{directory}: config.json has format {saved.get('format')!r}, expected {_FORMAT!r}")
        config = ProtoResConfig(**saved["model"])
        character = character_from_json(saved["character"])
        graphdef, params = init_protores(config, key=jax.random.key(0))
        like = {"params": cast_floating(params, saved.get("storage_dtype", "float32"))}
        restored = store.restore(like, step=store.latest_step(), verify=False)  # the folder's checksums cover it
    finally:
        store.close()
    return ProtoResModel(cast_floating(restored["params"], "float32"), character, graphdef, config)


__all__ = [
    "Effectors",
    "ProtoRes",
    "ProtoResConfig",
    "ProtoResModel",
    "ProtoResOutput",
    "apply_protores",
    "canonical_frame",
    "character_from_json",
    "character_to_json",
    "count_parameters",
    "init_protores",
    "load_ik_model",
    "pose_from_output",
    "protores_ik_fn",
    "save_ik_model",
    "side_joints",
    "solve_effectors",
]
