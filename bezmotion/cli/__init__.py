"""The ``bezmotion`` command line.

    bezmotion demo [--out DIR] [--force] [--joint J --frame F --offset X Y Z] [--ik exact|refined|learned|rig] [--exact NAME=VALUE …] [--channels clip]
    bezmotion inbetween CLIP.bvh --frames 0 30 [--handle JOINT@FRAME=X,Y,Z …] [--out out.bvh|out.glb|DIR/] [--force]
    bezmotion inbetween --start A.bvh@F --end B.bvh@G [--handles FILE] [--samples N] [--ik rig] [--mapping MAP.json]
    bezmotion edit CLIP.bvh [--frames 0 30] [--model NAME|PATH] [--out DIR] [--host H] [--port P]   # the browser editor
    bezmotion models [--check | --write-manifest]   # the pretrained models: bundled or not, size, data, licence, retraining

Errors are one line of about 300 characters at most (:func:`~bezmotion._src.messages.one_line`),
``bezmotion: error: …`` naming the argument and its value, with exit status 2; nothing is
written then. A run's output files are replaced all together or not at all; files that
bezmotion did not write are replaced only with ``--force``.

Paper tables and figures are reproduced by the scripts in ``experiments/``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bezmotion.assets.registry import check_manifest, models_table, write_manifest
from bezmotion._src.compilation_cache import use_compilation_cache
from bezmotion._src.messages import one_line
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.cli.demo import demo
from bezmotion.cli.edit import EDIT_HELP, add_edit_arguments, run_edit
from bezmotion.cli.inbetween import InbetweenCommand, run_inbetween
from bezmotion._src.options import add_options, option, options, options_from
from bezmotion.ik.exact import exact_settings
from bezmotion.pipeline.authoring import CHANNEL_CHOICES, EXACT_HELP, FOOT_LOCK_HELP, IK_CHOICES, VERIFY_HELP


@options
class DemoOptions:
    """The ``bezmotion demo`` options."""

    out: Path = option(Path("results/demo"), help="output folder (default results/demo); its other files stay")
    force: bool = option(
        False, help="replace the demo's files in --out where bezmotion did not write them (or they changed since); without it "
        "only its own earlier files are replaced, with a note",
    )  # fmt: skip
    joint: str = option("right_hand", choices=CHARACTERISTIC_JOINTS, help="the joint the handle moves")
    frame: int = option(12, help="the handle's frame, any in 1…29 (default 12)")
    offset: tuple[float, float, float] = option(
        (0.0, 25.0, 0.0), metavar=("X", "Y", "Z"), help="how far the handle moves the joint from the mocap (cm; default 0 25 0)"
    )
    ik: str = option(
        "exact", choices=IK_CHOICES,
        help="exact: the learned IK then a least-squares solve onto all six curves (default); refined: the learned IK then "
        "exact two-bone limbs; learned: the learned IK alone; rig: analytic, no data; exact_rig: the rig then the same solve",
    )  # fmt: skip
    steps: int = option(10, help="DDIM steps (default 10)")
    seed: int = 0
    bmm: str | None = option(
        None, metavar="NAME|PATH", help="the BMM: a pretrained model's name (default bandai_namco; bezmotion models lists them) or a saved BMM's folder"
    )
    bmm_corpus: str | None = option(
        None, help="the corpus --bmm was trained on: bandai_namco or lafan1 (transferred); default: a named model's own, else bandai_namco"
    )
    ik_model: str | None = option(None, metavar="NAME|PATH", help="the learned IK: a pretrained model's name (default bandai_namco) or a saved one's folder")
    channels: str = option(
        "default", choices=CHANNEL_CHOICES,
        help="BVH channels: default (positions on the root and hips, rotations elsewhere) or clip (the clip's own layout)",
    )  # fmt: skip
    foot_lock: bool = option(True, help=FOOT_LOCK_HELP)
    exact: tuple[str, ...] = option((), repeat=True, metavar="NAME=VALUE", help=EXACT_HELP)
    verify: bool = option(True, help=VERIFY_HELP)


INBETWEEN_EXAMPLES = """examples:
  bezmotion inbetween CLIP.bvh --frames 0 30 --handle right_hand@12=+0,25,0 --out take/
  bezmotion inbetween CLIP.bvh --frames 0 30 --handle right_hand@12=+0,40,0 --out take.v2/
  bezmotion inbetween --start A.bvh@0 --end B.bvh@40 --handle right_hand@12=40,150,80 --samples 3 --out take.bvh
  bezmotion inbetween CLIP.bvh --frames 0 30 --handles edited.json --out take.glb
  bezmotion inbetween OTHER.bvh --frames 0 30 --mapping map.json --ik rig --out take/

