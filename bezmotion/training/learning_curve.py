"""Training with a learning curve: validation metrics every N steps, and a stopping rule.

Model-agnostic, around :func:`~bezmotion.training.loop.run_training`: the run trains to
the next evaluation step (checkpointing there), calls ``evaluate(state)``, appends the
result to a JSON file in the run folder (written atomically), and stops early when the
:class:`StoppingRule` says the watched metric has stopped improving. Interrupted and
started again with the same arguments, it resumes from the checkpoint and keeps the
points already measured, so a curve spans as many sessions as the run does.

Curve file layout::

    {"points": [{"step": s, "train_s": cumulative training seconds, "loss": last logged loss,
                 <whatever evaluate returned>}, …],
     "stopped_at": step or null, "stopping": {"metric", "patience", "min_improvement"} or null}
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bezmotion._src.io import atomic_write_text
from bezmotion.training.loop import run_training
from bezmotion.training.state import TrainState


@dataclasses.dataclass(frozen=True)
class StoppingRule:
    """Stop when ``metric`` (lower is better) has not improved for ``patience`` evaluations.

    "Improved" means a value at least ``min_improvement`` (relative) below the best of the
    evaluations before the last ``patience``; ``metric`` is a dotted path into each point
    (e.g. ``"id.dense_error_cm"``).
    """

    metric: str
    patience: int
    min_improvement: float = 0.01

    def __post_init__(self):
        if self.patience < 1 or not 0.0 <= self.min_improvement < 1.0:
            raise ValueError(f"StoppingRule needs patience ≥ 1 and 0 ≤ min_improvement < 1, got {self}")

    def value(self, point: dict[str, Any]) -> float:
        value: Any = point
        for part in self.metric.split("."):
            if not isinstance(value, dict) or part not in value:
                raise KeyError(f"stopping metric {self.metric!r}: {part!r} missing from the evaluation {sorted(point)}")
            value = value[part]
        return float(value)

    def should_stop(self, points: list[dict[str, Any]]) -> bool:
        if len(points) <= self.patience:
            return False
        values = [self.value(p) for p in points]
        best_before = min(values[: -self.patience])
        return min(values[-self.patience :]) > best_before * (1.0 - self.min_improvement)


def load_curve(path: str | Path) -> dict[str, Any]:
    """The curve file at ``path``, or an empty curve when there is none yet."""
    path = Path(path)
    if not path.exists():
        return {"points": [], "stopped_at": None, "stopping": None}
    return json.loads(path.read_text())


def train_with_learning_curve(
    step_fn: Callable[[TrainState, Any], tuple[TrainState, dict]],
    state: TrainState,
    data: Any,
    *,
    num_steps: int,
    eval_every: int,
    evaluate: Callable[[TrainState], dict[str, Any]],
    curve_file: str | Path,
    stopping: StoppingRule | None = None,
    **run_kwargs: Any,
) -> tuple[TrainState, list[dict[str, float | int]], dict[str, Any]]:
    """Train to ``num_steps`` (or an early stop), evaluating every ``eval_every`` steps.

    Args:
      step_fn, state, data, num_steps: as in :func:`~bezmotion.training.loop.run_training`;
        ``run_kwargs`` (``store``, ``checkpoint_every``, ``config``, ``progress``, …) go
        to it too. Give it a ``store`` so a stopped run resumes where the curve ends.
      eval_every: steps between evaluations (the last step is always evaluated).
      evaluate: the state after training to an evaluation step → a JSON-able dict.
      curve_file: the curve's JSON file (created; resumed when it exists).
      stopping: the early-stopping rule, or ``None`` to train all ``num_steps``.
      ``run_kwargs["deadline"]`` (a :func:`time.monotonic` time), when given, also ends
      the curve: the step reached then is evaluated as the curve's last point.
    Returns:
      The final state, this call's logged training records, and the curve (as written).
    Raises:
      ValueError: ``eval_every`` < 1.
    """
    if eval_every < 1:
        raise ValueError(f"eval_every must be ≥ 1, got {eval_every}")
    curve = load_curve(curve_file)
    curve["stopping"] = dataclasses.asdict(stopping) if stopping else None
    done = {p["step"] for p in curve["points"]}
    history: list[dict[str, float | int]] = []
    targets = [*range(eval_every, num_steps, eval_every), num_steps]
    for target in targets:
        if curve["stopped_at"] is not None and curve["stopped_at"] < target:
            break
        started = time.perf_counter()
        state, logged = run_training(step_fn, state, data, num_steps=target, **run_kwargs)
        history += logged
        reached = int(np.max(np.asarray(state.step)))  # a checkpoint saved past ``target`` (Ctrl-C) resumes there
        out_of_time = reached < target  # ``deadline`` passed: later targets would not be reached either
        if reached in done:
            if out_of_time:
                break
            continue
        done.add(reached)
        previous = curve["points"][-1]["train_s"] if curve["points"] else 0.0
        point = {"step": reached, "train_s": previous + time.perf_counter() - started}
        if logged:
            point["loss"] = logged[-1]["loss"]
        point.update(evaluate(state))
        curve["points"].append(point)
        if stopping is not None and stopping.should_stop(curve["points"]):
            curve["stopped_at"] = reached
        atomic_write_text(curve_file, json.dumps(curve, indent=2) + "\n")
        if out_of_time:
            break
    return state, history, curve


__all__ = ["StoppingRule", "load_curve", "train_with_learning_curve"]
