"""Checkpoints of training-state pytrees with orbax: atomic, self-describing, checked, resumable.

Each checkpoint is a numbered orbax step folder (written under a temporary name and
renamed when complete, so an interrupted save never leaves a readable half checkpoint)
plus ``config.json`` beside them describing what was trained. Typed JAX PRNG keys are
stored as their raw key data and re-wrapped on restore. :meth:`CheckpointStore.check_resumable`
is the resume guard: it refuses a run directory whose checkpoints were trained with
another configuration.

Every step folder carries the SHA-256 of its files (``checksums.json``, written last;
:mod:`bezmotion._src.checksums`), and so does every saved model folder
(:func:`save_model_folder`, checked by :func:`open_model_folder`): a flipped, truncated,
emptied or deleted file is found before anything is restored, and a restored state must
be finite. :meth:`CheckpointStore.restore` falls back to the newest checkpoint that passes.
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
from pathlib import Path
from collections.abc import Collection
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from bezmotion._src.checksums import CHECKSUM_FILE, ChecksumError, MissingChecksums, checksum_problem, has_checksums, write_checksums
from bezmotion._src.io import atomic_write_text
from bezmotion._src.messages import listed, one_line
from bezmotion.training.distributed import checkpoint_processes, in_group

CONFIG_FILE = "config.json"
SET_ASIDE = "corrupt"
"""A refused checkpoint ``N`` is renamed ``N.corrupt`` (``N.corrupt-2``, …): orbax ignores
the name, nothing is lost, and the run can save step ``N`` again."""


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


class _Unusable(Exception):
    """A checkpoint that must not be restored: its files differ from their checksums, orbax
    cannot read it, or it holds NaN or inf (the message says which, in a few words)."""


def _finite(x: Any) -> bool:
    return not jnp.issubdtype(x.dtype, jnp.inexact) or bool(jnp.all(jnp.isfinite(x)))


def non_finite_leaves(tree: Any) -> list[str]:
    """The paths (``jax.tree_util.keystr``) of ``tree``'s leaves holding NaN or inf."""
    paths_and_leaves, _ = jax.tree_util.tree_flatten_with_path(tree)
    return [jax.tree_util.keystr(path) for path, leaf in paths_and_leaves if not _finite(leaf)]


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

    def steps(self) -> list[int]:
        """Every checkpoint's step, oldest first."""
        return sorted(self._manager.all_steps())

    def step_folder(self, step: int) -> Path:
        """Where checkpoint ``step`` lives (orbax's default step names)."""
        return self.directory / str(step)

    def save(self, step: int, state: Any, config: dict[str, Any] | None = None) -> None:
        """Write ``state`` as checkpoint ``step`` (synchronously), then its checksums, and
        ``config`` as JSON.

        Raises:
          ValueError: ``state`` holds NaN or inf (a diverged run): nothing is written, so
            the checkpoints before it stay the newest and a resume starts from them.
        """
        if self._read_only:
            raise ValueError(f"{self.directory} was opened read-only; open it without read_only=True to save")
        if bad := non_finite_leaves(state):
            last = self.latest_step()
            kept = f"checkpoint {last} is the newest kept" if last is not None else "no checkpoint was written"
            raise ValueError(f"checkpoint {step} not saved to {self.directory}: the state holds NaN or inf in {listed(bad, shown=3)} (diverged?); {kept}")
        if config is not None and self._writes_config:  # one writer when several processes train
            atomic_write_text(self.directory / CONFIG_FILE, json.dumps(config, indent=2, sort_keys=True, default=str) + "\n")
        if self._manager.latest_step() != step:  # else already saved at this step (a periodic save, then the final one)
            # A flat list of leaves, not the tree itself: orbax rebuilds trees with placeholder
            # leaves, which type-checked dataclass constructors (rightly) refuse.
            leaves = [jax.random.key_data(x) if _is_key(x) else x for x in jax.tree.leaves(state)]
            if self._alone:  # orbax takes no device arrays of one process in a multi-process job
                leaves = [np.asarray(x) for x in leaves]
            self._manager.save(step, args=ocp.args.StandardSave({"leaves": leaves}), force=True)
            self._manager.wait_until_finished()
        # Also when the step was saved already: Ctrl-C while hashing its files leaves it without.
        if self._writes_config and not has_checksums(self.step_folder(step)):
            write_checksums(self.step_folder(step))

    def restore(self, like: Any, step: int | None = None, *, verify: bool = True) -> Any:
        """Restore a checkpoint into the structure of ``like``, each leaf placed as ``like``'s
        (replicated over every process's devices when several processes train).

        A checkpoint is used only when its files match its ``checksums.json`` and every
        floating-point value it holds is finite. Without ``step`` the newest such one is
        restored: newer ones that fail are renamed aside (:data:`SET_ASIDE`; not in a
        read-only store), so the run saves those steps again, and a warning line names each
        with its problem. A checkpoint without checksums, saved before checkpoints carried
        them, is restored unverified (but still checked finite) with a warning; one that
        lacks them while an older one has them had its save cut short, and is refused.

        Args:
          like: a tree of the state's structure, dtypes and shapes (a fresh state).
          step: restore this checkpoint or raise; default: the newest usable one.
          verify: check the checksums (False: the caller has checked the whole folder,
            as :func:`open_model_folder` does).

        Raises:
          FileNotFoundError: the store holds no checkpoint (or not ``step``).
          ValueError: ``step`` is unusable; no checkpoint is usable (naming the folder
            and each one's problem; nothing is renamed then); or a checkpoint whose files
            match their checksums does not restore into ``like`` (another structure).
        """
        paths_and_leaves, treedef = jax.tree_util.tree_flatten_with_path(like)
        if step is not None:
            if step not in self.steps():
                raise FileNotFoundError(f"no checkpoint {step} in {self.directory}")
            try:
                return treedef.unflatten(self._restore_step(paths_and_leaves, step, verify))
            except _Unusable as problem:
                raise ValueError(f"checkpoint {step} in {self.directory} is unusable: {problem}") from None
        steps = self.steps()[::-1]
        if not steps:
            raise FileNotFoundError(f"no checkpoint in {self.directory}")
        refused: list[tuple[int, str]] = []
        for candidate in steps:
            try:
                leaves = self._restore_step(paths_and_leaves, candidate, verify)
            except _Unusable as problem:
                refused.append((candidate, str(problem)))
                continue
            if refused:
                aside = self._set_aside([s for s, _ in refused])
                several = len(refused) > 1
                warnings.warn(
                    one_line(
                        f"checkpoint{'s' if several else ''} "
                        + listed((f"{s} ({problem})" for s, problem in refused), shown=3, sep="; ")
                        + f" in {self.directory} {'are' if several else 'is'} unusable"
                        + (f"; renamed {'them' if several else 'it'} {listed(aside)}" if aside else "")
                        + f"; restored checkpoint {candidate} instead"
                    ),
                    stacklevel=2,
                )
            return treedef.unflatten(leaves)
        raise ValueError(
            one_line(
                f"no usable checkpoint in {self.directory}: "
                + listed((f"{s} ({problem})" for s, problem in refused), shown=3, sep="; ")
                + "; move the folder away to train from scratch"
            )
        )

    def _restore_step(self, paths_and_leaves: list[tuple[Any, Any]], step: int, verify: bool) -> list[Any]:
        """The leaves of checkpoint ``step``, checked (see :meth:`restore`).

        Raises:
          _Unusable: it must not be used (why, in a few words).
          ValueError: its files match their checksums but do not restore into the leaves.
        """
        folder = self.step_folder(step)
        intact = False
        if verify and has_checksums(folder):
            problem = checksum_problem(folder)
            if problem is not None:
                raise _Unusable(problem)
            intact = True
        elif verify:
            if any(s < step and has_checksums(self.step_folder(s)) for s in self.steps()):
                raise _Unusable(f"no {CHECKSUM_FILE}: its save was cut short")
            warnings.warn(
                f"checkpoint {step} in {self.directory} has no {CHECKSUM_FILE} (saved before checkpoints carried them): restoring it unverified",
                stacklevel=3,
            )
        flat = [x for _, x in paths_and_leaves]
        abstract = [
            jax.ShapeDtypeStruct(jax.random.key_data(x).shape, jnp.uint32, sharding=getattr(x, "sharding", None))
            if _is_key(x)
            else ocp.utils.to_shape_dtype_struct(x)
            for x in flat
        ]
        try:
            restored = self._manager.restore(step, args=ocp.args.StandardRestore({"leaves": abstract}))["leaves"]
        except Exception as error:  # orbax and TensorStore raise many kinds on damaged files
            reason = one_line(f"{type(error).__name__}: {(str(error).splitlines() or [''])[0]}", limit=160)
            if intact:  # not damage: the state asked for is not the one saved
                raise ValueError(f"checkpoint {step} in {self.directory} does not restore into this state ({reason})") from None
            raise _Unusable(f"unreadable: {reason}") from None
        leaves = [jax.random.wrap_key_data(r, impl=jax.random.key_impl(x)) if _is_key(x) else r for r, x in zip(restored, flat)]
        bad = [jax.tree_util.keystr(path) for (path, _), leaf in zip(paths_and_leaves, leaves) if not _finite(leaf)]
        if bad:
            raise _Unusable(f"NaN or inf in {listed(bad, shown=3)}")
        return leaves

    def _set_aside(self, steps: list[int]) -> list[str]:
        """Rename refused checkpoints out of orbax's sight; their new names (none when read-only)."""
        names = []
        if self._writes_config:  # the one writer; the others refused the same steps
            for step in steps:
                folder, n = self.step_folder(step), 1
                while (target := folder.with_name(f"{step}.{SET_ASIDE}" + (f"-{n}" if n > 1 else ""))).exists():
                    n += 1
                folder.rename(target)
                names.append(target.name)
        if in_group():  # every process sees the renames before it looks at the steps again
            from jax.experimental import multihost_utils

            multihost_utils.sync_global_devices("bezmotion checkpoints set aside")
        self._manager.reload()
        return names

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


