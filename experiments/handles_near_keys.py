"""How far the curves swing for a handle a few frames from a key.

A handle ``OFFSET`` (cm, default 20 up) off the straight line, ``d`` frames after a key, asks
the joint to cover that much in ``d`` frames. Where the tangent at that key is held (a key's
given velocity, ``--key-velocities``; a chain's shared key), the projection onto the handle
can move only the next control point, whose weight one frame from the key is 0.07, and the
curve swings far out. For each distance this
samples the bundled clip's in-between (seed 0, bundled models, foot lock) with and without
key velocities, and a chain of two windows through the clip played there and back with the
handle after (and before) its shared key, and reports the joint's largest distance from its
curve without the handle and its fastest frame-to-frame speed::

    python experiments/handles_near_keys.py --out results/handles_near_keys.json
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.cli.plan import InbetweenCommand, plan
from bezmotion._src.io import atomic_write_text
from bezmotion._src.options import option, options, parse_options
from bezmotion.pipeline import InbetweenOptions, Inbetweener, inbetween


@options
class Options:
    joint: str = option("right_hand", help="the handle's joint")
    offset: str = option("+0,20,0", help="the handle's offset from the straight line (cm)")
    frames: tuple[int, ...] = option((1, 2, 3, 4, 5, 8, 12), help="frames after the start key (window) / the shared key (chain)")
    out: Path | None = option(None, help="a JSON file for the table")


def curve(argv: list[str]) -> np.ndarray:
    """The dense curve ``(frames, 6, 3)`` of ``bezmotion inbetween ARGV``'s first sample (IK skipped: the rig)."""
    p = plan(parse_options(InbetweenCommand, [*argv, "--ik", "rig"]))
    model = Inbetweener(p.bmm, p.ik_fn, p.ik_params, p.recognised.character, p.transfer)
    keys = jax.tree.map(lambda *x: jnp.stack(x), *p.keys)
    result = inbetween(
        model, keys, p.handles, key=jax.random.fold_in(jax.random.key(0), 0), options=InbetweenOptions(foot_lock=True), key_velocity=p.key_velocity
    )
    return np.asarray(result.positions)


def swing(keys: list[str], handle_frames: list[int], joint: str, offset: str) -> list[dict]:
    j = CHARACTERISTIC_JOINTS.index(joint)
    without = curve(keys)[:, j]
    rows = []
    for frame in handle_frames:
        path = curve([*keys, "--handle", f"{joint}@{frame}={offset}"])[:, j]
        rows.append({
            "frame": frame,
            "largest_move_cm": float(np.linalg.norm(path - without, axis=-1).max()),
            "fastest_cm_per_frame": float(np.linalg.norm(np.diff(path, axis=0), axis=-1).max()),
        })  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    clip = str(DEMO_CLIP)
    table = {
        "window": swing([clip, "--frames", "3", "33"], list(args.frames), args.joint, args.offset),
        "window_key_velocities": swing([clip, "--frames", "3", "33", "--key-velocities"], list(args.frames), args.joint, args.offset),
    }
    with tempfile.TemporaryDirectory() as folder:  # the clip there and back: room for keys 0, 30, 60
        motion = read_bvh(DEMO_CLIP)
        there_and_back = np.r_[np.arange(40), np.arange(38, -1, -1)]
        long = Path(folder) / "there_and_back.bvh"
        write_bvh(long, dataclasses.replace(motion, quat_local=motion.quat_local[there_and_back], pos_local=motion.pos_local[there_and_back]))
        around = sorted({30 + f for f in args.frames} | {30 - f for f in args.frames})
        table["chain"] = swing([str(long), "--frames", "0", "30", "60"], around, args.joint, args.offset)
    for name, rows in table.items():
        print(name)
        for r in rows:
            print(f"  handle at {r['frame']:2d}: moves the curve up to {r['largest_move_cm']:6.1f} cm, fastest {r['fastest_cm_per_frame']:5.1f} cm/frame")
    if args.out is not None:
        atomic_write_text(args.out, json.dumps(table, indent=1) + "\n")
    return table


if __name__ == "__main__":
    main()
