"""Training the BMM (``bezmotion.bmm.train`` through ``bezmotion.training``): the config,
the step, the loss going down, checkpoint resume, Ctrl-C and SIGTERM, and vmapped seeds.

The tiny model's compiled training step lives in a module-scoped fixture shared by the tests.
"""

from __future__ import annotations

import dataclasses
import os
import signal
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import assert_trees_close, assert_trees_identical, trees_differ, without_key_bias
from bmm.common import TINY

from bezmotion.bmm.train import (
    BMMTrainConfig,
    CurveArrays,
    init_bmm_train_state,
    init_bmm_train_states,
    make_bmm_train_step,
)
from bezmotion.training import compile_train_step, data_mesh, run_training
from bezmotion.training.checkpoint import CheckpointStore


TRAIN = BMMTrainConfig(batch_size=8, learning_rate=1e-3, ema_decay=0.9)


def committed(step):
    """Run a compiled step on device-committed states. States restored by orbax are
    committed; without this, the first step on one would compile the step a second time."""
    device = jax.devices()[0]
    return lambda state, data: step(jax.device_put(state, device), data)


@pytest.fixture(scope="module")
def kit(demo_dataset, stats) -> SimpleNamespace:
    """The tiny model's compiled training step on the DEMO_CLIP curves (compiled once)."""
    assert len(demo_dataset) == 10
    graphdef, state0 = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(0))
    step_fn = make_bmm_train_step(graphdef, TINY, TRAIN, stats)
    step = committed(compile_train_step(step_fn, num_seeds=None))
    data = CurveArrays.from_dataset(demo_dataset)
    return SimpleNamespace(graphdef=graphdef, state0=state0, step_fn=step_fn, step=step, data=data)


@pytest.fixture(scope="module")
def trajectory(kit) -> list:
    """``states[k]``: the state after k steps from ``kit.state0``, by calling the step by hand."""
    states = [kit.state0]
    for _ in range(6):
        states.append(kit.step(states[-1], kit.data)[0])
    return states


def test_train_config_validation():
    for bad in ({"batch_size": 0}, {"learning_rate": 0.0}, {"weight_decay": -1.0}, {"condition_dropout": 1.0}, {"ema_decay": 1.0}):
        with pytest.raises(ValueError):
            BMMTrainConfig(**bad)
    assert BMMTrainConfig().learning_rate == 1e-4 and BMMTrainConfig().batch_size == 64 and BMMTrainConfig().min_snr_gamma == 5.0


def test_data_mesh_is_none_on_one_device():
    n = len(jax.local_devices())
    mesh = data_mesh()
    if n == 1:
        assert mesh is None
    else:  # e.g. under XLA_FLAGS=--xla_force_host_platform_device_count=2
        assert mesh.axis_names == ("data",) and mesh.devices.size == n


def test_train_step_updates_everything_consistently(kit, trajectory):
    s0, s1 = trajectory[0], trajectory[1]
    assert int(s1.step) == 1 and int(s0.step) == 0
    assert trees_differ(s1.params, s0.params) and trees_differ([s1.key], [s0.key])
    assert_trees_close(s1.ema, jax.tree.map(lambda e, p: 0.9 * e + 0.1 * p, s0.ema, s1.params), tol=1e-6)
    _, metrics = kit.step(s0, kit.data)
    names = {"loss", "grad_norm", "position", "tangent", "orientation", "velocity", "dense_position", "condition", "contact", "skate"}
    assert set(metrics) == names
    assert all(np.isfinite(float(v)) for v in metrics.values())
    # Pure: the same state gives the same next state, bit for bit.
    assert_trees_identical(kit.step(s0, kit.data)[0], s1)


def test_training_lowers_the_loss(kit):
    """60 steps of the tiny model on the real curves: the loss on fixed batches/noise drops."""
    eval_keys = [jax.random.key(100 + i) for i in range(4)]

    def eval_loss(state):
        return np.mean([float(kit.step(dataclasses.replace(state, key=k), kit.data)[1]["loss"]) for k in eval_keys])

    before = eval_loss(kit.state0)
    state, history = run_training(kit.step, kit.state0, kit.data, num_steps=60, progress=False, log_every=10)
    after = eval_loss(state)
    assert int(state.step) == 60
    assert [h["step"] for h in history] == [10, 20, 30, 40, 50, 60]
    assert all(np.isfinite(v) for h in history for v in h.values())
    assert after < 0.5 * before, f"loss {before:.4f} → {after:.4f}"