def _model_file(relative: str) -> bool:
    """Whether a file is part of what :func:`save_model_folder` writes (its config and
    checkpoint), not added beside it later (a learned IK's ``joint_limits.json``)."""
    return relative == CONFIG_FILE or relative.split("/", 1)[0].isdigit()


def save_model_folder(directory: str | os.PathLike, state: Any, config: dict[str, Any]) -> None:
    """Write a finished model (``state`` as checkpoint 0, ``config`` as JSON, and the
    checksums of both in ``checksums.json``) to ``directory``, replacing any model saved there before.

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
    write_model_checksums(staging)
    if target.exists():
        target.rename(previous)
    staging.rename(target)
    shutil.rmtree(previous, ignore_errors=True)


def write_model_checksums(directory: str | os.PathLike) -> Path:
    """Write the ``checksums.json`` of a saved model's files (its config and checkpoint;
    files added beside them later are not covered); returns its path.

    :func:`save_model_folder` calls it; call it yourself only on a folder whose files you
    trust (a bundled model checked against the package's manifest)."""
    return write_checksums(directory, include=_model_file)


def open_model_folder(directory: str | os.PathLike, what: str, *, verify: bool = True) -> CheckpointStore:
    """A saved model's folder as a read-only store, its files checked against its checksums.

    Restore from it with ``store.restore(like, step=store.latest_step(), verify=False)``:
    the folder's checksums cover the checkpoint's (the restore still refuses NaN and inf).

    Args:
      directory: the folder :func:`save_model_folder` wrote.
      what: the model's kind in messages (``"BMM"``, ``"learned IK"``).
      verify: check the checksums. ``False`` loads a folder without them (saved before
        models carried them) or one changed on purpose; it warns.

    Raises:
      FileNotFoundError: no such folder, or no ``config.json`` and checkpoint in it.
      ChecksumError: its files differ from ``checksums.json`` (naming them), or it has
        none (``verify=False`` loads it anyway).
    """
    try:  # read-only: loading from a wrong path must not leave a folder there
        store = CheckpointStore(directory, max_to_keep=1, read_only=True)
    except FileNotFoundError:
        raise FileNotFoundError(f"{directory}: not a saved {what} (no such folder)") from None
    try:
        present = has_checksums(store.directory)
        if verify and present and (problem := checksum_problem(store.directory)) is not None:
            raise ChecksumError(f"{directory}: {problem}; the saved {what} was changed or is incomplete: save or copy it again")
        if not (store.directory / CONFIG_FILE).is_file() or store.latest_step() is None:
            raise FileNotFoundError(f"{directory}: not a saved {what} (config.json and a checkpoint expected)")
        if verify and not present:
            raise MissingChecksums(
                f"{directory}: no {CHECKSUM_FILE} (a {what} saved before models carried checksums): "
                "load it with verify=False if you trust its files, then save it again to add them"
            )
    except BaseException:
        store.close()
        raise
    if not verify:
        warnings.warn(f"{directory}: loading the saved {what} unverified (verify=False)", stacklevel=3)
    return store
