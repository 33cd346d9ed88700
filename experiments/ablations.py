"""Train one of the paper's dense ablations of the BMM or its CondMDIᴳ baseline and evaluate
it like the BMM (Table 1 rows BMM⁻ᴮ, BMM⁻ᴵᴷ⁻ᴮ, CondMDIᴳ).

    python experiments/ablations.py --ablation minus_b --out results/ablation_minus_b_lafan1.json
    python experiments/ablations.py --ablation minus_ik_b --out results/ablation_minus_ik_b_lafan1.json
    python experiments/ablations.py --ablation condmdi_g --out results/ablation_condmdi_g_lafan1.json

``--ablation minus_b`` is BMM⁻ᴮ: the BMM's transformer generating the six characteristic
joints' positions (and ortho6D orientations; ``--no-orientation``: positions only) at every
frame instead of Bézier control points. ``--ablation minus_ik_b`` is BMM⁻ᴵᴷ⁻ᴮ: every joint of
the corpus skeleton at every frame, positions only, no IK. ``--ablation condmdi_g`` is
CondMDIᴳ: the same data as BMM⁻ᴵᴷ⁻ᴮ from a 1-D temporal UNet with the conditions as input
channels, sampled with classifier-free guidance 2.5 (``--guidance``; trained with
``--condition-dropout`` 0.1). All are conditioned like the
BMM (start and end of the six joints, 0–4 handles) and trained with its optimiser, loss
weights and defaults (``--steps``, ``--batch-size``, ``--learning-rate``, ``--min-snr-gamma``,
``--lr-schedule``: bmm_lafan1.py's), checkpointing into ``--run-dir`` (default
``<cache>/runs/ablation_<ablation>_<corpus>_<config>``; it resumes there, and a finished run
only evaluates). See :mod:`bezmotion.evaluation.ablations` for what differs from the BMM and why.

Evaluation is bmm_lafan1.py's, so the figures sit beside the BMM's (before IK): the same
validation windows and handles (``make_eval_set`` with key 1234; LaFAN1 subject 5 or
Bandai-Namco's validation takes), in distribution and OOD (±16 cm), at ``--eval-steps`` DDIM
steps; handles error, dense six-joint error, foot-skating ratio and contact accuracy of the
six joints' trajectories (:func:`~bezmotion.evaluation.curves.trajectory_metrics`), per
``--overwrite`` mode (``keys``: start and end written in, the paper's setting for the
ablation; ``all``: the handles too, at their own frame), beside the mocap and the
non-learned reference. BMM⁻ᴵᴷ⁻ᴮ and CondMDIᴳ also report the dense error of the whole skeleton.
Writes the JSON, a Markdown report beside it, and the model under ``<run-dir>/model``.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.bezier import BezierLayout
from bezmotion.evaluation.ablations import (
    ABLATIONS,
    OVERWRITE_MODES,
    DenseArrays,
    DenseBMMConfig,
    DenseMotionModel,
    dense_windows,
    init_dense_train_state,
    make_dense_train_step,
    sample_dense,
    save_dense_model,
)
from bezmotion.bmm.denoiser import BMMConfig
from bezmotion.evaluation.curves import (
    CurveMetricsConfig,
    curve_metrics,
    ground_truth_metrics,
    make_eval_set,
    map_in_chunks,
    reference_curves,
    trajectory_metrics,
)
from bezmotion.bmm.features import HANDLE_FRAMES, FeatureStats
from bezmotion.bmm.train import LR_SCHEDULES, BMMTrainConfig
from bezmotion.data.characteristic import FEET
from bezmotion.data.corpus import motion_clips
from bezmotion.data.curves import curve_dataset, skeleton_windows
from bezmotion.data.sources import default_source, load_corpus
from bezmotion._src.io import write_results
from bezmotion.evaluation.metrics import mean_position_error
from bezmotion._src.options import option, options, parse_options, presets
from bezmotion.training import CheckpointStore, compile_train_step, count_parameters, data_mesh, run_training
from _common import PARAMETER_CHOICES, PARAMETERS_HELP, runs_dir, trained_parameters

CORPORA = ("lafan1", "bandai_namco")
EVAL_KEY = 1234  # bmm_lafan1.py's evaluation windows and handles


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it)")
    ablation: str = option(
        "minus_b", choices=ABLATIONS, help="minus_b: dense six-joint trajectories (BMM⁻ᴮ); minus_ik_b: the dense full skeleton, no IK (BMM⁻ᴵᴷ⁻ᴮ); "
        "condmdi_g: the dense full skeleton from a 1-D UNet with classifier-free guidance (CondMDIᴳ)"
    )  # fmt: skip
    corpus: str = option("lafan1", choices=CORPORA, help="training and evaluation corpus (default lafan1)")
    data: str | None = option(None, help="the corpus archive or folder (default: the corpus's archive under ../shared/data)")
    config: str = option("cpu", choices=presets(BMMConfig), help="model size, the BMM's presets (default cpu; tiny: smoke tests); condmdi_g: its UNet's")
    no_orientation: bool = option(False, help="minus_b: positions only (default: positions and ortho6D orientations, what the IK reads)")
    steps: int = option(6000, help="training steps (default 6000, as bmm_lafan1.py)")
    stop_at: int | None = option(
        None, help="train only up to this step of the --steps run (or take its checkpoint there, if kept) and evaluate it; "
        "the same command without it (or with a later one) goes on training"
    )  # fmt: skip
    parameters: str = option("ema", choices=PARAMETER_CHOICES, help=PARAMETERS_HELP)
    batch_size: int = BMMTrainConfig.batch_size
    learning_rate: float = BMMTrainConfig.learning_rate
    min_snr_gamma: float = option(BMMTrainConfig.min_snr_gamma, help="Min-SNR-γ loss weighting (paper: 5; 0 = off)")
    ema_decay: float = option(BMMTrainConfig.ema_decay, help="decay of the evaluated parameters' moving average (paper: 0.999; a short smoke run wants less)")
    lr_schedule: str = option("constant", choices=LR_SCHEDULES, help="learning rate: constant (the paper) or cosine (warm-up, then decay to 0.1×)")
    warmup_steps: int = option(0, help="linear warm-up steps of the cosine schedule")
    condition_dropout: float = option(
        BMMTrainConfig.condition_dropout, help="classifier-free guidance: probability of dropping a training example's conditions (CondMDI, the BMM: 0.1)"
    )  # fmt: skip
    handle_frames: str = option("any", choices=HANDLE_FRAMES, help="training handles' frames: any (default) 1…29, grid (the BMM's control frames) or off_grid")
    seed: int = 0
    run_dir: str | None = option(None, help="checkpoints and the final model (default: <cache>/runs/ablation_<ablation>_<corpus>_<config>)")
    checkpoint_every: int = 500
    eval_windows: int = option(1000, help="validation windows evaluated (default 1000; 0 = all)")
    eval_steps: int = option(10, help="DDIM steps at evaluation (the paper's 10)")
    overwrite: tuple[str, ...] = option(
        ("keys", "all"), choices=OVERWRITE_MODES, help="overwrite modes evaluated: none, keys (start and end; the paper's), all (handles too)"
    )
    guidance: float | None = option(None, help="classifier-free guidance scale at sampling (1 = off; default: the model's, 2.5 for condmdi_g, else 1)")
    no_progress: bool = False

    def __post_init__(self):
        if self.no_orientation and self.ablation != "minus_b":
            raise ValueError(f"--no-orientation is for minus_b; {self.ablation} generates positions only")
        for name in ("steps", "batch_size", "eval_steps", "checkpoint_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be ≥ 1, got {getattr(self, name)}")
        if not 0.0 <= self.condition_dropout < 1.0:
            raise ValueError(f"--condition-dropout must be in [0, 1), got {self.condition_dropout}")
        if self.guidance is not None and not self.guidance >= 0.0:
            raise ValueError(f"--guidance must be ≥ 0, got {self.guidance}")
        if self.eval_windows < 0:
            raise ValueError(f"--eval-windows must be ≥ 0, got {self.eval_windows}")
        if self.stop_at is not None and not 1 <= self.stop_at <= self.steps:
            raise ValueError(f"--stop-at must be in 1 … --steps ({self.steps}), got {self.stop_at}")
        if self.run_dir is None:
            suffix = "_positions" if self.no_orientation else ""
            object.__setattr__(self, "run_dir", str(runs_dir(f"ablation_{self.ablation}_{self.corpus}_{self.config}{suffix}")))


def train(args, config: DenseBMMConfig, train_config: BMMTrainConfig, arrays: DenseArrays, stats: FeatureStats):
    """Train (resuming from ``args.run_dir``); returns ``(graphdef, state, history, seconds)``."""
    graphdef, state = init_dense_train_state(config, train_config, key=jax.random.key(args.seed))
    step = compile_train_step(make_dense_train_step(graphdef, config, train_config, stats, handle_frames=args.handle_frames, mesh=data_mesh()), num_seeds=None)
    store = CheckpointStore(Path(args.run_dir) / "checkpoints")
    saved = {
        "model": dataclasses.asdict(config),
        "train": {**dataclasses.asdict(train_config), "seed": args.seed, "num_steps": args.steps, "handle_frames": args.handle_frames},
    }
    store.check_resumable(saved)
    started = time.perf_counter()
    stop = args.steps if args.stop_at is None else args.stop_at
    latest = store.latest_step()
    if latest is not None and latest > stop:  # an earlier point of a longer run: its checkpoint there
        kept = sorted(int(d.name) for d in store.directory.iterdir() if d.name.isdigit())
        if stop not in kept:
            raise ValueError(f"--stop-at {stop}: {args.run_dir} is at step {latest} and keeps checkpoints {kept} only")
        state = store.restore(state, step=stop)
        history: list = []
    else:
        data = DenseArrays(*(jnp.asarray(a) for a in arrays))  # on the device once, not per step
        state, history = run_training(
            step, state, data, num_steps=stop, store=store, checkpoint_every=args.checkpoint_every, config=saved, progress=not args.no_progress
        )
    store.close()
    return graphdef, state, history, time.perf_counter() - started


def evaluate(args, model: DenseMotionModel, metrics_config: CurveMetricsConfig, eval_set, skeleton: np.ndarray | None) -> dict:
    """The Table 1 analogue per overwrite mode: in distribution and OOD."""
    config = model.config
    controls = metrics_config.layout.control_frames
    results: dict = {}
    for mode in args.overwrite:
        results[mode] = {}
        for split, handles in (("id", eval_set.handles), ("ood", eval_set.handles_ood)):
            started = time.perf_counter()
            motion = map_in_chunks(
                lambda x, k: sample_dense(model, *x, key=k, steps=args.eval_steps, guidance=args.guidance, overwrite=mode),  # noqa: B023
                (eval_set.start, eval_set.end, handles), key=jax.random.key(args.seed + 99),
            )  # fmt: skip
            metrics = trajectory_metrics(metrics_config, motion.characteristic_positions(config), motion.contacts[:, controls], eval_set, handles)
            if skeleton is not None:
                metrics["skeleton_dense_error_cm"] = float(mean_position_error(motion.pos, jnp.asarray(skeleton)))
            metrics["eval_s"] = time.perf_counter() - started
            results[mode][split] = metrics
            print(f"{config.variant} overwrite={mode} {split}: {metrics}", flush=True)
    return results


def format_report(results: dict) -> str:
    r = results
    name = {
        "minus_b": "BMM⁻ᴮ (dense six-joint trajectories)", "minus_ik_b": "BMM⁻ᴵᴷ⁻ᴮ (dense full skeleton, no IK)",
        "condmdi_g": f"CondMDIᴳ (dense full skeleton, 1-D UNet, guidance {r['eval']['guidance']})",
    }[r["ablation"]]  # fmt: skip
    t, e = r["training"], r["eval"]
    lines = [
        f"{name} on {t['corpus']}: config {r['model']['preset']} ({r['model']['params']} parameters), {t['steps']} steps of batch "
        f"{t['batch_size']} ({t['wall_s_this_run']:.0f} s this run), {e['n_windows']} validation windows, {e['eval_steps']} DDIM steps.",
        "",
        "Table 1 analogue, before IK (handles error over intermediate handles; dense error and skating of the six joints):",
        "",
        "| method | handles error ID (cm) | OOD (cm) | dense error ID (cm) | foot skating ID | contact acc. ID |",
        "|---|---|---|---|---|---|",
        f"| mocap (GT) | – | – | – | {r['ground_truth']['foot_skating_ratio']:.4f} | – |",
    ]

    def row(label, ident, ood):
        return (
            f"| {label} | {ident['handles_error_cm']:.4f} | {ood['handles_error_cm']:.4f} | {ident['dense_error_cm']:.3f} | "
            f"{ident['foot_skating_ratio']:.4f} | {ident['contact_accuracy']:.3f} |"
        )

    lines.append(row("reference: curves through start, end, handles", r["reference"]["id"], r["reference"]["ood"]))
    for mode, m in r["ablation_metrics"].items():
        lines.append(row(f"{r['ablation']}, overwrite {mode}", m["id"], m["ood"]))
    if r["ablation"] != "minus_b":
        lines += ["", "Full-skeleton dense error (cm, ID / OOD): " + ", ".join(
            f"overwrite {mode} {m['id']['skeleton_dense_error_cm']:.3f} / {m['ood']['skeleton_dense_error_cm']:.3f}" for mode, m in r["ablation_metrics"].items()
        )]  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    started = time.perf_counter()
    progress = not args.no_progress
    corpus = load_corpus(args.corpus, source=args.data or default_source(args.corpus), progress=progress)
    mapping = corpus.characteristic_map
    train_clips = motion_clips(corpus, "train")
    if args.ablation == "minus_b":
        config = DenseBMMConfig.minus_b(args.config, orientation=not args.no_orientation)
    elif args.ablation == "minus_ik_b":
        config = DenseBMMConfig.minus_ik_b(train_clips.joint_names, mapping, args.config)
    else:
        config = DenseBMMConfig.condmdi_g(train_clips.joint_names, mapping, args.config)
    arrays, _, _ = dense_windows(train_clips, mapping, config)
    stats = FeatureStats.from_features(arrays.features)
    # floor_height_from of the training curves: these are the same windows' ankles.
    floor = float(np.percentile(arrays.characteristic_positions(config)[..., list(FEET), 1], 5.0))
    train_config = BMMTrainConfig(
        batch_size=args.batch_size, learning_rate=args.learning_rate, min_snr_gamma=args.min_snr_gamma or None, ema_decay=args.ema_decay,
        condition_dropout=args.condition_dropout,
        lr_schedule=args.lr_schedule, warmup_steps=args.warmup_steps, total_steps=args.steps if args.lr_schedule != "constant" else None,
    )  # fmt: skip
    graphdef, state, history, train_s = train(args, config, train_config, arrays, stats)
    num_train = int(arrays.features.shape[0])
    del arrays
    trained, folder = trained_parameters(state, args.parameters)
    model = DenseMotionModel(trained, stats, graphdef, config)
    model_dir = Path(args.run_dir) / folder
    save_dense_model(model_dir, model)

    val_set = curve_dataset(corpus, "validation", progress=progress)
    eval_set = make_eval_set(val_set, key=jax.random.key(EVAL_KEY), num_windows=args.eval_windows or None)
    layout = BezierLayout(config.num_frames)  # the BMM's control frames: where the contact labels are
    metrics_config = CurveMetricsConfig(layout, val_set.fps, floor)
    skeleton = None
    if config.full_skeleton:
        pos, clip_index, start_frame = skeleton_windows(motion_clips(corpus, "validation"), mapping, window=config.num_frames)
        assert np.array_equal(clip_index, val_set.clip_index) and np.array_equal(start_frame, val_set.start_frame)
        skeleton = pos[eval_set.rows]
    results: dict = {
        "ablation": args.ablation,
        "model": {"preset": args.config, **dataclasses.asdict(config), "params": count_parameters(model.params)},
        "training": {
            "corpus": args.corpus, "steps": args.steps if args.stop_at is None else args.stop_at, "schedule_steps": args.steps, "batch_size": args.batch_size, "learning_rate": args.learning_rate,
            "min_snr_gamma": train_config.min_snr_gamma, "ema_decay": args.ema_decay, "lr_schedule": args.lr_schedule, "warmup_steps": args.warmup_steps,
            "handle_frames": args.handle_frames, "seed": args.seed, "train_windows": num_train, "evaluated_parameters": args.parameters, "wall_s_this_run": train_s,
            "run_dir": args.run_dir, "history": history,
        },  # fmt: skip
        "eval": {
            "n_windows": int(eval_set.start.shape[0]), "floor_height_cm": floor, "fps": val_set.fps, "eval_steps": args.eval_steps,
            "guidance": config.default_guidance if args.guidance is None else args.guidance, "key": EVAL_KEY,
        },  # fmt: skip
        "ground_truth": ground_truth_metrics(metrics_config, eval_set),
        "reference": {
            name: curve_metrics(metrics_config, reference_curves(eval_set, h, layout), eval_set, h)
            for name, h in (("id", eval_set.handles), ("ood", eval_set.handles_ood))
        },
        "ablation_metrics": evaluate(args, model, metrics_config, eval_set, skeleton),
    }
    results["wall_s"] = time.perf_counter() - started
    write_results(args.out, results, format_report(results))
    print(f"model in {model_dir}")
    return results


if __name__ == "__main__":
    main()
