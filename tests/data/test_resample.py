"""A BVH motion at another frame rate (bezmotion.data.resample): samples through an anchor
frame, frames on the sample times kept exactly, slerp and lerp between; the bundled clip."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.data.resample import resample_motion
from bezmotion.geometry.rotations import slerp


@pytest.fixture(scope="module")
def clip():
    return read_bvh(DEMO_CLIP)  # 40 frames at 30 fps


def test_its_own_rate_returns_the_motion_itself(clip):
    same, at = resample_motion(clip, 30.0, 5)
    assert same is clip and at == 5


def test_a_lower_rate_keeps_the_anchor_and_every_frame_whole_steps_from_it(clip):
    half, at = resample_motion(clip, 15.0, 7)
    assert (at, half.num_frames, half.nominal_fps) == (3, 20, 15.0)  # frames 1, 3, …, 39
    np.testing.assert_array_equal(half.quat_local, clip.quat_local[1::2])
    np.testing.assert_array_equal(half.pos_local, clip.pos_local[1::2])
    assert half.skeleton is clip.skeleton and half.channels == clip.channels


def test_a_higher_rate_interpolates_between_frames_and_goes_back_exactly(clip):
    fast, at = resample_motion(clip, 120.0)
    assert (at, fast.num_frames, fast.nominal_fps) == (0, 157, 120.0)
    np.testing.assert_array_equal(fast.quat_local[::4], clip.quat_local)  # the clip's own frames, as they are
    want = np.asarray(slerp(jnp.asarray(clip.quat_local[10]), jnp.asarray(clip.quat_local[11]), 0.25))
    np.testing.assert_allclose(np.abs(np.sum(fast.quat_local[41] * want, axis=-1)), 1.0, atol=1e-6)  # a quarter of the way, the short way
    np.testing.assert_allclose(fast.pos_local[42, 0], 0.5 * (clip.pos_local[10, 0] + clip.pos_local[11, 0]), atol=1e-9)
    back, at = resample_motion(fast, 30.0, 8)
    assert at == 2
    np.testing.assert_array_equal(back.quat_local, clip.quat_local)
    np.testing.assert_array_equal(back.pos_local, clip.pos_local)


@pytest.mark.parametrize(
    ("fps", "anchor", "message"),
    [
        (0.0, 0, "fps must be a positive number of frames per second, got 0.0"),
        (float("nan"), 0, "got nan"),
        (30.0, 40, "anchor must be a frame 0…39 of the motion, got 40"),
        (30.0, -1, "got -1"),
    ],
)
def test_a_bad_rate_or_anchor_is_refused_with_its_value(clip, fps, anchor, message):
    with pytest.raises(ValueError, match=message):
        resample_motion(clip, fps, anchor)