handles: JOINT@FRAME=X,Y,Z is a position (cm, the clip's world frame, +Y up); a leading +
is an offset from the straight line between the keys' positions of that joint. Frames
count from the start key (0) to the end key (30). JOINT: hips, head, left_hand,
right_hand, left_foot, right_foot, or the skeleton's own name for one of them."""


class _Parser(argparse.ArgumentParser):
    """Reports a bad command line in one line, as every other error (exit status 2)."""

    def error(self, message: str):
        self.exit(2, f"bezmotion: error: {one_line(message)} (see {self.prog} --help)\n")


def main(argv: list[str] | None = None) -> int:
    parser = _Parser(prog="bezmotion", description="Precise, character-agnostic motion in-betweening.")
    sub = parser.add_subparsers(dest="command", required=True)
    p_demo = sub.add_parser(
        "demo", help="in-between the bundled real clip with the bundled models; write BVH, PNG and a summary (no downloads)"
    )
    add_options(p_demo, DemoOptions)
    p_inbetween = sub.add_parser(
        "inbetween", help="in-between two poses of your own BVH files through handles; write BVH, glTF and a preview",
        description=InbetweenCommand.__doc__, epilog=INBETWEEN_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    add_options(p_inbetween, InbetweenCommand)
    add_edit_arguments(sub.add_parser("edit", help=EDIT_HELP, description=EDIT_HELP))
    p_models = sub.add_parser(
        "models", help="list the pretrained models: bundled or how to train them, size, data, licence, retrain commands",
        description="The pretrained models by name (bezmotion.pretrained(NAME) in Python; --model NAME, --ik-model NAME here).",
    )  # fmt: skip
    manifest = p_models.add_mutually_exclusive_group()
    manifest.add_argument("--check", action="store_true", help="check every bundled model's files against the checksum manifest")
    manifest.add_argument("--write-manifest", action="store_true", help="rewrite the checksum manifest from the bundled files (after retraining one)")
    parsed = parser.parse_args(argv)
    if parsed.command in ("demo", "inbetween", "edit"):
        use_compilation_cache()  # the next run loads what this one compiles

    try:
        if parsed.command == "demo":
            args = options_from(p_demo, DemoOptions, parsed)
            demo(
                args.out, joint=args.joint, frame=args.frame, offset=tuple(args.offset), ik=args.ik, steps=args.steps,
                seed=args.seed, bmm_dir=args.bmm, bmm_corpus=args.bmm_corpus, ik_dir=args.ik_model,
                channels=args.channels, foot_lock=args.foot_lock, exact_settings=exact_settings(args.exact, "--exact"), force=args.force, verify=args.verify,
            )  # fmt: skip
        elif parsed.command == "inbetween":
            run_inbetween(options_from(p_inbetween, InbetweenCommand, parsed))
        elif parsed.command == "edit":
            run_edit(parsed)
        elif parsed.command == "models":
            if parsed.write_manifest:
                print(f"wrote {write_manifest()}")
            elif parsed.check:
                print(f"every bundled model matches {check_manifest()}")
            else:
                print(models_table())
    except (ValueError, FileNotFoundError) as e:
        print(f"bezmotion: error: {one_line(e)}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
