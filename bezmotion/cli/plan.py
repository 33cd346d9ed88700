"""``bezmotion inbetween``'s options and plan: every argument checked, the inputs read and the models loaded, nothing written."""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bezmotion.assets.registry import trained_for
from bezmotion.bmm.sampling import MAX_WINDOW_FRAMES, BezierMotionModel, Handles, load_model, window_frames
from bezmotion.data.bvh import BvhMotion, read_bvh
from bezmotion.data.clip_frame import CM_PER_UNIT, TYPICAL_PERSON_CM, UP_AXES, ClipFrame, cm_per_unit, detect_units, detect_up, skeleton_size
from bezmotion.data.resample import TRAINED_FPS, resample_motion
from bezmotion.ik.exact import exact_settings
from bezmotion.ik.protocol import Character, Pose
from bezmotion.ik.protores import load_ik_model
from bezmotion.ik.rig import make_rig
from bezmotion._src.io import check_writable_folder
from bezmotion.cli.errors import argument_error
from bezmotion._src.output_sets import ExistingOutputs, existing_outputs
from bezmotion._src.options import option, options
from bezmotion.evaluation.window_figures import (
    ReachChains,
    reach_chains,
)
from bezmotion.pipeline.authoring import (
    clip_key_velocities,
    CHANNEL_CHOICES,
    EXACT_HELP,
    VERIFY_HELP,
    EXACT_IK_CHOICES,
    FOOT_LOCK_HELP,
    IK_CHOICES,
    LEARNED_IK_CHOICES,
    RecognisedCharacter,
    check_ik_model,
    ik_model_joint_limits,
    load_profile,
    make_ik,
    FACING_CHOICES,
    make_transfer,
    motion_poses,
    motion_window,
    output_format,
    recognise_character,
    resolve_bmm,
    resolve_ik_model,
    same_skeleton,
    target_profile,
)
from bezmotion.pipeline.transfer import ORIENTATION_CHOICES, Transfer

from bezmotion.cli.handles import parse_handle, read_handles_file, resolve_handles, handle_role


