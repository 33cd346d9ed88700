"""How well the learned frame IK recovers full LaFAN1 poses: BMM Table 2 and Figure 8 analogues.

    python experiments/ik_subsets.py --out results/ik_subsets.json

Loads the learned IK trained on LaFAN1 subjects 1–4 from ``--model-dir`` (default
``~/.cache/bezmotion/runs/ik_lafan1/model``; trained there first with
``experiments/train_ik.py`` when missing) and evaluates it on subject 5:

- **Table 2 analogue**: MPJPE (cm, mean over all 22 joints and every ``--eval-step``-th
  frame) when the IK is given the true positions *and* global orientations of each
  joint subset of the paper (all joints; root, neck, hands, feet, elbows, knees; root,
  neck, hands, feet; root, hands, feet; hands, feet), beside the paper's values, plus
  the six characteristic joints our pipeline uses (hips, **head**, hands, feet), with and
  without orientations.
- **Figure 8 analogue**: every 31-frame window (``--offset`` apart) of subject 5 is
  reduced to the six characteristic joints, their positions fitted with Bézier curves
  (:func:`bezmotion.bezier.fit_curves`, control positions pinned to the data) at each
  stride dividing 30, the curves evaluated at every frame, orientations slerped between
  the control frames (:func:`bezmotion.bezier.reconstruct_dense`), the IK run on every
  frame and the MPJPE taken against the true full pose. The six-joint error of the
  curves alone (before IK, as ``experiments/bezier_stride.py``) is reported beside it.

Writes the JSON, a Markdown report (``.md``) and a plot (``.png``) beside it.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion._src.io import save_figure, write_results
from bezmotion.bezier import BezierLayout, fit_curves, reconstruct_dense
from bezmotion.data.lafan1 import TEST_SUBJECTS
from bezmotion.data.sources import default_source, load_corpus
from bezmotion.geometry.rotations import safe_norm
from bezmotion.ik.frames import corpus_frame_starts, corpus_frames
from bezmotion.ik.protocol import IKTargets, Pose, pose_fk, targets_from_pose
from bezmotion.ik.protores import ProtoResModel, load_ik_model, protores_ik_fn
from bezmotion.training import count_parameters
from bezmotion.ik.training import CHARACTERISTIC, TABLE2, body_joints, effector_configurations, effector_mpjpe
from bezmotion._src.options import option, options, parse_options
from _common import runs_dir

WINDOW = 31
STRIDES = (1, 2, 3, 5, 6, 10, 15, 30)


@options
class Options:
    out: str = option(help="output JSON (.md and .png written beside it)")
    data: str | None = option(None, help="LaFAN1 zip or folder (default ../shared/data/lafan1/lafan1-subset.zip)")
    model_dir: str | None = option(None, help="saved learned IK (default ~/.cache/bezmotion/runs/ik_lafan1/model)")
    train_steps: int = option(8000, help="steps to train with when no model is found")
    eval_step: int = option(1, help="Table 2 on every n-th subject-5 frame (default 1: all)")
    offset: int = option(10, help="frames between Figure 8 window starts (default 10)")
    strides: str = option(",".join(map(str, STRIDES)), help="Figure 8 strides (default 1,2,3,5,6,10,15,30)")


def table2(model: ProtoResModel, poses: Pose) -> dict:
    """MPJPE (cm) for each Table 2 configuration and the six characteristic joints."""
    configs = effector_configurations(model.character)
    rows = {}
    for name, (_, paper) in TABLE2.items():
        rows[name] = {"mpjpe_cm": float(np.mean(effector_mpjpe(model, poses, configs[name]))), "paper_cm": paper, "joints": len(configs[name])}
    six = configs[CHARACTERISTIC]
    rows[CHARACTERISTIC] = {"mpjpe_cm": float(np.mean(effector_mpjpe(model, poses, six))), "paper_cm": None, "joints": 6}
    rows[CHARACTERISTIC + ", positions only"] = {
        "mpjpe_cm": float(np.mean(effector_mpjpe(model, poses, six, rotations=False))), "paper_cm": None, "joints": 6,
    }  # fmt: skip
    return rows


def windows_of(poses: Pose, starts: np.ndarray, window: int, offset: int) -> np.ndarray:
    """``(windows, window)`` frame indices of every window inside one file, ``offset`` apart."""
    rows = [
        s + np.arange(0, e - s - window + 1, offset)[:, None] + np.arange(window)
        for s, e in zip(starts[:-1], starts[1:])
        if e - s >= window
    ]
    return np.concatenate(rows) if rows else np.zeros((0, window), np.int64)


def _stride_errors(model: ProtoResModel, truth: Pose, layout: BezierLayout):
    """Per-window ``(MPJPE after IK, six-joint curve error)`` of windows ``truth (w, frames, …)``."""
    character = model.character
    targets = targets_from_pose(character, truth)  # (w, frames, 6, ·)
    fit = fit_curves(layout, jnp.moveaxis(targets.position, -2, -3))  # per joint: (w, 6, frames, 3)
    ctrl = layout.control_frames
    ctrl_pos, ctrl_tangent = jnp.moveaxis(fit.ctrl_pos, -3, -2), jnp.moveaxis(fit.ctrl_tangent, -3, -2)
    pos, rot6d = reconstruct_dense(layout, ctrl_pos, ctrl_tangent, targets.rot6d[:, ctrl])
    pose = jax.vmap(jax.vmap(protores_ik_fn, in_axes=(None, 0)), in_axes=(None, 0))(model, IKTargets(pos, rot6d))
    _, pos_pred = pose_fk(character, pose)
    _, pos_true = pose_fk(character, truth)
    body = np.asarray(body_joints(character))
    mpjpe = jnp.mean(safe_norm(pos_pred[..., body, :] - pos_true[..., body, :]), axis=(-2, -1))
    curve = jnp.mean(safe_norm(pos - targets.position), axis=(-2, -1))
    return mpjpe, curve, fit.succeeded.all(axis=-1)


_stride_errors_jit = jax.jit(_stride_errors, static_argnames=("layout",))


def figure8(model: ProtoResModel, poses: Pose, frames: np.ndarray, strides: tuple[int, ...], chunk: int = 256) -> dict:
    """MPJPE after IK and the curves' own six-joint error for each stride (means over windows)."""
    out: dict = {"mpjpe_cm": {}, "curve_error_cm": {}}
    n = len(frames)
    for stride in strides:
        layout = BezierLayout(frames.shape[1], stride)
        mpjpe, curve = [], []
        for lo in range(0, n, chunk):
            idx = frames[lo : lo + chunk]
            pad = chunk - len(idx)
            idx = np.concatenate([idx, np.repeat(idx[:1], pad, axis=0)]) if pad else idx
            truth = jax.tree.map(lambda a: a[idx], poses)
            m, c, ok = _stride_errors_jit(model, truth, layout)
            if not bool(np.asarray(ok).all()):
                raise RuntimeError(f"stride {stride}: a curve fit did not converge")
            mpjpe.append(np.asarray(m)[: chunk - pad])
            curve.append(np.asarray(c)[: chunk - pad])
        out["mpjpe_cm"][str(stride)] = float(np.concatenate(mpjpe).mean())
        out["curve_error_cm"][str(stride)] = float(np.concatenate(curve).mean())
        print(f"  stride {stride}: MPJPE {out['mpjpe_cm'][str(stride)]:.3f} cm, curves {out['curve_error_cm'][str(stride)]:.3f} cm", flush=True)
    return out


