"""Benchmark: BMM sampling latency and throughput (10 DDIM steps) at paper size and CPU size.

    python benchmarks/bmm_inference.py --out bmm_inference.json

For each configuration: parameter count, compile time of ``sample_curves`` (lowering and
XLA compilation separately), steady-state latency of one motion at batch 1 (start, end
and two intermediate handles; no guidance, as in the paper's timing), and throughput in
motions per second at ``--batch``. Weights are random: latency does not depend on them.
Everything is compiled with the options ``sample_curves`` itself uses
(:func:`bezmotion._src.xla_options.inference_compiler_options`); ``"xla_defaults"`` repeats the
single-motion figures with XLA's default options, to show what they are worth.
Writes ``{"paper": {"params", "compile_s", "latency_s", "motions_per_s", …}, "default": {…}}``;
latency is the median of ``--repeats`` runs, ``latency_min_s`` the fastest (this CPU is a
shared virtual machine, so the median drifts by ±10 % from run to run).
"""

from __future__ import annotations

import functools
import sys

import jax
import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report, time_jitted
from bezmotion._src.xla_options import inference_compiler_options
from bezmotion.bmm.denoiser import BMMConfig, init_denoiser
from bezmotion.training import count_parameters
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, Handles, sample_curves
from bezmotion._src.options import option, options, parse_options

PAPER_LATENCY_S = 0.08  # BMM §6: 10 steps on an RTX 3090


@options
class Options:
    steps: int = option(10, help="DDIM steps (default 10)")
    batch: int = option(256, help="batch for the throughput figure (default 256)")
    repeats: int = option(100, help="timed repeats; the median and the minimum are reported")
    batch_repeats: int = option(5, help="timed repeats of the batched call")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def example_inputs(config: BMMConfig, batch: int | None):
    """A plausible in-betweening problem: a 2 m walk with a hand and a foot handle."""
    rng = np.random.default_rng(0)
    start = rng.normal(scale=30.0, size=(config.num_joints, 3)).astype(np.float32) + [0, 90, 0]
    end = start + np.float32([200.0, 0.0, 0.0])
    handles = Handles.from_frames(["left_hand", "right_foot"], [12, 18], start[[2, 5]] + 80.0, config=config)
    if batch is None:
        return jnp.asarray(start), jnp.asarray(end), handles
    tile = lambda x: jnp.broadcast_to(jnp.asarray(x), (batch, *np.shape(x)))  # noqa: E731
    return tile(start), tile(end), jax.tree.map(tile, handles)


def measure(config: BMMConfig, *, batch: int, steps: int, repeats: int, batch_repeats: int) -> dict:
    graphdef, params = init_denoiser(config, key=jax.random.key(0))
    j = config.num_joints
    stats = FeatureStats(jnp.zeros((j, 12)), jnp.full((j, 12), 30.0))
    model = BezierMotionModel(params, stats, graphdef, config)
    key = jax.random.key(1)
    fn = functools.partial(sample_curves, steps=steps)
    sample = lambda m, s, e, h, k: fn(m, s, e, h, key=k)  # noqa: E731
    options = dict(inference_compiler_options()) or None
    single = time_jitted(sample, (model, *example_inputs(config, None), key), repeats=repeats, compiler_options=options)
    batched = time_jitted(sample, (model, *example_inputs(config, batch), key), repeats=batch_repeats, compiler_options=options)
    xla_defaults = time_jitted(sample, (model, *example_inputs(config, None), key), repeats=repeats)
    return {
        "compiler_options": options,
        "params": count_parameters(params),
        "config": {k: getattr(config, k) for k in ("width", "ff_width", "num_heads", "num_layers")},
        "steps": steps,
        "lower_s": single["lower_s"],
        "compile_s": single["compile_s"],
        "latency_s": single["steady_s"],
        "latency_min_s": single["min_s"],
        "batch": batch,
        "batch_compile_s": batched["compile_s"],
        "batch_s": batched["steady_s"],
        "motions_per_s": batch / batched["steady_s"],
        "xla_defaults": {"compile_s": xla_defaults["compile_s"], "latency_s": xla_defaults["steady_s"], "latency_min_s": xla_defaults["min_s"]},
    }


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)

    result = {
        "benchmark": "bmm_inference",
        "paper_latency_s": PAPER_LATENCY_S,
        "paper": measure(BMMConfig.paper(), batch=args.batch, steps=args.steps, repeats=args.repeats, batch_repeats=args.batch_repeats),
        "default": measure(BMMConfig.cpu(), batch=args.batch, steps=args.steps, repeats=args.repeats, batch_repeats=args.batch_repeats),
        "machine": machine_info(),
    }
    summary = {
        name: {k: result[name][k] for k in ("params", "compile_s", "latency_s", "latency_min_s", "motions_per_s")} for name in ("paper", "default")
    }
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
