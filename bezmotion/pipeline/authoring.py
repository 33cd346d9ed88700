"""From files to an in-between and back: models by name or folder, the character from a
BVH file's joint names (or a mapping file), poses at given frames, the IK, the transfer
from the BMM's training skeleton, and results written by file suffix.

``bezmotion demo`` and ``bezmotion inbetween`` are built from these pieces:

- :func:`resolve_bmm`, :func:`resolve_ik_model`: ``--model NAME|PATH``, a name from the one
  registry of pretrained models (:mod:`bezmotion.assets.registry`) or a folder;
- :func:`recognise_character`: a BVH skeleton is LaFAN1 or Bandai-Namco when it has that
  preset's whole hierarchy; any other skeleton has its six joints read off
  its names (``mixamorig:LeftHand``, ``hand_l``, ``L_Wrist``:
  :mod:`bezmotion.data.joint_roles`) or given by a mapping file (:func:`read_mapping`: the
  six joints, and optionally the rig's chains — without them the chains are read off the
  hierarchy, :func:`derive_rig_spec`);
- :func:`motion_poses`: frames of a BVH motion as :class:`~bezmotion.ik.protocol.Pose`;
- :func:`target_profile`, :func:`make_transfer`: driving the clip's skeleton with a BMM
  trained on another (BMM §5.2);
- :func:`make_ik`: ``--ik learned|refined|rig`` as ``(ik_fn, ik_params)``;
- :func:`check_output`, :func:`write_result`: one writer per suffix (``.bvh``, ``.glb``,
  ``.gif``), so that a command checks every output path before it writes any.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion._src.structured_files import read_structured_file
from bezmotion._src.messages import listed, one_line
from bezmotion.assets import PROFILES_DIR
from bezmotion.assets.registry import resolve_folder
from bezmotion.bezier import BezierLayout
from bezmotion.bmm.sampling import SampledCurves
from bezmotion.data.bvh import BvhMotion, read_bvh, write_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, PRESET_HIERARCHIES, preset_of
from bezmotion.data.joint_roles import elided, guess_characteristic_joints
from bezmotion.data.clip_frame import ClipFrame
from bezmotion.data.resample import resample_motion
from bezmotion.geometry.skeleton import ancestors, forward_kinematics
from bezmotion.ik.protocol import Character, IKFn, Pose, pose_fk, pose_from_motion, targets_from_pose
from bezmotion.ik.exact import exact_ik
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protores import ProtoResModel, protores_ik_fn, protores_refined_ik_fn
from bezmotion.ik.rig import RigSpec, derive_rig_spec, make_rig, rig_ik
from bezmotion.pipeline.transfer import CharacterProfile, Transfer

IK_CHOICES = ("refined", "learned", "rig", "exact", "exact_rig")
"""``refined``: the learned IK, then exact two-bone arms and legs; ``learned``: the learned
IK alone; ``rig``: the analytic rig (no data, any skeleton); ``exact``: the learned IK, then
a least-squares solve of the whole body onto all six targets (:mod:`bezmotion.ik.exact`);
``exact_rig``: the same solve from the rig's poses (any skeleton, no training)."""

LEARNED_IK_CHOICES = ("refined", "learned", "exact")
"""The IK choices that start from a learned IK (the others need no trained model)."""

EXACT_IK_CHOICES = ("exact", "exact_rig")
"""The IK choices that end in the exact solve (and take ``--exact`` settings)."""

CHANNEL_CHOICES = ("default", "clip")
"""BVH channels: positions on the root and the hips only, or the clip's own layout."""

EXACT_HELP = (
    "an exact IK setting NAME=VALUE (ExactIKParams), repeatable: e.g. plant_weight=10 holds planted feet "
    "harder (default 4), iterations=4 or window_passes=1 trades precision for speed, key_hold_decay=0.6 keeps the body "
    "nearer its curves between the keys (for a faster catch-up after them), robust_cm=0 solves every target by "
    "least squares (default 5: a curve point more than 5 cm out of reach stops dragging the body)"
)
"""The commands' ``--exact`` help (``bezmotion demo``, ``bezmotion inbetween``; parsed by
:func:`~bezmotion.ik.exact.exact_settings`, as in ``experiments/pipeline_eval.py``)."""

