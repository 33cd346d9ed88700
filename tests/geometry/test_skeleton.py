"""Tests for ``bezmotion.geometry.skeleton``: validation, pytree behaviour, FK/IK against NumPy."""

from __future__ import annotations

import zipfile
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxtyping
import numpy as np
import pytest
from helpers import (
    SHARED_DATA,
    assert_same_rotation,
    check_jacobians,
    np_forward_kinematics,
    random_parents,
    random_quat,
    requires_shared,
    tree_allclose,
)

from bezmotion.geometry.skeleton import Skeleton, forward_kinematics, inverse_kinematics
from bezmotion.assets import DEMO_CLIP

#: The 22-joint LaFAN1 topology (Hips, legs, spine/head, arms).
LAFAN1_PARENTS = (-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 12, 11, 14, 15, 16, 11, 18, 19, 20)
LAFAN1_ZIP = SHARED_DATA / "lafan1" / "lafan1-subset.zip"
LAFAN1_MEMBER = "walk4_subject1.bvh"
# The bundled real Bandai-Namco clip (dataset-2_walk_normal_001, first 40 frames): it was
# a file in an unpacked archive under ~/.cache that nothing creates, so the case always skipped.
BANDAI_CLIP = DEMO_CLIP
FRAMES = 8


def make_skeleton(rng: np.random.Generator, parents: tuple[int, ...] | None = None, joints: int = 22) -> Skeleton:
    """A skeleton with bone-like random offsets (cm); a random tree unless ``parents`` is given."""
    parents = parents if parents is not None else random_parents(rng, joints)
    offsets = rng.normal(scale=10.0, size=(len(parents), 3))
    return Skeleton.from_parents(parents, [f"j{j}" for j in range(len(parents))], offsets)


def random_pose(rng: np.random.Generator, skeleton: Skeleton, frames: int = FRAMES) -> tuple[jax.Array, jax.Array]:
    """Random local rotations ``(frames, J, 4)`` and root positions ``(frames, 3)``."""
    return random_quat(rng, (frames, skeleton.num_joints)), jnp.asarray(rng.normal(scale=50.0, size=(frames, 3)))


# ------------------------------------------------------------------------------ validation


@pytest.mark.parametrize(
    ("parents", "names", "shape", "message"),
    [
        ((-1, 2, 0), ("a", "b", "c"), (3, 3), r"joint 1 \('b'\) has parent 2; parents must precede their children"),
        ((0, 0), ("a", "b"), (2, 3), r"joint 0 \('a'\) must be the root with parent -1, got 0"),
        ((-1, 0, -1), ("a", "b", "c"), (3, 3), r"joint 2 \('c'\) has parent -1"),
        ((-1, 0, 1), ("a", "b", "a"), (3, 3), r"joint name 'a' is used twice \(joints 0 and 2\)"),
        ((-1, 0), ("a",), (2, 3), r"1 names for 2 parents"),
        ((-1, 0), ("a", "b"), (3, 3), r"offsets must have shape \(\.\.\., 2, 3\), got \(3, 3\)"),
        ((), (), (0, 3), r"at least one joint"),
    ],
    ids=["parent-after-child", "root-not-minus-1", "second-root", "duplicate-name", "name-count", "offset-count",
         "empty"],
)  # fmt: skip
def test_invalid_skeletons_are_rejected(parents, names, shape, message):
    with pytest.raises(ValueError, match=message):
        Skeleton.from_parents(parents, names, np.zeros(shape))


def test_offsets_of_the_wrong_width_are_rejected():
    """Caught by the runtime annotation check (``TypeCheckError``) when the jaxtyping hook is on,
    by ``__post_init__`` (``ValueError``) otherwise; either way the message names ``offsets``."""
    with pytest.raises((ValueError, jaxtyping.TypeCheckError), match="offsets"):
        Skeleton.from_parents((-1, 0), ("a", "b"), np.zeros((2, 4)))


def test_joint_lookup(rng):
    skeleton = make_skeleton(rng, LAFAN1_PARENTS)
    assert skeleton.num_joints == 22
    assert skeleton.index("j11") == 11
    assert skeleton.indices(["j3", "j0"]) == (3, 0)
    assert skeleton.children(11) == (12, 14, 18)
    with pytest.raises(ValueError, match=r"unknown joint 'LeftHand'; this skeleton has \['j0', 'j1'"):
        skeleton.index("LeftHand")


def test_forward_kinematics_rejects_mismatched_topology(rng):
    skeleton = make_skeleton(rng, joints=5)
    quat, _ = random_pose(rng, skeleton)
    with pytest.raises(ValueError, match="4 parents, 5 joint rotations and 5 joint translations disagree"):
        forward_kinematics(skeleton.parents[:4], quat, skeleton.offsets)


