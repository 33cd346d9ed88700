"""Skeletons and forward / inverse kinematics.

A ``Skeleton`` is an immutable pytree: the topology (``parents``) and joint ``names`` are
static metadata, the rest-pose ``offsets`` (centimetres, in the parent's frame) are the
only array leaf. It can therefore be passed straight into ``jit``/``vmap``/``grad``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion.geometry.rotations import quat_conjugate, quat_mul, quat_rotate


def ancestors(parents: Sequence[int], joint: int) -> list[int]:
    """``joint`` and its ancestors up to the root, in that order."""
    chain = [joint]
    while parents[chain[-1]] >= 0:
        chain.append(parents[chain[-1]])
    return chain


def check_parents(parents: Sequence[int], names: Sequence[str] | None = None) -> None:
    """Raise ``ValueError`` unless ``parents`` lists the root first (parent -1) and every other
    joint after its parent: the order forward kinematics places them in. ``names`` (optional)
    name the joints in the message."""
    parents = [int(p) for p in np.asarray(parents).reshape(-1)]
    shown = (lambda j: f"joint {j}") if names is None else (lambda j: f"joint {j} ({names[j]!r})")
    if parents and parents[0] != -1:
        raise ValueError(f"{shown(0)} must be the root with parent -1, got {parents[0]}")
    for j, p in enumerate(parents[1:], start=1):
        if not (0 <= p < j):
            raise ValueError(f"{shown(j)} has parent {p}; parents must precede their children (0 <= parent < {j})")


def _validate_topology(parents: tuple[int, ...], names: tuple[str, ...]) -> None:
    if len(parents) == 0:
        raise ValueError("a skeleton needs at least one joint")
    if len(names) != len(parents):
        raise ValueError(f"{len(names)} names for {len(parents)} parents")
    check_parents(parents, names)
    seen: dict[str, int] = {}
    for j, name in enumerate(names):
        if not isinstance(name, str) or not name:
            raise ValueError(f"joint {j} has an invalid name {name!r}")
        if name in seen:
            raise ValueError(f"joint name {name!r} is used twice (joints {seen[name]} and {j})")
        seen[name] = j


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Skeleton:
    """A joint hierarchy with rest offsets.

    Attributes:
      parents: parent index per joint; ``-1`` for the root (joint 0); parents precede children.
      names: unique joint names, in the same order.
      offsets: ``(joints, 3)`` rest translation of each joint in its parent's frame (cm).
        The root's entry is its rest position (usually overridden by animated root motion).
        Leading batch axes ``(..., joints, 3)`` are allowed so that a batch of skeletons
        sharing one topology can be stacked and ``vmap``-ped over.
    """

    parents: tuple[int, ...] = dataclasses.field(metadata=dict(static=True))
    names: tuple[str, ...] = dataclasses.field(metadata=dict(static=True))
    offsets: Float[Array | np.ndarray, "*batch joints 3"]

    def __post_init__(self) -> None:
        object.__setattr__(self, "parents", tuple(int(p) for p in self.parents))
        object.__setattr__(self, "names", tuple(self.names))
        _validate_topology(self.parents, self.names)
        # Leaves may be tracers or placeholders inside JAX transformations: only check real shapes.
        shape = getattr(self.offsets, "shape", None)
        if shape is not None and (len(shape) < 2 or tuple(shape[-2:]) != (len(self.parents), 3)):
            raise ValueError(f"offsets must have shape (..., {len(self.parents)}, 3), got {tuple(shape)}")

    @classmethod
    def from_parents(cls, parents: Sequence[int], names: Sequence[str], offsets) -> "Skeleton":
        """Build a skeleton from plain sequences; ``offsets`` is anything array-like of shape (J, 3)."""
        return cls(tuple(parents), tuple(names), jnp.asarray(offsets))

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    def index(self, name: str) -> int:
        """Index of the joint called ``name``; raises ``ValueError`` listing the known names."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown joint {name!r}; this skeleton has {list(self.names)}") from None

    def indices(self, names: Sequence[str]) -> tuple[int, ...]:
        """Indices of several joints, in the order given."""
        return tuple(self.index(n) for n in names)

    def children(self, joint: int) -> tuple[int, ...]:
        """Indices of the direct children of ``joint``."""
        return tuple(j for j, p in enumerate(self.parents) if p == joint)

    def local_positions(self, root_pos: Float[Array, "*batch 3"]) -> Float[Array, "*batch joints 3"]:
        """Per-frame local translations: ``root_pos`` for the root, the rest offsets elsewhere."""
        batch = root_pos.shape[:-1]
        offsets = jnp.broadcast_to(jnp.asarray(self.offsets, root_pos.dtype), (*batch, self.num_joints, 3))
        return offsets.at[..., 0, :].set(root_pos)

    def fk(
        self, quat_local: Float[Array, "*batch joints 4"], root_pos: Float[Array, "*batch 3"]
    ) -> tuple[Float[Array, "*batch joints 4"], Float[Array, "*batch joints 3"]]:
        """Forward kinematics from local rotations and the root position (rest offsets elsewhere).

        Returns ``(quat_global, pos_global)``; positions in the units of the offsets (cm).
        """
        offsets = jnp.asarray(self.offsets, quat_local.dtype)
        return forward_kinematics(self.parents, quat_local, offsets, root_pos=root_pos)