@options
class InbetweenCommand:
    """In-between two poses of your own BVH files through handles; write BVH, glTF and a preview."""

    clip: Path | None = option(None, positional=True, metavar="CLIP.bvh", help="one BVH file holding both key poses (with --frames)")
    frames: tuple[int, ...] | None = option(
        None, metavar="FRAME",
        help="the key frames in CLIP, increasing, any distance apart (2 … 900 frames at 30 fps): START END, or more for a "
        "chain through every one (C¹ at the shared keys), e.g. 0 20 65 90",
    )  # fmt: skip
    start: str | None = option(None, metavar="FILE.bvh@FRAME", help="the start pose (default frame 0)")
    end: str | None = option(None, metavar="FILE.bvh@FRAME", help="the end pose (default the last frame), put --gap frames after the start")
    key: tuple[str, ...] = option(
        (), repeat=True, metavar="FILE.bvh@FRAME",
        help="a key pose, repeatable (two or more, instead of --start/--end): a chain through them in order, each put --gap frames "
        "after the one before (without @FRAME: the first frame, the last key's last frame)",
    )  # fmt: skip
    gap: tuple[int, ...] | None = option(
        None, metavar="N",
        help="with --start/--end or --key: frames from one key to the next at 30 fps, 2 … 900 (default 30, the BMM's window); "
        "one per pair of --key poses for a chain of unequal windows (--gap 20 45 25); with CLIP --frames the clip's own spacing is kept",
    )  # fmt: skip
    handle: tuple[str, ...] = option(
        (), repeat=True, metavar="JOINT@FRAME=X,Y,Z",
        help="a handle, repeatable: the joint's position (cm) at a frame 0…GAP of the in-between (0…GAP·K through K + 1 keys; GAP 30 by default); "
        "a leading + (JOINT@FRAME=+X,Y,Z) offsets it from the straight line between the keys around it",
    )  # fmt: skip
    handles: Path | None = option(None, metavar="FILE", help='a JSON or TOML handles file: [{"joint", "frame", "position" or "offset"}]')
    samples: int = option(1, metavar="N", help="how many in-betweens, each with its own seed (default 1)")
    seed: int = option(0, metavar="SEED", help="PRNG seed of the first sample (sample k uses fold_in(key(seed), k))")
    steps: int = option(10, metavar="N", help="DDIM steps (default 10)")
    ik: str = option(
        "auto", choices=("auto", *IK_CHOICES),
        help="auto (default): exact when the learned IK fits the skeleton, else exact_rig; refined: learned IK then "
        "exact two-bone limbs; learned: the learned IK alone; rig: analytic, any skeleton, no training; "
        "exact: the learned IK then a least-squares solve onto all six curves (hips and head too); "
        "exact_rig: the rig then the same solve (any skeleton, no training)",
    )  # fmt: skip
    model: str | None = option(
        None, metavar="NAME|PATH",
        help="the BMM: a pretrained model's name (bezmotion models lists them) or a saved BMM's folder; default: one "
        "trained on the clips' skeleton that is here (bundled or trained locally), else bandai_namco",
    )  # fmt: skip
    ik_model: str | None = option(
        None, metavar="NAME|PATH",
        help="the learned IK: a pretrained model's name or a saved one's folder; default as --model's",
    )  # fmt: skip
    trained_on: str | None = option(
        None, metavar="NAME|PROFILE.json", help="the skeleton --model was trained on: a profile name (bandai_namco, lafan1) or a profile JSON; "
        "default: a named model's own; for a folder, the clips' skeleton (no transfer)",
    )  # fmt: skip
    facing: str = option(
        "trained", choices=FACING_CHOICES,
        help="trained (default): turn the in-between to start facing the way the BMM's training motions do, and back; "
        "keys: sample it facing the way the keys do (the paper's)",
    )  # fmt: skip
    orientation: str = option(
        "anatomical", choices=ORIENTATION_CHOICES,
        help="how a transfer to another skeleton aligns the joints' orientations: anatomical (default: each joint against its bones) "
        "or facing (each joint's mean orientation against the facing, over the clip)",
    )  # fmt: skip
    mapping: Path | None = option(None, metavar="MAP.json", help="JSON or TOML naming the six characteristic joints (and optionally the rig's chains) of another skeleton; without it they are read off the joint names (LeftHand, hand_l, L_Wrist, …), with a warning")
    units: str = option(
        "auto", metavar="auto|cm|m|mm|in|CM",
        help="the clips' length unit, or centimetres per unit (a number); auto (default): told from the skeleton's size (cm, m or mm "
        "where one gives a person's size, else the unit that gives a typical adult's, with a warning). "
        "The in-between is written in it; handles, reports and the .glb are in cm (.glb: m), Y up",
    )  # fmt: skip
    up: str = option("auto", choices=("auto", *UP_AXES), help="the clips' up axis; auto (default): where the head stands above the feet")
    out: str = option(
        "results/inbetween", metavar="PATH",
        help="a .bvh, .glb or .gif file, or a folder (default results/inbetween): a name ending in / or an existing folder is a "
        "folder; another suffix of letters and digits, two letters or more (take.fbx, take.mp4), is refused; any other name is a "
        "folder (take, take.v2). Other files in the folder stay",
    )  # fmt: skip
    force: bool = option(
        False, help="replace output files that bezmotion did not write (or that changed since), an input file included; "
        "without it only its own earlier outputs are replaced, with a note",
    )  # fmt: skip
    channels: str = option(
        "default", choices=CHANNEL_CHOICES, help="BVH channels: default (positions on the root and hips) or clip (the start file's layout)"
    )  # fmt: skip
    bvh_fps: str = option(
        "clip",
        choices=("clip", "30"),
        help="the BVH file's frame rate: clip (default) the start clip's own where it is a whole multiple of 30 fps (60, 120: "
        "every in-between frame kept, the frames between slerped), else 30; or 30, the BMM's (the glTF file and the preview "
        "are at 30 fps either way, timed in seconds)",
    )  # fmt: skip
    key_positions_only: bool = option(
        False, help="condition the BMM on the key poses' joint positions alone (the paper); default: their orientations too"
    )
    key_velocities: bool = option(
        False,
        help="the curves leave and reach the keys at the clip's own velocities (from the frame before the first key and the one "
        "after the last; a chain's inner keys from the frames on both sides)",
    )  # fmt: skip
    foot_lock: bool = option(True, help=FOOT_LOCK_HELP)
    exact: tuple[str, ...] = option((), repeat=True, metavar="NAME=VALUE", help=EXACT_HELP)
    verify: bool = option(True, help=VERIFY_HELP)
    no_preview: bool = option(False, help="with --out FOLDER: no preview.gif (drawing it takes a few seconds)")
    no_progress: bool = option(False, help="no progress lines on stderr (warnings and missed handles still go there)")


