"""Checkpoints of training-state pytrees with orbax: atomic, self-describing, resumable.

Each checkpoint is a numbered orbax step folder (written under a temporary name and
renamed when complete, so an interrupted save never leaves a readable half checkpoint)
plus ``config.json`` beside them describing what was trained. Typed JAX PRNG keys are
stored as their raw key data and re-wrapped on restore. :meth:`CheckpointStore.check_resumable`
is the resume guard: it refuses a run directory whose checkpoints were trained with
another configuration.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from collections.abc import Collection
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from bezmotion._src.io import atomic_write_text
from bezmotion.training.distributed import checkpoint_processes, in_group

CONFIG_FILE = "config.json"


def _is_key(x: Any) -> bool:
    return isinstance(x, jax.Array | jax.ShapeDtypeStruct) and jnp.issubdtype(x.dtype, jax.dtypes.prng_key)


class _Absent:
    def __repr__(self) -> str:
        return "(absent)"


_ABSENT = _Absent()


def _flatten(tree: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts as ``{"section.key": value}`` (other values, lists included, are leaves)."""
    if not isinstance(tree, dict) or not tree:
        return {prefix: tree}
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        flat.update(_flatten(value, f"{prefix}.{key}" if prefix else str(key)))
    return flat


def _grows(old: Any, new: Any) -> bool:
    """Whether an extendable setting went from ``old`` to a number at least as large."""
    numbers = (int, float)
    return isinstance(old, numbers) and isinstance(new, numbers) and not isinstance(old, bool) and new >= old


class CheckpointStore:
    """Numbered checkpoints of one training run in ``directory``.

    Args:
      directory: the run's folder (created if missing, unless ``read_only``).
      max_to_keep: how many of the most recent checkpoints to keep.
      read_only: open an existing folder to read (loading a saved model): nothing is
        created or written, and a missing folder raises.

    Raises:
      FileNotFoundError: ``read_only`` and ``directory`` is not a folder.
    """

    def __init__(self, directory: str | os.PathLike, *, max_to_keep: int = 3, read_only: bool = False):
        self.directory = Path(directory).expanduser().absolute()
        if read_only and not self.directory.is_dir():
            raise FileNotFoundError(f"{directory}: no such folder")
        primary, active = checkpoint_processes()  # several processes: who writes (see distributed)
        self._writes_config = jax.process_index() == primary and not read_only
        self._alone = active is not None  # a process that has left its training group
        if self._alone and not read_only:  # orbax creates folders only with every process taking part
            self.directory.mkdir(parents=True, exist_ok=True)
        self._read_only = read_only
        self._manager = ocp.CheckpointManager(
            self.directory,
            options=ocp.CheckpointManagerOptions(
                # Not orbax's own read_only, which logs a warning on every load; ``save`` refuses instead.
                max_to_keep=max_to_keep, create=active is None and not read_only, enable_async_checkpointing=False,
                multiprocessing_options=ocp.options.MultiprocessingOptions(primary_host=primary, active_processes=active),
            ),
        )  # fmt: skip

    def latest_step(self) -> int | None:
        return self._manager.latest_step()

    def save(self, step: int, state: Any, config: dict[str, Any] | None = None) -> None:
        """Write ``state`` as checkpoint ``step`` (synchronously) and ``config`` as JSON."""
        if self._read_only:
            raise ValueError(f"{self.directory} was opened read-only; open it without read_only=True to save")
        if config is not None and self._writes_config:  # one writer when several processes train
            atomic_write_text(self.directory / CONFIG_FILE, json.dumps(config, indent=2, sort_keys=True, default=str) + "\n")
        if self._manager.latest_step() == step:
            return  # already saved at this step (e.g. periodic save, then the final one)
        # A flat list of leaves, not the tree itself: orbax rebuilds trees with placeholder
        # leaves, which type-checked dataclass constructors (rightly) refuse.
        leaves = [jax.random.key_data(x) if _is_key(x) else x for x in jax.tree.leaves(state)]
        if self._alone:  # orbax takes no device arrays of one process in a multi-process job
            leaves = [np.asarray(x) for x in leaves]
        self._manager.save(step, args=ocp.args.StandardSave({"leaves": leaves}), force=True)
        self._manager.wait_until_finished()

    def restore(self, like: Any, step: int | None = None) -> Any:
        """Restore checkpoint ``step`` (default: the latest) into the structure of ``like``,
        each leaf placed as ``like``'s (replicated over every process's devices when
        several processes train)."""
        step = self._manager.latest_step() if step is None else step
        if step is None:
            raise FileNotFoundError(f"no checkpoint in {self.directory}")
        flat, treedef = jax.tree.flatten(like)
        abstract = [
            jax.ShapeDtypeStruct(jax.random.key_data(x).shape, jnp.uint32, sharding=getattr(x, "sharding", None))
            if _is_key(x)
            else ocp.utils.to_shape_dtype_struct(x)
            for x in flat
        ]
        restored = self._manager.restore(step, args=ocp.args.StandardRestore({"leaves": abstract}))["leaves"]
        leaves = [jax.random.wrap_key_data(r, impl=jax.random.key_impl(x)) if _is_key(x) else r for r, x in zip(restored, flat)]
        return treedef.unflatten(leaves)

    def config(self) -> dict[str, Any] | None:
        """The configuration saved with the checkpoints (as JSON read it back), or ``None``."""
        path = self.directory / CONFIG_FILE
        return json.loads(path.read_text()) if path.exists() else None

    def check_resumable(self, config: dict[str, Any], extendable: Collection[str] = ()) -> None:
        """Refuse to resume checkpoints that were trained with another configuration.

        The one resume guard of every trainer: run it before :func:`run_training` restores
        from this store. A store without checkpoints (a fresh run) always passes.

        Args:
          config: the configuration this run would save (compared as ``save`` writes it,
            so tuples equal lists and non-JSON values compare as their ``str``).
          extendable: flattened keys (``"train.num_steps"``) that may grow but not shrink:
            lengthening a run whose updates do not depend on its length (a constant
            learning rate) continues the same trajectory, so it is a resume, not a new run.

        Raises:
          ValueError: naming every differing setting as ``section.key: saved → new``.
        """
        saved = self.config()
        if saved is None or self.latest_step() is None:
            return
        new = json.loads(json.dumps(config, sort_keys=True, default=str))
        old_flat, new_flat = _flatten(saved), _flatten(new)
        differ = [
            f"{key}: {old_flat.get(key, _ABSENT)!r} → {new_flat.get(key, _ABSENT)!r}"
            for key in sorted(old_flat.keys() | new_flat.keys())
            if old_flat.get(key, _ABSENT) != new_flat.get(key, _ABSENT)
            and not (key in extendable and _grows(old_flat.get(key), new_flat.get(key)))
        ]
        if differ:
            raise ValueError(
                f"{self.directory} holds a run with other settings ({'; '.join(differ)}); "
                "resume with the same settings or train in another directory"
            )

    def close(self) -> None:
        self._manager.close()


