"""``inbetween`` (``bezmotion.pipeline.inbetweening``) through three keys: windows between keys
sampled together, continuity at the chained keys (the curves share their tangents there,
the motion holds each key exactly), the handles hit, one compilation, a transfer, and the
input checks.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ik.demo_poses import fk, frame, targets_of
from pipeline.common import FRAMES, K, LEFT_HAND, STEPS, STRIDE, model_of

from bezmotion.bmm.sampling import Handles
from bezmotion.data.characteristic import HIPS
from bezmotion.ik.protocol import Pose
from bezmotion.evaluation.metrics import boundary_velocity_jump
from bezmotion.pipeline import InbetweenOptions, Transfer, chain_key_velocities, inbetween, join_windows, split_windows

KEY_FRAMES = [0, 30, 39]  # clip frames of the three keys (the clip has 40)
WINDOWS = len(KEY_FRAMES) - 1
LENGTH = WINDOWS * (FRAMES - 1) + 1  # 61 frames of chained motion


@pytest.fixture(scope="module")
def chain(clip, bmm, run) -> SimpleNamespace:
    """Three keys of the demo clip, two windows: hips 10 cm up at frame 29 (next to the shared
    key) and the left hand 10 cm up at frame 12; the left hand where the mocap has it at frame
    31 (the other side of the key: no kink forced there) and a padding slot holding NaN."""
    character = clip.character
    keys = jax.tree.map(lambda a: a[jnp.asarray(KEY_FRAMES)], clip.pose)
    _, pos = fk(character, clip.pose)
    idx = np.asarray(character.characteristic)
    up = np.array([0.0, 10.0, 0.0], np.float32)
    position = np.stack(
        [pos[29, idx[HIPS]] + up, pos[12, idx[LEFT_HAND]] + up, pos[31, idx[LEFT_HAND]], np.full(3, np.nan, np.float32)]
    ).astype(np.float32)
    handles = Handles(
        jnp.asarray([HIPS, LEFT_HAND, LEFT_HAND, HIPS], jnp.int32),
        jnp.asarray([29, 12, 31, 35], jnp.int32),
        jnp.asarray(position),
        jnp.asarray([True, True, True, False]),
    )
    model = model_of(bmm, run.ik, run.rest, character)
    result = inbetween(model, keys, handles, key=jax.random.key(3), options=InbetweenOptions(steps=STEPS))
    return SimpleNamespace(character=character, keys=keys, handles=handles, model=model, ik=run.ik, result=result)


def run_chain(chain, **options):
    """The chain's in-between with other options; ``key`` (default 3) and ``key_velocity`` apart."""
    key, key_velocity = options.pop("key", 3), options.pop("key_velocity", None)
    model = options.pop("model", chain.model)
    return inbetween(
        model, options.pop("keys", chain.keys), options.pop("handles", chain.handles), key=jax.random.key(key),
        options=InbetweenOptions(**{"steps": STEPS, **options}), key_velocity=key_velocity,
    )  # fmt: skip


def test_chain_has_all_frames_and_holds_every_key(chain):
    r, keys = chain.result, chain.keys
    assert r.pose.root_pos.shape == (LENGTH, 3) and r.pose.quat_local.shape == (LENGTH, 22, 4)
    assert r.positions.shape == (LENGTH, 6, 3) and r.rot6d.shape == (LENGTH, 6, 6)
    assert r.curves.ctrl_pos.shape == (WINDOWS, K, 6, 3) and all(np.isfinite(np.asarray(a)).all() for a in (*r.pose, *r.curves))
    # keep_keyframes: the given keys exactly at frames 0, 30, 60.
    for k, f in enumerate(range(0, LENGTH, FRAMES - 1)):
        np.testing.assert_array_equal(r.pose.root_pos[f], keys.root_pos[k])
        np.testing.assert_array_equal(r.pose.quat_local[f], keys.quat_local[k])
        t = targets_of(chain.character, frame(keys, k))
        np.testing.assert_allclose(r.positions[f], t.position, atol=1e-3)
        np.testing.assert_allclose(r.rot6d[f], t.rot6d, atol=1e-5)


