"""The model object: everything an in-between needs, in one pytree.

    model = bm.pretrained("bandai_namco")              # the bundled models, their own skeleton
    model = bm.Inbetweener.from_bvh(clip)              # any humanoid BVH: joints read off their names
    keys = model.poses(clip, [0, 30])                  # Pose (2, …): two keys are one window
    handles = model.handles({"right_hand": (12, (0.0, 25.0, 0.0))}, relative_to=keys)
    result = model.inbetween(keys, handles, key=jax.random.key(0))
    bm.write_bvh("out.bvh", model.to_bvh(result, template=clip))

An :class:`Inbetweener` holds the BMM, the IK module (``ik_fn`` static, its ``ik_params``
arrays), the character and the transfer from the BMM's training skeleton, so it passes
through ``jax.jit`` and ``jax.vmap`` like any pytree; :func:`~bezmotion.pipeline.inbetweening.inbetween`
is the function its :meth:`Inbetweener.inbetween` calls.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion.assets.registry import load_pretrained
from bezmotion.bmm.sampling import BezierMotionModel, Handles
from bezmotion.handles import line_between_keys
from bezmotion.data.bvh import BvhMotion
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.data.clip_frame import ClipFrame, detect_clip_frame
from bezmotion.ik.protocol import Character, IKFn, Pose, targets_from_pose
from bezmotion.ik.rig import RigSpec
from bezmotion.pipeline.authoring import (
    IK_CHOICES,
    RecognisedCharacter,
    check_ik_model,
    make_ik,
    make_transfer,
    motion_poses,
    recognise_character,
    target_profile,
)
from bezmotion.pipeline.export import pose_to_bvh
from bezmotion.pipeline.inbetweening import InbetweenOptions, InbetweenResult, inbetween, window_layout
from bezmotion.pipeline.key_times import TimedInbetween, checked_key_times, inbetween_at
from bezmotion.pipeline.transfer import Transfer

HANDLE_SLOTS = 4
"""Handles are padded to a multiple of this many slots, so that another count of handles
reuses the compiled in-between."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Inbetweener:
    """A BMM, an IK module and the character they drive: :func:`bm.inbetween`'s model.

    Attributes:
      bmm: the Bézier Motion Model.
      ik_fn: the IK module, ``ik_fn(params, targets) -> pose`` (static: part of the compiled program).
      ik_params: its parameters (a learned IK, a rig, the exact IK's parameters on either).
      character: the skeleton the motion is for and its six characteristic joints.
      transfer: from the BMM's training skeleton to ``character``'s (proportions, joint
        frames, facing); ``None``: none.
      clip_frame: the units and up axis of the user's clips (static); the model works in
        cm with Y up, and :meth:`poses` and :meth:`to_bvh` convert.
    """

    bmm: BezierMotionModel
    ik_fn: IKFn = dataclasses.field(metadata=dict(static=True))
    ik_params: Any
    character: Character
    transfer: Transfer | None = None
    clip_frame: ClipFrame = dataclasses.field(default=ClipFrame(), metadata=dict(static=True))

    # ------------------------------------------------------------------ construction

    @classmethod
    def pretrained(
        cls, name: str = "bandai_namco", *, ik: str = "exact", root: str | os.PathLike | None = None, verify: bool = True
    ) -> Inbetweener:
        """A registered model (``bezmotion models`` lists them) for the skeleton it was trained on.

        Args:
          name: the registered name, e.g. ``"bandai_namco"`` (bundled).
          ik: one of :data:`~bezmotion.pipeline.authoring.IK_CHOICES`; ``"exact"`` (default)
            is the learned IK refined until the handles are hit.
          root: the bundled models' root (default: the package's).
          verify: check the models' files against their checksums (``False``: load a
            locally trained model saved before models carried them; it warns).
        Raises:
          ValueError: an unknown name or IK (listing the known ones), or weights holding NaN or inf.
          ChecksumError: a model's files differ from their checksums, or have none.
          FileNotFoundError: a model that is not bundled and not trained yet (naming the command).
        """
        parts = load_pretrained(name, root=root, verify=verify)
        preset = parts.entry.skeleton
        recognised = RecognisedCharacter(parts.character, preset, RigSpec.preset(preset))
        rest = _identity_rotations(parts.character.num_joints)
        ik_fn, ik_params = _make_ik(ik, recognised, rest, parts.ik, parts.joint_limits)
        transfer = make_transfer(parts.profile, None)
        return cls(parts.bmm, ik_fn, ik_params, parts.character, transfer)

    @classmethod
    def from_bvh(
        cls,
        clip: BvhMotion,
        *,
        model: str = "bandai_namco",
        ik: str = "auto",
        mapping: str | os.PathLike | None = None,
        clip_frame: ClipFrame | None = None,
        facing: str = "trained",
        orientation: str = "anatomical",
        verify: bool = True,
    ) -> Inbetweener:
        """A model for the skeleton of ``clip``, whatever its joint names, units and up axis.

        The six characteristic joints are read as ``bezmotion inbetween`` reads them: a known
        hierarchy, else the joint names (Mixamo, Unreal, Blender, SMPL, Daz, 3ds Max), else
        ``mapping``. The BMM is moved onto the skeleton's proportions and joint frames
        (:class:`~bezmotion.pipeline.transfer.Transfer`) measured on ``clip``.

        Args:
          clip: a BVH of the character (:func:`~bezmotion.data.bvh.read_bvh`).
          model: a registered model name.
          ik: ``"auto"`` (the learned IK where it was trained on this skeleton, else the
            analytic rig, both refined by the exact IK) or one of
            :data:`~bezmotion.pipeline.authoring.IK_CHOICES`.
          mapping: a JSON/TOML file naming the six joints, for skeletons whose names do not tell them.
          clip_frame: the clip's units and up axis; default: told from the clip.
          facing, orientation: as in :func:`~bezmotion.pipeline.authoring.make_transfer`.
          verify: check the models' files against their checksums (as :meth:`pretrained`).
        Raises:
          ValueError: a skeleton whose six joints cannot be told (the message says how to
            name them), an unknown IK, or a learned IK that does not fit the skeleton.
          ChecksumError: a model's files differ from their checksums, or have none.
        """
        recognised = recognise_character(clip, mapping)
        if clip_frame is None:
            hips, head, _, _, left_foot, right_foot = recognised.character.characteristic
            clip_frame = detect_clip_frame(clip, hips, head, (left_foot, right_foot))
        ours = clip_frame.to_ours(clip)
        recognised = recognise_character(ours, mapping)  # the offsets in cm
        parts = load_pretrained(model, verify=verify)
        same = recognised.preset == parts.entry.skeleton
        target = None if same else target_profile(recognised, [ours])
        transfer = make_transfer(parts.profile, target, orientation=orientation, facing=facing)
        if ik == "auto":
            ik = "exact" if _fits(parts.ik, recognised.character) else "exact_rig"
        ik_fn, ik_params = _make_ik(ik, recognised, np.asarray(ours.quat_local[0]), parts.ik, parts.joint_limits if same else None)
        return cls(parts.bmm, ik_fn, ik_params, recognised.character, transfer, clip_frame)

    # ------------------------------------------------------------------ use

    @property
    def span(self) -> int:
        """Frames between consecutive keys (the BMM's window less one: 30)."""
        return self.bmm.config.num_frames - 1

    def poses(self, clip: BvhMotion, frames: Sequence[int] | int | slice) -> Pose:
        """Frames of ``clip`` (in its own units and up axis) as poses of the character, e.g.
        ``frames=[0, 30]`` for two keys; ``(len(frames), …)``.

        Raises:
          ValueError: a clip of another skeleton, or a frame outside it.
        """
        names = self.character.skeleton.names
        if tuple(clip.skeleton.names) != tuple(names) or tuple(clip.skeleton.parents) != tuple(self.character.skeleton.parents):
            raise ValueError(f"the clip's skeleton ({len(clip.skeleton.names)} joints) is not this model's {self.character.name} ({len(names)} joints)")
        count = clip.quat_local.shape[0]
        if not isinstance(frames, slice):
            wanted = np.atleast_1d(np.asarray(frames))
            if wanted.dtype.kind not in "iu" or ((wanted < -count) | (wanted >= count)).any():
                raise ValueError(f"frames must be integers within the clip's {count} frames, got {np.asarray(frames).tolist()}")
        return motion_poses(self.clip_frame.to_ours(clip), self.character, frames)

    def handles(
        self,
        where: Mapping[str, tuple[int, Any] | Sequence[tuple[int, Any]]],
        *,
        relative_to: Pose | None = None,
        span: int | None = None,
        times: Sequence[int] | None = None,
    ) -> Handles:
        """Handles from joint roles: ``{"right_hand": (12, (x, y, z)), "left_foot": [(8, …), (20, …)]}``.

        Frames count as the keys' do: with ``times`` (:meth:`inbetween_at`'s), in the same
        count; else from the first key, key ``k`` at frame ``span·k`` (``span`` as
        :meth:`inbetween`'s, default :attr:`span`: 30). Positions are in cm, Y up, in the
        model's world frame (the clip's, converted to cm). With ``relative_to`` (the keys), a
        position is an offset from the straight line between the joint's positions at the keys
        around its frame.

        Raises:
          ValueError: an unknown role, a frame on a key or outside the keys (when
            ``relative_to`` or ``times`` tells how many there are), a position that is not 3
            finite numbers, or both ``span`` and ``times``.
        """
        if times is not None and span is not None:
            raise ValueError(f"give the keys' frames as times or their spacing as span, not both (span={span!r}, times={times!r})")
        if times is None:
            span = window_layout(self.bmm.config, span).num_frames - 1
            count = None if relative_to is None else relative_to.root_pos.shape[0]
            key_frames = None if count is None else np.arange(count) * span
            on_key = lambda frame: frame <= 0 or frame % span == 0  # noqa: E731
            keys_named = f"frames 0, {span}, … are keys"
        else:
            key_frames = np.asarray(checked_key_times(times, len(times) if relative_to is None else relative_to.root_pos.shape[0]))
            on_key = lambda frame: frame <= key_frames[0] or frame >= key_frames[-1] or frame in key_frames  # noqa: E731
            keys_named = f"the keys are at frames {key_frames.tolist()}"
        roles, frames, positions = [], [], []
        for role, entries in where.items():
            if role not in CHARACTERISTIC_JOINTS:
                raise ValueError(f"unknown joint role {role!r}; handles go on {', '.join(CHARACTERISTIC_JOINTS)}")
            for frame, position in [entries] if _is_single(entries) else entries:
                position = np.asarray(position, np.float64)
                if position.shape != (3,) or not np.isfinite(position).all():
                    raise ValueError(f"{role} at frame {frame}: a position is 3 finite numbers (cm), got {np.asarray(position).tolist()}")
                if isinstance(frame, bool) or not isinstance(frame, int | np.integer) or on_key(frame):
                    raise ValueError(f"{role} at frame {frame!r}: handles go on integer frames between the keys ({keys_named})")
                roles.append(CHARACTERISTIC_JOINTS.index(role))
                frames.append(int(frame))
                positions.append(position)
        if relative_to is not None:
            positions = self._offsets_to_positions(relative_to, roles, frames, positions, key_frames)
        slots = HANDLE_SLOTS * max(1, -(-len(roles) // HANDLE_SLOTS))
        pad = slots - len(roles)
        return Handles(
            joint=jnp.asarray(roles + [0] * pad, jnp.int32),
            frame=jnp.asarray(frames + [0] * pad, jnp.int32),
            position=jnp.asarray(np.reshape(positions + [np.zeros(3)] * pad, (slots, 3)), jnp.float32),
            valid=jnp.asarray([True] * len(roles) + [False] * pad, bool),
        )

    def _offsets_to_positions(self, keys: Pose, roles: list[int], frames: list[int], offsets: list[np.ndarray], key_frames: np.ndarray) -> list[np.ndarray]:
        key_positions = np.asarray(targets_from_pose(self.character, keys).position, np.float64)  # (K, 6, 3)
        out = []
        for role, frame, offset in zip(roles, frames, offsets):
            if frame >= key_frames[-1]:
                raise ValueError(
                    f"{CHARACTERISTIC_JOINTS[role]} at frame {frame}: outside the in-between, frames {key_frames[0]} … {key_frames[-1]} (the keys' last)"
                )
            out.append(offset + line_between_keys(key_positions, role, frame, key_frames))
        return out

    def inbetween(
        self,
        keys: Pose,
        handles: Handles | None = None,
        *,
        key: Array,
        options: InbetweenOptions = InbetweenOptions(),
        key_velocity: Float[Array, "keys 6 3"] | None = None,
        span: int | None = None,
    ) -> InbetweenResult:
        """:func:`~bezmotion.pipeline.inbetweening.inbetween` of this model (``span``: frames
        from one key to the next, default the model's window, 30)."""
        return inbetween(self, keys, handles, key=key, options=options, key_velocity=key_velocity, span=span)

    def inbetween_at(
        self,
        keys: Pose,
        times: Sequence[int],
        handles: Handles | None = None,
        *,
        key: Array,
        options: InbetweenOptions = InbetweenOptions(),
        key_velocity: Float[Array, "keys 6 3"] | None = None,
    ) -> TimedInbetween:
        """:func:`~bezmotion.pipeline.key_times.inbetween_at` of this model: keys at the frames
        ``times`` (any distance apart, e.g. ``[0, 20, 65, 90]``)."""
        return inbetween_at(self, keys, times, handles, key=key, options=options, key_velocity=key_velocity)

    def to_bvh(self, result: InbetweenResult | TimedInbetween | Pose, *, template: BvhMotion | None = None, fps: float = 30.0) -> BvhMotion:
        """The motion as a BVH (:func:`~bezmotion.data.bvh.write_bvh` writes it), in the
        clips' units and up axis; ``template``: a clip whose OFFSETs, End Sites and channels
        the file keeps, so it rigs like the clip."""
        pose = result.pose if isinstance(result, InbetweenResult | TimedInbetween) else result
        template = None if template is None else self.clip_frame.to_ours(template)
        channels = None if template is None else template.channels
        motion = pose_to_bvh(self.character, pose, fps=fps, template=template, channels=channels)
        return self.clip_frame.from_ours(motion)


def _is_single(entries: Any) -> bool:
    """Whether a handle entry is one ``(frame, position)`` rather than a list of them."""
    return len(entries) == 2 and isinstance(entries[0], int | np.integer) and not isinstance(entries[0], bool)


def _identity_rotations(joints: int) -> np.ndarray:
    return np.tile(np.asarray([1.0, 0.0, 0.0, 0.0], np.float32), (joints, 1))


def _fits(ik_model: Any, character: Character) -> bool:
    try:
        check_ik_model(ik_model, character)
    except ValueError:
        return False
    return True


def _make_ik(kind: str, recognised: RecognisedCharacter, rest: np.ndarray, ik_model: Any, limits: Any) -> tuple[IKFn, Any]:
    if kind not in IK_CHOICES:
        raise ValueError(f"ik must be one of {', '.join(IK_CHOICES)}, got {kind!r}")
    return make_ik(kind, recognised, rest_quat_local=rest, ik_model=ik_model, limits=limits if kind == "exact" else None)


def pretrained(
    name: str = "bandai_namco", *, ik: str = "exact", root: str | os.PathLike | None = None, verify: bool = True
) -> Inbetweener:
    """:meth:`Inbetweener.pretrained`: ``bm.pretrained("bandai_namco")`` is the bundled model."""
    return Inbetweener.pretrained(name, ik=ik, root=root, verify=verify)


__all__ = ["HANDLE_SLOTS", "Inbetweener", "pretrained"]
