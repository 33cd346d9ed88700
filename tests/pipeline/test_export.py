"""BVH export (``bezmotion.pipeline.export``): the round trip through a file matches the
pipeline's FK; bad input is refused.
"""

from __future__ import annotations

import numpy as np
import pytest

from helpers import np_forward_kinematics
from ik.demo_poses import fk, np_pose_positions
from pipeline.common import FRAMES

from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.pipeline import default_channels, pose_to_bvh


@pytest.mark.parametrize("which", ["default", "clip"])
def test_bvh_export_round_trip_matches_pipeline_fk(clip, run, tmp_path, which):
    c, pose = run.character, run.result.pose
    channels = default_channels(c) if which == "default" else clip.motion.channels
    if which == "default":
        assert [len(ch) for ch in channels] == [6, 6] + [3] * 20
        assert channels[1] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    else:
        assert all(ch[3:] == ("Zrotation", "Xrotation", "Yrotation") and len(ch) == 6 for ch in channels)
    motion = pose_to_bvh(c, pose, fps=clip.motion.fps, channels=None if which == "default" else channels)
    assert motion.quat_local.dtype == np.float64 and motion.channels == tuple(channels)
    path = tmp_path / f"{which}.bvh"
    write_bvh(path, motion)
    back = read_bvh(path)
    assert back.skeleton.names == c.skeleton.names and back.channels == tuple(channels)
    assert back.num_frames == FRAMES and back.frame_time == pytest.approx(clip.motion.frame_time)
    assert back.end_sites == clip.motion.end_sites
    _, pos = np_forward_kinematics(back.skeleton.parents, back.quat_local, back.pos_local)
    np.testing.assert_allclose(pos, fk(c, pose)[1], atol=1e-3)
    np.testing.assert_allclose(pos, np_pose_positions(c, pose), atol=1e-3)


def test_pose_to_bvh_rejects_bad_input(run):
    c, pose = run.character, run.result.pose
    with pytest.raises(ValueError, match=r"poses must be \(frames, 22, 4\) for bandai_namco, got \(22, 4\)"):
        pose_to_bvh(c, run.start)
    with pytest.raises(ValueError, match=r"got \(31, 21, 4\)"):
        pose_to_bvh(c, pose._replace(quat_local=pose.quat_local[:, :21]))
    with pytest.raises(ValueError, match=r"poses.root_pos must be \(31, 3\), got \(3,\)"):
        pose_to_bvh(c, pose._replace(root_pos=pose.root_pos[0]))
    for fps in (0.0, -30.0, float("nan")):
        with pytest.raises(ValueError, match=f"fps must be positive, got {fps}"):
            pose_to_bvh(c, pose, fps=fps)
    with pytest.raises(ValueError, match="need channels for 22 joints, got 21"):
        pose_to_bvh(c, pose, channels=default_channels(c)[:21])
