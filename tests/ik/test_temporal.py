"""Filters over a window's frames (bezmotion.ik.temporal): one-frame and lasting flips of an
inner IK's poses, the temporal smoothing, planted feet. Synthetic rotations of known angles."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bezmotion.geometry.rotations import quat_angle, quat_from_axis_angle, quat_mul
from bezmotion.ik.protocol import Pose
from bezmotion.ik.temporal import limit_turns, planted_feet, remove_spikes, smooth, turn_out_of_keys, turns_near_keys
from bezmotion.evaluation.metrics import rotation_change_deg


def test_planted_feet_marks_still_foot_targets_only():
    """A foot target moving less than ``plant_step`` cm horizontally to the next frame or from
    the one before is planted (both frames of a still step), whatever its height does; hips,
    head and hands never are."""
    position = jnp.zeros((5, 6, 3)).at[:, 5, 0].set(jnp.asarray([0.0, 1.0, 1.1, 5.0, 9.0]))  # right foot: moving, still, moving
    position = position.at[:, 4, 1].set(jnp.asarray([0.0, 2.0, 4.0, 6.0, 8.0]))  # left foot: its heel rising, still planted
    position = position.at[:, 3, 0].set(0.0)  # a still hand stays unplanted
    planted = np.asarray(planted_feet(position, 0.5))
    np.testing.assert_array_equal(planted[:, 4], [True] * 5)
    np.testing.assert_array_equal(planted[:, 5], [False, True, True, False, False])  # frames 1 and 2: the still step's two ends
    ends = position.at[:, 5, 0].set(jnp.asarray([0.0, 5.0, 9.0, 9.1, 9.2]))  # still from frame 2 to the end
    np.testing.assert_array_equal(np.asarray(planted_feet(ends, 0.5))[:, 5], [False, False, True, True, True])
    batched = np.asarray(planted_feet(jnp.stack([position, ends]), 0.5))
    np.testing.assert_array_equal(batched[:, :, 5], [[False, True, True, False, False], [False, False, True, True, True]])
    assert not planted[:, :4].any()


def test_one_frame_flips_of_the_inner_ik_are_removed_and_fast_turns_kept():
    """``remove_spikes``: a joint flipped far from both neighbours for one frame (in the
    middle, or on the window's first frame) takes its neighbours' rotation; a joint turning
    fast but steadily, another joint, the hips' position and short windows are untouched."""
    frames, joints = 9, 3
    axis = jnp.asarray([0.0, 0.0, 1.0])
    steady = quat_from_axis_angle(jnp.broadcast_to(axis, (frames, 3)), 0.9 * jnp.arange(frames, dtype=jnp.float32))
    still = quat_from_axis_angle(jnp.broadcast_to(axis, (frames, 3)), jnp.full(frames, 0.2))
    flip = quat_from_axis_angle(jnp.asarray([1.0, 0.0, 0.0]), jnp.asarray(2.6))  # 149°
    spiky = still.at[4].set(quat_mul(still[4], flip)).at[0].set(quat_mul(still[0], flip))
    quat = jnp.stack([steady, spiky, still], axis=1)  # (frames, joints, 4)
    root = jnp.arange(frames * 3, dtype=jnp.float32).reshape(frames, 3)
    out = remove_spikes(Pose(root, quat), 0.75)

    np.testing.assert_array_equal(out.root_pos, root)
    np.testing.assert_array_equal(out.quat_local[:, 0], steady)  # 0.9 rad a frame, one way: no spike
    np.testing.assert_array_equal(out.quat_local[:, 2], still)
    assert float(jnp.max(quat_angle(out.quat_local[:, 1], still))) < 1e-3  # both flips gone
    np.testing.assert_array_equal(remove_spikes(Pose(root, quat), 0.0).quat_local, quat)  # off
    np.testing.assert_array_equal(remove_spikes(Pose(root, quat), 2.7).quat_local, quat)  # a 149° flip under the threshold
    short = Pose(root[:2], quat[:2])
    np.testing.assert_array_equal(remove_spikes(short, 0.75).quat_local, short.quat_local)


def test_lasting_flips_of_the_inner_ik_become_ramps_from_the_keys():
    """``limit_turns``: a joint that flips by 149° and stays flipped turns at most the limit a
    frame, counted from the nearer end of the window (so the frames next to the key keep the
    inner pose there); slower motion and the hips' position pass bit for bit."""
    frames, limit = 15, 0.5
    axis = jnp.asarray([0.0, 0.0, 1.0])
    steady = quat_from_axis_angle(jnp.broadcast_to(axis, (frames, 3)), 0.4 * jnp.arange(frames, dtype=jnp.float32))
    still = quat_from_axis_angle(jnp.broadcast_to(axis, (frames, 3)), jnp.full(frames, 0.2))
    flip = quat_from_axis_angle(jnp.asarray([1.0, 0.0, 0.0]), jnp.asarray(2.6))  # 149°
    late = still.at[11:].set(quat_mul(still[11:], flip))  # flipped from frame 11 to the end
    early = still.at[:3].set(quat_mul(still[:3], flip))  # flipped from the start to frame 2
    quat = jnp.stack([steady, late, early, still], axis=1)
    root = jnp.arange(frames * 3, dtype=jnp.float32).reshape(frames, 3)
    out = limit_turns(Pose(root, quat), limit)

    np.testing.assert_array_equal(out.root_pos, root)
    np.testing.assert_array_equal(out.quat_local[:, [0, 3]], quat[:, [0, 3]])  # 0.4 rad a frame: under the limit
    turns = np.radians(np.asarray(rotation_change_deg(out.quat_local)))
    assert turns[:, 1:3].max() <= limit + 1e-4  # no step left
    # The frames from the step to the nearer end keep the inner pose; the ramp runs away from that end.
    np.testing.assert_array_equal(out.quat_local[11:, 1], late[11:])
    np.testing.assert_array_equal(out.quat_local[:3, 2], early[:3])
    assert float(quat_angle(out.quat_local[10, 1], late[11])) == pytest.approx(limit, abs=1e-4)
    assert float(quat_angle(out.quat_local[3, 2], early[2])) == pytest.approx(limit, abs=1e-4)
    np.testing.assert_array_equal(out.quat_local[:5, 1], late[:5])  # reached the inner pose again (2.6 / 0.5: 6 frames)
    np.testing.assert_array_equal(limit_turns(Pose(root, quat), 0.0).quat_local, quat)  # off


def test_a_kept_frame_turned_alone_gets_ramps_into_it_from_both_sides():
    """``limit_turns`` with ``anchors``: a frame turned 92° away from its neighbours (the window
    solve's handle frame after a pass) is kept, and the frames on both sides ramp into it at
    the limit a frame, back on the given poses after ⌈92° / limit⌉ − 1 frames; without the
    anchor the same frame is cut down instead. Two anchors with a step between them keep both."""
    frames, limit = 31, np.radians(43.0)
    axis = jnp.asarray([0.0, 0.0, 1.0])
    still = quat_from_axis_angle(jnp.broadcast_to(axis, (frames, 3)), jnp.full(frames, 0.2))
    bend = quat_from_axis_angle(jnp.asarray([1.0, 0.0, 0.0]), jnp.asarray(np.radians(92.0)))
    alone = still.at[6].set(quat_mul(still[6], bend))
    quat = jnp.stack([alone, still], axis=1)
    root = jnp.zeros((frames, 3))
    anchors = jnp.zeros(frames, bool).at[6].set(True)
    out = limit_turns(Pose(root, quat), limit, anchors).quat_local

    np.testing.assert_array_equal(out[6, 0], alone[6])  # the anchor kept
    np.testing.assert_array_equal(out[:, 1], still)  # the other joint untouched
    turns = np.radians(np.asarray(rotation_change_deg(out)))
    assert turns.max() <= limit + 1e-4
    for side in (5, 7):  # one limit away from the anchor, two limits away on the next frame
        assert float(quat_angle(out[side, 0], alone[6])) == pytest.approx(limit, abs=1e-4)
        assert float(quat_angle(out[side, 0], still[side])) == pytest.approx(np.radians(92.0) - limit, abs=1e-4)
    np.testing.assert_array_equal(out[:4, 0], still[:4])
    np.testing.assert_array_equal(out[9:, 0], still[9:])
    assert float(quat_angle(out[4, 0], still[4])) == pytest.approx(np.radians(92.0) - 2 * limit, abs=1e-4)
    free = limit_turns(Pose(root, quat), limit).quat_local  # not kept: the spike itself is cut
    assert float(quat_angle(free[6, 0], still[6])) <= limit + 1e-4
    # Anchors one frame apart with a step beyond the limit between them: both kept as given.
    stepped = still.at[10:].set(quat_mul(still[10:], bend))
    both = limit_turns(Pose(root, jnp.stack([stepped, still], axis=1)), limit, jnp.zeros(frames, bool).at[9:11].set(True)).quat_local
    np.testing.assert_array_equal(both[9:11, 0], stepped[9:11])
    np.testing.assert_array_equal(limit_turns(Pose(root, quat), 0.0, anchors).quat_local, quat)  # off


@pytest.mark.parametrize(("before", "after"), [(2, 3), (3, 2), (2, 2)])
def test_limit_turns_spreads_a_step_over_both_sides(before, after):
    """A joint turned 149° in one step, ``before`` frames after one kept frame and ``after``
    frames before the next: at 43° a frame one side alone is too short for the ramp (3 steps:
    129°), both together are not. Every step comes out within the limit, the kept frames as
    given, and the joint ends up on its poses (the ramp spends the whole 149° and no more)."""
    frames, limit = before + after + 2, np.radians(43.0)
    z = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0]), (frames, 3))
    angle = np.where(np.arange(frames) > before, 149.0, 0.0).astype(np.float32)
    quat = quat_from_axis_angle(z, jnp.radians(jnp.asarray(angle)))[:, None]
    out = limit_turns(Pose(jnp.zeros((frames, 3)), quat), limit).quat_local
    turns = np.radians(np.asarray(rotation_change_deg(out)))[:, 0]
    assert turns.max() <= limit + 1e-4, np.degrees(turns)
    assert turns.sum() == pytest.approx(np.radians(149.0), abs=1e-4)
    np.testing.assert_array_equal(out[np.asarray([0, -1])], quat[np.asarray([0, -1])])