def test_chain_curves_are_c1_at_the_shared_key_and_hit_the_handles(chain):
    r, h = chain.result, chain.handles
    tangent, pos = np.asarray(r.curves.ctrl_tangent), np.asarray(r.curves.ctrl_pos)
    np.testing.assert_array_equal(tangent[0, -1], tangent[1, 0])
    np.testing.assert_array_equal(pos[0, -1], pos[1, 0])
    np.testing.assert_array_equal(np.asarray(r.curves.ctrl_rot6d)[0, -1], np.asarray(r.curves.ctrl_rot6d)[1, 0])
    # The dense trajectories given to IK: handles at chain frame 30·window + frame.
    np.testing.assert_allclose(r.positions[29, HIPS], h.position[0], atol=1e-3)
    np.testing.assert_allclose(r.positions[12, LEFT_HAND], h.position[1], atol=1e-3)
    np.testing.assert_allclose(r.positions[31, LEFT_HAND], h.position[2], atol=1e-3)
    # At the shared key the velocity changes no more than the curvature either side allows.
    jump = np.asarray(boundary_velocity_jump(r.positions, [FRAMES - 1]))[0]
    inner = np.asarray(boundary_velocity_jump(r.positions, [FRAMES - 2, FRAMES]))
    assert (jump <= 2.0 * inner.max(axis=0) + 1e-3).all(), (jump, inner)


def test_independent_windows_jump_at_the_shared_key_and_the_chain_compiles_once(chain):
    traces = len(chain.ik.traces)
    apart = run_chain(chain, coupled=False)
    again = run_chain(chain, key=4, coupled=False)
    assert len(chain.ik.traces) == traces + 1, "a second call with the same shapes must not retrace"
    tangent = np.asarray(apart.curves.ctrl_tangent)
    assert np.abs(tangent[0, -1] - tangent[1, 0]).max() > 1.0  # velocity 3·T/6 differs either side
    assert not np.array_equal(np.asarray(again.positions), np.asarray(apart.positions))
    # The keys and handles hold either way.
    np.testing.assert_array_equal(apart.pose.root_pos[FRAMES - 1], chain.keys.root_pos[1])
    np.testing.assert_allclose(apart.positions[31, LEFT_HAND], chain.handles.position[2], atol=1e-3)


def test_chain_with_a_transfer_keeps_the_shared_tangent_and_the_keys(chain):
    scaled = Transfer(jnp.asarray(1.3, jnp.float32), Transfer.identity().rot_offset)
    r = run_chain(chain, model=dataclasses.replace(chain.model, transfer=scaled), key_blend_frames=0)
    tangent = np.asarray(r.curves.ctrl_tangent)
    np.testing.assert_array_equal(tangent[0, -1], tangent[1, 0])
    np.testing.assert_allclose(r.positions[29, HIPS], chain.handles.position[0], atol=1e-3)
    np.testing.assert_array_equal(r.pose.quat_local[FRAMES - 1], chain.keys.quat_local[1])


def test_join_windows():
    x = jnp.arange(2 * 4 * 3, dtype=jnp.float32).reshape(2, 4, 3)
    np.testing.assert_array_equal(join_windows(x), np.concatenate([np.asarray(x[0, :3]), np.asarray(x[1])]))


def test_split_windows_undoes_join_windows():
    x = jnp.arange(3 * 5 * 2, dtype=jnp.float32).reshape(3, 5, 2)
    x = x.at[1:, 0].set(x[:-1, -1])  # each shared key the same on both sides, as in a chain
    np.testing.assert_array_equal(split_windows(join_windows(x), 3), x)
    for frames, windows in ((13, 0), (13, 5), (1, 1)):
        with pytest.raises(ValueError, match=rf"{frames} frames are not a chain of {windows} windows"):
            split_windows(jnp.zeros((frames, 2)), windows)


