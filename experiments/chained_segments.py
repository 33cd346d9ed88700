"""Chained segments: the velocity jump at shared keys, coupled vs independent windows.

    python experiments/chained_segments.py --chains 50 --out results/chained_segments.json

Chains of ``--keys`` key poses 30 frames apart are cut from the Bandai-Namco validation
takes (``(keys − 1)·30 + 1`` consecutive mocap frames, one chain per ``--offset`` frames of
a take, ``--chains`` of them drawn with ``--seed``); each window between two keys gets
``--handles`` handles on random (frame 1 … 29, joint) slots, placed where the mocap is.
The bundled BMM samples every chain's windows with
:func:`~bezmotion.bmm.sampling.sample_chained_curves`, coupled (one tangent, orientation and
contact at each shared key) and independent (BMM Appendix D.1) from the same noise, with
the keys' orientations as conditions (``--key-positions-only``: the paper's positions only).

Reported, for the six characteristic joints' dense curves (cm/frame;
:func:`~bezmotion.evaluation.metrics.boundary_velocity_jump`, ``‖(p[b+1] − p[b]) − (p[b] − p[b−1])‖``):
the jump at the shared keys for both variants; the same quantity at the curves' other
frames; and the mocap's own frame-to-frame velocity change over the same chains' frames
(all of them, and at the key frames alone). Mean, 95th percentile and max; per joint means.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.assets import BUNDLED_BMM
from bezmotion.bezier import BezierLayout, evaluate, reconstruct_dense
from bezmotion.bmm.features import draw_intermediate_frames
from bezmotion.bmm.sampling import Handles, load_model, sample_chained_curves
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.data.corpus import motion_clips
from bezmotion.data.curves import characteristic_windows
from bezmotion.data.sources import load_corpus
from bezmotion._src.io import write_results
from bezmotion.evaluation.metrics import chain_velocity_jumps, distribution_summary
from bezmotion._src.options import option, options, parse_options
from bezmotion.data.windows import join_windows


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it)")
    chains: int = option(50, help="chains to sample (drawn from all chains of the validation takes)")
    keys: int = option(4, help="key poses per chain (windows = keys − 1)")
    handles: int = option(2, help="handles per window, on random (frame 1…29, joint) slots, at the mocap's positions")
    offset: int = option(30, help="frames between the starts of consecutive candidate chains in a take")
    steps: int = option(10, help="DDIM steps")
    chunk: int = option(25, help="chains per compiled call")
    seed: int = option(0, help="draws of chains, handles and noise")
    key_positions_only: bool = option(False, help="condition on the keys' positions only (the paper), not their orientations")


def per_joint(x: np.ndarray) -> dict[str, float]:
    """Mean over everything but the last (joint) axis, by joint name."""
    means = np.asarray(x, np.float64).reshape(-1, x.shape[-1]).mean(axis=0)
    return {name: float(m) for name, m in zip(CHARACTERISTIC_JOINTS, means)}


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    if args.keys < 3:
        raise ValueError(f"--keys must be ≥ 3 (a chain with a shared key), got {args.keys}")
    started = time.perf_counter()
    bmm = load_model(BUNDLED_BMM)
    cfg = bmm.config
    layout = BezierLayout.from_controls(cfg.num_controls, cfg.stride)
    gap = cfg.num_frames - 1  # 30 frames between keys
    span = (args.keys - 1) * gap + 1
    corpus = load_corpus("bandai_namco", progress=False)
    clips = motion_clips(corpus, "validation")
    mocap, rot6d, clip_index, _ = characteristic_windows(clips, "bandai_namco", window=span, offset=args.offset)
    rng = np.random.default_rng(args.seed)
    rows = np.sort(rng.choice(len(mocap), size=min(args.chains, len(mocap)), replace=False))
    mocap, rot6d = mocap[rows], rot6d[rows]  # (chains, span, 6, ·), cm; hips start at the XZ origin
    n, windows = len(rows), args.keys - 1
    key_frames = np.arange(0, span, gap)
    key_pos, key_rot6d = mocap[:, key_frames], rot6d[:, key_frames]

    # Handles: per window, distinct random (frame, joint) slots, positions from the mocap.
    draw = jax.vmap(lambda k: draw_intermediate_frames(k, layout, cfg.num_joints, args.handles, args.handles, frames="any"))
    drawn = draw(jax.random.split(jax.random.key(args.seed), n * windows))
    frame, joint, valid = (np.asarray(a).reshape(n, windows, args.handles) for a in drawn)
    chain_frame = frame + gap * np.arange(windows)[None, :, None]
    position = mocap[np.arange(n)[:, None, None], chain_frame, joint]
    handles = Handles(jnp.asarray(joint), jnp.asarray(frame), jnp.asarray(position), jnp.asarray(valid))

    def sample(coupled: bool) -> tuple[np.ndarray, np.ndarray]:
        """Dense curves ``(chains, span, 6, 3)`` of every chain, ``args.chunk`` chains per call,
        and the distance of each handle from its curve (cm)."""
        out, errors = [], []
        for lo in range(0, n, args.chunk):
            part = slice(lo, min(lo + args.chunk, n))
            pad = args.chunk - (part.stop - part.start)  # same shape every call: one compilation
            take = lambda a: jnp.concatenate([a[part], jnp.repeat(a[part][:1], pad, axis=0)])  # noqa: E731
            curves = sample_chained_curves(
                bmm, take(jnp.asarray(key_pos)), jax.tree.map(take, handles),
                key=jax.random.fold_in(jax.random.key(args.seed + 1), lo), steps=args.steps, coupled=coupled,
                key_rot6d=None if args.key_positions_only else take(jnp.asarray(key_rot6d)),
            )  # fmt: skip
            pos, _ = reconstruct_dense(layout, curves.ctrl_pos, curves.ctrl_tangent, curves.ctrl_rot6d)  # (chunk, windows, 31, 6, 3)
            dense = jax.vmap(join_windows)(pos)
            # Handles are conditions: check they are met (cm).
            at = evaluate(layout, jnp.moveaxis(curves.ctrl_pos, -2, -3), jnp.moveaxis(curves.ctrl_tangent, -2, -3))
            chain_ids, window_ids = np.arange(args.chunk)[:, None, None], np.arange(windows)[None, :, None]
            got = np.asarray(at)[chain_ids, window_ids, np.asarray(take(handles.joint)), np.asarray(take(handles.frame))]
            errors.append(np.linalg.norm(got - np.asarray(take(handles.position)), axis=-1)[: part.stop - part.start])
            out.append(np.asarray(dense)[: part.stop - part.start])
        return np.concatenate(out), np.concatenate(errors)

    results: dict = {
        "chains": int(n), "keys": args.keys, "handles_per_window": args.handles, "steps": args.steps,
        "key_orientations": not args.key_positions_only, "fps": float(clips.fps), "units": "cm/frame",
        "candidate_chains": int(len(clip_index)), "takes": int(len(np.unique(clip_index[rows]))),
    }  # fmt: skip
    for name, coupled in (("coupled", True), ("independent", False)):
        t0 = time.perf_counter()
        dense, errors = sample(coupled)
        jumps = chain_velocity_jumps(jnp.asarray(dense), windows)
        at_keys = np.asarray(jumps.at_shared_keys)  # (chains, keys − 2, 6)
        results[name] = {
            "at_shared_keys": distribution_summary(at_keys), "at_shared_keys_per_joint_mean": per_joint(at_keys),
            "other_frames": distribution_summary(jumps.other_frames), "handles_error_max_cm": float(errors.max()),
            "seconds": time.perf_counter() - t0,
        }  # fmt: skip
        print(f"{name}: {results[name]}", flush=True)
    mocap_jumps = chain_velocity_jumps(jnp.asarray(mocap), windows)
    all_frames = np.asarray(mocap_jumps.all_frames)
    results["mocap"] = {
        "all_frames": distribution_summary(all_frames), "all_frames_per_joint_mean": per_joint(all_frames),
        "at_shared_keys": distribution_summary(mocap_jumps.at_shared_keys),
    }  # fmt: skip
    results["seconds"] = time.perf_counter() - started

    row = lambda label, s: f"| {label} | {s['mean']:.3f} | {s['p95']:.3f} | {s['max']:.3f} | {s['count']} |"  # noqa: E731
    c, i, m = results["coupled"], results["independent"], results["mocap"]
    at = "at_shared_keys_per_joint_mean"
    lines = [
        f"Bandai-Namco validation, {n} chains of {args.keys} keys 30 frames apart ({windows} windows, {args.handles} mocap "
        f"handles each), bundled BMM, {args.steps} DDIM steps, key orientations {'on' if not args.key_positions_only else 'off'} "
        f"({results['seconds']:.0f} s).",
        "",
        "Velocity jump ‖(p[b+1] − p[b]) − (p[b] − p[b−1])‖ of the six joints' dense curves, cm/frame:",
        "",
        "| where | mean | p95 | max | values |",
        "|---|---|---|---|---|",
        row("coupled, at shared keys", c["at_shared_keys"]),
        row("independent (D.1), at shared keys", i["at_shared_keys"]),
        row("coupled, other frames", c["other_frames"]),
        row("independent, other frames", i["other_frames"]),
        row("mocap, all frames", m["all_frames"]),
        row("mocap, at the key frames", m["at_shared_keys"]),
        "",
        f"Handles error max: coupled {c['handles_error_max_cm']:.2e} cm, independent {i['handles_error_max_cm']:.2e} cm.",
        "Per joint means at shared keys (coupled / independent / mocap all frames): "
        + ", ".join(
            f"{j} " + "/".join(f"{means[j]:.2f}" for means in (c[at], i[at], m["all_frames_per_joint_mean"]))
            for j in CHARACTERISTIC_JOINTS
        ),
    ]
    write_results(args.out, results, "\n".join(lines))
    return results


if __name__ == "__main__":
    main()
