"""Every skeleton as itself: one clip written many ways, in-betweened by ``bezmotion inbetween``.

    python experiments/skeleton_zoo.py --out results/skeleton_zoo.json
    python experiments/skeleton_zoo.py --clips bundled --variants axes_random unit_cmu --seeds 2 --out quick.json

Each clip is first renamed to a skeleton no preset knows (every joint ``ref:<name>``), the
*reference*: it goes the way a user's own character goes (six joints read off the names,
the bundled Bandai-Namco BMM through a transfer, the rig and the exact solve). Each variant
re-expresses the reference (:mod:`bezmotion.evaluation.skeleton_zoo`): other joint names
(Daz lower-case, Unreal, Blender, SMPL), another rest pose or other bone axes, added joints
(fingers, toes, a jaw, twist joints), a spine joint fewer, another length unit (m, mm, in,
CMU's ~5.6 cm), Z up, the whole clip turned about the vertical, and 24, 25, 60 or 120 fps.
Per variant, with the same keys and seed:

- ``invariance_max_cm``: the largest distance, over every frame and every joint of the
  reference, between the variant's in-between brought back into the reference's
  conventions and the reference's own in-between (the variant's unit, up axis and turn
  undone, its frames at 30 fps);
- ``still_max_cm``: a frame of the clip held still for the whole chain, in-betweened with no
  handle, over ``--seeds`` seeds: the largest distance of any joint from the held pose;
- ``no_handle_ratio``: the six joints' mean distance to the clip's real frames, in-between
  over interpolation (the six joints' positions linear between the keys).

Keys: ``--keys`` frames of each clip, 30 frames apart at 30 fps (a chain); the same instants
in a variant at another rate. Writes JSON (``{"variants": {name: {...}}, "clips": [...]}``)
and a Markdown table beside it.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import BvhMotion, read_bvh, write_bvh
from bezmotion.data.resample import TRAINED_FPS, resample_motion
from bezmotion.evaluation import skeleton_zoo as zoo
from bezmotion.geometry.rotations import quat_conjugate
from bezmotion.geometry.skeleton import forward_kinematics
from bezmotion.cli.inbetween import InbetweenCommand, run_inbetween
from bezmotion._src.io import write_results
from bezmotion.ik.rig import derive_rig_spec
from bezmotion._src.options import option, options, parse_options
from bezmotion.pipeline.authoring import motion_window, recognise_character

PREFIX = "ref:"  # the reference's namespace: no preset's names, read as a user's own skeleton


class Variant(NamedTuple):
    """One way of writing the reference clip.

    Attributes:
      make: the variant of a reference clip (cm, Y up, 30 fps).
      rename: a reference joint's name → the variant's (None: the joint is gone).
      cm_per_unit, up, yaw_deg, fps: the variant's length unit, up axis, turn about the
        vertical and frame rate, undone to compare it with the reference.
      same_skeleton: a re-expression of the same skeleton (False: a joint fewer, which an IK
        poses otherwise).
    """

    make: Callable[[BvhMotion], BvhMotion]
    rename: Callable[[str], str | None] = lambda name: name
    cm_per_unit: float = 1.0
    up: str = "y"
    yaw_deg: float = 0.0
    fps: float = TRAINED_FPS
    same_skeleton: bool = True


def roles(motion: BvhMotion) -> dict[str, str]:
    """A generic part name per joint of a clip its joint names tell (``"spine"``, ``"l_hand"``, …),
    from the six joints read off its names and the rig's chains read off its hierarchy."""
    recognised = recognise_character(motion)
    spec = derive_rig_spec(recognised.character)
    names, parents = motion.skeleton.names, motion.skeleton.parents
    part = {spec.spine[0]: "hips", spec.spine[-1]: "head", spec.spine[-2]: "neck"}
    for k, name in enumerate(spec.spine[1:-2]):
        part[name] = f"spine{k + 1}"
    for side, arm, leg in (("l", spec.left_arm, spec.left_leg), ("r", spec.right_arm, spec.right_leg)):
        for what, name in zip(("upper_arm", "forearm", "hand"), arm):
            part[name] = f"{side}_{what}"
        for what, name in zip(("thigh", "shin", "foot"), leg):
            part[name] = f"{side}_{what}"
        collar = names[parents[names.index(arm[0])]]
        if collar not in part:
            part[collar] = f"{side}_collar"
        toes = [n for n, p in zip(names, parents) if p >= 0 and names[p] == leg[2]]
        if toes:
            part[toes[0]] = f"{side}_toe"
    return part


