"""Training the learned frame IK: losses, effector sampling and one jitted step.

``step(state, poses) -> (state, metrics)`` is pure: it draws its frames and their
effector configurations from ``state.key``, so a run is fully determined by its seed
and resumes bit-identically from a checkpoint. It trains with :mod:`bezmotion.training`:
``TrainState`` (``ema`` is ``None``), ``apply_gradients``, ``compile_train_step``,
``stack_seeds`` and ``run_training`` (atomic orbax checkpoints, Ctrl-C / SIGTERM handling).

**Effectors.** Each example is one frame of the corpus posed on its character; the
step gives the network a subset of its *body* joints (every joint but the static ones
above the hips) at their true world positions, with or without their true global
orientations. Two groups share every batch, so that small subsets do not pay for the
padding of large ones:

- *sparse* (``batch_size − dense_batch_size`` examples, ``sparse_slots`` effector
  slots): the six characteristic joints with orientations — what the pipeline uses —
  with probability ``characteristic_probability``; the Table 2 configurations that fit
  (:func:`effector_configurations`, orientations given) with ``table2_probability``
  shared equally; otherwise both hands and feet plus a uniformly random number of
  other joints, each orientation given with probability ``rotation_probability``;
- *dense* (``dense_batch_size`` examples, one slot per body joint): all joints with
  orientations (Table 2's first row) with probability ``all_joints_probability``,
  otherwise hands and feet plus a random number of others as above.

No yaw or translation augmentation: the model is equivariant to both by construction.

**Loss** (weights in :class:`IKTrainConfig`): ``pos_weight ·`` the mean per-joint
position error over the body joints (cm, Euclidean — MPJPE itself, through
:func:`~bezmotion.ik.protocol.pose_fk`) ``+ rot_weight ·`` the mean over body joints of
the L1 distance between predicted (orthonormalised) and true 6D local rotations (which
also fixes the twist of the hands, feet and head, invisible in positions). With the
default 10, a 0.1 difference in 6D — a few degrees — weighs like a centimetre.

**Optimiser.** Adam with a linear warm-up and a cosine decay to ``final_learning_rate``
over ``num_steps``. BMM (C.4.1) trains its ProtoRes for 3600 epochs at 2e-4 halved
every 300 epochs; we have minutes of CPU, hence the larger rate and the short cosine.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jax.sharding import Mesh
from jaxtyping import Array, Bool, Float, Int

from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.geometry.rotations import rot6d_from_quat, safe_norm
from bezmotion.ik.protocol import Character, Pose, pose_fk
from bezmotion.ik.protores import (
    Effectors,
    ProtoResConfig,
    ProtoResModel,
    apply_protores,
    init_protores,
    pose_from_output,
    solve_effectors,
)
from bezmotion.training import TrainState, apply_gradients, fresh_train_state, shard_batch, stack_seeds, warmup_then_decay

#: Joints beyond the characteristic six that Table 2 uses, by role, for the bundled skeletons.
EXTRA_ROLES: Mapping[str, Mapping[str, str]] = {
    "lafan1": {
        "neck": "Neck", "left_elbow": "LeftForeArm", "right_elbow": "RightForeArm",
        "left_knee": "LeftLeg", "right_knee": "RightLeg",
    },
    "bandai_namco": {
        "neck": "Neck", "left_elbow": "LowerArm_L", "right_elbow": "LowerArm_R",
        "left_knee": "LowerLeg_L", "right_knee": "LowerLeg_R",
    },
}  # fmt: skip

_HANDS_FEET = ("left_hand", "right_hand", "left_foot", "right_foot")
ALL_JOINTS = "all joints"
CHARACTERISTIC = "hips, head, hands, feet"
#: BMM Table 2's rows (role tuples; ``None``: every body joint) and the paper's MPJPE (cm).
TABLE2: Mapping[str, tuple[tuple[str, ...] | None, float]] = {
    ALL_JOINTS: (None, 0.9943),
    "root, neck, hands, feet, elbows, knees": (
        ("hips", "neck", *_HANDS_FEET, "left_elbow", "right_elbow", "left_knee", "right_knee"), 1.1610),
    "root, neck, hands, feet": (("hips", "neck", *_HANDS_FEET), 1.2802),
    "root, hands, feet": (("hips", *_HANDS_FEET), 2.8380),
    "hands, feet": (_HANDS_FEET, 6.5878),
}  # fmt: skip


def body_joints(character: Character) -> tuple[int, ...]:
    """Every joint but the static ones above the hips (the joints a pose moves)."""
    above = set(character.ancestors_of_hips())
    return tuple(j for j in range(character.num_joints) if j not in above)


def effector_configurations(
    character: Character, extra_roles: Mapping[str, str] | None = None
) -> dict[str, tuple[int, ...]]:
    """Named effector sets of ``character`` (joint indices): Table 2's rows and the six
    characteristic joints.

    Args:
      character: the skeleton.
      extra_roles: role → joint name for ``neck``, ``left_elbow``, ``right_elbow``,
        ``left_knee``, ``right_knee`` (default: :data:`EXTRA_ROLES` for ``character.name``
        when it has an entry). Rows needing a role that is not mapped are left out.
    Raises:
      ValueError: a mapped joint name the skeleton does not have.
    """
    if extra_roles is None:
        extra_roles = EXTRA_ROLES.get(character.name, {})
    index = {role: character.characteristic[i] for i, role in enumerate(CHARACTERISTIC_JOINTS)}
    index.update({role: character.skeleton.index(name) for role, name in extra_roles.items()})
    out: dict[str, tuple[int, ...]] = {}
    for name, (roles, _) in TABLE2.items():
        if roles is None:
            out[name] = body_joints(character)
        elif all(r in index for r in roles):
            out[name] = tuple(index[r] for r in roles)
    out[CHARACTERISTIC] = tuple(character.characteristic)
    return out


@dataclasses.dataclass(frozen=True)
class IKTrainConfig:
    """Optimisation and effector-sampling settings (see the module docstring).

    Attributes:
      num_steps: the length of the learning-rate schedule (steps).
      batch_size: frames per step, both groups together.
      dense_batch_size: frames of the dense group (one effector slot per body joint).
      sparse_slots: effector slots of the sparse group (≥ the largest fixed sparse set).
      learning_rate, final_learning_rate, warmup_steps: Adam's schedule.
      pos_weight, rot_weight: loss weights of MPJPE (cm) and 6D local rotation L1.
      characteristic_probability, table2_probability: sparse-group configuration odds
        (the rest: random subsets).
      all_joints_probability: dense-group odds of all joints (the rest: random subsets).
      rotation_probability: odds that a random subset's effector has its orientation.
    """

    num_steps: int = 20000
    batch_size: int = 256
    dense_batch_size: int = 32
    sparse_slots: int = 10
    learning_rate: float = 1e-3
    final_learning_rate: float = 1e-5
    warmup_steps: int = 200
    pos_weight: float = 1.0
    rot_weight: float = 10.0
    characteristic_probability: float = 0.35
    table2_probability: float = 0.35
    all_joints_probability: float = 0.5
    rotation_probability: float = 0.5

    def __post_init__(self):
        for name in ("num_steps", "batch_size", "sparse_slots"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"IKTrainConfig.{name} must be a positive integer, got {value!r}")
        if not isinstance(self.dense_batch_size, int) or not 0 <= self.dense_batch_size < self.batch_size:
            raise ValueError(f"IKTrainConfig.dense_batch_size must be in [0, batch_size={self.batch_size}), got {self.dense_batch_size!r}")
        if not isinstance(self.warmup_steps, int) or self.warmup_steps < 0:
            raise ValueError(f"IKTrainConfig.warmup_steps must be a non-negative integer, got {self.warmup_steps!r}")
        if not (self.learning_rate > 0 and self.final_learning_rate > 0):
            raise ValueError(f"learning rates must be positive, got {self.learning_rate}, {self.final_learning_rate}")
        if self.pos_weight < 0 or self.rot_weight < 0:
            raise ValueError(f"loss weights must be non-negative, got pos_weight={self.pos_weight}, rot_weight={self.rot_weight}")
        probabilities = ("characteristic_probability", "table2_probability", "all_joints_probability", "rotation_probability")
        for name in probabilities:
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"IKTrainConfig.{name} must be in [0, 1], got {getattr(self, name)}")
        if self.characteristic_probability + self.table2_probability > 1.0:
            raise ValueError("characteristic_probability + table2_probability must not exceed 1")


def learning_rate_schedule(config: IKTrainConfig) -> optax.Schedule:
    """Linear warm-up to ``learning_rate``, then cosine decay to ``final_learning_rate`` at ``num_steps``."""
    # At least one warm-up step and one decay step, however short the run.
    warmup = min(config.warmup_steps, config.num_steps - 1)
    warmup_steps, decay_steps = max(warmup, 1), max(config.num_steps, warmup + 2)
    cosine = optax.cosine_decay_schedule(
        config.learning_rate, decay_steps - warmup_steps, alpha=config.final_learning_rate / config.learning_rate
    )
    return warmup_then_decay(
        cosine, init_value=config.learning_rate * 0.01, peak_value=config.learning_rate, warmup_steps=warmup_steps
    )


def make_optimizer(config: IKTrainConfig) -> optax.GradientTransformation:
    return optax.adam(learning_rate_schedule(config))


def init_ik_train_state(
    model_config: ProtoResConfig, train_config: IKTrainConfig, *, key: Array
) -> tuple[nnx.GraphDef, TrainState]:
    """Fresh parameters and Adam state for one seed (``ema`` is ``None``)."""
    return fresh_train_state(lambda k: init_protores(model_config, key=k), make_optimizer(train_config), key=key, ema=False)


def init_ik_train_states(
    model_config: ProtoResConfig, train_config: IKTrainConfig, seeds: Sequence[int]
) -> tuple[nnx.GraphDef, TrainState]:
    """States for several seeds, stacked on a leading axis (for the vmapped step)."""
    return stack_seeds(lambda key: init_ik_train_state(model_config, train_config, key=key), tuple(seeds))


# ------------------------------------------------------------------------------- losses


def ik_loss_terms(
    rot6d_pred: Float[Array, "*batch joints 6"],
    pos_pred: Float[Array, "*batch joints 3"],
    rot6d_true: Float[Array, "*batch joints 6"],
    pos_true: Float[Array, "*batch joints 3"],
    body: Sequence[int],
) -> dict[str, Float[Array, "*batch"]]:
    """Unweighted loss terms of predicted poses against the truth.

    Args:
      rot6d_pred, rot6d_true: 6D local rotations (the prediction orthonormalised).
      pos_pred, pos_true: global joint positions (cm).
      body: the joints that count (:func:`body_joints`).
    Returns:
      ``{"pos": MPJPE over the body joints (cm), "rot": mean over body joints of the L1
      distance of 6D local rotations}``.
    """
    idx = np.asarray(body)
    pos = jnp.mean(safe_norm(pos_pred[..., idx, :] - pos_true[..., idx, :]), axis=-1)
    rot = jnp.sum(jnp.abs(rot6d_pred[..., idx, :] - rot6d_true[..., idx, :]), axis=-1)
    return {"pos": pos, "rot": jnp.mean(rot, axis=-1)}


# ---------------------------------------------------------------------------- sampling


def _fixed_masks(configurations: Mapping[str, tuple[int, ...]], body: Sequence[int], slots: int) -> tuple[list[str], np.ndarray]:
    """Names and ``(n, body)`` masks of the fixed configurations that fit ``slots``, the
    characteristic one first."""
    position = {j: i for i, j in enumerate(body)}
    names = [CHARACTERISTIC] + [n for n in configurations if n != CHARACTERISTIC and len(configurations[n]) <= slots]
    masks = np.zeros((len(names), len(body)), bool)
    for k, name in enumerate(names):
        masks[k, [position[j] for j in configurations[name]]] = True
    return names, masks


def _random_mask(key: Array, always: Bool[Array, "body"], max_size: int) -> Bool[Array, "body"]:
    """``always`` plus a uniformly random number (0 … ``max_size − |always|``) of the other joints."""
    count_key, order_key = jax.random.split(key)
    n_always = jnp.sum(always)
    extra = jax.random.randint(count_key, (), 0, max_size - n_always + 1)
    scores = jnp.where(always, -1.0, jax.random.uniform(order_key, always.shape))
    rank = jnp.argsort(jnp.argsort(scores))
    return rank < n_always + extra


def _effectors_from_mask(
    body: Int[Array, "body"],
    mask: Bool[Array, "body"],
    rotation: Bool[Array, "body"],
    pos_global: Float[Array, "joints 3"],
    rot6d_global: Float[Array, "joints 6"],
    slots: int,
) -> Effectors:
    """The masked body joints packed into ``slots`` slots (real ones first, then padding)."""
    if slots >= body.shape[0]:
        order = jnp.arange(body.shape[0])
    else:
        order = jnp.argsort(~mask, stable=True)[:slots]
    joint = body[order]
    valid = mask[order]
    return Effectors(joint, pos_global[joint], rot6d_global[joint], rotation[order] & valid, valid)


def make_ik_train_step(
    graphdef: nnx.GraphDef,
    model_config: ProtoResConfig,
    train_config: IKTrainConfig,
    character: Character,
    configurations: Mapping[str, tuple[int, ...]] | None = None,
    *,
    mesh: Mesh | None = None,
) -> Callable[[TrainState, Pose], tuple[TrainState, dict[str, Array]]]:
    """The (un-jitted) single-seed training step; compile it with
    :func:`bezmotion.training.compile_train_step`.

    Args:
      graphdef: from :func:`init_ik_train_state`.
      model_config, train_config: the network and the optimisation settings.
      character: the skeleton the poses are of.
      configurations: fixed effector sets to train on (default
        :func:`effector_configurations`); must include :data:`CHARACTERISTIC`.
      mesh: split each batch over these devices (:func:`bezmotion.training.data_mesh`;
        several processes' when training data-parallel); ``None``: one device.
    Returns:
      ``step(state, poses) -> (state, metrics)``; ``poses`` are the training frames,
      a :class:`~bezmotion.ik.protocol.Pose` with a leading frames axis.
    """
    if model_config.num_joints != character.num_joints:
        raise ValueError(f"the network poses {model_config.num_joints} joints, the character has {character.num_joints}")
    configurations = effector_configurations(character) if configurations is None else dict(configurations)
    if CHARACTERISTIC not in configurations:
        raise ValueError(f"configurations must include {CHARACTERISTIC!r}, got {sorted(configurations)}")
    body = body_joints(character)
    position = {j: i for i, j in enumerate(body)}
    unknown = sorted({j for js in configurations.values() for j in js} - set(body))
    if unknown:
        raise ValueError(f"effector configurations use joints {unknown} that are not body joints {body}")
    slots = train_config.sparse_slots
    if slots < 4:
        raise ValueError(f"sparse_slots must hold at least both hands and feet (4), got {slots}")
    names, fixed = _fixed_masks(configurations, body, slots)
    n_fixed_table = len(names) - 1
    hands_feet = np.zeros(len(body), bool)
    hands_feet[[position[character.characteristic[CHARACTERISTIC_JOINTS.index(r)]] for r in _HANDS_FEET]] = True
    tc = train_config
    # Sparse-group configuration odds: characteristic, each other fixed set, random.
    table_each = tc.table2_probability / n_fixed_table if n_fixed_table else 0.0
    random_p = 1.0 - tc.characteristic_probability - table_each * n_fixed_table
    logits = np.log(np.maximum([tc.characteristic_probability] + [table_each] * n_fixed_table + [random_p], 1e-12))
    body_arr = np.asarray(body, np.int32)
    optimizer = make_optimizer(tc)
    schedule = learning_rate_schedule(tc)
    n_dense, n_sparse = tc.dense_batch_size, tc.batch_size - tc.dense_batch_size

    def sparse_mask(key):
        mode_key, random_key, rot_key = jax.random.split(key, 3)
        mode = jax.random.categorical(mode_key, jnp.asarray(logits, jnp.float32))
        is_random = mode == len(names)
        mask = jnp.where(is_random, _random_mask(random_key, jnp.asarray(hands_feet), slots), jnp.asarray(fixed)[jnp.minimum(mode, len(names) - 1)])
        rotation = jnp.where(is_random, jax.random.bernoulli(rot_key, tc.rotation_probability, mask.shape), True)
        return mask, rotation

    def dense_mask(key):
        mode_key, random_key, rot_key = jax.random.split(key, 3)
        everything = jax.random.bernoulli(mode_key, tc.all_joints_probability)
        mask = jnp.where(everything, True, _random_mask(random_key, jnp.asarray(hands_feet), len(body)))
        rotation = jnp.where(everything, True, jax.random.bernoulli(rot_key, tc.rotation_probability, mask.shape))
        return mask, rotation

    def example(params, truth: Pose, key, draw, n_slots):
        quat_global, pos_global = pose_fk(character, truth)
        mask, rotation = draw(key)
        effectors = _effectors_from_mask(jnp.asarray(body_arr), mask, rotation, pos_global, rot6d_from_quat(quat_global), n_slots)
        out = apply_protores(graphdef, params, character, effectors)
        _, pos_pred = pose_fk(character, pose_from_output(out))
        return ik_loss_terms(out.rot6d_local, pos_pred, rot6d_from_quat(truth.quat_local), pos_global, body)

    def group_terms(params, poses, keys, draw, n_slots):
        return jax.vmap(lambda p, k: example(params, p, k, draw, n_slots))(poses, keys)

    def loss_fn(params, sparse_poses, dense_poses, sparse_keys, dense_keys):
        terms = group_terms(params, sparse_poses, sparse_keys, sparse_mask, slots)
        if n_dense:
            dense = group_terms(params, dense_poses, dense_keys, dense_mask, len(body))
            terms = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), terms, dense)
        means = jax.tree.map(jnp.mean, terms)
        total = tc.pos_weight * means["pos"] + tc.rot_weight * means["rot"]
        return total, means

    def step(state: TrainState, poses: Pose) -> tuple[TrainState, dict[str, Array]]:
        if not isinstance(poses, Pose) or poses.quat_local.shape[-2] != character.num_joints:
            raise ValueError(f"the step trains on Pose frames of {character.num_joints} joints, got {type(poses).__name__}")
        key, index_key, example_key = jax.random.split(state.key, 3)
        index = jax.random.randint(index_key, (tc.batch_size,), 0, poses.root_pos.shape[0])
        batch = jax.tree.map(lambda a: a[index], poses)
        keys = jax.random.split(example_key, tc.batch_size)
        sparse = jax.tree.map(lambda a: shard_batch(a[:n_sparse], mesh), batch)
        dense = jax.tree.map(lambda a: shard_batch(a[n_sparse:], mesh), batch)
        args = (sparse, dense, keys[:n_sparse], keys[n_sparse:])
        new_state, metrics = apply_gradients(state, optimizer, loss_fn, *args, next_key=key)
        return new_state, {**metrics, "learning_rate": schedule(state.step)}

    return step


# -------------------------------------------------------------------------- evaluation


def _frame_errors(model: ProtoResModel, truth: Pose, joints: tuple[int, ...], rotations: bool, body: tuple[int, ...]):
    character = model.character
    quat_global, pos_global = pose_fk(character, truth)
    idx = np.asarray(joints)
    n = len(joints)
    effectors = Effectors(
        jnp.broadcast_to(jnp.asarray(idx, jnp.int32), (truth.root_pos.shape[0], n)),
        pos_global[:, idx], rot6d_from_quat(quat_global[:, idx]),
        jnp.full((truth.root_pos.shape[0], n), rotations), jnp.ones((truth.root_pos.shape[0], n), bool),
    )  # fmt: skip
    pose = jax.vmap(solve_effectors, in_axes=(None, 0))(model, effectors)
    _, pos_pred = pose_fk(character, pose)
    b = np.asarray(body)
    return jnp.mean(safe_norm(pos_pred[:, b] - pos_global[:, b]), axis=-1)


_frame_errors_jit = jax.jit(_frame_errors, static_argnames=("joints", "rotations", "body"))


def effector_mpjpe(
    model: ProtoResModel,
    poses: Pose,
    joints: Sequence[int],
    *,
    rotations: bool = True,
    chunk: int = 4096,
) -> np.ndarray:
    """Per-frame MPJPE (cm, over the body joints) of the learned IK given ``joints`` of each
    frame at their true positions (and orientations when ``rotations``).

    Args:
      model: the trained IK.
      poses: ``(frames, …)`` ground-truth poses of ``model.character``.
      joints: the effector joints.
      rotations: give the effectors' orientations too.
      chunk: frames per compiled call.
    Returns:
      ``(frames,)`` errors (float64).
    """
    joints = tuple(int(j) for j in joints)
    body = body_joints(model.character)
    bad = [j for j in joints if j not in body]
    if bad:
        raise ValueError(f"joints {bad} are not body joints of {model.character.name!r}")
    n = poses.root_pos.shape[0]
    out = []
    for lo in range(0, n, chunk):
        part = jax.tree.map(lambda a: a[lo : lo + chunk], poses)
        pad = chunk - part.root_pos.shape[0]
        if pad:  # one compiled shape for every chunk
            part = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]), part)
        out.append(np.asarray(_frame_errors_jit(model, part, joints, rotations, body), np.float64)[: chunk - pad])
    return np.concatenate(out) if out else np.zeros(0)


__all__ = [
    "ALL_JOINTS",
    "CHARACTERISTIC",
    "EXTRA_ROLES",
    "IKTrainConfig",
    "TABLE2",
    "body_joints",
    "effector_configurations",
    "effector_mpjpe",
    "ik_loss_terms",
    "init_ik_train_state",
    "init_ik_train_states",
    "learning_rate_schedule",
    "make_ik_train_step",
    "make_optimizer",
]