# ----------------------------------------------------------------------------- handles


def _read_clip(argument: str, path: Path, shown: str | None = None) -> BvhMotion:
    """The BVH file of an argument (``shown``: the argument's value as written, default ``path``)."""
    shown = str(path) if shown is None else shown
    if not path.is_file():
        raise argument_error(argument, shown, FileNotFoundError("no such file" if not path.exists() else "not a file"))
    try:
        return read_bvh(path)
    except (ValueError, UnicodeDecodeError, OSError) as error:
        message = str(error).removeprefix(f"{path}:").strip()
        message = re.sub(r"^(\d+):\s*", r"line \1: ", message)  # the parser's "path:line: …"
        raise argument_error(argument, shown, ValueError(message)) from None


def _key(argument: str, text: str, *, end: bool) -> tuple[Path, int | None]:
    """``FILE.bvh@FRAME`` → ``(path, frame)``; frame None without ``@``."""
    path, at, frame = text.rpartition("@")
    if not at:
        return Path(text), None
    if not re.fullmatch(r"[+-]?\d+", frame.strip()) or not path:
        raise ValueError(f"{argument} {text}: expected FILE.bvh@FRAME (a whole frame number), or FILE.bvh for its {'last' if end else 'first'} frame")
    return Path(path), int(frame)


def _check_frame(argument: str, text: str, motion: BvhMotion, frame: int) -> None:
    if not 0 <= frame < motion.num_frames:
        has = f"frames 0…{motion.num_frames - 1}" if motion.num_frames > 1 else "frame 0 alone" if motion.num_frames else "no frames"
        raise ValueError(f"{argument} {text}: frame {frame} is out of range; the file has {has}")


@dataclasses.dataclass(frozen=True)
class Plan:
    """Everything an in-between needs, checked: nothing has been written yet."""

    recognised: RecognisedCharacter
    start_motion: BvhMotion
    keys: tuple[Pose, ...]  # two for one window, more for a chain
    reference: BvhMotion | None
    bmm: BezierMotionModel
    ik: str
    ik_fn: Any
    ik_params: Any
    transfer: Transfer | None
    handles: Handles
    handle_records: list[dict[str, Any]]
    reach: ReachChains  # how far the character's joints reach, for the handles' reports
    outputs: list[dict[str, Path]]  # per sample, {suffix: path}
    folder: Path | None  # --out FOLDER, else None
    label: str
    key_velocity: Any = None  # (keys, 6, 3) cm/frame with --key-velocities
    models: dict[str, str | None] | None = None  # {"bmm": name or folder, "ik": the learned IK's, None without one}
    clip_frame: ClipFrame = ClipFrame()  # the clips' units and up axis (everything above is in cm, Y up)
    warnings: tuple[str, ...] = ()  # about the inputs, for stderr and the summary
    clip_fps: float = TRAINED_FPS  # the start clip's own frame rate (the keys are resampled to TRAINED_FPS)
    bvh_fps: float = TRAINED_FPS  # the BVH file's rate (bvh_frame_rate): TRAINED_FPS or a whole multiple of it
    transferred: bool = False  # the BMM was trained on another skeleton (``transfer`` may also hold the facing alone)
    out_dir: Path = Path()  # where the outputs go: the --out folder, or the --out file's
    set_name: str = ""  # their set's name there (_replacing)
    existing: ExistingOutputs = ExistingOutputs()  # what the outputs replace (ours, and theirs with --force) and remove (stale)
    key_times: tuple[int, ...] = (0, 30)  # the keys' frames at TRAINED_FPS, the first 0

    @property
    def frames(self) -> int:
        """Frames of the in-between at TRAINED_FPS."""
        return self.key_times[-1] + 1

    @property
    def gap(self) -> int | None:
        """Frames from one key to the next where they are evenly spaced, else None."""
        gaps = set(np.diff(self.key_times).tolist())
        return gaps.pop() if len(gaps) == 1 else None


