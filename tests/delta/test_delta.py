"""The Δ-interpolator: architecture contracts, Δ-modes, training and resume.

Real-shaped data comes from the ``synthetic_zip`` fixture (LaFAN1 layout, our own
skeleton and motion). Compiling is what costs time here, so each model configuration is
compiled once (``apply`` per fixture) and every test of that configuration reuses it;
training uses one compiled, two-seed vmapped step for the loss and resume tests.
"""

from __future__ import annotations

import dataclasses
import functools
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from helpers import assert_trees_identical, leaves, trees_differ

from bezmotion.training.checkpoint import CheckpointStore
from bezmotion.data import lafan1
from bezmotion.delta.train import (
    DeltaArrays,
    DeltaTrainConfig,
    draw_layout,
    example_layout,
    init_delta_train_states,
    learning_rate_schedule,
    make_delta_train_step,
    run_delta_training,
)
from bezmotion.evaluation.lafan1 import TEST_OFFSET, TEST_WINDOW, Lafan1Benchmark, evaluate_transitions
from bezmotion.geometry.skeleton import Skeleton, forward_kinematics
from bezmotion.evaluation.baselines import interpolation, interpolation_inbetweener
from bezmotion.delta.model import (
    DeltaConfig,
    DeltaInterpolator,
    KeyFrames,
    apply_delta,
    delta_inbetweener,
    init_delta,
    transition_layout,
)
from bezmotion.training import compile_train_step, count_parameters

N_PAST, MAX_GAP, WINDOW = 10, 39, 50
SIZES = {"parents": lafan1.PARENTS, "width": 32, "num_heads": 2, "mlp_layers": 2, "embedding_dim": 8}
FORWARD = DeltaConfig(num_blocks=2, dropout=0.2, **SIZES)  # Last / I: the paper's Δ-interpolator


# ------------------------------------------------------------------------------ helpers


def with_random_heads(params, seed: int):
    """The parameters with random output heads: zero-initialised residual heads would
    hide every change upstream of them."""
    rng = np.random.default_rng(seed)

    def randomise(path, x):
        names = [str(getattr(p, "key", "")) for p in path]
        if names[0] in ("rotation_head", "root_head"):
            return jnp.asarray(rng.normal(scale=0.3, size=x.shape), x.dtype)
        return x

    return jax.tree_util.tree_map_with_path(randomise, params)


def window_keys(w: SimpleNamespace, i: int, layout) -> KeyFrames:
    """Window ``i``'s key frames under ``layout`` (as the training step gathers them)."""
    kf = layout.key_frame
    return KeyFrames(w.quat[i][kf], w.root[i][kf], kf, jnp.ones(kf.shape, bool))


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def corpus(synthetic_zip) -> lafan1.Lafan1Corpus:
    return lafan1.load_lafan1(synthetic_zip, use_cache=False)


@pytest.fixture(scope="module")
def windows(corpus) -> SimpleNamespace:
    """The synthetic training windows (subjects 1–2, 50 frames, offset 20) as float32."""
    w = lafan1.lafan1_windows(corpus, (1, 2), WINDOW, 20)
    data = DeltaArrays.from_windows(w)
    return SimpleNamespace(data=data, quat=data.quat_local, root=data.root_pos, offsets=data.offsets, n=w.num_windows)


@pytest.fixture(scope="module")
def forward() -> SimpleNamespace:
    """The Δ-interpolator (Last / I), untrained and with random heads, and one jitted apply."""
    graphdef, params = init_delta(FORWARD, key=jax.random.key(1))
    apply = jax.jit(functools.partial(apply_delta, graphdef))
    return SimpleNamespace(graphdef=graphdef, params=params, trained=with_random_heads(params, 0), apply=apply)


@pytest.fixture(scope="module")
def no_delta_input() -> SimpleNamespace:
    """A model with absolute inputs and output relative to the last frame (No / Last)."""
    config = dataclasses.replace(FORWARD, input_delta="none", output_delta="last")
    graphdef, params = init_delta(config, key=jax.random.key(2))
    apply = jax.jit(functools.partial(apply_delta, graphdef))
    return SimpleNamespace(graphdef=graphdef, params=params, trained=with_random_heads(params, 1), apply=apply)


# ---------------------------------------------------------------------------- configs