FOOT_LOCK_HELP = (
    "hold each foot still while the BMM predicts it planted (default; ours, not the paper's: "
    "--no-foot-lock for the paper's curves)"
)
"""The commands' ``--foot-lock`` help. On by default there: the paper's curves skate (0.138
of Bandai-Namco validation frames, the mocap 0.110), locked ones 0.070, and every IK skates
less on them (``experiments/pipeline_eval.py --foot-lock``)."""


# ------------------------------------------------------------------------------ models


VERIFY_HELP = "check the models' files against their checksums (default); --no-verify loads a model saved without them (with a warning)"
"""The commands' help for their ``--verify`` / ``--no-verify`` switch."""


def resolve_bmm(name_or_path: str | os.PathLike, *, verify: bool = True) -> tuple[Path, str | None]:
    """``(folder, skeleton it was trained on or None)`` of a registered model's name
    (:data:`bezmotion.assets.registry.REGISTRY`; a bundled one's checksum is checked unless
    not ``verify``) or a saved BMM's folder. Load it with
    :func:`~bezmotion.bmm.sampling.load_model` and the same ``verify``.

    Raises:
      ChecksumError: a bundled model's files differ from the manifest.
      FileNotFoundError: a registered model that is not bundled was not trained (naming the command).
    """
    folder, entry = resolve_folder(name_or_path, "bmm", verify=verify)
    return folder, entry.skeleton if entry is not None else None


def ik_model_joint_limits(directory: str | os.PathLike, character: Character) -> JointLimits | None:
    """The joint limits stored beside a saved learned IK (``joint_limits.json``,
    ``experiments/joint_limits.py``), or None when it has none."""
    path = Path(directory) / "joint_limits.json"
    return JointLimits.load(path, character) if path.is_file() else None


def resolve_ik_model(name_or_path: str | os.PathLike, *, verify: bool = True) -> Path:
    """The folder of a registered learned IK's name (checked like :func:`resolve_bmm`) or of a
    saved one; load it with :func:`~bezmotion.ik.protores.load_ik_model` and the same ``verify``."""
    return resolve_folder(name_or_path, "ik", verify=verify)[0]


def profile_names() -> list[str]:
    """The bundled character profiles' names (skeletons a BMM can be transferred between)."""
    return sorted(p.stem for p in PROFILES_DIR.glob("*.json"))


def load_profile(name_or_path: str | os.PathLike) -> CharacterProfile:
    """A bundled character profile by name (:func:`profile_names`) or a profile JSON file.

    Raises:
      ValueError: neither a bundled name nor a readable profile file.
    """
    if str(name_or_path) in profile_names():
        return CharacterProfile.load(PROFILES_DIR / f"{name_or_path}.json")
    path = Path(name_or_path)
    if not path.is_file():
        raise ValueError(f"not a bundled profile ({', '.join(profile_names())}) nor a profile file")
    return CharacterProfile.load(path)


# --------------------------------------------------------------------------- character


@dataclasses.dataclass(frozen=True)
class RecognisedCharacter:
    """A clip's character and how it was recognised.

    Attributes:
      character: the clip's skeleton (its own offsets and End Sites) and six joints.
      preset: ``"lafan1"`` or ``"bandai_namco"`` when the hierarchy is a preset's, else None.
      rig_spec: the chains of the analytic rig.
      read_off_names: role → joint name when the six joints were read off the joint names
        (:func:`~bezmotion.data.joint_roles.guess_characteristic_joints`: no preset, no
        mapping file), for the user to check; else None.
    """

    character: Character
    preset: str | None
    rig_spec: RigSpec
    read_off_names: Mapping[str, str] | None = None


