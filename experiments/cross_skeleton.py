"""The full pipeline after IK on each skeleton, driven by its own BMM and by the other skeleton's (BMM §6.4).

    python experiments/cross_skeleton.py --out results/cross_skeleton.json
    python experiments/cross_skeleton.py --model lafan1=lafan1_cpu --windows 100 --ik learned exact --out results/cross_100.json

The six characteristic joints' curves do not name a skeleton, so a BMM trained on one drives
any other. For each target skeleton (``--targets``: LaFAN1 subject 5, Bandai-Namco
validation takes) this runs ``experiments/pipeline_eval.py`` twice on the same windows and
handles (its draws: a window's handles and OOD noise, ±16 cm, depend on the window alone):
once with the target's own BMM, once with the other skeleton's BMM, its curves moved over by
:class:`~bezmotion.pipeline.transfer.Transfer` (the ratio of the bundled profiles' heights,
the six joints' mean orientation offsets). Both drive the target's own IKs (``--ik``; the
default: the learned IK, it with the rig's exact two-bone limbs, the analytic rig, and the
exact IK on the learned one), each IK on the same sampled curves.

The models are registered ones (``bezmotion models``): ``--model CORPUS=NAME`` picks the
BMM and IK of a corpus (default: the corpus's own name, bundled for Bandai-Namco; LaFAN1's
are trained locally, e.g. ``lafan1_cpu`` in about an hour). Every run's full JSON, Markdown
report and per-window figures sit beside ``--out`` (``OUT.<target>.<bmm>.json``); ``--out``
gathers them: handles error after IK in distribution and OOD, MPJPE against the mocap window,
foot skating, key pop and the IK's milliseconds per window, and the curves' dense error
before IK. The same-skeleton LaFAN1 row with the learned IK is the analogue of the paper's
Table 1 BMM row (0.8914 / 1.7090 cm, skating 0.2176).
"""

from __future__ import annotations

import time
from pathlib import Path

import pipeline_eval
from bezmotion.assets.registry import REGISTRY
from bezmotion._src.io import write_results
from bezmotion._src.options import option, options, options_from, options_parser, parse_options

CORPORA = ("lafan1", "bandai_namco")
PAPER_LAFAN1 = {"handles_error_cm": 0.8914, "ood_handles_error_cm": 1.7090, "foot_skating_ratio": 0.2176, "gt_foot_skating_ratio": 0.1209}


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it, each run's own files too)")
    targets: tuple[str, ...] = option(CORPORA, choices=CORPORA, help="target skeletons (default: all)")
    windows: int = option(500, help="validation windows per skeleton (0 = all)")
    model: tuple[str, ...] = option(
        (), repeat=True, metavar="CORPUS=NAME",
        help="the registered model (BMM and IK) of a corpus, e.g. lafan1=lafan1_cpu (default: the corpus's own name); may repeat",
    )  # fmt: skip
    ik: tuple[str, ...] = option(("learned", "refined", "rig", "exact"), choices=pipeline_eval.IKS, help="the target's IKs, each on the same curves")
    foot_lock: bool = option(False, help="lock the curves' feet on their predicted contacts before any IK (pipeline_eval's --foot-lock)")

    def __post_init__(self):
        if self.windows < 0:
            raise ValueError(f"--windows {self.windows}: must be ≥ 0")
        models(self)  # raises naming a malformed --model


def models(args: Options) -> dict[str, str]:
    """``{corpus: registered model name}`` from ``--model`` (each corpus's own name by default).

    Raises:
      ValueError: naming the item, for one that is not ``CORPUS=NAME``, an unknown corpus or
        name, a model of another skeleton than its corpus's, or a corpus given twice.
    """
    chosen, given = {corpus: corpus for corpus in CORPORA}, {}
    for item in args.model:
        corpus, sep, name = item.partition("=")
        if not sep or corpus not in CORPORA:
            raise ValueError(f"--model {item}: expected CORPUS=NAME with CORPUS one of {list(CORPORA)}")
        entry = REGISTRY.get(name)
        if entry is None:
            raise ValueError(f"--model {item}: {name!r} is not a registered model ({', '.join(sorted(REGISTRY))}; `bezmotion models`)")
        if entry.skeleton != corpus:
            raise ValueError(f"--model {item}: {name} poses the {entry.skeleton} skeleton, not {corpus}'s")
        if corpus in given:
            raise ValueError(f"--model {given[corpus]} and --model {item}: one model per corpus")
        chosen[corpus], given[corpus] = name, item
    return chosen


def run_path(out: str | Path, target: str, source: str) -> Path:
    """Where the run of ``target``'s windows driven by ``source``'s BMM writes its JSON."""
    return Path(out).with_suffix(f".{target}.{source}.json")


