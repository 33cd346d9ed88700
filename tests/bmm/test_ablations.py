"""The dense ablations BMM⁻ᴮ and BMM⁻ᴵᴷ⁻ᴮ and the CondMDIᴳ baseline
(``bezmotion.evaluation.ablations``, its UNet ``bezmotion.bmm.unet``): configs, data, training
through ``bezmotion.training``, DDIM sampling with overwrite and classifier-free guidance,
storage, and the errors of bad inputs. Real data: the bundled ``DEMO_CLIP`` (10 windows of
31 frames).
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

from bezmotion.assets import DEMO_CLIP
from bezmotion.evaluation.ablations import (
    CondMDIConfig,
    DenseArrays,
    DenseBMMConfig,
    DenseMotionModel,
    dense_windows,
    drop_conditions,
    init_dense_network,
    init_dense_train_state,
    load_dense_model,
    make_dense_train_step,
    sample_dense,
    save_dense_model,
)
from bezmotion.bmm.denoiser import BMMDenoiser, init_denoiser
from bezmotion.bmm.features import FeatureStats, inbetween_conditions, predict_x0
from bezmotion.bmm.sampling import Handles, guided_denoiser
from bezmotion.bmm.train import BMMTrainConfig
from bezmotion.bmm.unet import CondUNet1D, condition_channels
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import characteristic_indices
from bezmotion.data.corpus import MotionClips
from bezmotion.training import compile_train_step, run_training

TRAIN = BMMTrainConfig(batch_size=8, learning_rate=1e-3, ema_decay=0.9)
VARIANTS = ("minus_b", "minus_ik_b", "condmdi_g")


@pytest.fixture(scope="module")
def clips() -> MotionClips:
    return MotionClips.from_bvh([read_bvh(DEMO_CLIP)])


def make_config(variant: str, clips: MotionClips) -> DenseBMMConfig:
    if variant == "minus_b":
        return DenseBMMConfig.minus_b("tiny", dropout=0.0)
    if variant == "condmdi_g":
        return DenseBMMConfig.condmdi_g(clips.joint_names, "bandai_namco", "tiny")
    return DenseBMMConfig.minus_ik_b(clips.joint_names, "bandai_namco", "tiny", dropout=0.0)


@pytest.fixture(scope="module", params=VARIANTS)
def kit(request, clips) -> SimpleNamespace:
    """One variant's config, windows (offset 1, as ``demo_dataset``), statistics and compiled step."""
    config = make_config(request.param, clips)
    arrays, clip_index, start_frame = dense_windows(clips, "bandai_namco", config, offset=1)
    stats = FeatureStats.from_features(arrays.features)
    graphdef, state0 = init_dense_train_state(config, TRAIN, key=jax.random.key(0))
    step = compile_train_step(make_dense_train_step(graphdef, config, TRAIN, stats), num_seeds=None)
    data = DenseArrays(*(jnp.asarray(a) for a in arrays))
    return SimpleNamespace(
        config=config, arrays=arrays, rows=(clip_index, start_frame), stats=stats, graphdef=graphdef, state0=state0, step=step, data=data
    )


def test_configs_are_the_bmm_with_a_token_per_frame(clips):
    minus_b, minus_ik_b = make_config("minus_b", clips), make_config("minus_ik_b", clips)
    joints = len(clips.joint_names)
    assert (minus_b.num_frames, minus_b.num_controls, minus_b.stride, minus_b.num_joints) == (31, 31, 1, 6)
    assert minus_b.frame_features == 6 * 9 and minus_b.orientation
    assert DenseBMMConfig.minus_b("tiny", orientation=False).frame_features == 6 * 3
    assert minus_ik_b.frame_features == joints * 3 and not minus_ik_b.orientation
    assert minus_ik_b.characteristic == characteristic_indices(clips.joint_names, "bandai_namco")
    # The BMM's own denoiser class, its token layout the config's.
    graphdef, params = init_denoiser(minus_ik_b, key=jax.random.key(1))
    denoiser = nnx.merge(graphdef, params)
    assert isinstance(denoiser, BMMDenoiser) and denoiser.frame_encoder.in_features == joints * 3
    # The BMM's sizes and presets.
    assert (minus_b.width, minus_b.num_layers) == (32, 1) and DenseBMMConfig.minus_b("paper").width == 512
    # A checkpoint's config.json gives it back (tuples as lists).
    for config in (minus_b, minus_ik_b):
        assert DenseBMMConfig.from_dict(json.loads(json.dumps(dataclasses.asdict(config)))) == config


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"variant": "minus_x"}, "'minus_x'"),
        ({"stride": 6}, "stride must be 1, got 6"),
        ({"prediction": "residual"}, "'residual'"),
        ({"features_per_joint": 12}, "got 12"),
        ({"characteristic": (0, 1, 2)}, "(0, 1, 2)"),
        ({"characteristic": (0, 0, 1, 2, 3, 4)}, "(0, 0, 1, 2, 3, 4)"),
        ({"variant": "minus_ik_b", "token_joints": 10, "characteristic": (0, 1, 2, 3, 4, 5)}, "got 9"),
        ({"token_joints": 8, "characteristic": (0, 1, 2, 3, 4, 7)}, "token_joints=8"),
        ({"token_joints": 5}, "got 5"),
    ],
)
def test_bad_configs_raise_naming_the_value(overrides, message):
    with pytest.raises(ValueError) as error:
        DenseBMMConfig.tiny(**overrides)
    assert message in str(error.value)


