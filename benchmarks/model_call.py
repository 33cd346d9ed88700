"""Benchmark: what a user's call costs, ``model.inbetween(keys, handles, key=…)`` on the bundled models.

The model object's eager call (its input checks run inside the compiled program, the result
waited for), one window with a right-hand handle 20 cm above the mocap at frame 12, feet
locked, 10 DDIM steps, per IK. The first call (tracing and compiling, or reading the
persistent compilation cache) and the steady state (median and minimum of ``--repeats``
calls, each with a new sampling key) are reported separately, with the machine and versions.

    python benchmarks/model_call.py --ik learned exact exact_rig --out model_call.json
"""

from __future__ import annotations

import sys
import time

import jax
import numpy as np

import bezmotion as bm
from _timing import machine_info, report
from bezmotion._src.options import option, options, parse_options


@options
class Options:
    ik: tuple[str, ...] = option(("learned", "exact"), help="the IKs to time (bm.pretrained's ik=)")
    repeats: int = option(15, help="timed calls after the first")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def time_calls(ik: str, repeats: int) -> dict[str, float]:
    model = bm.pretrained("bandai_namco", ik=ik)
    clip = bm.read_bvh(bm.DEMO_CLIP)
    keys = model.poses(clip, [0, 30])
    handles = model.handles({"right_hand": (12, (0.0, 20.0, 0.0))}, relative_to=keys)
    options = bm.InbetweenOptions(foot_lock=True)
    call = lambda k: jax.block_until_ready(model.inbetween(keys, handles, key=jax.random.key(k), options=options))  # noqa: E731
    t0 = time.perf_counter()
    call(0)
    first = time.perf_counter() - t0
    steady = []
    for k in range(1, repeats + 1):
        t0 = time.perf_counter()
        call(k)
        steady.append(time.perf_counter() - t0)
    return {"first_call_s": first, "steady_median_ms": 1e3 * float(np.median(steady)), "steady_min_ms": 1e3 * min(steady)}


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    rows = {}
    for ik in args.ik:
        rows[ik] = time_calls(ik, args.repeats)
        r = rows[ik]
        print(f"{ik}: first call {r['first_call_s']:.1f} s, steady {r['steady_median_ms']:.1f} ms (min {r['steady_min_ms']:.1f})", flush=True)
    result = {"benchmark": "model_call", "windows": 1, "steps": 10, "foot_lock": True, "rows": rows, "machine": machine_info()}
    return report(result, rows, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