def _convention(table: dict[str, str], spine: Callable[[int], str]) -> Callable[[str], str]:
    def name(part: str) -> str:
        if part.startswith("spine"):
            return spine(int(part[5:]))
        side, _, what = part.partition("_")
        return table[what].format(s=side, S=side.upper()) if side in ("l", "r") else table[part]

    return name


CONVENTIONS = {
    "daz_lower": _convention(
        {"hips": "hip", "neck": "neck", "head": "head", "collar": "{s}collar", "upper_arm": "{s}shldr", "forearm": "{s}forearm",
         "hand": "{s}hand", "thigh": "{s}thigh", "shin": "{s}shin", "foot": "{s}foot", "toe": "{s}toe"},
        lambda k: "abdomen" if k == 1 else f"chest{k - 1}",
    ),
    "unreal": _convention(
        {"hips": "pelvis", "neck": "neck_01", "head": "head", "collar": "clavicle_{s}", "upper_arm": "upperarm_{s}",
         "forearm": "lowerarm_{s}", "hand": "hand_{s}", "thigh": "thigh_{s}", "shin": "calf_{s}", "foot": "foot_{s}", "toe": "ball_{s}"},
        lambda k: f"spine_{k:02d}",
    ),
    "blender": _convention(
        {"hips": "hips", "neck": "neck", "head": "head", "collar": "shoulder.{S}", "upper_arm": "upper_arm.{S}",
         "forearm": "forearm.{S}", "hand": "hand.{S}", "thigh": "thigh.{S}", "shin": "shin.{S}", "foot": "foot.{S}", "toe": "toe.{S}"},
        lambda k: "spine" if k == 1 else f"spine.{k - 1:03d}",
    ),
    "smpl": _convention(
        {"hips": "Pelvis", "neck": "Neck", "head": "Head", "collar": "{S}_Collar", "upper_arm": "{S}_Shoulder", "forearm": "{S}_Elbow",
         "hand": "{S}_Wrist", "thigh": "{S}_Hip", "shin": "{S}_Knee", "foot": "{S}_Ankle", "toe": "{S}_Foot"},
        lambda k: f"Spine{k}",
    ),
}  # fmt: skip
"""Joint naming conventions a user's file may follow, by generic part (:func:`roles`)."""


def renaming(reference: BvhMotion, convention: str) -> Callable[[str], str]:
    """Reference joint name → its name in ``convention`` (joints it has no name for keep theirs, as extras)."""
    part = roles(reference)
    named = CONVENTIONS[convention]
    return lambda name: named(part[name]) if name in part else name.removeprefix(PREFIX).replace("_", "") + "_extra"


def _turn_to_rest(motion: BvhMotion) -> np.ndarray:
    """Per joint, the inverse of its world orientation in the clip's first frame: a rest pose that is that frame."""
    with jax.enable_x64(True):
        quat, _ = forward_kinematics(motion.skeleton.parents, jnp.asarray(motion.quat_local[0]), jnp.asarray(motion.pos_local[0]))
        return np.asarray(quat_conjugate(quat))


def _extra_joints(reference: BvhMotion) -> BvhMotion:
    part = {v: k for k, v in roles(reference).items()}
    leaves = {part[f"{s}_hand"]: tuple(f"{part[f'{s}_hand']}_Index{k}" for k in (1, 2, 3)) for s in "lr"}
    leaves |= {part[f"{s}_foot"]: (f"{part[f'{s}_foot']}_Toe_End",) for s in "lr"} | {part["head"]: (f"{part['head']}_Jaw",)}
    added = zoo.with_leaf_joints(reference, leaves, 2.5)
    return zoo.with_twist_joints(added, {part[f"{s}_hand"]: part[f"{s}_forearm"] + "_Twist" for s in "lr"})


def _daz_everything(reference: BvhMotion, rename: Callable[[str], str]) -> BvhMotion:
    """Daz lower-case names, fingers, toes, a jaw and twist joints, random bone axes and CMU's unit at once."""
    extended = zoo.renamed(_extra_joints(reference), rename)
    return zoo.scaled(zoo.reorient(extended, zoo.random_axes(extended, 1)), 1 / 5.6)