@pytest.mark.parametrize(
    ("parents", "message"),
    [
        ((-1, 5, 0), r"joint 1 has parent 5; parents must precede"),
        ((-1, 2, 0), r"joint 1 has parent 2"),
        ((0, 0, 1), r"joint 0 must be the root with parent -1, got 0"),
    ],
    ids=["parent-out-of-range", "parent-after-child", "root-with-a-parent"],
)
def test_forward_kinematics_rejects_parents_out_of_order(parents, message):
    """Parents FK cannot place in order raise naming the joint (before, an index past the end
    was clipped by XLA's gather and gave finite, wrong positions)."""
    with pytest.raises(ValueError, match=message):
        forward_kinematics(parents, jnp.zeros((2, 3, 4)).at[..., 0].set(1.0), jnp.zeros((3, 3)))


# -------------------------------------------------------------------------------- pytrees


def test_offsets_are_the_only_leaf(rng):
    skeleton = make_skeleton(rng)
    leaves, treedef = jax.tree_util.tree_flatten(skeleton)
    assert len(leaves) == 1 and leaves[0] is skeleton.offsets
    doubled = jax.tree_util.tree_unflatten(treedef, [2.0 * leaves[0]])
    assert (doubled.parents, doubled.names) == (skeleton.parents, skeleton.names)
    np.testing.assert_allclose(doubled.offsets, 2.0 * skeleton.offsets)
    # The topology is static metadata: it is part of the treedef, the offsets are not.
    lafan = make_skeleton(rng, LAFAN1_PARENTS)
    chain = Skeleton.from_parents(range(-1, 21), lafan.names, lafan.offsets)
    assert jax.tree_util.tree_structure(chain) != jax.tree_util.tree_structure(lafan)
    assert jax.tree_util.tree_structure(make_skeleton(rng, LAFAN1_PARENTS)) == jax.tree_util.tree_structure(lafan)


def test_skeleton_passes_through_jit_without_retracing_on_new_offsets(rng):
    traces = []

    @jax.jit
    def fk(skeleton, quat, root):
        traces.append(skeleton.parents)  # runs only while tracing
        return skeleton.fk(quat, root)

    skeleton = make_skeleton(rng, LAFAN1_PARENTS)
    quat, root = random_pose(rng, skeleton)
    tree_allclose(fk(skeleton, quat, root), skeleton.fk(quat, root), atol=1e-4)
    moved = Skeleton(skeleton.parents, skeleton.names, skeleton.offsets + 1.0)
    tree_allclose(fk(moved, quat, root), moved.fk(quat, root), atol=1e-4)
    assert len(traces) == 1
    returned = jax.jit(lambda s: s)(skeleton)
    assert isinstance(returned, Skeleton) and returned.parents == skeleton.parents
    np.testing.assert_array_equal(returned.offsets, skeleton.offsets)


def test_vmap_over_stacked_skeletons(rng):
    """A batch of skeletons (same topology, stacked offsets) vmaps like a Python loop over them."""
    skeletons = [make_skeleton(rng, LAFAN1_PARENTS) for _ in range(3)]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *skeletons)
    assert stacked.offsets.shape == (3, 22, 3) and stacked.parents == LAFAN1_PARENTS
    quat, root = random_pose(rng, skeletons[0], frames=3)
    batched = jax.vmap(lambda s, q, r: s.fk(q, r))(stacked, quat, root)
    looped = [s.fk(quat[i], root[i]) for i, s in enumerate(skeletons)]
    tree_allclose(batched, jax.tree_util.tree_map(lambda *x: jnp.stack(x), *looped), atol=1e-4)


# ---------------------------------------------------------------------- forward kinematics


def test_fk_matches_numpy_loop_on_random_tree(rng, x64):
    """Per-frame translations and rotations on a random 22-joint tree, float64."""
    skeleton = make_skeleton(rng)
    quat, _ = random_pose(rng, skeleton)
    pos_local = jnp.asarray(rng.normal(scale=10.0, size=(FRAMES, 22, 3)))
    rot, pos = forward_kinematics(skeleton.parents, quat, pos_local)
    rot_ref, pos_ref = np_forward_kinematics(skeleton.parents, quat, pos_local)
    np.testing.assert_allclose(rot, rot_ref, atol=1e-12)
    np.testing.assert_allclose(pos, pos_ref, atol=1e-10)


def test_skeleton_fk_uses_rest_offsets_and_root_position(rng):
    """``Skeleton.fk`` == FK of the rest offsets with the root's entry replaced by ``root_pos``."""
    skeleton = make_skeleton(rng, LAFAN1_PARENTS)
    quat, root = random_pose(rng, skeleton)
    rot, pos = skeleton.fk(quat, root)
    np.testing.assert_allclose(pos[:, 0], root, atol=1e-6)
    pos_local = np.broadcast_to(np.asarray(skeleton.offsets), (FRAMES, 22, 3)).copy()
    pos_local[:, 0] = root
    rot_ref, pos_ref = np_forward_kinematics(skeleton.parents, quat, pos_local)
    np.testing.assert_allclose(rot, rot_ref, atol=1e-5)
    np.testing.assert_allclose(pos, pos_ref, atol=1e-3)
    tree_allclose((rot, pos), forward_kinematics(skeleton.parents, quat, skeleton.local_positions(root)), atol=1e-4)


