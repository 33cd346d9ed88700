"""``bezmotion demo``: in-between a bundled real clip with the bundled BMM and IK.

No downloads: the clip (Bandai-Namco, CC BY-NC 4.0) and the small pretrained models
(trained on Bandai-Namco by ``experiments/bmm_lafan1.py --corpus bandai_namco`` and
``experiments/train_ik.py --corpus bandai_namco``) ship in :mod:`bezmotion.assets`.

The first 31 frames of the clip are a BMM window: its first and last frames are the
start and end poses, and one handle moves a joint at an intermediate frame.
The pipeline generates curves through the handle, IK turns them into full-body poses,
and the demo writes them as BVH (read back and checked by forward kinematics), a PNG
of the curves and poses, a glTF file (the skeleton and the six curves as CUBICSPLINE
controllers, :mod:`bezmotion.pipeline.gltf`), an animated GIF preview beside the mocap
(:mod:`bezmotion.pipeline.preview`), and a JSON summary: one set of files (:data:`DEMO_FILES`),
moved into the output folder together (:func:`~bezmotion._src.output_sets.output_set`).
"""

from __future__ import annotations

import functools
import json
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion._src.io import atomic_write_text, check_writable_folder, save_figure
from bezmotion._src.output_sets import existing_outputs, output_set
from bezmotion.cli.errors import argument_error
from bezmotion.assets import DEMO_CLIP, DEMO_CLIP_ATTRIBUTION
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, FEET
from bezmotion.ik.protocol import Character, Pose, pose_fk
from bezmotion.ik.protores import load_ik_model
from bezmotion.evaluation.pipeline import full_body_handles_error
from bezmotion.pipeline import InbetweenOptions, InbetweenResult, Inbetweener, inbetween, pose_to_bvh
from bezmotion.evaluation.window_figures import curve_miss, largest_turn
from bezmotion.pipeline.authoring import (
    CHANNEL_CHOICES,
    EXACT_IK_CHOICES,
    IK_CHOICES,
    LEARNED_IK_CHOICES,
    ResultFiles,
    bvh_fk_error_cm,
    load_profile,
    ik_model_joint_limits,
    make_ik,
    make_transfer,
    motion_poses,
    profile_names,
    recognise_character,
    resolve_bmm,
    resolve_ik_model,
    target_profile,
    write_result,
)
from bezmotion.bmm.sampling import Handles, load_model


DEMO_FILES = ("inbetween.bvh", "ground_truth.bvh", "demo.png", "inbetween.glb", "preview.gif", "summary.json")
"""The files the demo writes in its folder; ``summary.json`` last, so that beside it the set is whole."""


def _plot(
    path: Path, character: Character, result: InbetweenResult, truth: Pose, handle: np.ndarray, joint: int, handle_frame: int
) -> None:
    """Curves (side view) and stick figures of the in-between beside the mocap."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, pos = pose_fk(character, result.pose)
    _, true_pos = pose_fk(character, truth)
    pos, true_pos = np.asarray(pos), np.asarray(true_pos)
    # Plot in the walking plane: horizontal axis along the hips' travel.
    travel = pos[-1, character.hips] - pos[0, character.hips]
    forward = np.array([travel[0], 0.0, travel[2]]) / max(np.hypot(travel[0], travel[2]), 1e-6)
    along = lambda p: p @ forward  # noqa: E731
    fig, (curves_ax, poses_ax) = plt.subplots(1, 2, figsize=(13, 4.8))
    colours = plt.cm.tab10(np.arange(len(CHARACTERISTIC_JOINTS)))
    dense, ctrl = np.asarray(result.positions), np.asarray(result.joined_curves().ctrl_pos)
    for j, name in enumerate(CHARACTERISTIC_JOINTS):
        curves_ax.plot(along(dense[:, j]), dense[:, j, 1], color=colours[j], label=name)
        curves_ax.plot(along(ctrl[:, j]), ctrl[:, j, 1], "o", color=colours[j], ms=4)
    truth_joint = true_pos[:, character.characteristic[joint]]
    curves_ax.plot(along(truth_joint), truth_joint[:, 1], "--", color=colours[joint], alpha=0.6, label=f"{CHARACTERISTIC_JOINTS[joint]} (mocap)")
    curves_ax.plot(along(handle), handle[1], "*", color="purple", ms=16, label="handle")
    curves_ax.set(title="BMM curves (dots: control points)", xlabel="along the walk (cm)", ylabel="height (cm)", aspect="equal")
    curves_ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=4)
    hidden = set(character.ancestors_of_hips())  # static joints under the floor origin
    spacing = 45.0  # cm between drawn poses, so that they do not overlap
    origin = along(pos[0, character.hips])
    for k, frame in enumerate(range(0, pos.shape[0], 6)):
        shift = k * spacing - along(pos[frame, character.hips]) + origin
        for p, shade, style in ((true_pos, 0.35, "--"), (pos, 1.0, "-")):
            for j, parent in enumerate(character.skeleton.parents):
                if parent >= 0 and parent not in hidden:
                    seg = p[frame, [parent, j]]
                    poses_ax.plot(along(seg) + shift, seg[:, 1], style, color="k", alpha=shade, lw=1.2)
        if frame == handle_frame:
            poses_ax.plot(along(handle) + shift, handle[1], "*", color="purple", ms=16)
        poses_ax.text(origin + k * spacing, -8, f"frame {frame}", ha="center", fontsize=8)
    poses_ax.set(title="poses every 6 frames, spaced apart (solid: in-between, dashed: mocap)", aspect="equal")
    poses_ax.set_xticks([])
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


DEFAULT_MODEL = "bandai_namco"
"""The pretrained BMM and learned IK the demo runs without ``--bmm`` / ``--ik-model``."""


def _resolve(label: str, name_or_path: str | Path, resolve: Callable[[str | Path], Any]) -> Any:
    """``resolve(name_or_path)``, its errors naming the model as ``label`` (its option, or
    what the default is) and ``name_or_path``."""
    try:
        return resolve(name_or_path)
    except (FileNotFoundError, ValueError) as error:
        raise argument_error(label, name_or_path, error) from None


def ground_slide_cm(feet_pos: np.ndarray, ground: np.ndarray, *, height: float = 5.0) -> np.ndarray:
    """``(2,)`` how far (cm) each foot travels horizontally (X, Z) between frames on which it
    is within ``height`` cm of its ``ground`` height (``(2,)``, e.g. its lowest in the mocap):
    a planted foot's slide. ``feet_pos``: ``(frames, 2, 3)`` cm, +Y up."""
    low = feet_pos[..., 1] < ground + height
    step = np.linalg.norm((feet_pos[1:] - feet_pos[:-1])[..., [0, 2]], axis=-1)
    return (step * (low[1:] & low[:-1])).sum(axis=0)


