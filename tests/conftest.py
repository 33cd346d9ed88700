"""Test configuration.

The jaxtyping import hook is installed *before anything imports bezmotion*, so every
annotated function and dataclass in the package is checked at runtime with beartype
during the whole test session (shape and dtype annotations included).

Compilation settings for the session (the suite's time is mostly XLA compiling small
programs, not running them):

- XLA's slower optimisation passes are off (``jax_disable_most_optimizations``): the same
  programs with the same semantics, compiled faster. ``BEZMOTION_TEST_XLA_OPTIMIZE=1``
  runs the suite with XLA's full optimisation instead.
- With them, XLA's CPU compiler emits elementwise code the older way
  (``_FAST_COMPILE_FLAGS``, through ``XLA_FLAGS``), which compiles the exact IK's solves
  and the suite as a whole markedly faster. The programs are the same; they run a little
  slower, which the tests never time. (The older runtime's flag,
  ``--xla_cpu_use_thunk_runtime=false``, is not passed: jaxlib accepts it but ignores it,
  warning in every process that it is no longer supported.) A jaxlib that does not know a
  flag would abort at start-up, so the process that starts the session first tries them in a
  child process and keeps those it accepts (``BEZMOTION_TEST_XLA_FLAGS`` hands the choice to
  xdist's workers).
- A persistent compilation cache in a temporary folder lives as long as the session and is
  shared by xdist's workers, so a program that several modules compile (the bundled
  models' sampler, say) is compiled once, in whichever worker needs it first, although
  :func:`release_compiled_code` drops every executable after each module. Every program is
  written, however fast it compiled: the many small ones (FK, rotations, metrics) come back
  in module after module, and loading them beats compiling them again.
"""

import atexit
import os
import shutil
import subprocess
import sys
import tempfile

_OPTIMIZE = os.environ.get("BEZMOTION_TEST_XLA_OPTIMIZE", "") not in ("", "0")
_FAST_COMPILE_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)
_FLAGS_VARIABLE = "BEZMOTION_TEST_XLA_FLAGS"


def _accepted_flags(flags: tuple[str, ...]) -> str:
    """Those of ``flags`` with which this jaxlib starts a CPU backend, as one string."""

    def starts(candidate: list[str]) -> bool:
        env = {**os.environ, "XLA_FLAGS": " ".join([os.environ.get("XLA_FLAGS", ""), *candidate]), "JAX_PLATFORMS": "cpu"}
        probe = [sys.executable, "-c", "import jax.numpy as jnp; jnp.zeros(1).block_until_ready()"]
        return subprocess.run(probe, env=env, capture_output=True, timeout=300).returncode == 0

    if starts(list(flags)):
        return " ".join(flags)
    return " ".join(flag for flag in flags if starts([flag]))


# Before anything imports jax (a module constant would start the backend with the old flags).
if _FLAGS_VARIABLE not in os.environ:
    os.environ[_FLAGS_VARIABLE] = "" if _OPTIMIZE else _accepted_flags(_FAST_COMPILE_FLAGS)
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {os.environ[_FLAGS_VARIABLE]}".strip()

from jaxtyping import install_import_hook  # noqa: E402  (after the flags)

install_import_hook("bezmotion", "beartype.beartype")

import gc  # noqa: E402
import zipfile  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bezmotion.data import lafan1  # noqa: E402  (after the hook, so it is type-checked)
from bezmotion.data.bvh import BvhMotion, write_bvh  # noqa: E402
from bezmotion.geometry import Skeleton, quat_from_euler  # noqa: E402
from helpers import SHARED_DATA, requires_shared  # noqa: E402,F401  (re-exported for test modules)

# Before any test compiles (see the module docstring).
if not _OPTIMIZE:
    jax.config.update("jax_disable_most_optimizations", True)
# The process that starts the session (pytest itself, before xdist spawns its workers, which
# inherit the variable) makes the folder and removes it at exit; every worker shares it.
_CACHE_VARIABLE = "BEZMOTION_TEST_XLA_CACHE"
if _CACHE_VARIABLE not in os.environ:
    os.environ[_CACHE_VARIABLE] = tempfile.mkdtemp(prefix="bezmotion-test-xla-")
    atexit.register(shutil.rmtree, os.environ[_CACHE_VARIABLE], ignore_errors=True)