def variants(reference: BvhMotion) -> dict[str, Variant]:
    """The zoo: every way of writing ``reference`` this experiment checks."""
    spine = [n for n, p in roles(reference).items() if p.startswith("spine")]
    named = {c: renaming(reference, c) for c in CONVENTIONS}
    upper_arms = {p: n for n, p in roles(reference).items() if p.endswith("upper_arm")}
    out = {f"names_{c}": Variant(lambda m, f=f: zoo.renamed(m, f), f) for c, f in named.items()}
    out |= {
        "rest_first_frame": Variant(lambda m: zoo.reorient(m, _turn_to_rest(m))),
        "rest_a_pose": Variant(lambda m: zoo.a_pose(m, {"left": upper_arms["l_upper_arm"], "right": upper_arms["r_upper_arm"]})),
        "axes_random": Variant(lambda m: zoo.reorient(m, zoo.random_axes(m, 0))),
        "joints_extra": Variant(_extra_joints),
        "unit_m": Variant(lambda m: zoo.scaled(m, 0.01), cm_per_unit=100.0),
        "unit_mm": Variant(lambda m: zoo.scaled(m, 10.0), cm_per_unit=0.1),
        "unit_in": Variant(lambda m: zoo.scaled(m, 1 / 2.54), cm_per_unit=2.54),
        "unit_cmu": Variant(lambda m: zoo.scaled(m, 1 / 5.6), cm_per_unit=5.6),
        "z_up": Variant(zoo.z_up, up="z"),
        "yaw_90": Variant(lambda m: zoo.yawed(m, 90.0), yaw_deg=90.0),
        "yaw_180": Variant(lambda m: zoo.yawed(m, 180.0), yaw_deg=180.0),
        "daz_everything": Variant(lambda m: _daz_everything(m, named["daz_lower"]), named["daz_lower"], cm_per_unit=5.6),
    }  # fmt: skip
    if len(spine) > 1:
        out["joints_fewer_spine"] = Variant(lambda m: zoo.without_joint(m, spine[0]), lambda n: None if n == spine[0] else n, same_skeleton=False)
    for fps in (24.0, 25.0, 60.0, 120.0):
        out[f"fps_{fps:g}"] = Variant(lambda m, fps=fps: resample_motion(m, fps, 0)[0], fps=fps)
    return out


def in_reference_frame(variant: Variant, motion: BvhMotion, reference_names: tuple[str, ...]) -> np.ndarray:
    """``(frames, joints, 3)`` the reference's joints of a variant's in-between, in cm, Y up,
    its turn undone, at 30 fps (NaN where the variant has no such joint)."""
    pos = zoo.world_positions(motion) * variant.cm_per_unit
    if variant.up == "z":
        pos = np.stack([pos[..., 0], pos[..., 2], -pos[..., 1]], axis=-1)
    if variant.yaw_deg:
        a = np.radians(-variant.yaw_deg)
        x, z = pos[..., 0], pos[..., 2]
        pos = np.stack([np.cos(a) * x + np.sin(a) * z, pos[..., 1], -np.sin(a) * x + np.cos(a) * z], axis=-1)
    step = motion.nominal_fps / TRAINED_FPS
    if step > 1:
        pos = pos[:: int(round(step))]
    names = motion.skeleton.names
    out = np.full((pos.shape[0], len(reference_names), 3), np.nan)
    for j, name in enumerate(reference_names):
        theirs = variant.rename(name)
        if theirs is not None and theirs in names:
            out[:, j] = pos[:, names.index(theirs)]
    return out


def run(path: Path, frames: list[int], seed: int, out: Path, extra: tuple[str, ...] = ()) -> BvhMotion:
    """``bezmotion inbetween PATH --frames … --seed SEED --out OUT`` (a BVH file), read back."""
    argv = [str(path), "--frames", *map(str, frames), "--seed", str(seed), "--out", str(out), "--no-progress", *extra]
    run_inbetween(parse_options(InbetweenCommand, argv))
    return read_bvh(out)


def six_joint_ratio(clip: BvhMotion, frames: list[int], result: np.ndarray) -> float:
    """The six joints' mean distance to the clip's frames ``frames[0] … frames[-1]``: the in-between's
    (``result``, reference joints) over interpolation's (linear between the keys)."""
    six = list(recognise_character(clip).character.characteristic)
    truth = zoo.world_positions(clip)[frames[0] : frames[-1] + 1][:, six]
    keys = truth[np.asarray(frames) - frames[0]]
    t = np.arange(frames[-1] - frames[0] + 1)
    interp = np.stack([np.stack([np.interp(t, np.asarray(frames) - frames[0], keys[:, j, a]) for a in range(3)], -1) for j in range(len(six))], 1)
    ours = np.linalg.norm(result[:, six] - truth, axis=-1).mean()
    theirs = np.linalg.norm(interp - truth, axis=-1).mean()
    return float(ours / max(theirs, 1e-9))


