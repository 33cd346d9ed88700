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

from bezmotion.io import write_results
from bezmotion.assets import BUNDLED_BMM
from bezmotion.bmm.evaluation import (
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
from bezmotion.bmm.denoiser import PREDICTIONS, BMMConfig
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, load_model, sample_curves, save_model
from bezmotion.bmm.train import CurveArrays, BMMTrainConfig, init_bmm_train_states, make_bmm_train_step
from bezmotion.options import option, options, parse_options, presets
from bezmotion.training import compile_train_step, count_parameters, data_mesh, run_training
from bezmotion.training.distributed import DistributedOptions, is_coordinator, leave_group
from _common import runs_dir

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
    bandai_namco: str | None = option(None, help="also train on Bandai-Namco's training clips (archive or folder)")
    config: str = option("cpu", choices=CONFIGS, help="model size (default cpu; tiny: smoke tests)")
    prediction: str = option(
        "x0", choices=PREDICTIONS, help="decoder output: x0 (the paper) or residual over the reference curves through the conditions (ours)"
    )
    steps: int = option(6000, help="training steps (default 6000)")
    batch_size: int = BMMTrainConfig.batch_size
    learning_rate: float = BMMTrainConfig.learning_rate
    min_snr_gamma: float = option(BMMTrainConfig.min_snr_gamma, help="Min-SNR-γ loss weighting (paper: 5; 0 = off)")
    seeds: tuple[int, ...] = option((0,), help="seeds trained together (vmapped)")
    run_dir: str | None = option(None, help="checkpoints and the final model (default: <cache>/runs/bmm_lafan1_<config>)")
    checkpoint_every: int = 500
    eval_windows: int = option(1000, help="subject-5 windows evaluated (default 1000; 0 = all)")
    guidance: float = option(1.0, help="classifier-free guidance scale at sampling (1 = off)")
    table6_steps: tuple[int, ...] = option(STEP_COUNTS, help="DDIM step counts compared (default 5 10 25 50 100)")
    model: str | None = option(None, help="evaluate this saved BMM (a folder, or 'bundled') instead of training one")
    init: str | None = option(None, help="fine-tune this saved BMM (a folder, or 'bundled'): its size, statistics and parameters")
    handle_frames: str = option(
        "grid", choices=HANDLE_FRAMES, help="also evaluate handles off the control grid: off_grid (between control frames) or any (1…29)"
    )
    off_grid_handles: float = option(0.0, help="training: probability that a handle sits at any frame 1…29 (default 0: the paper's)")
    no_progress: bool = False

    def __post_init__(self):
        super().__post_init__()
        if self.model and self.init:
            raise ValueError("--model evaluates a saved BMM, --init fine-tunes one: give one of them")
        if self.run_dir is None and self.init:
            object.__setattr__(self, "run_dir", str(runs_dir(f"bmm_{self.corpus}_finetune_{Path(self.init).name}_offgrid{self.off_grid_handles:g}")))
        if self.run_dir is None:
            suffix = "" if self.prediction == "x0" else f"_{self.prediction}"
            object.__setattr__(self, "run_dir", str(runs_dir(f"bmm_{self.corpus}_{self.config}{suffix}")))
        if self.bandai_namco and self.corpus != "lafan1":
            raise ValueError("--bandai-namco adds Bandai-Namco to LaFAN1 training; with --corpus bandai_namco it is already the corpus")


def concat_datasets(parts: list[CurveDataset]) -> CurveDataset:
    first = parts[0]
    return dataclasses.replace(first, **{k: np.concatenate([getattr(p, k) for p in parts]) for k in CurveDataset._ARRAYS})


def train(args, model_config: BMMConfig, train_config: BMMTrainConfig, train_set: CurveDataset, stats: FeatureStats, init=None):
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
    store.check_resumable(config)
    started = time.perf_counter()
    state, history = run_training(
        step, state, CurveArrays.from_dataset(train_set), num_steps=args.steps, store=store,
        checkpoint_every=args.checkpoint_every, config=config, progress=not args.no_progress,
    )  # fmt: skip
    store.close()
    return graphdef, state, history, time.perf_counter() - started


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

    lines = [
        f"BMM on {results['training']['corpus']} ({results['model']['config']} config, {results['model']['prediction']} prediction, "
        f"{results['model']['params']:,} parameters, "
        f"{results['training']['steps']} steps × batch {results['training']['batch_size']}, "
        f"{len(results['training']['seeds'])} seed(s)); {results['eval']['n_windows']} validation windows; curves before IK.",
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
        train_set = concat_datasets([train_set, curve_dataset(extra, "train", progress=not args.no_progress)])
    val_set = curve_dataset(corpus, "validation", progress=not args.no_progress)
    stats = FeatureStats.from_dataset(train_set)
    train_config = BMMTrainConfig(
        batch_size=args.batch_size, learning_rate=args.learning_rate, min_snr_gamma=args.min_snr_gamma or None,
        off_grid_handles=args.off_grid_handles,
    )  # fmt: skip
    if args.model:
        saved = load_model(BUNDLED_BMM if args.model == "bundled" else args.model)
        model_config, stats, graphdef = saved.config, saved.stats, saved.graphdef
        state, history, train_s = None, [], 0.0
    else:
        init = load_model(BUNDLED_BMM if args.init == "bundled" else args.init) if args.init else None
        model_config = init.config if init else CONFIGS[args.config](prediction=args.prediction)
        stats = init.stats if init else stats
        graphdef, state, history, train_s = train(args, model_config, train_config, train_set, stats, init)
    coordinator = is_coordinator()
    leave_group()  # several processes: training is done; process 0 alone evaluates and writes
    if not coordinator:
        return {}

    layout = BezierLayout.from_controls(model_config.num_controls, model_config.stride)
    metrics_config = CurveMetricsConfig(layout, val_set.fps, floor_height_from(train_set))
    eval_set = make_eval_set(val_set, key=jax.random.key(1234), num_windows=args.eval_windows or None)
    results: dict = {
        "model": {"config": f"saved: {args.model}" if args.model else args.config, **dataclasses.asdict(model_config), "params": None},
        "training": {
            "corpus": args.corpus, "steps": 0 if args.model else args.steps, "batch_size": args.batch_size, "learning_rate": args.learning_rate,
            "seeds": ["saved"] if args.model else list(args.seeds), "saved_model": args.model, "fine_tuned_from": args.init,
            "min_snr_gamma": train_config.min_snr_gamma, "off_grid_handles": train_config.off_grid_handles,
            "train_windows": len(train_set), "bandai_namco": bool(args.bandai_namco), "wall_s_this_run": train_s,
            "history": history,
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
        models = {str(seed): BezierMotionModel(jax.tree.map(lambda x: x[i], state.ema), stats, graphdef, model_config) for i, seed in enumerate(args.seeds)}
        save_model(Path(args.run_dir) / "model", models[str(args.seeds[0])])
    seed_keys = {name: jax.random.key((0 if args.model else int(name)) + 99) for name in models}
    for name, model in models.items():
        results["model"]["params"] = count_parameters(model.params)
        results["bmm"][name] = evaluate_model(args, model, metrics_config, eval_set, seed_keys[name])
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