def test_limit_turns_puts_a_centred_ramp_on_the_same_side_whatever_the_rounding():
    """A joint turning 120° in two steps centred in its window (frames 14 → 16 of 0 … 30): the
    passes from both kept frames are back on the poses 2 frames either side of the middle, a
    tie that float rounding could break either way: a rotation of 1e-6 rad on every frame, or
    compiling the filter, could put the ramp on the other side. Every such input gives the
    noiseless result to rounding, the ramp on the earlier side."""
    frames, limit = 31, np.radians(43.0)
    z = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0]), (frames, 3))
    angle = np.select([np.arange(frames) <= 14, np.arange(frames) == 15], [0.0, 60.0], 120.0).astype(np.float32)
    # About a joint's own axis, turned from its parent's in general (about z alone the passes
    # agree bit for bit, and nothing is left to rounding).
    base = quat_from_axis_angle(jnp.asarray([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]), jnp.asarray(1.3))
    quat = quat_mul(base, quat_from_axis_angle(z, jnp.radians(jnp.asarray(angle))))[:, None]
    want = limit_turns(Pose(jnp.zeros((frames, 3)), quat), limit).quat_local
    turns = np.asarray(rotation_change_deg(want))[:, 0]  # degrees, per step
    np.testing.assert_allclose(turns[12:17], [0.0, 34.0, 43.0, 43.0, 0.0], atol=1e-3)  # the earlier side ramps
    filtered = jax.jit(limit_turns)
    rng = np.random.default_rng(0)
    for k in range(12):
        axis = rng.normal(size=(frames, 3)).astype(np.float32)
        noise = quat_from_axis_angle(jnp.asarray(axis / np.linalg.norm(axis, axis=-1, keepdims=True)), jnp.full(frames, 1e-6))
        noisy = Pose(jnp.zeros((frames, 3)), quat_mul(quat, noise[:, None]))
        for out in (limit_turns(noisy, limit).quat_local, filtered(noisy, limit).quat_local):
            assert float(jnp.max(quat_angle(out, want))) < 1e-4, (k, np.degrees(np.asarray(quat_angle(out, want))[:, 0]))


