"""Benchmark: Bézier curve fitting throughput and the time to build the cached curve datasets.

    python benchmarks/bezier_fit.py --data ../shared/data --out bezier_fit.json

1. Throughput: ``fit_curves`` on batches of 31-frame windows of the six characteristic
   joints (real LaFAN1 subject-5 windows when ``--data`` has LaFAN1, else random walks),
   stride 6, both variants; compile time and steady state reported separately, in
   windows per second.
2. Dataset build (with ``--data``): for LaFAN1 and Bandai-Namco, train and validation,
   the time to cut, FK, align, label and fit every window (``build_curve_dataset``),
   and to write and read back the ``.npz`` cache entry, after loading the (already
   cached) corpus, which is timed on its own.
"""

from __future__ import annotations

import functools
import sys
import tempfile
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report, time_jitted
from bezmotion.bezier import BezierLayout, fit_curves
from bezmotion.data.corpus import SPLITS, motion_clips
from bezmotion.data.curves import DEFAULT_OFFSET, DEFAULT_WINDOW, CurveDataset, build_curve_dataset, characteristic_windows
from bezmotion.data.sources import default_source, load_corpus
from bezmotion._src.options import option, options, parse_options


@options
class Options:
    data: str | None = option(None, help="the shared data folder (lafan1/, bandai-namco/); optional")
    windows: int = option(4096, help="windows per fitting call (default 4096)")
    stride: int = 6
    repeats: int = option(5, help="timed repeats; the median is reported")
    skip_build: bool = option(False, help="only measure throughput")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def windows_for_throughput(data: Path | None, count: int, window: int) -> tuple[np.ndarray, str]:
    """``(count, 6, window, 3)`` float32 trajectories: real LaFAN1 windows (tiled) or random walks."""
    zip_path = default_source("lafan1", data) if data else None
    if zip_path is not None and zip_path.exists():
        clips = motion_clips(load_corpus("lafan1", source=zip_path), "validation")
        pos, _, _, _ = characteristic_windows(clips, "lafan1", window=window)
        pos = np.resize(pos, (count,) + pos.shape[1:])
        source = "LaFAN1 subject 5 windows"
    else:
        rng = np.random.default_rng(0)
        pos = np.cumsum(rng.normal(size=(count, window, 6, 3)), axis=1).astype(np.float32)
        source = "random walks"
    return np.moveaxis(pos, 2, 1), source


def throughput(points: np.ndarray, stride: int, repeats: int) -> dict:
    layout = BezierLayout(points.shape[2], stride)
    x = jnp.asarray(points)
    out = {}
    for name, pin in (("pinned", True), ("free", False)):
        fn = functools.partial(fit_curves, layout, pin_positions=pin)
        timing = time_jitted(fn, (x,), repeats=repeats)
        out[name] = {**timing, "windows_per_s": points.shape[0] / timing["steady_s"]}
    return out


def dataset_build(data: Path) -> dict:
    """Build every curve dataset from the cached corpora, timing each stage."""
    results = {}
    for name in ("lafan1", "bandai_namco"):
        path = default_source(name, data)
        if not path.exists():
            continue
        t0 = time.perf_counter()
        corpus = load_corpus(name, source=path, progress=False)
        load_s = time.perf_counter() - t0
        for split in SPLITS:
            t0 = time.perf_counter()
            clips = motion_clips(corpus, split)
            t1 = time.perf_counter()
            dataset = build_curve_dataset(clips, corpus.characteristic_map, progress=False)
            t2 = time.perf_counter()
            with tempfile.TemporaryDirectory() as tmp:
                path_npz = Path(tmp) / "curves.npz"
                np.savez(path_npz, **dataset.to_arrays())
                t3 = time.perf_counter()
                with np.load(path_npz) as f:
                    CurveDataset.from_arrays({k: f[k] for k in f.files})
                t4 = time.perf_counter()
                size = path_npz.stat().st_size
            results[f"{name}/{split}"] = {
                "windows": len(dataset),
                "corpus_load_s": load_s,
                "select_clips_s": t1 - t0,
                "fit_s": t2 - t1,
                "cache_write_s": t3 - t2,
                "cache_read_s": t4 - t3,
                "cache_mb": size / 2**20,
                "windows_per_s": len(dataset) / (t2 - t1),
                "mean_fit_rms_cm": float(dataset.fit_rms.mean()),
            }
    total = sum(r["select_clips_s"] + r["fit_s"] + r["cache_write_s"] for r in results.values())
    return {"splits": results, "total_build_s": total}


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)

    data = Path(args.data) if args.data else None
    points, source = windows_for_throughput(data, args.windows, DEFAULT_WINDOW)
    result = {
        "benchmark": "bezier_fit",
        "window": DEFAULT_WINDOW,
        "joints": 6,
        "stride": args.stride,
        "batch_windows": args.windows,
        "throughput_data": source,
        "throughput": throughput(points, args.stride, args.repeats),
        "dataset_offset": DEFAULT_OFFSET,
        "machine": machine_info(),
    }
    if data is not None and not args.skip_build:
        result["dataset_build"] = dataset_build(data)
    summary = {
        name: {k: round(v[k], 4) for k in ("lower_s", "compile_s", "steady_s", "windows_per_s")}
        for name, v in result["throughput"].items()
    }
    if "dataset_build" in result:
        summary["dataset_build"] = {
            k: {m: round(v[m], 3) for m in ("windows", "fit_s", "cache_write_s", "windows_per_s")}
            for k, v in result["dataset_build"]["splits"].items()
        }
        summary["total_build_s"] = round(result["dataset_build"]["total_build_s"], 2)
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
