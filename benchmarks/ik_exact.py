"""Benchmark: the exact IK stage (bezmotion.ik.exact) per 31-frame window, jit-compiled.

Times the window solve the pipeline uses (``ExactIKFn.solve_window``: the inner IK's
poses, smoothed over time, then the Levenberg–Marquardt solve per frame, ``window_passes`` times) on the bundled
Bandai-Namco demo clip's first 31 frames, with the right hand's targets raised 15 cm on
frames 12–17, and the inner IKs alone for comparison: compile time and steady-state
milliseconds per window separately, one window (latency) and ``--batch`` windows vmapped
(throughput), with the machine and library versions.

    python benchmarks/ik_exact.py --repeats 20 --out ik_exact.json
    python benchmarks/ik_exact.py --repeats 20 --exact window_passes=1 --out ik_exact_one_pass.json   # half the solves
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python benchmarks/ik_exact.py --repeats 20 --out ik_exact_2dev.json

``--real N`` also times the window solve as the pipeline runs it (``solve_frames``: the keys
joined) on N Bandai-Namco validation windows (``../shared/data``), one window a call as
``bezmotion inbetween`` runs them, each with 1–4 handles moved up to ±16 cm and spread over
±6 frames like a curve through them (OOD handles): the benchmark's own window has
no keys and one handle, and needs less of the solve's work.

    python benchmarks/ik_exact.py --repeats 20 --real 40 --out ik_exact_real.json

``--parts`` splits the exact IK's time on the benchmark's window: its window solve without any
Levenberg–Marquardt step (the learned IK, the filters, the keys, the finish) against the whole,
in alternating rounds, and the ms per step from the two.

    python benchmarks/ik_exact.py --repeats 20 --parts --out ik_exact_parts.json

XLA runs one CPU computation on one core (the solve's operations are too small for its
intra-op threads). With several JAX devices (on a CPU: ``XLA_FLAGS`` as above, one per
core), the ``--batch`` windows are split over them (a 1-D mesh over the batch axis), so
the throughput figure uses every core; the one-window figure stays on one device.
"""

from __future__ import annotations

import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report, time_jitted
from bezmotion.assets import BUNDLED_IK, DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.data.corpus import motion_clips
from bezmotion.data.sources import load_corpus
from bezmotion.ik.exact import exact_ik, exact_settings
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protocol import Character, IKTargets, Pose, pose_from_motion, solve_frames, targets_from_pose
from bezmotion.ik.protores import load_ik_model, protores_ik_fn, protores_refined_ik_fn
from bezmotion.ik.rig import make_rig, rig_ik
from bezmotion._src.options import option, options, parse_options
from bezmotion.pipeline.inbetweening import KEY_BLEND_FRAMES
from bezmotion._src.xla_options import inference_compiler_options