def test_unknown_size_raises_naming_it():
    with pytest.raises(ValueError, match="'huge'"):
        DenseBMMConfig.minus_b("huge")


def test_dense_windows_are_the_bmm_windows(kit, demo_dataset):
    """The same windows as the curve dataset (offset 1), its mocap and contacts, every frame."""
    n = len(demo_dataset)
    cfg = kit.config
    assert kit.arrays.features.shape == (n, 31, cfg.token_joints, cfg.features_per_joint)
    assert kit.arrays.contacts.shape == (n, 31, 2)
    np.testing.assert_array_equal(kit.rows[0], demo_dataset.clip_index)
    np.testing.assert_array_equal(kit.rows[1], demo_dataset.start_frame)
    np.testing.assert_allclose(kit.arrays.characteristic_positions(cfg), demo_dataset.dense_pos, atol=1e-3)
    np.testing.assert_array_equal(kit.arrays.contacts, demo_dataset.dense_contacts)
    if cfg.orientation:  # the orientations at the control frames are the curve dataset's
        np.testing.assert_allclose(kit.arrays.features[:, ::6, :, 3:], demo_dataset.ctrl_rot6d, atol=1e-5)


def test_dense_windows_refuse_a_config_of_another_skeleton(clips):
    config = DenseBMMConfig.minus_ik_b([*clips.joint_names, "Extra"], "bandai_namco", "tiny")
    with pytest.raises(ValueError, match=f"{len(clips.joint_names) + 1} joints"):
        dense_windows(clips, "bandai_namco", config, offset=1)


def test_training_lowers_the_loss(kit):
    """30 steps of the tiny model on the real windows: the loss on fixed batches/noise drops."""
    eval_keys = [jax.random.key(100 + i) for i in range(3)]

    def eval_loss(state):
        return np.mean([float(kit.step(dataclasses.replace(state, key=k), kit.data)[1]["loss"]) for k in eval_keys])

    before = eval_loss(kit.state0)
    state, history = run_training(kit.step, kit.state0, kit.data, num_steps=30, progress=False, log_every=10)
    after = eval_loss(state)
    assert int(state.step) == 30 and all(np.isfinite(v) for h in history for v in h.values())
    terms = {"dense_position", "velocity", "condition", "contact", "skate"} | ({"orientation"} if kit.config.orientation else set())
    assert terms <= set(history[-1])
    assert after < 0.5 * before, f"loss {before:.4f} → {after:.4f}"


@pytest.fixture(scope="module")
def conditions(kit) -> SimpleNamespace:
    """Two windows moved away from the origin in XZ, with handles (one padding slot)."""
    six = np.asarray(kit.arrays.characteristic_positions(kit.config))[[0, 7]] + np.array([150.0, 3.0, -230.0], np.float32)
    handles = Handles(
        joint=jnp.asarray([[2, 4, 0], [1, 5, 3]], jnp.int32),
        frame=jnp.asarray([[6, 13, 24], [18, 12, 5]], jnp.int32),
        position=jnp.asarray(np.stack([six[0, [6, 13, 24], [2, 4, 0]] + 5.0, six[1, [18, 12, 5], [1, 5, 3]] - 7.0]), jnp.float32),
        valid=jnp.asarray([[True, True, True], [True, True, False]]),
    )
    model = DenseMotionModel(kit.state0.ema, kit.stats, kit.graphdef, kit.config)
    return SimpleNamespace(model=model, start=jnp.asarray(six[:, 0]), end=jnp.asarray(six[:, -1]), handles=handles)