def test_fk_at_rest_pose_accumulates_offsets(rng):
    """With identity rotations every joint sits at the sum of the offsets along its chain."""
    skeleton = make_skeleton(rng)
    rot, pos = skeleton.fk(jnp.zeros((22, 4)).at[:, 0].set(1.0), jnp.zeros(3))
    expected = np.zeros((22, 3))
    for j, p in enumerate(skeleton.parents[1:], start=1):
        expected[j] = expected[p] + np.asarray(skeleton.offsets[j])
    np.testing.assert_allclose(pos, expected, atol=1e-4)
    np.testing.assert_allclose(rot[:, 0], 1.0)


def test_fk_ik_round_trip(rng):
    skeleton = make_skeleton(rng)
    quat, root = random_pose(rng, skeleton)
    pos_local = skeleton.local_positions(root)
    rot_g, pos_g = forward_kinematics(skeleton.parents, quat, pos_local)
    rot_back, pos_back = inverse_kinematics(skeleton.parents, rot_g, pos_g)
    np.testing.assert_allclose(rot_back, quat, atol=1e-5)  # signs are preserved exactly
    np.testing.assert_allclose(pos_back, pos_local, atol=1e-3)
    # And the other way: IK then FK reproduces arbitrary global poses.
    rot_g = random_quat(rng, (FRAMES, 22))
    pos_g = jnp.asarray(rng.normal(scale=30.0, size=(FRAMES, 22, 3)))
    tree_allclose(forward_kinematics(skeleton.parents, *inverse_kinematics(skeleton.parents, rot_g, pos_g)),
                  (rot_g, pos_g), atol=1e-3)  # fmt: skip


def test_fk_jit_matches_eager(rng):
    skeleton = make_skeleton(rng)
    quat, root = random_pose(rng, skeleton)
    tree_allclose(jax.jit(Skeleton.fk)(skeleton, quat, root), skeleton.fk(quat, root), atol=1e-4)
    pos_local = skeleton.local_positions(root)
    ik = jax.jit(inverse_kinematics, static_argnums=0)
    tree_allclose(ik(skeleton.parents, quat, pos_local), inverse_kinematics(skeleton.parents, quat, pos_local), atol=1e-4)


def test_fk_vmap_matches_python_loop(rng):
    skeleton = make_skeleton(rng)
    quat, root = random_pose(rng, skeleton, frames=4)
    fk = jax.jit(skeleton.fk)  # jit both sides: compile once instead of every primitive eagerly
    looped = [fk(quat[i], root[i]) for i in range(4)]
    tree_allclose(jax.jit(jax.vmap(skeleton.fk))(quat, root), jax.tree_util.tree_map(lambda *x: jnp.stack(x), *looped),
                  atol=1e-4)  # fmt: skip


def test_fk_jacobians(rng, x64):
    """jacfwd == jacrev == central differences w.r.t. local rotations and root position (float64)."""
    skeleton = make_skeleton(rng, (-1, 0, 1, 1, 3))
    quat, root = random_pose(rng, skeleton, frames=2)

    def flat_fk(quat, root):
        rot, pos = skeleton.fk(quat, root)
        return jnp.concatenate([rot.reshape(-1), pos.reshape(-1)])

    check_jacobians(flat_fk, (quat, root), argnums=(0, 1))


# ------------------------------------------------------------------------- real skeletons


def _lafan1_clip(tmp_path: Path) -> Path:
    if not LAFAN1_ZIP.exists():
        pytest.skip(f"{LAFAN1_ZIP} not found")
    with zipfile.ZipFile(LAFAN1_ZIP) as archive:
        return Path(archive.extract(LAFAN1_MEMBER, tmp_path))


def _bandai_clip(tmp_path: Path) -> Path:
    return Path(BANDAI_CLIP)


@requires_shared
@pytest.mark.parametrize("clip", [_lafan1_clip, _bandai_clip], ids=["lafan1", "bandai-namco"])
def test_fk_matches_numpy_loop_on_real_skeletons(clip, tmp_path, x64):
    """The first 100 frames of a real clip: JAX FK == the NumPy loop, and FK → IK round trips."""
    bvh = pytest.importorskip("bezmotion.data.bvh")
    motion = bvh.read_bvh(clip(tmp_path))
    parents = motion.skeleton.parents
    assert len(parents) == 22
    quat_local, pos_local = motion.quat_local[:100], motion.pos_local[:100]
    rot, pos = forward_kinematics(parents, jnp.asarray(quat_local), jnp.asarray(pos_local))
    rot_ref, pos_ref = np_forward_kinematics(parents, quat_local, pos_local)
    np.testing.assert_allclose(rot, rot_ref, atol=1e-10)
    np.testing.assert_allclose(pos, pos_ref, atol=1e-8)
    assert np.ptp(pos_ref[:, 1:] - pos_ref[:, :1], axis=0).max() > 1.0  # the pose really moves
    rot_back, pos_back = inverse_kinematics(parents, rot, pos)
    assert_same_rotation(rot_back, quat_local, atol=1e-10)
    np.testing.assert_allclose(pos_back, pos_local, atol=1e-8)
