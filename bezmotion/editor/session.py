"""The editing session behind ``bezmotion edit``: one clip, its keys and handles, edited a step at a time.

    session = EditSession.open("my_walk.bvh", "take/")       # keys at the clip's frames 0 and 30
    hand = session.add_handle("right_hand", 12)              # on its curve: nothing moves yet
    session.drag(hand, (10.0, 140.0, 30.0))                   # curves at once, the body from the last solve
    session.release()                                        # a full resample through the handle
    session.undo(); session.redo()
    session.export("take")                                   # take/take.bvh, take.glb, take.handles.json

What the user edits is one immutable :class:`EditState` (the keys as clip frames, the handles,
the seed, the options and the IK); every edit makes a new one, and undo and redo move between
them along two stacks. What a state shows (:class:`EditView`: the poses, the six curves and
their control points, the handles' misses and warnings) is a pure function of it, the same
in-between ``bezmotion inbetween`` makes of those keys, handles and seed, and is kept per
state, so undo and redo are instant.

A drag is the one thing that is not an edit until it ends: :meth:`EditSession.drag` moves a
handle and re-projects the last sample's curves onto it (exactly, no diffusion:
:func:`~bezmotion.pipeline.inbetweening.reproject_curves`), and the exact IK solves the body
starting from the previous solution (a warm start); :meth:`EditSession.release` makes it an
edit, whose view is a full resample with the state's seed. Both are compiled once for the
shapes at hand: handles are padded to a multiple of :data:`~bezmotion.pipeline.model.HANDLE_SLOTS`
slots, so adding one (up to the next multiple) compiles nothing.

Nothing a caller passes after construction names a path to read or write: exports go to the
output folder given at construction, by a plain name, as one set of files replaced together
(:func:`~bezmotion._src.output_sets.output_set`); :meth:`EditSession.open_handles` reads only a
file in that folder. Every method that edits checks its input first and raises a one-line
``ValueError`` naming the offending value, with the state unchanged.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import json
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from bezmotion._src.io import atomic_write_text, check_writable_folder
from bezmotion._src.messages import listed, one_line
from bezmotion._src.output_sets import existing_outputs, output_set
from bezmotion._src.xla_options import inference_jit
from bezmotion.bmm.sampling import Handles, SampledCurves
from bezmotion.cli.inbetween import sample_key
from bezmotion.cli.handles import (
    HandleRequest,
    handle_conflicts,
    handle_misses,
    handle_role,
    read_handles_file,
    records_as_handles,
    resolve_handles,
)
from bezmotion.cli.plan import bvh_frame_rate
from bezmotion.data.bvh import BvhMotion, read_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.data.resample import TRAINED_FPS, resample_motion
from bezmotion.evaluation.window_figures import ReachChains, beyond_reach, conflicting_handles, reach_chains
from bezmotion.handles import HANDLE_FARTHEST_CM, line_between_keys
from bezmotion.ik.exact import ExactIKFn
from bezmotion.ik.protocol import Character, Pose, pose_fk, targets_from_pose
from bezmotion.ik.rig import make_rig
from bezmotion.pipeline.authoring import IK_CHOICES, ResultFiles, clip_key_velocities, recognise_character, write_result
from bezmotion.pipeline.export import pose_to_bvh
from bezmotion.pipeline.inbetweening import (
    InbetweenOptions,
    InbetweenResult,
    inbetween,
    join_chain_curves,
    reproject_curves,
    result_from_curves,
    window_handles,
)
from bezmotion.pipeline.model import HANDLE_SLOTS, Inbetweener

HISTORY = 200
"""How many edits :meth:`EditSession.undo` can take back."""

VIEWS_KEPT = 64
"""How many states' views a session keeps (the most recently shown), so undo and redo are instant."""

Position = ArrayLike | Sequence[float]
"""A position a caller gives: 3 numbers, cm."""

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")  # an export's name: a plain stem, nothing a path could hide in


# ------------------------------------------------------------------------------- state


@dataclasses.dataclass(frozen=True)
class EditHandle:
    """A handle: the joint ``joint`` is at ``position`` at frame ``frame`` of the in-between.

    Attributes:
      id: the session's name for it, the same across edits, undo and redo.
      joint: one of :data:`~bezmotion.data.characteristic.CHARACTERISTIC_JOINTS`.
      frame: frame of the in-between (0: the first key; key ``k`` at ``30·k``), never a key's.
      position: ``(x, y, z)`` cm, Y up, the model's world frame (the clip's, in cm).
    """

    id: int
    joint: str
    frame: int
    position: tuple[float, float, float]

    def record(self) -> dict[str, Any]:
        """``{"joint", "frame", "position"}``, as a handles file and ``summary.json`` write it."""
        return {"joint": self.joint, "frame": self.frame, "position": list(self.position)}


