"""Train the Bézier Motion Model on LaFAN1 and evaluate its curves (before IK).

    python experiments/bmm_lafan1.py --out results/bmm_lafan1.json

Trains on the curve dataset of LaFAN1 subjects 1–4 (31-frame windows, stride 6;
``--bandai-namco PATH`` adds Bandai-Namco's training clips; ``--corpus bandai_namco``
trains and evaluates on Bandai-Namco alone, its validation takes standing in for
subject 5) with the paper's losses and
optimiser, checkpointing into ``--run-dir`` (resumes there when interrupted), then
evaluates the EMA parameters on subject-5 windows:

- Table 1 analogue (before IK): handles error in distribution and OOD (±16 cm), dense
  six-joint position error, foot-skating ratio and contact accuracy at 10 DDIM steps,
  beside the non-learned reference (curves through start, end and handles only) and
  the mocap's own skating ratio;
- Table 3 analogue: with and without overwrite;
- Table 6 analogue: 5, 10, 25, 50 and 100 DDIM steps;
- ours: the same with foot locking on the predicted contacts (``sample_curves(foot_lock=True)``);
- ours: ``--handle-frames off_grid|any`` also evaluates the Table 1 analogue with the
  same windows' handles moved off the control grid (to frames between control frames, or
  to any intermediate frame; positions the fitted curves there), beside the grid figures;
  ``--off-grid-handles P`` trains with handles off the grid with probability P.

``--model PATH|bundled`` evaluates a saved BMM (``bundled``: the one in
:mod:`bezmotion.assets`) instead of training one, e.g.

    python experiments/bmm_lafan1.py --corpus bandai_namco --model bundled --eval-windows 200 \
        --handle-frames off_grid --table6-steps 10 --out results/bmm_off_grid.json

Several processes train one model data-parallel (each its share of every batch; one
machine or several): start the same command once per process with ``--coordinator
HOST:PORT --num-processes N --process-id I``; process 0 evaluates and writes the results.

``--spans LOW HIGH`` trains on windows of many lengths (keys LOW … HIGH frames apart, drawn
per example; ``BMMTrainConfig.spans``); the evaluation stays on 31-frame windows
(``experiments/gap_lengths.py`` measures the other lengths).

``--config cpu`` (default) trains in a session on a 2-core CPU; ``--config paper`` is the
paper's 17.4 M-parameter model and runs unchanged on a GPU. Writes the JSON, a Markdown
report beside it, and the trained model under ``<run-dir>/model``.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion._src.io import write_results
from bezmotion.assets import BUNDLED_BMM, PROFILES_DIR
from bezmotion.evaluation.curves import (
    HANDLE_FRAMES,
    CurveMetricsConfig,
    curve_metrics,
    floor_height_from,
    ground_truth_metrics,
    make_eval_set,
    reference_curves,
    sample_in_chunks,
)
from bezmotion.bezier import BezierLayout
from bezmotion.training.checkpoint import CheckpointStore
from bezmotion.data.curves import CurveDataset, curve_dataset
from bezmotion.data.sources import default_source, load_corpus
from bezmotion.evaluation.baselines import OFF_GRID_REFERENCES
from bezmotion.bmm.denoiser import PREDICTIONS, BMMConfig
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, load_model, sample_curves, save_model
from bezmotion.bmm.augmentation import rest_reflections
from bezmotion.bmm.train import LR_SCHEDULES, CurveArrays, BMMTrainConfig, DenseWindows, init_bmm_train_states, make_bmm_train_step
from bezmotion.data.characteristic import SKELETON_MAPS
from bezmotion.pipeline.transfer import CharacterProfile, Transfer, transfer_curve_dataset
from bezmotion._src.options import option, options, parse_options, presets
from bezmotion.training import StoppingRule, compile_train_step, count_parameters, data_mesh, run_training, train_with_learning_curve
from bezmotion.training.distributed import DistributedOptions, is_coordinator, leave_group
from _common import PARAMETER_CHOICES, PARAMETERS_HELP, clip_label, matches_any, runs_dir, trained_parameters, window_labels

DEFAULT_DATA = {name: default_source(name) for name in ("lafan1", "bandai_namco")}
STEP_COUNTS = (5, 10, 25, 50, 100)
CONFIGS = presets(BMMConfig)


@options
class Options(DistributedOptions):
    out: str = option(help="output JSON (a .md report is written beside it)")
    corpus: str = option("lafan1", choices=DEFAULT_DATA, help="training and evaluation corpus (default lafan1)")
    data: str | None = option(
        None,
        help="the corpus archive or folder (default ../shared/data/lafan1/lafan1-subset.zip or ../shared/data/bandai-namco/bandai-namco-2.tar.xz)",
    )
    bandai_namco: str | None = option(None, help="also train on Bandai-Namco's training clips (archive or folder), positions as they are")
    also_corpus: str | None = option(
        None, choices=DEFAULT_DATA,
        help="also train on this corpus's training clips in the character-agnostic space: moved into --corpus's character by the two character profiles (hip-height scale, orientation offsets)",
    )  # fmt: skip
    also_data: str | None = option(None, help="the --also-corpus archive or folder (default: its default archive)")
    config: str = option("cpu", choices=CONFIGS, help="model size (default cpu; tiny: smoke tests)")
    prediction: str = option(
        "x0", choices=PREDICTIONS, help="decoder output: x0 (the paper) or residual over the reference curves through the conditions (ours)"
    )
    off_grid_prior: str = option(
        "linear", choices=OFF_GRID_REFERENCES,
        help="with --prediction residual: how the reference curves it predicts over reach handles between control frames: linear (interpolated through them in frame; default) or projection (a bump at the handle; what models saved without off_grid_prior learned over)",
    )  # fmt: skip
    steps: int = option(6000, help="training steps (default 6000)")
    batch_size: int = BMMTrainConfig.batch_size
    learning_rate: float = BMMTrainConfig.learning_rate
    min_snr_gamma: float = option(BMMTrainConfig.min_snr_gamma, help="Min-SNR-γ loss weighting (paper: 5; 0 = off)")
    seeds: tuple[int, ...] = option((0,), help="seeds trained together (vmapped)")
    run_dir: str | None = option(None, help="checkpoints and the final model (default: <cache>/runs/bmm_lafan1_<config>)")
    checkpoint_every: int = 500
    train_seconds: float | None = option(
        None, help="stop training after this many seconds of this run (checkpointed; the same command later goes on), then evaluate"
    )
    eval_windows: int = option(1000, help="subject-5 windows evaluated (default 1000; 0 = all)")
    guidance: float = option(1.0, help="classifier-free guidance scale at sampling (1 = off)")
    table6_steps: tuple[int, ...] = option(STEP_COUNTS, help="DDIM step counts compared (default 5 10 25 50 100)")
    model: str | None = option(None, help="evaluate this saved BMM (a folder, or 'bundled') instead of training one")
    init: str | None = option(None, help="fine-tune this saved BMM (a folder, or 'bundled'): its size, statistics and parameters")
    handle_frames: str = option(
        "grid", choices=HANDLE_FRAMES, help="also evaluate handles off the control grid: off_grid (between control frames) or any (1…29)"
    )
    off_grid_handles: float = option(0.0, help="training: probability that a handle sits at any frame 1…29 (default 0: the paper's)")
    lr_schedule: str = option(
        "constant", choices=LR_SCHEDULES, help="learning rate: constant (the paper) or cosine (warm-up, then cosine decay to 0.1× at --steps)"
    )
    warmup_steps: int = option(0, help="linear warm-up steps of the cosine schedule")
    augment_yaw: bool = option(False, help="turn every training window by a random angle about the vertical (ours)")
    augment_mirror: float = option(0.0, help="probability of mirroring a training window left/right (ours)")
    augment_still: float = option(0.0, help="probability of holding one pose of a training window still for the whole window (ours)")
    ema_decay: float = option(
        BMMTrainConfig.ema_decay, help="decay of the evaluated and saved parameters' moving average (paper: 0.999; its ~1/(1-decay)-step memory lags a short run)"
    )
    parameters: str = option("ema", choices=PARAMETER_CHOICES, help=PARAMETERS_HELP)
    holdout_contents: tuple[str, ...] = option(
        (), help="held-out contents: train without the clips whose content/action matches these patterns (e.g. 'wave-*' run), evaluate on all their windows too"
    )
    spans: tuple[int, ...] = option(
        (), help="train on windows of many lengths: keys LOW … HIGH frames apart, drawn per example (e.g. 8 90; default: the model's 30)"
    )
    native_span: float = option(0.0, help="with --spans: the probability of an example's keys being the model's own window (30) apart")
    eval_every: int = option(0, help="learning curve: evaluate every N steps into <run-dir>/learning_curve.json (0 = only at the end)")
    curve_windows: int = option(200, help="validation windows per learning-curve point")
    patience: int = option(0, help="stop when the EMA validation dense error has not improved by 1 %% over this many curve points (0 = never)")
    no_progress: bool = False

    def __post_init__(self):
        super().__post_init__()
        if self.model and self.init:
            raise ValueError("--model evaluates a saved BMM, --init fine-tunes one: give one of them")
        if self.spans and (len(self.spans) != 2 or self.bandai_namco or self.also_corpus):
            raise ValueError(f"--spans takes LOW HIGH (got {' '.join(map(str, self.spans))}) and trains on --corpus alone (no --bandai-namco, --also-corpus)")
        if self.run_dir is None and self.init:  # named after every lever, as a run from scratch is
            name = f"bmm_{self.corpus}_finetune_{Path(self.init).name}_offgrid{self.off_grid_handles:g}{self.lever_suffix()}"
            object.__setattr__(self, "run_dir", str(runs_dir(name)))
        if self.run_dir is None:
            suffix = "" if self.prediction == "x0" else f"_{self.prediction}"
            object.__setattr__(self, "run_dir", str(runs_dir(f"bmm_{self.corpus}_{self.config}{suffix}{self.lever_suffix()}")))
        if self.patience and not self.eval_every:
            raise ValueError(f"--patience {self.patience} needs --eval-every (the curve it watches)")
        if self.train_seconds is not None and self.train_seconds <= 0:
            raise ValueError(f"--train-seconds must be > 0, got {self.train_seconds}")
        if self.eval_every < 0 or self.patience < 0 or self.curve_windows < 1:
            raise ValueError("--eval-every and --patience must be ≥ 0, --curve-windows ≥ 1")
        if self.also_corpus is not None and (self.also_corpus == self.corpus or self.bandai_namco):
            raise ValueError(f"--also-corpus {self.also_corpus}: name a corpus other than --corpus {self.corpus}, without --bandai-namco")
        if self.holdout_contents and self.bandai_namco:
            raise ValueError("--holdout-contents holds out contents of --corpus; it cannot be combined with --bandai-namco")
        if self.bandai_namco and self.corpus != "lafan1":
            raise ValueError("--bandai-namco adds Bandai-Namco to LaFAN1 training; with --corpus bandai_namco it is already the corpus")

    def lever_suffix(self) -> str:
        """The run-folder suffix naming the levers that differ from the paper's training."""
        parts = []
        if self.off_grid_prior != "linear":
            parts.append(f"{self.off_grid_prior}prior")
        if self.lr_schedule != "constant":
            parts.append(f"{self.lr_schedule}{self.warmup_steps}")
        if self.augment_yaw:
            parts.append("yaw")
        if self.augment_mirror:
            parts.append(f"mirror{self.augment_mirror:g}")
        if self.augment_still:
            parts.append(f"still{self.augment_still:g}")
        if self.ema_decay != BMMTrainConfig.ema_decay:
            parts.append(f"ema{self.ema_decay:g}")
        if self.also_corpus:
            parts.append(f"also-{self.also_corpus}")
        if self.holdout_contents:
            parts.append("holdout-" + "-".join(p.replace("*", "") for p in self.holdout_contents))
        if self.spans:
            parts.append(f"spans{self.spans[0]}-{self.spans[1]}" + (f"native{self.native_span:g}" if self.native_span else ""))
        return "".join(f"_{p}" for p in parts)