def read_mapping(path: str | os.PathLike) -> tuple[dict[str, str], RigSpec | None]:
    """A skeleton's characteristic joints (and optionally rig chains) from a JSON or TOML file.

    Either the six roles alone, ``{"hips": "pelvis", "head": "head", "left_hand": "l_wrist",
    …}``, or ``{"characteristic": {…the six roles…}, "rig": {"spine": [hips, …, head],
    "left_arm": [upper, fore, hand], "right_arm": […], "left_leg": [upper, lower, ankle],
    "right_leg": […]}}``.

    Raises:
      FileNotFoundError: no such file.
      ValueError: unreadable, or not of either shape.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError("no such file")
    data = read_structured_file(path)
    if not isinstance(data, dict):
        raise ValueError(f"expected a table of joint names, got {type(data).__name__}")
    if "characteristic" in data:
        unknown = sorted(set(data) - {"characteristic", "rig"})
        if unknown:
            raise ValueError(f"unknown keys {listed(map(repr, unknown))}; a mapping has 'characteristic' and optionally 'rig'")
        roles, rig = data["characteristic"], data.get("rig")
    else:
        roles, rig = data, None
    if not isinstance(roles, dict) or not all(isinstance(v, str) for v in roles.values()):
        raise ValueError(f"the characteristic joints must map each of {list(CHARACTERISTIC_JOINTS)} to a joint name, got {one_line(repr(roles), 120)}")
    if rig is not None and not isinstance(rig, dict):
        raise ValueError(f"'rig' must be a table of chains, got {one_line(repr(rig), 120)}")
    return dict(roles), (RigSpec.from_dict(rig) if rig is not None else None)


def recognise_character(motion: BvhMotion, mapping: str | os.PathLike | None = None) -> RecognisedCharacter:
    """The character of a BVH motion: a preset recognised by its whole hierarchy, or the mapping file's.

    Args:
      motion: the clip (its offsets and End Sites are kept).
      mapping: a mapping file (:func:`read_mapping`), for skeletons that are no preset;
        without one, the six joints of such a skeleton are read off its joint names
        (:func:`~bezmotion.data.joint_roles.guess_characteristic_joints`).
    Raises:
      ValueError: no preset matches, no mapping is given and the names do not tell the six
        joints (the message lists the joints, says why and how to write a mapping), or the
        mapping or its rig does not fit the skeleton.
      FileNotFoundError: the mapping file does not exist.
    """
    names = motion.skeleton.names
    if mapping is not None:
        roles, spec = read_mapping(mapping)
        character = Character.from_bvh(motion, roles, name=Path(mapping).stem)
        spec = spec if spec is not None else derive_rig_spec(character)
        make_rig(character, spec)  # check the chains against the skeleton now, with their names
        return RecognisedCharacter(character, None, spec)
    preset = preset_of(names, motion.skeleton.parents)
    if preset is not None:
        return RecognisedCharacter(Character.from_bvh(motion, preset), preset, RigSpec.preset(preset))
    try:
        roles = guess_characteristic_joints(names, motion.skeleton.parents)
        character = Character.from_bvh(motion, roles)
        spec = derive_rig_spec(character)
        make_rig(character, spec)
    except ValueError as why:
        raise ValueError(
            f"unknown skeleton of {len(names)} joints ({elided(names, 4)}): not {' or '.join(PRESET_HIERARCHIES)}, and its "
            f"names do not tell its six joints ({why}); name them in a mapping file"
        ) from None
    return RecognisedCharacter(character, None, spec, read_off_names=roles)



def same_skeleton(a: BvhMotion, b: BvhMotion) -> bool:
    """Whether two motions have the same joints in the same hierarchy (offsets may differ)."""
    return a.skeleton.names == b.skeleton.names and a.skeleton.parents == b.skeleton.parents


def motion_poses(motion: BvhMotion, character: Character, frames: slice | Sequence[int] | int) -> Pose:
    """Frames of ``motion`` as :class:`~bezmotion.ik.protocol.Pose` (float32), e.g. ``slice(0, 31)`` or ``12``."""
    index = frames if isinstance(frames, slice | int) else np.asarray(frames)
    return pose_from_motion(
        character, jnp.asarray(motion.quat_local[index], jnp.float32), jnp.asarray(motion.pos_local[index], jnp.float32)
    )


def clip_key_velocities(character: Character, keys: Sequence[tuple[BvhMotion, int]], names: Sequence[str] | None = None) -> jax.Array:
    """``(keys, 6, 3)`` cm/frame: the six joints' velocities at each key ``(motion, frame)``
    from its clip's frames around it: outwards at the first and last key (the frame before
    the first, the one after the last: the motion kept around the in-between), the central
    difference at a chain's inner keys (the velocity both its windows take).

    Raises:
      ValueError: a key whose clip lacks a frame it needs, naming it (``names[i]``, default
        its frame).
    """
    names = [f"at frame {frame}" for _, frame in keys] if names is None else names
    velocities = []
    last = len(keys) - 1
    for i, ((motion, frame), name) in enumerate(zip(keys, names, strict=True)):
        before, after = (frame - 1 if i < last else frame), (frame + 1 if i > 0 else frame)
        role = "start key" if i == 0 else "end key" if i == last else "key"
        needs = {"start key": "the frame before it", "end key": "the frame after it", "key": "the frames on both sides"}[role]
        if before < 0:
            raise ValueError(f"the {role} {name} is the first frame of its file; its velocity needs {needs}")
        if after >= motion.num_frames:
            raise ValueError(f"the {role} {name} is the last frame ({frame}) of its file; its velocity needs {needs}")
        six = targets_from_pose(character, motion_poses(motion, character, [before, after])).position  # (2, 6, 3)
        velocities.append((six[1] - six[0]) / (after - before))
    return jnp.stack(velocities)


def motion_window(motion: BvhMotion, first: int, count: int) -> BvhMotion:
    """Frames ``first … first + count − 1`` of ``motion``, as a motion of their own."""
    frames = slice(first, first + count)
    return dataclasses.replace(motion, quat_local=motion.quat_local[frames], pos_local=motion.pos_local[frames])


def target_profile(recognised: RecognisedCharacter, motions: Sequence[BvhMotion]) -> CharacterProfile:
    """The clip character's profile: the bundled one of its preset, else measured on every
    frame of ``motions`` (:meth:`CharacterProfile.from_poses`)."""
    if recognised.preset in profile_names():
        return load_profile(recognised.preset)
    character = recognised.character
    poses = [motion_poses(m, character, slice(None)) for m in motions]
    return CharacterProfile.from_poses(character, jax.tree.map(lambda *x: jnp.concatenate(x), *poses))


FACING_CHOICES = ("trained", "keys")
"""``trained`` (default): each in-between turned to start facing the way the BMM's training
motions do, and back (:attr:`~bezmotion.pipeline.transfer.Transfer.facing`); ``keys``: the
keys as they face (the paper's)."""


def make_transfer(
    trained_on: CharacterProfile | None,
    target: CharacterProfile | None,
    *,
    orientation: str = "anatomical",
    facing: str = "trained",
) -> Transfer | None:
    """The transfer from the BMM's training skeleton to the clip's (:meth:`Transfer.between`);
    for the same skeleton (``target`` None), the facing alone (:meth:`Transfer.identity`).
    None where nothing is to be moved: no known training skeleton, or the same skeleton with
    ``facing="keys"``.

    Raises:
      ValueError: an unknown ``facing`` or ``orientation``.
    """
    if facing not in FACING_CHOICES:
        raise ValueError(f"facing must be one of {', '.join(FACING_CHOICES)}, got {facing!r}")
    turn = facing == "trained"
    if trained_on is None:
        return None
    if target is None:
        return Transfer.identity(trained_on.facing) if turn and trained_on.facing is not None else None
    return Transfer.between(trained_on, target, orientation=orientation, facing=turn)


# ---------------------------------------------------------------------------------- IK


# A bone more than this far (degrees) from the learned IK's at rest: the file lays out its
# rest pose or its bones' axes otherwise, and the rotations the IK predicts would not fit it.
_REST_BONE_DEGREES = 20.0


def check_ik_model(model: ProtoResModel, character: Character) -> None:
    """Refuse a learned IK trained on another skeleton than ``character``'s: other joints,
    another hierarchy, or bones that point elsewhere at rest (another rest pose or other
    bone axes: the local rotations it predicts are in its own skeleton's frames).

    Raises:
      ValueError: the joints, the hierarchy or the rest pose differ (the message names the
        IK's skeleton, or the bones that differ most).
    """
    theirs = model.character.skeleton
    ours = character.skeleton
    if theirs.names != ours.names or theirs.parents != ours.parents:
        raise ValueError(
            f"it was trained on the {model.character.name} skeleton ({theirs.num_joints} joints, "
            f"{elided(theirs.names, 4)}), not this one ({character.num_joints} joints, "
            f"{elided(ours.names, 4)}); the rig and exact_rig IKs need no training"
        )
    # The bones below the hips: the hips' own offset is where a take put them (Bandai-Namco
    # animates their translation under a root at the origin), not a bone.
    bones = np.asarray(sorted(set(range(ours.num_joints)) - set(ancestors(ours.parents, character.characteristic[0]))))
    a, b = np.asarray(theirs.offsets, np.float64)[bones], np.asarray(ours.offsets, np.float64)[bones]
    length = np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1)
    cos = np.sum(a * b, axis=-1) / np.where(length > 1e-12, length, 1.0)
    degrees = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    names = [theirs.names[j] for j in bones]
    off = [(d, n) for d, n, ok in zip(degrees, names, length > 1e-12) if ok and d > _REST_BONE_DEGREES]
    if off:
        worst = [f"{n} {d:.0f}°" for d, n in sorted(off, reverse=True)]
        raise ValueError(
            f"its rest pose differs from the {model.character.name} skeleton's the learned IK was trained on "
            f"(bones turned by {elided(worst, 4)}: another rest pose or other bone axes); the rig and exact_rig IKs fit any"
        )