def test_limit_turns_takes_the_shortest_way_where_the_poses_spin_too_fast():
    """A joint spinning 50° a frame for six frames between two kept frames (0 and 6) cannot
    follow its poses at most 43° a frame: it turns the shortest way between them instead (60°
    back, 10° a frame), the kept frames as given, bit for bit; another joint's lasting 60° step
    in the same window is still ramped along its poses, and a third, spinning up to the kept
    frame 6 and stepping 60° after it, turns the short way before it and ramps after it (each
    stretch between kept frames on its own)."""
    frames = 9
    z = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0]), (frames, 3))
    spin = quat_from_axis_angle(z, jnp.radians(jnp.asarray([0, 50, 100, 150, 200, 250, 300, 310, 320], jnp.float32)))
    still = quat_from_axis_angle(z, jnp.full(frames, 0.2))
    flipped = still.at[3:].set(quat_mul(still[3:], quat_from_axis_angle(jnp.asarray([1.0, 0.0, 0.0]), jnp.radians(60.0))))
    then_step = quat_from_axis_angle(z, jnp.radians(jnp.asarray([0, 50, 100, 150, 200, 250, 300, 300, 360], jnp.float32)))
    quat = jnp.stack([spin, flipped, then_step], axis=1)
    limit = np.radians(43.0)
    out = limit_turns(Pose(jnp.zeros((frames, 3)), quat), limit, jnp.zeros(frames, bool).at[6].set(True)).quat_local
    short_way = quat_from_axis_angle(z[:7], jnp.radians(-10.0 * jnp.arange(7, dtype=jnp.float32)))
    for joint in (0, 2):
        np.testing.assert_array_equal(out[np.asarray([0, 6]), joint], quat[np.asarray([0, 6]), joint])
        assert np.degrees(np.asarray(quat_angle(out[:7, joint], short_way))).max() < 1e-3
    np.testing.assert_array_equal(out[7:, 0], spin[7:])  # after the kept frame: within the limit, unchanged
    turns = np.radians(np.asarray(rotation_change_deg(out)))
    assert turns[:, 1].max() == pytest.approx(limit, abs=1e-4)  # 60° → 43° + 17°
    assert turns[6:, 2].max() == pytest.approx(limit, abs=1e-4)  # 60° → 17° + 43° after the kept frame