STORAGE_DTYPES = ("float32", "float16", "bfloat16")
"""What a finished model's parameters may be stored as; loaders cast back to float32."""


def cast_floating(tree: Any, dtype: Any) -> Any:
    """``tree`` with every floating-point leaf cast to ``dtype`` (other leaves untouched).

    Raises:
      ValueError: ``dtype`` is not one of :data:`STORAGE_DTYPES`.
    """
    name = dtype if isinstance(dtype, str) else jnp.dtype(dtype).name
    if name not in STORAGE_DTYPES:
        raise ValueError(f"storage_dtype must be one of {STORAGE_DTYPES}, got {name!r}")
    dtype = jnp.dtype(name)
    return jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def save_model_folder(directory: str | os.PathLike, state: Any, config: dict[str, Any]) -> None:
    """Write a finished model (``state`` as checkpoint 0, ``config`` as JSON) to ``directory``,
    replacing any model saved there before.

    A :class:`CheckpointStore` skips a step it already holds (a periodic save, then the final
    one), so saving a retrained model over an old folder that way would keep the old
    parameters beside the new config. Here the model is written to a sibling folder first
    and swapped in, so a re-save replaces everything and an interrupted one leaves the old
    model whole. One process writes: a single process, or one that has left its training
    group (:func:`~bezmotion.training.distributed.leave_group`).

    Raises:
      RuntimeError: called while several processes train together.
    """
    if in_group():
        raise RuntimeError(f"saving a model to {directory}: leave the training group first (one process writes a finished model)")
    target = Path(directory).expanduser().absolute()
    staging = target.with_name(f".{target.name}.saving-{os.getpid()}")
    previous = target.with_name(f".{target.name}.replaced-{os.getpid()}")
    for leftover in (staging, previous):
        shutil.rmtree(leftover, ignore_errors=True)
    store = CheckpointStore(staging, max_to_keep=1)
    store.save(0, state, config)
    store.close()
    if target.exists():
        target.rename(previous)
    staging.rename(target)
    shutil.rmtree(previous, ignore_errors=True)

