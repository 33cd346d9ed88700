"""The after-IK metrics (``bezmotion.evaluation.pipeline`` and ``bezmotion.evaluation.window_figures``):
full-body handles error and MPJPE against NumPy, the true windows' poses, per-window figures and
their summaries, and the pipeline evaluation end to end.
"""

from __future__ import annotations

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ik.demo_poses import frame, np_pose_positions, targets_of
from pipeline.common import FRAMES, K, STRIDE, handles_error, hips_only_ik, identity_quats

from bezmotion.bezier import BezierLayout, tangent_from_velocity
from bezmotion.evaluation.curves import floor_height_from, make_eval_set
from bezmotion.bmm.sampling import Handles
from bezmotion.ik.protocol import IKTargets, Pose, targets_from_pose
from bezmotion.evaluation.pipeline import mpjpe
from bezmotion.evaluation.pipeline import (
    chain_frame_handles,
    chain_rows,
    evaluate_pipeline,
    ground_truth_pose_metrics,
    pose_metrics,
    run_pipeline,
    sample_window_curves,
    window_key_velocities,
    window_keys,
    window_poses,
)
from bezmotion.evaluation.window_figures import PipelineMetricsConfig, curve_miss

mpjpe_of = jax.jit(mpjpe)


def lookup_ik(params: tuple[jax.Array, Pose], targets: IKTargets) -> Pose:
    """A "perfect" IK on known poses: the pose whose six target positions are nearest."""
    table, poses = params
    i = jnp.argmin(jnp.sum((table - targets.position) ** 2, axis=(-2, -1)))
    return jax.tree.map(lambda x: x[i], poses)


# The mocap's own rotation-change figures (the key-pop yardstick) that the ground truth also reports.
ROTATION_CHANGE = {"key_pop_deg", "max_rotation_change_deg"}

def test_full_body_handles_error_against_numpy(clip, rng):
    c = clip.character
    pose = jax.tree.map(lambda x: jnp.stack([x[:FRAMES], x[5 : 5 + FRAMES]]), clip.pose)  # (2, 31, …)
    joint = rng.integers(0, 6, (2, 4))
    control = rng.integers(0, K, (2, 4))
    valid = np.array([[True, True, False, True], [False, True, False, False]])
    position = rng.normal(scale=30.0, size=(2, 4, 3)) + clip.pos_global[0, 1]
    position[~valid] = np.nan  # padding is ignored, whatever it holds
    handles = Handles(
        jnp.asarray(joint, jnp.int32), jnp.asarray(control * STRIDE, jnp.int32), jnp.asarray(position, jnp.float32), jnp.asarray(valid)
    )
    pos = np_pose_positions(c, pose)  # (2, 31, 22, 3)
    idx = np.asarray(c.characteristic)
    errors = [
        np.linalg.norm(pos[b, control[b, s] * STRIDE, idx[joint[b, s]]] - position[b, s])
        for b in range(2) for s in range(4) if valid[b, s]
    ]  # fmt: skip
    got = float(handles_error(c, pose, handles, STRIDE))
    assert np.isfinite(got) and got == pytest.approx(np.mean(errors), rel=1e-5)
    # One motion alone, and no valid handle at all.
    one = float(handles_error(c, frame(pose, 1), frame(handles, 1), STRIDE))
    assert one == pytest.approx(errors[-1], rel=1e-5)
    assert float(handles_error(c, pose, handles._replace(valid=jnp.zeros((2, 4), bool)), STRIDE)) == 0.0
    # MPJPE: zero against itself, the shift's length against a shifted copy.
    assert float(mpjpe_of(c, pose, pose)) == 0.0
    shifted = pose._replace(root_pos=pose.root_pos + jnp.asarray([3.0, 0.0, 4.0]))
    assert float(mpjpe_of(c, shifted, pose)) == pytest.approx(5.0 * 21 / 22, rel=1e-4)  # joint_Root stays put


