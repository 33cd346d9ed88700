"""Train the learned frame IK (ProtoRes-style, :mod:`bezmotion.ik.protores`) on one corpus.

    python experiments/train_ik.py --corpus lafan1 --steps 9000
    python experiments/train_ik.py --corpus bandai_namco --steps 9000
    python experiments/train_ik.py --corpus path/to/my_clips --characteristic my_joints.json

Trains on every frame of the corpus's training split (LaFAN1 subjects 1–4; Bandai-Namco
all but every 10th take; a folder of BVH files: all but every 10th file), posed on one skeleton per corpus (:mod:`bezmotion.ik.frames`),
with the effector sampling and losses of :mod:`bezmotion.ik.training`. Checkpoints go to
``<out-dir>/checkpoints`` every ``--checkpoint-every`` steps (and on Ctrl-C / SIGTERM);
running the same command again resumes from the latest one, bit-identically. At the end
the trained model is saved to ``<out-dir>/model`` (:func:`~bezmotion.ik.protores.save_ik_model`:
config, character and parameters) and ``<out-dir>/training.json`` records the loss curve
and the validation MPJPE of every Table 2 configuration (on every ``--eval-step``-th
validation frame).

Default ``--out-dir``: ``~/.cache/bezmotion/runs/ik_<corpus>``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Literal

import jax
import numpy as np

from bezmotion._src.io import atomic_write_text
from bezmotion.training.checkpoint import CheckpointStore
from bezmotion.data.corpus import Corpus
from bezmotion.ik.frames import corpus_frame_starts, corpus_frames
from bezmotion.ik.protocol import Pose
from bezmotion.ik.protores import ProtoResConfig, ProtoResModel, character_to_json, save_ik_model
from bezmotion.ik.training import (
    CHARACTERISTIC,
    IKTrainConfig,
    effector_configurations,
    effector_mpjpe,
    init_ik_train_state,
    make_ik_train_step,
)
from bezmotion._src.options import option, options, parse_options, presets
from bezmotion.training import compile_train_step, count_parameters, run_training
from _common import CHARACTERISTIC_HELP, CORPUS_HELP, clip_label, corpus_label, matches_any, open_corpus, runs_dir

CONFIGS = presets(ProtoResConfig)


@options
class Options:
    corpus: str = option(help=CORPUS_HELP)
    data: str | None = option(None, help="a published corpus's archive or folder (default: under ../shared/data)")
    characteristic: str | None = option(None, help=CHARACTERISTIC_HELP)
    out_dir: str | None = option(None, help="run folder (default ~/.cache/bezmotion/runs/ik_<corpus>)")
    steps: int = 9000
    config: str = option("cpu", choices=CONFIGS)
    batch_size: int = IKTrainConfig.batch_size
    learning_rate: float = IKTrainConfig.learning_rate
    output_rotations: Literal["local", "global"] | None = option(None, help="override the preset's")
    effector_skip: bool | None = option(None, help="override the preset's")
    rot_weight: float = IKTrainConfig.rot_weight
    seed: int = 0
    frame_step: int = option(1, help="train on every n-th frame (default 1)")
    checkpoint_every: int = 500
    train_seconds: float | None = option(
        None, help="stop training after this many seconds (at a step boundary, checkpointed; the same command resumes)"
    )
    eval_step: int = option(4, help="validate on every n-th validation frame (default 4)")
    holdout_contents: tuple[str, ...] = option(
        (), help="held-out contents: train without the clips whose content/action matches these patterns (e.g. 'wave-*' run); "
        "validation keeps every clip (pipeline_eval.py reports per content)",
    )  # fmt: skip
    no_progress: bool = False

    def __post_init__(self):
        if self.train_seconds is not None and not self.train_seconds > 0:
            raise ValueError(f"--train-seconds must be > 0, got {self.train_seconds}")


def parse_args(argv: list[str] | None = None) -> Options:
    return parse_options(Options, argv, description=__doc__)


def without_contents(corpus: Corpus, poses: Pose, patterns: tuple[str, ...], frame_step: int) -> Pose:
    """The training frames ``poses`` (:func:`corpus_frames`'s, clips in corpus order) less
    those of the clips whose content/action (:func:`clip_label`) matches ``patterns``.

    Raises:
      ValueError: no training clip matches (naming the patterns and the corpus' contents).
    """
    labels = [clip_label(corpus.labels(int(c))) for c in corpus.split("train")]
    held = matches_any(np.asarray(labels), patterns)
    if not held.any():
        raise ValueError(f"--holdout-contents {' '.join(patterns)}: no training clip of {corpus.name} has such a content (it has {sorted(set(labels))})")
    starts = corpus_frame_starts(corpus, "train", frame_step=frame_step)
    keep = np.repeat(~held, np.diff(starts))
    return jax.tree.map(lambda x: x[keep], poses)


def train_ik(args: Options) -> dict:
    """Train (or resume) and save; returns the summary written to ``training.json``."""
    out_dir = Path(args.out_dir).expanduser() if args.out_dir else runs_dir(f"ik_{corpus_label(args.corpus)}")
    started = time.perf_counter()
    corpus = open_corpus(args.corpus, data=args.data, characteristic=args.characteristic, progress=not args.no_progress)
    character, poses = corpus_frames(corpus, "train", frame_step=args.frame_step)
    if args.holdout_contents:
        poses = without_contents(corpus, poses, args.holdout_contents, args.frame_step)
    _, validation = corpus_frames(corpus, "validation", frame_step=args.eval_step)
    if not validation.root_pos.shape[0]:
        # A folder of fewer than ten files has no validation take (every 10th validates).
        print(f"{corpus.name} has no validation frames: the model is trained but not validated")
    print(f"{corpus.name}: {poses.root_pos.shape[0]} training frames of {character.num_joints} joints ({time.perf_counter() - started:.1f} s)")
    overrides = {k: v for k, v in (("output_rotations", args.output_rotations), ("effector_skip", args.effector_skip)) if v is not None}
    model_config = CONFIGS[args.config](character.num_joints, **overrides)
    train_config = IKTrainConfig(
        num_steps=args.steps, batch_size=args.batch_size, learning_rate=args.learning_rate, rot_weight=args.rot_weight,
        dense_batch_size=min(IKTrainConfig.dense_batch_size, args.batch_size // 8),
    )  # fmt: skip
    configurations = effector_configurations(character)
    graphdef, state = init_ik_train_state(model_config, train_config, key=jax.random.key(args.seed))
    config = {
        "corpus": args.corpus,
        **({"holdout_contents": list(args.holdout_contents)} if args.holdout_contents else {}),
        "seed": args.seed,
        "frame_step": args.frame_step,
        "model": dataclasses.asdict(model_config),
        "train": dataclasses.asdict(train_config),
        "character": character_to_json(character),
    }
    store = CheckpointStore(out_dir / "checkpoints")
    store.check_resumable(config)
    if store.latest_step() is not None:
        print(f"resuming from step {store.latest_step()} in {out_dir}")
    step = compile_train_step(make_ik_train_step(graphdef, model_config, train_config, character, configurations), num_seeds=None)
    # Restored checkpoints are committed to the device; commit the fresh state too, so
    # the step compiles once whether it starts fresh or from a checkpoint.
    state = jax.device_put(state, jax.devices()[0])
    poses = jax.device_put(poses, jax.devices()[0])
    train_started = time.perf_counter()

    def report(done: int, last: dict) -> None:
        # One line per checkpoint, so the log shows progress without a progress bar.
        if done % args.checkpoint_every == 0 or done == args.steps:
            print(
                f"step {done}: loss {last['loss']:.3f}, MPJPE {last['pos']:.3f} cm, rot {last['rot']:.4f}, "
                f"{last['steps_per_s']:.2f} steps/s, {time.perf_counter() - train_started:.0f} s",
                flush=True,
            )

    # The learning-rate schedule stays that of --steps: a run stopped by --train-seconds
    # resumes on the same schedule.
    deadline = None if args.train_seconds is None else time.monotonic() + args.train_seconds
    state, history = run_training(
        step, state, poses, num_steps=args.steps, store=store, checkpoint_every=args.checkpoint_every, config=config,
        progress=not args.no_progress, log_every=min(100, args.checkpoint_every), progress_fn=report, deadline=deadline,
    )  # fmt: skip
    store.close()
    train_s = time.perf_counter() - train_started
    model = ProtoResModel(state.params, character, graphdef, model_config)
    save_ik_model(out_dir / "model", model)

    errors: dict[str, float] = {}
    if validation.root_pos.shape[0]:
        errors = {name: float(np.mean(effector_mpjpe(model, validation, joints))) for name, joints in configurations.items()}
        errors[CHARACTERISTIC + " (positions only)"] = float(np.mean(effector_mpjpe(model, validation, configurations[CHARACTERISTIC], rotations=False)))
    summary = {
        "corpus": args.corpus,
        "config": args.config,
        "params": count_parameters(state.params),
        "steps": int(state.step),
        "steps_requested": args.steps,
        "train_frames": int(poses.root_pos.shape[0]),
        "validation_frames": int(validation.root_pos.shape[0]),
        "train_s_this_session": train_s,
        "validation_mpjpe_cm": errors,
        "history": history,
        "model_dir": str(out_dir / "model"),
        **config,
    }
    atomic_write_text(out_dir / "training.json", json.dumps(summary, indent=2, default=str) + "\n")
    print(f"saved {out_dir / 'model'}" + ("; validation MPJPE (cm):" if errors else ""))
    for name, value in errors.items():
        print(f"  {name}: {value:.3f}")
    return summary


def main(argv: list[str] | None = None) -> dict:
    return train_ik(parse_args(argv))


if __name__ == "__main__":
    main()
