"""The LaFAN1 transition benchmark for every in-betweener we train, beside the published records.

    python experiments/lafan1_benchmark.py --out results/lafan1_benchmark.json

The official protocol (:mod:`bezmotion.evaluation.lafan1`, which reproduces the La Forge
evaluator to 1e-4): subject 5's windows of 65 frames at offset 40, 10 past frames, the
target frame, n = 5 / 15 / 30 / 45 missing frames; L2Q, L2P and NPSS. Rows:

- ``zerov``, ``interp``: the official baselines;
- ``delta``: the Δ-interpolator trained by ``experiments/delta_lafan1.py``, restored from
  its run folder (``--delta-run``; the newest checkpoint, every seed in it, metrics averaged
  over seeds), with the steps and epochs it had trained;
- ``bmm``: a saved BMM (``--bmm``, e.g. one trained with ``experiments/bmm_lafan1.py --corpus
  lafan1 --spans 6 60``) in-betweens the last past frame and the target frame, ``n + 1``
  frames apart, through its curves and the exact IK from the analytic rig (``exact_rig``:
  LaFAN1's learned IK is not trained here); the keys' poses and the first key's velocity,
  the six joints' from the last two past frames (the target's is not known: NaN,
  ``--bmm-no-velocity`` gives neither). One sample (``bmm``), and the mean of
  ``--bmm-samples`` samples' curves put through the IK once (``bmm_mean``: what sampling
  costs on a deterministic metric). Without ``--bmm`` the row is absent and ``missing`` says why.

``published`` holds the records on the full LaFAN1 test set (2,232 windows;
``../shared/REFERENCE.md`` §1 and §6), which our subset's windows are not: compare the
``ratio_to_interp`` rows (each row over its own test set's interpolation), not the values.
``versus_delta`` is each row over the Δ-interpolator trained here (below 1: better).
Writes the JSON and a Markdown report beside it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from _common import runs_dir
from bezmotion._src.io import write_results
from bezmotion._src.options import option, options, parse_options
from bezmotion.data.lafan1 import JOINT_NAMES, PARENTS
from bezmotion.data.sources import default_source
from bezmotion.delta.model import DeltaConfig, delta_inbetweener
from bezmotion.delta.train import DeltaTrainConfig, init_delta_train_states
from bezmotion.bmm.sampling import load_model
from bezmotion.data.sources import load_corpus
from bezmotion.evaluation.lafan1 import N_PAST, TRANSITION_LENGTHS, evaluate_baselines, evaluate_transitions, lafan1_benchmark
from bezmotion.geometry.rotations import quat_fix_continuity
from bezmotion.handles import Handles
from bezmotion.ik.frames import corpus_character
from bezmotion.ik.protocol import Pose, targets_from_pose
from bezmotion.pipeline.authoring import RecognisedCharacter, derive_rig_spec, make_ik
from bezmotion.pipeline.inbetweening import InbetweenOptions, curves_traced, result_from_curves
from bezmotion.pipeline.model import Inbetweener
from bezmotion.pipeline.transfer import Transfer
from bezmotion.geometry import Skeleton
from bezmotion.training.checkpoint import CheckpointStore

METRICS = ("l2q", "l2p", "npss")
ROWS = ("zerov", "interp", "delta", "bmm", "bmm_mean")
LENGTHS = tuple(str(n) for n in TRANSITION_LENGTHS)


def _row(l2q, l2p, npss) -> dict:
    """A published row: per metric, the values at n = 5, 15, 30, 45 (None: not reported)."""
    return {m: dict(zip(LENGTHS, values)) for m, values in zip(METRICS, (l2q, l2p, npss))}


PUBLISHED = {
    "zerov": _row((0.56, 1.10, 1.51, 1.81), (1.5230, 3.6944, 6.6002, 9.3289), (0.0053, 0.0522, 0.2318, 0.4918)),
    "interp": _row((0.22, 0.62, 0.98, 1.25), (0.3729, 1.2488, 2.3158, 3.4469), (0.0023, 0.0391, 0.2013, 0.4493)),
    "rmib": _row((0.17, 0.42, 0.69, 0.94), (0.23, 0.65, 1.28, 2.24), (None, None, 0.1328, None)),
    "delta": _row((0.1138, 0.3175, 0.5723, None), (0.1290, 0.4670, 0.9954, None), (0.0014, 0.0217, 0.1217, None)),
    "two_stage": _row((0.099, 0.284, 0.545, 0.873), (0.105, 0.394, 0.895, 1.678), (0.0011, 0.0188, 0.1124, 0.3217)),
}
"""The records on the full LaFAN1 test set (official metrics; the Δ-interpolator: mean of 8
seeds, its paper's L2Q/NPSS convention). Sources: ``../shared/REFERENCE.md`` §1 and §6."""

PUBLISHED_NAMES = {
    "zerov": "zero-velocity", "interp": "interpolation", "rmib": "RMIB (Harvey et al. 2020)",
    "delta": "Δ-interpolator (its paper, 8 seeds)", "two_stage": "two-stage transformers (Qin et al. 2022)",
}  # fmt: skip

BMM_MISSING = (
    "no --bmm given: the benchmark's keys are n + 1 frames apart (6, 16, 31, 46), so the row wants a LaFAN1 BMM trained on windows "
    "of those lengths (experiments/bmm_lafan1.py --corpus lafan1 --spans 6 60)"
)


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it)")
    data: str = option(str(default_source("lafan1")), help="LaFAN1 zip or BVH folder (default the subset in ../shared/data)")
    delta_run: str = option(
        str(runs_dir("delta_lafan1_300ep_cpu") / "last-interpolation" / "checkpoints"),
        help="the Δ-interpolator's checkpoint folder (experiments/delta_lafan1.py's <run-dir>/last-interpolation/checkpoints)",
    )
    eval_batch: int = option(256, help="test windows per vectorised chunk")
    bmm: str | None = option(None, help="a saved BMM's folder (bmm_lafan1.py's <run-dir>/model) for the bmm rows; default: none")
    bmm_samples: int = option(8, help="samples whose mean curves make the bmm_mean row")
    bmm_batch: int = option(16, help="test windows per vectorised BMM chunk")
    bmm_no_velocity: bool = option(False, help="give the BMM the keys' poses alone, not the first key's velocity from the past frames")
    no_cache: bool = option(False, help="re-parse the corpus instead of using the cache")


