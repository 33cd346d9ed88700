"""Our motion feature extractor: train it, then check that FID and diversity on
its embeddings say what they should.

    python experiments/motion_features.py --out results/motion_features.json
    python experiments/motion_features.py --corpora lafan1 --steps 1500 --out results/motion_features_lafan1.json

Trains the autoencoder of :mod:`bezmotion.evaluation.motion_features` on every training
window (31 frames, offset 5) of the ``--corpora`` curve datasets (LaFAN1 subjects 1–4,
Bandai-Namco's training takes), each in the canonical frame with its skeleton's standing
hip height (``bezmotion/assets/profiles``). Checkpoints go to ``<out-dir>/checkpoints``
every ``--checkpoint-every`` steps; the same command resumes; the extractor is saved to
``<out-dir>/model`` (:func:`~bezmotion.evaluation.motion_features.load_motion_features`).
Default ``--out-dir``: ``~/.cache/bezmotion/runs/motion_features_<corpora>``.

Then, per corpus, with ``--eval-windows`` validation windows (a prefix of one
permutation, :func:`~bezmotion.evaluation.curves.make_eval_set` ``per_window``, so the
handles are the BMM evaluation's) and the training windows as the ground truth (a
random subset of the same size), FID against the training windows of:

- ``train_floor``: another disjoint subset of training windows (the finite-sample floor);
- ``mocap``: the validation mocap (should be near the floor);
- ``noise_<σ>cm``: the validation mocap plus i.i.d. Gaussian noise of σ cm on every
  coordinate of every frame (should rise with σ);
- ``fitted_curves``: the Bézier curves fitted to the validation mocap, evaluated densely
  (what the representation itself costs);
- ``reference`` / ``reference_ood``: the non-learned interpolation reference
  (:func:`~bezmotion.evaluation.curves.reference_curves`) through the start, end and the
  in-distribution / ±16 cm handles (should be far worse than the mocap);

and the diversity (``--diversity-pairs`` pairs) of each set, plus the extractor's
reconstruction error on the validation mocap (cm). Multimodality needs several samples
per condition, i.e. a generative model: it is not measured here (mocap and the reference
have one motion per condition; the reference's multimodality is 0 by construction).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.assets import PROFILES_DIR
from bezmotion.evaluation.curves import dense_positions, make_eval_set, reference_curves
from bezmotion.data.curves import CurveDataset, curve_dataset
from bezmotion.data.sources import CORPORA, load_corpus
from bezmotion.evaluation.motion_features import (
    MotionFeatureConfig,
    MotionFeatureExtractor,
    MotionFeatureTrainConfig,
    WindowStats,
    canonical_windows,
    init_motion_feature_train_state,
    make_motion_feature_train_step,
    motion_features,
    reconstruct_canonical,
    save_motion_features,
)
from bezmotion.evaluation.naturalness import diversity, frechet_distance, gaussian_fit
from bezmotion._src.io import atomic_write_text, write_results
from bezmotion._src.options import option, options, parse_options, presets
from bezmotion.pipeline.transfer import CharacterProfile
from bezmotion.training import CheckpointStore, compile_train_step, count_parameters, run_training
from _common import runs_dir

CONFIGS = presets(MotionFeatureConfig)


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it)")
    corpora: tuple[str, ...] = option(("lafan1", "bandai_namco"), help="corpora to train on and evaluate (lafan1, bandai_namco)")
    out_dir: str | None = option(None, help="run folder (default ~/.cache/bezmotion/runs/motion_features_<corpora>)")
    steps: int = option(3000, help="training steps")
    config: str = option("cpu", choices=CONFIGS, help="autoencoder size")
    embed_dim: int | None = option(None, help="override the preset's embedding size")
    batch_size: int = MotionFeatureTrainConfig.batch_size
    learning_rate: float = MotionFeatureTrainConfig.learning_rate
    velocity_weight: float = MotionFeatureTrainConfig.velocity_weight
    seed: int = option(0, help="parameters, batches and every evaluation draw")
    checkpoint_every: int = 500
    eval_windows: int = option(3000, help="windows per evaluated set (the paper: 3k on LaFAN1)")
    noise_cm: tuple[float, ...] = option((1.0, 2.0, 5.0, 10.0), help="std of the Gaussian noise added to the mocap (cm)")
    diversity_pairs: int = option(1000, help="S_d: pairs for the diversity (capped at half the windows)")
    no_progress: bool = False

    def __post_init__(self):
        unknown = [c for c in self.corpora if c not in CORPORA or c == "anidance"]
        if unknown:
            raise ValueError(f"--corpora takes lafan1 and bandai_namco, got {unknown}")
        if self.eval_windows < 4:
            raise ValueError(f"--eval-windows must be at least 4, got {self.eval_windows}")


def hip_height(corpus: str) -> float:
    """The corpus skeleton's standing hip height (cm), from its character profile."""
    return CharacterProfile.load(PROFILES_DIR / f"{corpus}.json").height


