"""Handles error after IK with the exact IK stage, bundled Bandai-Namco models (issue 15).

    python experiments/ik_exact.py --windows 100 --out results/ik_exact.json

The windows and handles of ``experiments/bmm_lafan1.py`` / ``cross_skeleton.py`` (same
draws: ``make_eval_set`` with key 1234; OOD = ±16 cm noise) on the Bandai-Namco validation
takes; the bundled BMM (:data:`bezmotion.assets.BUNDLED_BMM`) and learned IK drive the
learned IK, the learned IK + the rig's exact limbs, the analytic rig, and the exact IK
(:mod:`bezmotion.ik.exact`) on top of the learned IK and of the learned IK + exact limbs,
with the joint limits stored beside the IK model. Each row: handles error ID / OOD,
foot skating, MPJPE and ``key_pop_deg`` (largest per-frame joint rotation change at
frames 0→1 and 29→30), with the key blend (6 frames) and without it (``--no-blend`` rows
are the old behaviour); the mocap's own key pop and largest per-frame change beside them.
Each IK re-samples the curves with the same key, so the curves are the same for every IK.
"""

from __future__ import annotations

import time

import jax
import numpy as np

from bezmotion.assets import BUNDLED_BMM, BUNDLED_IK
from bezmotion.bmm.evaluation import floor_height_from, make_eval_set
from bezmotion.bmm.sampling import load_model
from bezmotion.data.corpus import motion_clips
from bezmotion.data.curves import curve_dataset
from bezmotion.data.sources import load_corpus
from bezmotion.ik.exact import exact_ik
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protores import load_ik_model, protores_ik_fn, protores_refined_ik_fn
from bezmotion.ik.rig import make_rig, rig_ik
from bezmotion.io import write_results
from bezmotion.options import option, options, parse_options
from bezmotion.pipeline.evaluation import evaluate_pipeline, ground_truth_pose_metrics, window_poses
from bezmotion.pipeline.window_figures import PipelineMetricsConfig


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it)")
    windows: int = option(100, help="validation windows (0 = all)")
    iks: tuple[str, ...] = option(
        ("learned", "refined", "rig", "exact", "exact_refined"),
        choices=("learned", "refined", "rig", "exact", "exact_refined"), help="IKs to evaluate",
    )
    blend: tuple[int, ...] = option((6, 0), help="key blend frames to evaluate (0 = the keys replace two frames alone)")
    chunk: int = option(10, help="windows per compiled call")
    rotation_weight: float | None = option(None, help="the exact IK's orientation weight (default: ExactIKParams')")
    iterations: int | None = option(None, help="the exact IK's steps per frame (default: ExactIKParams')")
    no_limits: bool = option(False, help="the exact IK without joint limits")


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    started = time.perf_counter()
    corpus = load_corpus("bandai_namco", progress=False)
    val_set = curve_dataset(corpus, "validation", progress=False)
    clips = motion_clips(corpus, "validation")
    bmm = load_model(BUNDLED_BMM)
    ik_model = load_ik_model(BUNDLED_IK)
    character = ik_model.character
    eval_set = make_eval_set(val_set, key=jax.random.key(1234), num_windows=args.windows or None)
    truth = window_poses(character, clips, val_set, eval_set.rows)
    rig = make_rig(character, "bandai_namco", rest_quat_local=np.asarray(truth.quat_local[0, 0]))
    limits = None if args.no_limits else JointLimits.load(BUNDLED_IK / "joint_limits.json", character)
    settings = {k: v for k in ("rotation_weight", "iterations") if (v := getattr(args, k)) is not None}
    iks = {
        "learned": (protores_ik_fn, ik_model),
        "refined": (protores_refined_ik_fn, (ik_model, rig)),
        "rig": (rig_ik, rig),
        "exact": exact_ik(protores_ik_fn, ik_model, character, limits=limits, **settings),
        "exact_refined": exact_ik(protores_refined_ik_fn, (ik_model, rig), character, limits=limits, **settings),
    }
    config = PipelineMetricsConfig(val_set.layout.stride, val_set.fps, floor_height_from(val_set))
    results = {
        "windows": int(truth.root_pos.shape[0]),
        "mocap": ground_truth_pose_metrics(config, character, truth),
        "exact_settings": {**settings, "limits": not args.no_limits},
        "rows": [],
    }
    print(f"mocap: {results['mocap']}", flush=True)
    for name in args.iks:
        fn, params = iks[name]
        for blend in args.blend:
            t0 = time.perf_counter()
            metrics = evaluate_pipeline(
                config, bmm, fn, params, character, truth, eval_set, key=jax.random.key(7), key_blend_frames=blend, chunk=args.chunk
            )
            row = {"ik": name, "key_blend_frames": blend, **metrics, "eval_s": time.perf_counter() - t0}
            results["rows"].append(row)
            print(f"{name} blend {blend}: {metrics} ({row['eval_s']:.0f} s)", flush=True)
    results["seconds"] = time.perf_counter() - started
    lines = [
        f"Bandai-Namco validation, {results['windows']} windows, bundled BMM + IK, 10 DDIM steps ({results['seconds']:.0f} s).",
        f"Mocap: foot skating {results['mocap']['foot_skating_ratio']:.4f}, key pop {results['mocap']['key_pop_deg']:.2f}°, "
        f"largest per-frame change {results['mocap']['max_rotation_change_deg']:.2f}°.",
        "",
        "| IK | key blend | handles ID (cm) | OOD (cm) | MPJPE ID (cm) | foot skating ID | key pop ID (°) | key pop OOD (°) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['ik']} | {r['key_blend_frames']} | {r['id']['handles_error_cm']:.4f} | {r['ood']['handles_error_cm']:.4f} | "
            f"{r['id']['mpjpe_cm']:.3f} | {r['id']['foot_skating_ratio']:.4f} | {r['id']['key_pop_deg']:.2f} | {r['ood']['key_pop_deg']:.2f} |"
        )
    write_results(args.out, results, "\n".join(lines))
    return results


if __name__ == "__main__":
    main()