def make_ik(
    kind: str,
    recognised: RecognisedCharacter,
    *,
    rest_quat_local: np.ndarray | jax.Array,
    ik_model: ProtoResModel | None = None,
    limits: JointLimits | None = None,
    exact_settings: Mapping[str, float | int] | None = None,
) -> tuple[IKFn, Any]:
    """``(ik_fn, ik_params)`` of an IK choice (:data:`IK_CHOICES`) for the clip's character.

    Args:
      kind: one of :data:`IK_CHOICES`.
      recognised: the character and its rig chains.
      rest_quat_local: ``(joints, 4)`` the rotations the rig keeps on joints it does not
        solve (clavicles, toes): typically the start pose's.
      ik_model: the learned IK (for ``"learned"``, ``"refined"`` and ``"exact"``), checked
        against the character (:func:`check_ik_model`).
      limits: joint limits for ``"exact"`` and ``"exact_rig"`` (:func:`ik_model_joint_limits`); default none.
      exact_settings: :class:`~bezmotion.ik.exact.ExactIKParams` keywords for the exact IKs
        (:data:`EXACT_IK_CHOICES`; :func:`~bezmotion.ik.exact.exact_settings` parses them
        from ``NAME=VALUE``); none for the other IKs.
    Raises:
      ValueError: an unknown ``kind``, settings for an IK other than the exact ones, or a
        learned IK that does not fit the character.
    """
    if kind not in IK_CHOICES:
        raise ValueError(f"must be one of {IK_CHOICES}, got {kind!r}")
    if exact_settings and kind not in EXACT_IK_CHOICES:
        shown = " ".join(f"{k}={v}" for k, v in exact_settings.items())
        raise ValueError(f"exact settings {shown}: the settings of the exact IKs ({', '.join(EXACT_IK_CHOICES)}), not of the {kind} IK")
    character = recognised.character
    settings = dict(exact_settings or {})
    if kind in LEARNED_IK_CHOICES:
        if ik_model is None:
            raise ValueError(f"the {kind} IK needs a learned IK model")
        check_ik_model(ik_model, character)
        if kind == "learned":
            return protores_ik_fn, ik_model
        if kind == "exact":
            return exact_ik(protores_ik_fn, ik_model, character, limits=limits, **settings)
    rig = make_rig(character, recognised.rig_spec, rest_quat_local=np.asarray(rest_quat_local))
    if kind == "rig":
        return rig_ik, rig
    if kind == "exact_rig":
        return exact_ik(rig_ik, rig, character, limits=limits, **settings)
    return protores_refined_ik_fn, (ik_model, rig)