def test_limit_turns_leaves_a_joint_it_cannot_turn_even_the_shortest_way():
    """Kept frames 0 and 3 with a joint spinning 50° a frame between them: 150° even the
    shortest way, more than three steps of 43° allow, so it keeps its poses, bit for bit."""
    frames = 5
    z = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0]), (frames, 3))
    spin = quat_from_axis_angle(z, jnp.radians(jnp.asarray([0, 50, 100, 150, 160], jnp.float32)))[:, None]
    out = limit_turns(Pose(jnp.zeros((frames, 3)), spin), np.radians(43.0), jnp.zeros(frames, bool).at[3].set(True)).quat_local
    np.testing.assert_array_equal(out, spin)


def test_limit_turns_takes_a_limit_per_step():
    """A joint turned 149° from frame 1 to the end, with limits of 0.2 rad on the first and the
    last step easing to 0.75 (``turns_near_keys``, keys at both ends): no step turns beyond its
    own limit, the first one exactly at it; one limit for every step gives the same poses as the
    scalar, bit for bit. ``key_turn = 0`` leaves every step at ``turn``."""
    frames = 13
    still = quat_from_axis_angle(jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0]), (frames, 3)), jnp.full(frames, 0.2))
    flip = quat_from_axis_angle(jnp.asarray([1.0, 0.0, 0.0]), jnp.asarray(2.6))
    quat = jnp.stack([still.at[1:].set(quat_mul(still[1:], flip)), still], axis=1)
    root = jnp.zeros((frames, 3))
    distance = np.minimum(np.arange(frames), frames - 1 - np.arange(frames))
    limits = turns_near_keys(distance, 0.2, 0.75, 4)
    np.testing.assert_allclose(np.asarray(limits)[[0, 1, 2, 3, 4, -1]], [0.2, 0.3375, 0.475, 0.6125, 0.75, 0.2])
    np.testing.assert_allclose(turns_near_keys(distance, 0.2, 0.0, 4), [0.2] + [0.0] * (frames - 3) + [0.2])  # others off
    np.testing.assert_array_equal(turns_near_keys(distance, 0.0, 0.75, 4), np.full(frames - 1, 0.75, np.float32))  # no key limit
    out = limit_turns(Pose(root, quat), jnp.asarray(limits)).quat_local
    turns = np.radians(np.asarray(rotation_change_deg(out)))
    assert np.all(turns[:, 0] <= limits + 1e-4)
    assert turns[0, 0] == pytest.approx(0.2, abs=1e-4)
    np.testing.assert_array_equal(out[:, 1], still)
    scalar = limit_turns(Pose(root, quat), 0.5).quat_local
    np.testing.assert_array_equal(limit_turns(Pose(root, quat), jnp.full(frames - 1, 0.5)).quat_local, scalar)