def runs(args: Options) -> list[tuple[str, str, list[str]]]:
    """``(target, source, pipeline_eval argv)`` of every run: each target's windows driven by its
    own BMM, then by each other corpus's (a registered model of another skeleton is transferred
    by ``pipeline_eval`` itself), always through the target's own IKs."""
    chosen = models(args)
    out = []
    for target in args.targets:
        for source in (target, *(c for c in CORPORA if c != target)):
            argv = [
                "--corpus", target, "--bmm", chosen[source], "--ik-model", chosen[target], "--windows", str(args.windows),
                "--ik", *args.ik, *(["--foot-lock"] if args.foot_lock else []), "--out", str(run_path(args.out, target, source)),
            ]  # fmt: skip
            out.append((target, source, argv))
    return out


def check_runs(args: Options) -> None:
    """Every run's options, checked before any work (a LaFAN1 model not trained here, say):
    SystemExit with pipeline_eval's message, naming the run."""
    for target, source, argv in runs(args):
        parser = options_parser(pipeline_eval.Options, prog=f"cross_skeleton.py ({target} driven by {source}'s BMM)")
        options_from(parser, pipeline_eval.Options, parser.parse_args(argv))


def gather(target: str, source: str, result: dict) -> list[dict]:
    """The report's rows of one run: per IK, the figures ``format_report`` tabulates."""
    curves = result["curves"]["bmm"]
    rows = []
    for ik, x in result["ik"].items():
        i, o = x["id"], x["ood"]
        rows.append({
            "target": target, "bmm": source, "ik": ik, "windows": result["windows"],
            "transfer_scale": (result["settings"]["transfer"] or {}).get("scale"),
            "handles_error_cm": i["handles_error_cm"], "ood_handles_error_cm": o["handles_error_cm"],
            "mpjpe_cm": i["mpjpe_cm"], "ood_mpjpe_cm": o["mpjpe_cm"],
            "foot_skating_ratio": i["foot_skating_ratio"], "mocap_foot_skating_ratio": result["mocap"]["foot_skating_ratio"],
            "key_pop_deg": max(i["key_pop_deg"], o["key_pop_deg"]), "ik_ms_per_window": i["ik_ms_per_window"],
            "curves_dense_error_cm": curves["id"]["dense_error_cm"], "ood_curves_dense_error_cm": curves["ood"]["dense_error_cm"],
        })  # fmt: skip
    return rows


def format_report(results: dict) -> str:
    lines = [
        f"Pipeline after IK on each skeleton, driven by its own BMM and the other's (transferred); each target's windows and "
        f"handles the same for both BMMs, every IK on the same curves{'; feet locked on their predicted contacts first' if results['foot_lock'] else ''} "
        f"({results['seconds']:.0f} s). Each run's full report: "
        f"`{Path(results['out']).with_suffix('')}.<target>.<bmm>.md`.",
        "",
        "| target skeleton | BMM trained on | IK | handles ID (cm) | OOD (cm) | MPJPE ID / OOD (cm) | skating ID (mocap) | key pop (°) | "
        "curves' dense error ID / OOD (cm) | IK ms/window |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        source = r["bmm"] if r["transfer_scale"] is None else f"{r['bmm']} (transferred, × {r['transfer_scale']:.3f})"
        lines.append(
            f"| {r['target']} ({r['windows']} windows) | {source} | {r['ik']} | {r['handles_error_cm']:.4f} | {r['ood_handles_error_cm']:.4f} | "
            f"{r['mpjpe_cm']:.3f} / {r['ood_mpjpe_cm']:.3f} | {r['foot_skating_ratio']:.4f} ({r['mocap_foot_skating_ratio']:.4f}) | "
            f"{r['key_pop_deg']:.1f} | {r['curves_dense_error_cm']:.3f} / {r['ood_curves_dense_error_cm']:.3f} | {r['ik_ms_per_window']:.1f} |"
        )
    p = PAPER_LAFAN1
    lines += ["", f"Paper (full LaFAN1, ProtoRes): handles error {p['handles_error_cm']} / OOD {p['ood_handles_error_cm']} cm, "
              f"foot skating {p['foot_skating_ratio']} (mocap {p['gt_foot_skating_ratio']})."]  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    check_runs(args)
    started = time.perf_counter()
    results = {"out": args.out, "models": models(args), "foot_lock": args.foot_lock, "runs": {}, "rows": [], "paper_lafan1": PAPER_LAFAN1}
    for target, source, run_argv in runs(args):
        print(f"{target} driven by {source}'s BMM: pipeline_eval.py {' '.join(run_argv)}", flush=True)
        result = pipeline_eval.main(run_argv)
        results["runs"][f"{target}.{source}"] = str(run_path(args.out, target, source))
        results["rows"] += gather(target, source, result)
    results["seconds"] = time.perf_counter() - started
    write_results(args.out, results, format_report(results))
    return results


if __name__ == "__main__":
    main()