def test_config_sizes_and_validation():
    paper, cpu = DeltaConfig.paper(parents=lafan1.PARENTS), DeltaConfig.cpu(parents=lafan1.PARENTS)
    assert (paper.width, paper.num_blocks, paper.num_heads, paper.embedding_dim, paper.dropout) == (1024, 6, 8, 32, 0.2)
    assert (paper.input_delta, paper.output_delta, paper.num_joints, paper.frame_features) == ("last", "interpolation", 22, 198)
    assert cpu.width <= 256 and cpu.num_blocks <= 3
    bad = {
        "width": ({"width": 100, "num_heads": 8}, "divisible by num_heads"),
        "dropout": ({"dropout": 1.0}, "dropout must be in"),
        "input": ({"input_delta": "interpolation"}, "input_delta must be one of"),
        "output": ({"output_delta": "slerp"}, "output_delta must be one of .*'slerp'"),
        "blocks": ({"num_blocks": 0}, "num_blocks must be a positive integer, got 0"),
        "frames": ({"max_frames": 11}, "max_frames \\(11\\)"),
        "parents": ({"parents": (-1, 0, 3, 1)}, "parents must be a tuple"),
        "scale": ({"position_scale": 0.0}, "position_scale must be positive"),
    }
    for overrides, message in bad.values():
        with pytest.raises(ValueError, match=message):
            DeltaConfig(**overrides)


def test_paper_size_has_the_published_parameter_count():
    """44.5 M parameters (REFERENCE §2 quotes ≈ 44.9 M for the original code), counted on
    abstract shapes so nothing is allocated."""
    model = nnx.eval_shape(lambda: DeltaInterpolator(DeltaConfig.paper(parents=lafan1.PARENTS), rngs=nnx.Rngs(0)))
    count = count_parameters(nnx.state(model, nnx.Param))
    w, blocks = 1024, 6
    per_block = 4 * (w * w + w) + 2 * w + 3 * (w * w + w)  # q, k, v, out; LayerNorm; MLP
    expected = blocks * per_block + 2 * 65 * 32 + (198 + 64 + 1) * w + (w + 1) * (132 + 3)
    assert count == expected
    assert 44.0e6 < count < 45.0e6


def test_train_config_validation_and_schedule(forward):
    for overrides, message in (
        ({"min_gap": 40}, "min_gap \\(40\\) exceeds max_gap \\(39\\)"),
        ({"batch_size": 0}, "batch_size must be a positive integer, got 0"),
        ({"learning_rate": 0.0}, "learning rates must be positive"),
        ({"decay_factor": 0.0}, "decay_factor must be in"),
        ({"warmup_steps": -1}, "warmup_steps must be a non-negative integer"),
    ):
        with pytest.raises(ValueError, match=message):
            DeltaTrainConfig(**overrides)
    config = DeltaTrainConfig(learning_rate=2e-4, initial_learning_rate=1e-6, warmup_steps=10, decay_every=20)
    lr = learning_rate_schedule(config)
    np.testing.assert_allclose([float(lr(s)) for s in (0, 5, 10, 29, 30, 49, 50)], [1e-6, 1.005e-4, 2e-4, 2e-4, 2e-5, 2e-5, 2e-6], rtol=1e-5)
    scaled = DeltaTrainConfig.for_steps(300)
    assert (scaled.warmup_steps, scaled.decay_every) == (50, 200)  # the paper's epochs 50 and 250 of 300
    with pytest.raises(ValueError, match="does not fit 30-frame windows"):
        make_delta_train_step(forward.graphdef, FORWARD, DeltaTrainConfig(), window_frames=30)
    with pytest.raises(ValueError, match="exceed the model's max_frames=65"):
        make_delta_train_step(forward.graphdef, FORWARD, DeltaTrainConfig(max_gap=60), window_frames=80)


# ------------------------------------------------------------------------ architecture


def test_one_set_of_block_weights_serves_both_streams(forward, windows):
    block = forward.params["blocks"][0]
    assert set(block.keys()) == {"attention", "norm", "mlp"}  # nothing stream-specific
    assert set(forward.params.keys()) == {"frame_embedding", "gap_embedding", "input", "blocks", "rotation_head", "root_head"}
    layout = example_layout(jnp.int32(12), jnp.int32(3), N_PAST, MAX_GAP)
    args = (windows.offsets[0], window_keys(windows, 0, layout), layout.missing_frame, layout.gap)
    base = forward.apply(forward.trained, *args)
    for b in range(FORWARD.num_blocks):
        for part in ("attention", "mlp"):
            bumped = jax.tree_util.tree_map_with_path(
                lambda path, x, b=b, part=part: x + 0.05 if [getattr(p, "key", None) for p in path][:3] == ["blocks", b, part] else x,
                forward.trained,
            )
            assert trees_differ(bumped, forward.trained)
            out = forward.apply(bumped, *args)
            # The key-frame stream (its reconstruction) and the missing-frame stream both move.
            assert np.abs(out.key_root - base.key_root).max() > 1e-3, (b, part)
            assert np.abs(out.missing_root[:12] - base.missing_root[:12]).max() > 1e-3, (b, part)


