"""The Δ-interpolator's positions representation and the Anidance benchmark.

Everything runs on synthetic dances (our own smooth motion, never Anidance data); only
the last test reads the real archive, when ``../shared/data`` is present. Compiling is
what costs time, so each model is compiled once per module and reused.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import json
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from bezmotion.evaluation.anidance import (
    AnidanceBenchmark,
    anidance_benchmark,
    anidance_from_world,
    anidance_layout,
    anidance_to_world,
    evaluate_anidance,
    evaluate_anidance_baselines,
    in_stored_layout,
)
from bezmotion.evaluation.baselines import (
    interpolation_position_inbetweener,
    keyframe_position_interpolation,
    keyframe_position_zero_velocity,
    zero_velocity_position_inbetweener,
)
from bezmotion.training.checkpoint import CheckpointStore
from bezmotion.data.anidance import COLUMNS, AnidanceStatistics, AnidanceWindows
from bezmotion.data.lafan1 import PARENTS
from bezmotion.delta.train import (
    DeltaArrays,
    DeltaPositionArrays,
    DeltaTrainConfig,
    example_layout,
    init_delta_train_states,
    make_delta_train_step,
    run_delta_training,
)
from bezmotion.delta.model import (
    DeltaConfig,
    KeyFrames,
    KeyPositions,
    apply_delta_positions,
    delta_position_inbetweener,
    init_delta,
)
from bezmotion.training import compile_train_step
from helpers import SHARED_DATA, requires_shared
from helpers import REPO_ROOT

P, N_PAST, MAX_GAP, PERIOD = 24, 1, 39, 6
SIZES = {"width": 32, "num_heads": 2, "mlp_layers": 2, "embedding_dim": 8, "num_blocks": 2}
LAST_I = DeltaConfig(representation="positions", num_points=P, n_past=N_PAST, dropout=0.0, **SIZES)


# ------------------------------------------------------------------------------ helpers


def synthetic_dance(frames: int, seed: int) -> np.ndarray:
    """``(frames, 24, 3)`` smooth made-up motion (cm): a drifting root and oscillating points."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None, None] / 25.0
    rest = rng.normal(scale=30.0, size=(1, P, 3))
    rest[0, 0] = (0.0, 95.0, 0.0)
    pos = rest + rng.uniform(2, 10, (1, P, 3)) * np.sin(2 * np.pi * rng.uniform(0.3, 1.5, (1, P, 3)) * t + rng.uniform(0, 6, (1, P, 3)))
    pos[:, 0] += np.concatenate([100 * np.sin(0.2 * t[:, 0]), np.zeros_like(t[:, 0]), 60 * np.cos(0.15 * t[:, 0])], axis=-1)
    return pos


def synthetic_bench(windows: int = 5, frames: int = 40, seed: int = 0) -> AnidanceBenchmark:
    positions = np.stack([synthetic_dance(frames, seed + k) for k in range(windows)])
    std = np.random.default_rng(seed).uniform(3.0, 60.0, P * 3)
    stats = AnidanceStatistics(positions.reshape(-1, P * 3).mean(axis=0), std)
    return AnidanceBenchmark(AnidanceWindows(positions, np.arange(windows), np.zeros(windows, np.int64)), stats)


def with_random_head(params, seed: int):
    """Random output head: the zero-initialised residual head would hide everything upstream."""
    rng = np.random.default_rng(seed)

    def randomise(path, x):
        if str(getattr(path[0], "key", "")) == "position_head":
            return jnp.asarray(rng.normal(scale=0.3, size=x.shape), x.dtype)
        return x

    return jax.tree_util.tree_map_with_path(randomise, params)


@pytest.fixture(scope="module")
def models() -> dict[str, SimpleNamespace]:
    """Last/I (the Δ-interpolator), Last/Last and No/No positions models, one jitted apply each."""
    out = {}
    for k, (inp, outp) in enumerate((("last", "interpolation"), ("last", "last"), ("none", "none"))):
        config = dataclasses.replace(LAST_I, input_delta=inp, output_delta=outp)
        graphdef, params = init_delta(config, key=jax.random.key(k))
        apply = jax.jit(functools.partial(apply_delta_positions, graphdef))
        out[f"{inp}-{outp}"] = SimpleNamespace(graphdef=graphdef, params=params, trained=with_random_head(params, k), apply=apply)
    return out