def forward_kinematics(
    parents: Sequence[int],
    quat_local: Float[Array, "*batch joints 4"],
    pos_local: Float[Array, "*#batch joints 3"],
    *,
    root_pos: Float[Array, "*#batch 3"] | None = None,
) -> tuple[Float[Array, "*batch joints 4"], Float[Array, "*batch joints 3"]]:
    """Global rotations and positions from local ones.

    ``global_rot[j] = global_rot[parent] ⊗ local_rot[j]`` and
    ``global_pos[j] = rotate(global_rot[parent], local_pos[j]) + global_pos[parent]``.

    Args:
      parents: static parent indices (root first, parents precede children).
      quat_local: ``(..., J, 4)`` local rotations.
      pos_local: ``(..., J, 3)`` local translations, broadcastable against ``quat_local``
        (pass the ``(J, 3)`` rest offsets to share them over all frames).
      root_pos: optional ``(..., 3)`` root position replacing ``pos_local[..., 0, :]``.
    Returns:
      ``(quat_global, pos_global)`` with shapes ``(..., J, 4)`` and ``(..., J, 3)``.
    """
    num_joints = quat_local.shape[-2]
    if len(parents) != num_joints or pos_local.shape[-2] != num_joints:
        raise ValueError(
            f"{len(parents)} parents, {num_joints} joint rotations and {pos_local.shape[-2]} joint translations disagree"
        )
    check_parents(parents)
    batch = jnp.broadcast_shapes(
        quat_local.shape[:-2], pos_local.shape[:-2], () if root_pos is None else root_pos.shape[:-1]
    )
    pos_local = jnp.broadcast_to(pos_local, (*batch, num_joints, 3)).astype(quat_local.dtype)
    if root_pos is not None:
        pos_local = pos_local.at[..., 0, :].set(root_pos)
    quat_local = jnp.broadcast_to(quat_local, (*batch, num_joints, 4))
    # A scan over joints (joints-leading buffers updated in place) rather than a Python
    # loop: the unrolled loop makes XLA fuse and recompute every ancestor chain, which is
    # slow to compile and to run.
    rot = jnp.moveaxis(quat_local, -2, 0)
    pos = jnp.moveaxis(pos_local, -2, 0)
    parent_of = jnp.asarray(np.asarray(parents, dtype=np.int32))

    def place_joint(carry, j):
        rot_g, pos_g = carry
        p = parent_of[j]
        rot_g = rot_g.at[j].set(quat_mul(rot_g[p], rot_g[j]))
        pos_g = pos_g.at[j].set(quat_rotate(rot_g[p], pos_g[j]) + pos_g[p])
        return (rot_g, pos_g), None

    if num_joints > 1:
        (rot, pos), _ = jax.lax.scan(place_joint, (rot, pos), jnp.arange(1, num_joints))
    return jnp.moveaxis(rot, 0, -2), jnp.moveaxis(pos, 0, -2)


def inverse_kinematics(
    parents: Sequence[int],
    quat_global: Float[Array, "*batch joints 4"],
    pos_global: Float[Array, "*batch joints 3"],
) -> tuple[Float[Array, "*batch joints 4"], Float[Array, "*batch joints 3"]]:
    """Inverse of ``forward_kinematics``: local rotations and translations from global ones.

    ``local_rot[j] = conj(global_rot[parent]) ⊗ global_rot[j]`` and
    ``local_pos[j] = rotate(conj(global_rot[parent]), global_pos[j] - global_pos[parent])``;
    the root keeps its global values. Quaternion signs are preserved exactly.
    """
    parent_idx = np.asarray(parents[1:], dtype=np.int32)
    parent_rot_inv = quat_conjugate(quat_global[..., parent_idx, :])
    rot = jnp.concatenate([quat_global[..., :1, :], quat_mul(parent_rot_inv, quat_global[..., 1:, :])], axis=-2)
    delta = pos_global[..., 1:, :] - pos_global[..., parent_idx, :]
    pos = jnp.concatenate([pos_global[..., :1, :], quat_rotate(parent_rot_inv, delta)], axis=-2)
    return rot, pos
