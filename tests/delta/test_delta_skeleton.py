"""The Δ-interpolator on a skeleton other than LaFAN1's: the bundled Bandai-Namco clip.

The clip (40 frames, 22 joints rooted at ``joint_Root``) has as many joints as LaFAN1
but another hierarchy, so only the parents tell the two apart: the model must take them
from its config and refuse a skeleton of another topology.
"""

from __future__ import annotations

import dataclasses
import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import leaves

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.data.bvh_folder import load_bvh_folder
from bezmotion.data.corpus_windows import motion_windows
from bezmotion.data.lafan1 import PARENTS as LAFAN1_PARENTS
from bezmotion.delta.model import DeltaConfig, KeyFrames, apply_delta, delta_inbetweener, init_delta
from bezmotion.delta.train import (
    DeltaArrays,
    DeltaTrainConfig,
    init_delta_train_state,
    init_delta_train_states,
    make_delta_train_step,
    run_delta_training,
)
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.training import compile_train_step

N_PAST, WINDOW = 3, 20
SIZES = {"n_past": N_PAST, "width": 16, "num_blocks": 1, "num_heads": 2, "mlp_layers": 2, "embedding_dim": 4, "max_frames": WINDOW}


@pytest.fixture(scope="module")
def clip():
    motion = read_bvh(DEMO_CLIP)
    assert motion.skeleton.parents != LAFAN1_PARENTS and motion.skeleton.num_joints == len(LAFAN1_PARENTS)
    return motion


def test_config_keeps_the_skeleton_and_reads_back_from_json(clip):
    config = DeltaConfig(parents=clip.skeleton.parents, **SIZES)
    assert config.num_joints == clip.skeleton.num_joints
    saved = json.loads(json.dumps(dataclasses.asdict(config)))  # as a checkpoint's config.json holds it
    assert DeltaConfig.from_dict(saved) == config
    with pytest.raises(ValueError, match="parents is required for the rotations representation"):
        DeltaConfig(**SIZES)
    with pytest.raises(ValueError, match="parents=\\(-1, 0\\) is only for the rotations representation"):
        DeltaConfig(parents=(-1, 0), representation="positions", num_points=2, **SIZES)


def test_trains_and_inbetweens_on_the_bandai_namco_clip(clip, tmp_path):
    # The clip as a user's BVH folder, windowed like LaFAN1 through the corpus interface:
    # the hips' motion (on Hips' position channels below a static joint_Root) is on joint 0.
    shutil.copy(DEMO_CLIP, tmp_path / "walk.bvh")
    corpus = load_bvh_folder(tmp_path, characteristic="bandai_namco", validation_every=None, use_cache=False, progress=False)
    windows = motion_windows(corpus, "train", window=WINDOW, offset=10, facing_frame=N_PAST - 1, forward_axis=(0.0, 0.0, 1.0))
    skeleton, starts = windows.skeleton(0), windows.start_frame
    assert skeleton.parents == clip.skeleton.parents
    data = DeltaArrays.from_windows(windows)
    config = DeltaConfig(parents=skeleton.parents, **SIZES)
    train = DeltaTrainConfig(batch_size=4, learning_rate=1e-3, warmup_steps=0, decay_every=100, min_gap=2, max_gap=8)
    graphdef, state0 = init_delta_train_states(config, train, [0])
    step = compile_train_step(make_delta_train_step(graphdef, config, train, window_frames=WINDOW), num_seeds=1)
    state, history = run_delta_training(step, state0, data, num_steps=3, progress=False, log_every=1)
    assert [h["step"] for h in history] == [1, 2, 3]
    assert all(np.isfinite(h["loss"]) and h["loss"] > 0 for h in history)
    assert any(not np.array_equal(a, b) for a, b in zip(leaves(state.params), leaves(state0.params), strict=True))

    params = jax.tree.map(lambda x: x[0], state.params)
    inbetween = jax.jit(delta_inbetweener(graphdef, params, skeleton), static_argnums=4)
    n = 5
    quat, root = inbetween(data.quat_local[:, :N_PAST], data.root_pos[:, :N_PAST], data.quat_local[:, N_PAST + n], data.root_pos[:, N_PAST + n], n)
    assert quat.shape == (len(starts), n, skeleton.num_joints, 4) and root.shape == (len(starts), n, 3)
    assert np.all(np.isfinite(quat)) and np.all(np.isfinite(root))


def test_a_skeleton_of_other_parents_is_refused(clip):
    bandai = clip.skeleton
    graphdef, params = init_delta(DeltaConfig(parents=LAFAN1_PARENTS, **SIZES), key=jax.random.key(0))
    # Same joint count, other hierarchy: only the parents tell them apart.
    with pytest.raises(ValueError, match="the skeleton's parents .* differ from the model's DeltaConfig.parents"):
        delta_inbetweener(graphdef, params, bandai)
    # A skeleton of another size: its offsets do not fit the model's joints.
    small = Skeleton((-1, 0, 1), ("a", "b", "c"), jnp.ones((3, 3)))
    frame = jnp.arange(N_PAST + 1, dtype=jnp.int32)
    keys = KeyFrames(jnp.ones((N_PAST + 1, 3, 4)), jnp.zeros((N_PAST + 1, 3)), frame, jnp.ones(N_PAST + 1, bool))
    with pytest.raises(ValueError, match="do not fit the model's 22-joint skeleton \\(DeltaConfig.parents\\)"):
        apply_delta(graphdef, params, small.offsets, keys, jnp.asarray([N_PAST + 1]), jnp.int32(1))
    config, train = DeltaConfig(parents=LAFAN1_PARENTS, **SIZES), DeltaTrainConfig(batch_size=2, min_gap=2, max_gap=4)
    graphdef, state = init_delta_train_state(config, train, key=jax.random.key(0))
    step = make_delta_train_step(graphdef, config, train, window_frames=WINDOW)
    wrong = DeltaArrays(jnp.ones((2, WINDOW, 3, 4)), jnp.zeros((2, WINDOW, 3)), jnp.ones((2, 3, 3)))
    with pytest.raises(ValueError, match="do not fit the model's 22 joints \\(DeltaConfig.parents\\)"):
        step(state, wrong)
    wrong = DeltaArrays(jnp.ones((2, WINDOW, 22, 4)), jnp.zeros((2, WINDOW, 3)), jnp.ones((2, 3, 3)))
    with pytest.raises(ValueError, match="offsets of shape \\(2, 3, 3\\) do not fit the model's 22-joint skeleton"):
        step(state, wrong)