@dataclasses.dataclass(frozen=True)
class EditState:
    """Everything a user edits, as one immutable snapshot (hashable: the key of its view).

    Attributes:
      keys: frames of the clip (at 30 fps) that are the key poses, in order: key ``k`` is frame
        ``30·k`` of the in-between; two keys are one window, more a chain.
      handles: the handles, in the order they were added.
      seed: the sample's seed, as ``bezmotion inbetween --seed`` takes it.
      options: how the in-between is sampled (foot lock, DDIM steps, …).
      key_velocities: the curves leave and reach every key at the clip's own velocities there.
      ik: the name of the IK, one of the session's :attr:`EditSession.ik_choices`.
    """

    keys: tuple[int, ...]
    handles: tuple[EditHandle, ...]
    seed: int
    options: InbetweenOptions
    key_velocities: bool
    ik: str


class EditView(NamedTuple):
    """What the session shows for a state, or for a drag in progress (cm, Y up; NumPy for
    drawing, but the pose, which library functions take).

    Attributes:
      pose: :class:`~bezmotion.ik.protocol.Pose` per frame, ``(frames, …)`` (JAX arrays).
      joints: ``(frames, joints, 3)`` every joint's world position, for drawing the body.
      curves: the six curves through every key, ``ctrl_pos``/``ctrl_tangent`` ``(controls, 6, 3)``,
        ``ctrl_rot6d`` ``(controls, 6, 6)``, ``contacts`` ``(controls, 2)``; a control point every
        ``bmm.config.stride`` frames.
      positions: ``(frames, 6, 3)`` the curves at every frame, what the IK was given.
      handle_errors: handle id → how far (cm) the body's joint lies from it.
      misses: a line per handle the body misses by more than 1 cm, saying why where it is known.
      warnings: a line per pair of handles on one frame that no pose meets together.
    """

    pose: Pose
    joints: np.ndarray
    curves: SampledCurves
    positions: np.ndarray
    handle_errors: dict[int, float]
    misses: tuple[str, ...]
    warnings: tuple[str, ...]


class _Shown(NamedTuple):
    """A state's view and what a drag from it needs, on the device."""

    view: EditView
    result: InbetweenResult
    keys: Pose
    key_velocity: Array | None


class _Drag(NamedTuple):
    """A drag in progress: the state it would commit, the body it last solved, its view."""

    state: EditState
    pose: Pose
    view: EditView


# ------------------------------------------------------------------------------- compiled


@functools.partial(inference_jit, static_argnames=("options", "keyed"))
def _dragged(
    model: Inbetweener, keys: Pose, handles: Handles, curves: SampledCurves, start: Pose | None, options: InbetweenOptions, keyed: bool
) -> InbetweenResult:
    """The sample's ``curves`` re-projected onto ``handles`` (in the in-between's frames) and
    the body from them, the IK starting from ``start`` where one is given."""
    windows = window_handles(handles, keys.root_pos.shape[0] - 1, model.bmm.config.num_frames - 1)
    moved = reproject_curves(model.bmm, curves, windows, options, keyed=keyed)
    return result_from_curves(model, moved, keys, windows, options, start=start)


@jax.jit
def _measured(character: Character, pose: Pose, handles: Handles, reach: ReachChains) -> tuple[Array, Array, Array]:
    """``(joints (frames, joints, 3) cm, beyond (slots,), conflict (slots, slots))``: FK of
    the body, the handles beyond their limb's reach, the pairs no pose meets together."""
    _, joints = pose_fk(character, pose)
    return joints, beyond_reach(joints, handles, reach), conflicting_handles(handles, reach)


@jax.jit
def _joint_positions(character: Character, pose: Pose) -> tuple[Array, Array]:
    """``(joints (frames, joints, 3), six (frames, 6, 3))`` world positions, cm."""
    return pose_fk(character, pose)[1], targets_from_pose(character, pose).position


# ------------------------------------------------------------------------------- session


