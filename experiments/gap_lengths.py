"""The BMM's curves at keys any distance apart, per length bucket, against interpolation.

    python experiments/gap_lengths.py --out results/gap_lengths.json

For each span (frames from one key to the next; by default the two ends of each bucket
8–15, 16–30, 31–60 and 61–90), the Bandai-Namco validation clips are cut into windows of
``span + 1`` frames and fitted with the control grid extended (a control point every 6
frames, the last segment shorter; cached like every curve dataset). Each window gets its
keys (all six joints at both ends) and 1–4 handles at any frame, drawn per window
(:func:`~bezmotion.evaluation.curves.make_eval_set`). The BMM samples ``--steps`` DDIM steps
over a window of that length (:func:`~bezmotion.bmm.sampling.sample_curves` with
``num_frames``); the reference is the interpolation through the same keys and handles
(:func:`~bezmotion.evaluation.curves.reference_curves`). With ``--holdout-contents P …``
(a model trained without those contents) the validation windows leave them out, and
``--held-out`` measures their windows of both splits instead. Reported per span and per bucket
(the mean of its spans' windows):

- ``bmm_dense_cm`` / ``reference_dense_cm``: the six joints' dense position error of the
  curves against the mocap, and their ratio;
- ``handles_error_max_cm``: the farthest any curve lies from its handle (exactness).

Writes ``{"<bucket>": {"bmm_dense_cm", "reference_dense_cm", "ratio", "handles_error_max_cm",
"spans": {…}}, "model": …}`` and a Markdown report beside it.
"""

from __future__ import annotations

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion._src.io import write_results
from bezmotion._src.options import option, options, parse_options
from bezmotion.pipeline.authoring import resolve_bmm
from bezmotion.bezier import BezierLayout
from bezmotion.bmm.sampling import load_model, sample_curves
from bezmotion.data.corpus import SPLITS
from bezmotion.data.curves import CurveDataset, curve_dataset
from bezmotion.data.sources import default_source, load_corpus
from bezmotion.evaluation.curves import dense_positions, make_eval_set, reference_curves, sample_in_chunks
from bezmotion.evaluation.metrics import mean_position_error
from _common import matches_any, window_labels

BUCKETS = {"8-15": (8, 15), "16-30": (16, 30), "31-60": (31, 60), "61-90": (61, 90)}
"""Length buckets (frames from one key to the next), each measured at its two ends by default."""


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it)")
    model: str = option("bandai_namco", help="a pretrained BMM's name (bezmotion models) or a saved BMM's folder")
    spans: tuple[int, ...] = option(
        tuple(end for bounds in BUCKETS.values() for end in bounds), help="spans to measure (default each bucket's two ends)"
    )
    windows: int = option(100, help="windows measured per span")
    holdout_contents: tuple[str, ...] = option(
        (), metavar="PATTERN", help="contents a model was trained without (bmm_lafan1.py --holdout-contents): left out of the validation windows"
    )
    held_out: bool = option(False, help="measure the --holdout-contents' windows of both splits instead of the validation windows")
    offset: int = option(15, help="frames between the starts of consecutive windows of a clip")
    steps: int = option(10, help="DDIM steps")
    seed: int = option(0, help="the windows' handles and the sampler's key")
    no_progress: bool = False

    def __post_init__(self):
        for span in self.spans:
            if not 2 <= span <= 900:
                raise ValueError(f"--spans: a span is 2 … 900 frames, got {span}")
        if self.held_out and not self.holdout_contents:
            raise ValueError("--held-out measures the --holdout-contents' windows: give the patterns")
        if self.windows < 1 or self.offset < 1 or self.steps < 1:
            raise ValueError(f"--windows, --offset and --steps must be positive, got {self.windows}, {self.offset}, {self.steps}")


def bucket_of(span: int) -> str | None:
    return next((name for name, (low, high) in BUCKETS.items() if low <= span <= high), None)


def measured_windows(corpus, span: int, args: Options) -> CurveDataset:
    """The windows of ``span + 1`` frames measured: the validation clips' (less the held-out
    contents), or with ``--held-out`` the held-out contents' of both splits."""
    fitted = {split: curve_dataset(corpus, split, window=span + 1, offset=args.offset, progress=not args.no_progress) for split in SPLITS}
    if not args.holdout_contents:
        return fitted["validation"]
    held = {split: matches_any(window_labels(corpus, data, split), args.holdout_contents) for split, data in fitted.items()}
    if args.held_out:
        return CurveDataset.concatenate([fitted[split].subset(held[split]) for split in SPLITS])
    return fitted["validation"].subset(~held["validation"])


