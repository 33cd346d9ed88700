"""Benchmark: Δ-interpolator latency of in-betweening one 30-frame gap, batch 1 and batched.

    python benchmarks/delta_inference.py --out delta_inference.json

For each configuration (``--configs``; default the paper's size and the CPU size):
parameter count, compile time of the in-betweener (lowering and XLA compilation
separately), steady-state latency of one transition at batch 1 (10 past frames and a
target, ``--gap`` missing frames; the benchmark's layout) and throughput in transitions
per second at ``--batch``. The parameters are an argument of the timed function, not
constants baked into it. Weights are random: latency does not depend on them.
Everything is compiled with :func:`bezmotion._src.xla_options.inference_compiler_options` (as the BMM
benchmark); ``"xla_defaults"`` repeats the batch-1 figures with XLA's default options.
Latency is the median of ``--repeats`` runs, ``latency_min_s`` the fastest.
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report, time_jitted
from bezmotion._src.xla_options import inference_compiler_options
from bezmotion.data.lafan1 import JOINT_NAMES, N_PAST, PARENTS
from bezmotion.delta.model import DeltaConfig, delta_inbetweener, init_delta
from bezmotion.geometry import Skeleton
from bezmotion._src.options import option, options, parse_options, presets
from bezmotion.training import count_parameters

CONFIGS = presets(DeltaConfig, parents=PARENTS)  # LaFAN1's skeleton, the paper's


@options
class Options:
    configs: tuple[str, ...] = option(("paper", "cpu"), choices=CONFIGS, help="sizes to measure (default: paper cpu)")
    gap: int = option(30, help="missing frames (default 30)")
    batch: int = option(64, help="batch for the throughput figure (default 64)")
    repeats: int = option(50, help="timed batch-1 repeats; the median and the minimum are reported")
    batch_repeats: int = option(5, help="timed repeats of the batched call")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def example_inputs(config: DeltaConfig, batch: int):
    """A plausible problem: random joint rotations, the root walking 2 m towards the target."""
    rng = np.random.default_rng(0)
    j = config.num_joints
    quat = rng.normal(size=(batch, N_PAST + 1, j, 4)) * [1.0, 0.1, 0.1, 0.1]
    quat = (quat / np.linalg.norm(quat, axis=-1, keepdims=True)).astype(np.float32)
    root = np.zeros((batch, N_PAST + 1, 3), np.float32) + [0.0, 90.0, 0.0]
    root[:, :N_PAST, 0] = np.arange(N_PAST) * 4.0
    root[:, N_PAST, 0] = 200.0
    offsets = rng.normal(scale=10.0, size=(j, 3)).astype(np.float32)
    arrays = (quat[:, :N_PAST], root[:, :N_PAST], quat[:, N_PAST], root[:, N_PAST])
    return jnp.asarray(offsets), tuple(jnp.asarray(a) for a in arrays)


def measure(config: DeltaConfig, *, gap: int, batch: int, repeats: int, batch_repeats: int) -> dict:
    graphdef, params = init_delta(config, key=jax.random.key(0))
    offsets, single_inputs = example_inputs(config, 1)
    skeleton = Skeleton(config.parents, JOINT_NAMES, offsets)
    _, batch_inputs = example_inputs(config, batch)

    def inbetween(params, past_quat, past_root, target_quat, target_root):
        return delta_inbetweener(graphdef, params, skeleton)(past_quat, past_root, target_quat, target_root, gap)

    options = dict(inference_compiler_options()) or None
    single = time_jitted(inbetween, (params, *single_inputs), repeats=repeats, compiler_options=options)
    batched = time_jitted(inbetween, (params, *batch_inputs), repeats=batch_repeats, compiler_options=options)
    xla_defaults = time_jitted(inbetween, (params, *single_inputs), repeats=repeats)
    return {
        "compiler_options": options,
        "params": count_parameters(params),
        "config": {k: getattr(config, k) for k in ("width", "num_blocks", "num_heads", "mlp_layers", "input_delta", "output_delta")},
        "gap": gap,
        "lower_s": single["lower_s"],
        "compile_s": single["compile_s"],
        "latency_s": single["steady_s"],
        "latency_min_s": single["min_s"],
        "frames_per_s": gap / single["steady_s"],
        "batch": batch,
        "batch_compile_s": batched["compile_s"],
        "batch_s": batched["steady_s"],
        "transitions_per_s": batch / batched["steady_s"],
        "xla_defaults": {"compile_s": xla_defaults["compile_s"], "latency_s": xla_defaults["steady_s"], "latency_min_s": xla_defaults["min_s"]},
    }


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)

    result = {"benchmark": "delta_inference", "machine": machine_info()}
    for name in args.configs:
        result[name] = measure(CONFIGS[name](), gap=args.gap, batch=args.batch, repeats=args.repeats, batch_repeats=args.batch_repeats)
    summary = {
        name: {k: result[name][k] for k in ("params", "compile_s", "latency_s", "latency_min_s", "transitions_per_s")} for name in args.configs
    }
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
