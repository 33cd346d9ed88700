"""BVH export (``bezmotion.pipeline.export``): the round trip through a file matches the
pipeline's FK; bad input is refused.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from helpers import np_forward_kinematics
from ik.demo_poses import fk, np_pose_positions
from pipeline.common import FRAMES

from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.geometry.skeleton import Skeleton
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


def _with_offset(skeleton: Skeleton, joint: str, offset) -> Skeleton:
    offsets = np.array(skeleton.offsets, np.float64)
    offsets[skeleton.names.index(joint)] = offset
    return dataclasses.replace(skeleton, offsets=offsets)


def test_bvh_export_takes_offsets_and_end_sites_from_a_template(clip, run, tmp_path):
    """A model's character stores another take's rest hips (−427 cm along Z) and no End
    Sites; with the user's clip as template the file carries the clip's own, and its FK
    still equals the pipeline's (the hips' offset is replaced by its position channels)."""
    c, pose = run.character, run.result.pose
    model = dataclasses.replace(c, skeleton=_with_offset(c.skeleton, "Hips", (4.59, 91.49, -427.24)), end_sites=())
    sites = tuple((j, (0.0, 9.5, 1.0)) for j, _ in clip.motion.end_sites)
    template = dataclasses.replace(clip.motion, end_sites=sites)
    path = tmp_path / "template.bvh"
    write_bvh(path, pose_to_bvh(model, pose, fps=30.0, template=template))
    text = path.read_text()
    hips_offset = re.search(r"JOINT Hips\n\s*\{\n\s*OFFSET (.*)\n", text).group(1)
    np.testing.assert_allclose([float(v) for v in hips_offset.split()], clip.motion.skeleton.offsets[1], atol=1e-6)
    back = read_bvh(path)
    np.testing.assert_allclose(back.skeleton.offsets, clip.motion.skeleton.offsets, atol=1e-6)
    assert back.end_sites == sites and back.channels == default_channels(c)
    _, pos = np_forward_kinematics(back.skeleton.parents, back.quat_local, back.pos_local)
    np.testing.assert_allclose(pos, fk(model, pose)[1], atol=1e-3)
    # A template with longer shins: rotations are copied, so the feet move with its bones.
    longer = dataclasses.replace(clip.motion, skeleton=_with_offset(clip.motion.skeleton, "LowerLeg_L", (45.0, 0.0, 0.0)))
    write_bvh(path, pose_to_bvh(model, pose, template=longer))
    back = read_bvh(path)
    _, pos = np_forward_kinematics(back.skeleton.parents, back.quat_local, back.pos_local)
    as_template = dataclasses.replace(c, skeleton=longer.skeleton)
    np.testing.assert_allclose(pos, fk(as_template, pose)[1], atol=1e-3)
    foot = c.skeleton.names.index("Foot_L")
    assert np.abs(pos[:, foot] - np.asarray(fk(model, pose)[1])[:, foot]).max() > 1.0


def test_pose_to_bvh_rejects_a_template_of_other_joints(clip, run):
    c, pose = run.character, run.result.pose
    renamed = Skeleton(clip.motion.skeleton.parents, ("root",) + clip.motion.skeleton.names[1:], clip.motion.skeleton.offsets)
    other = dataclasses.replace(clip.motion, skeleton=renamed)
    with pytest.raises(ValueError, match=r"template joints \['root', 'Hips', .*\] .* differ from bandai_namco's \['joint_Root', 'Hips', "):
        pose_to_bvh(c, pose, template=other)


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
    rotations_only = (("Zrotation", "Yrotation", "Xrotation"),) * 22
    with pytest.raises(ValueError, match=r"the hips \('Hips'\) need position channels \(they carry the root motion\), got \['Zrotation'"):
        pose_to_bvh(c, pose, channels=rotations_only)
