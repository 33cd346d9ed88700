"""One motion written many ways: re-expressions of a BVH clip that change how the file is
written and not what the body does.

A character-agnostic in-betweener must give the same motion whatever a file's conventions:
its rest pose (T, A or any other), each bone's local axes, the joint names, extra joints
(fingers, toes, twist joints), its length unit, up axis and frame rate. Each function here
returns a new :class:`~bezmotion.data.bvh.BvhMotion` whose joints move through exactly the
same world positions as the original's (to float64 rounding), written another way, so that
"the in-between of the re-expressed clip equals the re-expression of the in-between" can be
checked joint by joint (``experiments/skeleton_zoo.py``, ``tests/evaluation/test_skeleton_zoo.py``).

- :func:`reorient`: every joint's local frame turned by a fixed rotation ``C_j`` (its
  children's offsets and its channels re-expressed): a new rest pose, or new bone axes;
- :func:`a_pose`: the arms' rest pose lowered to an A (a :func:`reorient` of the arms);
- :func:`renamed`: joint names, e.g. Daz's lower-case ``lhand``;
- :func:`with_leaf_joints`, :func:`with_twist_joints`: joints added that the body's motion
  does not need (fingers and toes at rest, a joint halfway along a limb bone);
- :func:`without_joint`: a spine or neck joint fewer (another skeleton, the same motion of
  every other joint);
- :func:`yawed`: the whole clip facing another way in the world;
- :func:`scaled`, :func:`z_up`: the length unit and the up axis (:class:`~bezmotion.data.clip_frame.ClipFrame`'s inverse);
- :func:`world_positions`: every joint's world position per frame, to compare two writings.

The frame rate is changed by :func:`~bezmotion.data.resample.resample_motion`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data.bvh import BvhMotion
from bezmotion.geometry.rotations import quat_conjugate, quat_from_axis_angle, quat_mul, quat_rotate
from bezmotion.geometry.skeleton import Skeleton, ancestors, forward_kinematics


def _f64(fn: Callable, *args: np.ndarray) -> np.ndarray:
    """``fn(*args)`` in float64 (the re-expressions must not lose what float32 would)."""
    with jax.enable_x64(True):
        return np.asarray(fn(*(jnp.asarray(a, jnp.float64) for a in args)))


def world_positions(motion: BvhMotion) -> np.ndarray:
    """``(frames, joints, 3)`` every joint's world position, in the file's units (float64)."""
    with jax.enable_x64(True):
        _, pos = forward_kinematics(motion.skeleton.parents, jnp.asarray(motion.quat_local), jnp.asarray(motion.pos_local))
    return np.asarray(pos)


def _with(motion: BvhMotion, *, parents=None, names=None, offsets, quat_local, pos_local, channels=None, end_sites) -> BvhMotion:
    skeleton = Skeleton(
        tuple(motion.skeleton.parents if parents is None else parents),
        tuple(motion.skeleton.names if names is None else names),
        np.asarray(offsets, np.float64),
    )
    return dataclasses.replace(
        motion,
        skeleton=skeleton,
        quat_local=np.asarray(quat_local, np.float64),
        pos_local=np.asarray(pos_local, np.float64),
        channels=tuple(motion.channels if channels is None else channels),
        end_sites=tuple(end_sites),
    )


def reorient(motion: BvhMotion, turn: np.ndarray) -> BvhMotion:
    """``motion`` with joint ``j``'s local frame turned by ``turn[j]``: ``F'_j = F_j C_j``.

    A child's offset (and any animated translation) is re-expressed in its parent's new
    frame (``C_p⁻¹ o``), and the rotation channels become ``q'_j = C_p⁻¹ q_j C_j``, so every
    joint's world position is unchanged and its world orientation is ``R_j C_j``. At zero
    channels the skeleton then stands in another rest pose: this is both "another rest
    pose" and "other bone axes".

    Args:
      motion: any clip.
      turn: ``(joints, 4)`` unit quaternions (w, x, y, z); identity leaves a joint as it is.
    """
    turn = np.asarray(turn, np.float64)
    parents = np.asarray(motion.skeleton.parents)
    if turn.shape != (len(parents), 4):
        raise ValueError(f"turn must have shape ({len(parents)}, 4), got {turn.shape}")
    parent_turn = np.where(parents[:, None] >= 0, turn[np.maximum(parents, 0)], np.array([1.0, 0, 0, 0]))
    parent_inv = _f64(quat_conjugate, parent_turn)
    offsets = _f64(quat_rotate, parent_inv, np.asarray(motion.skeleton.offsets))
    pos_local = _f64(quat_rotate, parent_inv[None], motion.pos_local)
    quat_local = _f64(lambda p, q, c: quat_mul(quat_mul(p, q), c), parent_inv[None], motion.quat_local, turn[None])
    end_sites = [(j, tuple(_f64(quat_rotate, _f64(quat_conjugate, turn[j]), np.asarray(o)).tolist())) for j, o in motion.end_sites]
    return _with(motion, offsets=offsets, quat_local=quat_local, pos_local=pos_local, end_sites=end_sites)


def random_axes(motion: BvhMotion, seed: int, *, max_angle: float = np.pi) -> np.ndarray:
    """``(joints, 4)`` a random rotation per joint (the root's too), up to ``max_angle`` radians, for :func:`reorient`."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(motion.skeleton.num_joints, 3))
    angle = rng.uniform(0.0, max_angle, size=motion.skeleton.num_joints)
    return _f64(quat_from_axis_angle, axis / np.linalg.norm(axis, axis=-1, keepdims=True), angle)


def a_pose(motion: BvhMotion, arms: Mapping[str, str], degrees: float = 45.0) -> BvhMotion:
    """``motion`` with each arm's rest pose lowered by ``degrees`` about the body's forward axis:
    the joint ``arms[side]`` (the upper arm) and everything below it turned together, so the
    arm is straight at rest as before, only lower.

    Args:
      arms: ``{"left": upper arm's name, "right": …}``.
    """
    names = motion.skeleton.names
    parents = motion.skeleton.parents
    turn = np.tile([1.0, 0.0, 0.0, 0.0], (len(names), 1))
    offsets = np.asarray(motion.skeleton.offsets, np.float64)
    for upper in arms.values():
        top = names.index(upper)
        below = [j for j in range(len(names)) if top in ancestors(parents, j)]
        child = next(j for j in below if parents[j] == top)
        bone = offsets[child] / np.linalg.norm(offsets[child])  # the upper arm's rest direction (sideways)
        down = np.array([0.0, -1.0, 0.0])
        axis = np.cross(bone, down)  # the turn that takes the bone toward down
        rotation = _f64(quat_from_axis_angle, axis / np.linalg.norm(axis), np.array(np.radians(degrees)))
        # The new rest bone is C⁻¹ o: lowering it by the angle is C = the turn the other way.
        turn[below] = _f64(quat_conjugate, rotation)
    return reorient(motion, turn)


def renamed(motion: BvhMotion, rename: Mapping[str, str] | Callable[[str], str]) -> BvhMotion:
    """``motion`` with its joints renamed (a mapping, where a joint is missing it keeps its name; or a function)."""
    fn = rename if callable(rename) else (lambda n: rename.get(n, n))
    names = tuple(fn(n) for n in motion.skeleton.names)
    if len(set(names)) != len(names):
        raise ValueError(f"the new names are not unique: {names}")
    return _with(
        motion, names=names, offsets=motion.skeleton.offsets, quat_local=motion.quat_local, pos_local=motion.pos_local, end_sites=motion.end_sites
    )


def _insert(motion: BvhMotion, new: Sequence[tuple[str, int, np.ndarray, int | None]]) -> BvhMotion:
    """``motion`` with joints added, each ``(name, parent, offset, child or None)``: a new leaf
    at rest, or a joint at rest between ``parent`` and its ``child`` (whose offset becomes
    what is left of the bone). Joints are renumbered so that parents precede children, in
    file (depth-first) order."""
    skeleton = motion.skeleton
    parents = list(skeleton.parents)
    names = list(skeleton.names)
    offsets = [np.asarray(o, np.float64) for o in np.asarray(skeleton.offsets)]
    channels = list(motion.channels)
    frames = motion.num_frames
    quat = [motion.quat_local[:, j] for j in range(len(names))]
    pos = [motion.pos_local[:, j] for j in range(len(names))]
    rotation_only = lambda j: tuple(c for c in channels[j] if c.endswith("rotation")) or ("Zrotation", "Xrotation", "Yrotation")  # noqa: E731
    for name, parent, offset, child in new:
        j = len(names)
        names.append(name)
        parents.append(parent)
        offsets.append(np.asarray(offset, np.float64))
        channels.append(rotation_only(parent))
        quat.append(np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1)))
        pos.append(np.tile(np.asarray(offset, np.float64), (frames, 1)))
        if child is not None:  # the joint sits on the bone, at rest: the child hangs from it
            parents[child] = j
            offsets[child] = offsets[child] - offset
            pos[child] = pos[child] - offset
    # Depth-first order with children in their original order (new joints after their siblings).
    order: list[int] = []
    stack = [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed([c for c in range(len(names)) if parents[c] == j]))
    index = {old: new_j for new_j, old in enumerate(order)}
    end_sites = [(index[p], o) for p, o in motion.end_sites]
    return _with(
        motion,
        parents=[-1 if parents[j] < 0 else index[parents[j]] for j in order],
        names=[names[j] for j in order],
        offsets=np.stack([offsets[j] for j in order]),
        quat_local=np.stack([quat[j] for j in order], axis=1),
        pos_local=np.stack([pos[j] for j in order], axis=1),
        channels=[channels[j] for j in order],
        end_sites=end_sites,
    )


