"""The full pipeline after IK, on each skeleton and across skeletons (BMM Table 1 after IK, §6.4).

    python experiments/cross_skeleton.py --out results/cross_skeleton.json

For each target skeleton (LaFAN1 subject 5, Bandai-Namco validation takes) the start and
end poses and 1–4 intermediate handles of each window come from the mocap (the windows
and handles of ``experiments/bmm_lafan1.py``: same draws, OOD = ±16 cm noise). Curves
from a BMM trained on the *same* skeleton, and from the BMM trained on the *other*
skeleton moved over by :class:`bezmotion.pipeline.inbetweening.Transfer` (hip-height ratio, fixed
orientation offsets), drive the target skeleton through its own learned IK
(``experiments/train_ik.py``), the same followed by the rig's exact two-bone arms and legs
(ours, :func:`bezmotion.ik.protores.protores_refined_ik_fn`), and the analytic rig alone
(:mod:`bezmotion.ik.rig`).
Reported after IK, on the full skeleton: handles error in distribution and OOD, foot
skating, MPJPE against the mocap window. The same-skeleton LaFAN1 row with the learned
IK is the analogue of the paper's Table 1 BMM row (0.8914 / 1.7090 cm, skating 0.2176).
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

from bezmotion.io import write_results
from bezmotion.assets import PROFILES_DIR
from bezmotion.bmm.evaluation import floor_height_from, make_eval_set
from bezmotion.data.corpus import motion_clips
from bezmotion.data.curves import curve_dataset
from bezmotion.data.sources import load_corpus
from bezmotion.ik.protores import load_ik_model, protores_ik_fn, protores_refined_ik_fn
from bezmotion.ik.rig import make_rig, rig_ik
from bezmotion.pipeline import CharacterProfile, Transfer
from bezmotion.pipeline.evaluation import evaluate_pipeline, ground_truth_pose_metrics, window_poses
from bezmotion.pipeline.window_figures import PipelineMetricsConfig
from bezmotion.bmm.sampling import load_model
from bezmotion.options import option, options, parse_options
from _common import runs_dir

CORPORA = ("lafan1", "bandai_namco")
PAPER_LAFAN1 = {"handles_error_cm": 0.8914, "ood_handles_error_cm": 1.7090, "foot_skating_ratio": 0.2176, "gt_foot_skating_ratio": 0.1209}


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it)")
    targets: tuple[str, ...] = option(CORPORA, choices=CORPORA, help="target skeletons (default: all)")
    windows: int = option(500, help="validation windows per skeleton (0 = all)")
    bmm_dir: str | None = option(None, help="BMM per corpus ({corpus} is filled in; default <cache>/runs/bmm_{corpus}_cpu_residual/model)")
    ik_dir: str | None = option(None, help="learned IK per corpus ({corpus} is filled in; default <cache>/runs/ik_{corpus}/model)")

    def __post_init__(self):
        if self.bmm_dir is None:
            object.__setattr__(self, "bmm_dir", str(runs_dir("bmm_{corpus}_cpu_residual", "model")))
        if self.ik_dir is None:
            object.__setattr__(self, "ik_dir", str(runs_dir("ik_{corpus}", "model")))


def evaluate_target(args, target: str, bmms: dict, profiles: dict) -> dict:
    corpus = load_corpus(target, progress=False)
    val_set = curve_dataset(corpus, "validation", progress=False)
    clips = motion_clips(corpus, "validation")
    ik_model = load_ik_model(Path(args.ik_dir.format(corpus=target)))
    character = ik_model.character
    eval_set = make_eval_set(val_set, key=jax.random.key(1234), num_windows=args.windows or None)
    truth = window_poses(character, clips, val_set, eval_set.rows)
    # The joints the rig does not solve (clavicles, toes) keep one real pose's rotations.
    rig = make_rig(character, target, rest_quat_local=np.asarray(truth.quat_local[0, 0]))
    iks = {
        "learned IK": (protores_ik_fn, ik_model),
        "learned IK + exact limbs (ours)": (protores_refined_ik_fn, (ik_model, rig)),
        "analytic rig": (rig_ik, rig),
    }
    config = PipelineMetricsConfig(val_set.layout.stride, val_set.fps, floor_height_from(val_set))
    out = {
        "windows": int(truth.root_pos.shape[0]),
        "floor_height_cm": config.floor_height,
        "mocap": {name: ground_truth_pose_metrics(config, character, truth, fn, params) for name, (fn, params) in iks.items()},
        "rows": [],
    }
    for source_corpus, bmm in bmms.items():
        transfer = None if source_corpus == target else Transfer.between(profiles[source_corpus], profiles[target])
        for ik_name, (fn, params) in iks.items():
            t0 = time.perf_counter()
            metrics = evaluate_pipeline(config, bmm, fn, params, character, truth, eval_set, key=jax.random.key(7), transfer=transfer)
            out["rows"].append({"bmm": source_corpus, "ik": ik_name, **metrics, "eval_s": time.perf_counter() - t0})
            print(f"  {target}: BMM({source_corpus}) + {ik_name}: {metrics}", flush=True)
    return out


def format_report(results: dict) -> str:
    lines = [
        f"Pipeline after IK (10 DDIM steps, BMM curves → dense trajectories → IK), {results['seconds']:.0f} s.",
        "",
        "| target skeleton | BMM trained on | IK | handles error ID (cm) | OOD (cm) | foot skating ID | MPJPE ID (cm) |",
        "|---|---|---|---|---|---|---|",
    ]
    for target, r in results["targets"].items():
        for ik_name, m in r["mocap"].items():
            lines.append(
                f"| {target} ({r['windows']} windows) | mocap, {ik_name} of the true six joints | {ik_name} | – | – | "
                f"{m['ik_of_mocap_foot_skating_ratio']:.4f} (mocap {m['foot_skating_ratio']:.4f}) | {m['ik_of_mocap_mpjpe_cm']:.3f} |"
            )
        for row in r["rows"]:
            lines.append(
                f"| {target} | {row['bmm']}{'' if row['bmm'] == target else ' (transferred)'} | {row['ik']} | "
                f"{row['id']['handles_error_cm']:.4f} | {row['ood']['handles_error_cm']:.4f} | {row['id']['foot_skating_ratio']:.4f} | "
                f"{row['id']['mpjpe_cm']:.3f} |"
            )
    p = PAPER_LAFAN1
    lines += ["", f"Paper (full LaFAN1, ProtoRes): handles error {p['handles_error_cm']} / OOD {p['ood_handles_error_cm']} cm, "
              f"foot skating {p['foot_skating_ratio']} (mocap {p['gt_foot_skating_ratio']})."]  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    started = time.perf_counter()
    bmms = {corpus: load_model(Path(args.bmm_dir.format(corpus=corpus))) for corpus in CORPORA}
    profiles = {corpus: CharacterProfile.load(PROFILES_DIR / f"{corpus}.json") for corpus in CORPORA}
    results = {
        "bmm_dirs": {c: args.bmm_dir.format(corpus=c) for c in CORPORA},
        "ik_dirs": {c: args.ik_dir.format(corpus=c) for c in CORPORA},
        "transfer": {f"{a}->{b}": float(profiles[b].height / profiles[a].height) for a in CORPORA for b in CORPORA if a != b},
        "targets": {target: evaluate_target(args, target, bmms, profiles) for target in args.targets},
        "paper_lafan1": PAPER_LAFAN1,
    }
    results["seconds"] = time.perf_counter() - started
    report = format_report(results)
    write_results(args.out, results, report)
    return results


if __name__ == "__main__":
    main()
