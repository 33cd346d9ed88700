"""Characteristic joints and Bézier curve datasets (``bezmotion.data.characteristic``, ``bezmotion.data.curves``),
plus smoke runs of ``experiments/bezier_stride.py`` and ``benchmarks/bezier_fit.py``.

Runs without ../shared: on the bundled real clip (``DEMO_CLIP``, 40 Bandai-Namco frames),
a miniature Bandai-Namco folder cut from it, and the synthetic LaFAN1-layout zip from
conftest. Only the last test reads the real LaFAN1 subset. Dense trajectories are checked
against plain-NumPy forward kinematics from ``helpers`` (no library FK code).

The curve fit is compiled once per distinct (skeleton, window, stride, variant), so the
expensive builds live in module-scoped fixtures shared by several tests.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import (
    SHARED_DATA,
    np_forward_kinematics,
    np_matrix_from_quat,
    requires_shared,
)

from bezmotion.assets import DEMO_CLIP
from bezmotion.bezier import BezierLayout, evaluate
from bezmotion.data import curves, lafan1
from bezmotion.data.bandai_namco import load_bandai_namco
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import (
    CHARACTERISTIC_JOINTS,
    CONTACT_SPEED,
    FEET,
    HIPS,
    SKELETON_MAPS,
    align_to_start,
    characteristic_indices,
    characteristic_trajectories,
    contact_labels,
)
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import CurveDataset, build_curve_dataset, characteristic_windows, curve_dataset
from bezmotion.geometry.rotations import matrix_from_rot6d
from bezmotion.geometry.skeleton import forward_kinematics
from helpers import REPO_ROOT, SHARED_DATA

ROOT = REPO_ROOT
DEMO = read_bvh(DEMO_CLIP)  # 40 frames at 30 fps, 22 joints (joint_Root, Hips, …)
BANDAI_NAMES = ("Hips", "Head", "Hand_L", "Hand_R", "Foot_L", "Foot_R")
LAFAN1_NAMES = ("Hips", "Head", "LeftHand", "RightHand", "LeftFoot", "RightFoot")
WINDOW, STRIDE, OFFSET = 31, 6, 5  # the defaults
CONTROL_FRAMES = [0, 6, 12, 18, 24, 30]


def np_characteristic(parents, indices, quat_local, pos_local) -> tuple[np.ndarray, np.ndarray]:
    """Plain-NumPy FK picked at ``indices``: ``(positions, global rotation matrices)``."""
    quat, pos = np_forward_kinematics(parents, quat_local, pos_local)
    return pos[..., list(indices), :], np_matrix_from_quat(quat[..., list(indices), :])


def np_aligned_window(parents, indices, quat_local, pos_local, start: int) -> np.ndarray:
    """The ``WINDOW``-frame window at ``start``, hips moved to the XZ origin at its first frame."""
    pos, _ = np_characteristic(parents, indices, quat_local[start : start + WINDOW], pos_local[start : start + WINDOW])
    return pos - pos[0, HIPS] * np.array([1.0, 0.0, 1.0])


def assert_datasets_equal(a: CurveDataset, b: CurveDataset) -> None:
    assert a.layout == b.layout and a.fps == b.fps
    for name in CurveDataset._ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def curve_errors(ds: CurveDataset) -> np.ndarray:
    """``(windows, frames, 6)`` distance between the evaluated curves and ``dense_pos`` (cm)."""
    ctrl_pos, ctrl_tangent = (jnp.moveaxis(jnp.asarray(a), -2, -3) for a in (ds.ctrl_pos, ds.ctrl_tangent))
    curve = np.moveaxis(np.asarray(evaluate(ds.layout, ctrl_pos, ctrl_tangent)), -3, -2)  # joints back after frames
    return np.linalg.norm(curve - ds.dense_pos, axis=-1)


def tiny_clips(lengths, joints: int = 2) -> MotionClips:
    """Motionless clips of the given lengths on a ``joints``-chain (for window bookkeeping)."""
    frames = int(sum(lengths))
    quat = np.zeros((frames, joints, 4))
    quat[..., 0] = 1.0
    return MotionClips(
        tuple(range(-1, joints - 1)), tuple(f"j{i}" for i in range(joints)), quat, np.zeros((frames, joints, 3)),
        np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64), 30.0,
    )  # fmt: skip


# ------------------------------------------------------------------ characteristic joints


def test_characteristic_indices_of_the_presets():
    idx = characteristic_indices(lafan1.JOINT_NAMES, "lafan1")
    assert idx == (0, 13, 17, 21, 3, 7)
    assert tuple(lafan1.JOINT_NAMES[i] for i in idx) == LAFAN1_NAMES
    idx = characteristic_indices(DEMO.skeleton.names, "bandai_namco")
    assert idx == (1, 5, 9, 13, 16, 20)  # joint 0 is joint_Root, not the hips
    assert tuple(DEMO.skeleton.names[i] for i in idx) == BANDAI_NAMES
    assert set(SKELETON_MAPS) == {"lafan1", "bandai_namco"}
    assert CHARACTERISTIC_JOINTS == ("hips", "head", "left_hand", "right_hand", "left_foot", "right_foot")
    assert HIPS == 0 and FEET == (4, 5)


def test_characteristic_indices_of_a_user_map():
    names = ("l_wrist", "pelvis", "r_ankle", "head", "spine", "l_ankle", "r_wrist")
    mapping = {  # any key order; the result follows CHARACTERISTIC_JOINTS
        "right_foot": "r_ankle", "left_foot": "l_ankle", "head": "head", "hips": "pelvis",
        "right_hand": "r_wrist", "left_hand": "l_wrist",
    }  # fmt: skip
    assert characteristic_indices(names, mapping) == (1, 3, 0, 6, 5, 2)
    assert characteristic_indices(list(names), mapping) == (1, 3, 0, 6, 5, 2)  # any sequence of names


def test_characteristic_indices_errors():
    names = DEMO.skeleton.names
    preset = dict(SKELETON_MAPS["bandai_namco"])
    with pytest.raises(ValueError, match=r"unknown skeleton map 'smpl'; known: \['bandai_namco', 'lafan1'\]"):
        characteristic_indices(names, "smpl")
    missing = {k: v for k, v in preset.items() if k != "head"}
    with pytest.raises(ValueError, match=r"needs exactly the roles .*missing \['head'\], unknown \[\]"):
        characteristic_indices(names, missing)
    with pytest.raises(ValueError, match=r"missing \[\], unknown \['tail'\]"):
        characteristic_indices(names, {**preset, "tail": "Spine"})
    renamed = {("left_wrist" if k == "left_hand" else k): v for k, v in preset.items()}
    with pytest.raises(ValueError, match=r"missing \['left_hand'\], unknown \['left_wrist'\]"):
        characteristic_indices(names, renamed)
    with pytest.raises(ValueError, match=r"joints \{'head': 'Skull'\} are not in the skeleton"):
        characteristic_indices(names, {**preset, "head": "Skull"})
    with pytest.raises(ValueError, match=r"'left_hand': 'LeftHand'.* are not in the skeleton"):
        characteristic_indices(names, "lafan1")  # the LaFAN1 names on the Bandai-Namco skeleton
    with pytest.raises(ValueError, match="characteristic joints must be distinct"):
        characteristic_indices(names, {**preset, "right_foot": "Foot_L"})


def test_characteristic_trajectories_are_forward_kinematics_at_the_indices(x64):
    idx = characteristic_indices(DEMO.skeleton.names, "bandai_namco")
    parents = DEMO.skeleton.parents
    quat = jnp.asarray(DEMO.quat_local).reshape(2, 20, -1, 4)  # a batch axis in front of frames
    pos_local = jnp.asarray(DEMO.pos_local).reshape(2, 20, -1, 3)
    pos, rot6d = characteristic_trajectories(parents, idx, quat, pos_local)
    assert pos.shape == (2, 20, 6, 3) and rot6d.shape == (2, 20, 6, 6) and pos.dtype == jnp.float64

    quat_global, pos_global = forward_kinematics(parents, quat, pos_local)
    np.testing.assert_array_equal(pos, np.asarray(pos_global)[..., list(idx), :])
    # Independently: NumPy FK, and the ortho6D is the first two columns of the global rotation matrix.
    ref_pos, ref_matrix = np_characteristic(parents, idx, DEMO.quat_local, DEMO.pos_local)
    np.testing.assert_allclose(np.asarray(pos).reshape(40, 6, 3), ref_pos, atol=1e-9)
    r6 = np.asarray(rot6d).reshape(40, 6, 6)
    np.testing.assert_allclose(r6[..., :3], ref_matrix[..., :, 0], atol=1e-12)
    np.testing.assert_allclose(r6[..., 3:], ref_matrix[..., :, 1], atol=1e-12)
    np.testing.assert_allclose(np.asarray(matrix_from_rot6d(rot6d)).reshape(40, 6, 3, 3), ref_matrix, atol=1e-12)
    # The walk actually moves (a test on a static pose would prove little).
    assert np.ptp(ref_pos[:, HIPS, 2]) > 10.0


def test_align_to_start_translates_rigidly_in_xz(rng):
    positions = rng.normal(scale=100.0, size=(3, 2, 10, 6, 3)).astype(np.float32)
    aligned, translation = align_to_start(jnp.asarray(positions))
    aligned, translation = np.asarray(aligned), np.asarray(translation)
    assert aligned.shape == positions.shape and translation.shape == (3, 2, 3)
    np.testing.assert_array_equal(aligned[..., 0, HIPS, [0, 2]], 0.0)  # hips start at the XZ origin
    np.testing.assert_array_equal(aligned[..., 1], positions[..., 1])  # heights untouched
    np.testing.assert_array_equal(translation[..., 1], 0.0)
    np.testing.assert_array_equal(translation[..., [0, 2]], positions[..., 0, HIPS, :][..., [0, 2]])
    # One translation for the whole window (every frame, every joint): nothing rotates.
    shift = positions - aligned
    np.testing.assert_allclose(shift, np.broadcast_to(translation[..., None, None, :], shift.shape), atol=1e-4)
    np.testing.assert_allclose(aligned + translation[..., None, None, :], positions, atol=1e-4)  # undoes it


def feet_moving(speeds_cm_s, fps: float, seconds_each: int = 1) -> np.ndarray:
    """``(frames, 6, 3)`` positions: the left foot moves along X at each speed in turn (one
    ``seconds_each`` segment each), the right foot stands still, the hands race (ignored)."""
    t = np.arange(round(len(speeds_cm_s) * seconds_each * fps) + 1) / fps
    segment = np.minimum((t // seconds_each).astype(int), len(speeds_cm_s) - 1)
    starts = np.concatenate([[0.0], np.cumsum(speeds_cm_s) * seconds_each])
    x = starts[segment] + np.asarray(speeds_cm_s)[segment] * (t - segment * seconds_each)
    pos = np.zeros((len(t), 6, 3))
    pos[:, :, 1] = 10.0
    pos[:, 4, 0] = x  # left foot
    pos[:, 5] = [20.0, 8.0, -30.0]  # right foot, still
    pos[:, 2, 2] = pos[:, 3, 2] = 500.0 * t  # hands at 500 cm/s
    return pos


def test_contact_labels_follow_foot_speed():
    assert CONTACT_SPEED == pytest.approx(89.4427, abs=1e-4)  # √0.002 m per frame at 20 fps
    speeds = [120.0, 0.0, 50.0, 0.95 * CONTACT_SPEED, 1.05 * CONTACT_SPEED]
    pos = feet_moving(speeds, fps=30.0)
    labels = np.asarray(contact_labels(jnp.asarray(pos, jnp.float32), 30.0))
    assert labels.shape == (151, 2) and labels.dtype == bool
    expected_left = np.repeat([False, True, True, True, False], 30)
    np.testing.assert_array_equal(labels[:150, 0], expected_left)
    assert labels[150, 0] == labels[149, 0]  # the last frame repeats the one before
    assert labels[:, 1].all()  # the standing foot is in contact throughout
    # A stricter threshold changes the 50 cm/s segment only.
    strict = np.asarray(contact_labels(jnp.asarray(pos, jnp.float32), 30.0, speed_threshold=40.0))
    np.testing.assert_array_equal(strict[:150, 0], np.repeat([False, True, False, False, False], 30))
    # Batched like the positions.
    batched = np.asarray(contact_labels(jnp.asarray(np.stack([pos, pos[::-1]]), jnp.float32), 30.0))
    np.testing.assert_array_equal(batched[0], labels)


def test_contact_threshold_is_a_speed_so_it_holds_at_any_frame_rate():
    speeds = [120.0, 0.0, 60.0, 100.0, 80.0]
    at30 = np.asarray(contact_labels(jnp.asarray(feet_moving(speeds, 30.0), jnp.float32), 30.0))
    at60 = np.asarray(contact_labels(jnp.asarray(feet_moving(speeds, 60.0), jnp.float32), 60.0))
    assert at30.shape == (151, 2) and at60.shape == (301, 2)
    np.testing.assert_array_equal(at60[::2], at30)  # same motion resampled: same labels
    np.testing.assert_array_equal(at60[1::2], at30[:-1])
    assert at30[:, 0].any() and not at30[:, 0].all()
    # A per-frame threshold would not be rate independent: 120 cm/s is 2 cm per frame at 60 fps,
    # which the 30 fps threshold (2.98 cm per frame) would call a contact.
    assert not at60[:60, 0].any()


@pytest.mark.parametrize(
    ("fps", "threshold"),
    [(0.0, CONTACT_SPEED), (-30.0, CONTACT_SPEED), (30.0, 0.0), (30.0, -1.0), (float("nan"), CONTACT_SPEED)],
)
def test_contact_labels_reject_non_positive_rates(fps, threshold):
    pos = jnp.zeros((5, 6, 3))
    with pytest.raises(ValueError, match=rf"fps and speed_threshold must be positive, got fps={fps}"):
        contact_labels(pos, fps, threshold)


# ------------------------------------------------------------------------- MotionClips


def test_window_starts_fit_inside_each_clip():
    clips = tiny_clips([40, 30, 31, 0, 36, 45])
    assert clips.num_clips == 6
    clip_index, start_frame = clips.window_starts(31, 5)
    # 40: 0, 5 (10 + 31 > 40); 30: none; 31: 0 (0 + 31 == 31 fits); 0: none; 36: 0, 5 (5 + 31 == 36); 45: 0, 5, 10.
    assert clip_index.tolist() == [0, 0, 2, 4, 4, 5, 5, 5]
    assert start_frame.tolist() == [0, 5, 0, 0, 5, 0, 5, 10]
    assert clip_index.dtype == start_frame.dtype == np.int64
    lengths = np.diff(clips.starts)
    assert np.all(start_frame + 31 <= lengths[clip_index])
    # Offset 1: every start; window 2 is the shortest allowed.
    clip_index, start_frame = clips.window_starts(2, 1)
    assert len(start_frame) == sum(n - 1 for n in lengths if n >= 2)
    assert clips.window_starts(46, 1)[0].size == 0  # every clip shorter than the window
    empty = tiny_clips([])
    assert empty.num_clips == 0 and [a.tolist() for a in empty.window_starts(31, 5)] == [[], []]


@pytest.mark.parametrize(("window", "offset"), [(1, 5), (0, 5), (31, 0), (31, -2)])
def test_window_starts_validation(window, offset):
    with pytest.raises(ValueError, match=rf"window must be ≥ 2 and offset ≥ 1, got window={window}, offset={offset}"):
        tiny_clips([40]).window_starts(window, offset)


def test_motion_clips_validation():
    good = tiny_clips([10, 5])
    with pytest.raises(ValueError, match=r"quat_local \(15, 3, 4\) and pos_local \(15, 2, 3\) must be"):
        MotionClips(good.parents, good.joint_names, np.zeros((15, 3, 4)), good.pos_local, good.starts, 30.0)
    with pytest.raises(ValueError, match=r"must be \(frames, 2, 4\) and \(frames, 2, 3\)"):
        MotionClips(good.parents, good.joint_names, good.quat_local, np.zeros((14, 2, 3)), good.starts, 30.0)
    for starts in ([1, 10, 15], [0, 10, 14], [0, 10, 9, 15], [[0, 15]], []):
        with pytest.raises(ValueError, match="MotionClips.starts must rise from 0 to 15"):
            MotionClips(good.parents, good.joint_names, good.quat_local, good.pos_local, np.asarray(starts, int), 30.0)
    with pytest.raises(ValueError, match="1 joint names for 2 joints"):
        MotionClips(good.parents, good.joint_names[:1], good.quat_local, good.pos_local, good.starts, 30.0)
    for fps in (0.0, -30.0, float("nan")):
        with pytest.raises(ValueError, match="MotionClips.fps must be positive"):
            MotionClips(good.parents, good.joint_names, good.quat_local, good.pos_local, good.starts, fps)


def test_motion_clips_from_bvh():
    second = read_bvh(DEMO_CLIP)
    clips = MotionClips.from_bvh([DEMO, second])
    assert clips.starts.tolist() == [0, 40, 80] and clips.fps == round(1 / DEMO.frame_time, 6)
    assert clips.parents == DEMO.skeleton.parents and clips.joint_names == DEMO.skeleton.names
    np.testing.assert_array_equal(clips.quat_local[40:], DEMO.quat_local)
    np.testing.assert_array_equal(clips.pos_local[:40], DEMO.pos_local)
    with pytest.raises(ValueError, match="needs at least one motion"):
        MotionClips.from_bvh([])
    slower = dataclasses.replace(second, frame_time=1 / 60)
    with pytest.raises(ValueError, match=r"motion 1 has frame time 0\.01666"):
        MotionClips.from_bvh([DEMO, slower])
    renamed = dataclasses.replace(
        second, skeleton=dataclasses.replace(second.skeleton, names=("Root",) + second.skeleton.names[1:])
    )
    with pytest.raises(ValueError, match="motion 1 has a different hierarchy from motion 0"):
        MotionClips.from_bvh([DEMO, renamed])


# ------------------------------------------------------------- curve dataset on DEMO_CLIP


@pytest.fixture(scope="module")
def demo_clips() -> MotionClips:
    return MotionClips.from_bvh([DEMO])


@pytest.fixture(scope="module")
def demo_dataset(demo_clips) -> CurveDataset:
    return build_curve_dataset(demo_clips, "bandai_namco", progress=False)


def test_demo_dataset_shapes(demo_dataset, demo_clips):
    ds = demo_dataset
    assert len(ds) == 2  # 40 frames: windows at 0 and 5 (10 + 31 > 40)
    assert ds.layout == BezierLayout(WINDOW, STRIDE) and ds.layout.control_frames.tolist() == CONTROL_FRAMES
    assert ds.fps == demo_clips.fps == pytest.approx(30.0, abs=1e-4)
    shapes = {
        "ctrl_pos": ((2, 6, 6, 3), np.float32), "ctrl_tangent": ((2, 6, 6, 3), np.float32),
        "ctrl_rot6d": ((2, 6, 6, 6), np.float32), "ctrl_contacts": ((2, 6, 2), np.bool_),
        "dense_pos": ((2, 31, 6, 3), np.float32), "dense_contacts": ((2, 31, 2), np.bool_),
        "fit_rms": ((2, 6), np.float32), "clip_index": ((2,), np.int64), "start_frame": ((2,), np.int64),
    }  # fmt: skip
    for name, (shape, dtype) in shapes.items():
        array = getattr(ds, name)
        assert isinstance(array, np.ndarray) and array.shape == shape and array.dtype == dtype, name
    assert ds.clip_index.tolist() == [0, 0] and ds.start_frame.tolist() == [0, 5]
    assert all(np.all(np.isfinite(getattr(ds, k))) for k in ("ctrl_pos", "ctrl_tangent", "ctrl_rot6d", "fit_rms"))


def test_demo_dataset_dense_values_are_the_aligned_mocap(demo_dataset, demo_clips):
    ds = demo_dataset
    idx = characteristic_indices(DEMO.skeleton.names, "bandai_namco")
    for w, start in enumerate(ds.start_frame):
        want = np_aligned_window(DEMO.skeleton.parents, idx, DEMO.quat_local, DEMO.pos_local, int(start))
        np.testing.assert_allclose(ds.dense_pos[w], want, atol=2e-3)  # float32 FK at ~150 cm
        # Hips start at the XZ origin exactly; their height is the mocap's.
        np.testing.assert_array_equal(ds.dense_pos[w, 0, HIPS, [0, 2]], 0.0)
        assert ds.dense_pos[w, 0, HIPS, 1] > 50.0
    # Window 1 is window 0's motion five frames on, shifted by where the hips stood at frame 5.
    shift = ds.dense_pos[0, 5, HIPS] * np.array([1, 0, 1])
    np.testing.assert_allclose(ds.dense_pos[1, :26], ds.dense_pos[0, 5:] - shift, atol=2e-3)
    # characteristic_windows gives the same trajectories without fitting.
    pos, rot6d, clip_index, start_frame = characteristic_windows(demo_clips, "bandai_namco")
    assert pos.dtype == rot6d.dtype == np.float32 and rot6d.shape == (2, 31, 6, 6)
    np.testing.assert_allclose(pos, ds.dense_pos, atol=1e-4)
    assert clip_index.tolist() == [0, 0] and start_frame.tolist() == [0, 5]
    # Contacts: the ankle's per-frame speed against the threshold, from the dense positions.
    step = np.linalg.norm(np.diff(ds.dense_pos[:, :, list(FEET)].astype(np.float64), axis=1), axis=-1) * ds.fps
    expected = np.concatenate([step < CONTACT_SPEED, step[:, -1:] < CONTACT_SPEED], axis=1)
    np.testing.assert_array_equal(ds.dense_contacts, expected)
    assert ds.dense_contacts.any() and not ds.dense_contacts.all()  # a walk: both phases present


def test_demo_dataset_control_values_are_the_dense_values_at_control_frames(demo_dataset, demo_clips):
    ds = demo_dataset
    np.testing.assert_array_equal(ds.ctrl_pos, ds.dense_pos[:, CONTROL_FRAMES])  # pinned: exact
    np.testing.assert_array_equal(ds.ctrl_contacts, ds.dense_contacts[:, CONTROL_FRAMES])
    _, rot6d, _, _ = characteristic_windows(demo_clips, "bandai_namco")
    np.testing.assert_allclose(ds.ctrl_rot6d, rot6d[:, CONTROL_FRAMES], atol=1e-6)
    # …and the global joint orientation from NumPy FK (ortho6D = first two matrix columns).
    idx = characteristic_indices(DEMO.skeleton.names, "bandai_namco")
    _, matrix = np_characteristic(DEMO.skeleton.parents, idx, DEMO.quat_local, DEMO.pos_local)
    for w, start in enumerate(ds.start_frame):
        m = matrix[start + np.asarray(CONTROL_FRAMES)]
        np.testing.assert_allclose(ds.ctrl_rot6d[w], np.concatenate([m[..., :, 0], m[..., :, 1]], -1), atol=1e-5)


def test_demo_dataset_curves_reproduce_the_dense_trajectories(demo_dataset):
    ds = demo_dataset
    error = curve_errors(ds)  # (windows, frames, 6)
    assert error.max() < 1.0  # measured 0.44 cm (a foot mid-step)
    assert error.mean() < 0.12  # measured 0.056 cm
    np.testing.assert_allclose(error[:, CONTROL_FRAMES], 0.0, atol=1e-4)  # pinned: through the data
    # fit_rms is the per-joint RMS of exactly this error over the window's frames.
    np.testing.assert_allclose(ds.fit_rms, np.sqrt(np.mean(error**2, axis=1)), rtol=1e-3, atol=1e-5)
    assert np.all(ds.fit_rms > 0)


def test_free_control_positions_fit_at_least_as_well(demo_dataset, demo_clips):
    free = build_curve_dataset(demo_clips, "bandai_namco", pin_positions=False, progress=False)
    np.testing.assert_array_equal(free.dense_pos, demo_dataset.dense_pos)
    # Least squares over a superset of the pinned curves (measured: 0.078 vs 0.063 cm mean).
    assert np.all(free.fit_rms <= demo_dataset.fit_rms + 1e-5)
    assert free.fit_rms.mean() < demo_dataset.fit_rms.mean()
    # Free curves miss the data at their own control frames.
    assert np.abs(free.ctrl_pos - demo_dataset.ctrl_pos).max() > 1e-3


def test_curve_dataset_subset_and_array_round_trip(demo_dataset, tmp_path):
    ds = demo_dataset
    last = ds.subset([1])
    assert len(last) == 1 and last.layout == ds.layout and last.fps == ds.fps
    for name in CurveDataset._ARRAYS:
        np.testing.assert_array_equal(getattr(last, name), getattr(ds, name)[1:2], err_msg=name)
    assert_datasets_equal(ds.subset(np.array([True, False])), ds.subset([0]))
    assert_datasets_equal(ds.subset(np.arange(2)[::-1]).subset([1, 0]), ds)

    arrays = ds.to_arrays()
    assert set(arrays) == set(CurveDataset._ARRAYS) | {"num_frames", "stride", "fps"}
    np.savez(tmp_path / "curves.npz", **arrays)  # plain arrays: no pickling needed
    with np.load(tmp_path / "curves.npz", allow_pickle=False) as f:
        again = CurveDataset.from_arrays({k: f[k] for k in f.files})
    assert_datasets_equal(again, ds)
    assert isinstance(again.layout.num_frames, int) and isinstance(again.fps, float)


def test_build_curve_dataset_errors(demo_clips):
    with pytest.raises(ValueError, match=r"no windows of 41 frames in 1 clips \(longest 40\)"):
        build_curve_dataset(demo_clips, "bandai_namco", window=41, progress=False)
    with pytest.raises(ValueError, match="are not in the skeleton"):
        build_curve_dataset(demo_clips, "lafan1", progress=False)
    with pytest.raises(ValueError, match="window must be ≥ 2"):
        build_curve_dataset(demo_clips, "bandai_namco", offset=0, progress=False)


def test_fit_that_does_not_converge_names_the_window(demo_clips, monkeypatch):
    real = curves._window_curves

    def failing(*args, **kwargs):
        out = dict(real(*args, **kwargs))
        out["fit_ok"] = out["fit_ok"].at[1, 3].set(False)  # window 1 (frame 5), one joint
        return out

    monkeypatch.setattr(curves, "_window_curves", failing)
    with pytest.raises(RuntimeError, match=r"did not converge for 1 windows, first: clip 0, frame 5"):
        build_curve_dataset(demo_clips, "bandai_namco", progress=False)


# ----------------------------------------------------------------- Bandai-Namco (synthetic)

BANDAI_ROOT = "Bandai-Namco-Research-Motiondataset-2"
CONTENTS = ("walk", "walk-turn-left", "walk-turn-right", "run", "wave-both-hands", "wave-left-hand",
            "wave-right-hand", "raise-up-both-hands", "raise-up-left-hand", "raise-up-right-hand")  # fmt: skip
STYLES = ("active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful")
MINI_BANDAI = {  # name: (frames, label); take 10 validates, the 12-frame run is too short for a window
    "dataset-2_walk_normal_001": (40, {"content": 0, "style": 5}),
    "dataset-2_walk_normal_010": (35, {"content": 0, "style": 5}),
    "dataset-2_run_active_002": (12, {"content": 3, "style": 0}),
}


def demo_clip_text(frames: int) -> str:
    """DEMO_CLIP cut to its first ``frames`` frames."""
    lines = DEMO_CLIP.read_text().split("\n")
    at = lines.index("Frames:\t40")
    return "\n".join(lines[:at] + [f"Frames:\t{frames}"] + lines[at + 1 : at + 2 + frames]) + "\n"


@pytest.fixture(scope="module")
def mini_bandai(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("bandai") / BANDAI_ROOT
    (root / "data").mkdir(parents=True)
    (root / "cfg").mkdir()
    (root / "cfg" / "content_label.txt").write_text("\n".join(f"dataset-2_{c}" for c in CONTENTS))
    (root / "cfg" / "style_label.txt").write_text("\n".join(f"dataset-2_{s}" for s in STYLES))
    for name, (frames, label) in MINI_BANDAI.items():
        (root / "data" / f"{name}.bvh").write_text(demo_clip_text(frames))
        (root / "data" / f"{name}.json").write_text(json.dumps(label))
    return root


def test_motion_clips_from_bandai_namco(mini_bandai, demo_dataset, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    corpus = load_bandai_namco(mini_bandai, progress=False)
    assert corpus.names == tuple(sorted(MINI_BANDAI))  # run_002, walk_001, walk_010
    clips = corpus.motion([2, 1])  # any selection, in the order given
    assert clips.starts.tolist() == [0, 35, 75] and clips.fps == demo_dataset.fps
    assert clips.joint_names == DEMO.skeleton.names and clips.parents == DEMO.skeleton.parents
    np.testing.assert_array_equal(clips.quat_local[35:], DEMO.quat_local)
    np.testing.assert_array_equal(clips.pos_local[:35], DEMO.pos_local[:35])
    assert corpus.motion([]).num_clips == 0


def test_bandai_namco_curve_dataset_splits_by_take(mini_bandai, demo_dataset, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    corpus = load_bandai_namco(mini_bandai, progress=False)
    train = curve_dataset(corpus, "train", progress=False)
    # Train clips in corpus (name) order: run_002 (12 frames: no window), walk_001 (the demo clip).
    assert train.clip_index.tolist() == [1, 1] and train.start_frame.tolist() == [0, 5]
    for name in ("ctrl_pos", "ctrl_tangent", "ctrl_rot6d", "dense_pos", "fit_rms"):
        np.testing.assert_array_equal(getattr(train, name), getattr(demo_dataset, name), err_msg=name)
    assert train.layout == demo_dataset.layout and train.fps == demo_dataset.fps
    validation = curve_dataset(corpus, "validation", progress=False)
    assert validation.clip_index.tolist() == [0] and validation.start_frame.tolist() == [0]  # 5 + 31 > 35
    np.testing.assert_array_equal(validation.dense_pos, demo_dataset.dense_pos[:1])
    assert len(list(tmp_path.glob("bandai-namco-curves-*.npz"))) == 2


def test_bandai_namco_curve_dataset_bad_split(mini_bandai, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    with pytest.raises(ValueError, match=r"split must be one of \('train', 'validation'\), got 'test'"):
        curve_dataset(load_bandai_namco(mini_bandai, progress=False), "test")


# ------------------------------------------------------------------- LaFAN1 (synthetic zip)


@pytest.fixture(scope="module")
def lafan1_curves(synthetic_zip, tmp_path_factory):
    """``(cache folder, train, validation)`` built once into a private cache."""
    cache = tmp_path_factory.mktemp("curve-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("BEZMOTION_CACHE", str(cache))
        corpus = lafan1.load_lafan1(synthetic_zip, use_cache=False)
        train = curve_dataset(corpus, "train", progress=False)
        validation = curve_dataset(corpus, "validation", progress=False)
    return cache, train, validation


def test_lafan1_curve_dataset_splits_by_subject(lafan1_curves, synthetic_zip, tmp_path, monkeypatch):
    _, train, validation = lafan1_curves
    # Corpus order is by file name: dance1_subject5 (300 frames), run2_subject2 (150), walk1_subject1 (230).
    # Train = files_of(1..4) = [run2, walk1]: 24 + 40 windows; validation = [dance1]: 54 windows.
    assert np.bincount(train.clip_index).tolist() == [24, 40]
    assert train.start_frame[:24].tolist() == list(range(0, 120, 5))
    assert train.start_frame[24:].tolist() == list(range(0, 200, 5))
    assert validation.clip_index.tolist() == [0] * 54 and validation.start_frame[-1] == 265
    assert train.fps == validation.fps == 30.0 and train.layout == BezierLayout(31, 6)
    # Dense trajectories are the aligned FK of the right file.
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    corpus = lafan1.load_lafan1(synthetic_zip)
    idx = characteristic_indices(lafan1.JOINT_NAMES, "lafan1")
    for dataset, files in ((train, [1, 2]), (validation, [0])):
        for w in (0, len(dataset) // 2, len(dataset) - 1):
            f = files[dataset.clip_index[w]]
            quat, root = corpus.clip(f)
            pos_local = np.broadcast_to(corpus.offsets[f], quat.shape[:2] + (3,)).copy()
            pos_local[:, 0] = root
            want = np_aligned_window(lafan1.PARENTS, idx, quat, pos_local, int(dataset.start_frame[w]))
            np.testing.assert_allclose(dataset.dense_pos[w], want, atol=5e-3)  # float32, |Z| up to ~400 cm
    np.testing.assert_array_equal(train.ctrl_pos, train.dense_pos[:, CONTROL_FRAMES])
    # The synthetic root path is smooth (a sine and a line): its curve is exact to float32
    # round-off (measured 4.8e-4 cm); the limbs swing fast (measured mean 2.7 cm, max 16 cm).
    assert train.fit_rms[:, HIPS].max() < 2e-3
    assert train.fit_rms.mean() < 6.0 and validation.fit_rms.mean() < 3.0  # measured 2.73, 1.18


def test_lafan1_curve_dataset_is_cached(lafan1_curves, synthetic_zip, monkeypatch):
    cache, train, validation = lafan1_curves
    assert len(list(cache.glob("lafan1-curves-*.npz"))) == 2  # one entry per split
    monkeypatch.setenv("BEZMOTION_CACHE", str(cache))

    def no_fitting(*args, **kwargs):
        raise AssertionError("build_curve_dataset called: the cache missed")

    monkeypatch.setattr(curves, "build_curve_dataset", no_fitting)
    corpus = lafan1.load_lafan1(synthetic_zip, use_cache=False)
    assert_datasets_equal(curve_dataset(corpus, "train", progress=False), train)
    assert_datasets_equal(curve_dataset(corpus, "validation", progress=False), validation)
    # Any other configuration is another entry, and use_cache=False always fits.
    for changed in ({"stride": 5}, {"window": 30}, {"offset": 4}, {"pin_positions": False}, {"use_cache": False}):
        with pytest.raises(AssertionError, match="the cache missed"):
            curve_dataset(corpus, "train", progress=False, **changed)
    assert len(list(cache.glob("lafan1-curves-*.npz"))) == 2


def test_lafan1_curve_dataset_new_stride_is_a_new_entry(synthetic_zip, lafan1_curves, tmp_path, monkeypatch):
    _, _, validation = lafan1_curves
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    corpus = lafan1.load_lafan1(synthetic_zip, use_cache=False)
    strided = curve_dataset(corpus, "validation", stride=10, offset=15, progress=False)
    assert len(list(tmp_path.glob("lafan1-curves-*.npz"))) == 1
    assert strided.layout == BezierLayout(31, 10) and strided.ctrl_pos.shape == (18, 4, 6, 3)
    np.testing.assert_array_equal(strided.dense_pos, validation.dense_pos[::3])  # offset 15 = every third window
    np.testing.assert_array_equal(strided.ctrl_pos, validation.dense_pos[::3][:, [0, 10, 20, 30]])
    curve_dataset(corpus, "validation", stride=10, offset=15, window=31, progress=False)
    assert len(list(tmp_path.glob("lafan1-curves-*.npz"))) == 1  # same configuration: same entry


def test_lafan1_curve_dataset_bad_split(synthetic_zip):
    with pytest.raises(ValueError, match=r"split must be one of \('train', 'validation'\), got 'test'"):
        curve_dataset(lafan1.load_lafan1(synthetic_zip, use_cache=False), "test")


# --------------------------------------------------------------- experiment and benchmark


def load_script(path: Path):
    spec = importlib.util.spec_from_file_location(f"_under_test_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bezier_stride_experiment(synthetic_zip, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    experiment = load_script(ROOT / "experiments" / "bezier_stride.py")
    out = tmp_path / "results" / "stride.json"
    results = experiment.main(["--data", synthetic_zip, "--out", str(out), "--max-stride", "3"])
    assert json.loads(out.read_text()) == results
    assert results["n_windows"] == 54 and results["window"] == 31 and results["subjects"] == [5]
    assert set(results["stride"]) == {"1", "2", "3"} and results["stride"] == results["variants"]["pinned"]["stride"]
    pinned, free = results["variants"]["pinned"], results["variants"]["free"]
    assert set(pinned["per_joint"]["3"]) == set(CHARACTERISTIC_JOINTS)
    assert pinned["stride"]["1"] < 1e-4 and free["stride"]["1"] < 1e-4  # a control point on every frame
    assert 0 < pinned["stride"]["2"] < pinned["stride"]["3"]
    assert pinned["stride"]["3"] >= free["stride"]["3"]  # pinning costs dense accuracy…
    assert pinned["control_error"]["3"] < 1e-4 < free["control_error"]["3"]  # …but hits the handles
    table = out.with_suffix(".md").read_text().strip().splitlines()
    assert len(table) == 2 + 3 and table[-1].startswith("| 3 | 11 |")
    assert out.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(SystemExit, match="--max-stride must be between 1 and window - 1 = 30, got 31"):
        experiment.main(["--data", synthetic_zip, "--out", str(out), "--max-stride", "31"])


def test_bezier_fit_benchmark_without_data(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))  # the script imports _timing from its folder
    had_timing = "_timing" in sys.modules
    try:
        benchmark = load_script(ROOT / "benchmarks" / "bezier_fit.py")
        out = tmp_path / "bezier_fit.json"
        result = benchmark.main(["--windows", "64", "--repeats", "1", "--out", str(out)])
    finally:
        if not had_timing:
            sys.modules.pop("_timing", None)  # a module beside the scripts: do not leak it to other tests
    assert json.loads(out.read_text()) == json.loads(json.dumps(result))
    assert result["throughput_data"] == "random walks" and result["batch_windows"] == 64
    assert "dataset_build" not in result
    for variant in ("pinned", "free"):
        timing = result["throughput"][variant]
        assert timing["windows_per_s"] > 0 and timing["steady_s"] > 0 and len(timing["times_s"]) == 1


# -------------------------------------------------------------------------- real LaFAN1


@pytest.mark.shared
@requires_shared
def test_lafan1_validation_curves_on_the_real_subset(tmp_path, monkeypatch):
    zip_path = SHARED_DATA / "lafan1" / "lafan1-subset.zip"
    if not zip_path.exists():
        pytest.skip(f"{zip_path} not found")
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))  # cold: parse (~5 s) and fit (~3 s)
    ds = curve_dataset(lafan1.load_lafan1(zip_path), "validation", progress=False)
    assert len(ds) == 3020 and np.bincount(ds.clip_index).tolist() == [1004, 943, 1073]  # subject 5's 3 files
    np.testing.assert_array_equal(ds.dense_pos[:, 0, HIPS, [0, 2]], 0.0)
    # Measured: mean fit RMS 0.276 cm; the mean per-joint error is the 0.211 cm that
    # fit_curves' docstring and experiments/bezier_stride.py report for pinned stride 6.
    assert 0.25 < ds.fit_rms.mean() < 0.30
    error = curve_errors(ds)
    assert error.mean() == pytest.approx(0.211, abs=1e-3)
    assert 0.5 < ds.dense_contacts.mean() < 0.9  # measured 0.69: feet mostly planted