jax.config.update("jax_compilation_cache_dir", os.environ[_CACHE_VARIABLE])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)  # every program: see the docstring


@pytest.fixture
def rng() -> np.random.Generator:
    """A fresh, fixed-seed NumPy generator per test (tests are independent of their order)."""
    return np.random.default_rng(20240531)


@pytest.fixture
def x64():
    """Run the test body with 64-bit JAX arrays enabled (for finite-difference checks)."""
    with jax.enable_x64(True):
        yield


# ------------------------------------------------------------ synthetic LaFAN1-layout corpus


def synthetic_clip(num_frames: int, seed: int) -> tuple[Skeleton, np.ndarray, np.ndarray]:
    """A smooth random motion on a LaFAN1-shaped skeleton (made-up offsets)."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(scale=10.0, size=(22, 3))
    skeleton = Skeleton(lafan1.PARENTS, lafan1.JOINT_NAMES, offsets)
    t = np.arange(num_frames)[:, None, None] / 30.0
    freq, phase = rng.uniform(0.2, 1.5, size=(1, 22, 3)), rng.uniform(0, 2 * np.pi, size=(1, 22, 3))
    angles = 0.8 * np.sin(2 * np.pi * freq * t + phase)
    angles[:, 0, 0] += np.linspace(0, 3.0, num_frames)  # the root turns around
    with jax.enable_x64(True):
        quat = np.asarray(quat_from_euler(jnp.asarray(angles), "zyx"))
    root = np.stack([100 * np.sin(t[:, 0, 0]), 90 + 5 * np.cos(3 * t[:, 0, 0]), 50 * t[:, 0, 0]], axis=-1)
    return skeleton, quat, root


#: ``(file stem, frames)`` of the synthetic corpus, in the order they are generated (seed = position).
SYNTHETIC_LAFAN1_FILES = (("walk1_subject1", 230), ("run2_subject2", 150), ("dance1_subject5", 300))


@pytest.fixture(scope="session")
def synthetic_zip(tmp_path_factory) -> str:
    """A zip in the official LaFAN1 layout: subjects 1, 2 (train) and 5 (test).

    Our own skeleton offsets and motion (:func:`synthetic_clip`), never LaFAN1 data. Treat it
    as read-only: it is shared by the whole session.
    """
    folder = tmp_path_factory.mktemp("lafan1")
    archive = folder / "lafan1.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for seed, (name, frames) in enumerate(SYNTHETIC_LAFAN1_FILES):
            skeleton, quat, root = synthetic_clip(frames, seed)
            path = folder / f"{name}.bvh"
            write_bvh(path, BvhMotion.from_skeleton(skeleton, quat, root, rotation_order="zyx"), precision=6)
            zf.write(path, arcname=path.name)
    return str(archive)


# ------------------------------------------------------------------ compiled-code housekeeping


@pytest.fixture(scope="module", autouse=True)
def release_compiled_code():
    """Drop every compiled computation after each test module.

    XLA's CPU backend maps each executable's machine code into memory pages of its own, and
    JAX keeps every executable it compiled for as long as the process lives. One pytest
    process compiles thousands of them; after ~20 minutes the mappings pass the kernel's
    ``vm.max_map_count`` (65,530 here) and the next compilation aborts the whole process
    (``Fatal Python error: Aborted`` inside ``backend_compile_and_load``, with ~7 GB of
    RSS, so not an out-of-memory kill). Modules do not share compiled shapes worth keeping:
    recompiling what a later module needs costs less than losing the run.
    """
    yield
    jax.clear_caches()
    gc.collect()


# ------------------------------------------------------------------------ worker processes

#: At most this many pytest-xdist workers (``-n auto``, pyproject's addopts): each holds
#: ~2.5 GB while it compiles, so a many-core machine would otherwise need tens of GB.
MAX_WORKERS = 4


def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: one worker per core this process may use, at most :data:`MAX_WORKERS`.

    Each worker compiles on one core (XLA's CPU compiler is single-threaded per program),
    so two cores halve the suite's time.
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, MAX_WORKERS))