def test_missing_frames_and_padding_cannot_change_the_prediction(forward, windows):
    gap, start = 7, 4
    layout = example_layout(jnp.int32(gap), jnp.int32(start), N_PAST, MAX_GAP)
    quat, root = windows.quat[1], windows.root[1]
    keys = window_keys(windows, 1, layout)
    out = forward.apply(forward.trained, windows.offsets[1], keys, layout.missing_frame, layout.gap)
    # The window's content anywhere but at the key frames is never read: scramble it.
    key_rows = np.zeros(WINDOW, bool)
    key_rows[np.asarray(layout.key_frame)] = True
    scrambled_quat = jnp.where(key_rows[:, None, None], quat, -jnp.roll(quat, 5, axis=0))
    scrambled_root = jnp.where(key_rows[:, None], root, root + 1000.0)
    keys2 = KeyFrames(scrambled_quat[layout.key_frame], scrambled_root[layout.key_frame], layout.key_frame, keys.valid)
    out2 = forward.apply(forward.trained, windows.offsets[1], keys2, layout.missing_frame, layout.gap)
    for a, b in zip(out, out2, strict=True):
        np.testing.assert_array_equal(a, b)
    # The max_gap padding slots do not change the real ones: the exact layout agrees, to the
    # rounding of sums over another number of slots (a CPU may compile the two shapes'
    # reductions differently).
    exact = forward.apply(forward.trained, windows.offsets[1], keys, layout.missing_frame[:gap], layout.gap)
    np.testing.assert_allclose(exact.missing_quat, out.missing_quat[:gap], atol=2e-5)
    np.testing.assert_allclose(exact.missing_root, out.missing_root[:gap], atol=1e-4)
    np.testing.assert_allclose(exact.key_root, out.key_root, atol=1e-4)
    # A padding key slot is neither attended to nor read, even when it holds NaN — the
    # same as the model seeing only the other keys (here: one past frame fewer).
    valid = keys.valid.at[0].set(False)
    poisoned = keys._replace(quat_local=keys.quat_local.at[0].set(jnp.nan), root_pos=keys.root_pos.at[0].set(jnp.nan), valid=valid)
    out3 = forward.apply(forward.trained, windows.offsets[1], poisoned, layout.missing_frame, layout.gap)
    assert np.all(np.isfinite(out3.missing_quat)) and np.all(np.isfinite(out3.missing_root))
    other = keys._replace(quat_local=keys.quat_local.at[0].set(keys.quat_local[5]), root_pos=keys.root_pos.at[0].add(50.0), valid=valid)
    out4 = forward.apply(forward.trained, windows.offsets[1], other, layout.missing_frame, layout.gap)
    np.testing.assert_allclose(out3.missing_root, out4.missing_root, atol=1e-4)
    assert np.abs(out3.missing_root - out.missing_root).max() > 1e-3  # the slot mattered while valid


