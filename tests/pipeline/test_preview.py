"""Animated preview (``bezmotion.pipeline.preview``): one GIF frame per motion frame, read
back with Pillow; with and without the mocap beside it; bad input refused, nothing written.

Real data in NumPy (the bundled clip and curves through its joints, no JAX compile), drawn
small: these tests check the frames, not the picture.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PIL import Image

from helpers import np_forward_kinematics

from bezmotion.assets import DEMO_CLIP
from bezmotion.bezier import BezierLayout
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import characteristic_indices
from bezmotion.ik.protocol import Character
from bezmotion.pipeline.preview import write_preview


def window(frames: int):
    clip = read_bvh(DEMO_CLIP)
    motion = dataclasses.replace(clip, quat_local=clip.quat_local[:frames], pos_local=clip.pos_local[:frames], frame_time=1 / 30)
    _, pos = np_forward_kinematics(motion.skeleton.parents, motion.quat_local, motion.pos_local)
    points = pos[:, characteristic_indices(motion.skeleton.names, "bandai_namco")]
    layout = BezierLayout(frames, 6)
    tangent = np.gradient(points, axis=0)[layout.control_frames] * 2.0
    return Character.from_bvh(clip, "bandai_namco"), motion, points[layout.control_frames], tangent


def gif_frames(path) -> list[np.ndarray]:
    with Image.open(path) as im:
        assert im.format == "GIF"
        out = []
        for i in range(im.n_frames):
            im.seek(i)
            out.append(np.asarray(im.convert("RGB")))
            assert im.info["duration"] in (30, 40)  # 1/30 s in GIF hundredths
        return out


def test_preview_has_one_frame_per_motion_frame_beside_the_mocap(tmp_path):
    character, motion, ctrl_pos, ctrl_tangent = window(31)
    mocap = dataclasses.replace(motion, quat_local=motion.quat_local[::-1].copy(), pos_local=motion.pos_local[::-1].copy())
    handles = [{"joint": "right_hand", "frame": 12, "position": (ctrl_pos[2, 3] + [0, 25, 0]).tolist()}]
    path = tmp_path / "preview.gif"
    n = write_preview(path, character, motion, ctrl_pos, ctrl_tangent, reference=mocap, handles=handles, title="test", dpi=25)
    frames = gif_frames(path)
    assert n == len(frames) == 31
    assert frames[0].shape[1] > frames[0].shape[0]  # two panels side by side
    assert all(not np.array_equal(a, b) for a, b in zip(frames, frames[1:]))


def test_preview_without_curves_or_mocap(tmp_path):
    character, motion, _, _ = window(9)
    path = tmp_path / "keys.gif"
    assert write_preview(path, character, motion, dpi=20) == 9
    assert len(gif_frames(path)) == 9


def test_preview_bad_input_is_refused(tmp_path):
    character, motion, ctrl_pos, ctrl_tangent = window(13)
    path = tmp_path / "bad.gif"
    with pytest.raises(ValueError, match=r"ctrl_tangent must be \(3, 6, 3\) for 13 frames at stride 6, got \(2, 6, 3\)"):
        write_preview(path, character, motion, ctrl_pos, ctrl_tangent[:2])
    with pytest.raises(ValueError, match="reference has 12 frames, the motion 13"):
        write_preview(path, character, motion, reference=dataclasses.replace(motion, quat_local=motion.quat_local[:12], pos_local=motion.pos_local[:12]))
    with pytest.raises(ValueError, match="handle 0 must be .* got {'joint': 'tail'"):
        write_preview(path, character, motion, handles=[{"joint": "tail", "frame": 3, "position": [0, 0, 0]}])
    other = dataclasses.replace(character, skeleton=dataclasses.replace(character.skeleton, names=tuple(n + "_x" for n in character.skeleton.names)))
    with pytest.raises(ValueError, match="motion joints .* are not"):
        write_preview(path, other, motion)
    assert not path.exists()
