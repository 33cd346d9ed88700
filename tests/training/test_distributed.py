"""Data-parallel training over several processes (``bezmotion.training.distributed``).

Two CPU processes on localhost train the tiny BMM on the bundled clip's curves (each
process computes its half of every batch; gloo all-reduces the gradients) and are
compared with one ordinary process; the two-process run, cut back to its orbax
multi-process checkpoint at step 2 and resumed, is compared with itself run straight. Each
process is ``distributed_worker.py``.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from bezmotion.training.distributed import DistributedOptions, check_process_layout

WORKER = Path(__file__).with_name("distributed_worker.py")
STEPS = 6
RESUME_FROM = 2  # the step of the checkpoint the resumed run starts from (the worker checkpoints every 2)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def run_group(run_dir: Path, steps: int, out: Path, num_processes: int, cache: Path) -> None:
    """Run ``num_processes`` workers together (one: an ordinary process) and wait for all.

    The workers share a persistent XLA compilation cache (``cache``): the five processes
    compile the same few programs, and only the first compilation of each need run. They
    compile with the same optimisation setting and XLA flags as this session (``conftest``;
    none of a user's own ``XLA_FLAGS``, which might set the device count).
    """
    env = {
        **os.environ, "XLA_FLAGS": os.environ.get("BEZMOTION_TEST_XLA_FLAGS", ""), "JAX_PLATFORMS": "cpu",
        "JAX_COMPILATION_CACHE_DIR": str(cache), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_DISABLE_MOST_OPTIMIZATIONS": str(int(jax.config.read("jax_disable_most_optimizations"))),
    }  # fmt: skip
    if num_processes == 1:
        commands = [[sys.executable, str(WORKER), str(run_dir), str(steps), str(out)]]
    else:
        coordinator = f"localhost:{free_port()}"
        commands = [
            [sys.executable, str(WORKER), str(run_dir), str(steps), str(out), coordinator, str(num_processes), str(i)]
            for i in range(num_processes)
        ]
    procs = [subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for c in commands]
    try:
        outputs = [p.communicate(timeout=300)[0] for p in procs]
    finally:
        for p in procs:
            p.kill()
    for p, output in zip(procs, outputs):
        assert p.returncode == 0, output[-3000:]


def load(path: Path) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, int]:
    """(state leaves, the same without the attention key bias, losses, device count)."""
    data = np.load(path)
    arrays = [data[f"arr_{i}"] for i in range(len([k for k in data.files if k.startswith("arr_")]))]
    half = len(arrays) // 2
    return arrays[:half], arrays[half:], data["losses"], int(data["devices"])


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("distributed")
    out = {name: root / f"{name}.npz" for name in ("single", "pair", "pair_resumed")}
    cache = root / "xla_cache"
    run_group(root / "single", STEPS, out["single"], 1, cache)
    run_group(root / "pair", STEPS, out["pair"], 2, cache)
    # The pair's run as if killed after its checkpoint at step 2 (those at 4 and 6 never
    # written), then resumed: one launch fewer than an interrupted run of its own.
    shutil.copytree(root / "pair", root / "pair_resumed", ignore=lambda _, names: [n for n in names if n.isdigit() and int(n) > RESUME_FROM])
    run_group(root / "pair_resumed", STEPS, out["pair_resumed"], 2, cache)
    return out


def test_two_processes_train_like_one(runs):
    single, single_stripped, single_losses, single_devices = load(runs["single"])
    pair, pair_stripped, pair_losses, pair_devices = load(runs["pair"])
    assert (single_devices, pair_devices) == (1, 2)  # the pair's batch really was split over two processes
    assert len(pair_losses) == len(single_losses) == STEPS
    np.testing.assert_allclose(pair_losses, single_losses, rtol=1e-5)
    # Sums over two shards round differently; Adam magnifies rounding only where the true
    # gradient is zero (the attention key bias), so everything else agrees closely.
    for a, b in zip(pair_stripped, single_stripped, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4, rtol=1e-4)
    assert any(not np.array_equal(a, b) for a, b in zip(pair, single))  # not the same computation


def test_two_process_resume_is_bit_identical(runs):
    straight, _, straight_losses, _ = load(runs["pair"])
    resumed, _, resumed_losses, _ = load(runs["pair_resumed"])
    for a, b in zip(resumed, straight, strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(resumed_losses) == STEPS - RESUME_FROM  # it did resume: only steps 3…6 ran
    np.testing.assert_array_equal(resumed_losses, straight_losses[RESUME_FROM:])


@pytest.mark.parametrize(
    ("coordinator", "num_processes", "process_id", "message"),
    [
        ("localhost", 2, 0, "'localhost'"),
        ("localhost:99999", 2, 0, "'localhost:99999'"),
        ("localhost:1234", 0, 0, "got 0"),
        ("localhost:1234", 2, 2, "got 2"),
        ("localhost:1234", 2, -1, "got -1"),
    ],
)
def test_bad_process_layout_names_the_value(coordinator, num_processes, process_id, message):
    with pytest.raises(ValueError, match=message):
        check_process_layout(coordinator, num_processes, process_id)
    with pytest.raises(ValueError, match=message):
        DistributedOptions(coordinator=coordinator, num_processes=num_processes, process_id=process_id)


def test_process_flags_without_a_coordinator_raise():
    with pytest.raises(ValueError, match="need a coordinator"):
        DistributedOptions(num_processes=2)
    assert DistributedOptions().coordinator is None  # one process: the default