def restore_delta(folder: Path):
    """``(graphdef, per-seed params list, config dict, step)`` of the newest usable checkpoint
    in a Δ-interpolator run's checkpoint ``folder`` (its ``config.json`` rebuilds the model)."""
    config = json.loads((folder / "config.json").read_text())
    model = dict(config["model"], parents=tuple(config["model"]["parents"]))
    train = {k: v for k, v in config["train"].items() if k not in ("seeds", "num_steps")}
    model_config, train_config = DeltaConfig(**model), DeltaTrainConfig(**train)
    graphdef, like = init_delta_train_states(model_config, train_config, config["train"]["seeds"])
    store = CheckpointStore(folder, read_only=True)
    try:
        state = store.restore(like)  # the newest usable one (a run still training may be saving the next)
    finally:
        store.close()
    seeds = len(config["train"]["seeds"])
    return graphdef, [jax.tree.map(lambda x, i=i: x[i], state.params) for i in range(seeds)], config, int(np.asarray(state.step).ravel()[0])


def bmm_model(bmm_dir: str, data: str, no_cache: bool) -> Inbetweener:
    """The saved BMM with the exact IK from the analytic rig, on LaFAN1's character."""
    character = corpus_character(load_corpus("lafan1", source=data, use_cache=not no_cache))
    recognised = RecognisedCharacter(character, "lafan1", derive_rig_spec(character))
    rest = np.tile(np.asarray([1.0, 0.0, 0.0, 0.0], np.float32), (character.num_joints, 1))
    ik_fn, ik_params = make_ik("exact_rig", recognised, rest_quat_local=rest)
    return Inbetweener(load_model(bmm_dir), ik_fn, ik_params, character)


