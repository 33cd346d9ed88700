"""The learned frame IK (ProtoRes-style): contracts of the network, the protocol adapter,
training, checkpoints and bad input.

Real data: the bundled Bandai-Namco clip (:data:`bezmotion.assets.DEMO_CLIP`, 40 frames,
a skeleton with a static ``joint_Root`` above the hips). Compiling dominates the time, so
one jitted batched solve serves the network tests and one compiled training step (both
effector groups) serves the loss and resume tests.
"""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from helpers import assert_trees_identical, leaves, np_axis_matrix, np_matrix_from_quat

from bezmotion.assets import DEMO_CLIP
from bezmotion.training.checkpoint import CheckpointStore
from bezmotion.data.bvh import read_bvh
from bezmotion.geometry.rotations import rot6d_from_quat
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.data.bvh_folder import load_bvh_folder
from bezmotion.data.sources import load_corpus
from bezmotion.ik.frames import corpus_frames
from bezmotion.ik.protocol import Character, IKTargets, Pose, pose_fk, pose_from_motion, targets_from_pose
from bezmotion.ik.protores import (
    Effectors,
    ProtoResConfig,
    ProtoResModel,
    apply_protores,
    canonical_frame,
    count_parameters,
    init_protores,
    load_ik_model,
    protores_ik_fn,
    save_ik_model,
    side_joints,
    solve_effectors,
)
from bezmotion.ik.training import (
    ALL_JOINTS,
    CHARACTERISTIC,
    IKTrainConfig,
    body_joints,
    effector_configurations,
    effector_mpjpe,
    init_ik_train_state,
    make_ik_train_step,
)
from bezmotion.training import compile_train_step, run_training

SIX = ("Hips", "Head", "Hand_L", "Hand_R", "Foot_L", "Foot_R")
_solve = jax.jit(jax.vmap(solve_effectors, in_axes=(None, 0)))
_ik = jax.jit(jax.vmap(protores_ik_fn, in_axes=(None, 0)))
_fk = jax.jit(pose_fk)
_targets = jax.jit(targets_from_pose)


def np_matrix_from_rot6d(r6: np.ndarray) -> np.ndarray:
    """Gram–Schmidt of the two 6D columns, in NumPy."""
    a, b = np.asarray(r6[..., :3], float), np.asarray(r6[..., 3:], float)
    c1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b - np.sum(c1 * b, axis=-1, keepdims=True) * c1
    c2 = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.stack([c1, c2, np.cross(c1, c2)], axis=-1)


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def clip() -> SimpleNamespace:
    """The demo clip as a character (float32 skeleton) and its 40 poses with global joints."""
    motion = read_bvh(DEMO_CLIP)
    skeleton = Skeleton(motion.skeleton.parents, motion.skeleton.names, np.asarray(motion.skeleton.offsets, np.float32))
    character = dataclasses.replace(Character.from_bvh(motion, "bandai_namco"), skeleton=skeleton)
    poses = jax.jit(pose_from_motion)(character, jnp.asarray(motion.quat_local, jnp.float32), jnp.asarray(motion.pos_local, jnp.float32))
    quat_global, pos_global = _fk(character, poses)
    return SimpleNamespace(character=character, poses=poses, pos=pos_global, rot6d=jax.jit(rot6d_from_quat)(quat_global))


def random_head_model(character: Character, config: ProtoResConfig, seed: int) -> ProtoResModel:
    """An untrained network whose zero-initialised head is replaced by random weights
    (a zero head would output its baseline for every input and hide most bugs)."""
    graphdef, params = init_protores(config, key=jax.random.key(seed))
    rng = np.random.default_rng(seed)

    def randomise(path, x):
        if str(getattr(path[0], "key", "")) == "head":
            return jnp.asarray(rng.normal(scale=0.05, size=x.shape), x.dtype)
        return x

    return ProtoResModel(jax.tree_util.tree_map_with_path(randomise, params), character, graphdef, config)


@pytest.fixture(scope="module")
def model(clip) -> ProtoResModel:
    """The shipped variant (global rotations, effector skip), tiny, with a random head."""
    return random_head_model(clip.character, ProtoResConfig.tiny(clip.character.num_joints), 3)


@pytest.fixture(scope="module")
def protores_model(clip) -> ProtoResModel:
    """ProtoRes as published (local rotations, prototype only), tiny, with a random head."""
    config = ProtoResConfig.tiny(clip.character.num_joints, output_rotations="local", effector_skip=False)
    return random_head_model(clip.character, config, 4)


