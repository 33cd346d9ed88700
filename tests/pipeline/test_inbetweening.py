"""``inbetween`` (``bezmotion.pipeline.inbetweening``) of one window (two keys): BMM curves
→ dense trajectories → ``ik_fn`` per frame, with the handles and keyframes hit, any plain
function as an IK, and the input checks.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ik.demo_poses import fk, np_rot6d, targets_of
from pipeline.common import FRAMES, K, LEFT_HAND, STEPS, STRIDE, handles_error, model_of

from bezmotion.data.characteristic import HIPS
from bezmotion.ik.protocol import IKTargets, Pose
from bezmotion.pipeline import InbetweenOptions, inbetween


def test_inbetween_curves_pass_through_the_handles_and_the_keyframes(run):
    r, h = run.result, run.handles
    assert r.positions.shape == (FRAMES, 6, 3) and r.rot6d.shape == (FRAMES, 6, 6)
    assert r.pose.root_pos.shape == (FRAMES, 3) and r.pose.quat_local.shape == (FRAMES, 22, 4)
    assert r.curves.ctrl_pos.shape == (1, K, 6, 3) and all(np.isfinite(np.asarray(a)).all() for a in (*r.curves, *r.pose))
    curves = r.joined_curves()
    ctrl = np.asarray(curves.ctrl_pos)
    # Bit for bit at the handles' control points; the padding slot (NaN) is no constraint.
    np.testing.assert_array_equal(ctrl[2, HIPS], np.asarray(h.position[0]))
    np.testing.assert_array_equal(ctrl[3, LEFT_HAND], np.asarray(h.position[1]))
    # The end control points are the given poses' six joints, positions and orientations.
    for pose, k in ((run.start, 0), (run.end, K - 1)):
        t = targets_of(run.character, pose)
        np.testing.assert_allclose(ctrl[k], t.position, atol=1e-3)
        np.testing.assert_allclose(curves.ctrl_rot6d[k], t.rot6d, atol=1e-5)
    # The dense trajectories IK receives go through all of them.
    np.testing.assert_allclose(r.positions[12, HIPS], h.position[0], atol=1e-3)
    np.testing.assert_allclose(r.positions[18, LEFT_HAND], h.position[1], atol=1e-3)
    np.testing.assert_allclose(np.asarray(r.positions)[[0, -1]], ctrl[[0, -1]], atol=1e-3)


def test_keep_keyframes_returns_the_given_start_and_end_poses(run):
    pose = run.result.pose
    for i, given in ((0, run.start), (-1, run.end)):
        np.testing.assert_array_equal(pose.root_pos[i], given.root_pos)
        np.testing.assert_array_equal(pose.quat_local[i], given.quat_local)
    # Every other frame is the IK's own: body at identity (what hips-only IK gives).
    body = np.delete(np.asarray(pose.quat_local[1:-1]), run.character.hips, axis=1)
    np.testing.assert_array_equal(body, np.tile([1.0, 0.0, 0.0, 0.0], (FRAMES - 2, 21, 1)))
    assert not np.allclose(np.asarray(run.start.quat_local), [1.0, 0.0, 0.0, 0.0])


def test_hips_only_ik_has_no_full_body_error_on_a_hips_handle(run):
    r, h, c = run.result, run.handles, run.character
    # The IK puts the hips on the trajectory, oriented as the curves say.
    np.testing.assert_array_equal(r.pose.root_pos[1:-1], r.positions[1:-1, HIPS])
    quat, _ = fk(c, r.pose)
    np.testing.assert_allclose(np_rot6d(np.asarray(quat[1:-1, c.hips])), r.rot6d[1:-1, HIPS], atol=1e-5)
    hips_only = h._replace(valid=jnp.asarray([True, False, False]))
    assert float(handles_error(c, r.pose, hips_only, STRIDE)) < 1e-4
    # The hand handle is out of this IK's reach: the metric sees it.
    hand_only = h._replace(valid=jnp.asarray([False, True, False]))
    assert float(handles_error(c, r.pose, hand_only, STRIDE)) > 5.0


def test_any_plain_function_is_an_ik_and_compiles_once(clip, bmm, run):
    traces = []

    def translated_rest(params: dict, targets: IKTargets) -> Pose:  # ignores orientations
        traces.append(1)
        return Pose(targets.position[HIPS] + params["shift"], params["rest"])

    params = {"shift": jnp.asarray([0.0, 2.0, 0.0]), "rest": clip.pose.quat_local[20]}
    model = model_of(bmm, translated_rest, params, run.character)
    options = InbetweenOptions(steps=STEPS, keep_keyframes=False)
    first = inbetween(model, run.keys, run.handles, key=jax.random.key(0), options=options)
    second = inbetween(model, run.keys, run.handles, key=jax.random.key(1), options=options)
    assert len(traces) == 1, "a second call with the same shapes must not retrace"
    for r in (first, second):
        np.testing.assert_allclose(r.pose.root_pos, r.positions[:, HIPS] + np.array([0.0, 2.0, 0.0]), atol=1e-4)
        # Without keep_keyframes the first and last frames are the IK's too.
        np.testing.assert_array_equal(r.pose.quat_local, np.broadcast_to(params["rest"], (FRAMES, 22, 4)))
    assert not np.allclose(first.curves.ctrl_tangent, second.curves.ctrl_tangent)


def test_inbetween_rejects_bad_inputs(run):
    def call(keys=run.keys, handles=run.handles, **kwargs):
        return inbetween(run.model, keys, handles, key=run.key, options=InbetweenOptions(steps=STEPS), **kwargs)

    with pytest.raises(ValueError, match=r"poses of bandai_namco batched \(K, …\).*got \(3,\), \(22, 4\)"):
        call(keys=run.start)
    with pytest.raises(ValueError, match=r"at least 2 keys, got 1"):
        call(keys=jax.tree.map(lambda x: x[:1], run.keys))
    with pytest.raises(ValueError, match=r"\(K, 22, 4\); got \(2, 3\), \(2, 21, 4\)"):
        call(keys=run.keys._replace(quat_local=run.keys.quat_local[:, :21]))
    with pytest.raises(ValueError, match="key 0 contains non-finite values"):
        call(keys=run.keys._replace(root_pos=run.keys.root_pos.at[0, 1].set(jnp.nan)))
    with pytest.raises(ValueError, match="key 1 contains non-finite values"):
        call(keys=run.keys._replace(quat_local=run.keys.quat_local.at[1, 3, 0].set(jnp.inf)))
    with pytest.raises(ValueError, match=r"handles must be \(slots, 3\).*got \(1, 3, 3\)"):
        call(handles=jax.tree.map(lambda x: x[None], run.handles))
    with pytest.raises(ValueError, match=r"on a key: handles go on frames 1 … 29, not on the keys' frames \[0, 30\]"):
        call(handles=run.handles._replace(frame=run.handles.frame.at[1].set(30)))
    with pytest.raises(ValueError, match="position not finite"):
        call(handles=run.handles._replace(position=run.handles.position.at[0, 2].set(jnp.nan)))
    with pytest.raises(ValueError, match=r"key_velocity must be \(2, 6, 3\)"):
        call(key_velocity=np.zeros((3, 6, 3)))


def test_inbetween_checks_values_inside_a_callers_jit_too(run):
    """The checks are one path: inside a caller's ``jax.jit`` they run with the computation."""

    @jax.jit
    def mine(keys):
        return inbetween(run.model, keys, run.handles, key=run.key, options=InbetweenOptions(steps=STEPS)).pose.root_pos

    assert np.isfinite(np.asarray(mine(run.keys))).all()
    with pytest.raises(Exception, match="key 1 contains non-finite values"):
        jax.block_until_ready(mine(run.keys._replace(root_pos=run.keys.root_pos.at[1, 0].set(jnp.nan))))


