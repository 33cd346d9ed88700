"""Training with a learning curve (``bezmotion.training.learning_curve``) on the model-free
toy of ``test_loop``: evaluation points, the stopping rule, and resume across calls."""

from __future__ import annotations

import json
import time

import jax.numpy as jnp
import numpy as np
import pytest

from training.test_loop import TARGET, assert_identical, step, toy_state  # noqa: F401  (step: the compiled fixture)

from bezmotion.training import CheckpointStore, StoppingRule, train_with_learning_curve


def distance(state) -> dict:
    return {"val": {"distance": float(jnp.linalg.norm(state.ema["w"] - TARGET))}}


def test_stopping_rule():
    rule = StoppingRule("val.distance", patience=2, min_improvement=0.1)
    points = lambda *v: [{"val": {"distance": x}} for x in v]  # noqa: E731
    assert not rule.should_stop(points(5.0, 4.0))  # too few points
    assert not rule.should_stop(points(5.0, 4.0, 3.0))  # still improving
    assert rule.should_stop(points(5.0, 4.0, 3.8, 3.9))  # best before 4.0; 3.8 is only 5 % better
    assert not rule.should_stop(points(5.0, 4.0, 3.5, 3.9))  # 3.5 is 12.5 % better
    with pytest.raises(KeyError, match="distance"):
        rule.value({"val": {}})
    for bad in ({"patience": 0}, {"min_improvement": 1.0}):
        with pytest.raises(ValueError):
            StoppingRule("x", **{"patience": 2, **bad})


def test_curve_points_and_resume_across_calls(step, tmp_path):  # noqa: F811
    curve_file = tmp_path / "curve.json"

    def run(num_steps, store_dir):
        store = CheckpointStore(store_dir)
        try:
            return train_with_learning_curve(
                step, toy_state(0), TARGET, num_steps=num_steps, eval_every=10, evaluate=distance,
                curve_file=curve_file, store=store, progress=False, log_every=5,
            )  # fmt: skip
        finally:
            store.close()

    state, _, curve = run(25, tmp_path / "run")
    assert [p["step"] for p in curve["points"]] == [10, 20, 25]
    distances = [p["val"]["distance"] for p in curve["points"]]
    assert distances[0] > distances[-1] and all(np.isfinite(distances))
    assert all(b["train_s"] >= a["train_s"] for a, b in zip(curve["points"], curve["points"][1:]))
    assert json.loads(curve_file.read_text()) == curve
    # Again with a longer horizon: resumes at 25, keeps the points, adds 30, 40.
    state2, _, curve2 = run(40, tmp_path / "run")
    assert [p["step"] for p in curve2["points"]] == [10, 20, 25, 30, 40]
    assert curve2["points"][:3] == curve["points"]
    # The same 40 steps straight through give the same state (resume is exact).
    curve_file.unlink()
    straight, _, _ = run(40, tmp_path / "straight")
    assert_identical(state2, straight)


def test_early_stop_is_kept_on_resume(step, tmp_path):  # noqa: F811
    """A rule that always fires after 2 points stops the run; calling again trains no further."""
    curve_file = tmp_path / "curve.json"
    rule = StoppingRule("val.distance", patience=1, min_improvement=0.99)
    kwargs = dict(num_steps=100, eval_every=10, evaluate=distance, curve_file=curve_file, stopping=rule, progress=False)
    store = CheckpointStore(tmp_path / "run")
    state, _, curve = train_with_learning_curve(step, toy_state(0), TARGET, store=store, **kwargs)
    assert curve["stopped_at"] == 20 and int(state.step) == 20
    again, _, curve2 = train_with_learning_curve(step, toy_state(0), TARGET, store=store, **kwargs)
    store.close()
    assert int(again.step) == 20 and curve2["points"] == curve["points"]
    with pytest.raises(ValueError, match="eval_every"):
        train_with_learning_curve(step, toy_state(0), TARGET, **{**kwargs, "eval_every": 0})


def test_out_of_time_the_step_reached_is_the_last_point(step, tmp_path):  # noqa: F811
    """With the deadline already passed, one step is trained, evaluated as the curve's last
    point, and the curve ends there; the same call without a deadline goes on from it."""
    curve_file = tmp_path / "curve.json"
    kwargs = dict(num_steps=25, eval_every=10, evaluate=distance, curve_file=curve_file, progress=False)
    store = CheckpointStore(tmp_path / "run")
    state, _, curve = train_with_learning_curve(step, toy_state(0), TARGET, store=store, deadline=time.monotonic() - 1.0, **kwargs)
    assert int(state.step) == 1 and [p["step"] for p in curve["points"]] == [1]
    state, _, curve = train_with_learning_curve(step, toy_state(0), TARGET, store=store, **kwargs)
    store.close()
    assert int(state.step) == 25 and [p["step"] for p in curve["points"]] == [1, 10, 20, 25]