def train(
    args, model_config: BMMConfig, train_config: BMMTrainConfig, data: CurveArrays | DenseWindows, stats: FeatureStats, init=None, evaluate=None
):
    """Train (resuming from ``args.run_dir``); with ``evaluate`` and ``--eval-every``, keep a learning curve.

    Returns ``(graphdef, state, history, seconds, curve)``; ``curve`` is ``None`` without one.
    """
    graphdef, state = init_bmm_train_states(model_config, train_config, args.seeds)
    if init is not None:  # fine-tuning: every seed starts from the saved parameters (fresh optimiser state)
        start = jax.tree.map(lambda x: jnp.broadcast_to(x, (len(args.seeds), *x.shape)), init.params)
        state = dataclasses.replace(state, params=start, ema=start)
    step = compile_train_step(make_bmm_train_step(graphdef, model_config, train_config, stats, mesh=data_mesh()), num_seeds=len(args.seeds))
    store = CheckpointStore(Path(args.run_dir) / "checkpoints")
    config = {
        "model": dataclasses.asdict(model_config),
        "train": {**dataclasses.asdict(train_config), "seeds": list(args.seeds), "num_steps": args.steps},
    }
    # A constant learning rate does not depend on the run's length: --steps may grow to go on training.
    store.check_resumable(config, extendable=("train.num_steps",) if train_config.lr_schedule == "constant" else ())
    started = time.perf_counter()
    deadline = None if args.train_seconds is None else time.monotonic() + args.train_seconds
    kwargs = dict(store=store, checkpoint_every=args.checkpoint_every, config=config, progress=not args.no_progress, deadline=deadline)
    curve = None
    if args.eval_every and evaluate is not None:
        stopping = StoppingRule("id.ema.dense_error_cm", args.patience) if args.patience else None
        state, history, curve = train_with_learning_curve(
            step, state, data, num_steps=args.steps, eval_every=args.eval_every, evaluate=lambda s: evaluate(graphdef, s),
            curve_file=Path(args.run_dir) / "learning_curve.json", stopping=stopping, **kwargs,
        )  # fmt: skip
    else:
        state, history = run_training(step, state, data, num_steps=args.steps, **kwargs)
    store.close()
    return graphdef, state, history, time.perf_counter() - started, curve