# ---------------------------------------------------------------------------- configs


def test_positions_config_and_errors(models):
    assert (LAST_I.num_joints, LAST_I.frame_features, LAST_I.output_features) == (24, 72, 72)
    assert DeltaConfig(parents=PARENTS).frame_features == 198 and DeltaConfig(parents=PARENTS).output_features == 22 * 6 + 3
    for overrides, message in (
        ({"representation": "positions"}, "num_points must be a positive integer for the positions representation, got None"),
        ({"num_points": 24}, "num_points=24 is only for the positions representation"),
        ({"representation": "points", "num_points": 24}, "representation must be one of .*'points'"),
    ):
        with pytest.raises(ValueError, match=message):
            DeltaConfig(**overrides)
    for overrides, message in (
        ({"keyframe_period": 1}, "keyframe_period must be an integer >= 2 or None, got 1"),
        ({"infill_probability": 1.5}, "infill_probability must be in \\[0, 1\\], got 1.5"),
    ):
        with pytest.raises(ValueError, match=message):
            DeltaTrainConfig(**overrides)
    m = models["last-interpolation"]
    assert set(m.params.keys()) == {"frame_embedding", "gap_embedding", "input", "blocks", "position_head"}
    frames = jnp.asarray([0, 6], jnp.int32)
    keys = KeyPositions(jnp.zeros((2, P, 3)), frames, jnp.ones(2, bool))
    with pytest.raises(ValueError, match="call it with offsets and KeyFrames"):
        apply_delta_positions(*init_delta(DeltaConfig(parents=PARENTS, **SIZES), key=jax.random.key(0)), keys, jnp.arange(1, 6), jnp.int32(5))
    rotation_keys = KeyFrames(jnp.zeros((2, P, 4)), jnp.zeros((2, 3)), frames, jnp.ones(2, bool))
    with pytest.raises(ValueError, match="call .positions"):
        nnx.merge(m.graphdef, m.params)(jnp.zeros((P, 3)), rotation_keys, jnp.arange(1, 6), jnp.int32(5))
    with pytest.raises(ValueError, match="keys.pos has shape \\(2, 22, 3\\), expected \\(keys, 24, 3\\)"):
        m.apply(m.params, keys._replace(pos=jnp.zeros((2, 22, 3))), jnp.arange(1, 6), jnp.int32(5))
    inbetween = delta_position_inbetweener(m.graphdef, m.params)
    pos = jnp.zeros((1, 2, P, 3))
    for key_frame, missing_frame, message in (
        ((5, 0), (1, 2), "strictly increasing"),
        ((0,), (1,), "1 past frame\\(s\\) and a target"),
        ((0, 6), (3, 6), "frames \\[6\\] are both key and missing"),
        ((0, 70), (3,), "must lie in \\[0, 65\\)"),
        ((0, 6), (), "non-empty tuples of ints"),
    ):
        with pytest.raises(ValueError, match=message):
            inbetween(pos[:, : len(key_frame)], key_frame, missing_frame)
    with pytest.raises(ValueError, match="batch_size must be a positive integer"):
        delta_position_inbetweener(m.graphdef, m.params, batch_size=0)


# --------------------------------------------------------------------------- baselines