SUMMARY = "summary.json"
"""The summary's name in an ``--out`` folder: written last, so that beside it the set is whole."""


def _outputs(args: InbetweenCommand) -> tuple[list[dict[str, Path]], Path | None]:
    """Per sample, ``{suffix: path}``; and the folder (None when ``--out`` is a file,
    :func:`~bezmotion.pipeline.authoring.output_format`)."""
    out = Path(args.out)
    n = args.samples
    tag = (lambda k: "") if n == 1 else (lambda k: f"_{k}")
    try:
        suffix = output_format(args.out)
        if suffix is not None:
            check_writable_folder(out.parent)
            return [{suffix: out.with_name(f"{out.stem}{tag(k)}{out.suffix}")} for k in range(n)], None
        if out.exists() and not out.is_dir():
            raise ValueError("exists and is not a folder")
        check_writable_folder(out)
    except ValueError as error:
        raise argument_error("--out", args.out, error) from None
    names = {".bvh": "inbetween", ".glb": "inbetween"} | ({} if args.no_preview else {".gif": "preview"})
    return [{s: out / f"{stem}{tag(k)}{s}" for s, stem in names.items()} for k in range(n)], out


def _replacing(
    args: InbetweenCommand, outputs: list[dict[str, Path]], folder: Path | None, inputs: Sequence[tuple[str, Path]]
) -> tuple[Path, str, ExistingOutputs]:
    """Where the outputs go, the name of their set there (``""``: an ``--out`` folder's own;
    else the ``--out`` file's name, for its numbered samples too) and what they would replace
    (:func:`~bezmotion._src.output_sets.existing_outputs`).

    Raises:
      ValueError: without ``--force``, an output that is one of the ``inputs``
        (``(argument, path)``), or a file there that bezmotion did not write.
    """
    names = [path.name for sample in outputs for path in sample.values()]
    if folder is not None:
        where, set_name, names = folder, "", [*names, SUMMARY]
    else:
        where, set_name = Path(args.out).parent, Path(args.out).name
    try:
        existing = existing_outputs(where, names, set_name)
    except ValueError as error:
        raise argument_error("--out", args.out, error) from None
    if args.force:
        return where, set_name, existing
    for name in [*existing.ours, *existing.theirs]:
        for argument, path in inputs:
            try:
                same = os.path.samefile(where / name, path)
            except OSError:
                same = False
            if same:
                raise ValueError(f"--out {args.out}: would replace {name}, the {argument} file, an input of this run; --force replaces it")
    if existing.refusal() is not None:
        raise ValueError(f"--out {args.out}: {existing.refusal()}; --force replaces {'it' if len(existing.theirs) == 1 else 'them'}")
    return where, set_name, existing


DEFAULT_MODEL = "bandai_namco"  # the bundled models: any skeleton, through a transfer


def default_models(skeleton: str | None, model: str | None, ik_model: str | None) -> tuple[str, str]:
    """``(--model, --ik-model)``: each as given, or the first registered model trained on the
    clips' ``skeleton`` (a recognised preset) that is here (:func:`~bezmotion.assets.registry.trained_for`:
    bundled, or trained locally), else :data:`DEFAULT_MODEL`. A model of the clips' own
    skeleton needs no transfer, and its learned IK fits them (the exact IK rather than
    ``exact_rig`` under ``--ik auto``)."""
    return (
        model if model is not None else trained_for(skeleton, "bmm") or DEFAULT_MODEL,
        ik_model if ik_model is not None else trained_for(skeleton, "ik") or DEFAULT_MODEL,
    )