def test_inbetween_options_are_hashable_and_checked():
    assert hash(InbetweenOptions()) == hash(InbetweenOptions())
    for bad in (dict(steps=0), dict(key_blend_frames=-1), dict(guidance=float("nan"))):
        with pytest.raises(ValueError, match="InbetweenOptions"):
            InbetweenOptions(**bad)
    for bad in (dict(steps=2.5), dict(foot_lock="mean")):  # TypeError where the test session checks annotations
        with pytest.raises((ValueError, TypeError)):
            InbetweenOptions(**bad)


@pytest.mark.parametrize(
    ("what", "message"),
    [
        ("joint 9", "handle 0: joint index outside 0 … 5"),
        ("nan", "handle 1: position not finite"),
        ("far", "handle 0: farther than 100 m"),
        ("frame 45", "outside the in-between or on a key"),
        ("frame 12.5", "handles.frame must be integers"),
        ("conflict", "another handle puts the same joint at the same frame elsewhere"),
    ],
)
def test_every_malformed_handle_is_refused_naming_it(run, what, message):
    """Raw ``Handles`` are checked where they enter, eagerly with the slot that fails."""
    h = run.handles
    bad = {
        "joint 9": lambda: h._replace(joint=h.joint.at[0].set(9)),
        "nan": lambda: h._replace(position=h.position.at[1, 0].set(jnp.nan)),
        "far": lambda: h._replace(position=h.position.at[0].set(1e30)),
        "frame 45": lambda: h._replace(frame=h.frame.at[0].set(45)),
        "frame 12.5": lambda: h._replace(frame=h.frame.astype(jnp.float32).at[0].set(12.5)),
        "conflict": lambda: h._replace(position=h.position.at[2].set(h.position[0] + 5.0), valid=h.valid.at[2].set(True)),
    }[what]()
    with pytest.raises(ValueError, match=message):
        inbetween(run.model, run.keys, bad, key=run.key, options=InbetweenOptions(steps=STEPS))


def test_the_sampler_checks_raw_handles_too(bmm, run):
    """``sample_curves`` alone (no in-between around it) refuses the same handles."""
    from bezmotion.bmm.sampling import sample_curves
    from bezmotion.ik.protocol import targets_from_pose

    ends = targets_from_pose(run.character, run.keys).position
    h = run.handles._replace(joint=run.handles.joint.at[1].set(-1))
    with pytest.raises(ValueError, match="handle 1: joint index outside 0 … 5"):
        sample_curves(bmm, ends[0], ends[1], h, key=run.key, steps=1)