def handle_errors(pos6: np.ndarray, handles: Handles) -> np.ndarray:
    """Distance of every valid handle from the trajectory at its frame (cm)."""
    b, s = np.nonzero(np.asarray(handles.valid))
    got = pos6[b, np.asarray(handles.frame)[b, s], np.asarray(handles.joint)[b, s]]
    return np.linalg.norm(got - np.asarray(handles.position)[b, s], axis=-1)


def test_sampler_hits_the_keys_and_with_overwrite_the_handles(kit, conditions):
    c = conditions
    key = jax.random.key(5)
    motions = {mode: sample_dense(c.model, c.start, c.end, c.handles, key=key, steps=3, overwrite=mode) for mode in ("keys", "all")}
    cfg = kit.config
    for mode, motion in motions.items():
        assert motion.pos.shape == (2, 31, cfg.token_joints, 3) and motion.contacts.shape == (2, 31, 2)
        assert (motion.rot6d is not None) == cfg.orientation
        six = np.asarray(motion.characteristic_positions(cfg))
        np.testing.assert_array_equal(six[:, 0], c.start)
        np.testing.assert_array_equal(six[:, -1], c.end)
        assert np.isfinite(np.asarray(motion.pos)).all()
    assert handle_errors(np.asarray(motions["all"].characteristic_positions(cfg)), c.handles).max() < 1e-4
    # Without overwrite the handles are only conditions: a tiny model misses them.
    assert handle_errors(np.asarray(motions["keys"].characteristic_positions(cfg)), c.handles).min() > 1e-3


def test_sampler_without_overwrite_hits_nothing_exactly(kit, conditions):
    c = conditions
    motion = sample_dense(c.model, c.start, c.end, c.handles, key=jax.random.key(5), steps=3, overwrite="none")
    assert np.abs(np.asarray(motion.characteristic_positions(kit.config))[:, 0] - np.asarray(c.start)).max() > 1e-3


def test_sampler_bad_inputs_raise_naming_them(kit, conditions):
    c = conditions
    with pytest.raises(ValueError, match="'everything'"):
        sample_dense(c.model, c.start, c.end, c.handles, key=jax.random.key(0), overwrite="everything")
    with pytest.raises(ValueError, match=r"\(2, 5, 3\)"):
        sample_dense(c.model, c.start[:, :5], c.end[:, :5], c.handles, key=jax.random.key(0))
    with pytest.raises(ValueError, match=r"\(1,\)"):
        sample_dense(c.model, c.start, c.end, jax.tree.map(lambda x: x[:1], c.handles), key=jax.random.key(0))


def test_training_levers_of_the_bezier_step_are_refused(kit):
    for train, value in ((BMMTrainConfig(yaw_augmentation=True), "True"), (BMMTrainConfig(off_grid_handles=0.5), "0.5")):
        with pytest.raises(ValueError, match=value):
            make_dense_train_step(kit.graphdef, kit.config, train, kit.stats)
    with pytest.raises(ValueError, match="'everywhere'"):
        make_dense_train_step(kit.graphdef, kit.config, TRAIN, kit.stats, handle_frames="everywhere")


def test_save_and_load_give_the_same_samples(kit, conditions, tmp_path):
    c = conditions
    save_dense_model(tmp_path / "model", c.model)
    loaded = load_dense_model(tmp_path / "model")
    assert loaded.config == kit.config
    a, b = (sample_dense(m, c.start, c.end, c.handles, key=jax.random.key(2), steps=3) for m in (c.model, loaded))
    np.testing.assert_array_equal(a.pos, b.pos)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_dense_model(tmp_path / "nowhere")


# ------------------------------------------------------------------------------- CondMDIᴳ