def curve_evaluator(args, model_config: BMMConfig, stats: FeatureStats, metrics_config, eval_sets: dict):
    """``evaluate(graphdef, state)`` for the learning curve: 10-step samples of seed 0's EMA and raw
    parameters on the in-distribution set (``id``), the EMA's on the others (e.g. ``held_out``)."""
    key = jax.random.key(7)

    def metrics(params, graphdef, eval_set):
        model = BezierMotionModel(params, stats, graphdef, model_config)
        fn = functools.partial(sample_curves, model, steps=10, guidance=args.guidance)
        curves = sample_in_chunks(lambda s, e, h, k: fn(s, e, h, key=k), eval_set, eval_set.handles, key=key)
        return curve_metrics(metrics_config, curves, eval_set, eval_set.handles)

    def evaluate(graphdef, state) -> dict:
        first = lambda tree: jax.tree.map(lambda x: x[0], tree)  # noqa: E731  (seed 0 of the stacked seeds)
        point = {"id": {"ema": metrics(first(state.ema), graphdef, eval_sets["id"]), "raw": metrics(first(state.params), graphdef, eval_sets["id"])}}
        for name, eval_set in eval_sets.items():
            if name != "id":
                point[name] = {"ema": metrics(first(state.ema), graphdef, eval_set)}
        return point

    return evaluate