# ------------------------------------------------------------------------------ output


def bvh_fk_error_cm(path: str | os.PathLike, character: Character, pose: Pose, clip_frame: ClipFrame = ClipFrame(), *, every: int = 1) -> float:
    """Largest joint-position difference (cm) between a written BVH, read back (in
    ``clip_frame``'s units and up axis), and ``pose``: ``pose``'s frame ``f`` against the
    file's ``every · f`` (a file written at ``every`` times the pose's rate, ``ResultFiles.bvh_fps``)."""
    reread = clip_frame.to_ours(read_bvh(path))
    reread = dataclasses.replace(reread, quat_local=reread.quat_local[::every], pos_local=reread.pos_local[::every])
    with jax.enable_x64(True):
        _, from_file = forward_kinematics(reread.skeleton.parents, jnp.asarray(reread.quat_local), jnp.asarray(reread.pos_local))
        from_file = np.asarray(from_file)
    return float(np.abs(from_file - np.asarray(pose_fk(character, pose)[1], np.float64)).max())


@dataclasses.dataclass(frozen=True)
class ResultFiles:
    """What a writer takes: one in-between as a BVH motion, its curves and its handles.

    Attributes:
      character: the character the motion is of.
      motion: the in-between (``pose_to_bvh(character, pose, …, template=clip)``).
      curves: the BMM curves (``InbetweenResult.curves``), or None.
      stride: frames between control points (``bmm.config.stride``).
      handles: ``[{"joint", "frame", "position"}]`` (cm, world frame).
      reference: the mocap between the keys, drawn beside the preview; or None.
      title: the preview's title line.
      key_frames: the frames that are key poses (None: the first and last; a chain's inner
        keys too), for the glTF file.
      clip_frame: the units and up axis the BVH file is written in (everything here is in
        cm with Y up; the glTF file in metres with Y up, as glTF wants).
      bvh_fps: the BVH file's frame rate: None, the motion's own; else a whole multiple of it,
        the motion resampled (:func:`~bezmotion.data.resample.resample_motion`: its every
        frame kept, those between slerped). The glTF file and the preview keep the motion's
        frames (glTF times them in seconds).
      layout: where the curves' control points sit (None: ``BezierLayout(frames, stride)``;
        keys at unequal distances: ``TimedInbetween.layout``).
    """

    character: Character
    motion: BvhMotion
    curves: SampledCurves | None
    stride: int
    handles: tuple[Mapping[str, Any], ...] = ()
    reference: BvhMotion | None = None
    title: str | None = None
    key_frames: tuple[int, ...] | None = None
    clip_frame: ClipFrame = ClipFrame()
    bvh_fps: float | None = None
    layout: BezierLayout | None = None

    def curve_arrays(self) -> dict[str, Any]:
        if self.curves is None:
            return {"stride": self.stride}
        arrays = {"ctrl_pos": np.asarray(self.curves.ctrl_pos), "ctrl_tangent": np.asarray(self.curves.ctrl_tangent), "stride": self.stride}
        return arrays if self.layout is None else {**arrays, "layout": self.layout}