def test_baselines_against_hand_computed_values():
    """Two points, keys at frames 0, 6 and 9 (plus a NaN padding slot that must not be read)."""
    pos = np.zeros((4, 2, 3))
    pos[0] = [[0.0, 0.0, 0.0], [10.0, 20.0, 30.0]]
    pos[1] = [[6.0, 12.0, -6.0], [10.0, 20.0, 30.0]]
    pos[2] = np.nan  # padding
    pos[3] = [[9.0, 0.0, 3.0], [40.0, 20.0, 0.0]]
    keys = KeyPositions(jnp.asarray(pos), jnp.asarray([0, 6, 0, 9]), jnp.asarray([True, True, False, True]))
    missing = jnp.asarray([1, 3, 7, 8])
    lerp = np.asarray(keyframe_position_interpolation(keys, missing))
    expected = np.array([
        [[1.0, 2.0, -1.0], [10.0, 20.0, 30.0]],   # 1/6 of the way from frame 0 to frame 6
        [[3.0, 6.0, -3.0], [10.0, 20.0, 30.0]],   # half way
        [[7.0, 8.0, -3.0], [20.0, 20.0, 20.0]],   # 1/3 of the way from frame 6 to frame 9
        [[8.0, 4.0, 0.0], [30.0, 20.0, 10.0]],    # 2/3
    ])  # fmt: skip
    np.testing.assert_allclose(lerp, expected, atol=1e-12)
    zerov = np.asarray(keyframe_position_zero_velocity(keys, missing))
    np.testing.assert_array_equal(zerov, pos[[0, 0, 1, 1]])
    # The benchmark's batched in-betweeners agree (key slots without padding).
    batch = jnp.asarray(np.stack([pos[[0, 1, 3]], pos[[0, 1, 3]] + 5.0]))
    np.testing.assert_allclose(interpolation_position_inbetweener(batch, (0, 6, 9), (1, 3, 7, 8))[1], expected + 5.0, atol=1e-12)
    np.testing.assert_array_equal(zero_velocity_position_inbetweener(batch, (0, 6, 9), (1, 3, 7, 8))[0], pos[[0, 0, 1, 1]])


