"""Reproduce the official LaFAN1 baselines (zero-velocity, interpolation) at n = 5, 15, 30, 45.

    python experiments/lafan1_baselines.py --data ../shared/data/lafan1/lafan1-subset.zip --out results/lafan1_baselines.json

Builds the official test set (subject 5, windows of 65 frames, offset 40) and training
statistics (subjects 1–4, windows of 50, offset 20) from the LaFAN1 zip or a directory
of its BVH files, evaluates L2Q, L2P and NPSS in float64, prints the table and writes
``{"n_windows": …, "zerov": {"l2q": {"5": …}, "l2p": …, "npss": …}, "interp": {…}}``.
On a subset of the files (like ../shared/data's 27 of 77) the numbers differ from the
published full-dataset ones: say so when reporting them.
"""

from __future__ import annotations

import json
import time
from typing import Literal

from bezmotion._src.io import atomic_write_text
from bezmotion.evaluation.lafan1 import TRANSITION_LENGTHS, evaluate_baselines, format_table, lafan1_benchmark
from bezmotion._src.options import option, options, parse_options


@options
class Options:
    data: str = option(help="LaFAN1 zip (e.g. lafan1.zip) or a directory of its .bvh files")
    out: str = option(help="output JSON file")
    variant: Literal["official", "delta"] = option(
        "official", help="metric convention: the La Forge evaluator (default) or the Δ-interpolator code's L2Q/NPSS"
    )
    no_cache: bool = option(False, help="re-parse the BVH files instead of using the cache")


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)

    start = time.perf_counter()
    bench = lafan1_benchmark(args.data, use_cache=not args.no_cache)
    results = evaluate_baselines(bench, TRANSITION_LENGTHS, variant=args.variant)
    print(f"LaFAN1 baselines on {args.data}: {results['n_windows']} test windows, {args.variant} metrics")
    print(format_table(results))
    atomic_write_text(args.out, json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out} in {time.perf_counter() - start:.1f} s")
    return results


if __name__ == "__main__":
    main()