def _write_bvh(path: Path, result: ResultFiles) -> None:
    # Six decimals of a cm, as many of a larger unit (8 of a metre): the file as precise in any unit.
    decimals = 6 + max(0, int(np.ceil(np.log10(result.clip_frame.cm_per_unit))))
    motion = result.motion
    if result.bvh_fps is not None:
        motion, _ = resample_motion(motion, result.bvh_fps)
    write_bvh(path, result.clip_frame.from_ours(motion), precision=decimals)


def _write_glb(path: Path, result: ResultFiles) -> None:
    from bezmotion.pipeline.gltf import write_glb

    write_glb(path, result.motion, **result.curve_arrays(), handles=list(result.handles), key_frames=result.key_frames)


def _write_gif(path: Path, result: ResultFiles) -> None:
    from bezmotion.pipeline.preview import write_preview  # Matplotlib: imported only when drawn

    write_preview(
        path, result.character, result.motion, **result.curve_arrays(), reference=result.reference,
        handles=list(result.handles), title=result.title,
    )  # fmt: skip


WRITERS: Mapping[str, Callable[[Path, ResultFiles], None]] = {".bvh": _write_bvh, ".glb": _write_glb, ".gif": _write_gif}
"""One writer per output suffix: BVH, glTF 2.0 binary (skeleton and curves), animated GIF preview."""


