"""Benchmark: BVH parsing and corpus loading (host-side I/O, cold vs warm).

- ``bvh_parse``: ``parse_bvh`` of one long LaFAN1 file (``walk4_subject1.bvh``, 4,918
  frames, extracted from the zip to a temporary folder and read with ``read_bvh``). The
  first call in the process includes jit compilation of the Euler → quaternion and
  continuity converters (``cold_s``); ``warm_s`` is the median of ``--repeats`` more.
- ``bandai_namco`` / ``anidance``: ``load_*`` of the whole corpus from its ``.tar.xz``
  into an empty temporary cache (``cold_s``: stream, parse, write the cache), then again
  (``warm_s``: fingerprint + cache read).

    python benchmarks/bvh_parse.py --out bvh_parse.json

Run it in a fresh process: "cold" is only cold the first time in a process. Sources that
are absent are skipped and reported as such.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from _timing import machine_info, write_json
from bezmotion.data.anidance import load_anidance
from bezmotion.data.bandai_namco import load_bandai_namco
from bezmotion.data.bvh import read_bvh
from bezmotion.data.cache import CACHE_ENV
from bezmotion._src.options import option, options, parse_options
from bezmotion.data.sources import data_dir

SHARED_DATA = data_dir()
LAFAN1_MEMBER = "walk4_subject1.bvh"


@options
class Options:
    lafan1_zip: Path = SHARED_DATA / "lafan1" / "lafan1-subset.zip"
    bandai: Path = SHARED_DATA / "bandai-namco" / "bandai-namco-2.tar.xz"
    anidance: Path = SHARED_DATA / "anidance" / "anidance.tar.xz"
    repeats: int = option(5, help="warm repeats of the BVH parse; the median is reported")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def _seconds(fn: Callable[[], Any]) -> tuple[float, Any]:
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


def bench_bvh_parse(lafan1_zip: Path, repeats: int) -> dict[str, Any]:
    """Cold (first, with jit compilation) and warm (median) ``read_bvh`` of one LaFAN1 file."""
    with tempfile.TemporaryDirectory() as tmp:
        with zipfile.ZipFile(lafan1_zip) as zf:
            path = Path(zf.extract(LAFAN1_MEMBER, tmp))
        size = path.stat().st_size
        cold_s, motion = _seconds(lambda: read_bvh(path))
        warm = [_seconds(lambda: read_bvh(path))[0] for _ in range(repeats)]
    return {
        "file": LAFAN1_MEMBER,
        "frames": motion.num_frames,
        "joints": motion.skeleton.num_joints,
        "bytes": size,
        "cold_s": cold_s,
        "warm_s": statistics.median(warm),
        "warm_times_s": warm,
        "frames_per_s_warm": motion.num_frames / statistics.median(warm),
    }


def bench_corpus_load(load: Callable[[Path], Any], source: Path, describe: Callable[[Any], dict]) -> dict[str, Any]:
    """Cold (empty cache) and warm (cache hit) load of a whole corpus; the cache is deleted afterwards."""
    previous = os.environ.get(CACHE_ENV)
    with tempfile.TemporaryDirectory() as cache:
        os.environ[CACHE_ENV] = cache
        try:
            cold_s, corpus = _seconds(lambda: load(source))
            warm_s, _ = _seconds(lambda: load(source))
            cache_bytes = sum(p.stat().st_size for p in Path(cache).glob("*.npz"))
        finally:
            if previous is None:
                os.environ.pop(CACHE_ENV, None)
            else:
                os.environ[CACHE_ENV] = previous
    timings = {"source": str(source), "cold_s": cold_s, "warm_s": warm_s, "cache_mb": cache_bytes / 2**20}
    return timings | describe(corpus)


def _load_anidance_quietly(source: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the missing-files warning is expected here
        return load_anidance(source, progress=False)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)

    result: dict[str, Any] = {"benchmark": "bvh_parse", "command": " ".join(sys.argv), "machine": machine_info()}
    benches = {
        "bvh_parse": (args.lafan1_zip, lambda: bench_bvh_parse(args.lafan1_zip, args.repeats)),
        "bandai_namco": (
            args.bandai,
            lambda: bench_corpus_load(
                lambda s: load_bandai_namco(s, progress=False),
                args.bandai,
                lambda c: {"clips": len(c), "frames": c.num_frames},
            ),
        ),
        "anidance": (
            args.anidance,
            lambda: bench_corpus_load(
                _load_anidance_quietly, args.anidance, lambda c: {"files": len(c), "frames": int(c.positions.shape[0])}
            ),
        ),
    }
    for name, (source, run) in benches.items():
        result[name] = run() if source.exists() else {"skipped": f"{source} not found"}
        print(name, json.dumps({k: v for k, v in result[name].items() if k != "warm_times_s"}), flush=True)
    print(json.dumps(result["machine"], indent=2))
    if args.out:
        write_json(args.out, result)
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
