"""``bezmotion inbetween``: in-between two poses of your own BVH files through handles.

    bezmotion inbetween CLIP.bvh --frames 0 30 --handle right_hand@12=+0,25,0 --out take/
    bezmotion inbetween --start A.bvh@0 --end B.bvh@12 --handles handles.json --samples 3 --out take.bvh
    bezmotion inbetween CLIP.bvh --frames 0 30 60 90 --handle left_hand@45=+0,30,0 --out chain/
    bezmotion inbetween --key idle.bvh@0 --key wave.bvh@25 --key idle.bvh@80 --out chain.bvh

**Keys.** One file and two frames (``CLIP.bvh --frames F G``), or a file and a frame each
(``--start A.bvh@F --end B.bvh@G``; without ``@`` the start is frame 0 and the end the
last frame). The keys may be any distance apart, 2 … 900 frames at 30 fps (the rate every
model here was trained at): with ``--frames`` the clip's own distance, so the in-between
keeps its timing (a clip at another rate is resampled to 30 fps through its keys first,
:func:`~bezmotion.data.resample.resample_motion`, and the in-between's BVH file written at
the clip's rate where that is a whole multiple of 30 fps, ``--bvh-fps``; a distance that is
no whole number of 30 fps frames is refused); ``--start``/``--end`` put two poses ``--gap``
frames apart (default 30, the BMM's window). More than two ``--frames``
(``CLIP.bvh --frames 0 20 65 90``, any distances apart) in-between a chain through every
one of them, joined C¹ at the shared keys: one window per pair of consecutive keys
(:func:`~bezmotion.pipeline.inbetween_at`; keys evenly spaced a multiple of 6 frames apart
are sampled in one call, others one window after another).
``--key FILE.bvh@FRAME``, repeated, makes such a chain through any poses of any files, in
the order given, each put ``--gap`` frames after the one before (one gap, or one per pair of
keys: ``--gap 20 45 25``).
Every key file must have the same joints; the output rigs like the first one (its OFFSETs
and End Sites).

**Handles** (any number; frames count at 30 fps from the first key, 0, to the last (the gap
G, 30 by default, G·K through K + 1 keys spaced by ``--gap``; with ``--frames`` the clip's
distance from the first key frame); a frame between two keys, not on one):

- ``--handle JOINT@FRAME=X,Y,Z``: the joint at that frame is at ``(X, Y, Z)`` in the
  clip's world frame (cm for LaFAN1 and Bandai-Namco, +Y up);
- ``--handle JOINT@FRAME=+X,Y,Z`` (a leading ``+``): an offset from the straight line
  between the joint's positions in the start and end poses, at that frame — the one
  reference that exists for any two poses (``right_hand@12=+0,25,0``: 25 cm above it; in a
  chain, the line between the two keys around the frame);
- ``--handles FILE``: a JSON list (the format ``bezmotion/integrations/blender_curves.py`` exports)
  ``[{"joint": "right_hand", "frame": 12, "position": [x, y, z]}, …]``, or ``{"handles":
  […]}``, or a TOML file of ``[[handles]]`` tables; ``"offset"`` instead of
  ``"position"`` is relative as above.

``JOINT`` is one of the six characteristic joints (``hips``, ``head``, ``left_hand``,
``right_hand``, ``left_foot``, ``right_foot``) or the skeleton's own name for it. Two
handles of one frame that no pose meets together (farther apart than the skeleton reaches
between their joints) get a warning before sampling (:func:`handle_conflicts`); after each
sample, every handle missed by more than 1 cm gets a line saying by how much and, where
known, why (:func:`handle_misses`). Both also go to ``summary.json``.

**Character.** Recognised from the joint names (LaFAN1, Bandai-Namco), or named by
``--mapping MAP.json`` (:func:`bezmotion.pipeline.authoring.read_mapping`). A BMM
trained on another skeleton drives it through a transfer (BMM §5.2) with the character's
bundled profile, or for other skeletons a profile measured on the input files' frames.
Without ``--model`` / ``--ik-model``, the models are the first registered ones trained on the
clips' skeleton that are here (bundled, or trained locally by the commands ``bezmotion models``
lists: LaFAN1's), else the bundled Bandai-Namco ones (:func:`default_models`).
``--ik auto`` (default) takes the exact IK (the learned IK, then a least-squares solve that
puts all six joints on their curves, handles on the hips and head included, without
popping at the keys) when the learned IK was trained on this skeleton, else the same solve
from the analytic rig's poses (``exact_rig``), which needs no training.

**Output.** ``--out x.bvh`` / ``x.glb`` / ``x.gif``: that file (``x_0.bvh``, ``x_1.bvh``, …
with ``--samples N``); ``--out FOLDER``: ``inbetween.bvh``, ``inbetween.glb``,
``preview.gif`` (unless ``--no-preview``) and ``summary.json``
(:func:`~bezmotion.pipeline.authoring.output_format` tells a file from a folder). Every
argument is checked and the models are loaded before anything is written: a bad argument
writes nothing. A run's files are one set, written in a staging folder and moved into place
together (:func:`~bezmotion._src.output_sets.output_set`): the folder holds the earlier set or the
new one, and the earlier set's files the new one lacks are removed; other files there stay.
A file that bezmotion did not write (or that changed since), or an input, is replaced only
with ``--force``; an earlier output is replaced with a note on stderr.
"""
from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.data.resample import TRAINED_FPS
from bezmotion.ik.exact import exact_settings
from bezmotion.ik.protocol import Pose, pose_fk
from bezmotion._src.io import atomic_write_text
from bezmotion._src.output_sets import output_set
from bezmotion.pipeline import InbetweenOptions, Inbetweener, inbetween_at, pose_to_bvh
from bezmotion.evaluation.window_figures import (
    beyond_reach,
    conflicting_handles,
    curve_miss,
    largest_turn,
)
from bezmotion.pipeline.authoring import (
    ResultFiles,
    bvh_fk_error_cm,
    write_result,
)

