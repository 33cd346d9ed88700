"""A persistent XLA compilation cache for the command line.

Most of a ``bezmotion demo`` or ``bezmotion inbetween`` run is XLA compiling the sampler and
the IKs, the same programs every time. JAX can keep compiled programs on disk and load them
in the next process instead of compiling again (its persistent compilation cache, keyed by
the program, the jax/jaxlib versions and the backend, so an upgrade misses rather than
loads a stale program), so a second run of the demo skips most of its compiling.

The command line turns it on (:func:`use_compilation_cache`); the library does not, so code
that imports bezmotion keeps whatever cache its process configures. Where the process has a
cache folder already (``JAX_COMPILATION_CACHE_DIR`` or ``jax.config``), that one is used.
``BEZMOTION_XLA_CACHE=off`` turns it off; delete the folder at any time.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

from bezmotion.data.cache import cache_dir

SWITCH_ENV = "BEZMOTION_XLA_CACHE"
OFF = ("0", "off", "false", "no")
#: Programs that compile faster than this are not written (JAX's default is 1 s). Every program
#: is kept: besides one large program (the whole in-between) the demo compiles hundreds of small
#: ones, each under JAX's threshold but together a large part of its compile time.
MIN_COMPILE_SECONDS = 0.0


def compilation_cache_folder() -> Path:
    """``<cache>/xla`` (:func:`~bezmotion.data.cache.cache_dir`: ``$BEZMOTION_CACHE`` or ``~/.cache/bezmotion``)."""
    return cache_dir() / "xla"


def use_compilation_cache() -> Path | None:
    """Keep this process's compiled programs in :func:`compilation_cache_folder` across runs.

    Returns the folder in use: the one the process configured already, if any (left as it
    is), else :func:`compilation_cache_folder`; None when ``$BEZMOTION_XLA_CACHE`` turns it off.
    Call it before the first compilation: JAX decides once per process whether to use a cache.
    """
    if os.environ.get(SWITCH_ENV, "").strip().lower() in OFF:
        return None
    configured = jax.config.jax_compilation_cache_dir
    if configured:
        return Path(configured)
    folder = compilation_cache_folder()
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return folder