@pytest.fixture(scope="module")
def unet(clips) -> SimpleNamespace:
    """A tiny CondMDIᴳ UNet (untrained) with real statistics, and one motion's conditions."""
    config = make_config("condmdi_g", clips)
    arrays, _, _ = dense_windows(clips, "bandai_namco", config, offset=1)
    graphdef, params = init_dense_network(config, key=jax.random.key(3))
    rng = np.random.default_rng(0)
    conditions = inbetween_conditions(
        31, jnp.asarray(rng.normal(size=(6, 3)), jnp.float32), jnp.asarray(rng.normal(size=(6, 3)), jnp.float32),
        Handles(
            frame=jnp.asarray([7, 20, 0], jnp.int32), joint=jnp.asarray([2, 5, 0], jnp.int32),
            position=jnp.asarray(rng.normal(size=(3, 3)), jnp.float32), valid=jnp.asarray([True, True, False]),
        ),
    )  # fmt: skip
    x_t = jnp.asarray(rng.normal(size=(31, config.frame_features)), jnp.float32)
    stats = FeatureStats.from_features(arrays.features)
    # Used functionally, as the training step and the sampler use it (and jitted: eager NNX is slow).
    predict = jax.jit(lambda x, t, c: predict_x0(nnx.merge(graphdef, params), stats, x, t, c))
    return SimpleNamespace(config=config, net=nnx.merge(graphdef, params), predict=predict, conditions=conditions, x_t=x_t)


def test_condmdi_g_config_is_the_full_skeleton_with_unet_sizes(clips):
    config = make_config("condmdi_g", clips)
    joints = len(clips.joint_names)
    assert isinstance(config, CondMDIConfig) and config.variant == "condmdi_g" and config.full_skeleton
    assert config.frame_features == joints * 3 and config.characteristic == make_config("minus_ik_b", clips).characteristic
    assert (config.width, config.unet_mults, config.kernel_size, config.guidance) == (16, (1, 2), 5, 2.5)
    assert config.default_guidance == 2.5 and make_config("minus_ik_b", clips).default_guidance == 1.0
    cpu = DenseBMMConfig.condmdi_g(clips.joint_names, "bandai_namco")
    assert (cpu.width, cpu.unet_mults) == (64, (1, 2, 4))
    # The paper size without building it: GMD's UNet is ≈ 224 M parameters (the paper's Table 7: 224.6 M).
    paper = DenseBMMConfig.condmdi_g(clips.joint_names, "bandai_namco", "paper")
    shapes = nnx.state(nnx.eval_shape(lambda: CondUNet1D(paper, rngs=nnx.Rngs(0))), nnx.Param)
    assert 200e6 < sum(int(np.prod(x.shape)) for x in jax.tree.leaves(shapes)) < 250e6
    assert DenseBMMConfig.from_dict(json.loads(json.dumps(dataclasses.asdict(config)))) == config


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"guidance": -0.5}, "-0.5"),
        ({"unet_mults": ()}, "()"),
        ({"unet_mults": (1, 0)}, "(1, 0)"),
        ({"width": 12}, "width 12"),
        ({"kernel_size": 4}, "got 4"),
        ({"features_per_joint": 9}, "got 9"),
    ],
)
def test_bad_condmdi_g_configs_raise_naming_the_value(clips, overrides, message):
    with pytest.raises(ValueError) as error:
        DenseBMMConfig.condmdi_g(clips.joint_names, "bandai_namco", "tiny", **overrides)
    assert message in str(error.value)
    with pytest.raises(ValueError, match="CondMDIConfig"):
        DenseBMMConfig.tiny(variant="condmdi_g", features_per_joint=3)


def test_unet_shapes_and_condition_channels(unet):
    cfg, cond = unet.config, unet.conditions
    f = cfg.frame_features
    assert unet.net.downs[0].res1.block1.conv.in_features == 3 * f  # noisy motion ⊕ condition values ⊕ mask
    x0, logits = unet.predict(unet.x_t, jnp.int32(500), cond)
    assert x0.shape == (31, f) and logits.shape == (31, 2) and np.isfinite(np.asarray(x0)).all()
    values, mask = (np.asarray(a).reshape(31, cfg.token_joints, 3) for a in condition_channels(cfg, cond))
    char = np.asarray(cfg.characteristic)
    # Start and end of all six joints, the two valid handles; nothing else, the padding slot neither.
    expected = np.zeros((31, cfg.token_joints, 3))
    expected[0, char] = expected[-1, char] = expected[7, char[2]] = expected[20, char[5]] = 1.0
    np.testing.assert_array_equal(mask, expected)
    np.testing.assert_array_equal(values[20, char[5]], cond.position[13])
    np.testing.assert_array_equal(values[0, char], cond.position[:6])
    assert values[0, char[0]].tolist() != [0.0, 0.0, 0.0]
    # A padding slot holding NaN leaves no trace; a moved handle changes the prediction.
    poisoned = cond._replace(position=cond.position.at[-1].set(jnp.nan))
    np.testing.assert_array_equal(unet.predict(unet.x_t, jnp.int32(500), poisoned)[0], x0)
    moved = cond._replace(position=cond.position.at[12].add(1.0))
    assert np.abs(np.asarray(unet.predict(unet.x_t, jnp.int32(500), moved)[0] - x0)).max() > 1e-4