def test_translating_the_input_translates_the_output_and_nothing_else(forward, no_delta_input, windows):
    """The paper's robustness claim (§4.2): with the root-relative input, a constant offset of
    the whole input moves the output root and positions by that offset and changes no rotation."""
    layout = example_layout(jnp.int32(15), jnp.int32(2), N_PAST, MAX_GAP)
    keys = window_keys(windows, 2, layout)
    shift = jnp.asarray([312.5, -47.25, 1030.0], jnp.float32)
    moved = keys._replace(root_pos=keys.root_pos + shift)
    offsets = windows.offsets[2]
    out = forward.apply(forward.trained, offsets, keys, layout.missing_frame, layout.gap)
    out_moved = forward.apply(forward.trained, offsets, moved, layout.missing_frame, layout.gap)
    np.testing.assert_allclose(out_moved.missing_root, out.missing_root + shift, atol=2e-3)
    np.testing.assert_allclose(out_moved.key_root, out.key_root + shift, atol=2e-3)
    np.testing.assert_allclose(out_moved.missing_quat, out.missing_quat, atol=1e-5)
    np.testing.assert_allclose(out_moved.key_quat, out.key_quat, atol=1e-5)
    _, pos = forward_kinematics(FORWARD.parents, out.missing_quat, offsets, root_pos=out.missing_root)
    _, pos_moved = forward_kinematics(FORWARD.parents, out_moved.missing_quat, offsets, root_pos=out_moved.missing_root)
    np.testing.assert_allclose(pos_moved, pos + shift, atol=2e-3)
    assert np.abs(out.missing_root - keys.root_pos[N_PAST - 1]).max() > 1.0  # the heads do move the output
    # Absolute input features: the same shift changes the prediction itself.
    out = no_delta_input.apply(no_delta_input.trained, offsets, keys, layout.missing_frame, layout.gap)
    out_moved = no_delta_input.apply(no_delta_input.trained, offsets, moved, layout.missing_frame, layout.gap)
    assert np.abs(out_moved.missing_root - (out.missing_root + shift)).max() > 1.0
    assert np.abs(out_moved.missing_quat - out.missing_quat).max() > 1e-3


def test_an_untrained_model_is_its_baseline(forward, no_delta_input, windows):
    """Residual heads start at zero: Last / I is the interpolation baseline, No / Last zero velocity."""
    n = 9
    key_frame, missing_frame = (jnp.asarray(a) for a in transition_layout(N_PAST, n))
    q, r = windows.quat[3], windows.root[3]
    keys = KeyFrames(q[key_frame], r[key_frame], key_frame, jnp.ones(key_frame.shape, bool))
    pad = jnp.full(MAX_GAP - n, N_PAST, jnp.int32)  # the compiled (max_gap) layout
    out = forward.apply(forward.params, windows.offsets[3], keys, jnp.concatenate([missing_frame, pad]), jnp.int32(n))
    quat, root = interpolation(q[N_PAST - 1], r[N_PAST - 1], q[N_PAST + n], r[N_PAST + n], n)
    sign = jnp.sign(jnp.sum(out.missing_quat[:n] * quat, axis=-1, keepdims=True))
    np.testing.assert_allclose(sign * out.missing_quat[:n], quat, atol=2e-6)
    np.testing.assert_allclose(out.missing_root[:n], root, atol=1e-4)
    sign = jnp.sign(jnp.sum(out.key_quat * keys.quat_local, axis=-1, keepdims=True))
    np.testing.assert_allclose(sign * out.key_quat, keys.quat_local, atol=2e-6)  # keys reconstruct themselves
    last = no_delta_input.apply(no_delta_input.params, windows.offsets[3], keys, jnp.concatenate([missing_frame, pad]), jnp.int32(n))
    sign = jnp.sign(jnp.sum(last.missing_quat * q[N_PAST - 1], axis=-1, keepdims=True))
    np.testing.assert_allclose(sign * last.missing_quat, jnp.broadcast_to(q[N_PAST - 1], last.missing_quat.shape), atol=2e-6)
    np.testing.assert_allclose(last.missing_root, jnp.broadcast_to(r[N_PAST - 1], last.missing_root.shape), atol=1e-4)


def test_inbetweener_runs_the_official_benchmark(forward, corpus):
    """Untrained, the in-betweener scores as the interpolation baseline on the official
    protocol (signs included: its output is made sign-continuous like the data)."""
    test = lafan1.lafan1_windows(corpus, lafan1.TEST_SUBJECTS, TEST_WINDOW, TEST_OFFSET)
    bench = Lafan1Benchmark(test, lafan1.lafan1_statistics(corpus))
    skeleton = Skeleton(lafan1.PARENTS, lafan1.JOINT_NAMES, bench.stats.offsets)
    inbetween = delta_inbetweener(forward.graphdef, forward.params, skeleton, batch_size=4)
    ours = evaluate_transitions(bench, inbetween, lengths=(5,))
    reference = evaluate_transitions(bench, interpolation_inbetweener, lengths=(5,))
    for metric in ("l2q", "l2p", "npss"):
        np.testing.assert_allclose(ours[metric]["5"], reference[metric]["5"], rtol=1e-4, atol=1e-6)
    w = bench.windows
    with pytest.raises(ValueError, match="beyond the model's max_frames=65"):
        inbetween(w.quat_local[:1, :N_PAST], w.root_pos[:1, :N_PAST], w.quat_local[:1, 0], w.root_pos[:1, 0], 55)
    with pytest.raises(ValueError, match="batch_size must be a positive integer"):
        delta_inbetweener(forward.graphdef, forward.params, skeleton, batch_size=0)