def with_leaf_joints(motion: BvhMotion, at: Mapping[str, Sequence[str]], length: float) -> BvhMotion:
    """``motion`` with a chain of new joints at rest hanging from each joint ``at`` names:
    ``{"Hand_L": ("index1_l", "index2_l", "index3_l"), …}`` — fingers, toes, face joints.
    Each new bone is ``length`` long (file units), along its parent's own bone (straight
    on from it), so the new joints lie where fingers would."""
    names = motion.skeleton.names
    offsets = np.asarray(motion.skeleton.offsets, np.float64)
    new: list[tuple[str, int, np.ndarray, int | None]] = []
    count = len(names)
    for joint, chain in at.items():
        j = names.index(joint)
        direction = offsets[j] if np.linalg.norm(offsets[j]) > 1e-9 else np.array([0.0, 1.0, 0.0])
        step = length * direction / np.linalg.norm(direction)
        parent = j
        for name in chain:
            new.append((name, parent, step, None))
            parent = count
            count += 1
    return _insert(motion, new)


def with_twist_joints(motion: BvhMotion, bones: Mapping[str, str]) -> BvhMotion:
    """``motion`` with a joint at rest halfway along each bone ``{child: new joint's name}``
    names (the bone from ``child``'s parent to ``child``): Daz's ``lForearmTwist``, Unreal's
    ``upperarm_twist_01_l``."""
    names = motion.skeleton.names
    offsets = np.asarray(motion.skeleton.offsets, np.float64)
    new = []
    for child, name in bones.items():
        c = names.index(child)
        new.append((name, motion.skeleton.parents[c], 0.5 * offsets[c], c))
    return _insert(motion, new)