def test_window_poses_reproduce_the_curve_dataset(clip, curves):
    c, ds = clip.character, curves.dataset
    assert len(ds) == 2 and list(ds.start_frame) == [0, 5]
    truth = window_poses(c, curves.clips, ds, np.arange(2))
    assert truth.root_pos.shape == (2, FRAMES, 3) and truth.quat_local.shape == (2, FRAMES, 22, 4)
    np.testing.assert_array_equal(np.asarray(truth.root_pos)[:, 0, [0, 2]], np.zeros((2, 2)))
    np.testing.assert_array_equal(truth.quat_local[..., 0, :], np.broadcast_to([1.0, 0.0, 0.0, 0.0], (2, FRAMES, 4)))
    targets = targets_of(c, truth)
    np.testing.assert_allclose(targets.position, ds.dense_pos, atol=1e-3)
    np.testing.assert_allclose(targets.rot6d[:, ds.layout.control_frames], ds.ctrl_rot6d, atol=1e-5)
    # The windows are the clip's frames 0–30 and 5–35, moved in XZ only.
    for w, first in enumerate((0, 5)):
        moved = np.asarray(clip.pose.root_pos[first : first + FRAMES]) - np.asarray(truth.root_pos[w])
        np.testing.assert_allclose(moved - moved[0], 0.0, atol=1e-3)
        assert moved[0, 1] == 0.0
        np.testing.assert_array_equal(truth.quat_local[w], clip.pose.quat_local[first : first + FRAMES])
    # Rows pick windows, in the order given.
    swapped = window_poses(c, curves.clips, ds, np.array([1, 0]))
    np.testing.assert_array_equal(swapped.root_pos, np.asarray(truth.root_pos)[::-1])
    # Longer spans from the same starts (chains), within the 40-frame clip only.
    longer = window_poses(c, curves.clips, ds, np.arange(2), frames=35)
    np.testing.assert_array_equal(np.asarray(longer.root_pos)[:, :FRAMES], truth.root_pos)
    with pytest.raises(ValueError, match="window 1 .*36 frames from its start run past its clip's 40 frames"):
        window_poses(c, curves.clips, ds, np.arange(2), frames=36)


def test_chain_rows_and_chain_frame_handles(curves):
    ds = curves.dataset  # two windows of the 40-frame clip, at frames 0 and 5
    np.testing.assert_array_equal(chain_rows(ds, 1), [[0], [1]])
    with pytest.raises(ValueError, match="no chain of 2 windows: it needs 61 frames of one clip, and the longest clip's windows cover 36"):
        chain_rows(ds, 2)
    with pytest.raises(ValueError, match="a chain has at least 1 window, got 0"):
        chain_rows(ds, 0)
    handles = Handles(
        jnp.asarray([[[0, 1], [2, 3]]]), jnp.asarray([[[6, 29], [1, 12]]]), jnp.zeros((1, 2, 2, 3)), jnp.asarray([[[True, False], [True, True]]])
    )  # (chains, windows, handles)
    at = chain_frame_handles(handles, FRAMES)
    np.testing.assert_array_equal(at.frame, [[6, 29, 31, 42]])
    np.testing.assert_array_equal(at.joint, [[0, 1, 2, 3]])
    np.testing.assert_array_equal(at.valid, [[True, False, True, True]])
    assert at.position.shape == (1, 4, 3)


@pytest.fixture(scope="module")
def evaluation(clip, curves) -> SimpleNamespace:
    ds = curves.dataset
    eval_set = make_eval_set(ds, key=jax.random.key(5))
    truth = window_poses(clip.character, curves.clips, ds, eval_set.rows)
    config = PipelineMetricsConfig(stride=STRIDE, fps=ds.fps, floor_height=floor_height_from(ds))
    return SimpleNamespace(eval_set=eval_set, truth=truth, config=config)


def test_evaluate_pipeline_returns_finite_metrics_and_compiles_once(clip, bmm, evaluation):
    c, ev = clip.character, evaluation
    ik, rest = hips_only_ik(c), identity_quats(c.num_joints)
    metrics = evaluate_pipeline(ev.config, bmm, ik, rest, c, ev.truth, ev.eval_set, key=jax.random.key(2))
    assert set(metrics) == {"id", "ood"}
    for m in metrics.values():
        assert set(m) == {"handles_error_cm", "foot_skating_ratio", "mpjpe_cm", "key_pop_deg"}
        assert all(np.isfinite(v) for v in m.values())
        assert m["handles_error_cm"] >= 0.0 and 0.0 <= m["foot_skating_ratio"] <= 1.0 and m["mpjpe_cm"] > 1.0
    assert len(ik.traces) == 1, "the in-distribution and OOD runs must share one compilation"
    # The windows start and end on the true poses; same key and steps (10), same poses as evaluate_pipeline's.
    pose = run_pipeline(bmm, ik, rest, c, ev.truth, ev.eval_set.handles, key=jax.random.key(2), steps=10)
    assert len(ik.traces) == 1
    for i in (0, -1):
        np.testing.assert_array_equal(pose.root_pos[:, i], ev.truth.root_pos[:, i])
        np.testing.assert_array_equal(pose.quat_local[:, i], ev.truth.quat_local[:, i])
    again_metrics = pose_metrics(ev.config, c, pose, ev.truth, ev.eval_set.handles)
    assert again_metrics == pytest.approx(metrics["id"], rel=1e-6)


