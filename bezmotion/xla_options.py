"""XLA compiler options for jit-compiled inference, chosen per backend.

On the CPU backend, XLA hands matrix products to YNNPACK by default. For the BMM
sampler's shapes (≈ 20 tokens × 512 features against 512 × 1536 weights, batch 1) its
kernels are slower than XLA's own (Eigen): paper-size 10-step sampling measured
75 ms against 81–83 ms (min of 80 runs, 2-core AMD EPYC, jaxlib 0.10.2;
``benchmarks/bmm_inference.py`` reports both). Training steps, with 64× more rows,
showed no difference, so training keeps XLA's defaults.

The options are passed per computation (``jax.jit(..., compiler_options=…)``), never
through the process-wide ``XLA_FLAGS``, so nothing else a user compiles is affected.
A jaxlib that does not know an option gets none (checked once by compiling a scalar).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax

CPU_INFERENCE_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}  # "" = no YNNPACK fusions


@functools.cache
def inference_compiler_options() -> tuple[tuple[str, str], ...]:
    """The options for the default backend as a hashable tuple (``dict(...)`` it); empty
    when the backend is not a CPU or the installed jaxlib rejects them."""
    if jax.default_backend() != "cpu":
        return ()
    try:
        jax.jit(lambda x: x + 1, compiler_options=CPU_INFERENCE_OPTIONS).lower(1.0).compile()
    except Exception:  # noqa: BLE001 - an unknown or renamed flag: fall back to XLA's defaults
        return ()
    return tuple(sorted(CPU_INFERENCE_OPTIONS.items()))


def call_with_inference_options(compiled: Callable[[tuple[tuple[str, str], ...]], Callable], *args, **kwargs):
    """``compiled(options)(*args, **kwargs)`` with the backend's inference options.

    ``compiled`` maps an options tuple to a jitted function (cache it). Inside a caller's
    own ``jax.jit`` the call is traced into that computation, whose options are the
    caller's, so none are passed; the same holds when a caller's jit traced the
    function with constant inputs only (JAX then refuses per-call options).
    """
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves((args, kwargs))):
        return compiled(())(*args, **kwargs)
    try:
        return compiled(inference_compiler_options())(*args, **kwargs)
    except ValueError as error:
        if "compiler_options" not in str(error):
            raise
        return compiled(())(*args, **kwargs)