def test_turn_out_of_keys_turns_a_joint_that_cannot_leave_slowly_the_shortest_way():
    """Keys at frames 0 and 12, an anchor at 6, 11.5° on the step out of a key easing to 43°
    over 4 frames. A joint stepping 60° right after the key leaves it at 11.5° and ramps; one
    spinning 10°, 40°, 40°, 40°, 60°, 20° up to the anchor cannot leave that slowly along its
    poses (the eased limits add up to 179° of its 210°): it turns the shortest way to the
    anchor (150° back), each step its limit's share, so no step beyond its limit; the key
    frames and the anchor as given."""
    frames, key_turn, turn = 13, 0.2, np.radians(43.0)
    z = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0]), (frames, 3))
    stepped = np.where(np.arange(frames) >= 1, 60.0, 0.0)
    spinning = np.concatenate([[0.0], np.cumsum([10.0, 40.0, 40.0, 40.0, 60.0, 20.0]), np.full(6, 210.0)])
    quat = jnp.stack([quat_from_axis_angle(z, jnp.radians(jnp.asarray(a, jnp.float32))) for a in (stepped, spinning)], axis=1)
    distance = np.minimum(np.arange(frames), frames - 1 - np.arange(frames))
    anchors = jnp.zeros(frames, bool).at[6].set(True)
    out = turn_out_of_keys(Pose(jnp.zeros((frames, 3)), quat), distance, key_turn, turn, 4, anchors).quat_local
    turns = np.radians(np.asarray(rotation_change_deg(out)))
    limits = np.asarray(turns_near_keys(distance, key_turn, turn, 4))
    assert turns[0, 0] == pytest.approx(key_turn, abs=1e-4)
    assert np.all(turns <= limits[:, None] + 1e-4)
    assert turns[:6, 1].sum() == pytest.approx(np.radians(150.0), abs=1e-4)  # the short way, every step the same way
    np.testing.assert_allclose(turns[:6, 1], np.radians(150.0) * limits[:6] / limits[:6].sum(), atol=1e-4)
    np.testing.assert_array_equal(out[np.asarray([0, 6, 12])], quat[np.asarray([0, 6, 12])])
    with pytest.raises(ValueError, match=r"one value per frame, \(13,\), got \(12,\)"):
        turn_out_of_keys(Pose(jnp.zeros((frames, 3)), quat), distance[:-1], key_turn, turn, 4, anchors)


def test_smoothing_averages_each_frame_with_its_neighbours():
    """``smooth``: weights ``[w, 1 − 2w, w]`` on the hips' position and, about one axis, on the
    half-angles' quaternions (a sign-flipped neighbour counts as the same rotation); at the
    window's ends the frame keeps ``1 − w``; ``w = 0`` changes nothing."""
    frames, w = 5, 0.25
    axis = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0]), (frames, 3))
    angle = jnp.asarray([0.0, 0.0, 0.6, 0.0, 0.0])
    quat = quat_from_axis_angle(axis, angle)[:, None]  # (frames, 1 joint, 4)
    quat = quat.at[3].multiply(-1.0)  # the same rotation, the other hemisphere
    root = jnp.asarray([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 4.0, 0.0], [3.0, 0.0, 0.0], [4.0, 0.0, 8.0]])
    out = smooth(Pose(root, quat), w)

    expected_root = np.asarray(root)
    previous, following = np.concatenate([expected_root[:1], expected_root[:-1]]), np.concatenate([expected_root[1:], expected_root[-1:]])
    np.testing.assert_allclose(out.root_pos, (1 - 2 * w) * expected_root + w * (previous + following), atol=1e-6)
    # The half-angles' unit vectors averaged: frame 2 lands halfway (0.3 rad); frames 1 and 3
    # take a quarter of its (cos, sin)(0.3).
    neighbour = 2 * np.arctan2(w * np.sin(0.3), (1 - w) + w * np.cos(0.3))
    expected_angle = np.asarray([0.0, neighbour, 0.3, neighbour, 0.0])
    got = np.asarray(quat_angle(out.quat_local[:, 0], quat_from_axis_angle(axis, jnp.zeros(frames))))
    np.testing.assert_allclose(got, expected_angle, atol=1e-5)
    assert float(jnp.max(jnp.abs(jnp.linalg.norm(out.quat_local, axis=-1) - 1.0))) < 1e-6
    unchanged = smooth(Pose(root, quat), 0.0)
    np.testing.assert_allclose(unchanged.quat_local, quat, atol=1e-7)
    np.testing.assert_array_equal(unchanged.root_pos, root)
    # A weight per frame: each frame filtered with its own, from the same neighbours.
    weights = jnp.asarray([0.5, 0.0, 0.25, 0.1, 0.5])
    each = smooth(Pose(root, quat), weights)
    for t, wt in enumerate(np.asarray(weights)):
        alone = smooth(Pose(root, quat), float(wt))
        np.testing.assert_allclose(each.root_pos[t], alone.root_pos[t], atol=1e-6)
        np.testing.assert_allclose(each.quat_local[t], alone.quat_local[t], atol=1e-6)
