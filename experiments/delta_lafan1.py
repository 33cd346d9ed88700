"""Train the Δ-interpolator on LaFAN1 and evaluate it with the official benchmark.

    python experiments/delta_lafan1.py --out results/delta_lafan1.json

Trains on the official training windows (subjects 1–4, 50 frames, offset 20) with the
paper's losses, gap sampling and optimiser (Adam, linear warm-up then ×0.1 steps, the
paper's 300-epoch schedule squeezed into ``--steps``), checkpointing into
``--run-dir/<input>-<output>/`` (rerunning the command resumes there), then evaluates every
trained seed on the test windows (subject 5, 65 frames, offset 40) at n = 5, 15, 30, 45
with both metric conventions (``official``: the La Forge evaluator; ``delta``: L2Q and
NPSS on quaternions hemisphere-aligned to the last past frame, as the Δ-interpolator's
code), beside the zero-velocity and interpolation baselines:

- Table 1 layout: zero-velocity, interpolation and the Δ-interpolator (Last / I);
- Table 3 layout: the Δ-mode ablation (``--modes table3``: Last/I, Last/Last, No/No,
  No/I, No/Last; ``--modes main`` trains the Δ-interpolator only).

Metrics are averaged over seeds (the paper: 8 seeds, last 10 epochs). ``--config cpu``
(default) trains in minutes on a 2-core CPU; ``--config paper`` is the paper's 44.5 M
parameter model and runs unchanged on a GPU. n = 45 lies beyond the training gaps
(5–39): its gap-length embedding is never trained, as in the paper, which reports
5–30 only. Writes the JSON and a Markdown report beside it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

from bezmotion._io import atomic_write_text
from bezmotion.checkpoint import CheckpointStore
from bezmotion.data.cache import cache_dir
from bezmotion.data.lafan1 import TEST_SUBJECTS, TRAIN_SUBJECTS, lafan1_statistics, lafan1_windows, load_lafan1
from bezmotion.delta_train import (
    DeltaArrays,
    DeltaTrainConfig,
    init_delta_train_states,
    make_delta_train_step,
    run_delta_training,
)
from bezmotion.evaluation import (
    METRIC_VARIANTS,
    TEST_OFFSET,
    TEST_WINDOW,
    TRANSITION_LENGTHS,
    Lafan1Benchmark,
    evaluate_baselines,
    evaluate_transitions,
    format_table,
)
from bezmotion.models.delta import TABLE3_MODES, DeltaConfig, count_parameters, delta_inbetweener
from bezmotion.train import compile_train_step

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "lafan1" / "lafan1-subset.zip"
TRAIN_WINDOW, TRAIN_OFFSET = 50, 20
CONFIGS = {
    "cpu": DeltaConfig.cpu,
    "paper": DeltaConfig.paper,
    "tiny": lambda **kw: DeltaConfig.cpu(**{"width": 32, "num_blocks": 1, "num_heads": 2, "embedding_dim": 8, **kw}),
}
MODE_NAMES = {"last": "Last", "none": "No", "interpolation": "I"}


def mode_label(mode: tuple[str, str]) -> str:
    return f"{mode[0]}-{mode[1]}"


def train_mode(args, model_config: DeltaConfig, train_config: DeltaTrainConfig, data: DeltaArrays):
    """Train (or resume) one Δ-mode for all seeds at once; returns ``(graphdef, state, history, seconds)``."""
    graphdef, state = init_delta_train_states(model_config, train_config, args.seeds)
    step = compile_train_step(
        make_delta_train_step(graphdef, model_config, train_config, window_frames=TRAIN_WINDOW), num_seeds=len(args.seeds)
    )
    device = jax.devices()[0]
    run_dir = Path(args.run_dir) / mode_label((model_config.input_delta, model_config.output_delta))
    store = CheckpointStore(run_dir / "checkpoints")
    config = {
        "model": dataclasses.asdict(model_config),
        "train": {**dataclasses.asdict(train_config), "seeds": list(args.seeds), "num_steps": args.steps},
    }
    started = time.perf_counter()
    # Restored checkpoints are device-committed; commit fresh states too (one compilation).
    state, history = run_delta_training(
        lambda s, d: step(jax.device_put(s, device), d), state, data, num_steps=args.steps, store=store,
        checkpoint_every=args.checkpoint_every, config=config, progress=not args.no_progress,
    )  # fmt: skip
    store.close()
    return graphdef, state, history, time.perf_counter() - started


def mean_metrics(per_seed: list[dict]) -> dict:
    """Average ``{"l2q": {"5": …}, …}`` dictionaries over seeds."""
    return {m: {n: float(np.mean([r[m][n] for r in per_seed])) for n in per_seed[0][m]} for m in per_seed[0]}


def table3(results: dict, variant: str, lengths) -> str:
    header = "| Δ-mode input | output | " + " | ".join(f"{m.upper()} n={n}" for m in ("l2q", "l2p", "npss") for n in lengths) + " |"
    lines = [header, "|" + "---|" * (2 + 3 * len(lengths))]
    for label, entry in results["ablation"].items():
        inp, out = label.split("-")
        r = entry[variant]["mean"]
        vals = " | ".join(f"{r[m][str(n)]:.4f}" for m in ("l2q", "l2p", "npss") for n in lengths)
        lines.append(f"| {MODE_NAMES[inp]} | {MODE_NAMES[out]} | {vals} |")
    return "\n".join(lines)


def format_report(results: dict, lengths) -> str:
    m, t = results["model"], results["training"]
    lines = [
        f"Δ-interpolator on LaFAN1 ({m['config']} config: width {m['width']}, {m['num_blocks']} blocks, {m['num_heads']} heads, "
        f"{m['params']:,} parameters; {t['steps']} steps × batch {t['batch_size']} ≈ {t['epochs']:.1f} epochs of "
        f"{t['train_windows']} training windows, peak lr {t['learning_rate']}, {len(t['seeds'])} seed(s), metrics averaged "
        f"over seeds); {results['n_windows']} subject-5 test windows.",
    ]
    main = mode_label(TABLE3_MODES[0])
    for variant in METRIC_VARIANTS:
        if main in results["ablation"]:
            rows = {
                "zero-velocity": results["baselines"][variant]["zerov"],
                "interpolation": results["baselines"][variant]["interp"],
                "Δ-interpolator": results["ablation"][main][variant]["mean"],
            }
            lines += ["", f"Table 1 layout ({variant} metrics):", "", format_table(rows, lengths)]
        lines += ["", f"Table 3 layout, Δ-mode ablation ({variant} metrics):", "", table3(results, variant, lengths)]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="output JSON (a .md report is written beside it)")
    parser.add_argument("--data", default=str(DEFAULT_DATA), help="LaFAN1 zip or BVH folder (default ../shared/data/lafan1/lafan1-subset.zip)")
    parser.add_argument("--config", choices=tuple(CONFIGS), default="cpu", help="model size (default cpu; tiny: smoke tests)")
    parser.add_argument("--modes", choices=("table3", "main"), default="table3", help="train all Table 3 Δ-modes or Last/I only")
    parser.add_argument("--steps", type=int, default=3000, help="training steps per Δ-mode (default 3000)")
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--learning-rate", type=float, default=2e-4, help="peak learning rate (paper: 2e-4)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds trained together (vmapped)")
    parser.add_argument("--run-dir", default=None, help="checkpoints (default: <cache>/runs/delta_lafan1_<config>)")
    parser.add_argument("--checkpoint-every", type=int, default=500)
    parser.add_argument("--eval-batch", type=int, default=256, help="test windows per vectorised chunk at evaluation")
    parser.add_argument("--lengths", type=int, nargs="+", default=list(TRANSITION_LENGTHS), help="transition lengths (default 5 15 30 45)")
    parser.add_argument("--no-cache", action="store_true", help="re-parse the BVH files instead of using the cache")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if args.steps < 1:
        parser.error(f"--steps must be positive, got {args.steps}")
    args.run_dir = args.run_dir or str(cache_dir() / "runs" / f"delta_lafan1_{args.config}")
    lengths = tuple(args.lengths)

    started = time.perf_counter()
    corpus = load_lafan1(args.data, use_cache=not args.no_cache)
    train_windows = lafan1_windows(corpus, TRAIN_SUBJECTS, TRAIN_WINDOW, TRAIN_OFFSET)
    bench = Lafan1Benchmark(lafan1_windows(corpus, TEST_SUBJECTS, TEST_WINDOW, TEST_OFFSET), lafan1_statistics(corpus))
    data = DeltaArrays.from_windows(train_windows)
    train_config = DeltaTrainConfig.for_steps(args.steps, batch_size=args.batch_size, learning_rate=args.learning_rate)
    modes = TABLE3_MODES if args.modes == "table3" else TABLE3_MODES[:1]

    results: dict = {
        "data": str(args.data),
        "n_windows": bench.num_windows,
        "lengths": list(lengths),
        "model": {"config": args.config, **dataclasses.asdict(CONFIGS[args.config]()), "params": None},
        "training": {
            "steps": args.steps, "batch_size": args.batch_size, "learning_rate": args.learning_rate, "seeds": args.seeds,
            "train_windows": train_windows.num_windows, "epochs": args.steps * args.batch_size / train_windows.num_windows,
            "schedule": dataclasses.asdict(train_config),
        },  # fmt: skip
        "baselines": {v: evaluate_baselines(bench, lengths, variant=v) for v in METRIC_VARIANTS},
        "ablation": {},
    }
    for mode in modes:
        model_config = CONFIGS[args.config](input_delta=mode[0], output_delta=mode[1])
        graphdef, state, history, train_s = train_mode(args, model_config, train_config, data)
        entry: dict = {"train_s_this_run": train_s, "history": history}
        for variant in METRIC_VARIANTS:
            per_seed = {}
            for i, seed in enumerate(args.seeds):
                params = jax.tree.map(lambda x, i=i: x[i], state.params)
                results["model"]["params"] = count_parameters(params)
                inbetween = delta_inbetweener(graphdef, params, bench.stats.offsets, batch_size=args.eval_batch)
                per_seed[str(seed)] = evaluate_transitions(bench, inbetween, lengths, variant=variant)
            entry[variant] = {"mean": mean_metrics(list(per_seed.values())), "seeds": per_seed}
        results["ablation"][mode_label(mode)] = entry
        print(f"{mode_label(mode)}: trained in {train_s:.0f} s this run", flush=True)
        print(table3({"ablation": {mode_label(mode): entry}}, "official", lengths), flush=True)
    results["wall_s"] = time.perf_counter() - started
    out = Path(args.out)
    report = format_report(results, lengths)
    print(report)
    atomic_write_text(out, json.dumps(results, indent=2) + "\n")
    atomic_write_text(out.with_suffix(".md"), report + "\n")
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return results


if __name__ == "__main__":
    main()
