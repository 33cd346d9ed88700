"""Damaged checkpoints and saved models are found, never used: checkpoints fall back to the
newest one that passes its checksums and is finite, saved models refuse to load."""

from __future__ import annotations

import shutil
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from bezmotion._src.checksums import CHECKSUM_FILE, ChecksumError
from bezmotion.assets import BUNDLED_IK
from bezmotion.bmm.denoiser import init_denoiser
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, load_model, save_model
from bezmotion.ik.protores import ProtoResConfig, ProtoResModel, init_protores, load_ik_model, save_ik_model
from bezmotion.training import checkpoint
from bezmotion.training import CheckpointStore, TrainState, apply_gradients, compile_train_step, run_training

from bmm.common import TINY
from helpers import load_experiment

OPTIMIZER = optax.adam(0.05)


def toy_step(state: TrainState, target):
    key, _ = jax.random.split(state.key)
    loss_fn = lambda params, goal: (jnp.mean((params["w"] - goal) ** 2), {})  # noqa: E731
    return apply_gradients(state, OPTIMIZER, loss_fn, target, next_key=key)


def toy_state(fill: float = 0.0) -> TrainState:
    params = {"w": jnp.full((8, 8), fill)}
    state = TrainState(params, OPTIMIZER.init(params), None, jnp.zeros((), jnp.int32), jax.random.key(0))
    return jax.device_put(state, jax.devices()[0])


def at_step(state: TrainState, step: int) -> TrainState:
    return TrainState(state.params, state.opt_state, state.ema, jnp.asarray(step, jnp.int32), state.key)



_benchmark = load_experiment("corruption", "benchmarks")
damage, data_file = _benchmark.damage, _benchmark.data_file  # the benchmark's: one definition of each kind of damage