def test_metrics_of_the_truth_and_of_a_perfect_ik(clip, evaluation):
    c, ev = clip.character, evaluation
    truth_metrics = pose_metrics(ev.config, c, ev.truth, ev.truth, ev.eval_set.handles)
    assert truth_metrics["mpjpe_cm"] == 0.0
    assert truth_metrics["handles_error_cm"] < 1e-3  # the handles are the mocap's (pinned) control points
    flat = jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), ev.truth)
    table = jnp.asarray(np_pose_positions(c, flat)[:, list(c.characteristic)], jnp.float32)
    gt = ground_truth_pose_metrics(ev.config, c, ev.truth, lookup_ik, (table, flat))
    assert set(gt) - ROTATION_CHANGE == {"foot_skating_ratio", "ik_of_mocap_mpjpe_cm", "ik_of_mocap_foot_skating_ratio"}
    assert gt["foot_skating_ratio"] == truth_metrics["foot_skating_ratio"]
    assert gt["ik_of_mocap_mpjpe_cm"] < 1e-4
    assert gt["ik_of_mocap_foot_skating_ratio"] == pytest.approx(gt["foot_skating_ratio"], abs=1e-6)
    assert set(ground_truth_pose_metrics(ev.config, c, ev.truth)) - ROTATION_CHANGE == {"foot_skating_ratio"}


def test_key_velocities_from_the_clip_reach_the_curves_exactly(clip, bmm, evaluation):
    c, ev = clip.character, evaluation
    velocity = np.asarray(window_key_velocities(c, ev.truth))  # (windows, 2, 6, 3) cm/frame
    position = np.asarray(targets_from_pose(c, ev.truth).position)
    np.testing.assert_allclose(velocity[:, 0], position[:, 1] - position[:, 0], atol=1e-4)
    np.testing.assert_allclose(velocity[:, 1], position[:, -1] - position[:, -2], atol=1e-4)
    keys = window_keys(jax.random.key(3), ev.eval_set.rows)
    handles = ev.eval_set.handles
    plain = sample_window_curves(bmm, c, ev.truth, handles, keys, steps=2)
    given = sample_window_curves(bmm, c, ev.truth, handles, keys, steps=2, with_key_velocities=True)
    tangent = np.asarray(tangent_from_velocity(BezierLayout.from_controls(K, STRIDE), velocity))
    np.testing.assert_array_equal(np.asarray(given.curves.ctrl_tangent)[:, [0, -1]], tangent)
    assert np.abs(np.asarray(plain.curves.ctrl_tangent)[:, [0, -1]] - tangent).max() > 1e-2  # the model alone guesses otherwise
    # Still through the keys and every handle.
    np.testing.assert_array_equal(np.asarray(given.positions)[:, 0], position[:, 0])
    for w, s in zip(*np.nonzero(np.asarray(handles.valid))):
        got = np.asarray(given.positions)[w, int(handles.frame[w, s]), int(handles.joint[w, s])]
        np.testing.assert_allclose(got, np.asarray(handles.position)[w, s], atol=1e-3)


def test_curve_error_is_how_far_the_six_joints_lie_from_their_curves(clip):
    """``window_pose_metrics(..., curves=…)``: 0 on the pose's own six trajectories; moving one
    joint's curve by 2 cm on one frame gives that as the largest, and 2 / (frames · 6) on average."""
    from bezmotion.ik.protocol import pose_fk
    from bezmotion.evaluation.window_figures import summarize_windows, window_pose_metrics

    c = clip.character
    pose = jax.tree.map(lambda x: jnp.stack([x[:FRAMES], x[5 : 5 + FRAMES]]), clip.pose)  # (2, 31, …)
    six = np.asarray(pose_fk(c, pose)[1])[..., np.asarray(c.characteristic), :]
    handles = Handles(jnp.zeros((2, 1), jnp.int32), jnp.zeros((2, 1), jnp.int32), jnp.zeros((2, 1, 3)), jnp.zeros((2, 1), bool))
    config = PipelineMetricsConfig(STRIDE, 30.0, 0.0)
    own = summarize_windows(window_pose_metrics(config, c, pose, pose, handles, curves=jnp.asarray(six)))
    assert own["curve_error_cm"] < 1e-5 and own["curve_error_max_cm"] < 1e-4
    moved = six.copy()
    moved[1, 7, 3] += np.asarray([0.0, 2.0, 0.0], np.float32)  # the right hand of window 1, frame 7
    w = window_pose_metrics(config, c, pose, pose, handles, curves=jnp.asarray(moved))
    np.testing.assert_allclose(w["curve_error_max"], [0.0, 2.0], atol=1e-4)
    np.testing.assert_allclose(w["curve_error"], [0.0, 2.0 / (FRAMES * 6)], atol=1e-5)
    assert "curve_error" not in window_pose_metrics(config, c, pose, pose, handles)
    # One motion's worst miss and its frame, for a summary.
    assert curve_miss(six[1], six[1])["cm"] == 0.0
    assert curve_miss(six[1], moved[1]) == {"cm": pytest.approx(2.0, abs=1e-3), "frame": 7}