class EditSession:
    """An editing session of one clip (see the module docstring): keys, handles, samples,
    undo and redo, drags, export. A plain Python object; a GUI calls only this.

    Args:
      clip: the clip (:func:`~bezmotion.data.bvh.read_bvh`, its own units and up axis); one at
        another frame rate is resampled to 30 fps through its first frame, and the keys are
        frames of that.
      models: IK name → the model (:class:`~bezmotion.pipeline.model.Inbetweener` of the
        clip's skeleton) to in-between with it; a mapping may load them when first asked for.
      out_dir: the one folder exports go to and handles files are read from (made at the first export).
      keys: the first state's keys (clip frames).
      ik: the first state's IK (default: the first of ``models``).
      seed, options, key_velocities: the first state's (:class:`EditState`).
      mapping: a JSON/TOML file naming the six joints of a skeleton whose names do not tell
        them (as ``bezmotion inbetween --mapping``).
    Raises:
      ValueError: keys that are not at least two frames of the clip, an unknown IK, an
        output folder that cannot be written, a clip whose six joints cannot be told.
    """

    def __init__(
        self,
        clip: BvhMotion,
        models: Mapping[str, Inbetweener],
        out_dir: str | os.PathLike,
        *,
        keys: Sequence[int] = (0, 30),
        ik: str | None = None,
        seed: int = 0,
        options: InbetweenOptions = InbetweenOptions(foot_lock=True),
        key_velocities: bool = False,
        mapping: str | os.PathLike | None = None,
    ) -> None:
        if not models:
            raise ValueError("an editing session needs at least one model (IK name → Inbetweener)")
        self._models = models
        self._clip_fps = clip.nominal_fps
        self._clip, _ = resample_motion(clip, TRAINED_FPS, 0)
        self._out = Path(out_dir).absolute()
        check_writable_folder(self._out)
        ik = next(iter(models)) if ik is None else ik
        model = self._model(ik)
        self._clip_frame = model.clip_frame
        self._ours = model.clip_frame.to_ours(self._clip)
        self._recognised = recognise_character(self._ours, mapping)
        character = self._recognised.character
        if character.skeleton.names != model.character.skeleton.names:
            raise ValueError(f"the models are of {model.character.name}, not of the clip's skeleton {character.name}")
        rest = np.asarray(self._ours.quat_local[0])
        reach = reach_chains(make_rig(character, self._recognised.rig_spec, rest_quat_local=rest))
        self._reach = reach
        self._reach_device = ReachChains(
            jnp.asarray(reach.root, jnp.int32), jnp.asarray(reach.length, jnp.float32), jnp.asarray(reach.apart, jnp.float32)
        )
        self._undo: list[EditState] = []
        self._redo: list[EditState] = []
        self._shown: collections.OrderedDict[EditState, _Shown] = collections.OrderedDict()
        self._layouts: set[tuple[Any, ...]] = set()  # (keys, IK, handles' joints and frames) resolve_handles passed
        self._key_cache: dict[tuple[int, ...], tuple[Pose, np.ndarray, np.ndarray]] = {}
        self._next_id = 0
        self._drag: _Drag | None = None
        self._state = EditState(self._checked_keys(keys), (), _seed(seed), _options(options), _flag(key_velocities, "key_velocities"), ik)
        if self._state.key_velocities:
            self._key_velocity(self._state.keys)
        self._seeds = [self._state.seed]

    @classmethod
    def open(
        cls,
        clip: str | os.PathLike,
        out_dir: str | os.PathLike,
        *,
        keys: Sequence[int] = (0, 30),
        model: str = "bandai_namco",
        ik: str = "auto",
        mapping: str | os.PathLike | None = None,
        seed: int = 0,
        options: InbetweenOptions = InbetweenOptions(foot_lock=True),
        key_velocities: bool = False,
        verify: bool = True,
    ) -> EditSession:
        """A session of the BVH file ``clip`` with a registered model (``bezmotion models``),
        every IK of :data:`~bezmotion.pipeline.authoring.IK_CHOICES` (and ``"auto"``) to choose
        from, each loaded when first used (:meth:`Inbetweener.from_bvh`).

        Raises:
          FileNotFoundError: no such clip.
          ValueError: as :func:`~bezmotion.data.bvh.read_bvh` and the constructor.
        """
        motion = read_bvh(clip)
        models = _ModelsByIK(motion, ("auto", *IK_CHOICES), model=model, mapping=mapping, verify=verify)
        return cls(motion, models, out_dir, keys=keys, ik=ik, seed=seed, options=options, key_velocities=key_velocities, mapping=mapping)

    # --------------------------------------------------------------------- what is shown

    @property
    def state(self) -> EditState:
        """The current state (a drag in progress not included until released)."""
        return self._state

    @property
    def view(self) -> EditView:
        """What to show now: the drag in progress, else the current state's in-between
        (sampled the first time it is asked for: the first paint compiles it)."""
        return self._drag.view if self._drag is not None else self._show(self._state).view

    @property
    def character(self) -> Character:
        """The clip's skeleton (its parents draw the bones) and six characteristic joints."""
        return self._recognised.character

    @property
    def frames(self) -> int:
        """Frames of the in-between: ``30·(K − 1) + 1`` through ``K`` keys."""
        return self._span * (len(self._state.keys) - 1) + 1

    @property
    def key_frames(self) -> tuple[int, ...]:
        """The in-between's frames that are keys: ``0, 30, …``."""
        return tuple(range(0, self.frames, self._span))

    @property
    def clip_frames(self) -> int:
        """Frames of the clip (at 30 fps): the keys are chosen among them."""
        return self._clip.num_frames

    @property
    def ghost(self) -> np.ndarray:
        """``(frames, joints, 3)`` cm: the clip's own motion between the keys, every joint,
        for drawing beside the in-between (each window's frames spread evenly over the clip's
        frames between its two keys)."""
        return self._keys(self._state.keys)[2]

    @property
    def ik_choices(self) -> tuple[str, ...]:
        """The IKs :meth:`set_ik` takes."""
        return tuple(self._models)

    @property
    def seeds(self) -> tuple[int, ...]:
        """The seeds sampled in this session, in the order first used (:meth:`use_seed` flips between them)."""
        return tuple(self._seeds)

    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    def warm_up(self) -> EditView:
        """Compile what editing the current state runs: its in-between, and a drag of its
        handles (the same shapes up to :data:`~bezmotion.pipeline.model.HANDLE_SLOTS` handles
        a window), so the first real drag does not wait. Changes nothing; returns :attr:`view`."""
        self._dragged(self._state, None)
        return self.view

    # --------------------------------------------------------------------- handles

    def add_handle(self, joint: str, frame: int, position: Position | None = None) -> int:
        """Add a handle; returns its id.

        Args:
          joint: a characteristic role (``"right_hand"``) or the skeleton's name for one.
          frame: a frame of the in-between between keys (not a key's).
          position: ``(3,)`` cm; default where the joint's curve is at that frame now, so that
            the handle pins it there (the view is resampled all the same).
        Raises:
          ValueError: an unknown joint, a frame outside the in-between or on a key, a position
            that is not 3 finite numbers or lies farther than 100 m from the line between the
            keys, another handle on that joint and frame.
        """
        handle_id = self._next_id
        source = f"handle {handle_id}"
        role = handle_role(HandleRequest(str(joint), 0, (0.0, 0.0, 0.0), False, source), self._recognised)
        frame = _frame(frame, source)
        for other in self._state.handles:
            if (other.joint, other.frame) == (role, frame):
                raise ValueError(f"{source}: {role} at frame {frame} has a handle already, handle {other.id}; move that one")
        if position is None:
            inside = 0 <= frame < self.frames  # elsewhere the frame's own check below says why
            position = self._show(self._state).view.positions[frame, CHARACTERISTIC_JOINTS.index(role)] if inside else np.zeros(3)
        handle = EditHandle(handle_id, role, frame, _position(position, source))
        self._commit(dataclasses.replace(self._state, handles=(*self._state.handles, handle)))
        self._next_id += 1
        return handle_id

    def move_handle(self, handle_id: int, position: Position) -> EditView:
        """Put a handle at ``position`` ``(3,)`` cm (one edit: a full resample; :meth:`drag` for
        a gizmo). Raises ``ValueError`` for an unknown id or a position :meth:`add_handle` refuses."""
        return self._commit(self._moved(self._state, handle_id, position))

    def delete_handle(self, handle_id: int) -> EditView:
        """Remove a handle. Raises ``ValueError`` for an unknown id."""
        self._handle(self._state, handle_id)
        return self._commit(dataclasses.replace(self._state, handles=tuple(h for h in self._state.handles if h.id != handle_id)))

    def open_handles(self, name: str) -> EditView:
        """Replace the handles with those of the handles file ``name`` in the output folder
        (a JSON or TOML file as ``bezmotion inbetween --handles`` reads, e.g. one
        :meth:`export` wrote; ``"offset"`` entries are offsets from the line between the keys).

        Raises:
          ValueError: a name that is not a plain file name in the output folder (no folders,
            no links out of it), a file that is missing or not a handles file, a handle the
            current keys refuse; each naming the file and, where it is one, the handle.
        """
        if not isinstance(name, str) or Path(name).name != name or name.startswith(".") or not name:
            raise ValueError(f"a handles file is named by its plain file name in {self._out}, got {one_line(repr(name), 80)}")
        path = self._out / name
        if not path.exists() or path.resolve().parent != self._out.resolve():
            raise ValueError(f"{name}: no such file in {self._out}")
        model = self._model(self._state.ik)
        keys = self._keys(self._state.keys)[0]
        try:
            requests = read_handles_file(path)
            _, records = resolve_handles(requests, self._recognised, _unbatched(keys), model.bmm)
        except (ValueError, FileNotFoundError) as error:
            raise ValueError(one_line(str(error).removeprefix("--handles "))) from None
        first = self._next_id
        handles = tuple(EditHandle(first + i, r["joint"], r["frame"], _position(r["position"], f"{name}: handle {i}")) for i, r in enumerate(records))
        view = self._commit(dataclasses.replace(self._state, handles=handles))
        self._next_id += len(handles)
        return view

    # --------------------------------------------------------------------- drag

    def drag(self, handle_id: int, position: Position) -> EditView:
        """Move a handle while its gizmo is dragged: the last sample's curves re-projected
        onto it (no diffusion) and the body solved from the previous drag's (the exact IK's
        warm start; other IKs solve afresh). Not an edit until :meth:`release`.

        Raises:
          ValueError: an unknown id, or a position :meth:`add_handle` refuses; the drag so far stays.
        """
        base = self._drag.state if self._drag is not None else self._state
        state = self._moved(base, handle_id, position)
        result, handles = self._dragged(state, None if self._drag is None else self._drag.pose)
        view = self._view(state, result, handles)
        self._drag = _Drag(state, result.pose, view)
        return view

    def release(self) -> EditView:
        """End the drag: its handle positions become an edit, sampled afresh with the state's seed.

        Raises:
          ValueError: no drag in progress.
        """
        if self._drag is None:
            raise ValueError("no handle is being dragged")
        state = self._drag.state
        self._drag = None
        return self._commit(state)

    def cancel_drag(self) -> EditView:
        """Drop the drag in progress (if any): the handles where they were."""
        self._drag = None
        return self.view

    # --------------------------------------------------------------------- keys, samples, options

    def set_keys(self, frames: Sequence[int]) -> EditView:
        """Key the in-between at these clip frames, in order (two: one window; more: a chain,
        each key 30 frames after the one before). The handles keep their frames and positions.

        Raises:
          ValueError: fewer than two frames, a frame outside the clip, a handle that falls on a
            key or outside the new in-between (naming it), key velocities the clip cannot give.
        """
        return self._commit(dataclasses.replace(self._state, keys=self._checked_keys(frames)))

    def add_key(self, frame: int | None = None) -> EditView:
        """Key one more clip frame after the last key (default: 30 frames after it), making
        the in-between a window longer. Raises as :meth:`set_keys`."""
        keys = self._state.keys
        return self.set_keys((*keys, keys[-1] + self._span if frame is None else frame))

    def resample(self) -> EditView:
        """A new sample: the next seed not yet used in this session."""
        return self.use_seed(max(self._seeds) + 1)

    def use_seed(self, seed: int) -> EditView:
        """The sample of ``seed`` (an earlier one's view comes back at once). Raises
        ``ValueError`` for a seed that is not a non-negative integer."""
        return self._commit(dataclasses.replace(self._state, seed=_seed(seed)))

    def set_foot_lock(self, on: bool) -> EditView:
        """Hold each foot still on the ground while its predicted contact lasts, or not."""
        return self._commit(dataclasses.replace(self._state, options=dataclasses.replace(self._state.options, foot_lock=_flag(on, "foot_lock"))))

    def set_key_velocities(self, on: bool) -> EditView:
        """The curves leave and reach the keys at the clip's own velocities (from the frames
        around each key), or as the model chooses. Raises ``ValueError`` where a key's clip
        frame has no neighbour to measure it from (the first key's frame 0, the last key's last frame)."""
        return self._commit(dataclasses.replace(self._state, key_velocities=_flag(on, "key_velocities")))

    def set_ik(self, name: str) -> EditView:
        """In-between with another of :attr:`ik_choices`. Raises ``ValueError`` for an
        unknown name or one that does not fit the clip's skeleton (a learned IK trained on another)."""
        return self._commit(dataclasses.replace(self._state, ik=name))

    # --------------------------------------------------------------------- history

    def undo(self) -> EditView:
        """Back to the state before the last edit (a drag in progress is dropped). Raises
        ``ValueError`` when there is nothing to undo."""
        if not self._undo:
            raise ValueError("nothing to undo")
        self._drag = None
        self._redo.append(self._state)
        self._state = self._undo.pop()
        return self.view

    def redo(self) -> EditView:
        """The edit :meth:`undo` took back. Raises ``ValueError`` when there is none."""
        if not self._redo:
            raise ValueError("nothing to redo")
        self._drag = None
        self._undo.append(self._state)
        self._state = self._redo.pop()
        return self.view

    # --------------------------------------------------------------------- export

    def export(self, name: str = "edit") -> dict[str, Path]:
        """Write the current state's in-between in the output folder as ``bezmotion inbetween``
        does: ``NAME.bvh`` (the clip's units, up axis, OFFSETs and End Sites; at the clip's
        rate where that is a whole multiple of 30 fps), ``NAME.glb`` (skeleton, the six curves,
        the handles) and ``NAME.handles.json`` (the handles, as ``--handles`` reads them, with
        the keys and the seed beside them), replacing an earlier export of that name all
        together. A drag in progress is not exported.

        Returns:
          ``{"bvh", "glb", "handles"}`` → the files written.
        Raises:
          ValueError: a name that is not 1–64 letters, digits, ``_`` or ``-`` (starting with a
            letter or digit), or files of that name in the folder that bezmotion did not write.
        """
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise ValueError(f"an export's name is 1 to 64 letters, digits, _ or - (a letter or digit first), got {one_line(repr(name), 80)}")
        state, shown = self._state, self._show(self._state)
        model = self._model(state.ik)
        character = self.character
        names = {"bvh": f"{name}.bvh", "glb": f"{name}.glb", "handles": f"{name}.handles.json"}
        existing = existing_outputs(self._out, names.values(), name)
        refusal = existing.refusal()
        if refusal is not None:
            raise ValueError(f"{self._out}: exporting {name} {refusal}; export under another name")
        motion = pose_to_bvh(character, shown.result.pose, fps=TRAINED_FPS, template=self._ours)
        records = self._records(state)
        files = ResultFiles(
            character, motion, shown.view.curves, model.bmm.config.stride, tuple(records), None, name, self.key_frames,
            self._clip_frame, bvh_fps=bvh_frame_rate("clip", self._clip_fps),
        )  # fmt: skip
        handles_file = {"handles": records, "keys": list(state.keys), "seed": state.seed, "ik": state.ik,
                        "foot_lock": state.options.foot_lock, "key_velocities": state.key_velocities}  # fmt: skip
        with output_set(self._out, name, remove=existing.stale) as staging:
            write_result(staging / names["bvh"], files)
            write_result(staging / names["glb"], files)
            atomic_write_text(staging / names["handles"], json.dumps(handles_file, indent=2) + "\n")
        return {kind: self._out / file for kind, file in names.items()}

    # --------------------------------------------------------------------- internals

    @property
    def _span(self) -> int:
        return self._model(self._state.ik).span

    def _model(self, ik: str) -> Inbetweener:
        if not isinstance(ik, str) or ik not in self._models:
            raise ValueError(f"unknown IK {one_line(repr(ik), 60)}; this session has {listed(self._models)}")
        try:
            return self._models[ik]
        except ValueError as error:
            raise ValueError(one_line(f"IK {ik}: {error}")) from None

    def _commit(self, state: EditState) -> EditView:
        """Make ``state`` the current one (its view computed first: an error changes nothing)."""
        view = self._show(state).view
        self._drag = None
        if state != self._state:
            self._undo = [*self._undo, self._state][-HISTORY:]
            self._redo.clear()
            self._state = state
        if state.seed not in self._seeds:
            self._seeds.append(state.seed)
        return view

    def _show(self, state: EditState) -> _Shown:
        """The state's in-between and view, kept for :data:`VIEWS_KEPT` states."""
        if state in self._shown:
            self._shown.move_to_end(state)
            return self._shown[state]
        model = self._model(state.ik)
        keys = self._keys(state.keys)[0]
        key_velocity = self._key_velocity(state.keys) if state.key_velocities else None
        records = self._records(state)
        handles = self._padded(records)
        result = inbetween(model, keys, handles, key=sample_key(state.seed), options=state.options, key_velocity=key_velocity)
        shown = _Shown(self._view(state, result, handles), result, keys, key_velocity)
        self._shown[state] = shown
        while len(self._shown) > VIEWS_KEPT:
            self._shown.popitem(last=False)
        return shown

    def _dragged(self, state: EditState, previous: Pose | None) -> tuple[InbetweenResult, Handles]:
        """The current state's sample re-projected onto ``state``'s handles (the same keys and
        options, positions moved), the body warm-started from ``previous`` (default: the
        sample's) where the IK takes a start; and the handles, padded."""
        shown, model = self._show(self._state), self._model(self._state.ik)
        handles = self._padded(self._records(state))
        start = None
        if isinstance(model.ik_fn, ExactIKFn):
            start = shown.result.pose if previous is None else previous
        keyed = shown.key_velocity is not None
        return _dragged(model, shown.keys, handles, shown.result.curves, start, self._state.options, keyed), handles

    def _view(self, state: EditState, result: InbetweenResult, handles: Handles) -> EditView:
        joints, beyond, conflict = jax.device_get(_measured(self.character, result.pose, handles, self._reach_device))
        n = len(state.handles)
        records = [h.record() for h in state.handles]
        idx = self.character.characteristic
        errors = [float(np.linalg.norm(joints[h.frame, idx[CHARACTERISTIC_JOINTS.index(h.joint)]] - np.asarray(h.position))) for h in state.handles]
        conflict = conflict[:n, :n]
        return EditView(
            pose=result.pose,
            joints=joints,
            curves=jax.device_get(join_chain_curves(result.curves)),
            positions=np.asarray(result.positions),
            handle_errors={h.id: e for h, e in zip(state.handles, errors)},
            misses=tuple(handle_misses(records, errors, beyond[:n], conflict.any(axis=-1))),
            warnings=tuple(handle_conflicts(records, conflict, self._reach)),
        )

    def _keys(self, keys: tuple[int, ...]) -> tuple[Pose, np.ndarray, np.ndarray]:
        """``(key poses (K, …), their six joints' positions (K, 6, 3), the ghost)`` of clip frames ``keys``."""
        if keys not in self._key_cache:
            model = self._model(self._state.ik)
            poses = model.poses(self._clip, list(keys))
            span = model.span
            local = np.arange(span) / span
            frames = [round(a + (b - a) * t) for a, b in zip(keys, keys[1:]) for t in local] + [keys[-1]]
            ghost, _ = _joint_positions(self.character, model.poses(self._clip, frames))
            _, six = _joint_positions(self.character, poses)
            self._key_cache[keys] = (poses, np.asarray(six, np.float64), np.asarray(ghost))
        return self._key_cache[keys]

    def _checked_keys(self, frames: Sequence[int]) -> tuple[int, ...]:
        if isinstance(frames, str) or not isinstance(frames, Sequence):
            raise ValueError(f"keys are a list of clip frames, got {one_line(repr(frames), 80)}")
        if len(frames) < 2:
            raise ValueError(f"an in-between needs at least two keys, got {list(frames)}")
        count = self._clip.num_frames
        for f in frames:
            if isinstance(f, bool) or not isinstance(f, int | np.integer) or not 0 <= f < count:
                raise ValueError(f"key {one_line(repr(f), 40)}: keys are frames 0 … {count - 1} of the clip (at {TRAINED_FPS:g} fps)")
        return tuple(int(f) for f in frames)

    def _key_velocity(self, keys: tuple[int, ...]) -> Array:
        """``(K, 6, 3)`` cm/frame: each key's velocity in the clip (:func:`clip_key_velocities`)."""
        try:
            return clip_key_velocities(self.character, [(self._clip, f) for f in keys])
        except ValueError as error:
            raise ValueError(f"key velocities: {error}") from None

    def _handle(self, state: EditState, handle_id: int) -> EditHandle:
        for handle in state.handles:
            if handle.id == handle_id:
                return handle
        raise ValueError(f"no handle {one_line(repr(handle_id), 40)}; the handles are {listed([h.id for h in state.handles]) or 'none'}")

    def _moved(self, state: EditState, handle_id: int, position: Position) -> EditState:
        handle = self._handle(state, handle_id)
        moved = dataclasses.replace(handle, position=_position(position, f"handle {handle_id}"))
        return dataclasses.replace(state, handles=tuple(moved if h.id == handle_id else h for h in state.handles))

    def _records(self, state: EditState) -> list[dict[str, Any]]:
        """The state's handles as records, checked as ``bezmotion inbetween`` checks its own
        (:func:`~bezmotion.cli.handles.resolve_handles`, every message naming the handle) the
        first time their joints and frames meet these keys; later, where only positions moved,
        by the one check a position can fail (its distance from the line between the keys),
        falling back on the full check to say why."""
        records = [h.record() for h in state.handles]
        layout = (state.keys, state.ik, tuple((h.joint, h.frame) for h in state.handles))
        if layout in self._layouts and all(self._near_line(state.keys, h) for h in state.handles):
            return records
        model = self._model(state.ik)
        requests = [HandleRequest(h.joint, h.frame, h.position, False, f"handle {h.id}") for h in state.handles]
        resolve_handles(requests, self._recognised, _unbatched(self._keys(state.keys)[0]), model.bmm)
        self._layouts.add(layout)
        return records

    def _near_line(self, keys: tuple[int, ...], handle: EditHandle) -> bool:
        line = line_between_keys(self._keys(keys)[1], CHARACTERISTIC_JOINTS.index(handle.joint), handle.frame, self.key_frames)
        return float(np.linalg.norm(np.asarray(handle.position) - line)) <= HANDLE_FARTHEST_CM

    def _padded(self, records: Sequence[dict[str, Any]]) -> Handles:
        """The records as handles padded to a multiple of :data:`HANDLE_SLOTS` slots."""
        return records_as_handles(records, slots=HANDLE_SLOTS * max(1, -(-len(records) // HANDLE_SLOTS)))


class _ModelsByIK(Mapping[str, Inbetweener]):
    """IK name → :meth:`Inbetweener.from_bvh` of one clip with that IK, loaded when first asked for."""

    def __init__(self, clip: BvhMotion, names: Sequence[str], **options: Any) -> None:
        self._clip, self._names, self._options = clip, tuple(names), options
        self._loaded: dict[str, Inbetweener] = {}

    def __getitem__(self, name: str) -> Inbetweener:
        if name not in self._names:
            raise KeyError(name)
        if name not in self._loaded:
            self._loaded[name] = Inbetweener.from_bvh(self._clip, ik=name, **self._options)
        return self._loaded[name]

    def __contains__(self, name: object) -> bool:
        return name in self._names  # without loading it

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


# ------------------------------------------------------------------------------- checks


def _unbatched(poses: Pose) -> list[Pose]:
    return [jax.tree.map(lambda a: a[k], poses) for k in range(poses.root_pos.shape[0])]


def _frame(frame: Any, source: str) -> int:
    if isinstance(frame, bool) or not isinstance(frame, int | np.integer):
        raise ValueError(f"{source}: a handle's frame is an integer frame of the in-between, got {one_line(repr(frame), 40)}")
    return int(frame)


def _position(position: Position, source: str) -> tuple[float, float, float]:
    try:
        value = np.asarray(position, np.float64)
    except (TypeError, ValueError):
        value = np.zeros(0)
    if value.shape != (3,) or not np.isfinite(value).all():
        raise ValueError(f"{source}: a position is 3 finite numbers (cm), got {one_line(repr(position), 80)}")
    return (float(value[0]), float(value[1]), float(value[2]))


def _seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"a seed is an integer ≥ 0, got {one_line(repr(seed), 40)}")
    return int(seed)


def _flag(on: Any, name: str) -> bool:
    if not isinstance(on, bool | np.bool_):
        raise ValueError(f"{name} is True or False, got {one_line(repr(on), 40)}")
    return bool(on)


def _options(options: Any) -> InbetweenOptions:
    if not isinstance(options, InbetweenOptions):
        raise ValueError(f"options are an InbetweenOptions, got {type(options).__name__}")
    return options


__all__ = ["HISTORY", "VIEWS_KEPT", "EditHandle", "EditSession", "EditState", "EditView"]
