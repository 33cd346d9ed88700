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

XLA runs one CPU computation on one core (the solve's operations are too small for its
intra-op threads). With several JAX devices (on a CPU: ``XLA_FLAGS`` as above, one per
core), the ``--batch`` windows are split over them (a 1-D mesh over the batch axis), so
the throughput figure uses every core; the one-window figure stays on one device.
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report, time_jitted
from bezmotion.assets import BUNDLED_IK, DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.ik.exact import exact_ik, exact_settings
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protocol import Character, pose_from_motion, targets_from_pose
from bezmotion.ik.protores import load_ik_model, protores_ik_fn, protores_refined_ik_fn
from bezmotion.ik.rig import make_rig, rig_ik
from bezmotion.options import option, options, parse_options
from bezmotion.xla_options import inference_compiler_options


@options
class Options:
    repeats: int = option(20, help="timed repeats; the median is reported")
    batch: int = option(16, help="windows per vmapped call for the throughput figure")
    iterations: int | None = option(None, help="Levenberg-Marquardt steps (default: ExactIKParams')")
    exact: tuple[str, ...] = option((), repeat=True, metavar="NAME=VALUE", help="an ExactIKParams setting (e.g. window_passes=1); may repeat")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


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
    result = {"benchmark": "ik_exact", "frames": 31, "batch": args.batch, "batch_devices": devices, "settings": settings, "rows": rows, "machine": machine_info()}
    summary = {k: {m: v for m, v in r.items() if m not in ("single", "batched")} for k, r in rows.items()}
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
