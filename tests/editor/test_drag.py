"""A drag with the exact IK: the sample's curves re-projected, the body warm-started, and
the exact IK's warm start itself (``start=``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from editor.common import options

import bezmotion as bm
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.editor import EditSession
from bezmotion.ik.protocol import IKTargets, pose_fk, targets_from_pose
from bezmotion.ik.rig import rig_ik, with_rest_pose
from bezmotion.data.windows import join_windows
from bezmotion.pipeline.inbetweening import pinned_frames, pose_from_curves, reproject_curves, window_handles

HAND = CHARACTERISTIC_JOINTS.index("right_hand")
MET_CM = 0.05  # the editor's promise: every handle met this closely after every edit and drag
reprojected = jax.jit(reproject_curves, static_argnames=("options", "keyed"))


@pytest.fixture(scope="module")
def model():
    return bm.pretrained("bandai_namco", ik="exact")  # the learned IK, then the exact solve


def test_a_drag_moves_the_curves_exactly_and_the_body_follows_onto_the_handle(clip, model, tmp_path):
    session = EditSession(clip, {"exact": model}, tmp_path, options=options())
    start = session.view.positions[12, HAND] + [0.0, 15.0, 0.0]
    hand = session.add_handle("right_hand", 12, start)
    committed = session.view
    keys = committed.pose
    for step in range(1, 5):  # a gizmo dragged up and forward
        target = start + step * np.array([0.0, 3.0, 2.0])
        view = session.drag(hand, target)
        assert np.linalg.norm(view.positions[12, HAND] - target) < 1e-3  # the curve through it, exactly
        assert view.handle_errors[hand] < MET_CM  # the body on it
        np.testing.assert_allclose(view.pose.quat_local[np.asarray([0, 30])], keys.quat_local[np.asarray([0, 30])], atol=1e-6)
    back = session.drag(hand, start)  # where it was: the sample's own curves, no new diffusion
    np.testing.assert_allclose(back.curves.ctrl_pos, committed.curves.ctrl_pos, atol=1e-3)
    np.testing.assert_allclose(back.curves.ctrl_tangent, committed.curves.ctrl_tangent, atol=1e-3)
    target = start + [0.0, 8.0, -6.0]
    session.drag(hand, target)
    released = session.release()
    expected = model.inbetween(
        model.poses(clip, [0, 30]), model.handles({"right_hand": (12, tuple(target))}),
        key=jax.random.fold_in(jax.random.key(0), 0), options=options(),
    )  # fmt: skip
    np.testing.assert_allclose(released.pose.quat_local, expected.pose.quat_local, atol=1e-5)
    assert released.handle_errors[hand] < MET_CM and released.misses == ()


def test_the_exact_ik_starts_from_the_poses_given(clip, model):
    """``start`` replaces the inner IK's poses and nothing else: given those very poses, the
    window solve is the one it makes without a start (to float32 rounding, compiled apart,
    which its accepted and refused steps amplify); given another pose, it ends elsewhere,
    on the handle all the same."""
    keys = model.poses(clip, [0, 30])
    handles = model.handles({"right_hand": (12, (0.0, 20.0, 0.0))}, relative_to=keys)
    result = model.inbetween(keys, handles, key=jax.random.key(1), options=options())
    windows = window_handles(handles, 1, 30)
    curves = reprojected(model.bmm, result.curves, windows, options())  # the sample's own: no handle moved
    params = with_rest_pose(model.ik_params, keys.quat_local[0])
    targets = IKTargets(join_windows(curves.positions), join_windows(curves.rot6d), pinned_frames(jax.tree.map(lambda a: a[0], windows), 31))
    solve = jax.jit(lambda start: pose_from_curves(model.ik_fn, params, curves, keys, handles=windows, start=start))
    inner = jax.jit(jax.vmap(model.ik_fn.inner, in_axes=(None, 0)))(params.inner, targets)
    np.testing.assert_allclose(solve(inner).quat_local, result.pose.quat_local, atol=1e-2)  # within a degree
    still = jax.tree.map(lambda a: jnp.broadcast_to(a[0], (31, *a.shape[1:])), keys)  # the first key, held
    elsewhere = solve(still)
    assert np.abs(elsewhere.quat_local - result.pose.quat_local).max() > 0.1  # started elsewhere, it ends elsewhere
    hand = model.character.characteristic[HAND]
    assert np.linalg.norm(pose_fk(model.character, elsewhere)[1][12, hand] - handles.position[0]) < MET_CM  # on the handle all the same


def test_only_an_ik_that_solves_windows_takes_a_start(clip, model):
    keys = model.poses(clip, [0, 30])
    handles = model.handles({"right_hand": (12, (0.0, 20.0, 0.0))}, relative_to=keys)
    result = model.inbetween(keys, handles, key=jax.random.key(0), options=options())
    curves = reprojected(model.bmm, result.curves, window_handles(handles, 1, 30), options())
    with pytest.raises(ValueError, match=r"a start pose needs an IK that solves whole windows \(one with solve_window\), got function"):
        pose_from_curves(rig_ik, model.ik_params.inner, curves, keys, start=result.pose)


def test_a_start_of_other_frames_is_refused(clip, model):
    keys = model.poses(clip, [0, 30])
    targets = targets_from_pose(model.character, model.poses(clip, slice(0, 31)))
    with pytest.raises(ValueError, match=r"start must be poses of the targets' 31 frames, got quat_local \(2, 22, 4\)"):
        model.ik_fn.solve_window(model.ik_params, targets, keys, start=keys)
