"""Benchmark: a whole in-between (BMM sampling, then IK) per window and per chain, jit-compiled.

Times what a user calls, :func:`bezmotion.inbetween` for one window (two keys) and for K
windows through K + 1 keys, on the bundled
Bandai-Namco models (10 DDIM steps, foot lock on as in ``bezmotion inbetween``, a right-hand
handle 25 cm above the straight line in every window, at its frame 15 or ``--handle-frame``), against K calls of the one-window
in-between, the independent alternative. Compile time and steady-state milliseconds are
reported separately, with the machine and library versions.

    python benchmarks/inbetween.py --windows 1 2 4 --ik learned exact --out inbetween.json

The keys are frames 0, 30, 60, … of the bundled clip played forward and back (it has 40
frames); the time does not depend on the motion. A handle within a stride (6 frames) of a
shared key (``--handle-frame 2``) makes a chain meet that joint over the whole chain
(:func:`bezmotion.bmm.sampling._projector`), the costlier projection.
"""

from __future__ import annotations

import functools
import sys

import jax
import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report, time_jitted
from bezmotion.assets import BUNDLED_BMM, BUNDLED_IK, DEMO_CLIP
from bezmotion.bmm.sampling import Handles, load_model
from bezmotion.data.bvh import read_bvh
from bezmotion.ik.exact import exact_ik
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protocol import Character, pose_from_motion, targets_from_pose
from bezmotion.ik.protores import load_ik_model, protores_ik_fn
from bezmotion._src.options import option, options, parse_options
from bezmotion.pipeline.inbetweening import InbetweenOptions, inbetween_traced
from bezmotion.pipeline.model import Inbetweener
from bezmotion.pipeline.transfer import Transfer
from bezmotion._src.xla_options import inference_compiler_options


@options
class Options:
    windows: tuple[int, ...] = option((1, 2, 4), help="chain lengths K (windows; K + 1 keys) to time")
    ik: tuple[str, ...] = option(("learned", "exact"), choices=("learned", "exact"), help="the IKs to time")
    steps: int = option(10, help="DDIM steps (default 10)")
    handle_frame: int = option(15, help="the frame (1…29) of each window's right-hand handle (default 15)")
    repeats: int = option(10, help="timed repeats; the median is reported")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def chain_keys(character: Character, windows: int, span: int):
    """``windows + 1`` key poses ``span`` frames apart from the bundled clip played forward and back."""
    motion = read_bvh(DEMO_CLIP)
    there_and_back = np.r_[np.arange(motion.num_frames), np.arange(motion.num_frames - 2, 0, -1)]
    frames = there_and_back[np.arange(windows + 1) * span % len(there_and_back)]
    return pose_from_motion(character, jnp.asarray(motion.quat_local[frames], jnp.float32), jnp.asarray(motion.pos_local[frames], jnp.float32))


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    if min(args.windows) < 1:
        raise SystemExit(f"--windows {' '.join(map(str, args.windows))}: every chain needs at least one window")
    bmm = load_model(BUNDLED_BMM)
    model = load_ik_model(BUNDLED_IK)
    character = model.character
    span = bmm.config.num_frames - 1
    iks = {"learned": (protores_ik_fn, model)}
    if "exact" in args.ik:
        iks["exact"] = exact_ik(protores_ik_fn, model, character, limits=JointLimits.load(BUNDLED_IK / "joint_limits.json", character))
    options_ = dict(inference_compiler_options()) or None
    run = functools.partial(inbetween_traced, options=InbetweenOptions(steps=args.steps, foot_lock=True))
    key = jax.random.key(0)
    rows = {}
    for name in args.ik:
        ik_fn, ik_params = iks[name]
        model_ = Inbetweener(bmm, ik_fn, ik_params, character, Transfer.identity())
        single = None
        for k in args.windows:
            keys = chain_keys(character, k, span)
            above = np.asarray(targets_from_pose(character, keys).position[:, 3]) + [0.0, 25.0, 0.0]  # the right hand, raised
            per_window = [Handles.from_frames(["right_hand"], [args.handle_frame], (0.5 * (above[i] + above[i + 1]))[None], config=bmm.config) for i in range(k)]
            handles = jax.tree.map(lambda *x: jnp.stack(x), *per_window)
            if single is None:  # one window, the independent alternative's unit: timed once per IK
                first = (jax.tree.map(lambda x: x[:2], keys), jax.tree.map(lambda x: x[None], per_window[0]))
                single = time_jitted(run, (model_, *first, key), repeats=args.repeats, compiler_options=options_)
            chained = time_jitted(run, (model_, keys, handles, key), repeats=args.repeats, compiler_options=options_)
            label = f"{name}, {k} window(s)"
            rows[label] = {
                "ik": name, "windows": k, "frames": k * span + 1,
                "chain_compile_s": chained["lower_s"] + chained["compile_s"],
                "chain_ms": 1e3 * chained["steady_s"], "chain_ms_per_window": 1e3 * chained["steady_s"] / k,
                "independent_ms": 1e3 * k * single["steady_s"],  # K calls of the one-window in-between
                "window_compile_s": single["lower_s"] + single["compile_s"], "window_ms": 1e3 * single["steady_s"],
                "chain": chained, "window": single,
            }  # fmt: skip
            print(f"{label}: chain {rows[label]['chain_ms']:.1f} ms, {k} independent windows {rows[label]['independent_ms']:.1f} ms", flush=True)
    result = {"benchmark": "inbetween", "steps": args.steps, "handle_frame": args.handle_frame, "foot_lock": True, "rows": rows, "machine": machine_info()}
    summary = {k: {m: v for m, v in r.items() if m not in ("chain", "window")} for k, r in rows.items()}
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
