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

import dataclasses
import time
from typing import ClassVar, Literal

import jax

from bezmotion._src.io import write_results
from bezmotion.data.lafan1 import JOINT_NAMES, PARENTS, TEST_SUBJECTS, TRAIN_SUBJECTS, lafan1_statistics, lafan1_windows, load_lafan1
from bezmotion.data.sources import default_source
from _delta import MODE_NAMES, DeltaOptions, ModeRun, mean_over_seeds, mode_label, train_delta_mode
from bezmotion.delta.train import DeltaArrays, DeltaTrainConfig
from bezmotion.evaluation.lafan1 import (
    METRIC_VARIANTS,
    TEST_OFFSET,
    TEST_WINDOW,
    TRANSITION_LENGTHS,
    Lafan1Benchmark,
    evaluate_baselines,
    evaluate_transitions,
    format_table,
)
from bezmotion.delta.model import TABLE3_MODES, DeltaConfig, delta_inbetweener
from bezmotion.geometry import Skeleton
from bezmotion.training import count_parameters
from bezmotion._src.options import option, options, parse_options, presets

DEFAULT_DATA = default_source("lafan1")
TRAIN_WINDOW, TRAIN_OFFSET = 50, 20
CONFIGS = presets(DeltaConfig, parents=PARENTS)


@options
class Options(DeltaOptions):
    RUN_NAME: ClassVar[str] = "delta_lafan1"
    data: str = option(str(DEFAULT_DATA), help="LaFAN1 zip or BVH folder (default ../shared/data/lafan1/lafan1-subset.zip)")
    lengths: tuple[int, ...] = option(TRANSITION_LENGTHS, help=f"transition lengths (default {' '.join(map(str, TRANSITION_LENGTHS))})")
    modes: Literal["table3", "main"] = option("table3", help="train all Table 3 Δ-modes or Last/I only")

    def __post_init__(self):
        super().__post_init__()
        if self.steps < 1:
            raise ValueError(f"--steps must be positive, got {self.steps}")


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
    args = parse_options(Options, argv, description=__doc__)
    lengths = tuple(args.lengths)

    started = time.perf_counter()
    corpus = load_lafan1(args.data, use_cache=not args.no_cache)
    train_windows = lafan1_windows(corpus, TRAIN_SUBJECTS, TRAIN_WINDOW, TRAIN_OFFSET)
    bench = Lafan1Benchmark(lafan1_windows(corpus, TEST_SUBJECTS, TEST_WINDOW, TEST_OFFSET), lafan1_statistics(corpus))
    skeleton = Skeleton(PARENTS, JOINT_NAMES, bench.stats.offsets)  # the benchmark's constant skeleton
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

    def per_seed_metrics(graphdef, state, variant: str) -> dict:
        """``{seed: metrics}`` of every trained seed on the test windows under ``variant``."""
        per_seed = {}
        for i, seed in enumerate(args.seeds):
            params = jax.tree.map(lambda x, i=i: x[i], state.params)
            results["model"]["params"] = count_parameters(params)
            inbetween = delta_inbetweener(graphdef, params, skeleton, batch_size=args.eval_batch)
            per_seed[str(seed)] = evaluate_transitions(bench, inbetween, lengths, variant=variant)
        return per_seed

    def curve_point(graphdef, state) -> dict:
        return {"official": mean_over_seeds(list(per_seed_metrics(graphdef, state, "official").values()))}

    for mode in modes:
        model_config = CONFIGS[args.config](input_delta=mode[0], output_delta=mode[1])
        run = ModeRun.plan(args, model_config, train_config)
        graphdef, state, history, train_s, curve = train_delta_mode(
            args, run, model_config, train_config, data, window_frames=TRAIN_WINDOW, evaluate=curve_point
        )
        entry: dict = {"train_s_this_run": train_s, "history": history, **({"learning_curve": curve} if curve else {})}
        for variant in METRIC_VARIANTS:
            per_seed = per_seed_metrics(graphdef, state, variant)
            entry[variant] = {"mean": mean_over_seeds(list(per_seed.values())), "seeds": per_seed}
        results["ablation"][mode_label(mode)] = entry
        print(f"{mode_label(mode)}: trained in {train_s:.0f} s this run", flush=True)
        print(table3({"ablation": {mode_label(mode): entry}}, "official", lengths), flush=True)
    results["wall_s"] = time.perf_counter() - started
    report = format_report(results, lengths)
    write_results(args.out, results, report)
    return results


if __name__ == "__main__":
    main()