def check_output(path: str | os.PathLike) -> str:
    """The writer's suffix for ``path``, checked before anything is written.

    Raises:
      ValueError: an unknown suffix, or a path that is an existing folder.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITERS:
        raise ValueError(f"unknown output format {path.suffix!r}; bezmotion writes {', '.join(WRITERS)}")
    if path.is_dir():
        raise ValueError("is a folder")
    return suffix


# A suffix of letters and digits, two letters at least (.fbx, .json, .mp4), names a file
# format; any other (.v2, .001) is part of a folder's name.
_FORMAT_SUFFIX = re.compile(r"\.(?=(?:[0-9]*[A-Za-z]){2})[A-Za-z0-9]+")
_SEPARATORS = tuple(sep for sep in (os.sep, os.altsep) if sep)


def output_format(out: str | os.PathLike) -> str | None:
    """Whether ``out`` (as written, a trailing separator kept) names a file or a folder: the
    writer's suffix (:data:`WRITERS`) for a file, None for a folder.

    A name that ends in a path separator is a folder. Otherwise a name that ends in one of
    :data:`WRITERS`' suffixes (any case) is that file; an existing folder is a folder; a name
    whose suffix looks like a file format, letters and digits with two letters at least
    (``take.fbx``, ``take.json``, ``take.mp4``), is refused; any other name is a folder
    (``take``, ``take.v2``, ``run.001``).

    Raises:
      ValueError: a file format bezmotion does not write, or one it writes naming an
        existing folder (the message says that a trailing separator makes a folder).
    """
    text = os.fspath(out)
    if text.endswith(_SEPARATORS):
        return None
    path = Path(text)
    if path.suffix.lower() in WRITERS:
        if path.is_dir():
            raise ValueError(f"is a folder; {text}{os.sep} writes into it")
        return path.suffix.lower()
    if path.is_dir() or not _FORMAT_SUFFIX.fullmatch(path.suffix):
        return None
    raise ValueError(
        f"unknown output format {path.suffix!r}; bezmotion writes {', '.join(WRITERS)} files, and into a folder named with "
        f"a trailing {os.sep} ({text}{os.sep})"
    )


def write_result(path: str | os.PathLike, result: ResultFiles) -> None:
    """Write ``result`` in the format of ``path``'s suffix (:data:`WRITERS`), atomically."""
    path = Path(path)
    WRITERS[check_output(path)](path, result)


__all__ = [
    "CHANNEL_CHOICES",
    "EXACT_HELP",
    "FOOT_LOCK_HELP",
    "EXACT_IK_CHOICES",
    "IK_CHOICES",
    "LEARNED_IK_CHOICES",
    "WRITERS",
    "RecognisedCharacter",
    "ResultFiles",
    "bvh_fk_error_cm",
    "check_ik_model",
    "check_output",
    "derive_rig_spec",
    "load_profile",
    "ik_model_joint_limits",
    "make_ik",
    "FACING_CHOICES",
    "make_transfer",
    "clip_key_velocities",
    "motion_poses",
    "motion_window",
    "output_format",
    "profile_names",
    "read_mapping",
    "recognise_character",
    "resolve_bmm",
    "resolve_ik_model",
    "same_skeleton",
    "target_profile",
    "write_result",
]