def demo(
    out: Path,
    *,
    joint: str = "right_hand",
    frame: int = 12,
    offset: tuple[float, float, float] = (0.0, 25.0, 0.0),
    ik: str = "exact",
    steps: int = 10,
    seed: int = 0,
    bmm_dir: str | Path | None = None,
    bmm_corpus: str | None = None,
    ik_dir: str | Path | None = None,
    clip: Path = DEMO_CLIP,
    channels: str = "default",
    foot_lock: bool = True,
    exact_settings: Mapping[str, float | int] | None = None,
    force: bool = False,
    verify: bool = True,
) -> dict:
    """Run the demo; returns (and writes) its summary. See the module docstring.

    Args:
      out: output folder (created).
      joint, frame, offset: the handle: ``joint`` (a characteristic joint) is moved by
        ``offset`` (cm) from where the mocap has it at ``frame`` (any frame in 1…29).
      ik: ``"exact"`` (default: the learned IK, then a whole-body least-squares solve onto
        all six targets, with the joint limits stored beside the IK model), ``"refined"``
        (the bundled learned IK, then exact two-bone arms and legs), ``"learned"`` (the
        learned IK alone), ``"rig"`` (analytic, no data) or ``"exact_rig"`` (the rig, then the
        exact solve, without joint limits).
      steps, seed: DDIM steps and PRNG seed of the sampler.
      bmm_dir, bmm_corpus: the BMM — a pretrained model's name (:mod:`bezmotion.assets.registry`,
        ``bezmotion models``) or a saved BMM's folder — and the corpus it was trained on (one
        with a profile in :data:`~bezmotion.assets.PROFILES_DIR`; default: a named model's
        own, else ``"bandai_namco"``; another skeleton's curves are transferred).
      ik_dir: the learned IK, a name or a folder (for the ``ik`` choices that start from it,
        :data:`~bezmotion.pipeline.authoring.LEARNED_IK_CHOICES`).
      channels: the BVH files' channels: ``"default"`` (positions on the root and the hips,
        rotations elsewhere) or ``"clip"`` (the clip's own layout). Either way the files
        carry the clip's OFFSETs and End Sites and its whole frame rate.
      foot_lock: hold each foot still while the BMM says it is planted
        (:func:`~bezmotion.bmm.foot_lock.lock_feet`; ours, not the paper's): on the demo the
        left foot slides 2.6 cm on the ground instead of 17.3 (the mocap 3.9; the summary's ``ground_slide_cm``).
      exact_settings: :class:`~bezmotion.ik.exact.ExactIKParams` keywords of the exact IKs
        (``--exact NAME=VALUE``), e.g. ``{"plant_weight": 10.0}``.
      force: replace files of :data:`DEMO_FILES` in ``out`` that bezmotion did not write (or
        that changed since); without it they are refused, and only its own are replaced.
      verify: check the models' files against their checksums; ``False`` loads a model saved
        without them, with a warning.
    Raises:
      ValueError: a bad argument (naming its option), before the work; files in ``out``
        that bezmotion did not write, without ``force``.
    """
    if ik not in IK_CHOICES:
        raise ValueError(f"--ik must be one of {IK_CHOICES}, got {ik!r}")
    if joint not in CHARACTERISTIC_JOINTS:
        raise ValueError(f"--joint must be one of {list(CHARACTERISTIC_JOINTS)}, got {joint!r}")
    if channels not in CHANNEL_CHOICES:
        raise ValueError(f"--channels must be one of {CHANNEL_CHOICES}, got {channels!r}")
    if exact_settings and ik not in EXACT_IK_CHOICES:
        shown = " ".join(f"{k}={v}" for k, v in exact_settings.items())
        raise ValueError(f"--exact {shown}: the settings of the exact IK, not of --ik {ik}")
    if not (steps >= 1):
        raise ValueError(f"--steps must be at least 1, got {steps}")
    if bmm_corpus is not None and bmm_corpus not in profile_names():
        raise ValueError(f"--bmm-corpus must be one of {profile_names()}, got {bmm_corpus!r}")
    try:
        check_writable_folder(out)
        existing = existing_outputs(out, DEMO_FILES, "")
    except ValueError as error:
        raise ValueError(f"--out {out}: {error}") from None
    if existing.refusal() is not None and not force:
        raise ValueError(f"--out {out}: {existing.refusal()}; --force replaces {'it' if len(existing.theirs) == 1 else 'them'}")
    started = time.perf_counter()
    # Errors name the option only where the user gave it.
    bmm_label, bmm_dir = ("--bmm", bmm_dir) if bmm_dir is not None else ("the default BMM", DEFAULT_MODEL)
    ik_label, ik_dir = ("--ik-model", ik_dir) if ik_dir is not None else ("the default learned IK", DEFAULT_MODEL)
    bmm_folder, trained_on = _resolve(bmm_label, bmm_dir, functools.partial(resolve_bmm, verify=verify))
    bmm_corpus = bmm_corpus if bmm_corpus is not None else trained_on or "bandai_namco"
    ik_folder = _resolve(ik_label, ik_dir, functools.partial(resolve_ik_model, verify=verify)) if ik in LEARNED_IK_CHOICES else None
    motion = read_bvh(clip)
    bmm = _resolve(bmm_label, bmm_dir, lambda _: load_model(bmm_folder, verify=verify))
    # The clip's own skeleton (its offsets) throughout: the files' FK is the pipeline's.
    recognised = recognise_character(motion)
    character = recognised.character
    frames = bmm.config.num_frames
    if motion.num_frames < frames:
        raise ValueError(f"{clip}: the demo needs {frames} frames, the clip has {motion.num_frames}")
    truth = motion_poses(motion, character, slice(0, frames))
    # Joints the rig does not solve (clavicles, toes) keep the start pose's rotations.
    ik_fn, ik_params = make_ik(
        ik, recognised, rest_quat_local=np.asarray(truth.quat_local[0]), ik_model=None if ik_folder is None else _resolve(ik_label, ik_dir, lambda _: load_ik_model(ik_folder, verify=verify)),
        limits=ik_model_joint_limits(ik_folder, character) if ik == "exact" else None, exact_settings=exact_settings,
    )  # fmt: skip
    _, true_pos = pose_fk(character, truth)
    j = CHARACTERISTIC_JOINTS.index(joint)
    handle_pos = np.asarray(true_pos[frame, character.characteristic[j]]) + np.asarray(offset, np.float32)
    try:
        handles = Handles.from_frames([joint], [frame], handle_pos[None], config=bmm.config)
    except ValueError as error:
        raise ValueError(f"--frame {frame} --offset {' '.join(f'{x:g}' for x in offset)}: {error}") from None
    # Curves of another skeleton are moved over (BMM §5.2).
    transfer = make_transfer(load_profile(bmm_corpus), None if bmm_corpus == recognised.preset else target_profile(recognised, [motion]))
    model = Inbetweener(bmm, ik_fn, ik_params, character, transfer)
    keys = jax.tree.map(lambda x: x[jnp.asarray([0, -1])], truth)
    t0 = time.perf_counter()
    run = functools.partial(inbetween, model, keys, handles, key=jax.random.key(seed), options=InbetweenOptions(steps=steps, foot_lock=foot_lock))
    result = jax.block_until_ready(run())
    first_call_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(run())
    second_call_s = time.perf_counter() - t0

    paths = dict(zip(("inbetween", "ground_truth", "png", "glb", "gif"), (out / name for name in DEMO_FILES[:-1]), strict=True))
    # The files rig like the user's clip (its offsets, End Sites, 30 fps rather than the
    # 30.00003 of its 0.0333333 s), not like the take the IK model stored as its character.
    export = dict(fps=motion.nominal_fps, channels=None if channels == "default" else motion.channels, template=motion)
    truth_motion = pose_to_bvh(character, truth, **export)
    handle_records = ({"joint": joint, "frame": frame, "position": handle_pos.tolist()},)
    # BVH; the curves as glTF CUBICSPLINE controllers beside the skeleton; an animated preview.
    files = ResultFiles(
        character, pose_to_bvh(character, result.pose, **export), result.joined_curves(), bmm.config.stride, handle_records, truth_motion,
        f"{clip.name}: {joint} at frame {frame} moved by {list(offset)} cm",
    )  # fmt: skip
    _, pos = pose_fk(character, result.pose)
    feet = np.asarray(character.characteristic)[np.asarray(FEET)]
    ground = np.asarray(true_pos)[:, feet, 1].min(axis=0)
    slides = {which: ground_slide_cm(np.asarray(p[:, feet], np.float64), ground).round(2).tolist() for which, p in (("inbetween", pos), ("mocap", true_pos))}
    turns = {which: largest_turn(character, q) for which, q in (("inbetween", result.pose.quat_local), ("mocap", truth.quat_local))}
    with output_set(out, "", remove=existing.stale, last=DEMO_FILES[-1]) as staging:
        staged = {name: staging / path.name for name, path in paths.items()}
        for name in ("inbetween", "glb", "gif"):
            write_result(staged[name], files)
        write_result(staged["ground_truth"], ResultFiles(character, truth_motion, None, bmm.config.stride))
        _plot(staged["png"], character, result, truth, handle_pos, j, frame)
        summary = {
            "clip": clip.name,
            "frames": frames,
            "joints": character.num_joints,
            "handle": {"joint": joint, "frame": frame, "offset_cm": list(offset), "position_cm": handle_pos.tolist()},
            "ik": ik,
            "steps": steps,
            "channels": channels,
            "foot_lock": foot_lock,
            "exact": dict(exact_settings or {}),
            "curve_handle_error_cm": float(np.linalg.norm(np.asarray(result.positions[frame, j]) - handle_pos)),
            "full_body_handle_error_cm": float(full_body_handles_error(character, result.pose, handles, bmm.config.stride)),
            "joint_moved_cm": float(np.linalg.norm(np.asarray(pos[frame, character.characteristic[j]] - true_pos[frame, character.characteristic[j]]))),
            # How far each foot slides along the ground (near its lowest mocap height), the mocap's beside it.
            "ground_slide_cm": {which: dict(zip(("left_foot", "right_foot"), cm, strict=True)) for which, cm in slides.items()},
            # The fastest any joint turns from one frame to the next, and where: a pop or a
            # catch-up shows here (the mocap's beside it).
            "largest_turn_deg": turns,
            # How far the IK'd six joints lie from their curves at worst, and at which frame.
            "curve_error_max_cm": curve_miss(np.asarray(pos)[:, np.asarray(character.characteristic)], result.positions),
            "bvh_fk_error_cm": bvh_fk_error_cm(staged["inbetween"], character, result.pose),
            "first_call_s": first_call_s,
            "second_call_s": second_call_s,
            "total_s": time.perf_counter() - started,
            "files": {k: str(v) for k, v in paths.items()},
            "attribution": DEMO_CLIP_ATTRIBUTION,
        }
        atomic_write_text(staging / DEMO_FILES[-1], json.dumps(summary, indent=2) + "\n")
    note = existing.note(out)
    if note is not None:
        print(f"bezmotion demo: note: {note}", file=sys.stderr)
    print(f"bezmotion demo: {clip.name}, frames 0–{frames - 1}, {character.num_joints} joints, IK: {ik}")
    print(f"  handle: {joint} at frame {frame} moved by {list(offset)} cm")
    print(f"  curve passes the handle within {summary['curve_handle_error_cm']:.2e} cm; full body after IK {summary['full_body_handle_error_cm']:.2f} cm")
    print(f"  compiled and ran in {first_call_s:.1f} s, then {1e3 * second_call_s:.0f} ms per window")
    print(f"  wrote {paths['inbetween']} (BVH re-read matches to {summary['bvh_fk_error_cm']:.1e} cm), {paths['ground_truth']}, {paths['png']}")
    print(f"  wrote {paths['glb']} (skeleton and the six curves, glTF) and {paths['gif']} (animated preview)")
    print(f"  data: {DEMO_CLIP_ATTRIBUTION}")
    return summary
