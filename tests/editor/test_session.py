"""The editing session as a plain object: handles, keys, samples, undo and redo, export.

The bundled models with the analytic rig and 2 DDIM steps; the exact IK's warm-started drag
is tested in ``test_drag.py``.
"""

from __future__ import annotations

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from editor.common import options

import bezmotion as bm
from bezmotion.cli.handles import read_handles_file, records_as_handles
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.editor import EditSession
from bezmotion.ik.protocol import pose_fk, targets_from_pose
from bezmotion.pipeline.authoring import bvh_fk_error_cm
from bezmotion.pipeline.gltf import read_glb
from bezmotion.pipeline.model import HANDLE_SLOTS

HAND = CHARACTERISTIC_JOINTS.index("right_hand")


def curve_at(session: EditSession, joint: str, frame: int) -> np.ndarray:
    return session.view.positions[frame, CHARACTERISTIC_JOINTS.index(joint)]


def test_a_state_shows_the_inbetween_bezmotion_inbetween_makes_of_it(session, rig_model, clip):
    """Keys, handles and seed give what ``model.inbetween`` (the command's call) gives, with
    the command's first sample's key; the ghost is the clip between the keys."""
    hand = session.add_handle("right_hand", 12, curve_at(session, "right_hand", 12) + [0.0, 15.0, 0.0])
    session.use_seed(3)
    keys = rig_model.poses(clip, [0, 30])
    handles = rig_model.handles({"right_hand": (12, session.state.handles[0].position)})
    expected = rig_model.inbetween(keys, handles, key=jax.random.fold_in(jax.random.key(3), 0), options=options())
    view = session.view
    np.testing.assert_allclose(view.pose.quat_local, expected.pose.quat_local, atol=1e-6)
    np.testing.assert_allclose(view.curves.ctrl_pos, expected.joined_curves().ctrl_pos, atol=1e-4)
    np.testing.assert_allclose(view.joints, pose_fk(rig_model.character, expected.pose)[1], atol=1e-3)
    assert view.joints.shape == (31, 22, 3) and view.curves.ctrl_pos.shape == (6, 6, 3) and view.positions.shape == (31, 6, 3)
    assert np.linalg.norm(view.positions[12, HAND] - np.asarray(session.state.handles[0].position)) < 1e-3  # the curve, exactly
    assert set(view.handle_errors) == {hand}
    np.testing.assert_allclose(session.ghost, pose_fk(rig_model.character, rig_model.poses(clip, slice(0, 31)))[1], atol=1e-3)
    assert (session.frames, session.key_frames, session.clip_frames) == (31, (0, 30), 40)


