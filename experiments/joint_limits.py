"""Per-joint rotation limits of a corpus' skeleton, for the exact IK (:mod:`bezmotion.ik.exact`; kept in :mod:`bezmotion.ik.joint_limits`).

    python experiments/joint_limits.py --corpus bandai_namco --out bezmotion/assets/models/ik_bandai_namco/joint_limits.json

Measured on the training clips only (the validation windows stay unseen): each joint's
mean local rotation, and the 0.5th–99.5th percentile of each axis of the rotation vector
relative to it, widened by 0.1 rad (:func:`bezmotion.ik.joint_limits.joint_limits_from_motion`).
The file sits beside the learned IK of the same skeleton, which the demo reads it from.
"""

from __future__ import annotations

import numpy as np

from bezmotion.data.corpus import motion_clips
from bezmotion.data.sources import load_corpus
from bezmotion.ik.joint_limits import joint_limits_from_motion
from bezmotion.ik.protocol import Character, pose_from_motion
from bezmotion.geometry.skeleton import Skeleton
from bezmotion._src.options import option, options, parse_options


@options
class Options:
    out: str = option(help="output JSON")
    corpus: str = option("bandai_namco", choices=("bandai_namco", "lafan1"), help="corpus (training split)")
    percentile: float = option(0.5, help="lower percentile per axis (the upper is 100 minus it)")
    margin: float = option(0.1, help="radians added on both sides")


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    corpus = load_corpus(args.corpus, progress=False)
    clips = motion_clips(corpus, "train")
    offsets = np.asarray(clips.pos_local[0])
    character = Character.from_skeleton(Skeleton(clips.parents, clips.joint_names, offsets), args.corpus)
    # The Pose convention: the hips' rotation global, joints above it at identity.
    quat = np.asarray(pose_from_motion(character, clips.quat_local.astype(np.float32), clips.pos_local.astype(np.float32)).quat_local)
    limits = joint_limits_from_motion(character, quat, percentile=args.percentile, margin=args.margin)
    data = limits.to_json(character)
    data["measured_on"] = f"{args.corpus} training clips, {quat.shape[0]} frames; percentile {args.percentile}, margin {args.margin} rad"
    import json
    from pathlib import Path

    Path(args.out).write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    width = np.degrees(np.asarray(limits.upper - limits.lower))
    finite = width < 1e4
    print(f"{args.corpus}: {quat.shape[0]} training frames; median range {np.median(width[finite]):.0f}°, wrote {args.out}")
    return data


if __name__ == "__main__":
    main()