@options
class Options:
    repeats: int = option(20, help="timed repeats; the median is reported")
    batch: int = option(16, help="windows per vmapped call for the throughput figure")
    iterations: int | None = option(None, help="Levenberg-Marquardt steps (default: ExactIKParams')")
    exact: tuple[str, ...] = option((), repeat=True, metavar="NAME=VALUE", help="an ExactIKParams setting (e.g. window_passes=1); may repeat")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")
    real: int = option(0, help="also time the exact IK on this many real Bandai-Namco validation windows with keys and handles (0: none)")
    parts: bool = option(False, help="also time the exact IK on learned without its Levenberg-Marquardt steps, alternating with it: its fixed part and ms per step")

    def __post_init__(self):
        if self.real < 0:
            raise ValueError(f"--real {self.real}: must be ≥ 0")


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    motion = read_bvh(DEMO_CLIP)
    character = Character.from_bvh(motion, "bandai_namco")
    truth = pose_from_motion(character, jnp.asarray(motion.quat_local[:31], jnp.float32), jnp.asarray(motion.pos_local[:31], jnp.float32))
    targets = targets_from_pose(character, truth)
    targets = targets._replace(position=targets.position.at[12:18, 3, 1].add(15.0))
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (args.batch, *x.shape)), targets)
    devices = jax.device_count()
    if args.batch % devices:
        raise SystemExit(f"--batch {args.batch}: must be a multiple of the {devices} devices")
    mesh = jax.make_mesh((devices,), ("windows",), axis_types=(jax.sharding.AxisType.Auto,))
    batch = jax.device_put(batch, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("windows")))
    on_every_device = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())  # the parameters, replicated
    model = load_ik_model(BUNDLED_IK)
    rig = make_rig(character, "bandai_namco", rest_quat_local=np.asarray(truth.quat_local[0]))
    limits = JointLimits.load(BUNDLED_IK / "joint_limits.json", character)
    settings = exact_settings(args.exact) | ({} if args.iterations is None else {"iterations": args.iterations})
    options_ = dict(inference_compiler_options()) or None
    inners = {"learned": (protores_ik_fn, model), "refined": (protores_refined_ik_fn, (model, rig)), "rig": (rig_ik, rig)}
    rows = {}
    for name, (fn, params) in inners.items():
        alone = lambda p, t, fn=fn: jax.vmap(fn, in_axes=(None, 0))(p, t)  # noqa: E731
        exact_fn, exact_params = exact_ik(fn, params, character, limits=limits, **settings)
        for label, f, p in ((name, alone, params), (f"exact on {name}", exact_fn.solve_window, exact_params)):
            one = time_jitted(f, (p, targets), repeats=args.repeats, compiler_options=options_)
            many = time_jitted(jax.vmap(f, in_axes=(None, 0)), (jax.device_put(p, on_every_device), batch), repeats=max(3, args.repeats // 4), compiler_options=options_)
            rows[label] = {
                "compile_s": one["lower_s"] + one["compile_s"],
                "ms_per_window": 1e3 * one["steady_s"],
                "ms_per_window_min": 1e3 * one["min_s"],
                f"ms_per_window_batched_{args.batch}": 1e3 * many["steady_s"] / args.batch,
                "single": one,
                "batched": many,
            }
            print(f"{label}: compile {rows[label]['compile_s']:.1f} s, {rows[label]['ms_per_window']:.2f} ms/window "
                  f"(min {rows[label]['ms_per_window_min']:.2f}), batched {rows[label][f'ms_per_window_batched_{args.batch}']:.2f}", flush=True)  # fmt: skip
    if args.parts:
        rows["exact on learned, part by part"] = time_parts(model, character, limits, settings, targets, args.repeats, options_)
    if args.real:
        exact_fn, exact_params = exact_ik(protores_ik_fn, model, character, limits=limits, **settings)
        rows["exact on learned, real windows"] = time_real_windows(exact_fn, exact_params, character, args.real, args.repeats, options_)
    result = {"benchmark": "ik_exact", "frames": 31, "batch": args.batch, "batch_devices": devices, "settings": settings, "rows": rows, "machine": machine_info()}
    summary = {k: {m: v for m, v in r.items() if m not in ("single", "batched", "ms_each_window")} for k, r in rows.items()}
    return report(result, summary, args.out)


def call_times(compiled, args: tuple, repeats: int) -> list[float]:
    """Seconds of ``repeats`` calls of a compiled function, after one untimed call."""
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - started)
    return times


def time_parts(model, character: Character, limits: JointLimits, settings: dict, targets: IKTargets, repeats: int, compiler_options, rounds: int = 4) -> dict:
    """Where the exact IK's time goes: ms per window of its window solve on the learned IK with
    no Levenberg–Marquardt steps (``iterations=0``: the learned IK, the filters between the
    passes, the finish) and with its steps, timed in alternating rounds (this machine's speed
    drifts within minutes), and from the two the ms per step (``window_passes × iterations``
    steps a window)."""
    solves = {}
    for label, extra in (("no_steps", {"iterations": 0}), ("with_steps", {})):
        fn, params = exact_ik(protores_ik_fn, model, character, limits=limits, **(settings | extra))
        solves[label] = (jax.jit(fn.solve_window, compiler_options=compiler_options).lower(params, targets).compile(), params)
    times: dict[str, list[float]] = {label: [] for label in solves}
    for _ in range(rounds):
        for label, (compiled, params) in solves.items():
            times[label] += call_times(compiled, (params, targets), repeats)
    ms = {label: 1e3 * statistics.median(t) for label, t in times.items()}
    params = solves["with_steps"][1]
    steps = params.window_passes * params.iterations
    row = {"ms_per_window_no_steps": ms["no_steps"], "ms_per_window": ms["with_steps"], "steps": steps,
           "ms_per_step": (ms["with_steps"] - ms["no_steps"]) / max(steps, 1), "rounds": rounds}  # fmt: skip
    print(f"exact on learned, part by part: {row['ms_per_window_no_steps']:.2f} ms without steps, {row['ms_per_window']:.2f} with "
          f"{steps} steps: {row['ms_per_step']:.3f} ms a step", flush=True)  # fmt: skip
    return row


def real_windows(character: Character, count: int, seed: int = 0) -> list[tuple[IKTargets, tuple[Pose, Pose]]]:
    """``count`` Bandai-Namco validation windows of 31 frames as ``(targets, (start key, end key))``:
    the mocap's six joints, 1–4 of them moved up to ±16 cm at a frame 1…29 (a handle) and the
    move spread over ±6 frames (a curve through it)."""
    clips = motion_clips(load_corpus("bandai_namco", progress=False), "validation")
    rng = np.random.default_rng(seed)
    t = np.arange(31)
    windows = []
    for _ in range(count):
        c = rng.integers(len(clips.starts) - 1)
        s = rng.integers(clips.starts[c], clips.starts[c + 1] - 31)
        truth = pose_from_motion(character, jnp.asarray(clips.quat_local[s : s + 31], jnp.float32), jnp.asarray(clips.pos_local[s : s + 31], jnp.float32))
        targets = targets_from_pose(character, truth)
        position, pinned = np.asarray(targets.position).copy(), np.zeros((31, 6), bool)
        for _ in range(rng.integers(1, 5)):
            joint, frame = rng.integers(6), rng.integers(1, 30)
            position[:, joint] += np.maximum(0.0, 1.0 - np.abs(t - frame) / 6.0)[:, None] * rng.uniform(-16.0, 16.0, 3)
            pinned[frame, joint] = True
        keys = (jax.tree.map(lambda x: x[0], truth), jax.tree.map(lambda x: x[-1], truth))
        windows.append((targets._replace(position=jnp.asarray(position), pinned=jnp.asarray(pinned)), keys))
    return windows


def time_real_windows(fn, params, character: Character, count: int, repeats: int, compiler_options) -> dict:
    """ms per window of ``solve_frames`` (keys joined over ``KEY_BLEND_FRAMES``) on
    :func:`real_windows`: compiled once, each window's median of ``repeats`` calls."""
    windows = real_windows(character, count)
    solve = jax.jit(lambda p, t, k: solve_frames(fn, p, t, keys=k, key_blend_frames=KEY_BLEND_FRAMES), compiler_options=compiler_options)
    started = time.perf_counter()
    compiled = solve.lower(params, *windows[0]).compile()
    compile_s = time.perf_counter() - started
    medians = [statistics.median(call_times(compiled, (params, targets, keys), repeats)) for targets, keys in windows]
    row = {"compile_s": compile_s, "windows": count, "ms_per_window": 1e3 * statistics.median(medians), "ms_per_window_mean": 1e3 * statistics.fmean(medians)}
    print(f"exact on learned, {count} real windows: compile {compile_s:.1f} s, {row['ms_per_window']:.2f} ms/window (median of the windows' medians)", flush=True)
    return row | {"ms_each_window": [1e3 * m for m in medians]}


if __name__ == "__main__":
    main(sys.argv[1:])