def test_guidance_one_is_the_conditional_prediction_and_2_5_extrapolates(unet):
    predict = unet.predict
    t = jnp.int32(300)
    cond_x0, cond_logits = predict(unet.x_t, t, unet.conditions)
    uncond_x0, _ = predict(unet.x_t, t, unet.conditions._replace(valid=jnp.zeros_like(unet.conditions.valid)))
    assert np.abs(np.asarray(cond_x0 - uncond_x0)).max() > 1e-4
    one = guided_denoiser(predict, unet.conditions, 1.0)(unet.x_t, t)
    np.testing.assert_array_equal(one[0], cond_x0)
    np.testing.assert_array_equal(one[1], cond_logits)
    guided, logits = guided_denoiser(predict, unet.conditions, 2.5)(unet.x_t, t)
    np.testing.assert_allclose(guided, uncond_x0 + 2.5 * (cond_x0 - uncond_x0), atol=1e-5)
    np.testing.assert_allclose(logits, cond_logits, atol=1e-5)


def test_condition_dropout_drops_every_condition_at_the_configured_rate(unet):
    keys = jax.random.split(jax.random.key(11), 4000)
    for rate in (0.1, 0.3):
        valid = np.asarray(jax.vmap(lambda k: drop_conditions(k, unet.conditions, rate).valid)(keys))  # noqa: B023
        dropped = ~valid.any(axis=1)
        # All conditions of an example at once, never some of them; the padding slot stays invalid.
        assert ((valid == np.asarray(unet.conditions.valid)) | dropped[:, None]).all()
        assert abs(dropped.mean() - rate) < 0.025, (rate, dropped.mean())  # 4000 draws: σ ≤ 0.008
    assert np.asarray(jax.vmap(lambda k: drop_conditions(k, unet.conditions, 0.0).valid)(keys[:100])).any(axis=1).all()
    for bad in (1.0, -0.1, 1.5):
        with pytest.raises(ValueError, match=str(bad)):
            drop_conditions(keys[0], unet.conditions, bad)
    with pytest.raises(ValueError, match="condition_dropout=1.0"):
        BMMTrainConfig(condition_dropout=1.0)


@pytest.fixture(scope="module")
def condmdi_kit(clips) -> SimpleNamespace:
    config = make_config("condmdi_g", clips)
    arrays, _, _ = dense_windows(clips, "bandai_namco", config, offset=1)
    stats = FeatureStats.from_features(arrays.features)
    graphdef, state = init_dense_train_state(config, TRAIN, key=jax.random.key(0))
    return SimpleNamespace(config=config, model=DenseMotionModel(state.params, stats, graphdef, config), arrays=arrays)


def test_condmdi_g_samples_at_guidance_2_5_by_default_and_refuses_negative_guidance(condmdi_kit):
    k = condmdi_kit
    six = np.asarray(k.arrays.characteristic_positions(k.config))[[0, 3]]
    start, end = jnp.asarray(six[:, 0]), jnp.asarray(six[:, -1])
    handles = Handles(
        joint=jnp.asarray([[4], [1]], jnp.int32), frame=jnp.asarray([[9], [22]], jnp.int32),
        position=jnp.asarray(six[[0, 1], [9, 22], [4, 1]][:, None] + 3.0, jnp.float32), valid=jnp.ones((2, 1), bool),
    )  # fmt: skip
    key = jax.random.key(4)
    default = sample_dense(k.model, start, end, handles, key=key, steps=3)
    np.testing.assert_array_equal(default.pos, sample_dense(k.model, start, end, handles, key=key, steps=3, guidance=2.5).pos)
    plain = sample_dense(k.model, start, end, handles, key=key, steps=3, guidance=1.0)
    assert np.abs(np.asarray(default.pos - plain.pos)).max() > 1e-3
    for motion in (default, plain):
        assert np.isfinite(np.asarray(motion.pos)).all()
        pos6 = np.asarray(motion.characteristic_positions(k.config))
        np.testing.assert_array_equal(pos6[:, 0], start)  # the keys inpainted
        np.testing.assert_array_equal(pos6[:, -1], end)
    with pytest.raises(ValueError, match="-0.5"):
        sample_dense(k.model, start, end, handles, key=key, guidance=-0.5)
