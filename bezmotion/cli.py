"""The ``bezmotion`` command line.

    bezmotion demo [--out DIR] [--joint J --frame F --offset X Y Z] [--ik learned|rig]

Paper tables and figures are reproduced by the scripts in ``experiments/``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bezmotion.assets import BUNDLED_BMM, BUNDLED_IK
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.demo import IK_CHOICES, demo


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bezmotion", description="Precise, character-agnostic motion in-betweening.")
    sub = parser.add_subparsers(dest="command", required=True)
    p_demo = sub.add_parser(
        "demo", help="in-between the bundled real clip with the bundled models; write BVH, PNG and a summary (no downloads)"
    )
    p_demo.add_argument("--out", type=Path, default=Path("results/demo"), help="output folder (default results/demo)")
    p_demo.add_argument("--joint", default="right_hand", choices=CHARACTERISTIC_JOINTS, help="the joint the handle moves")
    p_demo.add_argument("--frame", type=int, default=12, help="the handle's frame, a multiple of 6 in 6…24 (default 12)")
    p_demo.add_argument("--offset", type=float, nargs=3, default=(0.0, 25.0, 0.0), metavar=("X", "Y", "Z"),
                        help="how far the handle moves the joint from the mocap (cm; default 0 25 0)")  # fmt: skip
    p_demo.add_argument(
        "--ik", choices=IK_CHOICES, default="refined",
        help="refined: the learned IK then exact two-bone limbs (default); learned: the learned IK alone; rig: analytic, no data",
    )  # fmt: skip
    p_demo.add_argument("--steps", type=int, default=10, help="DDIM steps (default 10)")
    p_demo.add_argument("--seed", type=int, default=0)
    p_demo.add_argument("--bmm", type=Path, default=BUNDLED_BMM, help="a saved BMM (default: the bundled one)")
    p_demo.add_argument("--bmm-corpus", default="bandai_namco", help="the corpus --bmm was trained on: bandai_namco (default) or lafan1 (transferred)")
    p_demo.add_argument("--ik-model", type=Path, default=BUNDLED_IK, help="a saved learned IK (default: the bundled one)")
    args = parser.parse_args(argv)

    try:
        if args.command == "demo":
            demo(
                args.out, joint=args.joint, frame=args.frame, offset=tuple(args.offset), ik=args.ik, steps=args.steps,
                seed=args.seed, bmm_dir=args.bmm, bmm_corpus=args.bmm_corpus, ik_dir=args.ik_model,
            )  # fmt: skip
    except (ValueError, FileNotFoundError) as e:
        print(f"bezmotion: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
