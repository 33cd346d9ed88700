"""What a BMM does with keys that ask for no motion, and where it learned it.

    python experiments/still_keys.py --clip MY_CLIP.bvh --frame 2411 --out results/still_keys.json
    python experiments/still_keys.py --clip MY_CLIP.bvh --frame 2411 --model FOLDER --trained-on bandai_namco --out …

1. **The corpus.** Of Bandai-Namco's training takes (every ``--every``-th file), the 31-frame
   windows (every 10 frames) whose start and end poses agree within 5 cm at every one of the six
   joints, counted by content, and how many of those raise a hand more than 30 cm between them.
2. **The model.** Frame ``--frame`` of ``--clip`` held still for 31 frames, in-betweened by
   ``bezmotion inbetween``'s plan (the clip read as the command reads it: its skeleton, units,
   facing and the transfer), the curves alone, for ``--seeds`` seeds: each of the six joints'
   largest distance from the held pose (cm) and largest turn from it (degrees).
"""

from __future__ import annotations

import collections
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, SKELETON_MAPS
from bezmotion.evaluation import skeleton_zoo as zoo
from bezmotion.geometry.rotations import quat_angle, quat_from_rot6d
from bezmotion.cli.plan import InbetweenCommand, plan
from bezmotion._src.io import write_results
from bezmotion._src.options import option, options, parse_options
from bezmotion.pipeline.inbetweening import InbetweenOptions, curves_traced, window_handles
from bezmotion.pipeline.transfer import Transfer


@options
class Options:
    out: str = option(help="JSON results (a Markdown report beside it)")
    clip: str = option(help="a BVH clip of any skeleton")
    frame: int = option(0, help="the frame of --clip held still")
    model: str | None = option(None, help="the BMM (default: the command's)")
    trained_on: str | None = option(None, help="the skeleton --model was trained on (a profile name)")
    seeds: int = option(4, help="sampler seeds")
    bandai_namco: str | None = option(None, help="folder of Bandai-Namco's BVH files (default: skip the corpus count)")
    every: int = option(3, help="count every N-th training take")


def corpus_still_windows(folder: Path, every: int) -> dict[str, dict[str, int]]:
    """Per content: ``{"windows", "still_keys", "hand_raised"}`` (see the module docstring)."""
    names = [SKELETON_MAPS["bandai_namco"][role] for role in CHARACTERISTIC_JOINTS]
    counts: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    files = [f for f in sorted(folder.glob("*.bvh")) if int(f.stem.rsplit("_", 1)[1]) % 10 != 0]  # training takes
    for path in files[::every]:
        motion = read_bvh(path)
        pos = zoo.world_positions(motion)[:, [motion.skeleton.names.index(n) for n in names]]
        content = path.stem.split("dataset-2_")[1].rsplit("_", 2)[0]
        for s in range(0, len(pos) - 31, 10):
            counts[content]["windows"] += 1
            if np.linalg.norm(pos[s] - pos[s + 30], axis=-1).max() < 5.0:
                counts[content]["still_keys"] += 1
                counts[content]["hand_raised"] += int((pos[s : s + 31, 2:4, 1] - pos[s, 2:4, 1]).max() > 30.0)
    return {c: dict(v) for c, v in sorted(counts.items())}


def still_curves(args: Options) -> dict[str, list[float]]:
    """The held pose's curves, per seed: each joint's largest distance (cm) and turn (°) from it."""
    clip = read_bvh(args.clip)
    with tempfile.TemporaryDirectory() as tmp:
        held = Path(tmp) / "still.bvh"
        write_bvh(held, zoo.still(clip, args.frame, round(31 * clip.nominal_fps / 30.0)), precision=9)
        extra = ["--model", args.model] if args.model else []
        extra += ["--trained-on", args.trained_on] if args.trained_on else []
        p = plan(parse_options(InbetweenCommand, [str(held), "--frames", "0", str(round(30 * clip.nominal_fps / 30.0)), "--out", f"{tmp}/x.bvh", *extra]))
    keys = jax.tree.map(lambda *x: jnp.stack(x), *p.keys)
    transfer = p.transfer if p.transfer is not None else Transfer.identity()
    handles = window_handles(p.handles, 1, p.bmm.config.num_frames - 1)
    moved, turned = [], []
    for seed in range(args.seeds):
        w = curves_traced(p.bmm, p.recognised.character, keys, handles, transfer, jax.random.key(seed), InbetweenOptions(foot_lock=True))
        pos, quat = np.asarray(w.positions[0]), quat_from_rot6d(w.rot6d[0])
        moved.append(np.linalg.norm(pos - pos[:1], axis=-1).max(0).tolist())
        turned.append(np.degrees(np.asarray(quat_angle(quat, quat[:1]))).max(0).tolist())
    return {"moved_cm": moved, "turned_deg": turned}


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    results: dict = {"clip": args.clip, "frame": args.frame, "model": args.model or "the command's"}
    if args.bandai_namco:
        results["corpus"] = corpus_still_windows(Path(args.bandai_namco), args.every)
    results["curves"] = still_curves(args)
    moved, turned = np.asarray(results["curves"]["moved_cm"]), np.asarray(results["curves"]["turned_deg"])
    lines = [
        f"Frame {args.frame} of {args.clip} held still, {args.seeds} seeds (joints: {', '.join(CHARACTERISTIC_JOINTS)}):",
        "",
        f"- largest move per joint (cm): {np.round(moved.max(0), 1).tolist()}",
        f"- largest turn per joint (°): {np.round(turned.max(0), 1).tolist()}",
    ]
    if "corpus" in results:
        lines += ["", "| content | windows | keys within 5 cm | of which a hand rises > 30 cm |", "|---|---|---|---|"]
        lines += [f"| {c} | {v['windows']} | {v.get('still_keys', 0)} | {v.get('hand_raised', 0)} |" for c, v in results["corpus"].items()]
    write_results(args.out, results, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return results


if __name__ == "__main__":
    main()