# ---------------------------------------------------------------------------- training


def test_gap_lengths_follow_one_over_n_and_examples_fit_the_window():
    layouts = jax.jit(jax.vmap(lambda k: draw_layout(k, WINDOW, N_PAST, 5, MAX_GAP)))(jax.random.split(jax.random.key(0), 40000))
    gap = np.asarray(layouts.gap)
    assert gap.min() == 5 and gap.max() == MAX_GAP
    lengths = np.arange(5, MAX_GAP + 1)
    expected = (1 / lengths) / np.sum(1 / lengths)
    observed = np.bincount(gap, minlength=MAX_GAP + 1)[5:] / gap.size
    np.testing.assert_allclose(observed, expected, atol=0.006)
    target = np.asarray(layouts.key_frame[:, -1])
    np.testing.assert_array_equal(target - np.asarray(layouts.key_frame[:, N_PAST - 1]), gap + 1)
    assert target.max() == WINDOW - 1 and np.asarray(layouts.key_frame).min() == 0  # every start is reachable
    valid = np.asarray(layouts.missing_valid)
    np.testing.assert_array_equal(valid.sum(1), gap)
    assert np.all(np.asarray(layouts.missing_frame) < WINDOW)


@pytest.fixture(scope="module")
def kit(windows) -> SimpleNamespace:
    """A tiny model with neither Δ-mode (it starts far from the data, so a few dozen steps
    show) and its compiled two-seed training step."""
    config = DeltaConfig(num_blocks=1, dropout=0.1, input_delta="none", output_delta="none", **SIZES)
    train = DeltaTrainConfig(batch_size=8, learning_rate=3e-3, warmup_steps=2, decay_every=1000)
    graphdef, state0 = init_delta_train_states(config, train, [0, 1])
    step = compile_train_step(make_delta_train_step(graphdef, config, train, window_frames=WINDOW), num_seeds=2)
    device = jax.devices()[0]
    # Restored checkpoints are device-committed; committing here too avoids a second compile.
    committed = lambda state, data: step(jax.device_put(state, device), data)  # noqa: E731
    return SimpleNamespace(config=config, train=train, state0=state0, step=committed, jitted=step, data=windows.data)


def test_training_lowers_the_loss(kit):
    eval_keys = jax.random.split(jax.random.key(100), 3)

    def eval_loss(state):
        return np.mean([kit.step(dataclasses.replace(state, key=jnp.stack([k, k])), kit.data)[1]["loss"] for k in eval_keys])

    before = eval_loss(kit.state0)
    state, history = run_delta_training(kit.step, kit.state0, kit.data, num_steps=40, progress=False, log_every=10)
    after = eval_loss(state)
    np.testing.assert_array_equal(state.step, [40, 40])
    assert [h["step"] for h in history] == [10, 20, 30, 40]
    assert all(np.isfinite(v) for h in history for v in h.values())
    assert history[0]["learning_rate"] == pytest.approx(3e-3)
    assert after < 0.5 * before, f"loss {before:.1f} → {after:.1f}"
    assert kit.jitted._cache_size() == 1  # every gap length ran in the one compiled shape


def test_checkpoint_resume_is_bit_identical(kit, tmp_path):
    straight, _ = run_delta_training(kit.step, kit.state0, kit.data, num_steps=4, progress=False)
    store = CheckpointStore(tmp_path / "run")
    config = {"model": dataclasses.asdict(kit.config), "train": dataclasses.asdict(kit.train)}
    half, _ = run_delta_training(kit.step, kit.state0, kit.data, num_steps=2, store=store, config=config, progress=False)
    assert store.latest_step() == 2 and store.config()["model"]["output_delta"] == "none"
    assert half.ema is None
    fresh = init_delta_train_states(kit.config, kit.train, [7, 8])[1]  # restore must replace all of it
    resumed, _ = run_delta_training(kit.step, fresh, kit.data, num_steps=4, store=store, progress=False)
    assert_trees_identical(resumed, straight)
    assert store.latest_step() == 4
    store.close()
    assert kit.jitted._cache_size() == 1  # restored states reuse the compiled step
    # The two seeds really are two runs.
    assert not np.array_equal(leaves(straight.params)[0][0], leaves(straight.params)[0][1])