def without_joint(motion: BvhMotion, name: str) -> BvhMotion:
    """``motion`` without joint ``name`` (a spine or neck joint): its children hang from its
    parent, their rotations composed with its own and their translations animated (position
    channels), so every other joint keeps its world position. Not a re-expression of the
    same skeleton: an IK poses the shorter chain otherwise."""
    skeleton = motion.skeleton
    names, parents = list(skeleton.names), list(skeleton.parents)
    j = names.index(name)
    if parents[j] < 0:
        raise ValueError(f"{name!r} is the root")
    quat, pos = motion.quat_local, motion.pos_local
    children = [c for c in range(len(names)) if parents[c] == j]
    quat_local, pos_local = quat.copy(), pos.copy()
    channels = list(motion.channels)
    for c in children:
        quat_local[:, c] = _f64(quat_mul, quat[:, j], quat[:, c])
        pos_local[:, c] = pos[:, j] + _f64(quat_rotate, quat[:, j], pos[:, c])
        rotations = tuple(x for x in channels[c] if x.endswith("rotation"))
        channels[c] = ("Xposition", "Yposition", "Zposition", *rotations)
    offsets = np.asarray(skeleton.offsets, np.float64).copy()
    offsets[children] = pos_local[0, children]
    keep = [k for k in range(len(names)) if k != j]
    index = {old: new for new, old in enumerate(keep)}
    new_parent = lambda k: -1 if parents[k] < 0 else index[parents[j] if parents[k] == j else parents[k]]  # noqa: E731
    end_sites = [(index[p], o) for p, o in motion.end_sites if p != j]
    return _with(
        motion,
        parents=[new_parent(k) for k in keep],
        names=[names[k] for k in keep],
        offsets=offsets[keep],
        quat_local=quat_local[:, keep],
        pos_local=pos_local[:, keep],
        channels=[channels[k] for k in keep],
        end_sites=end_sites,
    )


