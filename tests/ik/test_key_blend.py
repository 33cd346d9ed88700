"""Key blend (bezmotion.ik.key_blend) and the key-pop metric (bezmotion.evaluation.metrics)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.geometry.rotations import quat_from_axis_angle
from bezmotion.ik.protocol import Pose
from bezmotion.evaluation.metrics import key_pop_deg, rotation_change_deg
from bezmotion.ik.key_blend import blend_to_chain_keys, blend_to_keys, key_blend_weights, key_distances


def _about_y(degrees: np.ndarray) -> jnp.ndarray:
    return quat_from_axis_angle(jnp.asarray([0.0, 1.0, 0.0]), jnp.radians(jnp.asarray(degrees, jnp.float32)))


def test_key_pop_hand_computed():
    # One joint turning 1°, 2°, 3° … about y per frame; the other still.
    angles = np.cumsum(np.arange(1.0, 7.0))  # 1, 3, 6, 10, 15, 21
    quat = jnp.stack([_about_y(angles), _about_y(np.zeros(6))], axis=1)[None]  # (1, 6 frames, 2 joints, 4)
    np.testing.assert_allclose(np.asarray(rotation_change_deg(quat))[0, :, 0], np.arange(2.0, 7.0), atol=1e-3)
    assert float(key_pop_deg(quat)) == pytest.approx(6.0, abs=1e-3)  # the last step; the first is 2°
    assert float(key_pop_deg(-quat)) == pytest.approx(6.0, abs=1e-3)  # either quaternion sign


def test_blend_joins_keys_and_leaves_handle_frames():
    frames = 31
    ik = Pose(jnp.zeros((frames, 3)), jnp.stack([_about_y(np.zeros(frames))] * 2, axis=1))
    start = Pose(jnp.asarray([1.0, 2.0, 3.0]), jnp.stack([_about_y(np.asarray(20.0)), _about_y(np.asarray(0.0))]))
    end = Pose(jnp.asarray([0.0, 0.0, -3.0]), jnp.stack([_about_y(np.asarray(-24.0)), _about_y(np.asarray(0.0))]))
    old = blend_to_keys(ik, start, end, 0)
    assert float(key_pop_deg(old.quat_local)) == pytest.approx(24.0, abs=1e-3)  # the pop
    new = blend_to_keys(ik, start, end, 6)
    np.testing.assert_allclose(np.asarray(new.quat_local[0]), np.asarray(start.quat_local), atol=1e-6)
    np.testing.assert_allclose(np.asarray(new.root_pos[-1]), np.asarray(end.root_pos), atol=1e-6)
    np.testing.assert_allclose(np.asarray(new.quat_local[6:25]), np.asarray(ik.quat_local[6:25]), atol=1e-7)  # handle frames
    # A half cosine over 6 frames: the largest step is 24° · (1 − cos(π/6)) / 2 ≈ 1.6° at the key, ≤ 24° · sin(π/12)·… overall.
    assert float(key_pop_deg(new.quat_local)) < 2.0
    assert float(jnp.max(rotation_change_deg(new.quat_local))) < 24.0 * np.pi / 12 + 1e-3
    w_start, w_end = key_blend_weights(frames, 6)
    assert w_start[0] == 1.0 and w_start[6] == 0.0 and w_end[-1] == 1.0 and w_end[-7] == 0.0
    with pytest.raises(ValueError, match="-1"):
        blend_to_keys(ik, start, end, -1)


def test_chain_blend_joins_every_window_to_its_own_keys():
    """A chain of 3 windows (91 frames): every key exactly at its frame, each window faded
    to its own two keys (the middle window's frames equal a one-window blend of them), and
    a (start, end) pair gives the one-window blend itself."""
    frames, windows = 91, 3
    ik = Pose(jnp.zeros((frames, 3)), jnp.stack([_about_y(np.zeros(frames))] * 2, axis=1))
    keys = Pose(
        jnp.asarray([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0], [4.0, 0.0, 0.0]]),
        jnp.stack([jnp.stack([_about_y(np.asarray(a)), _about_y(np.asarray(0.0))]) for a in (20.0, -30.0, 10.0, 5.0)]),
    )
    chain = blend_to_chain_keys(ik, keys, 6)
    for k, frame in enumerate(range(0, frames, 30)):
        np.testing.assert_allclose(np.asarray(chain.quat_local[frame]), np.asarray(keys.quat_local[k]), atol=1e-6)
        np.testing.assert_allclose(np.asarray(chain.root_pos[frame]), np.asarray(keys.root_pos[k]), atol=1e-6)
    key = lambda k: Pose(keys.root_pos[k], keys.quat_local[k])  # noqa: E731
    middle = blend_to_keys(Pose(ik.root_pos[30:61], ik.quat_local[30:61]), key(1), key(2), 6)
    np.testing.assert_allclose(np.asarray(chain.quat_local[30:61]), np.asarray(middle.quat_local), atol=1e-6)
    one = blend_to_chain_keys(Pose(ik.root_pos[:31], ik.quat_local[:31]), (key(0), key(1)), 6)
    np.testing.assert_allclose(np.asarray(one.quat_local), np.asarray(chain.quat_local[:31]), atol=1e-6)
    distance = key_distances(frames, windows)  # the exact IK's key hold decays with it
    assert distance.shape == (frames,) and distance[[0, 30, 60, 90]].tolist() == [0] * 4
    assert distance[[1, 29, 31, 44, 45, 46, 89]].tolist() == [1, 1, 1, 14, 15, 14, 1]
    with pytest.raises(ValueError, match="not a chain of 4 windows"):
        blend_to_chain_keys(ik, Pose(jnp.zeros((5, 3)), jnp.zeros((5, 2, 4))), 6)
    with pytest.raises(ValueError, match="91 frames are not a chain of 4 windows"):
        key_distances(frames, 4)