def train(args: Options, train_sets: dict[str, CurveDataset], out_dir: Path) -> tuple[MotionFeatureExtractor, dict]:
    """Train (or resume) the extractor on the training windows of every corpus and save it."""
    canonical = np.concatenate(
        [np.asarray(canonical_windows(jnp.asarray(d.dense_pos), hip_height(name))) for name, d in train_sets.items()]
    )
    stats = WindowStats.from_windows(canonical)
    overrides = {} if args.embed_dim is None else {"embed_dim": args.embed_dim}
    model_config = CONFIGS[args.config](**overrides)
    train_config = MotionFeatureTrainConfig(
        num_steps=args.steps, batch_size=args.batch_size, learning_rate=args.learning_rate, velocity_weight=args.velocity_weight
    )
    config = {
        "corpora": list(train_sets), "seed": args.seed, "windows": int(len(canonical)),
        "hip_height_cm": {name: hip_height(name) for name in train_sets},
        "model": dataclasses.asdict(model_config), "train": dataclasses.asdict(train_config),
    }  # fmt: skip
    store = CheckpointStore(out_dir / "checkpoints")
    store.check_resumable(config)
    if store.latest_step() is not None:
        print(f"resuming from step {store.latest_step()} in {out_dir}")
    graphdef, state = init_motion_feature_train_state(model_config, train_config, key=jax.random.key(args.seed))
    step = compile_train_step(make_motion_feature_train_step(graphdef, stats, train_config), num_seeds=None)
    state = jax.device_put(state, jax.devices()[0])  # committed like a restored state: one compilation
    data = jax.device_put(jnp.asarray(canonical), jax.devices()[0])
    started = time.perf_counter()

    def report(done: int, last: dict) -> None:
        if done % args.checkpoint_every == 0 or done == args.steps:
            print(f"step {done}: loss {last['loss']:.4f} (pos {last['pos']:.4f}, vel {last['vel']:.4f}), "
                  f"{last['steps_per_s']:.1f} steps/s, {time.perf_counter() - started:.0f} s", flush=True)  # fmt: skip

    state, history = run_training(
        step, state, data, num_steps=args.steps, store=store, checkpoint_every=args.checkpoint_every, config=config,
        progress=not args.no_progress, log_every=min(100, args.checkpoint_every), progress_fn=report,
    )  # fmt: skip
    store.close()
    # The loss curve over every session of this run (a resumed run appends to it).
    history_file = out_dir / "history.json"
    earlier = json.loads(history_file.read_text()) if history_file.exists() else []
    history = [r for r in earlier if r["step"] < (history[0]["step"] if history else args.steps + 1)] + history
    atomic_write_text(history_file, json.dumps(history, indent=1) + "\n")
    extractor = MotionFeatureExtractor(state.params, stats, graphdef, model_config)
    save_motion_features(out_dir / "model", extractor, **{k: v for k, v in config.items() if k != "model"})
    summary = {
        **config, "params": count_parameters(state.params), "train_s_this_session": time.perf_counter() - started,
        "history": history, "model_dir": str(out_dir / "model"),
    }  # fmt: skip
    return extractor, summary


def reconstruction_error_cm(extractor: MotionFeatureExtractor, pos_cm: np.ndarray, height: float) -> float:
    """Mean joint distance (cm) between canonical windows and their autoencoded copies."""
    canonical = canonical_windows(jnp.asarray(pos_cm), height)
    recon = reconstruct_canonical(extractor, canonical)
    return float(jnp.mean(jnp.linalg.norm(recon - canonical, axis=-1)) * height)


