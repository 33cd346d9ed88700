"""Rotation windows of any corpus (the Δ-interpolator's training data): the LaFAN1 protocol
reproduced through the corpus interface, and the bundled Bandai-Namco clip re-rooted at its hips."""

from __future__ import annotations

import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.data import lafan1
from bezmotion.data.anidance import AnidanceCorpus
from bezmotion.data.bvh import read_bvh
from bezmotion.data.bvh_folder import load_bvh_folder
from bezmotion.data.characteristic import SKELETON_MAPS
from bezmotion.data.corpus_windows import MotionWindows, motion_windows
from bezmotion.data.windows import facing_rotation
from bezmotion.delta.train import DeltaArrays, RotationWindows
from bezmotion.geometry.rotations import quat_conjugate, quat_rotate
from bezmotion.geometry.skeleton import forward_kinematics

BANDAI_FORWARD = (0.0, 0.0, 1.0)  # the bundled clip walks along +Z, the hips' local +Z


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))


@pytest.fixture
def bandai(tmp_path):
    """The bundled 40-frame Bandai-Namco clip as a one-file BVH folder (training split)."""
    folder = tmp_path / "clips"
    folder.mkdir()
    shutil.copy(DEMO_CLIP, folder / "walk.bvh")
    return load_bvh_folder(folder, characteristic="bandai_namco", validation_every=None, progress=False)


def test_lafan1_windows_are_the_official_ones(synthetic_zip):
    corpus = lafan1.load_lafan1(synthetic_zip)
    ours = motion_windows(corpus, "train", window=50, offset=20, facing_frame=lafan1.N_PAST - 1)
    official = lafan1.lafan1_windows(corpus, lafan1.TRAIN_SUBJECTS, 50, 20)
    assert isinstance(ours, MotionWindows) and ours.num_windows == official.num_windows == 14
    np.testing.assert_array_equal(ours.clip_index, official.file_index)
    np.testing.assert_array_equal(ours.start_frame, official.start_frame)
    np.testing.assert_allclose(ours.quat_local, official.quat_local, rtol=0, atol=1e-13)
    np.testing.assert_allclose(ours.root_pos, official.root_pos, rtol=0, atol=1e-11)
    # Offsets below the root are the files' own; row 0 is the file's root OFFSET line in
    # LaFAN1's windows and zero in ours: FK replaces it with root_pos, so the poses agree.
    np.testing.assert_array_equal(ours.offsets[:, 1:], official.offsets[:, 1:])
    np.testing.assert_array_equal(ours.offsets[:, 0], 0.0)
    with jax.enable_x64(True):
        _, pos_official = official.fk()
        _, pos_ours = forward_kinematics(
            ours.parents, jnp.asarray(ours.quat_local), jnp.asarray(ours.offsets[:, None]), root_pos=jnp.asarray(ours.root_pos)
        )
    np.testing.assert_allclose(np.asarray(pos_ours), np.asarray(pos_official), rtol=0, atol=1e-10)


