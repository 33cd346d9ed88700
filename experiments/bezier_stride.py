"""Dense reconstruction error of the six characteristic joints against the Bézier stride.

    python experiments/bezier_stride.py --data ../shared/data/lafan1/lafan1-subset.zip --out results/bezier_stride.json

The analogue of BMM's Figure 8 before IK: every 31-frame window (offset 5) of LaFAN1
subject 5 is reduced to the six characteristic joints, fitted with Bézier curves at
strides 1…12, and the curves are evaluated back at every frame. The error is the mean
per-joint position error (cm) over windows, frames and joints, for both fitting
variants (control positions pinned to the data — the default — or free). Writes the JSON
``{"stride": {"1": cm, …, "12": cm}, "n_windows": …, "variants": {…}, …}`` (``"stride"``
is the default, pinned variant), a Markdown table (``.md``) and a plot (``.png``) beside
it, and prints the table.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion._src.io import save_figure, write_results
from bezmotion.bezier import BezierLayout, evaluate, fit_curves
from bezmotion.data import lafan1
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.data.corpus import motion_clips
from bezmotion.data.curves import DEFAULT_OFFSET, DEFAULT_WINDOW, characteristic_windows
from bezmotion._src.options import option, options, parse_options

VARIANTS = {"pinned": True, "free": False}  # name -> pin_positions


@options
class Options:
    data: str = option(help="LaFAN1 zip or a directory of its .bvh files")
    out: str = option(help="output JSON file (.md and .png are written beside it)")
    window: int = option(DEFAULT_WINDOW, help="frames per window (default 31)")
    offset: int = option(DEFAULT_OFFSET, help="frames between window starts (default 5)")
    max_stride: int = option(12, help="largest stride (default 12)")
    no_cache: bool = option(False, help="re-parse the BVH files instead of using the cache")


@jax.jit
def _joint_errors(curve, points):
    return jnp.linalg.norm(curve - points, axis=-1)


def stride_errors(positions: np.ndarray, strides: list[int]) -> dict:
    """Reconstruction errors of ``positions (windows, frames, 6, 3)`` for each stride and variant."""
    points = jnp.moveaxis(jnp.asarray(positions), -2, -3)  # (windows, 6, frames, 3): one curve per joint
    num_frames = positions.shape[1]
    results: dict = {name: {"stride": {}, "per_joint": {}, "control_error": {}} for name in VARIANTS}
    for stride in strides:
        layout = BezierLayout(num_frames, stride)
        for name, pin in VARIANTS.items():
            fit = fit_curves(layout, points, pin_positions=pin)
            if not bool(fit.succeeded.all()):
                raise RuntimeError(f"stride {stride}, {name}: {int((~fit.succeeded).sum())} fits did not converge")
            error = np.asarray(_joint_errors(evaluate(layout, fit.ctrl_pos, fit.ctrl_tangent), points))  # (w, 6, f)
            key = str(stride)
            results[name]["stride"][key] = float(error.mean())
            results[name]["per_joint"][key] = dict(zip(CHARACTERISTIC_JOINTS, error.mean(axis=(0, 2)).tolist()))
            results[name]["control_error"][key] = float(error[..., layout.control_frames].mean())
    return results


def format_table(results: dict, strides: list[int]) -> str:
    lines = [
        "| stride | controls | pinned (cm) | free (cm) | free: error at control frames (cm) |",
        "|---|---|---|---|---|",
    ]
    num_frames = results["window"]
    for s in strides:
        k = str(s)
        v = results["variants"]
        lines.append(
            f"| {s} | {BezierLayout(num_frames, s).num_controls} | {v['pinned']['stride'][k]:.4f} | "
            f"{v['free']['stride'][k]:.4f} | {v['free']['control_error'][k]:.4f} |"
        )
    return "\n".join(lines)


def plot(results: dict, strides: list[int], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    for name, style in (("pinned", "o-"), ("free", "s--")):
        ax.plot(strides, [results["variants"][name]["stride"][str(s)] for s in strides], style, label=name)
    ax.axvline(6, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("stride between control points (frames)")
    ax.set_ylabel("six-joint position error (cm)")
    ax.set_title(f"Bézier reconstruction, LaFAN1 subject 5 ({results['n_windows']} windows)")
    ax.set_xticks(strides)
    ax.grid(alpha=0.3)
    ax.legend(title="control positions")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    if not 1 <= args.max_stride < args.window:
        raise SystemExit(f"--max-stride must be between 1 and window - 1 = {args.window - 1}, got {args.max_stride}")

    start = time.perf_counter()
    corpus = lafan1.load_lafan1(args.data, use_cache=not args.no_cache)
    clips = motion_clips(corpus, "validation")
    positions, _, _, _ = characteristic_windows(clips, "lafan1", window=args.window, offset=args.offset)
    strides = list(range(1, args.max_stride + 1))
    variants = stride_errors(positions, strides)
    results = {
        "stride": variants["pinned"]["stride"],
        "n_windows": int(len(positions)),
        "window": args.window,
        "offset": args.offset,
        "subjects": list(lafan1.TEST_SUBJECTS),
        "default_variant": "pinned",
        "metric": "mean per-joint position error of the six characteristic joints over all frames (cm), before IK",
        "variants": variants,
    }
    out = Path(args.out)
    table = format_table(results, strides)
    print(f"Bézier stride on LaFAN1 subject 5 ({args.data}): {results['n_windows']} windows of {args.window} frames")
    write_results(out, results, table)
    plot(results, strides, out.with_suffix(".png"))
    print(f"wrote {out}, {out.with_suffix('.md')}, {out.with_suffix('.png')} in {time.perf_counter() - start:.1f} s")
    return results


if __name__ == "__main__":
    main()
