"""XLA compiler options for jit-compiled inference, chosen per backend.

On the CPU backend, XLA hands matrix products to YNNPACK by default. For the BMM
sampler's shapes (≈ 20 tokens × 512 features against 512 × 1536 weights, batch 1) its
kernels are slower than XLA's own (Eigen), so inference turns them off
(``benchmarks/bmm_inference.py`` times both). Training steps, with 64× more rows, gain
nothing from it, so training keeps XLA's defaults.

The options are passed per computation (``jax.jit(..., compiler_options=…)``), never
through the process-wide ``XLA_FLAGS``, so nothing else a user compiles is affected.
A jaxlib that does not know an option gets none (checked once by compiling a scalar).
"""

from __future__ import annotations

import functools
import logging
import re
from collections.abc import Callable
from typing import Any

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


def traced(tree: Any) -> bool:
    """Whether any leaf of ``tree`` is a tracer (the call is inside a caller's ``jax.jit``)."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(tree))


def inference_jit(fn: Callable | None = None, *, static_argnames: tuple[str, ...] = ()):
    """``jax.jit(fn)`` compiled with the backend's inference options, for entry points.

    Called with concrete arrays it waits for the result, so that a run-time check inside
    (``eqx.error_if``) raises here as a ``ValueError`` with the check's own message; traced
    inside a caller's ``jax.jit`` it is part of that computation and its checks raise
    there, as Equinox reports them.
    """
    if fn is None:
        return functools.partial(inference_jit, static_argnames=static_argnames)

    @functools.cache
    def compiled(options: tuple[tuple[str, str], ...]):
        return jax.jit(fn, static_argnames=static_argnames, compiler_options=dict(options) or None)

    @functools.wraps(fn)
    def call(*args, **kwargs):
        if traced((args, kwargs)):
            return compiled(())(*args, **kwargs)
        try:
            return jax.block_until_ready(compiled(inference_compiler_options())(*args, **kwargs))
        except (jax.errors.JaxRuntimeError, ValueError) as error:  # jax raises a failed callback as either
            message = check_message(error)
            if message is not None:
                raise ValueError(message) from None
            if "compiler_options" not in str(error):
                raise
        # A caller's jit traced this with constant inputs only: JAX refuses per-call options.
        return jax.block_until_ready(compiled(())(*args, **kwargs))

    return call


class _QuietChecks(logging.Filter):
    """Drops JAX's log of a failed ``eqx.error_if`` callback: :func:`inference_jit` raises it."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.exc_info and type(record.exc_info[1]).__name__ == "_EquinoxRuntimeError")


logging.getLogger("jax._src.callback").addFilter(_QuietChecks())


def check_message(error: BaseException) -> str | None:
    """The message of a failed ``eqx.error_if`` inside a computation that ``jax.jit`` ran
    (which wraps it in its own runtime error), or ``None`` for any other error."""
    found = re.search(r"_EquinoxRuntimeError: (.*?)\n\n\n-----", str(error), re.DOTALL)
    return None if found is None else found.group(1).strip()