def bmm_transitions(
    bench, model: Inbetweener, n: int, *, samples: int, batch: int, velocity: bool = True, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """``(quat (W, n, 22, 4), root (W, n, 3))``: each test window's in-between of its last past
    frame and its target frame (``n + 1`` frames apart); ``samples > 1``: the mean of that many
    samples' curves, through the IK once. ``velocity``: the first key's six-joint velocity
    from the last two past frames is a condition (the target's is not known: NaN)."""
    w = bench.windows
    ends = np.asarray([N_PAST - 1, N_PAST + n])
    pose = lambda frames: Pose(root_pos=np.asarray(w.root_pos[:, frames], np.float32), quat_local=np.asarray(w.quat_local[:, frames], np.float32))  # noqa: E731
    keys = pose(ends)
    past = np.asarray(targets_from_pose(model.character, pose(np.asarray([N_PAST - 2, N_PAST - 1]))).position)  # (W, 2, 6, 3)
    key_velocity = np.stack([past[:, 1] - past[:, 0], np.full_like(past[:, 0], np.nan)], axis=1)  # (W, 2, 6, 3) cm/frame
    none = Handles(jnp.zeros((1, 1), jnp.int32), jnp.zeros((1, 1), jnp.int32), jnp.zeros((1, 1, 3)), jnp.zeros((1, 1), bool))
    options, transfer = InbetweenOptions(), Transfer.identity()

    def one(keys: Pose, key_velocity, key):
        kv = key_velocity if velocity else None
        draws = jax.vmap(lambda k: curves_traced(model.bmm, model.character, keys, none, transfer, k, options, kv, checked=False, span=n + 1))(
            jax.random.split(key, samples)
        )  # fmt: skip
        windows = jax.tree.map(lambda a: jnp.mean(a, axis=0), draws)
        pose = result_from_curves(model, windows, keys, none, options).pose
        return pose.quat_local[1:-1], pose.root_pos[1:-1]

    run = jax.jit(jax.vmap(one))
    quat, root = [], []
    for lo in range(0, w.num_windows, batch):
        part = jax.tree.map(lambda a: a[lo : lo + batch], (keys, key_velocity))
        count = part[1].shape[0]
        padded = jax.tree.map(lambda a: np.concatenate([a, np.repeat(a[:1], batch - count, axis=0)]), part)  # one compiled shape
        keys_per_window = jax.random.split(jax.random.fold_in(jax.random.key(seed), lo), batch)
        q, r = run(*padded, keys_per_window)
        # q and −q are one rotation, but L2Q and NPSS compare components: each joint's sign is
        # made continuous from the last past frame on, as the data's own are.
        q = quat_fix_continuity(jnp.concatenate([padded[0].quat_local[:, :1], q], axis=1), axis=1)[:, 1:]
        quat.append(np.asarray(q)[:count])
        root.append(np.asarray(r)[:count])
    return np.concatenate(quat), np.concatenate(root)


def evaluate_bmm(bench, model: Inbetweener, samples: int, batch: int, velocity: bool) -> dict:
    """Official metrics of the BMM's in-betweens (precomputed per length outside the
    evaluator's float64 mode, then scored by it)."""
    predicted = {n: bmm_transitions(bench, model, n, samples=samples, batch=batch, velocity=velocity) for n in TRANSITION_LENGTHS}
    return evaluate_transitions(bench, lambda pq, pr, tq, tr, n: tuple(jnp.asarray(a, jnp.float64) for a in predicted[n]), TRANSITION_LENGTHS)


def ratios(rows: dict, denominator: dict) -> dict:
    """Each row's values over ``denominator``'s, metric by metric and length by length."""
    out = {}
    for name, row in rows.items():
        out[name] = {
            m: {n: (None if row[m].get(n) is None or not denominator[m].get(n) else row[m][n] / denominator[m][n]) for n in LENGTHS}
            for m in METRICS
        }
    return out


def table(rows: dict, names: dict, fmt: str = "{:.3f}") -> str:
    header = "| row | " + " | ".join(f"{m.upper()} n={n}" for m in METRICS for n in LENGTHS) + " |"
    lines = [header, "|" + "---|" * (1 + len(METRICS) * len(LENGTHS))]
    for name, row in rows.items():
        cells = [("–" if row[m].get(n) is None else fmt.format(row[m][n])) for m in METRICS for n in LENGTHS]
        lines.append(f"| {names.get(name, name)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def report(results: dict) -> str:
    ours = {k: results[k] for k in ROWS if k in results}
    names = {
        "zerov": "zero-velocity", "interp": "interpolation", "delta": f"Δ-interpolator here ({results['delta_training']['steps']} steps)",
        "bmm": "BMM here, one sample", "bmm_mean": f"BMM here, mean of {results.get('bmm_model', {}).get('samples')} samples",
    }  # fmt: skip
    return "\n\n".join([
        f"# LaFAN1 benchmark, {results['n_windows']} test windows of the subset (official metrics)",
        table(ours, names, "{:.4f}"),
        "Ratio to interpolation (comparable across test sets):",
        table(results["ratio_to_interp"], {**names, **{f"published_{k}": f"{v}, full set" for k, v in PUBLISHED_NAMES.items()}}),
        "Each row over the Δ-interpolator trained here (below 1: better):",
        table(results["versus_delta"], names),
        "Published, the full LaFAN1 test set (not our subset):",
        table(PUBLISHED, PUBLISHED_NAMES),
        *([f"BMM: {results['missing']['bmm']}"] if "bmm" in results.get("missing", {}) else [f"BMM: {results['bmm_model']}"]),
    ])  # fmt: skip


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    started = time.perf_counter()
    bench = lafan1_benchmark(args.data, use_cache=not args.no_cache)
    results: dict = evaluate_baselines(bench, TRANSITION_LENGTHS)
    results["data"] = str(args.data)

    graphdef, per_seed, config, step = restore_delta(Path(args.delta_run))
    skeleton = Skeleton(PARENTS, JOINT_NAMES, bench.stats.offsets)
    metrics = [evaluate_transitions(bench, delta_inbetweener(graphdef, p, skeleton, batch_size=args.eval_batch), TRANSITION_LENGTHS) for p in per_seed]
    results["delta"] = {m: {n: float(np.mean([r[m][n] for r in metrics])) for n in LENGTHS} for m in METRICS}
    schedule_steps = config["train"]["num_steps"]
    results["delta_training"] = {
        "run": str(args.delta_run), "steps": step, "schedule_steps": schedule_steps, "finished": step >= schedule_steps,
        "seeds": config["train"]["seeds"], "model": config["model"] | {"parents": None},
    }  # fmt: skip
    if args.bmm:
        model = bmm_model(args.bmm, args.data, args.no_cache)
        t0 = time.perf_counter()
        velocity = not args.bmm_no_velocity
        results["bmm"] = evaluate_bmm(bench, model, 1, args.bmm_batch, velocity)
        results["bmm_mean"] = evaluate_bmm(bench, model, args.bmm_samples, args.bmm_batch, velocity)
        results["bmm_model"] = {
            "folder": args.bmm, "ik": "exact_rig", "samples": args.bmm_samples, "steps": 10, "first_key_velocity": velocity,
            "wall_s": time.perf_counter() - t0,
        }  # fmt: skip
    else:
        results["missing"] = {"bmm": BMM_MISSING}
    ours = {k: results[k] for k in ROWS if k in results}
    results["ratio_to_interp"] = {
        **ratios(ours, results["interp"]),
        **{f"published_{k}": v for k, v in ratios(PUBLISHED, PUBLISHED["interp"]).items()},
    }
    results["versus_delta"] = ratios(ours, results["delta"])
    results["published"] = {"note": "the full LaFAN1 test set (2,232 windows), not our subset", **PUBLISHED}
    results["wall_s"] = time.perf_counter() - started
    write_results(args.out, results, report(results))
    return results


if __name__ == "__main__":
    main()