def test_planted_feet_rise_and_sink_against_their_curves(clip):
    """``foot_rise`` / ``foot_sink``: the feet's largest height above / below their curves on
    the frames where a curve's foot stands still horizontally; a moving curve's foot is not
    counted, and 0 where the feet lie on their curves."""
    from bezmotion.ik.protocol import pose_fk
    from bezmotion.evaluation.window_figures import summarize_windows, window_pose_metrics

    c = clip.character
    pose = jax.tree.map(lambda x: jnp.stack([x[:FRAMES], x[5 : 5 + FRAMES]]), clip.pose)  # (2, 31, …)
    six = np.asarray(pose_fk(c, pose)[1])[..., np.asarray(c.characteristic), :]
    curves = six.copy()
    left, right = 4, 5
    curves[..., [left, right], :] = curves[:, :1, [left, right], :]  # both feet's curves planted (still) throughout
    curves[..., [left, right], 1] = six[..., [left, right], 1]  # at the feet's own heights
    handles = Handles(jnp.zeros((2, 1), jnp.int32), jnp.zeros((2, 1), jnp.int32), jnp.zeros((2, 1, 3)), jnp.zeros((2, 1), bool))
    config = PipelineMetricsConfig(STRIDE, 30.0, 0.0)
    on = window_pose_metrics(config, c, pose, pose, handles, curves=jnp.asarray(curves))
    np.testing.assert_allclose(np.stack([on["foot_rise"], on["foot_sink"]]), 0.0, atol=1e-4)
    curves[0, 10, left, 1] -= 3.0  # window 0: the foot 3 cm above its curve on frame 10
    curves[1, 12, right, 1] += 1.5  # window 1: 1.5 cm below on frame 12
    curves[1, 20:, left, 0] += 10.0 * np.arange(FRAMES - 20)  # window 1's left foot moves from frame 20 …
    curves[1, 22:26, left, 1] -= 5.0  # … so its 5 cm above the curve there is no planted foot's
    w = window_pose_metrics(config, c, pose, pose, handles, curves=jnp.asarray(curves))
    np.testing.assert_allclose(w["foot_rise"], [3.0, 0.0], atol=1e-4)
    np.testing.assert_allclose(w["foot_sink"], [0.0, 1.5], atol=1e-4)
    out = summarize_windows(w)
    assert out["planted_foot_rise_cm"] == pytest.approx(1.5, abs=1e-4) and out["planted_foot_rise_max_cm"] == pytest.approx(3.0, abs=1e-4)
    assert out["planted_foot_sink_max_cm"] == pytest.approx(1.5, abs=1e-4)