def test_chain_input_errors(chain):
    def call(**kwargs):
        return run_chain(chain, steps=1, **kwargs)

    with pytest.raises(ValueError, match=r"keys must be poses .*\(3, 5, 4\)"):
        call(keys=Pose(chain.keys.root_pos, chain.keys.quat_local[:, :5]))
    with pytest.raises(ValueError, match=r"not on the keys' frames \[0, 30, 60\]"):
        call(handles=chain.handles._replace(frame=chain.handles.frame.at[2].set(30)))
    with pytest.raises(ValueError, match=r"frames 1 … 59"):
        call(handles=chain.handles._replace(frame=chain.handles.frame.at[2].set(61)))
    with pytest.raises(ValueError, match="position not finite"):
        call(handles=chain.handles._replace(position=chain.handles.position.at[1, 2].set(jnp.inf)))
    with pytest.raises(ValueError, match="key 2 contains non-finite"):
        call(keys=chain.keys._replace(root_pos=chain.keys.root_pos.at[2, 0].set(jnp.nan)))


def test_chain_key_velocities_reach_both_windows_of_every_key(chain):
    """``key_velocity`` ``(keys, 6, 3)``: each window leaves and reaches its keys at the given
    velocities (tangent ``v·stride/3``), a shared key's on both sides; keys and handles still
    hold; a wrong shape or a NaN raises."""
    velocity = np.random.default_rng(0).normal(0.0, 1.5, (len(KEY_FRAMES), 6, 3)).astype(np.float32)  # cm/frame
    r = run_chain(chain, key_velocity=velocity)
    tangent = np.asarray(r.curves.ctrl_tangent)
    want = velocity * (STRIDE / 3.0)
    for window in range(WINDOWS):
        np.testing.assert_allclose(tangent[window, 0], want[window], atol=1e-5)
        np.testing.assert_allclose(tangent[window, -1], want[window + 1], atol=1e-5)
    np.testing.assert_allclose(r.positions[29, HIPS], chain.handles.position[0], atol=1e-3)
    np.testing.assert_array_equal(r.pose.root_pos[FRAMES - 1], chain.keys.root_pos[1])
    with pytest.raises(ValueError, match=r"key_velocity must be \(3, 6, 3\) \(one per key.*got \(2, 6, 3\)"):
        run_chain(chain, steps=1, key_velocity=velocity[:2])
    with pytest.raises(ValueError, match="key_velocity contains infinite values"):
        run_chain(chain, steps=1, key_velocity=np.where(np.arange(3)[:, None, None] == 1, np.inf, velocity))
    # NaN at the shared key: not known there; both windows still leave and reach it alike.
    free = np.asarray(run_chain(chain, steps=1, key_velocity=np.where(np.arange(3)[:, None, None] == 1, np.nan, velocity)).curves.ctrl_tangent)
    assert np.isfinite(free).all()
    np.testing.assert_allclose(free[0, -1], free[1, 0], atol=1e-4)
    np.testing.assert_allclose(free[0, 0], want[0], atol=1e-5)


def test_chain_key_velocities_of_a_clip(clip):
    """``chain_key_velocities``: central differences at the shared keys, one-sided inside the
    chain at its two ends; frames that are not keys ``stride`` apart raise."""
    c = clip.character
    poses = jax.tree.map(lambda a: a[:31], clip.pose)
    position = np.asarray(fk(c, poses)[1])[:, np.asarray(c.characteristic)]
    got = np.asarray(chain_key_velocities(c, poses, stride=15))
    np.testing.assert_allclose(got[0], position[1] - position[0], atol=1e-4)
    np.testing.assert_allclose(got[1], (position[16] - position[14]) / 2.0, atol=1e-4)
    np.testing.assert_allclose(got[2], position[30] - position[29], atol=1e-4)
    with pytest.raises(ValueError, match=r"keys 15 apart \(K·15 \+ 1\), got 30"):
        chain_key_velocities(c, jax.tree.map(lambda a: a[:30], poses), stride=15)