def frame_effectors(clip, frame: int, names, rotations) -> Effectors:
    """Effectors of one clip frame on the named joints (orientation flags per joint)."""
    idx = np.asarray(clip.character.skeleton.indices(names))
    return Effectors(
        jnp.asarray(idx, jnp.int32), clip.pos[frame, idx], clip.rot6d[frame, idx],
        jnp.asarray(rotations, bool), jnp.ones(len(idx), bool),
    )  # fmt: skip


def stack(*effectors: Effectors) -> Effectors:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *effectors)


def yaw_translate(effectors: Effectors, angle: float, shift: np.ndarray) -> Effectors:
    """Rotate the effectors about +Y by ``angle`` and move them by ``shift`` (world frame)."""
    r = jnp.asarray(np_axis_matrix("y", angle), jnp.float32)
    rot = jnp.concatenate([effectors.rot6d[..., :3] @ r.T, effectors.rot6d[..., 3:] @ r.T], axis=-1)
    return effectors._replace(position=effectors.position @ r.T + jnp.asarray(shift, jnp.float32), rot6d=rot)


# ------------------------------------------------------------------------------ network


def test_shapes_units_and_the_joints_above_the_hips(clip, model):
    names = SIX + ("LowerArm_L", "LowerLeg_R")
    e = stack(frame_effectors(clip, 0, names, [True] * 8), frame_effectors(clip, 5, names, [False] * 8))
    pose = _solve(model, e)
    j = clip.character.num_joints
    assert pose.root_pos.shape == (2, 3) and pose.quat_local.shape == (2, j, 4)
    np.testing.assert_allclose(np.linalg.norm(pose.quat_local, axis=-1), 1.0, atol=1e-5)
    assert clip.character.ancestors_of_hips() == (0,)  # joint_Root
    np.testing.assert_allclose(pose.quat_local[:, 0], [[1.0, 0.0, 0.0, 0.0]] * 2, atol=1e-6)
    # Pose convention: root_pos is the hips' global position.
    _, pos = _fk(clip.character, pose)
    np.testing.assert_allclose(pos[:, clip.character.hips], pose.root_pos, atol=1e-4)
    assert 20_000 < count_parameters(model.params) < 60_000
    shipped = jax.eval_shape(lambda key: init_protores(ProtoResConfig.cpu(22), key=key)[1], jax.random.key(0))
    assert count_parameters(shipped) < 1_500_000


def test_the_prototype_ignores_order_and_padding_and_nan_never_leaks(clip, model):
    net = nnx.merge(model.graphdef, model.params)
    prototype = jax.jit(lambda f, j, v: net.prototype(f, j, v))
    rng = np.random.default_rng(1)
    features = jnp.asarray(rng.normal(size=(6, 10)), jnp.float32)
    joint = jnp.asarray(clip.character.skeleton.indices(SIX), jnp.int32)
    valid = jnp.ones(6, bool)
    proto = prototype(features, joint, valid)
    perm = rng.permutation(6)
    np.testing.assert_allclose(prototype(features[perm], joint[perm], valid[perm]), proto, rtol=1e-5, atol=1e-5)
    # Padding slots holding NaN and out-of-range joint ids change nothing.
    padded = jnp.concatenate([features, jnp.full((3, 10), jnp.nan)])
    pad_joint = jnp.concatenate([joint, jnp.asarray([999, -5, 7], jnp.int32)])
    pad_valid = jnp.concatenate([valid, jnp.zeros(3, bool)])
    np.testing.assert_allclose(prototype(padded, pad_joint, pad_valid), proto, rtol=1e-5, atol=1e-5)

    # Through the whole model (canonical frame included), batched, and for the gradient.
    e = frame_effectors(clip, 3, SIX, [True, False, True, True, False, True])
    nan_pad = Effectors(
        jnp.asarray([1, 2], jnp.int32), jnp.full((2, 3), jnp.nan), jnp.full((2, 6), jnp.nan),
        jnp.ones(2, bool), jnp.zeros(2, bool),
    )  # fmt: skip
    with_pad = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), e, nan_pad)
    order = np.asarray([7, 2, 0, 6, 5, 1, 4, 3])
    shuffled = jax.tree.map(lambda a: a[order], with_pad)
    pose, pose_pad = _solve(model, stack(e, e)), _solve(model, stack(with_pad, shuffled))
    for a, b in zip(jax.tree.leaves(pose_pad), jax.tree.leaves(pose)):
        assert np.isfinite(a).all()
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4)

    def loss(params, effectors):
        out = apply_protores(model.graphdef, params, model.character, effectors)
        return jnp.sum(out.root_pos) + jnp.sum(out.rot6d_local)

    grads = jax.jit(jax.grad(loss))(model.params, with_pad)
    assert all(np.isfinite(g).all() for g in leaves(grads))