def plan(args: InbetweenCommand) -> Plan:
    """Check every argument, read the inputs and load the models; writes nothing (what a
    killed run left in the output folder is finished or removed: :func:`~bezmotion._src.output_sets.clear_interrupted`).

    Raises:
      ValueError: a bad argument; the message starts with the argument and its value. An
        output that would replace an input or a file bezmotion did not write is one, unless ``--force``.
    """
    for h in args.handle:  # the syntax first, before any file is read
        parse_handle(h)
    if args.samples < 1:
        raise ValueError(f"--samples {args.samples}: must be at least 1")
    if args.steps < 1:
        raise ValueError(f"--steps {args.steps}: must be at least 1")
    outputs, folder = _outputs(args)
    keys, label = _read_keys(args)
    (arg0, text0, path0, start_motion, f0), f1 = keys[0], keys[-1][-1]
    if args.mapping is not None and not Path(args.mapping).is_file():
        raise ValueError(f"--mapping {args.mapping}: no such file")
    inputs = [(argument, path) for argument, _, path, _, _ in keys]
    inputs += [(flag, Path(path)) for flag, path in (("--handles", args.handles), ("--mapping", args.mapping)) if path is not None]
    out_dir, set_name, existing = _replacing(args, outputs, folder, inputs)

    def recognise(motion: BvhMotion) -> RecognisedCharacter:
        try:
            return recognise_character(motion, args.mapping)
        except (ValueError, FileNotFoundError) as error:
            if args.mapping is not None:
                raise argument_error("--mapping", args.mapping, error) from None
            raise argument_error(arg0, path0, error) from None

    recognised = recognise(start_motion)
    for argument, text, _, motion, _ in keys[1:]:
        if not same_skeleton(start_motion, motion):
            raise ValueError(
                f"{argument} {text}: its skeleton ({len(motion.skeleton.names)} joints) differs from the start's "
                f"({len(start_motion.skeleton.names)} joints, {text0}); every key needs the same joints"
            )
    # Every clip in cm with Y up from here on (what the models and thresholds are measured in);
    # the character again from the converted clip, its offsets in cm.
    clip_frame, frame_warnings = _clip_frame(args, keys, recognised.character)
    if not clip_frame.is_ours:
        converted = {id(m): clip_frame.to_ours(m) for _, _, _, m, _ in keys}
        keys = [(a, t, p, converted[id(m)], f) for a, t, p, m, f in keys]
        start_motion = keys[0][3]
        recognised = recognise(start_motion)
    character = recognised.character
    if recognised.read_off_names is not None:
        joints = ", ".join(f"{role} {name}" for role, name in recognised.read_off_names.items())
        frame_warnings = [*frame_warnings, f"{path0}: no known skeleton; its six joints read off their names: {joints} (--mapping MAP.json names others)"]

    # The handles as written (their joints known now; their frames once the model is).
    requests = [parse_handle(h) for h in args.handle]
    if args.handles is not None:
        requests += read_handles_file(args.handles)
    for r in requests:
        handle_role(r, recognised)

    # The models.
    model_name, ik_model_name = default_models(recognised.preset, args.model, args.ik_model)
    try:
        bmm_dir, bundled_trained_on = resolve_bmm(model_name, verify=args.verify)
        bmm = load_model(bmm_dir, verify=args.verify)
    except (FileNotFoundError, ValueError, TypeError) as error:
        raise argument_error("--model" if args.model is not None else "the default BMM", model_name, error) from None
    clip_fps = start_motion.nominal_fps
    key_times = _key_times(args, bmm, clip_fps, len(keys))
    # Every clip at the BMM's frame rate from here on (its window, thresholds and velocities count those frames).
    bvh_fps = bvh_frame_rate(args.bvh_fps, clip_fps)
    keys, rate_warnings = _at_trained_rate(keys, bvh_fps)
    frame_warnings = [*frame_warnings, *rate_warnings]
    start_motion, f0, f1 = keys[0][3], keys[0][4], keys[-1][4]
    reference = motion_window(start_motion, f0, f1 - f0 + 1) if args.clip is not None else None
    key_poses = tuple(motion_poses(m, character, f) for _, _, _, m, f in keys)
    key_velocity = None
    if args.key_velocities:
        try:
            key_velocity = clip_key_velocities(character, [(m, f) for _, _, _, m, f in keys], names=[text for _, text, _, _, _ in keys])
        except ValueError as error:
            raise ValueError(f"--key-velocities: {error}") from None
    trained_on = args.trained_on if args.trained_on is not None else bundled_trained_on
    transfer = None
    transferred = trained_on is not None and trained_on != recognised.preset
    if trained_on is not None:
        try:
            source = load_profile(trained_on)
        except ValueError as error:
            raise argument_error("--trained-on" if args.trained_on is not None else "the BMM's training skeleton", trained_on, error) from None
        target = target_profile(recognised, list({id(m): m for _, _, _, m, _ in keys}.values())) if transferred else None
        transfer = make_transfer(source, target, orientation=args.orientation, facing=args.facing)

    settings = exact_settings(args.exact, "--exact")  # its errors name the item
    ik = args.ik
    ik_model = ik_folder = None
    if ik == "auto" or ik in LEARNED_IK_CHOICES:
        try:
            ik_folder = resolve_ik_model(ik_model_name, verify=args.verify)
            ik_model = load_ik_model(ik_folder, verify=args.verify)
        except (FileNotFoundError, ValueError, TypeError) as error:
            raise argument_error("--ik-model" if args.ik_model is not None else "the default learned IK", ik_model_name, error) from None
        if ik == "auto":
            try:
                check_ik_model(ik_model, character)
                ik = "exact"
            except ValueError:
                ik, ik_model, ik_folder = "exact_rig", None, None
    if settings and ik not in EXACT_IK_CHOICES:
        chose = f"not of the {ik} IK chosen for this skeleton" if args.ik == "auto" else f"not of --ik {ik}"
        raise ValueError(f"--exact {' '.join(args.exact)}: the settings of the exact IK, {chose}")
    try:
        # The exact IK's soft joint limits: those measured beside the learned IK, if any
        # (none for the rig's start: no limits were measured on an unknown skeleton).
        limits = ik_model_joint_limits(ik_folder, character) if ik == "exact" else None
        ik_fn, ik_params = make_ik(
            ik, recognised, rest_quat_local=np.asarray(key_poses[0].quat_local), ik_model=ik_model, limits=limits, exact_settings=settings
        )
    except ValueError as error:  # the settings were checked above: what is left is the IK against the skeleton
        fit = f"the learned IK {ik_model_name} does not fit this skeleton: " if ik in LEARNED_IK_CHOICES else ""
        chosen = f"--ik {ik}" if args.ik != "auto" else f"{path0}: the IK chosen for this skeleton ({ik})"
        raise ValueError(f"{chosen}: {fit}{error}") from None

    handles, records = resolve_handles(requests, recognised, key_poses, bmm, key_frames=key_times)
    reach = reach_chains(make_rig(character, recognised.rig_spec, rest_quat_local=np.asarray(key_poses[0].quat_local)))
    return Plan(
        recognised, start_motion, key_poses, reference, bmm, ik, ik_fn, ik_params, transfer, handles, records, reach, outputs, folder,
        label, key_velocity, {"bmm": model_name, "ik": None if ik_model is None else ik_model_name}, clip_frame, tuple(frame_warnings),
        clip_fps, bvh_fps, transferred, out_dir, set_name, existing, key_times,
    )  # fmt: skip