def test_bandai_namco_windows_are_rooted_at_the_moving_hips(bandai):
    w = motion_windows(bandai, "train", window=20, offset=10, facing_frame=5, forward_axis=BANDAI_FORWARD)
    # 40 frames: starts 0 and 10 (20 + 20 == 40 is dropped, as LaFAN1's extractor does).
    assert w.start_frame.tolist() == [0, 10] and w.clip_index.tolist() == [0, 0]
    assert w.quat_local.shape == (2, 20, 22, 4) and w.root_pos.shape == (2, 20, 3) and w.offsets.shape == (2, 22, 3)
    assert w.parents == bandai.skeleton.parents and w.joint_names[:2] == ("joint_Root", "Hips")
    # joint_Root (static at the origin) and Hips are merged: the hips' motion is on joint 0.
    np.testing.assert_array_equal(w.quat_local[:, :, 1], np.broadcast_to([1.0, 0, 0, 0], (2, 20, 4)))
    np.testing.assert_array_equal(w.offsets[:, :2], 0.0)
    travel = np.linalg.norm(w.root_pos[:, -1, [0, 2]] - w.root_pos[:, 0, [0, 2]], axis=-1)
    assert travel.min() > 10.0 and w.root_pos[:, -1, 0].min() > w.root_pos[:, 0, 0].max()  # walks forward, along +X (cm)
    # Centred as LaFAN1's windows are: the window-mean root X and Z are zero.
    np.testing.assert_allclose(w.root_pos[..., [0, 2]].mean(axis=1), 0.0, atol=1e-9)
    # Facing: at frame 5 the hips' forward axis, on the ground, points along +X (LaFAN1's convention).
    with jax.enable_x64(True):
        fwd = np.array(quat_rotate(jnp.asarray(w.quat_local[:, 5, 0]), jnp.asarray(BANDAI_FORWARD)))
    fwd[:, 1] = 0
    np.testing.assert_allclose(fwd / np.linalg.norm(fwd, axis=-1, keepdims=True), [[1.0, 0, 0]] * 2, atol=1e-9)
    # Every joint's world position below joint_Root is the raw clip's, centred and turned
    # about +Y; joint_Root (static at the origin in the file) now sits on the hips.
    raw = read_bvh(DEMO_CLIP)
    with jax.enable_x64(True):
        quat_g, pos_g = forward_kinematics(raw.skeleton.parents, jnp.asarray(raw.quat_local), jnp.asarray(raw.pos_local))
        _, pos_w = forward_kinematics(w.parents, jnp.asarray(w.quat_local), jnp.asarray(w.offsets[:, None]), root_pos=jnp.asarray(w.root_pos))
        for i, s in enumerate(w.start_frame):
            hips = pos_g[s : s + 20, 1]
            centre = jnp.mean(hips, axis=0) * jnp.asarray([1.0, 0.0, 1.0])
            yaw_inv = quat_conjugate(facing_rotation(quat_g[s + 5, 1], BANDAI_FORWARD))
            expected = quat_rotate(yaw_inv, pos_g[s : s + 20] - centre)
            np.testing.assert_allclose(np.asarray(pos_w[i, :, 1:]), np.asarray(expected[:, 1:]), rtol=0, atol=1e-9)
            np.testing.assert_allclose(np.asarray(pos_w[i, :, 0]), np.asarray(expected[:, 1]), rtol=0, atol=1e-9)


def test_windows_feed_the_delta_trainer(bandai):
    w = motion_windows(bandai, "train", window=20, offset=10, forward_axis=BANDAI_FORWARD)
    assert isinstance(w, RotationWindows)
    data = DeltaArrays.from_windows(w)
    assert data.quat_local.shape == (2, 20, 22, 4) and data.quat_local.dtype == jnp.float32
    assert w.skeleton(1).parents == bandai.skeleton.parents
    np.testing.assert_array_equal(w.skeleton(1).offsets, w.offsets[1])


def test_bad_windows_are_refused(bandai, tmp_path):
    with pytest.raises(ValueError, match="no 40-frame windows in the 'train' split: a window needs a clip of more than 40 frames, and its longest has 40 frames \\(1 clips\\)"):
        motion_windows(bandai, "train", window=40, offset=10)
    with pytest.raises(ValueError, match="no 20-frame windows in the 'validation' split.*it has none \\(0 clips\\)"):
        motion_windows(bandai, "validation", window=20, offset=10)
    with pytest.raises(ValueError, match="facing_frame 9 must lie inside the 5-frame window"):
        motion_windows(bandai, "train", window=5, offset=1)
    with pytest.raises(ValueError, match="offset must be an integer ≥ 1, got 0"):
        motion_windows(bandai, "train", window=20, offset=0)
    with pytest.raises(ValueError, match="split must be one of"):
        motion_windows(bandai, "test", window=20, offset=10)
    anidance = AnidanceCorpus(
        names=("dance_a",), is_validation=np.array([False]), starts=np.array([0, 300]), positions=np.zeros((300, 24, 3))
    )
    with pytest.raises(ValueError, match="anidance: a positions-only corpus has no rotations"):
        motion_windows(anidance, "train", window=20, offset=10)
    # Hips that are not the top of the moving body: the legs hang off a joint above them.
    spine_hips = load_bvh_folder(
        bandai.cache_inputs[0].parent, characteristic={**SKELETON_MAPS["bandai_namco"], "hips": "Spine"},
        validation_every=None, progress=False,
    )  # fmt: skip
    with pytest.raises(ValueError, match="joints \\['UpperLeg_L', 'UpperLeg_R'\\] hang off \\['joint_Root', 'Hips'\\], above the hips 'Spine'"):
        motion_windows(spine_hips, "train", window=20, offset=10)
