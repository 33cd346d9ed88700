"""Benchmark: jitted forward kinematics of a 22-joint LaFAN1-topology skeleton.

Times ``Skeleton.fk`` (per-frame local rotations + root position, shared rest offsets)
over many frames in float32 and reports compile time, steady-state time and frames/s.

    python benchmarks/fk.py --frames 1000000 --repeats 5 --out fk.json
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report, time_jitted
from bezmotion.geometry.skeleton import Skeleton
from bezmotion._src.options import option, options, parse_options

# LaFAN1 joint order (Hips, legs, spine/head, arms).
LAFAN1_PARENTS = (-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 12, 11, 14, 15, 16, 11, 18, 19, 20)


@options
class Options:
    frames: int = option(10**6, help="number of frames (default 1e6)")
    repeats: int = option(5, help="timed repeats; the median is reported")
    seed: int = 0
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def make_inputs(frames: int, seed: int = 0) -> tuple[Skeleton, jax.Array, jax.Array]:
    """A LaFAN1-like skeleton (random offsets of bone-like length) and random float32 poses."""
    rng = np.random.default_rng(seed)
    joints = len(LAFAN1_PARENTS)
    offsets = rng.normal(scale=10.0, size=(joints, 3)).astype(np.float32)
    skeleton = Skeleton.from_parents(LAFAN1_PARENTS, [f"joint{j}" for j in range(joints)], offsets)
    quat = rng.normal(size=(frames, joints, 4)).astype(np.float32)
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    root = rng.normal(scale=100.0, size=(frames, 3)).astype(np.float32)
    return skeleton, jnp.asarray(quat), jnp.asarray(root)


def fk_positions_and_rotations(skeleton: Skeleton, quat: jax.Array, root: jax.Array):
    """The benchmarked function: global rotations and positions of every joint."""
    return skeleton.fk(quat, root)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)

    skeleton, quat, root = make_inputs(args.frames, args.seed)
    timing = time_jitted(fk_positions_and_rotations, (skeleton, quat, root), repeats=args.repeats)
    result = {
        "benchmark": "fk",
        "joints": skeleton.num_joints,
        "frames": args.frames,
        "dtype": str(quat.dtype),
        **timing,
        "frames_per_s": args.frames / timing["steady_s"],
        "machine": machine_info(),
    }
    summary = {k: result[k] for k in ("frames", "joints", "lower_s", "compile_s", "first_call_s", "steady_s", "frames_per_s")}
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