def test_benchmark_layouts_and_the_training_in_filling_mask():
    """Key frames every 6 frames, plus the target; the training layout draws the same mask."""
    assert anidance_layout(5) == anidance_layout(5, "infill") == ((0, 5), (1, 2, 3, 4))
    assert anidance_layout(15, "gap") == ((0, 15), tuple(range(1, 15)))
    assert anidance_layout(15, "infill") == ((0, 6, 12, 15), (1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 13, 14))
    keys, missing = anidance_layout(30, "infill")
    assert keys == (0, 6, 12, 18, 24, 30) and len(missing) == 25 and set(keys) | set(missing) == set(range(31))
    assert anidance_layout(12, "infill")[0] == (0, 6, 12)  # a multiple of 6 is the target, not an extra key
    for n, protocol, message in ((1, "gap", "integer >= 2"), (5, "periodic", "unknown Anidance protocol 'periodic'")):
        with pytest.raises(ValueError, match=message):
            anidance_layout(n, protocol)
    for n in (5, 12, 15, 30, 40):
        for start, infill, protocol in ((0, True, "infill"), (37, True, "infill"), (11, False, "gap")):
            layout = example_layout(jnp.int32(n - 1), jnp.int32(start), N_PAST, MAX_GAP, PERIOD, infill)
            key_frame = np.asarray(layout.key_frame)[np.asarray(layout.key_valid)] - start
            missing_frame = np.asarray(layout.missing_frame)[np.asarray(layout.missing_valid)] - start
            assert (tuple(key_frame), tuple(missing_frame)) == anidance_layout(n, protocol), (n, start, protocol)
            assert int(layout.gap) == len(missing_frame)
            assert layout.key_frame.shape == (N_PAST + MAX_GAP // PERIOD + 1,) and layout.missing_frame.shape == (MAX_GAP,)
            # Padding slots index real frames of the example (no out-of-window gathers).
            assert np.all((np.asarray(layout.missing_frame) > start) & (np.asarray(layout.missing_frame) < start + n))
            assert np.all((np.asarray(layout.key_frame) >= start) & (np.asarray(layout.key_frame) <= start + n))


def np_l2p(pred: np.ndarray, true: np.ndarray, x_std: np.ndarray) -> float:
    """Plain-loop reference: mean over (window, frame) of the std-normalised 72-d L2 distance."""
    dists = [
        np.sqrt(np.sum(((pred[w, f].ravel() - true[w, f].ravel()) / x_std) ** 2))
        for w in range(pred.shape[0])
        for f in range(pred.shape[1])
    ]
    return float(np.mean(dists))


def test_l2p_and_baselines_against_numpy():
    bench = synthetic_bench()
    pos, std = bench.windows.positions, bench.stats.x_std
    results = evaluate_anidance_baselines(bench, lengths=(5, 30))
    for protocol in ("gap", "infill"):
        for n in (5, 30):
            keys, missing = anidance_layout(n, protocol)
            lerp = np.stack([
                np.stack([np.interp(missing, keys, pos[w, list(keys), p, c]) for c in range(3)], axis=-1)
                for w in range(pos.shape[0]) for p in range(P)
            ]).reshape(pos.shape[0], P, len(missing), 3).transpose(0, 2, 1, 3)  # fmt: skip
            zerov = pos[:, [max(k for k in keys if k < t) for t in missing]]
            true = pos[:, list(missing)]
            assert results[protocol]["interp"][str(n)] == pytest.approx(np_l2p(lerp, true, std), rel=1e-12)
            assert results[protocol]["zerov"][str(n)] == pytest.approx(np_l2p(zerov, true, std), rel=1e-12)
    assert results["gap"]["interp"]["5"] == results["infill"]["interp"]["5"]
    assert results["infill"]["interp"]["30"] < results["gap"]["interp"]["30"]  # key frames every 6 help
    # A prediction off by 2·x_std/√72 in every coordinate scores exactly 2.
    offset = 2.0 * std.reshape(P, 3) / np.sqrt(72.0)
    cheat = evaluate_anidance(bench, lambda key_pos, kf, mf: jnp.asarray(pos[:, list(mf)] + offset), (15,), protocol="infill")
    assert cheat == pytest.approx({"15": 2.0}, rel=1e-12)
    # The stored layout (bones relative to point 0) and world positions: a linear, per-frame
    # map, so both baselines score the same through it.
    stored = np.array([[[10.0, 90.0, -5.0], [1.0, 2.0, 3.0], [-4.0, -80.0, 6.0]]])
    world = np.array([[[10.0, 90.0, -5.0], [11.0, 92.0, -2.0], [6.0, 10.0, 1.0]]])
    np.testing.assert_allclose(anidance_to_world(stored), world)
    np.testing.assert_allclose(anidance_from_world(world), stored)
    np.testing.assert_allclose(anidance_from_world(anidance_to_world(pos)), pos, atol=1e-4)  # float32 outside x64
    for protocol in ("gap", "infill"):
        through_world = evaluate_anidance(bench, in_stored_layout(interpolation_position_inbetweener), (30,), protocol=protocol)
        assert through_world["30"] == pytest.approx(results[protocol]["interp"]["30"], rel=1e-12)
    with pytest.raises(ValueError, match="in-betweener returned shape"):
        evaluate_anidance(bench, lambda key_pos, kf, mf: key_pos, (5,))
    with pytest.raises(ValueError, match="does not fit 40-frame windows"):
        evaluate_anidance(bench, interpolation_position_inbetweener, (45,))


# ------------------------------------------------------------------------------ model


def test_translating_the_input_translates_the_output(models):
    """Root-relative input (Last/·): a constant offset of every input point moves every output
    point by that offset and changes nothing else; absolute input (No/No) does not."""
    dance = jnp.asarray(synthetic_dance(64, seed=3), jnp.float32)
    layout = example_layout(jnp.int32(16), jnp.int32(5), N_PAST, MAX_GAP, PERIOD)
    frames = layout.key_frame - layout.key_frame[0]
    keys = KeyPositions(dance[layout.key_frame], frames, layout.key_valid)
    missing = layout.missing_frame - layout.key_frame[0]
    shift = jnp.asarray([312.5, -47.25, 1030.0], jnp.float32)
    moved = keys._replace(pos=keys.pos + shift)
    for label in ("last-interpolation", "last-last"):
        m = models[label]
        out = m.apply(m.trained, keys, missing, layout.gap)
        out_moved = m.apply(m.trained, moved, missing, layout.gap)
        np.testing.assert_allclose(out_moved.missing_pos, out.missing_pos + shift, atol=2e-3)
        np.testing.assert_allclose(out_moved.key_pos, out.key_pos + shift, atol=2e-3)
        assert np.abs(out.missing_pos - dance[layout.missing_frame]).max() > 1.0  # the head does move the output
    m = models["none-none"]
    out = m.apply(m.trained, keys, missing, layout.gap)
    out_moved = m.apply(m.trained, moved, missing, layout.gap)
    assert np.abs(out_moved.missing_pos - (out.missing_pos + shift)).max() > 1.0


def test_padding_and_unread_frames_cannot_change_the_prediction(models):
    m = models["last-interpolation"]
    dance = jnp.asarray(synthetic_dance(64, seed=4), jnp.float32)
    layout = example_layout(jnp.int32(14), jnp.int32(2), N_PAST, MAX_GAP, PERIOD)
    frames, missing = layout.key_frame - 2, layout.missing_frame - 2
    keys = KeyPositions(dance[layout.key_frame], frames, layout.key_valid)
    out = m.apply(m.trained, keys, missing, layout.gap)
    # Padding key slots hold NaN: neither attended to nor read.
    poisoned = keys._replace(pos=jnp.where(layout.key_valid[:, None, None], keys.pos, jnp.nan))
    out2 = m.apply(m.trained, poisoned, missing, layout.gap)
    valid_keys = np.asarray(layout.key_valid)
    np.testing.assert_array_equal(out2.missing_pos, out.missing_pos)
    np.testing.assert_array_equal(out2.key_pos[valid_keys], out.key_pos[valid_keys])
    # The exact layout (valid slots only) predicts the same missing frames.
    n = int(layout.gap)
    exact_keys = KeyPositions(keys.pos[valid_keys], frames[valid_keys], jnp.ones(int(valid_keys.sum()), bool))
    exact = m.apply(m.trained, exact_keys, missing[:n], layout.gap)
    np.testing.assert_allclose(exact.missing_pos, out.missing_pos[:n], atol=1e-3)


# --------------------------------------------------------------------------- training


def test_training_lowers_the_loss():
    """A tiny No/No model (it starts far from the data) on synthetic windows, mixed layouts."""
    config = DeltaConfig(representation="positions", num_points=P, n_past=N_PAST, num_blocks=1, dropout=0.1,
                         input_delta="none", output_delta="none", **{k: v for k, v in SIZES.items() if k != "num_blocks"})  # fmt: skip
    train = DeltaTrainConfig(batch_size=8, learning_rate=3e-3, warmup_steps=2, decay_every=1000, min_gap=4,
                             keyframe_period=PERIOD, infill_probability=0.5)  # fmt: skip
    data = DeltaPositionArrays(jnp.asarray(np.stack([synthetic_dance(64, seed) for seed in range(6)]), jnp.float32))
    graphdef, state0 = init_delta_train_states(config, train, [0])
    jitted = compile_train_step(make_delta_train_step(graphdef, config, train, window_frames=64), num_seeds=1)
    eval_keys = jax.random.split(jax.random.key(100), 3)

    def eval_loss(state):
        return np.mean([jitted(dataclasses.replace(state, key=k[None]), data)[1]["loss"] for k in eval_keys])

    before = eval_loss(state0)
    state, history = run_delta_training(jitted, state0, data, num_steps=40, progress=False, log_every=20)
    after = eval_loss(state)
    assert [h["step"] for h in history] == [20, 40] and set(history[0]) >= {"pos", "rec_pos", "loss"}
    assert "quat" not in history[0]
    assert after < 0.5 * before, f"loss {before:.1f} → {after:.1f}"
    assert jitted._cache_size() == 1  # every gap length and layout ran in the one compiled shape
    wrong = DeltaArrays(jnp.zeros((1, 64, 22, 4)), jnp.zeros((1, 64, 3)), jnp.zeros((1, 22, 3)))
    with pytest.raises(ValueError, match="a 'positions' model trains on DeltaPositionArrays, got DeltaArrays"):
        jitted(state0, wrong)


# ------------------------------------------------------------------------- experiment


def write_synthetic_anidance(folder: Path) -> Path:
    """A miniature Anidance folder (``split.json`` + ``dances/``) with one absent entry."""
    (folder / "dances").mkdir(parents=True)
    split = {"training_files": ["dances/dance_a_1.csv", "dances/dance_a_2.csv"],
             "validation_files": ["dances/dance_b_1.csv", "dances/dance_b_9.csv"]}  # fmt: skip
    (folder / "split.json").write_text(json.dumps(split))
    header = ",".join(COLUMNS)
    for seed, (name, frames) in enumerate((("dance_a_1", 260), ("dance_a_2", 200), ("dance_b_1", 260))):
        rows = synthetic_dance(frames, seed).reshape(frames, -1)
        (folder / "dances" / f"{name}.csv").write_text(header + "\n" + "\n".join(",".join(f"{v:.4f}" for v in r) for r in rows) + "\n")
    return folder


def test_experiment_end_to_end_untrained_is_lerp_and_resumes(tmp_path, monkeypatch):
    """The experiment on a synthetic corpus with ``--steps 0`` (no compile of a training
    step; training is tested above): the untrained Δ-interpolator scores exactly as LERP
    under both protocols, chunked evaluation included; the rerun restores its checkpoint,
    and a run directory with other settings is refused."""
    monkeypatch.syspath_prepend(str(REPO_ROOT / "experiments"))  # the script imports _delta and _common from its folder
    path = REPO_ROOT / "experiments" / "delta_anidance.py"
    spec = importlib.util.spec_from_file_location("_under_test_delta_anidance", path)
    experiment = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(experiment)
    out = tmp_path / "anidance.json"
    args = ["--out", str(out), "--data", str(write_synthetic_anidance(tmp_path / "anidance")), "--config", "tiny",
            "--modes", "main", "--steps", "0", "--eval-batch", "2", "--lengths", "15", "--run-dir", str(tmp_path / "run"),
            "--no-cache", "--no-progress"]  # fmt: skip
    results = experiment.main(args)
    saved = json.loads(out.read_text())
    assert saved["missing_files"] == ["dances/dance_b_9.csv"] and saved["n_windows"] == 3
    assert saved["training"]["train_windows"] == 5 and saved["training"]["schedule"]["keyframe_period"] == 6
    assert saved["model"]["representation"] == "positions" and saved["model"]["params"] > 0
    entry = saved["delta"]["last-interpolation"]
    for protocol in ("gap", "infill"):
        assert entry[protocol]["mean"] == pytest.approx(saved["baselines"][protocol]["interp"], rel=1e-5)
    assert saved["baselines"]["infill"]["interp"]["15"] < saved["baselines"]["gap"]["interp"]["15"]
    report = out.with_suffix(".md").read_text()
    assert "Δ-Interpolator (ours)" in report and "in-filling (key frames every 6 frames" in report and "dance_b_9" in report
    store = CheckpointStore(tmp_path / "run" / "last-interpolation-mixed-world" / "checkpoints")
    assert store.latest_step() == 0 and store.config()["model"]["num_points"] == 24
    store.close()
    again = experiment.main(args)
    assert again["delta"]["last-interpolation"]["history"] == []
    assert again["delta"]["last-interpolation"]["gap"] == results["delta"]["last-interpolation"]["gap"]
    with pytest.raises(ValueError, match="holds a run with other settings \\(train.learning_rate: 0.0002 → 0.001\\)"):
        experiment.main([*args, "--learning-rate", "1e-3"])


# ------------------------------------------------------------------------- real data


@requires_shared
def test_real_anidance_baselines():
    """The two baselines on the archive's 143 validation windows (49 of the 61 files: not
    the paper's numbers, which Table 7 gives as 2.44/5.15/6.89 and 0.94/3.06/4.84)."""
    archive = SHARED_DATA / "anidance" / "anidance.tar.xz"
    with pytest.warns(UserWarning, match="absent and were dropped"):
        bench = anidance_benchmark(archive)
    assert bench.num_windows == 143 and len(bench.missing_files) == 12
    results = evaluate_anidance_baselines(bench)
    expected = {
        "gap": {"zerov": (3.103, 6.104, 7.604), "interp": (1.333, 3.898, 5.705)},
        "infill": {"zerov": (3.103, 3.215, 3.445), "interp": (1.333, 1.408, 1.530)},
    }
    for protocol, rows in expected.items():
        for name, values in rows.items():
            got = [results[protocol][name][n] for n in ("5", "15", "30")]
            np.testing.assert_allclose(got, values, atol=6e-4, err_msg=f"{protocol} {name}")