def plot_learning_curve(curve: dict, references: dict, path: Path) -> None:
    """Dense error, skating and contact accuracy against steps (PNG), with the reference curves' levels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bezmotion._src.io import save_figure

    points = curve["points"]
    steps = [p["step"] for p in points]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for ax, metric, title in zip(
        axes, ("dense_error_cm", "foot_skating_ratio", "contact_accuracy"), ("dense six-joint error (cm)", "foot skating ratio", "contact accuracy")
    ):
        for split, style in (("id", "-"), ("held_out", "--")):
            if split not in points[0]:
                continue
            for which in ("ema", "raw"):
                if which in points[0][split]:
                    ax.plot(steps, [p[split][which][metric] for p in points], style, marker="o", label=f"BMM {split} ({which})")
            if split in references and metric != "contact_accuracy":
                ax.axhline(references[split][metric], linestyle=style, color="grey", label=f"reference {split}")
        ax.set_xlabel("training step")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    if curve.get("stopped_at"):
        for ax in axes:
            ax.axvline(curve["stopped_at"], color="red", alpha=0.4)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def handles_table(args, model: BezierMotionModel, metrics_config, eval_set, key) -> dict:
    """Table 1 analogue (10 DDIM steps, overwrite): in distribution and OOD."""
    fn = functools.partial(sample_curves, model, steps=10, guidance=args.guidance)
    return {
        name: curve_metrics(metrics_config, sample_in_chunks(lambda s, e, h, k: fn(s, e, h, key=k), eval_set, handles, key=key), eval_set, handles)
        for name, handles in (("id", eval_set.handles), ("ood", eval_set.handles_ood))
    }


def evaluate_model(args, model: BezierMotionModel, metrics_config, eval_set, key) -> dict:
    results: dict = {}

    def run(handles, *, steps=10, overwrite=True, foot_lock=False):
        fn = functools.partial(sample_curves, model, steps=steps, overwrite=overwrite, guidance=args.guidance, foot_lock=foot_lock)
        curves = sample_in_chunks(lambda s, e, h, k: fn(s, e, h, key=k), eval_set, handles, key=key)
        return curves

    for overwrite in (True, False):
        row = {}
        for name, handles in (("id", eval_set.handles), ("ood", eval_set.handles_ood)):
            m = curve_metrics(metrics_config, run(handles, overwrite=overwrite), eval_set, handles)
            row[name] = m
        results["overwrite" if overwrite else "no_overwrite"] = row
    results["foot_lock"] = {
        name: curve_metrics(metrics_config, run(handles, foot_lock=True), eval_set, handles)
        for name, handles in (("id", eval_set.handles), ("ood", eval_set.handles_ood))
    }
    results["steps"] = {}
    for steps in args.table6_steps:
        t0 = time.perf_counter()
        m = curve_metrics(metrics_config, run(eval_set.handles, steps=steps), eval_set, eval_set.handles)
        results["steps"][str(steps)] = {**m, "eval_s": time.perf_counter() - t0}
    return results


def format_report(results: dict) -> str:
    def row(name, id_, ood):
        return (
            f"| {name} | {id_['handles_error_cm']:.4f} | {ood['handles_error_cm']:.4f} | {id_['dense_error_cm']:.3f} | "
            f"{id_['foot_skating_ratio']:.4f} | {id_.get('contact_accuracy', float('nan')):.3f} |"
        )

    # A saved model: its folder, and not this run's training options, which did not train it.
    training = results["training"]
    saved = training.get("saved_model")
    lines = [
        f"BMM on {training['corpus']} ({'saved: ' + saved if saved else results['model']['config'] + ' config'}, {results['model']['prediction']} prediction, "
        f"{results['model']['params']:,} parameters, "
        + ("trained elsewhere" if saved else f"{training['steps']} steps × batch {training['batch_size']}, {len(training['seeds'])} seed(s)")
        + f"); {results['eval']['n_windows']} validation windows; curves before IK.",
        "",
        "Table 1 / Table 3 analogue (10 DDIM steps):",
        "",
        "| method | handles error ID (cm) | OOD (cm) | dense error ID (cm) | foot skating | contact acc. |",
        "|---|---|---|---|---|---|",
        f"| mocap (GT) | – | – | – | {results['ground_truth']['foot_skating_ratio']:.4f} | – |",
        f"| curves fitted to the mocap (the representation's floor) | 0 | – | "
        f"{results['ground_truth']['fitted_curves']['dense_error_cm']:.3f} | {results['ground_truth']['fitted_curves']['foot_skating_ratio']:.4f} | – |",
        row("reference: curves through start, end, handles", results["reference"]["id"], results["reference"]["ood"]),
    ]
    for seed, r in results["bmm"].items():
        lines.append(row(f"BMM seed {seed}", r["overwrite"]["id"], r["overwrite"]["ood"]))
        lines.append(row(f"BMM seed {seed} w/o overwrite", r["no_overwrite"]["id"], r["no_overwrite"]["ood"]))
        lines.append(row(f"BMM seed {seed} + foot lock (ours)", r["foot_lock"]["id"], r["foot_lock"]["ood"]))
    if "handle_frames" in results:
        section = results["handle_frames"]
        lines += [
            "", f"Table 1 analogue with the same handles moved off the control grid ({section['handle_frames']}), 10 DDIM steps:", "",
            "| method | handles error ID (cm) | OOD (cm) | dense error ID (cm) | foot skating | contact acc. | dense / skating vs grid (ID) |",
            "|---|---|---|---|---|---|---|",
            row("reference: curves through start, end, handles", section["reference"]["id"], section["reference"]["ood"]) + " – |",
        ]  # fmt: skip
        for seed, r in section["bmm"].items():
            rel = r["relative_to_grid"]["id"]
            lines.append(row(f"BMM seed {seed}", r["id"], r["ood"]) + f" {100 * rel['dense_error_cm']:+.1f} % / {100 * rel['foot_skating_ratio']:+.1f} % |")
    if "held_out" in results:
        section = results["held_out"]
        lines += [
            "", f"Held-out contents ({', '.join(section['contents'])}: {section['trained_on']}; {section['n_windows']} windows), 10 DDIM steps:", "",
            "| method | handles error ID (cm) | OOD (cm) | dense error ID (cm) | foot skating | contact acc. |",
            "|---|---|---|---|---|---|",
            f"| mocap (GT) | – | – | – | {section['ground_truth']['foot_skating_ratio']:.4f} | – |",
            row("reference: curves through start, end, handles", section["reference"]["id"], section["reference"]["ood"]),
        ]  # fmt: skip
        for seed, r in section["bmm"].items():
            ratio = r["id"]["dense_error_cm"] / section["reference"]["id"]["dense_error_cm"]
            lines.append(row(f"BMM seed {seed} ({ratio:.3f} × reference)", r["id"], r["ood"]))
    curve = results["training"].get("learning_curve")
    if curve:
        stopped = f"stopped early at step {curve['stopped_at']}" if curve["stopped_at"] is not None else "not stopped early"
        with_held = any("held_out" in p for p in curve["points"])  # a column only for runs that hold contents out
        lines += ["", f"Learning curve (seed 0, {len(curve['points'])} points; {stopped}):", "",
                  "| step | train s | loss | dense ID EMA (cm) | raw (cm) | skating ID | contact acc. |" + (" dense held-out (cm) |" if with_held else ""),
                  "|---|---|---|---|---|---|---|" + ("---|" if with_held else "")]  # fmt: skip
        for p in curve["points"]:
            e = p["id"]["ema"]
            line = (
                f"| {p['step']} | {p['train_s']:.0f} | {p.get('loss', float('nan')):.4f} | {e['dense_error_cm']:.3f} | {p['id']['raw']['dense_error_cm']:.3f} | "
                f"{e['foot_skating_ratio']:.4f} | {e['contact_accuracy']:.3f} |"
            )
            if with_held:
                line += f" {p.get('held_out', {}).get('ema', {}).get('dense_error_cm', float('nan')):.3f} |"
            lines.append(line)
    lines += ["", "Table 6 analogue (with overwrite, in distribution):", "", "| seed | steps | handles error (cm) | dense error (cm) | foot skating | eval s |", "|---|---|---|---|---|---|"]
    for seed, r in results["bmm"].items():
        for steps, m in r["steps"].items():
            lines.append(f"| {seed} | {steps} | {m['handles_error_cm']:.4f} | {m['dense_error_cm']:.3f} | {m['foot_skating_ratio']:.4f} | {m['eval_s']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    args = dataclasses.replace(args, data=args.data or str(DEFAULT_DATA[args.corpus]))
    args.initialize()  # several processes: join the group before any JAX computation

    started = time.perf_counter()
    corpus = load_corpus(args.corpus, source=args.data, progress=not args.no_progress)
    train_set = curve_dataset(corpus, "train", progress=not args.no_progress)
    if args.bandai_namco:
        extra = load_corpus("bandai_namco", source=args.bandai_namco, progress=not args.no_progress)
        train_set = CurveDataset.concatenate([train_set, curve_dataset(extra, "train", progress=not args.no_progress)])
    val_set = curve_dataset(corpus, "validation", progress=not args.no_progress)
    held_set = None
    if args.holdout_contents:
        # Held-out contents: no window of theirs is trained on; all of them (both splits) are evaluated.
        held_train = matches_any(window_labels(corpus, train_set, "train"), args.holdout_contents)
        held_val = matches_any(window_labels(corpus, val_set, "validation"), args.holdout_contents)
        if not held_train.any() and not held_val.any():
            raise ValueError(f"--holdout-contents {' '.join(args.holdout_contents)}: no clip of {args.corpus} has such a content")
        held_set = CurveDataset.concatenate([train_set.subset(held_train), val_set.subset(held_val)])
        train_set, val_set = train_set.subset(~held_train), val_set.subset(~held_val)
    # The floor the skating metric measures against: the corpus's own training windows, never
    # the other corpus's moved into its character (whose ankles sit at another height).
    floor_height = floor_height_from(train_set)
    if args.also_corpus:
        # Character-agnostic training (BMM §8): the other corpus's windows as --corpus's character.
        other = load_corpus(args.also_corpus, source=args.also_data or str(DEFAULT_DATA[args.also_corpus]), progress=not args.no_progress)
        transfer = Transfer.between(*(CharacterProfile.load(PROFILES_DIR / f"{name}.json") for name in (args.also_corpus, args.corpus)))
        also_set = transfer_curve_dataset(curve_dataset(other, "train", progress=not args.no_progress), transfer)
        train_set = CurveDataset.concatenate([train_set, also_set])
    stats = FeatureStats.from_dataset(train_set)
    mapping = corpus.characteristic_map
    reflections = None
    if args.augment_mirror:
        reflections = rest_reflections(corpus.skeleton, dict(SKELETON_MAPS[mapping] if isinstance(mapping, str) else mapping))
    train_config = BMMTrainConfig(
        batch_size=args.batch_size, learning_rate=args.learning_rate, min_snr_gamma=args.min_snr_gamma or None,
        off_grid_handles=args.off_grid_handles, lr_schedule=args.lr_schedule, warmup_steps=args.warmup_steps,
        total_steps=args.steps if args.lr_schedule != "constant" else None, yaw_augmentation=args.augment_yaw,
        mirror_augmentation=args.augment_mirror, rest_reflections=reflections, ema_decay=args.ema_decay,
        still_augmentation=args.augment_still, spans=tuple(args.spans) or None, native_span_fraction=args.native_span,
    )  # fmt: skip
    metrics_config = None
    curve = None
    if args.model:
        saved = load_model(BUNDLED_BMM if args.model == "bundled" else args.model)
        model_config, stats, graphdef = saved.config, saved.stats, saved.graphdef
        state, history, train_s = None, [], 0.0
    else:
        init = load_model(BUNDLED_BMM if args.init == "bundled" else args.init) if args.init else None
        model_config = init.config if init else CONFIGS[args.config](prediction=args.prediction, off_grid_prior=args.off_grid_prior)
        stats = init.stats if init else stats
        layout = BezierLayout.from_controls(model_config.num_controls, model_config.stride)
        metrics_config = CurveMetricsConfig(layout, val_set.fps, floor_height)
        curve_sets = {"id": make_eval_set(val_set, key=jax.random.key(4321), num_windows=args.curve_windows)}
        if held_set is not None:
            curve_sets["held_out"] = make_eval_set(held_set, key=jax.random.key(4321), num_windows=args.curve_windows)
        evaluate = curve_evaluator(args, model_config, stats, metrics_config, curve_sets)
        if args.spans:  # windows of many lengths: unfitted windows as long as the longest, fitted in the step
            train_clips = corpus.split("train")
            if args.holdout_contents:  # no clip of a held-out content is trained on
                labels = np.asarray([clip_label(corpus.labels(int(c))) for c in train_clips])
                train_clips = train_clips[~matches_any(labels, args.holdout_contents)]
            data = DenseWindows.from_clips(corpus.motion(train_clips), corpus.characteristic_map, frames=args.spans[1] + 1)
        else:
            data = CurveArrays.from_dataset(train_set)
        graphdef, state, history, train_s, curve = train(args, model_config, train_config, data, stats, init, evaluate)
        if curve is not None:
            curve["reference"] = {
                name: curve_metrics(metrics_config, reference_curves(e, e.handles, layout), e, e.handles) for name, e in curve_sets.items()
            }
    coordinator = is_coordinator()
    leave_group()  # several processes: training is done; process 0 alone evaluates and writes
    if not coordinator:
        return {}

    layout = BezierLayout.from_controls(model_config.num_controls, model_config.stride)
    metrics_config = metrics_config or CurveMetricsConfig(layout, val_set.fps, floor_height)
    eval_set = make_eval_set(val_set, key=jax.random.key(1234), num_windows=args.eval_windows or None)
    results: dict = {
        "model": {"config": f"saved: {args.model}" if args.model else args.config, **dataclasses.asdict(model_config), "params": None},
        "training": {
            "corpus": args.corpus, "steps": 0 if args.model else int(np.max(np.asarray(state.step))), "steps_requested": args.steps,
            "train_seconds_limit": args.train_seconds, "batch_size": args.batch_size, "learning_rate": args.learning_rate,
            "seeds": ["saved"] if args.model else list(args.seeds), "saved_model": args.model, "fine_tuned_from": args.init,
            "min_snr_gamma": train_config.min_snr_gamma, "off_grid_handles": train_config.off_grid_handles,
            "train_windows": len(train_set), "bandai_namco": bool(args.bandai_namco), "also_corpus": args.also_corpus, "wall_s_this_run": train_s,
            "lr_schedule": args.lr_schedule, "warmup_steps": args.warmup_steps, "augment_yaw": args.augment_yaw,
            "augment_mirror": args.augment_mirror, "augment_still": args.augment_still, "rest_reflections": reflections, "holdout_contents": list(args.holdout_contents),
            "ema_decay": args.ema_decay, "spans": list(args.spans) or None, "native_span": args.native_span, "evaluated_parameters": args.parameters, "history": history, "learning_curve": curve,
        },
        "eval": {"n_windows": int(eval_set.start.shape[0]), "floor_height_cm": metrics_config.floor_height, "fps": val_set.fps},
        "ground_truth": ground_truth_metrics(metrics_config, eval_set),
        "reference": {
            name: curve_metrics(metrics_config, reference_curves(eval_set, h, layout), eval_set, h)
            for name, h in (("id", eval_set.handles), ("ood", eval_set.handles_ood))
        },
        "bmm": {},
    }
    if args.model:
        models = {"saved": saved}
    else:
        trained, folder = trained_parameters(state, args.parameters)
        models = {str(seed): BezierMotionModel(jax.tree.map(lambda x: x[i], trained), stats, graphdef, model_config) for i, seed in enumerate(args.seeds)}
        save_model(Path(args.run_dir) / folder, models[str(args.seeds[0])])
    seed_keys = {name: jax.random.key((0 if args.model else int(name)) + 99) for name in models}
    for name, model in models.items():
        results["model"]["params"] = count_parameters(model.params)
        results["bmm"][name] = evaluate_model(args, model, metrics_config, eval_set, seed_keys[name])
    if held_set is not None:
        held = make_eval_set(held_set, key=jax.random.key(1234), num_windows=args.eval_windows or None)
        results["held_out"] = {
            "contents": list(args.holdout_contents), "n_windows": int(held.start.shape[0]),
            # A saved model (--model) was trained elsewhere: these contents may have been in its training set.
            "trained_on": "a saved model: it may have trained on them" if args.model else "never trained on",
            "ground_truth": ground_truth_metrics(metrics_config, held),
            "reference": {
                name: curve_metrics(metrics_config, reference_curves(held, h, layout), held, h) for name, h in (("id", held.handles), ("ood", held.handles_ood))
            },
            "bmm": {name: handles_table(args, model, metrics_config, held, seed_keys[name]) for name, model in models.items()},
        }  # fmt: skip
    if curve is not None:
        plot_learning_curve(curve, curve["reference"], Path(args.out).with_suffix(".curve.png"))
        results["learning_curve_png"] = str(Path(args.out).with_suffix(".curve.png"))
    if args.handle_frames != "grid":
        # The same windows, joints, handle counts and noise; only the frames move.
        moved = make_eval_set(val_set, key=jax.random.key(1234), num_windows=args.eval_windows or None, handle_frames=args.handle_frames)
        section: dict = {
            "handle_frames": args.handle_frames,
            "frames": np.asarray(moved.handles.frame)[np.asarray(moved.handles.valid)].tolist(),
            "reference": {
                name: curve_metrics(metrics_config, reference_curves(moved, h, layout), moved, h)
                for name, h in (("id", moved.handles), ("ood", moved.handles_ood))
            },
            "bmm": {},
        }
        for name, model in models.items():
            table = handles_table(args, model, metrics_config, moved, seed_keys[name])
            grid = results["bmm"][name]["overwrite"]
            table["relative_to_grid"] = {
                split: {m: table[split][m] / grid[split][m] - 1.0 for m in ("dense_error_cm", "foot_skating_ratio")} for split in ("id", "ood")
            }
            section["bmm"][name] = table
        results["handle_frames"] = section
    results["wall_s"] = time.perf_counter() - started
    report = format_report(results)
    write_results(args.out, results, report)
    if not args.model:
        print(f"model in {Path(args.run_dir) / 'model'}")
    return results


if __name__ == "__main__":
    main()
