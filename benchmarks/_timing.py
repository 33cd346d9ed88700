"""Shared benchmark helpers: machine/version info and a compile-vs-steady-state timer.

Every benchmark script reports numbers together with :func:`machine_info` so a result can
be traced to the hardware and library versions that produced it.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jaxlib
import numpy as np

from bezmotion._src.io import atomic_write_text


def _cpu_model() -> str:
    """CPU model name from ``/proc/cpuinfo`` (falls back to ``platform.processor()``)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _usable_cores() -> int:
    """Cores this process may run on (affinity mask where available)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def machine_info() -> dict[str, Any]:
    """Platform, CPU, core count, library versions and the JAX backend/devices."""
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu_model": _cpu_model(),
        "cpu_cores": _usable_cores(),
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "numpy": np.__version__,
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "x64": bool(jax.config.jax_enable_x64),
    }


def _block(tree: Any) -> Any:
    return jax.block_until_ready(tree)


def time_jitted(
    fn: Callable[..., Any],
    args: Sequence[Any],
    *,
    repeats: int = 5,
    warmup: int = 1,
    compiler_options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Time ``jax.jit(fn)(*args)``: compilation separately from steady-state execution.

    ``lower_s`` is tracing + lowering to StableHLO, ``compile_s`` the XLA compilation of
    that lowering (both measured with the AOT API ``jit(fn).lower(*args).compile()``),
    ``first_call_s`` one call of the compiled executable including transfer and
    ``block_until_ready``. ``steady_s`` is the median of ``repeats`` further calls after
    ``warmup`` unmeasured ones; ``times_s`` lists them all. ``compiler_options`` go to
    ``jax.jit`` (XLA debug options for this computation only).
    """
    jitted = jax.jit(fn, compiler_options=compiler_options)
    t0 = time.perf_counter()
    lowered = jitted.lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    _block(compiled(*args))
    t3 = time.perf_counter()
    for _ in range(warmup):
        _block(compiled(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        _block(compiled(*args))
        times.append(time.perf_counter() - start)
    return {
        "lower_s": t1 - t0,
        "compile_s": t2 - t1,
        "first_call_s": t3 - t2,
        "steady_s": statistics.median(times),
        "min_s": min(times),
        "times_s": times,
        "repeats": repeats,
    }


def write_json(path: str | os.PathLike, payload: dict[str, Any]) -> None:
    """Write ``payload`` as indented JSON, atomically (never a half-written file)."""
    atomic_write_text(Path(path), json.dumps(payload, indent=2, sort_keys=True) + "\n")


def report(result: dict[str, Any], summary: dict[str, Any], out: str | os.PathLike | None) -> dict[str, Any]:
    """Print ``summary`` as JSON, write the full ``result`` to ``out`` (if given), return ``result``."""
    print(json.dumps(summary, indent=2))
    if out:
        write_json(out, result)
    return result