def format_report(results: dict) -> str:
    m = results["model"]
    lines = [
        f"Learned frame IK on LaFAN1 subject 5 ({m['params']:,} parameters, {m['output_rotations']} rotations, "
        f"trained {m['steps']} steps on subjects 1–4; `{m['dir']}`).",
        "",
        f"Table 2 analogue: MPJPE over all 22 joints, {results['table2_frames']} frames, true positions and orientations of the constraint joints.",
        "",
        "| joints used as constraints | ours (cm) | paper (cm) |",
        "|---|---|---|",
    ]
    for name, row in results["table2"].items():
        paper = "–" if row["paper_cm"] is None else f"{row['paper_cm']:.4f}"
        lines.append(f"| {name} | {row['mpjpe_cm']:.4f} | {paper} |")
    f8 = results["figure8"]
    lines += [
        "",
        f"Figure 8 analogue: {f8['n_windows']} windows of {WINDOW} frames (offset {f8['offset']}), six characteristic joints "
        "fitted with Bézier curves (pinned), orientations slerped, IK on every frame.",
        "",
        "| stride | controls | MPJPE after IK (cm) | six-joint curve error (cm) |",
        "|---|---|---|---|",
    ]
    for s in f8["strides"]:
        lines.append(
            f"| {s} | {BezierLayout(WINDOW, s).num_controls} | {f8['mpjpe_cm'][str(s)]:.4f} | {f8['curve_error_cm'][str(s)]:.4f} |"
        )
    return "\n".join(lines)


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f8 = results["figure8"]
    strides = f8["strides"]
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    ax.plot(strides, [f8["mpjpe_cm"][str(s)] for s in strides], "o-", label="MPJPE after IK (all joints)")
    ax.plot(strides, [f8["curve_error_cm"][str(s)] for s in strides], "s--", label="curves alone (six joints)")
    ax.axhline(results["table2"][CHARACTERISTIC]["mpjpe_cm"], color="grey", lw=0.8, ls=":", label="IK on exact six joints")
    ax.set_xlabel("stride between control points (frames)")
    ax.set_ylabel("position error (cm)")
    ax.set_title(f"Learned IK after Bézier curves, LaFAN1 subject 5 ({f8['n_windows']} windows)")
    ax.set_xticks(strides)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    strides = tuple(int(s) for s in args.strides.split(","))
    if any(not 1 <= s <= WINDOW - 1 for s in strides):
        raise SystemExit(f"--strides must lie in 1…{WINDOW - 1}, got {strides}")
    started = time.perf_counter()
    data = args.data or str(default_source("lafan1"))
    model_dir = Path(args.model_dir).expanduser() if args.model_dir else runs_dir("ik_lafan1", "model")
    if not (model_dir / "config.json").exists():
        print(f"no learned IK at {model_dir}: training one ({args.train_steps} steps)")
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import train_ik

        train_ik.main(["--corpus", "lafan1", "--data", data, "--out-dir", str(model_dir.parent), "--steps", str(args.train_steps), "--no-progress"])
    model = load_ik_model(model_dir)
    if model.character.name != "lafan1":
        raise SystemExit(f"{model_dir} holds a learned IK for {model.character.name!r}, not LaFAN1")
    training = json.loads((model_dir.parent / "training.json").read_text()) if (model_dir.parent / "training.json").exists() else {}

    corpus = load_corpus("lafan1", source=data)
    _, table_poses = corpus_frames(corpus, "validation", frame_step=args.eval_step)
    print(f"Table 2 analogue on {table_poses.root_pos.shape[0]} subject-5 frames")
    rows = table2(model, table_poses)
    for name, row in rows.items():
        print(f"  {name}: {row['mpjpe_cm']:.4f} cm (paper {row['paper_cm']})")

    _, poses = corpus_frames(corpus, "validation")
    frames = windows_of(poses, corpus_frame_starts(corpus, "validation"), WINDOW, args.offset)
    print(f"Figure 8 analogue on {len(frames)} windows")
    f8 = figure8(model, poses, frames, strides)
    results = {
        "table2": rows,
        "table2_frames": int(table_poses.root_pos.shape[0]),
        "figure8": {**f8, "strides": list(strides), "n_windows": int(len(frames)), "offset": args.offset, "window": WINDOW},
        "subjects": list(TEST_SUBJECTS),
        "metric": "MPJPE: mean over joints (all 22) and frames of the Euclidean joint position error (cm)",
        "model": {
            "dir": str(model_dir),
            "params": count_parameters(model.params),
            "config": {k: getattr(model.config, k) for k in model.config.__dataclass_fields__},
            "output_rotations": model.config.output_rotations,
            "steps": training.get("steps"),
        },
        "eval_s": time.perf_counter() - started,
    }
    out = Path(args.out)
    write_results(out, results, format_report(results))
    plot(results, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.png')}; {time.perf_counter() - started:.1f} s in all")
    return results


if __name__ == "__main__":
    main()