@pytest.mark.parametrize("variant", ["model", "protores_model"])
def test_yaw_and_horizontal_translation_equivariance(clip, variant, request):
    model = request.getfixturevalue(variant)
    cases = [
        frame_effectors(clip, 10, SIX, [True] * 6),
        # hands and feet only, two orientations, two padding slots
        frame_effectors(clip, 20, SIX, [True, True, False, True, True, False])._replace(valid=jnp.asarray([False, False, True, True, True, True])),
    ]
    angle, shift = 2.3, np.asarray([150.0, 0.0, -420.0])
    moved = [yaw_translate(e, angle, shift) for e in cases]
    pose = _solve(model, stack(*cases, *moved))
    quat_global, pos = jax.tree.map(np.asarray, _fk(clip.character, pose))
    pose = jax.tree.map(np.asarray, pose)
    r = np_axis_matrix("y", angle)
    hips = clip.character.hips
    for i in range(2):
        j = i + 2
        np.testing.assert_allclose(pose.root_pos[j], r @ np.asarray(pose.root_pos[i]) + shift, atol=2e-3)
        body = np.asarray(body_joints(clip.character))  # joint_Root stays at the origin
        np.testing.assert_allclose(pos[j, body], np.asarray(pos[i, body]) @ r.T + shift, atol=2e-3)
        np.testing.assert_allclose(np_matrix_from_quat(pose.quat_local[j, hips]), r @ np.asarray(np_matrix_from_quat(pose.quat_local[i, hips])), atol=1e-4)
        others = [k for k in range(clip.character.num_joints) if k != hips]
        np.testing.assert_allclose(np_matrix_from_quat(pose.quat_local[j, others]), np_matrix_from_quat(pose.quat_local[i, others]), atol=1e-4)
        np.testing.assert_allclose(np_matrix_from_quat(quat_global[j, body]), r @ np.asarray(np_matrix_from_quat(quat_global[i, body])), atol=1e-4)


def test_an_untrained_skip_model_reproduces_its_effectors(clip):
    """Zero head + effector skip: the given hips position and every given orientation come
    straight back, through the canonical frame and FK, for any yaw and place."""
    config = ProtoResConfig.tiny(clip.character.num_joints)
    graphdef, params = init_protores(config, key=jax.random.key(5))
    fresh = ProtoResModel(params, clip.character, graphdef, config)
    e = yaw_translate(frame_effectors(clip, 12, SIX, [True, True, True, False, True, True]), -1.1, np.asarray([40.0, 0.0, 75.0]))
    quat_global, pos = _fk(clip.character, _solve(fresh, stack(e)))
    np.testing.assert_allclose(pos[0, clip.character.hips], e.position[0], atol=1e-3)
    given = [0, 1, 2, 4, 5]  # Hand_R comes without its orientation
    idx = np.asarray(e.joint)[given]
    np.testing.assert_allclose(np_matrix_from_quat(quat_global[0, idx]), np_matrix_from_rot6d(e.rot6d[np.asarray(given)]), atol=1e-5)


def test_canonical_frame_heading_and_its_fallback(clip):
    left, right = side_joints(clip.character)
    e = frame_effectors(clip, 0, SIX, [True] * 6)
    origin, yaw = canonical_frame(e, left, right)
    assert origin[1] == 0.0
    p = np.asarray(e.position)
    across = (p[[2, 4]].mean(0) - p[[3, 5]].mean(0)) * [1, 0, 1]
    np.testing.assert_allclose(np.asarray(yaw)[:, 0], across / np.linalg.norm(across), atol=1e-5)
    np.testing.assert_allclose(np.asarray(yaw) @ np.asarray(yaw).T, np.eye(3), atol=1e-6)
    only_left = frame_effectors(clip, 0, ("Hips", "Hand_L"), [True, True])
    _, yaw = canonical_frame(only_left, left, right)  # no right side: no heading
    np.testing.assert_allclose(yaw, np.eye(3), atol=1e-7)