def test_sliding_is_judged_on_the_curves_floor_contacts(clip):
    """``sliding``: the skating test on the IK'd feet's speeds with the curves' feet deciding
    which frames are on the floor. Feet sliding 20 cm above curves on the floor slide but do
    not skate by the paper's test; curves 20 cm up make the same feet neither."""
    from bezmotion.ik.protocol import pose_fk
    from bezmotion.evaluation.window_figures import paired_differences, summarize_windows, window_pose_metrics

    c = clip.character
    pose = jax.tree.map(lambda x: jnp.stack([x[:FRAMES], x[:FRAMES]]), clip.pose)  # (2, 31, …)
    lifted = pose._replace(root_pos=pose.root_pos + jnp.asarray([0.0, 20.0, 0.0]))  # every joint 20 cm up
    slide = 2.0 * jnp.arange(FRAMES, dtype=pose.root_pos.dtype)[:, None] * jnp.asarray([1.0, 0.0, 0.0])  # 60 cm/s along X
    lifted = lifted._replace(root_pos=lifted.root_pos + slide)
    six = np.asarray(pose_fk(c, pose)[1])[..., np.asarray(c.characteristic), :]
    floor = float(six[..., 4:6, 1].min())  # the clip's feet at their lowest: on the floor
    curves = six.copy()
    curves[1, ..., 1] += 20.0  # window 1's curves 20 cm up too
    handles = Handles(jnp.zeros((2, 1), jnp.int32), jnp.zeros((2, 1), jnp.int32), jnp.zeros((2, 1, 3)), jnp.zeros((2, 1), bool))
    config = PipelineMetricsConfig(STRIDE, 30.0, floor)
    w = window_pose_metrics(config, c, lifted, pose, handles, curves=jnp.asarray(curves))
    np.testing.assert_array_equal(w["skating"], [0.0, 0.0])  # 20 cm up: off the floor by the paper's test
    assert w["sliding"][0] > 0.5 and w["sliding"][1] == 0.0
    out = summarize_windows(w)
    assert out["foot_sliding_ratio"] == pytest.approx(w["sliding"].mean()) and out["foot_sliding_ratio_se"] is not None
    on_curves = window_pose_metrics(config, c, pose, pose, handles, curves=jnp.asarray(curves))
    np.testing.assert_array_equal(on_curves["sliding"][1], 0.0)
    paired = paired_differences(on_curves, w)
    assert paired["foot_sliding_ratio"]["mean"] == pytest.approx((w["sliding"] - on_curves["sliding"]).mean())


def test_summaries_give_each_mean_over_windows_its_standard_error():
    """``summarize_windows``: ``…_se`` is the windows' sample standard deviation over √n (a
    window with several values, e.g. dense error per joint, counts once, by its mean), and
    None for one window."""
    from bezmotion.evaluation.window_figures import standard_error, summarize_windows

    skating = np.asarray([0.0, 0.1, 0.2, 0.5])
    dense = np.asarray([[1.0, 3.0], [2.0, 2.0], [4.0, 6.0], [0.0, 2.0]])  # (windows, joints): means 2, 2, 5, 1
    out = summarize_windows({"skating": skating, "dense": dense})
    assert out["foot_skating_ratio_se"] == pytest.approx(np.std(skating, ddof=1) / 2.0)
    assert out["dense_error_cm_se"] == pytest.approx(np.std([2.0, 2.0, 5.0, 1.0], ddof=1) / 2.0)
    assert summarize_windows({"skating": skating}, np.asarray([True, False, False, False]))["foot_skating_ratio_se"] is None
    assert standard_error(np.full(9, 0.3)) == 0.0


def test_paired_differences_take_the_spread_of_the_differences_not_of_the_means():
    """Two IKs whose windows move together: each mean's own standard error is large, the
    difference's small; ``better_fraction`` counts windows where the second is lower."""
    from bezmotion.evaluation.window_figures import paired_differences, summarize_windows

    base = {"mpjpe": np.asarray([2.0, 8.0, 4.0, 10.0]), "skating": np.asarray([0.1, 0.3, 0.2, 0.2])}
    other = {"mpjpe": base["mpjpe"] + np.asarray([0.5, 0.7, 0.6, -0.2]), "skating": base["skating"]}
    out = paired_differences(base, other)
    assert out["mpjpe_cm"]["mean"] == pytest.approx(0.4)
    assert out["mpjpe_cm"]["se"] == pytest.approx(np.std([0.5, 0.7, 0.6, -0.2], ddof=1) / 2.0)
    assert out["mpjpe_cm"]["se"] < summarize_windows(base)["mpjpe_cm_se"] / 5.0
    assert out["mpjpe_cm"]["median"] == pytest.approx(0.55) and out["mpjpe_cm"]["better_fraction"] == 0.25
    assert out["foot_skating_ratio"] == {"mean": 0.0, "se": 0.0, "median": 0.0, "better_fraction": 0.5, "windows": 4}
    assert "curve_error_cm" not in out  # neither has it
    picked = paired_differences(base, other, np.asarray([True, True, False, False]))
    assert picked["mpjpe_cm"]["mean"] == pytest.approx(0.6) and picked["mpjpe_cm"]["windows"] == 2
    with pytest.raises(ValueError, match=r"mpjpe has shapes \(4,\) and \(3,\)"):
        paired_differences(base, {"mpjpe": np.zeros(3)})


