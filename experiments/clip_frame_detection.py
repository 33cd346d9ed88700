"""How often ``bezmotion inbetween`` tells a clip's units and up axis right.

Every ``--every``-th BVH file of the LaFAN1 subset and of Bandai-Namco (read from their
archives under the data folder), written in each of ``--frames`` conventions (cm/Y, m/Z, mm/Z
by default: :class:`~bezmotion.data.clip_frame.ClipFrame`), and told back by
:func:`~bezmotion.data.clip_frame.detect_clip_frame`. Prints and writes (``--out``) the count
right, wrong and refused per corpus and convention, and each file not told right::

    python experiments/clip_frame_detection.py --every 10 --out results/clip_frame_detection.json
"""

from __future__ import annotations

import json
import tarfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

from bezmotion.data.bvh import BvhMotion, parse_bvh
from bezmotion.data.clip_frame import ClipFrame, detect_clip_frame
from bezmotion.data.sources import default_source
from bezmotion.ik.protocol import Character
from bezmotion._src.io import atomic_write_text
from bezmotion._src.options import option, options, parse_options

CORPORA = ("lafan1", "bandai_namco")


@options
class Options:
    every: int = option(10, help="every N-th BVH file of each corpus (default 10)")
    frames: tuple[str, ...] = option(("cm/y", "m/z", "mm/z"), help="conventions UNITS/UP to write the clips in")
    corpora: tuple[str, ...] = option(CORPORA, choices=CORPORA, help="the corpora (default: both)")
    out: Path | None = option(None, help="a JSON file for the counts")


def clips(corpus: str, every: int) -> Iterator[tuple[str, BvhMotion]]:
    """``(name, motion)`` of every ``every``-th BVH file of the corpus's archive, in name order."""
    source = default_source(corpus)
    if source.suffix == ".zip":
        with zipfile.ZipFile(source) as archive:
            names = sorted(n for n in archive.namelist() if n.endswith(".bvh"))[::every]
            for name in names:
                yield name, parse_bvh(archive.read(name).decode(), f"{source}:{name}")
    else:
        with tarfile.open(source) as archive:
            members = sorted((m for m in archive.getmembers() if m.name.endswith(".bvh")), key=lambda m: m.name)[::every]
            for member in members:
                yield member.name, parse_bvh(archive.extractfile(member).read().decode(), f"{source}:{member.name}")


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    if args.every < 1:
        raise SystemExit(f"clip_frame_detection.py: error: --every {args.every}: must be at least 1")
    try:
        frames = [ClipFrame(*f.split("/")) for f in args.frames]
    except (TypeError, ValueError) as error:
        raise SystemExit(f"clip_frame_detection.py: error: --frames {' '.join(args.frames)}: {error} (write UNITS/UP, e.g. m/z)") from None
    counts: dict[str, dict[str, dict[str, int]]] = {}
    misses = []
    for corpus in args.corpora:
        per = counts.setdefault(corpus, {f"{f.units}/{f.up}": {"right": 0, "wrong": 0, "refused": 0} for f in frames})
        for name, motion in clips(corpus, args.every):
            hips, head, _, _, left_foot, right_foot = Character.from_bvh(motion, corpus).characteristic
            for frame in frames:
                key = f"{frame.units}/{frame.up}"
                try:
                    told = detect_clip_frame(frame.from_ours(motion), hips, head, (left_foot, right_foot))
                except ValueError as error:
                    per[key]["refused"] += 1
                    misses.append({"corpus": corpus, "file": name, "frame": key, "refused": str(error)})
                    continue
                right = told == frame
                per[key]["right" if right else "wrong"] += 1
                if not right:
                    misses.append({"corpus": corpus, "file": name, "frame": key, "told": f"{told.units}/{told.up}"})
        for key, c in per.items():
            print(f"{corpus} {key}: {c['right']} right, {c['wrong']} wrong, {c['refused']} refused")
    for miss in misses:
        print(miss)
    report = {"every": args.every, "counts": counts, "misses": misses}
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, json.dumps(report, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main()
