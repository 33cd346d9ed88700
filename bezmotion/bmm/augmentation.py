"""Training-time augmentation: the free symmetries of aligned curve windows (ours).

Curve windows are aligned by translation only (hips start at the origin in XZ, Y up,
:mod:`bezmotion.data.curves`), so two transformations of a window give another window a
person could have performed, with no new data:

- **yaw rotation** by any angle about the vertical axis through the origin: positions,
  tangents and dense trajectories rotate, global orientations are pre-multiplied
  (``R' = R_y R``); foot contacts do not change. Exact for any skeleton.
- **left/right mirror** through the vertical plane ``x = 0``: positions and tangents have
  ``x`` negated, the left and right hands and feet (and the two foot contacts) swap, and the
  global orientation of the joint that lands in slot ``s`` becomes ``R' = M R P_s`` with
  ``M = diag(−1, 1, 1)`` the world reflection and ``P_s`` the reflection, in that joint's
  own rest frame, that maps the right joint's bones onto the left one's
  (:func:`rest_reflections`). ``M R P_s`` is a rotation (two reflections) and carries the
  mirrored joint's bones where the mirror images of the original joint's went: for a bone
  ``o_l = P o_r``, ``R' o_l = M R o_r``. Skeletons differ here: Bandai-Namco's feet flip
  their X axis, its hips Y and its chest Z, so ``P`` is measured per joint from the rest
  offsets rather than assumed.

Both act on one training example ``(ctrl_pos, ctrl_tangent, ctrl_rot6d, ctrl_contacts,
dense_pos)`` — joints in :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS`
order — inside the jitted step, before the conditions are drawn from it, so handles follow
the augmented curves.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, HIPS
from bezmotion.geometry.rotations import matrix_from_rot6d, rot6d_from_matrix
from bezmotion.geometry.skeleton import Skeleton

# Joint order after mirroring: hips and head stay, the hands swap, the feet swap.
_MIRRORED_JOINTS = tuple(
    CHARACTERISTIC_JOINTS.index(name.replace("left", "@").replace("right", "left").replace("@", "right"))
    for name in CHARACTERISTIC_JOINTS
)
_WORLD_MIRROR = np.diag([-1.0, 1.0, 1.0]).astype(np.float32)

Example = tuple[
    Float[Array, "controls 6 3"],  # ctrl_pos (cm)
    Float[Array, "controls 6 3"],  # ctrl_tangent (cm per control interval)
    Float[Array, "controls 6 6"],  # ctrl_rot6d (global orientations)
    Bool[Array, "controls 2"],  # ctrl_contacts (left, right foot)
    Float[Array, "frames 6 3"],  # dense_pos (cm)
]


Reflection = tuple[float, float, float]  # the diagonal of an axis reflection, one entry −1


def _axis_reflection(left: np.ndarray, right: np.ndarray, tol: float = 0.05) -> Reflection | None:
    """The axis reflection ``P`` with ``P right ≈ left`` (within ``tol`` of the bone length), if any."""
    length = max(np.linalg.norm(left), np.linalg.norm(right))
    if length < 1e-3:
        return None
    for axis in range(3):
        diag = np.ones(3)
        diag[axis] = -1.0
        if abs(right[axis]) > tol * length and np.linalg.norm(diag * right - left) <= tol * length:
            return tuple(float(d) for d in diag)
    return None


def _mirrored_children(skeleton: Skeleton, joint: int) -> Reflection | None:
    """The reflection between two children of ``joint`` that are mirror images (e.g. the hips' legs)."""
    offsets = np.asarray(skeleton.offsets, np.float64)
    children = skeleton.children(joint)
    for i, a in enumerate(children):
        for b in children[i + 1 :]:
            found = _axis_reflection(offsets[a], offsets[b])
            if found is not None:
                return found
    return None


def rest_reflections(skeleton: Skeleton, joints: dict[str, str]) -> tuple[Reflection, ...]:
    """Per characteristic joint, the axis reflection of its rest frame that swaps the body's sides.

    A left/right pair (hands, feet) compares the right joint's bones with the left one's:
    first their first child bones, then their own bones, then their parents' bones, and so
    up the two chains until a pair differs by the sign of one significant component (a bone
    along the reflection's fixed axes, equal on both sides, says nothing: Bandai-Namco's feet
    decide at their toes, X; LaFAN1's, whose leg bones all lie along X, at the hips, Z). A
    joint on the body's midline takes the reflection between two mirror-image children (the
    hips' legs), or else its nearest ancestor's (the head: the chest's shoulders).

    Args:
      skeleton: the skeleton (its rest offsets).
      joints: role → joint name for every role of
        :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS`.
    Returns:
      Six diagonals, in :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS` order.
    Raises:
      ValueError: naming the joints whose two sides are not mirror images along an axis.
    """
    offsets = np.asarray(skeleton.offsets, np.float64)
    index = {role: skeleton.index(joints[role]) for role in CHARACTERISTIC_JOINTS}

    def first_child(joint: int) -> int | None:
        children = [c for c in skeleton.children(joint) if np.linalg.norm(offsets[c]) > 1e-3]
        return children[0] if children else None

    found: dict[str, Reflection] = {}
    for side in ("hand", "foot"):
        left, right = index[f"left_{side}"], index[f"right_{side}"]
        pairs = [(first_child(left), first_child(right))]
        a, b = left, right
        while a != b and a > 0 and b > 0:  # up both chains until they meet (the bones below a shared joint)
            pairs.append((a, b))
            a, b = skeleton.parents[a], skeleton.parents[b]
        reflection = None
        for a, b in pairs:
            if a is None or b is None:
                continue
            reflection = _axis_reflection(offsets[a], offsets[b])
            length = max(np.linalg.norm(offsets[a]), 1e-3)
            if reflection is not None or np.linalg.norm(offsets[a] - offsets[b]) > 0.05 * length:
                break  # decided, or two bones that are not mirror images
        if reflection is None:
            raise ValueError(
                f"{joints[f'left_{side}']!r} and {joints[f'right_{side}']!r}: no bones of the two chains are mirror images "
                f"along an axis at rest (last compared: {offsets[a].tolist()} and {offsets[b].tolist()}); mirror augmentation cannot pair them"
            )
        found[f"left_{side}"] = found[f"right_{side}"] = reflection
    for role in ("hips", "head"):
        joint = index[role]
        while joint >= 0 and (reflection := _mirrored_children(skeleton, joint)) is None:
            joint = skeleton.parents[joint]
        if joint < 0:
            raise ValueError(f"no joint at or above {joints[role]!r} has mirror-image children; cannot mirror its frame")
        found[role] = reflection
    return tuple(found[role] for role in CHARACTERISTIC_JOINTS)


def rotate_yaw(example: Example, angle: Float[Array, ""]) -> Example:
    """The window turned by ``angle`` (radians) about the vertical (Y) axis through the origin."""
    pos, tangent, rot6d, contacts, dense = example
    c, s = jnp.cos(angle), jnp.sin(angle)
    zero, one = jnp.zeros_like(c), jnp.ones_like(c)
    yaw = jnp.stack([jnp.stack([c, zero, s]), jnp.stack([zero, one, zero]), jnp.stack([-s, zero, c])]).astype(pos.dtype)
    turn = lambda v: v @ yaw.T  # noqa: E731  (row vectors: v' = R v)
    rot6d = rot6d_from_matrix(yaw @ matrix_from_rot6d(rot6d))
    return turn(pos), turn(tangent), rot6d, contacts, turn(dense)


def mirror(example: Example, reflections: tuple[Reflection, ...]) -> Example:
    """The window mirrored through the plane ``x = 0``, left and right swapped (see the module notes).

    Args:
      example: one training window.
      reflections: the six joints' rest reflections ``P`` (:func:`rest_reflections`).
    """
    pos, tangent, rot6d, contacts, dense = example
    world = jnp.asarray(_WORLD_MIRROR, pos.dtype)
    swap = np.asarray(_MIRRORED_JOINTS)
    flip = lambda v: (v * jnp.diag(world))[..., swap, :]  # noqa: E731
    # Slot s receives joint swap[s]'s orientation, reflected in slot s's rest frame.
    rest = jnp.asarray(np.stack([np.diag(r) for r in reflections]), pos.dtype)  # (6, 3, 3)
    matrices = world @ matrix_from_rot6d(rot6d)[..., swap, :, :] @ rest
    return flip(pos), flip(tangent), rot6d_from_matrix(matrices), contacts[..., ::-1], flip(dense)


def hold_still(example: Example, control: Int[Array, ""]) -> Example:
    """``example``'s pose at control point ``control`` held for the whole window: every control
    point and dense frame at it, tangents zero, both feet planted; moved in XZ so the hips
    start at the origin, as every window is.

    A corpus records people moving: where its start and end poses agree, the window is often
    a gesture (a wave, a raised hand). A BMM trained on it alone learns that identical keys
    call for a gesture, and invents one when a user's clip stands still; held poses of every
    content teach it that keys which ask for no motion may get none
    (``experiments/still_keys.py`` counts such windows and measures a model on a held pose).
    """
    pos, tangent, rot6d, contacts, dense = example
    held = pos[control] - pos[control, HIPS] * jnp.asarray([1.0, 0.0, 1.0], pos.dtype)
    return (
        jnp.broadcast_to(held, pos.shape),
        jnp.zeros_like(tangent),
        jnp.broadcast_to(rot6d[control], rot6d.shape),
        jnp.ones_like(contacts),
        jnp.broadcast_to(held, dense.shape),
    )


def augment(
    key: Array,
    example: Example,
    *,
    yaw: bool,
    mirror_probability: float,
    reflections: tuple[Reflection, ...] | None,
    still_probability: float = 0.0,
) -> Example:
    """A random symmetry of ``example``: a uniform yaw turn (when ``yaw``), then a mirror with
    ``mirror_probability``; then, with ``still_probability``, one of its poses held still
    (:func:`hold_still`, at a uniformly drawn control point).

    With ``yaw=False`` and both probabilities 0 the example comes back unchanged (no random
    numbers drawn, so the paper's setting keeps its random stream).
    """
    yaw_key, mirror_key = jax.random.split(key)
    if yaw:
        example = rotate_yaw(example, jax.random.uniform(yaw_key, (), minval=-jnp.pi, maxval=jnp.pi))
    if mirror_probability > 0.0:
        mirrored = mirror(example, reflections)
        flip = jax.random.bernoulli(mirror_key, mirror_probability)
        example = jax.tree.map(lambda m, e: jnp.where(flip, m, e), mirrored, example)
    if still_probability > 0.0:
        still_key, control_key = jax.random.split(jax.random.fold_in(key, 3))
        held = hold_still(example, jax.random.randint(control_key, (), 0, example[0].shape[0]))
        stay = jax.random.bernoulli(still_key, still_probability)
        example = jax.tree.map(lambda h, e: jnp.where(stay, h, e), held, example)
    return example


__all__ = ["Reflection", "augment", "hold_still", "mirror", "rest_reflections", "rotate_yaw"]
