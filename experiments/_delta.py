"""What the Δ-interpolator experiment scripts share: their command-line options, one
training run per Δ-mode with a self-describing, resume-safe checkpoint directory, and
averaging over seeds (``experiments/delta_lafan1.py``, ``experiments/delta_anidance.py``)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ClassVar

import jax
import numpy as np

from bezmotion.training.checkpoint import CheckpointStore
from bezmotion.delta.train import DeltaTrainConfig, init_delta_train_states, make_delta_train_step, run_delta_training
from bezmotion.delta.model import DeltaConfig
from bezmotion._src.options import option, options, presets
from bezmotion.training import compile_train_step, train_with_learning_curve
from _common import runs_dir

MODE_NAMES = {"last": "Last", "none": "No", "interpolation": "I"}
"""How the paper's tables name the Δ-modes."""


def mode_label(mode: tuple[str, str]) -> str:
    """``(input Δ-mode, output Δ-mode)`` → the run's name, e.g. ``"last-interpolation"``."""
    return f"{mode[0]}-{mode[1]}"


@options
class DeltaOptions:
    """The options both Δ experiment scripts take (``--out``, data, model size, training, run
    directory); each script subclasses it with its corpus's data, transition lengths and
    ``RUN_NAME``, and adds its own."""

    RUN_NAME: ClassVar[str] = "delta"
    """The default run directory is ``<cache>/runs/<RUN_NAME>_<config>``."""

    out: str = option(help="output JSON (a .md report is written beside it)")
    data: str = option(help="the corpus archive or folder")
    config: str = option(
        "cpu", choices=presets(DeltaConfig), help="model size (default cpu; paper: width 1024, 6 blocks; tiny: smoke tests)"
    )
    steps: int = option(3000, help="training steps per Δ-mode (default 3000)")
    batch_size: int = DeltaTrainConfig.batch_size
    learning_rate: float = option(DeltaTrainConfig.learning_rate, help="peak learning rate (paper: 2e-4)")
    seeds: tuple[int, ...] = option((0,), help="seeds trained together (vmapped)")
    run_dir: str | None = option(
        None, help="checkpoints (default: <cache>/runs/<script>_<config>; {name} and {config} in a given path are filled in)"
    )
    checkpoint_every: int = 500
    eval_every: int = option(0, help="learning curve: evaluate every N steps into <run-dir>/<mode>/learning_curve.json (0 = only at the end)")
    eval_batch: int = option(256, help="test windows per vectorised chunk at evaluation")
    lengths: tuple[int, ...] = option(help="transition lengths")
    no_cache: bool = option(False, help="re-parse the corpus instead of using the cache")
    no_progress: bool = False

    def __post_init__(self):
        if self.eval_every < 0:
            raise ValueError(f"--eval-every must be ≥ 0, got {self.eval_every}")
        # The run directory's placeholders: {name} the script's RUN_NAME, {config} --config.
        template = self.run_dir if self.run_dir is not None else str(runs_dir("{name}_{config}"))
        object.__setattr__(self, "run_dir", template.format(name=self.RUN_NAME, config=self.config))


@dataclasses.dataclass(frozen=True)
class ModeRun:
    """Where one Δ-mode trains and the configuration saved beside its checkpoints."""

    directory: Path
    config: dict[str, Any]

    @classmethod
    def plan(
        cls, args: DeltaOptions, model_config: DeltaConfig, train_config: DeltaTrainConfig, *, data: dict | None = None, suffix: str = ""
    ) -> ModeRun:
        label = mode_label((model_config.input_delta, model_config.output_delta)) + suffix
        config = {
            **({"data": data} if data else {}),
            "model": dataclasses.asdict(model_config),
            "train": {**dataclasses.asdict(train_config), "seeds": list(args.seeds), "num_steps": args.steps},
        }
        return cls(Path(args.run_dir) / label / "checkpoints", config)

    def check_resumable(self) -> None:
        """Refuse, before any work, a run folder whose checkpoints were trained with other
        settings (the schedule depends on ``--steps`` too); see :meth:`CheckpointStore.check_resumable`."""
        store = CheckpointStore(self.directory)
        try:
            store.check_resumable(self.config)
        finally:
            store.close()


def train_delta_mode(
    args: DeltaOptions, run: ModeRun, model_config: DeltaConfig, train_config: DeltaTrainConfig, data, *, window_frames: int,
    evaluate: Callable[[Any, Any], dict] | None = None,
):
    """Train (or resume) one Δ-mode for all seeds at once; returns ``(graphdef, state, history, seconds, curve)``.

    With ``args.eval_every`` > 0 and ``evaluate(graphdef, state)`` (→ a JSON-able dict), the
    run also writes a learning curve beside its checkpoints (``curve`` is then that curve,
    else ``None``); it resumes with the run."""
    graphdef, state = init_delta_train_states(model_config, train_config, args.seeds)
    step = compile_train_step(
        make_delta_train_step(graphdef, model_config, train_config, window_frames=window_frames), num_seeds=len(args.seeds)
    )
    device = jax.devices()[0]
    run.check_resumable()
    store = CheckpointStore(run.directory)
    started = time.perf_counter()
    kwargs = dict(num_steps=args.steps, store=store, checkpoint_every=args.checkpoint_every, config=run.config, progress=not args.no_progress)
    # Restored checkpoints are device-committed; commit fresh states too (one compilation).
    step_fn = lambda s, d: step(jax.device_put(s, device), d)  # noqa: E731
    curve = None
    if args.eval_every and evaluate is not None:
        state, history, curve = train_with_learning_curve(
            step_fn, state, data, eval_every=args.eval_every, evaluate=lambda s: evaluate(graphdef, s),
            curve_file=run.directory.parent / "learning_curve.json", **kwargs,
        )  # fmt: skip
    else:
        state, history = run_delta_training(step_fn, state, data, **kwargs)
    store.close()
    return graphdef, state, history, time.perf_counter() - started, curve


def mean_over_seeds(per_seed: list[Any]) -> Any:
    """Average nested ``{name: {…: float}}`` metric dictionaries over seeds, leaf by leaf."""
    first = per_seed[0]
    if isinstance(first, Mapping):
        return {k: mean_over_seeds([r[k] for r in per_seed]) for k in first}
    return float(np.mean(per_seed))
