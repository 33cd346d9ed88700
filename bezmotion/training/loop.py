"""The training loop for any model: compile a step, run it with checkpoints and resume.

``run_training`` knows no model: it calls a compiled ``step(state, data)``, logs its
metrics, checkpoints every N steps and on Ctrl-C or SIGTERM, and resumes from the
newest checkpoint of its store that passes its checksums and holds finite values
(:meth:`~bezmotion.training.checkpoint.CheckpointStore.restore`: never from a damaged one). With more than one device, :func:`data_mesh` and
:func:`shard_batch` split the batch over them and XLA all-reduces the gradients; after
:func:`bezmotion.training.distributed.initialize` the devices are every process's, and
``run_training`` replicates the state and data over them.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxtyping import Array
from tqdm.auto import tqdm

from bezmotion.training.checkpoint import CheckpointStore
from bezmotion.training.distributed import is_coordinator, is_distributed, localize, replicate
from bezmotion.training.state import TrainState


def shard_batch(x: Array, mesh: Mesh | None) -> Array:
    """Split the batch axis over the mesh's devices (no-op on one device)."""
    if mesh is None:
        return x
    return jax.lax.with_sharding_constraint(x, NamedSharding(mesh, PartitionSpec("data")))


def compile_train_step(step_fn: Callable, *, num_seeds: int | None) -> Callable:
    """``jax.jit`` the step, vmapped over stacked seeds when ``num_seeds`` is given.

    The state is not donated: if Ctrl-C lands mid-step, the previous state must still be
    intact so it can be checkpointed."""
    fn = jax.vmap(step_fn, in_axes=(0, None)) if num_seeds is not None else step_fn
    return jax.jit(fn)


def data_mesh() -> Mesh | None:
    """A 1-D mesh named ``"data"`` over all devices — every process's, when training on
    several (:mod:`bezmotion.training.distributed`) — or ``None`` with one device."""
    devices = jax.devices()
    return Mesh(np.asarray(devices), ("data",)) if len(devices) > 1 else None


def _host_value(x: Array) -> np.ndarray:
    """A metric's value on this host; a global array (several processes) is gathered
    unless every process already holds all of it."""
    if isinstance(x, jax.Array) and not x.is_fully_addressable and not x.is_fully_replicated:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(x)


@contextlib.contextmanager
def _terminate_requests():
    """Record SIGTERM (``kill``, a scheduler's pre-emption) instead of dying, so the loop
    can stop at a step boundary and checkpoint as on Ctrl-C. Background jobs of a
    non-interactive shell ignore SIGINT, so for them SIGTERM is the polite way to stop.
    Yields a list that gets the signal number; a no-op outside the main thread."""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: received.append(signum))
    try:
        yield received
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_training(
    step_fn: Callable[[TrainState, Any], tuple[TrainState, dict[str, Array]]],
    state: TrainState,
    data: Any,
    *,
    num_steps: int,
    store: CheckpointStore | None = None,
    checkpoint_every: int = 1000,
    config: dict[str, Any] | None = None,
    progress: bool = True,
    log_every: int = 25,
    progress_fn: Callable[[int, dict[str, float | int]], None] | None = None,
    deadline: float | None = None,
) -> tuple[TrainState, list[dict[str, float | int]]]:
    """Run a compiled step until ``state.step`` reaches ``num_steps``, resuming from ``store``.

    Model-agnostic: ``data`` is whatever the step takes (BMM's :class:`CurveArrays`, the
    Δ-interpolator's windows, the IK's poses).

    Args:
      step_fn: the compiled ``step(state, data) -> (state, metrics)``; ``metrics`` holds
        scalars (one per seed when vmapped), ``"loss"`` among them.
      state: the state to start from when ``store`` holds no checkpoint.
      data: passed to every step unchanged.
      num_steps: the step count to stop at (total, not this call's share).
      store: where to checkpoint and resume from; ``None`` runs without checkpoints. A
        damaged latest checkpoint is set aside with a warning and the one before it resumed;
        with none usable, ``ValueError`` names the folder. A state that turned NaN or inf
        (a diverged run) is never saved: ``ValueError`` at its checkpoint, the ones before kept.
      checkpoint_every: checkpoint period (steps); also at the end and on Ctrl-C or
        SIGTERM (then raises ``KeyboardInterrupt``).
      config: saved as the store's ``config.json`` with every checkpoint.
      progress: show a tqdm progress bar (on process 0 only, when training on several).
      log_every: logging period (steps); the last step is always logged.
      progress_fn: called as ``progress_fn(step, record)`` at every logged step, after
        that step's periodic checkpoint if it has one (the final checkpoint is written
        after the last call); ``record`` is the entry appended to
        the history (``step``, ``steps_per_s`` since this call started, and the metrics
        averaged over seeds).
      deadline: a :func:`time.monotonic` time after which training stops at the next
        step boundary, checkpoints and returns (the state's step then falls short of
        ``num_steps``; a later call with the same store goes on from there), so a run sized
        to a wall-clock budget (a lent GPU, a session's end) keeps all it trained.

    Returns:
      The final state and the logged records (every ``log_every`` steps and the last).

    On several processes (:mod:`bezmotion.training.distributed`) every process calls this
    with the same ``state`` and ``data``; both are replicated over :func:`data_mesh`, the
    step splits each batch over all processes' devices, ``progress_fn`` runs in every
    process (guard file writes with ``is_coordinator()``), checkpoints are orbax's
    multi-process ones, and the returned state is each process's own local copy, so the
    code after training runs as in one process.
    """
    if is_distributed():
        mesh = data_mesh()
        state, data = replicate(state, mesh), replicate(data, mesh)
        progress = progress and is_coordinator()
    if store is not None and store.latest_step() is not None:
        state = store.restore(state)
    done = int(np.max(_host_value(state.step)))
    history: list[dict[str, float]] = []
    bar = tqdm(total=num_steps, initial=done, desc="training", unit="step", disable=not progress)
    started, started_step = time.perf_counter(), done
    with _terminate_requests() as terminate:
        try:
            while done < num_steps:
                if terminate:  # a SIGTERM arrived during the last step: stop here, cleanly
                    raise KeyboardInterrupt(f"signal {terminate[0]}")
                state, metrics = step_fn(state, data)
                done += 1
                out_of_time = deadline is not None and time.monotonic() >= deadline
                record = None
                if done % log_every == 0 or done == num_steps or out_of_time:
                    logged = {k: float(np.mean(_host_value(v))) for k, v in metrics.items()}
                    rate = (done - started_step) / max(time.perf_counter() - started, 1e-9)
                    record = {"step": done, "steps_per_s": rate, **logged}
                    history.append(record)
                    bar.set_postfix(loss=f"{logged['loss']:.4g}", steps_per_s=f"{rate:.2f}")
                bar.update(1)
                if store is not None and done % checkpoint_every == 0:
                    store.save(done, state, config)
                if progress_fn is not None and record is not None:
                    progress_fn(done, record)
                if out_of_time:
                    bar.write(f"time limit reached at step {done} of {num_steps}")
                    break
        except KeyboardInterrupt:
            if store is not None:
                done = int(np.max(_host_value(state.step)))  # the state actually held, whatever was interrupted
                store.save(done, state, config)
                bar.write(f"interrupted: saved step {done} to {store.directory}")
            raise
        finally:
            bar.close()
    if store is not None:
        store.save(done, state, config)
    if is_distributed():
        state = localize(state)
    return state, history


__all__ = ["compile_train_step", "data_mesh", "run_training", "shard_batch"]