def test_handles_are_added_moved_and_deleted_by_id(session):
    before = curve_at(session, "left_foot", 20).copy()
    first = session.add_handle("left_foot", 20)  # where its curve is: a pin
    second = session.add_handle("Hand_R", 8, curve_at(session, "right_hand", 8) + [0.0, 0.0, 10.0])  # the skeleton's own name
    assert (first, second) == (0, 1)
    assert session.state.handles[0].position == pytest.approx(tuple(before))
    assert [(h.id, h.joint, h.frame) for h in session.state.handles] == [(0, "left_foot", 20), (1, "right_hand", 8)]
    target = np.asarray(session.state.handles[1].position) + [5.0, 0.0, 0.0]
    session.move_handle(second, target)
    assert np.linalg.norm(curve_at(session, "right_hand", 8) - target) < 1e-3
    session.delete_handle(first)
    assert [h.id for h in session.state.handles] == [second]
    assert session.add_handle("left_foot", 20) == 2  # ids are never reused
    assert set(session.view.handle_errors) == {1, 2}


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda s: s.add_handle("left_elbow", 12), "handle 0: unknown joint 'left_elbow'"),
        (lambda s: s.add_handle("right_hand", 31), "handle 0: frame 31 is outside the in-between, frames 0…30"),
        (lambda s: s.add_handle("right_hand", 30), "handle 0: handles sit on integer frames strictly between 0 and 30"),
        (lambda s: s.add_handle("right_hand", 0), "handle 0: handles sit on integer frames strictly between 0 and 30"),
        (lambda s: s.add_handle("right_hand", 12, [0.0, float("nan"), 0.0]), "handle 0: a position is 3 finite numbers"),
        (lambda s: s.add_handle("right_hand", 12, [0.0, 1.0]), "handle 0: a position is 3 finite numbers"),
        (lambda s: s.add_handle("right_hand", 12, [1e6, 0.0, 0.0]), "farther than 100 m"),
        (lambda s: s.move_handle(7, [0.0, 0.0, 0.0]), "no handle 7; the handles are none"),
        (lambda s: s.delete_handle(7), "no handle 7"),
        (lambda s: s.drag(7, [0.0, 0.0, 0.0]), "no handle 7"),
        (lambda s: s.release(), "no handle is being dragged"),
        (lambda s: s.undo(), "nothing to undo"),
        (lambda s: s.redo(), "nothing to redo"),
        (lambda s: s.set_keys([0]), "at least two keys, got [0]"),
        (lambda s: s.set_keys([0, 40]), "key 40: keys are frames 0 … 39 of the clip"),
        (lambda s: s.add_key(), "key 60: keys are frames 0 … 39"),
        (lambda s: s.use_seed(-1), "a seed is an integer ≥ 0, got -1"),
        (lambda s: s.set_ik("exact"), "unknown IK 'exact'; this session has rig"),
        (lambda s: s.set_key_velocities(True), "key velocities: the start key at frame 0 is the first frame of its file"),
    ],
)
def test_a_refused_edit_says_why_in_one_line_and_changes_nothing(session, edit, message):
    state = session.state
    with pytest.raises(ValueError) as error:
        edit(session)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert session.state is state and not session.can_undo


def test_a_second_handle_on_one_joint_and_frame_is_refused(session):
    session.add_handle("right_hand", 12)
    with pytest.raises(ValueError, match=r"handle 1: right_hand at frame 12 has a handle already, handle 0; move that one"):
        session.add_handle("right_hand", 12, [0.0, 0.0, 0.0])


def test_adding_handles_up_to_the_slot_count_compiles_nothing_more(session, rig_model):
    """Handles are padded to HANDLE_SLOTS: the second to fourth handle reuse the in-between
    and the drag compiled for the first (the rig IK is traced once per compilation)."""
    first = session.add_handle("right_hand", 12)
    session.drag(first, curve_at(session, "right_hand", 12) + [0.0, 5.0, 0.0])
    session.release()
    traced = len(rig_model.ik_fn.traces)
    for joint, frame in (("left_hand", 9), ("left_foot", 15), ("head", 21)):
        added = session.add_handle(joint, frame)
        session.drag(added, curve_at(session, joint, frame) + [0.0, 3.0, 0.0])
        session.release()
    assert len(rig_model.ik_fn.traces) == traced


def test_undo_and_redo_walk_the_states_and_their_views_come_back_unchanged(session):
    views = [session.view]
    hand = session.add_handle("right_hand", 12)
    views.append(session.view)
    session.move_handle(hand, curve_at(session, "right_hand", 12) + [0.0, 10.0, 0.0])
    views.append(session.view)
    states = [session.state]
    assert session.undo() is views[1] and session.undo() is views[0]  # kept: no new sample
    assert session.state.handles == () and not session.can_undo and session.can_redo
    session.redo()
    assert session.redo() is views[2] and session.state == states[0] and not session.can_redo
    session.undo()
    session.delete_handle(hand)  # a new edit: the undone one is gone
    assert not session.can_redo


def test_resample_draws_new_seeds_and_flips_back_to_an_earlier_one(session):
    first = session.view
    second = session.resample()
    assert session.state.seed == 1 and session.seeds == (0, 1)
    assert not np.allclose(second.curves.ctrl_pos, first.curves.ctrl_pos)
    assert session.use_seed(0) is first
    session.resample()
    assert session.state.seed == 2 and session.seeds == (0, 1, 2)