def measure_span(bmm, corpus, span: int, args: Options) -> dict:
    """One span's windows: the BMM's and the reference's dense errors and the handles' error."""
    dataset = measured_windows(corpus, span, args)
    layout = BezierLayout(span + 1, dataset.layout.stride)
    eval_set = make_eval_set(dataset, key=jax.random.key(args.seed), num_windows=min(args.windows, len(dataset)), handle_frames="any", per_window=True)
    sample = functools.partial(sample_curves, bmm, steps=args.steps, num_frames=span + 1)
    curves = sample_in_chunks(lambda s, e, h, k: sample(s, e, h, key=k), eval_set, eval_set.handles, key=jax.random.key(args.seed + 1))
    reference = reference_curves(eval_set, eval_set.handles, layout)
    truth = jnp.asarray(eval_set.dense_pos)
    bmm_dense = dense_positions(layout, curves.ctrl_pos, curves.ctrl_tangent)
    ref_dense = dense_positions(layout, reference.ctrl_pos, reference.ctrl_tangent)
    h = eval_set.handles
    at = bmm_dense[jnp.arange(h.frame.shape[0])[:, None], h.frame, h.joint]  # (windows, slots, 3)
    miss = jnp.where(h.valid, jnp.linalg.norm(at - h.position, axis=-1), 0.0)
    return {
        "windows": int(truth.shape[0]),
        "bmm_dense_cm": float(mean_position_error(bmm_dense, truth)),
        "reference_dense_cm": float(mean_position_error(ref_dense, truth)),
        "handles_error_max_cm": float(miss.max()),
    }


def report(results: dict) -> str:
    lines = [
        f"# The BMM at keys any distance apart: {results['model']['name']}, its config's window {results['model']['window_frames']} frames apart, "
        f"{results['steps']} DDIM steps, {results['windows_of']} windows"
        + (f" (held-out contents {' '.join(results['holdout_contents'])})" if results["holdout_contents"] else ""),
        "",
        "| bucket (frames apart) | windows | BMM dense (cm) | interpolation dense (cm) | ratio | handles error max (cm) |",
        "|---|---|---|---|---|---|",
    ]
    for name in BUCKETS:
        if name in results:
            r = results[name]
            lines.append(f"| {name} | {r['windows']} | {r['bmm_dense_cm']:.2f} | {r['reference_dense_cm']:.2f} | {r['ratio']:.2f} | {r['handles_error_max_cm']:.1e} |")
    lines += ["", "| span | windows | BMM dense (cm) | interpolation dense (cm) | ratio |", "|---|---|---|---|---|"]
    for span, r in results["spans"].items():
        lines.append(f"| {span} | {r['windows']} | {r['bmm_dense_cm']:.2f} | {r['reference_dense_cm']:.2f} | {r['bmm_dense_cm'] / r['reference_dense_cm']:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    started = time.perf_counter()
    folder, _ = resolve_bmm(args.model)
    bmm = load_model(folder)
    corpus = load_corpus("bandai_namco", source=default_source("bandai_namco"), progress=not args.no_progress)
    spans = {str(span): measure_span(bmm, corpus, span, args) for span in args.spans}
    results: dict = {
        "model": {"name": args.model, "folder": str(folder), "window_frames": bmm.config.num_frames - 1},
        "windows_of": "held-out contents" if args.held_out else "validation", "holdout_contents": list(args.holdout_contents),
        "steps": args.steps, "seed": args.seed, "spans": spans,
    }  # fmt: skip
    for name in BUCKETS:
        members = [r for span, r in spans.items() if bucket_of(int(span)) == name]
        if members:
            weights = np.asarray([r["windows"] for r in members], float)
            mean = lambda key, rows=members, w=weights: float(np.average([r[key] for r in rows], weights=w))  # noqa: E731
            results[name] = {
                "windows": int(weights.sum()), "bmm_dense_cm": mean("bmm_dense_cm"), "reference_dense_cm": mean("reference_dense_cm"),
                "handles_error_max_cm": max(r["handles_error_max_cm"] for r in members),
                "spans": [int(span) for span, r in spans.items() if bucket_of(int(span)) == name],
            }  # fmt: skip
            results[name]["ratio"] = results[name]["bmm_dense_cm"] / results[name]["reference_dense_cm"]
    results["wall_s"] = time.perf_counter() - started
    write_results(args.out, results, report(results))
    return results


if __name__ == "__main__":
    main()