def test_checkpoint_resume_is_bit_identical(kit, trajectory, tmp_path):
    # Half the run (a periodic checkpoint at 2, the final one at 3) ...
    config = {"model": dataclasses.asdict(TINY), "note": "resume"}
    store = CheckpointStore(tmp_path / "resume")
    half, history = run_training(
        kit.step, kit.state0, kit.data, num_steps=3, store=store, checkpoint_every=2, config=config, progress=False, log_every=1
    )
    assert_trees_identical(half, trajectory[3])
    assert [h["step"] for h in history] == [1, 2, 3]
    assert store.latest_step() == 3 and store.config() == config
    fresh = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(99))[1]  # another seed: restore must replace it all
    assert_trees_identical(store.restore(fresh, step=2), trajectory[2])
    restored = store.restore(fresh)
    assert_trees_identical(restored, trajectory[3])
    assert jnp.issubdtype(restored.key.dtype, jax.dtypes.prng_key)
    # ... then, as a new process would, from a fresh state and the same folder, to the end.
    resumed, _ = run_training(kit.step, fresh, kit.data, num_steps=6, store=store, progress=False)
    assert_trees_identical(resumed, trajectory[6])
    assert store.latest_step() == 6
    # Already done: nothing more runs, the stored state comes back.
    again, history = run_training(kit.step, fresh, kit.data, num_steps=6, store=store, progress=False)
    assert_trees_identical(again, trajectory[6]) and history == []
    store.close()
    empty = CheckpointStore(tmp_path / "empty")
    assert empty.latest_step() is None and empty.config() is None
    with pytest.raises(FileNotFoundError):
        empty.restore(fresh)
    empty.close()


def test_ctrl_c_saves_the_held_state_and_resume_completes_identically(kit, trajectory, tmp_path):
    def interrupted_at(k):
        def step(state, data):
            if int(state.step) == k:
                raise KeyboardInterrupt
            return kit.step(state, data)

        return step

    store = CheckpointStore(tmp_path / "run")
    with pytest.raises(KeyboardInterrupt):
        run_training(interrupted_at(4), kit.state0, kit.data, num_steps=6, store=store, checkpoint_every=1000, progress=False)
    assert store.latest_step() == 4
    fresh = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(98))[1]
    assert_trees_identical(store.restore(fresh), trajectory[4])
    resumed, _ = run_training(kit.step, fresh, kit.data, num_steps=6, store=store, progress=False)
    assert_trees_identical(resumed, trajectory[6])
    store.close()


def test_sigterm_checkpoints_at_a_step_boundary_like_ctrl_c(kit, trajectory, tmp_path):
    def terminated_after(k):
        def step(state, data):
            new = kit.step(state, data)
            if int(new[0].step) == k:  # as `kill` from another shell would, mid-run
                os.kill(os.getpid(), signal.SIGTERM)
            return new

        return step

    before = signal.getsignal(signal.SIGTERM)
    store = CheckpointStore(tmp_path / "run")
    with pytest.raises(KeyboardInterrupt, match="signal"):
        run_training(terminated_after(3), kit.state0, kit.data, num_steps=6, store=store, checkpoint_every=1000, progress=False)
    assert signal.getsignal(signal.SIGTERM) == before  # the handler is gone again
    assert store.latest_step() == 3
    fresh = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(98))[1]
    resumed, _ = run_training(kit.step, fresh, kit.data, num_steps=6, store=store, progress=False)
    assert_trees_identical(resumed, trajectory[6])
    store.close()


def test_vmapped_seeds_match_single_seed_runs(kit, tmp_path):
    seeds = (5, 6)
    graphdef, stacked = init_bmm_train_states(TINY, TRAIN, list(seeds))
    assert graphdef == kit.graphdef
    vstep = committed(compile_train_step(kit.step_fn, num_seeds=len(seeds)))
    store = CheckpointStore(tmp_path / "seeds")
    multi, history = run_training(vstep, stacked, kit.data, num_steps=1, store=store, progress=False, log_every=1)
    np.testing.assert_array_equal(multi.step, [1, 1])
    _, multi_metrics = vstep(multi, kit.data)
    assert len(history) == 1 and np.isfinite(history[0]["loss"])
    singles = []
    for i, seed in enumerate(seeds):
        _, single = init_bmm_train_state(TINY, TRAIN, key=jax.random.key(seed))
        assert_trees_identical(jax.tree.map(lambda a, i=i: a[i], stacked), single)
        single, metrics = kit.step(single, kit.data)
        # One step matches to float rounding. (Not more steps: Adam's m̂/(√v̂ + ε) turns
        # rounding-level differences of gradients near ε into visible parameter differences.)
        assert_trees_close(without_key_bias(jax.tree.map(lambda a, i=i: a[i], multi)), without_key_bias(single), tol=1e-6)
        assert history[0]["loss"] != pytest.approx(float(metrics["loss"]))  # the history averages the seeds
        _, metrics = kit.step(single, kit.data)
        np.testing.assert_allclose(multi_metrics["loss"][i], metrics["loss"], rtol=1e-5)
        singles.append(single)
    assert trees_differ(singles[0].params, singles[1].params)
    np.testing.assert_allclose(history[0]["loss"], np.mean([float(s) for s in vstep(stacked, kit.data)[1]["loss"]]), rtol=1e-6)
    # The stacked state (keys included) survives a checkpoint round trip.
    assert_trees_identical(store.restore(stacked), multi)
    store.close()
    with pytest.raises(ValueError, match="seed"):
        init_bmm_train_states(TINY, TRAIN, [])