def test_protocol_adapter_is_the_six_joint_solve(clip, model):
    targets = _targets(clip.character, clip.poses)
    assert isinstance(targets, IKTargets)
    pose = _ik(model, targets)
    assert isinstance(pose, Pose) and pose.quat_local.shape == clip.poses.quat_local.shape
    effectors = jax.vmap(lambda p, r: Effectors.from_targets(clip.character, IKTargets(p, r)))(targets.position, targets.rot6d)
    direct = _solve(model, effectors)
    for a, b in zip(jax.tree.leaves(pose), jax.tree.leaves(direct)):
        np.testing.assert_allclose(a, b, atol=1e-5)
    named = Effectors.from_names(clip.character, SIX, targets.position[7], targets.rot6d[7])
    np.testing.assert_allclose(_solve(model, stack(named)).root_pos[0], pose.root_pos[7], atol=1e-4)
    # pose_fk of the returned Pose puts the hips at root_pos and is what the loss trains.
    _, pos = _fk(clip.character, pose)
    np.testing.assert_allclose(pos[:, clip.character.hips], pose.root_pos, atol=1e-4)
    with pytest.raises(ValueError, match=r"\(5, 3\)"):
        protores_ik_fn(model, IKTargets(targets.position[0, :5], targets.rot6d[0, :5]))


# ----------------------------------------------------------------------------- training


@pytest.fixture(scope="module")
def kit(clip) -> SimpleNamespace:
    """One compiled training step (both effector groups) on the demo clip's 40 frames."""
    config = ProtoResConfig.tiny(clip.character.num_joints)
    train = IKTrainConfig(num_steps=120, batch_size=32, dense_batch_size=4, learning_rate=3e-3, warmup_steps=5)
    graphdef, state0 = init_ik_train_state(config, train, key=jax.random.key(0))
    jitted = compile_train_step(make_ik_train_step(graphdef, config, train, clip.character), num_seeds=None)
    device = jax.devices()[0]  # restored checkpoints are committed: commit the fresh state too
    data = jax.device_put(clip.poses, device)
    return SimpleNamespace(
        config=config, train=train, graphdef=graphdef, state0=jax.device_put(state0, device), step=jitted, data=data
    )


def test_effector_configurations_cover_table2(clip):
    configs = effector_configurations(clip.character)
    names = clip.character.skeleton.names
    assert [names[j] for j in configs[CHARACTERISTIC]] == list(SIX)
    assert [names[j] for j in configs["root, neck, hands, feet"]] == ["Hips", "Neck", *SIX[2:]]
    assert len(configs["root, neck, hands, feet, elbows, knees"]) == 10
    assert configs[ALL_JOINTS] == body_joints(clip.character) and 0 not in configs[ALL_JOINTS]
    with pytest.raises(ValueError, match="Elbow_L"):
        effector_configurations(clip.character, {"left_elbow": "Elbow_L"})


def test_training_lowers_the_loss(clip, kit):
    _, before = kit.step(kit.state0, kit.data)
    state, history = run_training(kit.step, kit.state0, kit.data, num_steps=kit.train.num_steps, progress=False, log_every=20)
    _, after = kit.step(state, kit.data)
    assert float(after["pos"]) < 0.35 * float(before["pos"]), (float(before["pos"]), float(after["pos"]))
    assert float(after["rot"]) < float(before["rot"])
    assert history[-1]["step"] == kit.train.num_steps and np.isfinite(history[-1]["grad_norm"])
    model = ProtoResModel(state.params, clip.character, kit.graphdef, kit.config)
    six = effector_mpjpe(model, clip.poses, clip.character.characteristic, chunk=64)
    assert six.shape == (40,) and float(six.mean()) < 0.35 * float(before["pos"])


def test_checkpoint_resume_is_bit_identical(kit, tmp_path):
    straight, _ = run_training(kit.step, kit.state0, kit.data, num_steps=4, progress=False)
    store = CheckpointStore(tmp_path / "run")
    config = {"model": dataclasses.asdict(kit.config), "train": dataclasses.asdict(kit.train)}
    half, _ = run_training(kit.step, kit.state0, kit.data, num_steps=2, store=store, config=config, progress=False)
    assert store.latest_step() == 2 and store.config()["model"]["encoder_width"] == kit.config.encoder_width
    assert half.ema is None
    fresh = jax.device_put(init_ik_train_state(kit.config, kit.train, key=jax.random.key(9))[1], jax.devices()[0])
    resumed, _ = run_training(kit.step, fresh, kit.data, num_steps=4, store=store, progress=False)
    assert_trees_identical(resumed, straight)
    store.close()
    assert kit.step._cache_size() == 1  # the restored state reuses the compiled step


