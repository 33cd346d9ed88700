"""Joint limits (bezmotion.ik.joint_limits): measured from motion, kept as JSON, checked on load."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.geometry.rotations import quat_conjugate, quat_log, quat_mul
from bezmotion.ik.joint_limits import JointLimits, joint_limits_from_motion
from bezmotion.ik.protocol import Character


@pytest.fixture(scope="module")
def demo():
    motion = read_bvh(DEMO_CLIP)
    return Character.from_bvh(motion, "bandai_namco"), np.asarray(motion.quat_local[::4], np.float32)


def test_measured_limits_hold_every_frame_they_were_measured_on(demo):
    character, quat = demo
    limits = joint_limits_from_motion(character, quat, percentile=0.0, margin=0.0)
    hips = character.hips
    assert float(limits.lower[hips, 0]) < -100 and float(limits.upper[hips, 0]) > 100  # the hips: unlimited
    rel = np.asarray(quat_log(quat_mul(quat_conjugate(limits.center[None]), jnp.asarray(quat))))  # (frames, joints, 3)
    limited = np.asarray(limits.upper) < 100
    inside = (rel >= np.asarray(limits.lower) - 1e-5) & (rel <= np.asarray(limits.upper) + 1e-5)
    assert limited.any() and inside[:, limited].all()
    # The range is the data's own, not wider: some frame touches each end of each limited axis.
    lower_hit = np.isclose(rel.min(axis=0), np.asarray(limits.lower), atol=1e-4)
    assert lower_hit[limited].all()
    wider = joint_limits_from_motion(character, quat, percentile=0.0, margin=0.1)
    np.testing.assert_allclose(np.asarray(wider.lower)[limited], np.asarray(limits.lower)[limited] - 0.1, atol=1e-5)


def test_json_round_trip_and_bad_entries(demo, tmp_path):
    character, quat = demo
    limits = joint_limits_from_motion(character, quat)
    limits.save(tmp_path / "limits.json", character)
    back = JointLimits.load(tmp_path / "limits.json", character)
    np.testing.assert_allclose(np.asarray(back.lower), np.asarray(limits.lower), atol=1e-4)
    np.testing.assert_allclose(np.asarray(back.center), np.asarray(limits.center), atol=1e-5)
    assert list(tmp_path.iterdir()) == [tmp_path / "limits.json"]  # written in place of a temporary file, none left
    with pytest.raises(ValueError, match="'Nope'"):
        JointLimits.from_json({"joints": {"Nope": {}}}, character)
    with pytest.raises(ValueError, match="Hips"):
        JointLimits.from_json({"joints": {"Hips": {"center": [1, 0, 0, 0], "lower": [1, 1, 1], "upper": [0, 0, 0]}}}, character)
    with pytest.raises(ValueError, match="'joints' mapping"):
        JointLimits.from_json({"joint": {}}, character)


def test_limits_saved_into_a_checked_model_folder_join_its_checksums(demo, tmp_path):
    from bezmotion._src.checksums import ChecksumError, checksum_problem, write_checksums

    character, quat = demo
    limits = joint_limits_from_motion(character, quat)
    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "params.bin").write_bytes(b"weights")
    write_checksums(folder)
    limits.save(folder / "joint_limits.json", character)
    assert checksum_problem(folder) is None and "joint_limits.json" in (folder / "checksums.json").read_text()
    (folder / "joint_limits.json").write_text((folder / "joint_limits.json").read_text().replace("0", "1", 1))
    assert "joint_limits.json differs" in checksum_problem(folder)  # a change to the limits is caught now

    (folder / "params.bin").write_bytes(b"damaged")
    before = (folder / "checksums.json").read_text()
    with pytest.raises(ChecksumError, match="params.bin"):  # a damaged folder is not listed anew as sound
        limits.save(folder / "joint_limits.json", character)
    assert (folder / "checksums.json").read_text() == before
