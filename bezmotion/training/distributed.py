"""Data-parallel training over several processes (``jax.distributed``), one machine or many.

JAX's multi-controller model: the same script runs once per process; every process holds
the whole (small) dataset and the same state, replicated, and the compiled step splits
each batch over *all* processes' devices (:func:`~bezmotion.training.loop.data_mesh` is
global once :func:`initialize` has run), so XLA all-reduces the gradients across
processes. Since every trainer draws its batch indices and per-example keys from
``state.key`` inside the step, the processes agree on the batch without talking; each
computes the loss of its own shard of it. Checkpoints are orbax's multi-process ones:
every process calls save and restore, process 0 writes the metadata and ``config.json``.

Launch ``N`` copies of a training script with the same coordinator and each its own id::

    python experiments/bmm_lafan1.py ... --coordinator host0:12355 --num-processes 2 --process-id 0
    python experiments/bmm_lafan1.py ... --coordinator host0:12355 --num-processes 2 --process-id 1

On CPU the cross-process collectives go through gloo (:func:`initialize` selects it).
The single-process path is unchanged: without :func:`initialize`, nothing here runs.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from bezmotion._src.options import option, options


@options
class DistributedOptions:
    """The command-line options of a training script that can run on several processes."""

    coordinator: str | None = option(
        None, help="HOST:PORT of process 0, to train data-parallel on several processes (default: one process)"
    )
    num_processes: int = option(1, help="how many processes train together (with --coordinator)")
    process_id: int = option(0, help="this process's index, 0 … num-processes − 1 (with --coordinator)")

    def __post_init__(self):
        if self.coordinator is None:
            if self.num_processes != 1 or self.process_id != 0:
                raise ValueError(
                    f"num_processes {self.num_processes} / process_id {self.process_id} need a coordinator HOST:PORT"
                )
            return
        check_process_layout(self.coordinator, self.num_processes, self.process_id)

    def initialize(self) -> None:
        """Join the process group these options describe (nothing for one process)."""
        if self.coordinator is not None:
            initialize(self.coordinator, self.num_processes, self.process_id)


def check_process_layout(coordinator: str, num_processes: int, process_id: int) -> None:
    """Raise ``ValueError`` naming the value unless the three describe a valid process group."""
    host, _, port = coordinator.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"coordinator must be HOST:PORT, got {coordinator!r}")
    if num_processes < 1:
        raise ValueError(f"num_processes must be at least 1, got {num_processes}")
    if not 0 <= process_id < num_processes:
        raise ValueError(f"process_id must be in 0 … {num_processes - 1}, got {process_id}")


def initialize(coordinator: str, num_processes: int, process_id: int, *, timeout_s: int = 300) -> None:
    """Join a group of ``num_processes`` training processes coordinated at ``coordinator``.

    Call before any other JAX computation, in every process, with the same
    ``coordinator`` (``HOST:PORT`` reachable by all; process 0 listens there) and
    ``num_processes`` and a distinct ``process_id``. Selects gloo for CPU collectives
    (the CPU backend has no cross-process all-reduce otherwise).

    Raises:
      ValueError: a malformed coordinator or an id outside ``0 … num_processes − 1``.
    """
    check_process_layout(coordinator, num_processes, process_id)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator, num_processes=num_processes, process_id=process_id, initialization_timeout=timeout_s)


def is_distributed() -> bool:
    """Whether this process is one of several (after :func:`initialize`)."""
    return jax.process_count() > 1


def is_coordinator() -> bool:
    """Whether this process writes the files every process would otherwise write alike."""
    return jax.process_index() == 0


def replicate(tree: Any, mesh: Mesh) -> Any:
    """Every leaf as a global array replicated on all of ``mesh``'s devices.

    Every process must pass the same values (they are not compared): the training state
    built from the same seed, the same dataset."""
    sharding = NamedSharding(mesh, PartitionSpec())

    def leaf(x):
        if isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            return jax.random.wrap_key_data(leaf(jax.random.key_data(x)), impl=jax.random.key_impl(x))
        # Through the host: device_put moves a host value onto every process's devices,
        # but refuses an array committed to one local device.
        return jax.device_put(np.asarray(x), sharding)

    return jax.tree.map(leaf, tree)


_left_group = False  # set by leave_group: jax.process_count() stays > 1 after shutdown


def leave_group() -> None:
    """End this process's part in the group (every process calls it, once the shared
    training is done); afterwards each computes alone on its own devices, so process 0
    can evaluate while the others exit. Nothing for one process."""
    global _left_group
    if is_distributed():
        jax.distributed.shutdown()
        _left_group = True


def in_group() -> bool:
    """Whether several processes are training together now (and have not left the group)."""
    return jax.process_count() > 1 and not _left_group


def checkpoint_processes() -> tuple[int, set[int] | None]:
    """The orbax primary host and active processes for a checkpoint written now: all
    processes while the group trains (``None``), this process alone once it has left."""
    return (jax.process_index(), {jax.process_index()}) if _left_group else (0, None)


def localize(tree: Any) -> Any:
    """Every leaf of a replicated global tree as this process's own array on its first
    local device, so code after training (evaluation, saving) runs as in one process."""
    device = jax.local_devices()[0]

    def leaf(x):
        if isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            return jax.random.wrap_key_data(leaf(jax.random.key_data(x)), impl=jax.random.key_impl(x))
        return jax.device_put(np.asarray(x), device)

    return jax.tree.map(leaf, tree)


__all__ = [
    "checkpoint_processes",
    "in_group",
    "localize",
    "DistributedOptions",
    "check_process_layout",
    "initialize",
    "is_coordinator",
    "is_distributed",
    "leave_group",
    "replicate",
]