from bezmotion.cli.handles import records_as_handles, handle_conflicts, handle_misses
from bezmotion.cli.plan import SUMMARY, InbetweenCommand, Plan, plan


def _stderr(message: str) -> None:
    print(f"bezmotion inbetween: {message}", file=sys.stderr, flush=True)


def sample_key(seed: int, sample: int = 0) -> jax.Array:
    """The PRNG key of sample ``sample`` of ``bezmotion inbetween --seed SEED`` (the editor
    draws its first, so that an export reproduces with the command)."""
    return jax.random.fold_in(jax.random.key(seed), sample)


def run_inbetween(args: InbetweenCommand, *, say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run ``bezmotion inbetween`` (see the module docstring); returns its summary.

    Args:
      args: the parsed options.
      say: where progress goes (default: stderr, unless ``--no-progress``).
    Raises:
      ValueError: a bad argument, before anything is written.
    """
    warn = say or _stderr  # warnings and missed handles are results: --no-progress keeps them
    say = say or ((lambda _: None) if args.no_progress else _stderr)
    started = time.perf_counter()
    p = plan(args)  # no progress line before it: a bad argument's error is the only output
    character = p.recognised.character
    n = len(p.outputs)
    windows = len(p.keys) - 1
    frames = p.frames
    say(
        f"{p.label}: {character.name} ({character.num_joints} joints), BMM {p.models['bmm']}, IK {p.ik}"
        + (f" (learned IK {p.models['ik']})" if p.models["ik"] is not None else "") + f", {len(p.handle_records)} handle(s), "
        f"{n} sample(s) of {frames} frames" + (f" ({windows} windows, one chain)" if windows > 1 else "") + f", {args.steps} DDIM steps"
        + (", transferred from the BMM's skeleton" if p.transferred else "")
    )
    # The handles as written, all in the in-between's frames (a chain's too), for their reports.
    targets = records_as_handles(p.handle_records)
    conflict = np.asarray(conflicting_handles(targets, p.reach))
    warnings = handle_conflicts(p.handle_records, conflict, p.reach)
    for warning in [*p.warnings, *warnings]:
        warn(f"warning: {warning}")
    export = dict(fps=p.start_motion.nominal_fps, channels=None if args.channels == "default" else p.start_motion.channels, template=p.start_motion)
    model = Inbetweener(p.bmm, p.ik_fn, p.ik_params, character, p.transfer)
    keys = jax.tree.map(lambda *x: jnp.stack(x), *p.keys)
    options = InbetweenOptions(steps=args.steps, foot_lock=args.foot_lock, key_orientations=not args.key_positions_only)
    samples, written = [], []
    for k in range(n):
        t0 = time.perf_counter()
        say(f"sample {k + 1}/{n}" + (" (compiling first, about a minute on a CPU) …" if k == 0 else " …"))
        result = inbetween_at(model, keys, p.key_times, p.handles, key=sample_key(args.seed, k), options=options, key_velocity=p.key_velocity)
        curves = result.curves  # one curve through every key (C¹ there)
        seconds = time.perf_counter() - t0
        motion = pose_to_bvh(character, result.pose, **export)
        files = ResultFiles(
            character, motion, curves, p.bmm.config.stride, tuple(p.handle_records), p.reference,
            f"{p.label}, sample {k}" if n > 1 else p.label, p.key_times, p.clip_frame,
            bvh_fps=p.bvh_fps, layout=result.layout,
        )  # fmt: skip
        _, pos = pose_fk(character, result.pose)
        pos = np.asarray(pos)
        errors = [
            float(np.linalg.norm(pos[h["frame"], character.characteristic[CHARACTERISTIC_JOINTS.index(h["joint"])]] - np.asarray(h["position"])))
            for h in p.handle_records
        ]
        entry: dict[str, Any] = {
            "sample": k, "seconds": seconds, "handle_errors_cm": errors,
            # Where the body jumps or leaves its curves (the demo reports the same).
            "largest_turn_deg": largest_turn(character, result.pose.quat_local),
            "curve_error_max_cm": curve_miss(pos[:, np.asarray(character.characteristic)], result.positions),
            "files": {},
        }  # fmt: skip
        entry["handle_misses"] = handle_misses(p.handle_records, errors, np.asarray(beyond_reach(jnp.asarray(pos), targets, p.reach)), conflict.any(axis=-1))
        samples.append(entry)
        written.append((files, result.pose))
    summary = {
        "keys": p.label,
        "character": character.name,
        "joints": character.num_joints,
        "frames": frames,
        "windows": windows,
        "gap": p.gap,
        "key_frames": list(p.key_times),
        "fps": p.start_motion.nominal_fps,
        "clip_fps": p.clip_fps,
        "bvh_fps": p.bvh_fps,
        "ik": p.ik,
        "models": p.models,
        "steps": args.steps,
        "foot_lock": args.foot_lock,
        "exact": exact_settings(args.exact, "--exact"),
        "seed": args.seed,
        "transfer": p.transferred,
        "facing": args.facing,
        "clip_units": {"units": p.clip_frame.units, "up": p.clip_frame.up},  # the BVH's; the rest here is in cm, Y up
        "handles": p.handle_records,
        "input_warnings": list(p.warnings),
        "handle_warnings": warnings,
        "samples": samples,
    }
    write_outputs(p, written, summary, started=started, say=say)
    for entry in samples:
        errors, misses = entry["handle_errors_cm"], entry["handle_misses"]
        worst = (
            "" if not errors
            else f", handles hit within {max(errors):.2g} cm" if not misses
            else f", {len(misses)} of {len(errors)} handle(s) missed, by up to {max(errors):.1f} cm"
        )  # fmt: skip
        print(f"sample {entry['sample']}: {', '.join(entry['files'].values())}{worst} ({entry['seconds']:.1f} s)")
        for line in misses:
            warn(line)
    note = p.existing.note(p.out_dir)
    if note is not None:
        warn(f"note: {note}")
    say(f"done in {summary['total_s']:.1f} s")
    return summary


def write_outputs(
    p: Plan, results: Sequence[tuple[ResultFiles, Pose]], summary: dict[str, Any], *, started: float, say: Callable[[str], None]
) -> None:
    """Write every sample's files (``results``: per sample, the files and the pose they show),
    and with ``--out FOLDER`` the summary, as one set (:func:`~bezmotion._src.output_sets.output_set`):
    they replace the earlier ones all together, and the earlier set's files that the new one
    lacks are removed. Fills each of ``summary["samples"]`` in with its files and
    ``bvh_fk_error_cm``, and ``summary["total_s"]``: seconds since ``started`` (``time.perf_counter``)."""
    every = round(p.bvh_fps / TRAINED_FPS)
    last = SUMMARY if p.folder is not None else None
    with output_set(p.out_dir, p.set_name, remove=p.existing.stale, last=last) as staging:
        for (files, pose), outputs, entry in zip(results, p.outputs, summary["samples"], strict=True):
            for suffix, path in outputs.items():
                say(f"writing {path}")
                write_result(staging / path.name, files)
                entry["files"][suffix[1:]] = str(path)
                if suffix == ".bvh":
                    entry["bvh_fk_error_cm"] = bvh_fk_error_cm(staging / path.name, files.character, pose, p.clip_frame, every=every)
        summary["total_s"] = time.perf_counter() - started
        if last is not None:
            atomic_write_text(staging / last, json.dumps(summary, indent=2) + "\n")