def scaled(motion: BvhMotion, factor: float) -> BvhMotion:
    """``motion`` in another length unit: every offset, translation and End Site times ``factor``
    (``factor`` file units per centimetre: 0.01 for metres, 1/5.6 for CMU's ~5.6 cm unit)."""
    return _with(
        motion,
        offsets=np.asarray(motion.skeleton.offsets) * factor,
        quat_local=motion.quat_local,
        pos_local=motion.pos_local * factor,
        end_sites=[(p, tuple(float(x) * factor for x in o)) for p, o in motion.end_sites],
    )


_Y_TO_Z = np.array([np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0])  # +90° about X: (x, y, z) → (x, −z, y)


def turned(motion: BvhMotion, turn: np.ndarray) -> BvhMotion:
    """``motion`` turned as a whole about the world origin by the quaternion ``turn`` (the
    root's rotation and position; every other joint is in its parent's frame)."""
    quat_local = motion.quat_local.copy()
    pos_local = motion.pos_local.copy()
    quat_local[:, 0] = _f64(quat_mul, np.asarray(turn)[None], motion.quat_local[:, 0])
    pos_local[:, 0] = _f64(quat_rotate, np.asarray(turn)[None], motion.pos_local[:, 0])
    return _with(motion, offsets=motion.skeleton.offsets, quat_local=quat_local, pos_local=pos_local, end_sites=motion.end_sites)


def z_up(motion: BvhMotion) -> BvhMotion:
    """``motion`` (Y up) turned to Z up: +90° about X."""
    return turned(motion, _Y_TO_Z)


def yawed(motion: BvhMotion, degrees: float) -> BvhMotion:
    """``motion`` (Y up) facing elsewhere: turned ``degrees`` about the vertical through the origin."""
    return turned(motion, _f64(quat_from_axis_angle, np.array([0.0, 1.0, 0.0]), np.array(np.radians(degrees))))


def still(motion: BvhMotion, frame: int, frames: int) -> BvhMotion:
    """A clip of ``frames`` frames that all hold ``motion``'s frame ``frame``: a person standing still."""
    return _with(
        motion,
        offsets=motion.skeleton.offsets,
        quat_local=np.repeat(motion.quat_local[frame : frame + 1], frames, axis=0),
        pos_local=np.repeat(motion.pos_local[frame : frame + 1], frames, axis=0),
        end_sites=motion.end_sites,
    )


__all__ = [
    "a_pose",
    "random_axes",
    "renamed",
    "reorient",
    "scaled",
    "still",
    "with_leaf_joints",
    "without_joint",
    "turned",
    "with_twist_joints",
    "world_positions",
    "yawed",
    "z_up",
]