def _key_times(args: InbetweenCommand, bmm: BezierMotionModel, clip_fps: float, num_keys: int) -> tuple[int, ...]:
    """The keys' frames at :data:`TRAINED_FPS`, the first 0: CLIP ``--frames``' own (the
    clip's frames at its rate, any distance apart), else every ``--gap`` frames (default the
    BMM's window, 30); checked."""
    if args.clip is not None:
        shown = " ".join(map(str, args.frames))
        if args.gap is not None:
            raise ValueError(f"--gap {' '.join(map(str, args.gap))}: goes with --start/--end or --key; CLIP --frames {shown} keeps the clip's own spacing")
        gaps = [b - a for a, b in zip(args.frames, args.frames[1:])]
        at_trained = [gap * TRAINED_FPS / clip_fps for gap in gaps]  # the clip's gaps in the frames the BMM counts
        off = [(gap, at) for gap, at in zip(gaps, at_trained) if abs(at - round(at)) > 1e-6]
        if off:
            gap, at = off[0]
            whole_rate = abs(clip_fps - round(clip_fps)) < 1e-6  # then a whole number of the clip's frames makes whole 30 fps frames
            advice = (
                f"space the keys a multiple of {round(clip_fps) // np.gcd(round(clip_fps), round(TRAINED_FPS))} frames apart" if whole_rate
                else f"resample the clip to {TRAINED_FPS:g} fps"
            )  # fmt: skip
            raise ValueError(
                f"--frames {shown}: {gap} frames at the clip's {clip_fps:g} fps are {at:.4g} frames at {TRAINED_FPS:g} fps, "
                f"not a whole number; {advice}, or give the keys with --start/--end and --gap"
            )
        spans, given = [round(at) for at in at_trained], f"--frames {shown}"
    else:
        gaps = (bmm.config.num_frames - 1,) if args.gap is None else args.gap
        given = f"--gap {' '.join(map(str, gaps))}"
        if len(gaps) not in (1, num_keys - 1):
            raise ValueError(f"{given}: one gap for every pair of keys, or one per pair ({num_keys - 1} through {num_keys} keys), got {len(gaps)}")
        spans = list(gaps) * (num_keys - 1) if len(gaps) == 1 else list(gaps)
    for span in spans:
        try:
            window_frames(bmm.config, span + 1)
        except ValueError:
            raise ValueError(f"{given}: keys are 2 … {MAX_WINDOW_FRAMES - 1} frames apart at {TRAINED_FPS:g} fps, got {span}") from None
    return tuple(int(t) for t in np.concatenate([[0], np.cumsum(spans)]))