def test_a_handle_that_no_pose_meets_with_another_counts_as_unreachable(clip):
    """``reach_chains(...).apart``: the bones between two characteristic joints;
    ``conflicting_handles``: two handles of one frame farther apart than that (+1 cm).
    ``handle_unreachable``: a hips handle missed on a frame whose hand handle no pose meets
    with it is unreachable; a hips handle met there is not (the hand is: beyond its arm), nor
    a hips handle missed with no such partner."""
    from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
    from bezmotion.ik.protocol import pose_fk
    from bezmotion.ik.rig import make_rig
    from bezmotion.evaluation.window_figures import conflicting_handles, reach_chains, window_pose_metrics

    c = clip.character
    hand, left_hand, head = (CHARACTERISTIC_JOINTS.index(r) for r in ("right_hand", "left_hand", "head"))
    chains = reach_chains(make_rig(c, "bandai_namco", rest_quat_local=np.asarray(clip.pose.quat_local[0])))
    bone = lambda j: float(np.linalg.norm(np.asarray(c.skeleton.offsets[j])))  # noqa: E731

    def up_to(joint, stop):  # the bones from ``stop`` (exclusive) down to ``joint``
        total = 0.0
        while joint != stop:
            total, joint = total + bone(joint), c.skeleton.parents[joint]
        return total

    path = up_to(c.characteristic[hand], c.characteristic[HIPS])
    assert chains.apart[HIPS, hand] == pytest.approx(path, rel=1e-6) == chains.apart[hand, HIPS]
    assert chains.apart[HIPS, head] == pytest.approx(chains.length[head]) and np.all(np.diag(chains.apart) == 0.0)
    # The hands meet where their arms leave the spine (the chest), not at the hips.
    chest = c.skeleton.names.index("Chest")
    both = up_to(c.characteristic[hand], chest) + up_to(c.characteristic[left_hand], chest)
    assert chains.apart[hand, left_hand] == pytest.approx(both, rel=1e-6) and both < 2 * path

    spread = jnp.asarray([[0.0, 0.0, 0.0], [both + 0.5, 0.0, 0.0], [both + 2.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    pairs = Handles(
        joint=jnp.asarray([left_hand, hand, hand, hand], jnp.int32),
        frame=jnp.asarray([7, 7, 7, 8], jnp.int32),
        position=spread,
        valid=jnp.asarray([True, True, True, True]),
    )
    conflict = np.asarray(conflicting_handles(pairs, chains))
    expected = np.zeros((4, 4), bool)
    expected[0, 2] = expected[2, 0] = True  # 2 cm beyond the arms' span; 0.5 cm is within the tolerance
    expected[1, 2] = expected[2, 1] = True  # one joint in two places 1.5 cm apart on one frame
    np.testing.assert_array_equal(conflict, expected)
    assert not np.asarray(conflicting_handles(pairs._replace(valid=jnp.asarray([True, True, False, True])), chains)).any()

    pose = jax.tree.map(lambda x: jnp.stack([x[:FRAMES]] * 3), clip.pose)  # (3 windows, 31, …): the truth
    six = np.asarray(pose_fk(c, pose)[1])[..., np.asarray(c.characteristic), :]
    far = np.asarray([0.0, 0.0, path + 30.0], np.float32)  # 30 cm beyond the hand's reach from the hips
    hips5, hand5 = six[0, 5, HIPS], six[0, 5, hand]
    position = np.stack([
        [hips5, hips5 + far, hips5],  # met hips, hand out of reach of it: the hand is unreachable
        [hand5 + far, hand5, hips5],  # hips 30+ cm off, the hand met: the hips is unreachable
        [hips5 + np.float32([0.0, 10.0, 0.0]), hand5, hips5],  # hips 10 cm off, nothing against it: an avoidable miss
    ])
    handles = Handles(
        joint=jnp.asarray([[HIPS, hand, HIPS]] * 3, jnp.int32),
        frame=jnp.asarray([[5, 5, 9]] * 3, jnp.int32),
        position=jnp.asarray(position),
        valid=jnp.asarray([[True, True, False]] * 3),  # a padding slot on the hips, at another frame
    )
    w = window_pose_metrics(PipelineMetricsConfig(STRIDE, 30.0, 0.0), c, pose, pose, handles, chains=chains)
    np.testing.assert_array_equal(w["handle_unreachable"], [[False, True, False], [True, False, False], [False, False, False]])
    assert w["handle_error"][2, 0] == pytest.approx(10.0, abs=1e-3)