def test_keys_make_a_chain_and_handles_keep_their_frames(session, rig_model, clip):
    hand = session.add_handle("right_hand", 12)
    session.add_key(9)  # any clip frame, 30 frames after the last key (as --key puts them)
    assert session.state.keys == (0, 30, 9) and session.frames == 61 and session.key_frames == (0, 30, 60)
    far = session.add_handle("left_hand", 45, curve_at(session, "left_hand", 45) + [0.0, 10.0, 0.0])
    assert np.linalg.norm(curve_at(session, "left_hand", 45) - np.asarray(session.state.handles[1].position)) < 1e-3
    assert set(session.view.handle_errors) == {hand, far}
    # The ghost: the second window spreads the clip's frames 30 … 9 over its 31 frames.
    np.testing.assert_allclose(session.ghost[60], pose_fk(rig_model.character, rig_model.poses(clip, [9]))[1][0], atol=1e-3)
    with pytest.raises(ValueError, match=r"handle 1: frame 45 is outside the in-between, frames 0…30"):
        session.set_keys([0, 30])
    assert session.state.keys == (0, 30, 9)


def test_key_velocities_are_the_clips_around_each_key(session, rig_model, clip):
    session.set_keys([1, 31])
    view = session.set_key_velocities(True)
    six = np.asarray(targets_from_pose(rig_model.character, rig_model.poses(clip, [0, 1, 31, 32])).position)
    velocity = np.stack([six[1] - six[0], six[3] - six[2]])  # into the first key, out of the last
    expected = rig_model.inbetween(
        rig_model.poses(clip, [1, 31]), records_as_handles([], slots=HANDLE_SLOTS),
        key=jax.random.fold_in(jax.random.key(0), 0), options=options(), key_velocity=jnp.asarray(velocity),
    )  # fmt: skip
    np.testing.assert_allclose(view.curves.ctrl_tangent, expected.joined_curves().ctrl_tangent, atol=1e-3)
    assert session.state.key_velocities
    session.set_foot_lock(False)
    assert not session.state.options.foot_lock and session.state.key_velocities


def test_another_ik_is_another_state(clip, rig_model, tmp_path):
    session = EditSession(clip, {"rig": rig_model, "also_rig": rig_model}, tmp_path, options=options())
    assert session.ik_choices == ("rig", "also_rig") and session.state.ik == "rig"
    session.set_ik("also_rig")
    assert session.state.ik == "also_rig"
    session.undo()
    assert session.state.ik == "rig"


def test_drag_moves_the_curves_until_release_makes_it_an_edit(session):
    hand = session.add_handle("right_hand", 12)
    committed = session.state
    target = curve_at(session, "right_hand", 12) + [0.0, 12.0, -4.0]
    dragged = session.drag(hand, target)
    assert np.linalg.norm(dragged.positions[12, HAND] - target) < 1e-3 and session.view is dragged
    assert session.state is committed  # not an edit yet
    assert session.cancel_drag() is session.view and session.state is committed
    session.drag(hand, target)
    released = session.release()
    assert session.state.handles[0].position == pytest.approx(tuple(target)) and session.can_undo
    assert np.linalg.norm(released.positions[12, HAND] - target) < 1e-3  # resampled, through the handle
    session.undo()
    assert session.state is committed