def bvh_frame_rate(choice: str, clip_fps: float) -> float:
    """The rate ``--bvh-fps choice`` writes the BVH file at: ``"30"``, :data:`TRAINED_FPS`;
    ``"clip"``, ``clip_fps`` where it is a whole multiple of it (60, 120 fps: every frame of the
    in-between is a frame of the file, keys and handles included), else :data:`TRAINED_FPS`
    (at 24 or 25 fps most of its frames would fall between the file's, handles too)."""
    if choice not in ("clip", "30"):
        raise ValueError(f"--bvh-fps must be clip or 30, got {choice!r}")
    ratio = clip_fps / TRAINED_FPS
    whole = ratio > 1.0 and abs(ratio - round(ratio)) < 1e-6
    return float(round(ratio) * TRAINED_FPS) if choice == "clip" and whole else TRAINED_FPS


def _clip_frame(
    args: InbetweenCommand, keys: Sequence[tuple[str, str, Path, BvhMotion, int]], character: Character
) -> tuple[ClipFrame, list[str]]:
    """The clips' units and up axis (``--units``/``--up`` where given, else told from the
    clips: :mod:`bezmotion.data.clip_frame`), and warnings.

    The units are told from each clip's skeleton, and must agree. The up axis is told from all
    the clips' frames together; where even they cannot tell it (a few frames of someone lying
    down), Y up — the BVH custom — with a warning.

    Raises:
      ValueError: a clip whose units cannot be told, or two clips whose units differ, naming
        the key and asking for ``--units``.
    """
    hips, head, _, _, left_foot, right_foot = character.characteristic
    feet = (left_foot, right_foot)
    clips = {id(m): (f"{argument} {text}", m) for argument, text, _, m, _ in keys}  # each clip read once
    units = args.units
    warnings = []
    if units != "auto":
        try:
            cm_per_unit(units)
        except ValueError as error:
            raise argument_error("--units", units, error) from None
    else:
        told = {}
        for shown, motion in clips.values():
            try:
                told[shown] = detect_units(motion, hips, head, feet)
            except ValueError as error:
                raise ValueError(f"{shown}: {error}") from None
        (first, units), *others = told.items()
        for other, other_units in others:
            if other_units != units:
                raise ValueError(f"{other}: its units ({other_units}) differ from {first}'s ({units}); the keys' files must share one unit")
        if units not in CM_PER_UNIT:
            size = skeleton_size(keys[0][3], hips, head, feet)
            warnings.append(
                f"{first}: its skeleton is a person's size in none of cm, m or mm (head to hips to foot {size:.4g} units); "
                f"taking a typical adult's {TYPICAL_PERSON_CM:g} cm, 1 unit = {float(units):.4g} cm (--units sets it)"
            )
    up = args.up
    if up == "auto":
        try:
            up = detect_up([m for _, m in clips.values()], head, feet)
        except ValueError as error:
            up = "y"
            warnings.append(f"{error.args[0].split('; give it')[0]}; taking Y up, the BVH custom (--up says it)")
    return ClipFrame(units, up), warnings


