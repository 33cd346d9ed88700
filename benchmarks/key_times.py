"""Benchmark: an in-between through keys at given frames (:func:`bezmotion.inbetween_at`).

Evenly spaced keys a multiple of 6 frames apart are one compiled chain; keys at unequal
distances are one window after another, one compiled program per distinct gap. This times
both on the bundled Bandai-Namco models with the exact IK (10 DDIM steps, foot lock on as in
``bezmotion inbetween``, a right-hand handle 25 cm above the straight line in the middle of
every window): the first call (tracing and compiling every program it needs, then running)
and the steady state (the median of ``--repeats`` further calls), separately, with the
machine and library versions. No persistent compilation cache is used.

    python benchmarks/key_times.py --times 0,30,60,90 0,20,65,90 --out key_times.json

The keys are the bundled clip's frames at those times, played forward and back (it has 40
frames); the time does not depend on the motion.
"""

from __future__ import annotations

import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report
from bezmotion.assets import BUNDLED_BMM, BUNDLED_IK, DEMO_CLIP
from bezmotion.bmm.sampling import Handles, load_model
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.ik.exact import exact_ik
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protocol import pose_from_motion, targets_from_pose
from bezmotion.ik.protores import load_ik_model, protores_ik_fn
from bezmotion._src.options import option, options, parse_options
from bezmotion.pipeline import InbetweenOptions, Inbetweener, Transfer, inbetween_at


@options
class Options:
    times: tuple[str, ...] = option(("0,30,60,90", "0,20,65,90"), metavar="T0,T1,…", help="key frames, comma-separated; one set per run")
    steps: int = option(10, help="DDIM steps (default 10)")
    repeats: int = option(5, help="timed steady-state calls; the median is reported")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def parsed_times(text: str) -> tuple[int, ...]:
    try:
        times = tuple(int(word) for word in text.split(","))
    except ValueError:
        raise SystemExit(f"--times {text}: key frames are whole numbers separated by commas, e.g. 0,20,65,90") from None
    if len(times) < 2 or any(b - a < 2 for a, b in zip(times, times[1:])):
        raise SystemExit(f"--times {text}: two or more key frames, each 2 or more after the one before")
    return times


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    sets = [parsed_times(text) for text in args.times]
    bmm = load_model(BUNDLED_BMM)
    ik_model = load_ik_model(BUNDLED_IK)
    character = ik_model.character
    ik_fn, ik_params = exact_ik(protores_ik_fn, ik_model, character, limits=JointLimits.load(BUNDLED_IK / "joint_limits.json", character))
    model = Inbetweener(bmm, ik_fn, ik_params, character, Transfer.identity())
    motion = read_bvh(DEMO_CLIP)
    there_and_back = np.r_[np.arange(motion.num_frames), np.arange(motion.num_frames - 2, 0, -1)]
    options_ = InbetweenOptions(steps=args.steps, foot_lock=True)
    rows = {}
    for times in sets:
        frames = there_and_back[np.asarray(times) % len(there_and_back)]
        keys = pose_from_motion(character, jnp.asarray(motion.quat_local[frames], jnp.float32), jnp.asarray(motion.pos_local[frames], jnp.float32))
        above = np.asarray(targets_from_pose(character, keys).position[:, 3]) + [0.0, 25.0, 0.0]  # the right hand, raised
        middle = [(a + b) // 2 for a, b in zip(times, times[1:])]
        handles = Handles(
            joint=jnp.full(len(middle), CHARACTERISTIC_JOINTS.index("right_hand"), jnp.int32), frame=jnp.asarray(middle, jnp.int32),
            position=jnp.asarray(0.5 * (above[:-1] + above[1:]), jnp.float32), valid=jnp.ones(len(middle), bool),
        )  # fmt: skip

        def call(seed: int):
            return jax.block_until_ready(inbetween_at(model, keys, times, handles, key=jax.random.key(seed), options=options_))

        started = time.perf_counter()
        call(0)
        first = time.perf_counter() - started
        steady = []
        for r in range(args.repeats):
            started = time.perf_counter()
            call(r + 1)
            steady.append(time.perf_counter() - started)
        gaps = np.diff(times).tolist()
        label = ",".join(map(str, times))
        rows[label] = {
            "times": list(times), "gaps": gaps, "distinct_gaps": len(set(gaps)), "frames": times[-1] - times[0] + 1,
            "first_call_s": first, "steady_ms": 1e3 * statistics.median(steady), "steady_all_ms": [1e3 * s for s in steady],
        }  # fmt: skip
        print(f"{label}: first call {first:.1f} s, then {rows[label]['steady_ms']:.0f} ms", flush=True)
    result = {"benchmark": "key_times", "ik": "exact", "steps": args.steps, "foot_lock": True, "rows": rows, "machine": machine_info()}
    summary = {k: {m: v for m, v in r.items() if m != "steady_all_ms"} for k, r in rows.items()}
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
