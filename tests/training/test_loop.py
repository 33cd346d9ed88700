"""The training loop (``bezmotion.training.loop.run_training``) and the resume guard
(``CheckpointStore.check_resumable``) on a model-free toy: a noisy quadratic whose
noise is drawn from ``state.key``, so the run depends on its key like a real one.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from bezmotion.training import CheckpointStore, TrainState, apply_gradients, compile_train_step, run_training, save_model_folder

OPTIMIZER = optax.adam(0.05)
TARGET = jnp.asarray([1.0, -1.0, 0.5, 2.0])


def toy_step(state: TrainState, target):
    """Pull ``w`` towards ``target`` plus noise drawn from the state's key (with an EMA)."""
    key, noise_key = jax.random.split(state.key)
    noisy = target + 0.1 * jax.random.normal(noise_key, target.shape)

    def loss_fn(params, goal):
        return jnp.mean((params["w"] - goal) ** 2), {"w0": params["w"][0]}

    return apply_gradients(state, OPTIMIZER, loss_fn, noisy, next_key=key, ema_decay=0.9)


def toy_state(seed: int) -> TrainState:
    params = {"w": jnp.zeros(4)}
    # Restored checkpoints are committed to the device; so is the fresh state (one compilation).
    state = TrainState(params, OPTIMIZER.init(params), params, jnp.zeros((), jnp.int32), jax.random.key(seed))
    return jax.device_put(state, jax.devices()[0])


@pytest.fixture(scope="module")
def step():
    return compile_train_step(toy_step, num_seeds=None)


def leaves(state: TrainState) -> list[np.ndarray]:
    return [np.asarray(jax.random.key_data(x) if jnp.issubdtype(x.dtype, jax.dtypes.prng_key) else x) for x in jax.tree.leaves(state)]


def assert_identical(a: TrainState, b: TrainState) -> None:
    for x, y in zip(leaves(a), leaves(b), strict=True):
        np.testing.assert_array_equal(x, y)


def test_progress_fn_sees_every_logged_step_after_its_checkpoint(step, tmp_path):
    store = CheckpointStore(tmp_path / "run")
    calls = []

    def progress_fn(done, record):
        # Called after that step's periodic checkpoint: the store already holds it.
        calls.append((done, dict(record), store.latest_step()))

    _, history = run_training(
        step, toy_state(0), TARGET, num_steps=7, store=store, checkpoint_every=4, progress=False, log_every=2, progress_fn=progress_fn
    )  # fmt: skip
    assert [c[0] for c in calls] == [2, 4, 6, 7] == [h["step"] for h in history]
    assert [c[1] for c in calls] == history
    assert [c[2] for c in calls] == [None, 4, 4, 4]  # step 7's final checkpoint comes after the last call
    assert store.latest_step() == 7
    assert set(history[0]) == {"step", "steps_per_s", "loss", "grad_norm", "w0"}
    # Resumed from step 7 to 10: the calls continue from there.
    calls.clear()
    run_training(step, toy_state(5), TARGET, num_steps=10, store=store, progress=False, log_every=2, progress_fn=progress_fn)
    assert [c[0] for c in calls] == [8, 10]
    store.close()


def test_resume_is_bit_identical_to_a_straight_run(step, tmp_path):
    straight, straight_history = run_training(step, toy_state(0), TARGET, num_steps=6, progress=False, log_every=1)
    store = CheckpointStore(tmp_path / "run")
    config = {"train": {"learning_rate": 0.05}}
    half, _ = run_training(step, toy_state(0), TARGET, num_steps=3, store=store, config=config, progress=False)
    assert int(half.step) == 3 and store.latest_step() == 3
    store.check_resumable(config)
    # A new process: another seed's fresh state, replaced by the checkpoint.
    resumed, history = run_training(step, toy_state(7), TARGET, num_steps=6, store=store, config=config, progress=False, log_every=1)
    assert_identical(resumed, straight)
    assert [h["step"] for h in history] == [4, 5, 6]
    assert [h["loss"] for h in history] == [h["loss"] for h in straight_history[3:]]
    store.close()
    assert step._cache_size() == 1  # the restored state reuses the compiled step


def test_a_passed_deadline_stops_after_one_step_and_the_run_goes_on_from_there(step, tmp_path):
    """A wall-clock budget (``deadline``) ends training at a step boundary with a checkpoint;
    the same run started again without one finishes as a straight run would."""
    straight, _ = run_training(step, toy_state(0), TARGET, num_steps=6, progress=False)
    store = CheckpointStore(tmp_path / "run")
    stopped, history = run_training(
        step, toy_state(0), TARGET, num_steps=6, store=store, checkpoint_every=100, progress=False, deadline=time.monotonic() - 1.0
    )  # fmt: skip
    assert int(stopped.step) == 1 and store.latest_step() == 1
    assert [h["step"] for h in history] == [1]  # the step it stopped at is logged
    resumed, _ = run_training(step, toy_state(7), TARGET, num_steps=6, store=store, progress=False)
    assert_identical(resumed, straight)
    store.close()


def test_the_resume_guard_names_every_differing_setting(tmp_path):
    store = CheckpointStore(tmp_path / "run")
    config = {"model": {"width": 32, "sizes": (1, 2)}, "train": {"learning_rate": 0.001, "seeds": [0]}}
    store.check_resumable({"anything": 1})  # nothing to resume yet: any configuration passes
    store.save(3, toy_state(0), config)
    store.check_resumable(config)  # the same settings (tuples saved as lists) pass
    other = {"model": {"width": 32, "sizes": [1, 2]}, "train": {"learning_rate": 0.002, "seeds": [0], "warmup": 5}}
    with pytest.raises(ValueError, match="holds a run with other settings") as error:
        store.check_resumable(other)
    message = str(error.value)
    assert str(store.directory) in message
    assert "train.learning_rate: 0.001 → 0.002" in message and "train.warmup: (absent) → 5" in message
    assert "model" not in message.split("(", 1)[1]  # unchanged sections are not reported
    store.close()


def test_an_extendable_setting_may_grow_but_not_shrink(tmp_path):
    store = CheckpointStore(tmp_path / "run")
    config = {"train": {"learning_rate": 0.001, "num_steps": 600}}
    store.save(3, toy_state(0), config)
    longer = {"train": {"learning_rate": 0.001, "num_steps": 2400}}
    store.check_resumable(longer, extendable=("train.num_steps",))  # going on training
    with pytest.raises(ValueError, match=r"train.num_steps: 600 → 2400"):
        store.check_resumable(longer)  # not extendable unless the trainer says so
    with pytest.raises(ValueError, match=r"train.num_steps: 600 → 300"):
        store.check_resumable({"train": {"learning_rate": 0.001, "num_steps": 300}}, extendable=("train.num_steps",))
    with pytest.raises(ValueError, match=r"train.learning_rate"):
        store.check_resumable({"train": {"learning_rate": 0.002, "num_steps": 2400}}, extendable=("train.num_steps",))
    store.close()


def test_saving_a_model_over_an_old_one_replaces_it(tmp_path):
    """A retrained model saved into the folder of an earlier one must replace its parameters
    (a store alone skips a step it holds) and leave no staging folders behind."""
    folder = tmp_path / "model"
    save_model_folder(folder, toy_state(0), {"version": 1})
    save_model_folder(folder, toy_state(7), {"version": 2})
    store = CheckpointStore(folder, read_only=True)
    assert_identical(store.restore(toy_state(0)), toy_state(7))
    assert store.config() == {"version": 2}
    store.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]