def _read_keys(args: InbetweenCommand) -> tuple[list[tuple[str, str, Path, BvhMotion, int]], str]:
    """The key poses the arguments name, read and checked, in order: ``[(argument, as
    written, path, clip, frame)]``, and a label for them. One of CLIP ``--frames``,
    ``--start``/``--end`` or ``--key`` (repeated)."""
    forms = {"CLIP": args.clip, "--start": args.start, "--end": args.end, "--key": args.key[0] if args.key else None}
    given = [name for name, value in forms.items() if value is not None]
    if len({{"--end": "--start"}.get(name, name) for name in given}) > 1:  # --start and --end are one way
        raise ValueError(
            f"{given[0]} {forms[given[0]]}: give the keys one way, CLIP.bvh --frames …, --start/--end or --key (repeated), not {' and '.join(given)}"
        )
    if args.clip is not None:
        if args.frames is None:
            raise ValueError(f"CLIP {args.clip}: needs --frames START END (the key frames in it)")
        shown = " ".join(map(str, args.frames))
        if len(args.frames) < 2:
            raise ValueError(f"--frames {shown}: needs at least two key frames (START END, or more for a chain)")
        motion = _read_clip("CLIP", args.clip)
        for f in args.frames:
            _check_frame("--frames", shown, motion, f)
        return [("CLIP", str(args.clip), args.clip, motion, f) for f in args.frames], f"{args.clip.name} frames {'–'.join(map(str, args.frames))}"
    if args.frames is not None:
        raise ValueError(f"--frames {' '.join(map(str, args.frames))}: goes with one CLIP.bvh (bezmotion inbetween CLIP.bvh --frames START END)")
    if args.key:
        if len(args.key) < 2:
            raise ValueError(f"--key {args.key[0]}: needs at least two --key poses")
        named = [("--key", text) for text in args.key]
    elif args.start is None and args.end is None:
        raise ValueError("give the key poses: CLIP.bvh --frames START END, or --start A.bvh@FRAME --end B.bvh@FRAME")
    elif args.start is None or args.end is None:
        given_one, missing = ("--start", "--end") if args.end is None else ("--end", "--start")
        raise ValueError(f"{given_one} {args.start or args.end}: needs {missing} FILE.bvh@FRAME too")
    else:
        named = [("--start", args.start), ("--end", args.end)]
    keys = []
    read: dict[Path, BvhMotion] = {}
    for i, (argument, text) in enumerate(named):
        last = i == len(named) - 1
        path, frame = _key(argument, text, end=last)
        if path not in read:
            read[path] = _read_clip(argument, path, text)
        m = read[path]
        frame = (m.num_frames - 1 if last else 0) if frame is None else frame
        _check_frame(argument, text, m, frame)
        keys.append((argument, text, path, m, frame))
    return keys, " → ".join(text for _, text in named)


def _at_trained_rate(
    keys: Sequence[tuple[str, str, Path, BvhMotion, int]], bvh_fps: float = TRAINED_FPS
) -> tuple[list[tuple[str, str, Path, BvhMotion, int]], list[str]]:
    """The keys (as :func:`_read_keys` gives them) with every clip of another frame rate
    resampled to :data:`TRAINED_FPS` through its key frames (:func:`resample_motion`), each
    key's frame moved to its sample; and a warning per such file, saying that the BVH file
    is written at ``bvh_fps``. A clip's keys a whole number of new frames apart share one
    resampling (CLIP ``--frames``); any other key gets its own, through its frame."""
    written = (
        f"the in-between is written at {TRAINED_FPS:g} fps" if bvh_fps == TRAINED_FPS
        else f"the in-between is made at {TRAINED_FPS:g} fps and its BVH file written at {bvh_fps:g} (--bvh-fps)"
    )  # fmt: skip
    out, warnings, done = [], [], {}  # done: id(clip) → (resampled, anchor frame, its sample)
    for argument, text, path, motion, frame in keys:
        shared = done.get(id(motion))
        if shared is not None:
            resampled, anchor, at = shared
            moved = (frame - anchor) * TRAINED_FPS / motion.nominal_fps  # new frames from the anchor
            if abs(moved - round(moved)) < 1e-6:
                out.append((argument, text, path, resampled, at + round(moved)))
                continue
        resampled, at = resample_motion(motion, TRAINED_FPS, frame)  # the clip itself at TRAINED_FPS
        if shared is None:
            done[id(motion)] = (resampled, frame, at)
            if resampled is not motion:
                warnings.append(f"{path}: {motion.nominal_fps:g} fps, resampled to the BMM's {TRAINED_FPS:g} fps; {written}")
        out.append((argument, text, path, resampled, at))
    return out, warnings


# -------------------------------------------------------------------------------- run
