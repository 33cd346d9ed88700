"""The ``bezmotion`` command line.

    bezmotion demo [--out DIR] [--gap N]    in-between the bundled clip, write BVH files

Paper tables and figures are reproduced by the scripts in ``experiments/``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from bezmotion._io import atomic_write_text
from bezmotion.assets import DEMO_CLIP, DEMO_CLIP_ATTRIBUTION
from bezmotion.data.bvh import BvhMotion, read_bvh, write_bvh
from bezmotion.geometry.skeleton import forward_kinematics
from bezmotion.models.baselines import interpolation, transition_weights, zero_velocity

N_PAST = 10


def _inbetween_clip(motion: BvhMotion, gap: int, method: str) -> BvhMotion:
    """Replace frames ``10 … 9+gap`` of ``motion`` by a baseline transition.

    Every joint's local translation is lerped (or held), so skeletons whose translation
    lives below the root (Bandai-Namco animates ``Hips``) are handled like LaFAN1.
    """
    last, target = N_PAST - 1, N_PAST + gap
    q, p = jnp.asarray(motion.quat_local), jnp.asarray(motion.pos_local)
    if method == "interpolation":
        quat, _ = interpolation(q[last], p[last, 0], q[target], p[target, 0], gap)
        w = transition_weights(gap, p.dtype)[:, None, None]
        pos = p[last] + w * (p[target] - p[last])
    else:
        quat, _ = zero_velocity(q[last], p[last, 0], gap)
        pos = jnp.broadcast_to(p[last], (gap, *p.shape[1:]))
    quat_local = motion.quat_local.copy()
    pos_local = motion.pos_local.copy()
    quat_local[N_PAST:target] = np.asarray(quat)
    pos_local[N_PAST:target] = np.asarray(pos)
    return BvhMotion(motion.skeleton, quat_local, pos_local, motion.channels, motion.frame_time, motion.end_sites)


def _position_error_cm(a: BvhMotion, b: BvhMotion, frames: slice) -> float:
    """Mean per-joint position error (cm) between two motions of the same skeleton."""
    parents = a.skeleton.parents
    _, pa = forward_kinematics(parents, jnp.asarray(a.quat_local[frames]), jnp.asarray(a.pos_local[frames]))
    _, pb = forward_kinematics(parents, jnp.asarray(b.quat_local[frames]), jnp.asarray(b.pos_local[frames]))
    return float(jnp.mean(jnp.linalg.norm(pa - pb, axis=-1)))


def demo(out: Path, gap: int, clip: Path = DEMO_CLIP) -> dict:
    """In-between a gap of the bundled real clip with both baselines; write BVH files and a summary."""
    motion = read_bvh(clip)
    max_gap = motion.num_frames - N_PAST - 1
    if not (1 <= gap <= max_gap):
        raise ValueError(f"--gap must be between 1 and {max_gap} for this {motion.num_frames}-frame clip, got {gap}")
    out.mkdir(parents=True, exist_ok=True)
    summary = {"clip": clip.name, "frames": motion.num_frames, "gap": gap, "joints": motion.skeleton.num_joints}
    transition = slice(N_PAST, N_PAST + gap)
    write_bvh(out / "ground_truth.bvh", motion)
    for method in ("interpolation", "zero_velocity"):
        result = _inbetween_clip(motion, gap, method)
        path = out / f"{method}.bvh"
        write_bvh(path, result)
        reread = read_bvh(path)  # what an animation tool would load
        summary[method] = {
            "file": str(path),
            "mean_joint_error_cm": _position_error_cm(result, motion, transition),
            "bvh_roundtrip_error_cm": _position_error_cm(reread, result, slice(None)),
        }
    summary_path = out / "summary.json"
    atomic_write_text(summary_path, json.dumps(summary, indent=2) + "\n")
    print(f"bezmotion demo: {clip.name} ({motion.num_frames} frames, {motion.skeleton.num_joints} joints)")
    print(f"  frames {N_PAST}..{N_PAST + gap - 1} in-betweened from frames 0..{N_PAST - 1} and {N_PAST + gap}")
    for method in ("interpolation", "zero_velocity"):
        s = summary[method]
        print(f"  {method:14s} mean joint error {s['mean_joint_error_cm']:6.2f} cm -> {s['file']}")
    print(f"  summary: {summary_path}")
    print(f"  data: {DEMO_CLIP_ATTRIBUTION}")
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bezmotion", description="Precise, character-agnostic motion in-betweening.")
    sub = parser.add_subparsers(dest="command", required=True)
    p_demo = sub.add_parser("demo", help="in-between the bundled real clip and write BVH files (no downloads)")
    p_demo.add_argument("--out", type=Path, default=Path("results/demo"), help="output folder (default results/demo)")
    p_demo.add_argument("--gap", type=int, default=20, help="number of frames to in-between (default 20)")
    args = parser.parse_args(argv)

    try:
        if args.command == "demo":
            demo(args.out, args.gap)
    except (ValueError, FileNotFoundError) as e:
        print(f"bezmotion: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