def measure_clip(clip: BvhMotion, frames: list[int], names: list[str], seeds: int, folder: Path) -> dict[str, dict]:
    """Every zoo variant of one clip (``frames``: its keys at 30 fps): see the module docstring."""
    reference = zoo.renamed(clip, lambda n: PREFIX + n)
    still = zoo.still(reference, frames[0], frames[-1] + 1)
    ref_names = reference.skeleton.names
    write_bvh(folder / "reference.bvh", reference)
    write_bvh(folder / "still.bvh", still)
    ours = zoo.world_positions(run(folder / "reference.bvh", frames, 0, folder / "reference_out.bvh"))
    all_variants = variants(reference)
    results = {}
    for name in names:
        variant = all_variants[name]
        at = [round(f * variant.fps / TRAINED_FPS) for f in frames]
        write_bvh(folder / f"{name}.bvh", variant.make(reference), precision=9)
        theirs = in_reference_frame(variant, run(folder / f"{name}.bvh", at, 0, folder / f"{name}_out.bvh"), ref_names)
        gap = np.linalg.norm(theirs - ours, axis=-1)
        write_bvh(folder / f"{name}_still.bvh", variant.make(still), precision=9)
        held = zoo.world_positions(still)[0]
        moved = []
        for seed in range(seeds):
            out = in_reference_frame(variant, run(folder / f"{name}_still.bvh", at, seed, folder / f"{name}_still_out.bvh"), ref_names)
            moved.append(float(np.nanmax(np.linalg.norm(out - held, axis=-1))))
        results[name] = {
            "invariance_max_cm": float(np.nanmax(gap)),
            "invariance_mean_cm": float(np.nanmean(gap)),
            "still_max_cm": max(moved),
            "still_per_seed_cm": moved,
            "no_handle_ratio": six_joint_ratio(reference, frames, theirs),
            "same_skeleton": variant.same_skeleton,
        }
        print(f"{name}: {results[name]}", flush=True)
    return results


@options
class Options:
    out: str = option(help="JSON results (a Markdown table is written beside it)")
    clips: tuple[str, ...] = option(("bundled",), help="BVH clips (bundled: the demo clip)")
    first: int = option(0, help="the frame of each clip the keys count from (the clip is cut to first … first + the last key)")
    keys: tuple[int, ...] = option((0, 30), help="key frames at 30 fps (30 apart), counted from --first")
    variants: tuple[str, ...] = option((), help="variants to run (default: all)")
    seeds: int = option(4, help="seeds of the still-clip test")


def report(results: dict) -> str:
    lines = [
        "| variant | invariance max (cm) | still max (cm) | no-handle ratio |",
        "|---|---|---|---|",
    ]
    for name, r in results["variants"].items():
        same = "" if r["same_skeleton"] else " (another skeleton)"
        lines.append(f"| {name}{same} | {r['invariance_max_cm']:.3f} | {r['still_max_cm']:.2f} | {r['no_handle_ratio']:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    clips = [DEMO_CLIP if c == "bundled" else Path(c) for c in args.clips]
    per_clip = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, path in enumerate(clips):
            clip = motion_window(read_bvh(path), args.first, args.keys[-1] + 1)
            names = list(args.variants) or list(variants(zoo.renamed(clip, lambda n: PREFIX + n)))
            folder = Path(tmp) / str(k)
            folder.mkdir()
            per_clip.append(measure_clip(clip, list(args.keys), names, args.seeds, folder))
    merged = {}
    for name in per_clip[0]:
        rows = [c[name] for c in per_clip]
        merged[name] = {
            "invariance_max_cm": max(r["invariance_max_cm"] for r in rows),
            "still_max_cm": max(r["still_max_cm"] for r in rows),
            "no_handle_ratio": float(np.mean([r["no_handle_ratio"] for r in rows])),
            "same_skeleton": rows[0]["same_skeleton"],
        }
    results = {"variants": merged, "clips": [str(c) for c in clips], "first": args.first, "keys": list(args.keys), "per_clip": per_clip}
    write_results(args.out, results, report(results))
    print(report(results))
    return results


if __name__ == "__main__":
    main()