def evaluate(
    args: Options, extractor: MotionFeatureExtractor, name: str, train_set: CurveDataset, validation: CurveDataset
) -> dict:
    """FID against the training windows, diversity and reconstruction error of one corpus's sets."""
    height = hip_height(name)
    key = jax.random.key(args.seed)
    n = min(args.eval_windows, len(validation), len(train_set) // 2)
    eval_set = make_eval_set(validation, key=jax.random.fold_in(key, 0), num_windows=n, per_window=True)
    mocap = np.asarray(eval_set.dense_pos)
    order = np.asarray(jax.random.permutation(jax.random.fold_in(key, 1), len(train_set)))
    ground_truth, other = train_set.dense_pos[order[:n]], train_set.dense_pos[order[n : 2 * n]]
    layout = validation.layout

    sets: dict[str, np.ndarray] = {"train_floor": other, "mocap": mocap}
    noise_key = jax.random.fold_in(key, 2)
    for sigma in args.noise_cm:
        noise = sigma * np.asarray(jax.random.normal(jax.random.fold_in(noise_key, int(round(sigma * 1000))), mocap.shape))
        sets[f"noise_{sigma:g}cm"] = (mocap + noise).astype(np.float32)
    sets["fitted_curves"] = np.asarray(dense_positions(layout, eval_set.ctrl_pos, eval_set.ctrl_tangent))
    for label, handles in (("reference", eval_set.handles), ("reference_ood", eval_set.handles_ood)):
        curves = reference_curves(eval_set, handles, layout)
        sets[label] = np.asarray(dense_positions(layout, curves.ctrl_pos, curves.ctrl_tangent))

    truth_features = motion_features(extractor, ground_truth, height)
    truth = gaussian_fit(truth_features, name="training windows")
    pairs = min(args.diversity_pairs, n // 2)
    out: dict = {"windows": int(n), "diversity_pairs": int(pairs), "hip_height_cm": height, "fid": {}, "diversity": {}}
    out["diversity"]["train"] = diversity(truth_features, pairs, key=jax.random.fold_in(key, 3))
    for label, pos in sets.items():
        features = motion_features(extractor, pos, height)
        out["fid"][label] = frechet_distance(truth, gaussian_fit(features, name=label))
        out["diversity"][label] = diversity(features, pairs, key=jax.random.fold_in(key, 3))
    out["reconstruction_error_cm"] = {
        "validation": reconstruction_error_cm(extractor, mocap, height),
        "train": reconstruction_error_cm(extractor, ground_truth, height),
    }
    noise_fids = [out["fid"][f"noise_{s:g}cm"] for s in sorted(args.noise_cm)]
    out["checks"] = {
        "noise_fid_rises_monotonically": bool(np.all(np.diff([out["fid"]["mocap"], *noise_fids]) > 0)),
        "reference_fid_over_mocap_fid": out["fid"]["reference"] / max(out["fid"]["mocap"], 1e-12),
    }
    return out


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    out_dir = Path(args.out_dir).expanduser() if args.out_dir else runs_dir("motion_features_" + "_".join(args.corpora))
    started = time.perf_counter()
    train_sets, validation_sets = {}, {}
    for name in args.corpora:
        corpus = load_corpus(name, progress=not args.no_progress)
        train_sets[name] = curve_dataset(corpus, "train", progress=not args.no_progress)
        validation_sets[name] = curve_dataset(corpus, "validation", progress=not args.no_progress)
        print(f"{name}: {len(train_sets[name])} training, {len(validation_sets[name])} validation windows", flush=True)
    extractor, training = train(args, train_sets, out_dir)
    results: dict = {"training": training, "corpora": {}}
    for name in args.corpora:
        results["corpora"][name] = evaluate(args, extractor, name, train_sets[name], validation_sets[name])
        print(f"{name}: {results['corpora'][name]}", flush=True)
    results["seconds"] = time.perf_counter() - started

    final = f"final loss {training['history'][-1]['loss']:.4f}" if training["history"] else "no loss recorded"
    lines = [
        f"Motion feature extractor ({args.config}, {extractor.config.embed_dim}-d, {training['params']} parameters), "
        f"trained {args.steps} steps on {training['windows']} windows of {', '.join(args.corpora)}; "
        f"{final} ({results['seconds']:.0f} s).",
        "",
    ]
    for name, r in results["corpora"].items():
        lines += [
            f"**{name}** — {r['windows']} windows per set, FID against as many training windows, "
            f"diversity over {r['diversity_pairs']} pairs (training windows: {r['diversity']['train']:.3f}); "
            f"reconstruction error {r['reconstruction_error_cm']['validation']:.2f} cm "
            f"(training windows: {r['reconstruction_error_cm']['train']:.2f} cm).",
            "",
            "| set | FID ↓ | diversity → |",
            "|---|---|---|",
            *(f"| {label} | {r['fid'][label]:.4f} | {r['diversity'][label]:.3f} |" for label in r["fid"]),
            "",
            f"Noise FID rises monotonically: {r['checks']['noise_fid_rises_monotonically']}; "
            f"reference FID / mocap FID: {r['checks']['reference_fid_over_mocap_fid']:.1f}.",
            "",
        ]
    write_results(args.out, results, "\n".join(lines))
    return results


if __name__ == "__main__":
    main()
