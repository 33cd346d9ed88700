"""Measure the character profiles used to transfer BMM curves between skeletons (BMM §5.2).

    python experiments/character_profiles.py --out-dir bezmotion/assets/profiles

For LaFAN1 and Bandai-Namco: the height measure (bone lengths hips→head + hips→foot) and
each characteristic joint's mean global orientation relative to the facing, over every
10th training frame. Writes ``<corpus>.json`` (:class:`bezmotion.pipeline.inbetweening.CharacterProfile`).
"""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp

from bezmotion._src.io import atomic_write_text
from bezmotion.data.corpus import motion_clips
from bezmotion.data.sources import load_corpus
from bezmotion.geometry.skeleton import Skeleton
from bezmotion.ik.protocol import Character, pose_from_motion
from bezmotion._src.options import option, options, parse_options
from bezmotion.pipeline import CharacterProfile

SOURCES = ("lafan1", "bandai_namco")


@options
class Options:
    out_dir: str = option(help="folder the profiles are written to")
    corpora: tuple[str, ...] = option(SOURCES, choices=SOURCES, help="corpora to measure (default: all)")


def corpus_profile(corpus: str, every: int = 10) -> tuple[Character, CharacterProfile]:
    """The character (first clip's offsets) and profile of ``corpus``'s training clips."""
    clips = motion_clips(load_corpus(corpus), "train")
    offsets = clips.pos_local[0].copy()
    skeleton = Skeleton.from_parents(clips.parents, clips.joint_names, offsets)
    character = Character.from_skeleton(skeleton, corpus)
    frames = slice(None, None, every)
    poses = pose_from_motion(
        character, jnp.asarray(clips.quat_local[frames], jnp.float32), jnp.asarray(clips.pos_local[frames], jnp.float32)
    )
    return character, CharacterProfile.from_poses(character, poses)


def main(argv: list[str] | None = None) -> None:
    args = parse_options(Options, argv, description=__doc__)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for corpus in args.corpora:
        _, profile = corpus_profile(corpus)
        atomic_write_text(out / f"{corpus}.json", json.dumps({"corpus": corpus, **profile.to_json()}, indent=2) + "\n")
        print(f"{corpus}: height {profile.height:.2f} cm -> {out / f'{corpus}.json'}")


if __name__ == "__main__":
    main()