def test_export_writes_one_set_in_the_output_folder_and_reads_its_handles_back(session, rig_model, tmp_path):
    hand = session.add_handle("right_hand", 12, curve_at(session, "right_hand", 12) + [0.0, 20.0, 0.0])
    files = session.export("take")
    out = tmp_path / "out"
    assert files == {"bvh": out / "take.bvh", "glb": out / "take.glb", "handles": out / "take.handles.json"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert bvh_fk_error_cm(files["bvh"], session.character, session.view.pose) < 1e-3
    glb = read_glb(files["glb"])
    np.testing.assert_allclose(glb.ctrl_pos, session.view.curves.ctrl_pos, atol=1e-3)
    assert [(r.joint, r.frame, r.relative) for r in read_handles_file(files["handles"])] == [("right_hand", 12, False)]
    assert json.loads(files["handles"].read_text())["seed"] == 0
    position = session.state.handles[0].position
    session.delete_handle(hand)
    session.open_handles("take.handles.json")
    [reopened] = session.state.handles
    assert (reopened.joint, reopened.frame, reopened.position) == ("right_hand", 12, pytest.approx(position))
    session.export("take")  # its own earlier export: replaced


@pytest.mark.parametrize("name", ["../take", "a/b", ".take", "", "take.bvh", "x" * 65, "/tmp/take"])
def test_an_export_is_named_by_a_plain_name(session, name, tmp_path):
    with pytest.raises(ValueError, match="an export's name is 1 to 64 letters"):
        session.export(name)
    assert not (tmp_path / "out").exists()


def test_an_export_never_replaces_a_file_bezmotion_did_not_write(session, tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "take.bvh").write_text("mine")
    with pytest.raises(ValueError, match=r"exporting take would replace take\.bvh, which is not bezmotion's own output"):
        session.export("take")
    assert (tmp_path / "out" / "take.bvh").read_text() == "mine"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["take.bvh"]


def test_handles_files_are_read_from_the_output_folder_alone(session, rig_model, clip, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "outside.json").write_text('[{"joint": "right_hand", "frame": 12, "offset": [0, 10, 0]}]')
    os.symlink(tmp_path / "outside.json", out / "link.json")
    (out / "bad.json").write_text("{not json")
    (out / "outside.json").write_text('[{"joint": "right_hand", "frame": 31, "offset": [0, 10, 0]}]')
    for name, message in [
        ("../outside.json", "a handles file is named by its plain file name"),
        (str(tmp_path / "outside.json"), "a handles file is named by its plain file name"),
        (".hidden", "a handles file is named by its plain file name"),
        ("link.json", "link.json: no such file in"),
        ("missing.json", "missing.json: no such file in"),
        ("bad.json", "bad.json: "),
        ("outside.json", "outside.json: handle 0 (right_hand@31): frame 31 is outside the in-between"),
    ]:
        with pytest.raises(ValueError) as error:
            session.open_handles(name)
        assert message in str(error.value) and "\n" not in str(error.value) and not str(error.value).startswith("--")
    assert session.state.handles == ()
    (out / "offsets.json").write_text('{"handles": [{"joint": "right_hand", "frame": 15, "offset": [0, 10, 0]}]}')
    session.open_handles("offsets.json")  # an offset from the line between the keys, as the command reads it
    keys = np.asarray(targets_from_pose(rig_model.character, rig_model.poses(clip, [0, 30])).position)
    line = (keys[0, HAND] + keys[1, HAND]) / 2
    np.testing.assert_allclose(session.state.handles[0].position, line + [0.0, 10.0, 0.0], atol=1e-3)


def test_open_reads_a_clip_and_its_models(tmp_path):
    session = EditSession.open(bm.DEMO_CLIP, tmp_path, ik="rig", options=options())
    assert session.state.ik == "rig" and "exact" in session.ik_choices and session.character.num_joints == 22
    with pytest.raises(FileNotFoundError):
        EditSession.open(tmp_path / "missing.bvh", tmp_path)


def test_a_drag_in_a_chain_keeps_the_shared_key_and_its_tangent(session):
    """Coupled windows share their key's control point and tangent (C¹): a handle dragged
    next to it moves the curve through the handle and leaves both as sampled."""
    session.add_key(9)
    hand = session.add_handle("left_hand", 33)
    committed = session.view
    target = curve_at(session, "left_hand", 33) + [0.0, 10.0, 5.0]
    view = session.drag(hand, target)
    assert np.linalg.norm(view.positions[33, CHARACTERISTIC_JOINTS.index("left_hand")] - target) < 1e-3
    shared = 5  # the joined curve's control point on frame 30
    np.testing.assert_array_equal(view.curves.ctrl_pos[shared], committed.curves.ctrl_pos[shared])
    np.testing.assert_array_equal(view.curves.ctrl_tangent[shared], committed.curves.ctrl_tangent[shared])