def test_save_and_load_round_trip(clip, model, tmp_path):
    save_ik_model(tmp_path / "ik", model)
    saved = json.loads((tmp_path / "ik" / "config.json").read_text())
    assert saved["character"]["names"] == list(clip.character.skeleton.names)
    assert saved["character"]["characteristic"] == list(clip.character.characteristic)
    loaded = load_ik_model(tmp_path / "ik")
    assert loaded.config == model.config and loaded.character.name == "bandai_namco"
    assert loaded.character.skeleton.parents == clip.character.skeleton.parents
    assert loaded.character.end_sites == clip.character.end_sites
    np.testing.assert_array_equal(loaded.character.skeleton.offsets, clip.character.skeleton.offsets)
    assert_trees_identical(loaded.params, model.params)
    targets = _targets(clip.character, clip.poses)
    for a, b in zip(jax.tree.leaves(_ik(loaded, targets)), jax.tree.leaves(_ik(model, targets))):
        np.testing.assert_array_equal(a, b)


def test_a_half_precision_save_loads_as_float32_rounded_once(model, tmp_path):
    save_ik_model(tmp_path / "ik16", model, storage_dtype="float16")
    assert json.loads((tmp_path / "ik16" / "config.json").read_text())["storage_dtype"] == "float16"
    loaded = load_ik_model(tmp_path / "ik16")
    for a, b in zip(jax.tree.leaves(loaded.params), jax.tree.leaves(model.params)):
        assert a.dtype == jnp.float32
        np.testing.assert_array_equal(a, np.asarray(b).astype(np.float16).astype(np.float32))
    with pytest.raises(ValueError, match="'int8'"):
        save_ik_model(tmp_path / "ik8", model, storage_dtype="int8")


# ---------------------------------------------------------------------------- bad input


def test_bad_input_raises_with_the_value(clip, model, tmp_path):
    with pytest.raises(ValueError, match="'Nose'"):
        Effectors.from_names(clip.character, ["Hips", "Nose"], np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(2, 2\)"):
        Effectors.from_names(clip.character, ["Hips", "Head"], np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"\(1, 4\)"):
        Effectors.from_names(clip.character, ["Hips"], np.zeros((1, 3)), np.zeros((1, 4)))
    with pytest.raises(ValueError, match="once"):
        Effectors.from_names(clip.character, ["Hips", "Hips"], np.zeros((2, 3)))
    e = frame_effectors(clip, 0, SIX, [True] * 6)
    with pytest.raises(ValueError, match=r"\(6, 2\)"):
        apply_protores(model.graphdef, model.params, clip.character, e._replace(position=e.position[:, :2]))
    with pytest.raises(ValueError, match="num_joints must be a positive integer, got 0"):
        ProtoResConfig(num_joints=0)
    with pytest.raises(ValueError, match="encoder_width must be a positive integer, got -3"):
        ProtoResConfig(22, encoder_width=-3)
    with pytest.raises(ValueError, match="position_scale must be positive, got -1.0"):
        ProtoResConfig(22, position_scale=-1.0)
    with pytest.raises(ValueError, match="dense_batch_size"):
        IKTrainConfig(batch_size=8, dense_batch_size=8)
    with pytest.raises(ValueError, match="'amass'"):
        load_corpus("amass")
    (tmp_path / "clips").mkdir()
    (tmp_path / "clips" / "walk.bvh").write_text(DEMO_CLIP.read_text())
    with pytest.raises(ValueError, match="'test'"):
        corpus_frames(load_bvh_folder(tmp_path / "clips", characteristic="bandai_namco", use_cache=False), "test")
    with pytest.raises(FileNotFoundError, match="not a saved learned IK"):
        load_ik_model(tmp_path / "empty")
    with pytest.raises(ValueError, match="21 joints, the character 'bandai_namco' has 22"):
        ProtoResModel(model.params, model.character, model.graphdef, dataclasses.replace(model.config, num_joints=21))
    graphdef21, params21 = init_protores(ProtoResConfig.tiny(21), key=jax.random.key(0))
    with pytest.raises(ValueError, match="21 joints, the character 'bandai_namco' has 22"):
        apply_protores(graphdef21, params21, clip.character, e)