def flip_bit(path, bit: int) -> None:
    data = bytearray(path.read_bytes())
    data[(bit // 8) % len(data)] ^= 1 << (bit % 8)
    path.write_bytes(bytes(data))


def step_value(state: TrainState) -> int:
    return int(state.step)


# ------------------------------------------------------------------------ checkpoints


@pytest.mark.parametrize("how", ["flip", "truncate", "delete", "zero"])
def test_a_damaged_latest_checkpoint_falls_back_to_the_one_before(tmp_path, how):
    store = CheckpointStore(tmp_path / "run")
    store.save(10, at_step(toy_state(1.0), 10))
    store.save(20, at_step(toy_state(2.0), 20))
    damage(data_file(tmp_path / "run" / "20"), how)
    with pytest.warns(UserWarning) as caught:
        restored = store.restore(toy_state())
    (message,) = [str(w.message) for w in caught]
    assert "\n" not in message and message.startswith("checkpoint 20 (")
    assert message.endswith(f"in {tmp_path / 'run'} is unusable; renamed it 20.corrupt; restored checkpoint 10 instead")
    assert step_value(restored) == 10 and float(restored.params["w"][0, 0]) == 1.0
    # The damaged one is kept aside, out of orbax's sight; step 20 can be saved again.
    assert store.latest_step() == 10 and (tmp_path / "run" / "20.corrupt").is_dir()
    store.save(20, at_step(toy_state(3.0), 20))
    assert float(store.restore(toy_state()).params["w"][0, 0]) == 3.0
    store.close()


def test_the_training_loop_resumes_from_the_checkpoint_before_a_damaged_one(tmp_path):
    step = compile_train_step(toy_step, num_seeds=None)
    target = jnp.ones((8, 8))
    straight, _ = run_training(step, toy_state(), target, num_steps=6, progress=False)
    store = CheckpointStore(tmp_path / "run")
    run_training(step, toy_state(), target, num_steps=4, store=store, checkpoint_every=2, progress=False)
    damage(data_file(tmp_path / "run" / "4"), "flip")
    with pytest.warns(UserWarning, match=r"checkpoint 4 \(.*differs from its sha256\) .* restored checkpoint 2 instead"):
        resumed, _ = run_training(step, toy_state(), target, num_steps=6, store=store, checkpoint_every=2, progress=False)
    np.testing.assert_array_equal(resumed.params["w"], straight.params["w"])  # trained on from step 2, as if never damaged
    assert store.latest_step() == 6
    store.close()


def test_with_every_checkpoint_damaged_restore_stops_naming_the_folder(tmp_path):
    store = CheckpointStore(tmp_path / "run")
    for step in (10, 20):
        store.save(step, at_step(toy_state(), step))
        damage(data_file(tmp_path / "run" / str(step)), "zero")
    with pytest.raises(ValueError) as error:
        store.restore(toy_state())
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"no usable checkpoint in {tmp_path / 'run'}: 20 (")
    assert "; 10 (" in message and "bytes" in message
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["10", "20"]  # nothing renamed: nothing to resume from
    store.close()


@pytest.fixture
def saves_non_finite(monkeypatch):
    """Saving lets NaN through, as a store written before saves refused it would hold."""
    monkeypatch.setattr(checkpoint, "non_finite_leaves", lambda tree: [])


def test_a_checkpoint_holding_nan_is_refused_though_its_checksums_match(tmp_path, saves_non_finite):
    store = CheckpointStore(tmp_path / "run")
    store.save(10, at_step(toy_state(1.0), 10))
    store.save(20, at_step(toy_state(jnp.nan), 20))
    with pytest.raises(ValueError, match=r"checkpoint 20 in .* is unusable: NaN or inf in \.params\['w'\]"):
        store.restore(toy_state(), step=20)
    with pytest.warns(UserWarning, match=r"checkpoint 20 \(NaN or inf in \.params\['w'\].*\) in .* restored checkpoint 10 instead"):
        assert step_value(store.restore(toy_state())) == 10
    store.close()


def test_checkpoints_saved_before_checksums_restore_with_a_warning(tmp_path):
    store = CheckpointStore(tmp_path / "run")
    store.save(10, at_step(toy_state(1.0), 10))
    (tmp_path / "run" / "10" / CHECKSUM_FILE).unlink()
    with pytest.warns(UserWarning, match=rf"checkpoint 10 in .* has no {CHECKSUM_FILE} .*: restoring it unverified"):
        assert step_value(store.restore(toy_state())) == 10
    # Without them after one that has them, a save was cut short: refused.
    store.save(20, at_step(toy_state(2.0), 20))
    store.save(30, at_step(toy_state(3.0), 30))
    (tmp_path / "run" / "30" / CHECKSUM_FILE).unlink()
    with pytest.warns(UserWarning, match=rf"checkpoint 30 \(no {CHECKSUM_FILE}: its save was cut short\)"):
        assert step_value(store.restore(toy_state())) == 20
    store.close()


# ------------------------------------------------------------------------------ models


def tiny_bmm(fill: float | None = None) -> BezierMotionModel:
    graphdef, params = init_denoiser(TINY, key=jax.random.key(0))
    if fill is not None:
        params = jax.tree.map(lambda x: jnp.full_like(x, fill), params)
    j = TINY.num_joints
    return BezierMotionModel(params, FeatureStats(jnp.zeros((j, 12)), jnp.ones((j, 12))), graphdef, TINY)


@pytest.fixture(scope="module")
def saved_bmm(tmp_path_factory):
    folder = tmp_path_factory.mktemp("models") / "bmm"
    save_model(folder, tiny_bmm())
    return folder


def test_a_saved_model_carries_checksums_and_loads_verified(saved_bmm):
    assert (saved_bmm / CHECKSUM_FILE).is_file()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # verified: no warning
        loaded = load_model(saved_bmm)
    jax.tree.map(np.testing.assert_array_equal, loaded.params, tiny_bmm().params)


@pytest.mark.parametrize("victim", ["data", "config.json", CHECKSUM_FILE, "0/_CHECKPOINT_METADATA"])
def test_one_flipped_bit_in_a_saved_model_is_refused(saved_bmm, tmp_path, victim):
    folder = tmp_path / "bmm"
    shutil.copytree(saved_bmm, folder)
    path = data_file(folder) if victim == "data" else folder / victim
    flip_bit(path, 8 * path.stat().st_size // 2 + 3)
    with pytest.raises(ChecksumError) as error:
        load_model(folder)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{folder}: ")
    if victim != CHECKSUM_FILE:  # a flip there damages the list or one of its digests, whichever it lands in
        assert path.relative_to(folder).as_posix() in message


def test_a_model_without_checksums_loads_only_unverified(saved_bmm, tmp_path):
    folder = tmp_path / "bmm"
    shutil.copytree(saved_bmm, folder)
    (folder / CHECKSUM_FILE).unlink()
    with pytest.raises(ChecksumError, match=rf"{folder}: no {CHECKSUM_FILE} .*load it with verify=False"):
        load_model(folder)
    with pytest.warns(UserWarning, match=rf"{folder}: loading the saved BMM unverified \(verify=False\)"):
        load_model(folder, verify=False)


def test_a_model_with_non_finite_weights_is_not_saved(tmp_path):
    with pytest.raises(ValueError, match=r"checkpoint 0 not saved to .*: the state holds NaN or inf in \['params'\]"):
        save_model(tmp_path / "bmm", tiny_bmm(fill=np.inf))
    assert not (tmp_path / "bmm").exists()


def test_non_finite_weights_are_refused_naming_the_folder_and_the_weights(tmp_path, saves_non_finite):
    save_model(tmp_path / "bmm", tiny_bmm(fill=np.inf))
    with pytest.raises(ValueError, match=rf"checkpoint 0 in {tmp_path / 'bmm'} is unusable: NaN or inf in \['params'\]"):
        load_model(tmp_path / "bmm")
    character = load_ik_model(BUNDLED_IK).character
    config = ProtoResConfig.tiny(character.num_joints)
    graphdef, params = init_protores(config, key=jax.random.key(0))
    nan = jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), params)
    save_ik_model(tmp_path / "ik", ProtoResModel(nan, character, graphdef, config))
    with pytest.raises(ValueError, match=rf"checkpoint 0 in {tmp_path / 'ik'} is unusable: NaN or inf in \['params'\]"):
        load_ik_model(tmp_path / "ik")
    # The same model with finite weights loads, verified.
    save_ik_model(tmp_path / "ik", ProtoResModel(params, character, graphdef, config))
    assert load_ik_model(tmp_path / "ik").config == config


def test_a_checksum_list_not_exactly_as_written_is_damaged(saved_bmm, tmp_path):
    folder = tmp_path / "bmm"
    shutil.copytree(saved_bmm, folder)
    listing = folder / CHECKSUM_FILE
    listing.write_text(listing.read_text().replace('"format"', ' "format"', 1))  # still JSON, but not as written
    with pytest.raises(ChecksumError, match=rf"{folder}: {CHECKSUM_FILE} is damaged"):
        load_model(folder)


def test_a_diverged_state_is_never_saved(tmp_path):
    store = CheckpointStore(tmp_path / "run")
    store.save(10, at_step(toy_state(1.0), 10))
    with pytest.raises(ValueError, match=r"checkpoint 20 not saved to .*: the state holds NaN or inf in .*'w'.*checkpoint 10 is the newest kept"):
        store.save(20, at_step(toy_state(float("nan")), 20))
    assert store.steps() == [10]
    assert step_value(store.restore(toy_state())) == 10
