"""The paper's Table 1, complete: every row on every corpus, after IK, with FID,
diversity and multimodality; and its Table 6 / Figure 12 (FID against DDIM steps).

    python experiments/table1.py --out results/table1.json
    python experiments/table1.py --corpora bandai_namco --windows 500 --out results/table1_bn.json

**Rows** (JSON ``{corpus: {row: {metric: value}}}``; a row whose model is not there has
``null`` values and a ``missing`` line naming the one command that trains it):

- ``mocap``: the validation mocap itself (handles errors ``null``: the handles are drawn
  from it, as the paper's "–"; multimodality ``null``: one motion per condition);
- ``reference``: the non-learned interpolation through start, end and handles
  (:func:`~bezmotion.evaluation.curves.reference_curves`), the six joints' curves themselves
  (no orientations, so no IK: its handles error is 0 by construction; multimodality 0,
  it is deterministic);
- ``bmm``: the BMM's curves after the learned IK (``--bmm``, ``--ik-model``; bundled for
  Bandai-Namco), ``bmm_exact`` the same curves after the exact IK (the learned IK, then
  the damped least-squares stage with the joint limits beside the IK model);
- ``bmm_minus_b``: BMM⁻ᴮ's dense six-joint trajectories (position + ortho6D) after the
  learned IK, as the paper measures it (``--minus-b``; overwrite ``keys``);
- ``bmm_minus_ik_b``: BMM⁻ᴵᴷ⁻ᴮ's dense full skeleton, no IK (``--minus-ik-b``);
- ``condmdi_g``: CondMDIᴳ's dense full skeleton (a 1-D UNet, no IK), evaluated exactly as
  ``bmm_minus_ik_b`` (overwrite ``keys``), at its classifier-free guidance 2.5
  (``--condmdi-g``).

Trained models are reused from their standard run folders (``<cache>/runs/…``, the
defaults of ``experiments/bmm_lafan1.py``, ``train_ik.py``, ``ablations.py`` at ``--config
cpu``); ``--bmm CORPUS=PATH`` (and ``--ik-model``, ``--minus-b``, ``--minus-ik-b``,
``--condmdi-g``, ``--data``) point elsewhere.

**Windows.** ``--windows`` validation windows (LaFAN1 subject 5, Bandai-Namco's validation
takes) and their 1–4 handles on control frames, in distribution and OOD (±16 cm):
:func:`~bezmotion.evaluation.curves.make_eval_set` ``per_window`` with key ``--seed`` (1234,
as ``pipeline_eval.py`` and ``ablations.py``). Every model samples the same windows and
handles, key ``fold_in(--sample-seed, window row)``, ``--steps`` DDIM steps.

**Metrics** (all rows on the same windows):

- ``handles_error_cm`` / ``ood_handles_error_cm``: mean distance (cm) between each
  intermediate handle and its joint at its frame in the final motion (after IK where the
  row has one);
- ``foot_skating_ratio``: of the final motion's feet (the characteristic ankles), at the
  validation curves' floor height (:func:`~bezmotion.evaluation.curves.floor_height_from`);
- ``fid``: Fréchet distance (BMM eq. 5) between our motion feature extractor's embeddings
  (``--features``, :mod:`bezmotion.evaluation.motion_features`; trained by
  ``experiments/motion_features.py`` on both corpora, character-agnostic) of the row's
  six-joint windows (in distribution) and of as many random *training* windows;
- ``diversity`` (eq. 6): over ``--diversity-pairs`` random pairs of the row's windows
  (capped at half the windows); the training windows' own is in ``ground_truth``;
- ``multimodality`` (eq. 7): the first ``--mm-conditions`` windows (conditions: start,
  end, in-distribution handles), each sampled ``--mm-samples`` times, pairs of samples of
  one condition (after the learned IK for ``bmm`` and ``bmm_minus_b``).

**Table 6 / Figure 12.** FID, handles error and foot skating of ``bmm`` (learned IK, in
distribution) at each of ``--table6-steps`` DDIM steps, per corpus; the plot of FID against
steps is written beside the JSON (``.png``), the Markdown report beside it too.
"""

from __future__ import annotations

import functools
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.assets import BUNDLED_BMM, BUNDLED_IK, PROFILES_DIR
from bezmotion.evaluation.ablations import DenseMotion, load_dense_model, sample_dense
from bezmotion.evaluation.curves import EvalSet, dense_positions, floor_height_from, make_eval_set, reference_curves
from bezmotion.bmm.sampling import Handles, load_model
from bezmotion.data.corpus import motion_clips
from bezmotion.data.curves import CurveDataset, curve_dataset
from bezmotion.data.sources import default_source, load_corpus
from bezmotion.evaluation.motion_features import load_motion_features, motion_features
from bezmotion.evaluation.naturalness import diversity, frechet_distance, gaussian_fit, multimodality
from bezmotion.ik.exact import exact_ik, exact_settings
from bezmotion.ik.protocol import Pose, targets_from_pose
from bezmotion.ik.protores import load_ik_model, protores_ik_fn
from bezmotion._src.io import write_results
from bezmotion._src.options import option, options, parse_options
from bezmotion.evaluation.pipeline import sample_window_curves, solve_window_curves, window_keys, window_poses
from bezmotion.evaluation.window_figures import PipelineMetricsConfig, summarize_windows, window_curve_metrics, window_pose_metrics
from bezmotion.pipeline.authoring import ik_model_joint_limits
from bezmotion.pipeline.inbetweening import WindowCurves
from bezmotion.pipeline.transfer import CharacterProfile
from _common import runs_dir

CORPORA = ("bandai_namco", "lafan1")
ROWS = ("mocap", "reference", "bmm", "bmm_exact", "bmm_minus_b", "bmm_minus_ik_b", "condmdi_g")
METRICS = ("handles_error_cm", "ood_handles_error_cm", "foot_skating_ratio", "fid", "diversity", "multimodality")
IKS = ("learned", "exact")
MM_KEY = 1_000_003  # folded into a window's key for its multimodality samples (not its Table 1 sample)

TRAIN_COMMANDS = {
    "features": "python experiments/motion_features.py --corpora lafan1 bandai_namco --out results/motion_features.json",
    "bmm": "python experiments/bmm_lafan1.py --corpus {corpus} --out results/bmm_{corpus}.json",
    "ik": "python experiments/train_ik.py --corpus {corpus}",
    "bmm_minus_b": "python experiments/ablations.py --corpus {corpus} --ablation minus_b --out results/ablation_minus_b_{corpus}.json",
    "bmm_minus_ik_b": "python experiments/ablations.py --corpus {corpus} --ablation minus_ik_b --out results/ablation_minus_ik_b_{corpus}.json",
    "condmdi_g": "python experiments/ablations.py --corpus {corpus} --ablation condmdi_g --out results/ablation_condmdi_g_{corpus}.json",
}
DENSE_ROWS = {"bmm_minus_b": "minus_b", "bmm_minus_ik_b": "minus_ik_b", "condmdi_g": "condmdi_g"}  # row: its model option
DENSE_LABELS = {"minus_b": "BMM⁻ᴮ (minus_b)", "minus_ik_b": "BMM⁻ᴵᴷ⁻ᴮ (minus_ik_b)", "condmdi_g": "CondMDIᴳ (condmdi_g)"}


@options
class Options:
    out: str = option(help="output JSON (a .md report and the Figure 12 .png are written beside it)")
    corpora: tuple[str, ...] = option(CORPORA, choices=CORPORA, help="corpora evaluated (default both)")
    data: tuple[str, ...] = option((), repeat=True, metavar="CORPUS=PATH", help="a corpus's archive, or a folder of BVH files of its skeleton (every 2nd file validates)")
    features: str | None = option(None, help="the motion feature extractor folder (default <cache>/runs/motion_features_lafan1_bandai_namco/model)")
    bmm: tuple[str, ...] = option((), repeat=True, metavar="CORPUS=PATH", help="a saved BMM (default: bundled for bandai_namco, <cache>/runs/bmm_<corpus>_cpu/model)")
    ik_model: tuple[str, ...] = option((), repeat=True, metavar="CORPUS=PATH", help="a saved learned IK (default: bundled for bandai_namco, <cache>/runs/ik_<corpus>/model)")
    minus_b: tuple[str, ...] = option((), repeat=True, metavar="CORPUS=PATH", help="a saved BMM⁻ᴮ (default <cache>/runs/ablation_minus_b_<corpus>_cpu/model)")
    minus_ik_b: tuple[str, ...] = option((), repeat=True, metavar="CORPUS=PATH", help="a saved BMM⁻ᴵᴷ⁻ᴮ (default <cache>/runs/ablation_minus_ik_b_<corpus>_cpu/model)")
    condmdi_g: tuple[str, ...] = option((), repeat=True, metavar="CORPUS=PATH", help="a saved CondMDIᴳ (default <cache>/runs/ablation_condmdi_g_<corpus>_cpu/model)")
    ik: tuple[str, ...] = option(IKS, choices=IKS, help="IKs after the BMM: learned (row bmm), exact (row bmm_exact)")
    exact: tuple[str, ...] = option((), repeat=True, metavar="NAME=VALUE", help="an ExactIKParams setting of the exact IK (e.g. plant_weight=1); may repeat")
    rows: tuple[str, ...] = option(ROWS, choices=ROWS, help="rows evaluated (default all; the others are taken from --merge, or null)")
    merge: str | None = option(None, help="an earlier table1 JSON of the same windows and settings: its rows (and Table 6) fill the rows not evaluated here")
    windows: int = option(1000, help="validation windows (the paper: 3k on LaFAN1; 0 = all)")
    steps: int = option(10, help="DDIM steps of every model (the paper's 10)")
    table6_steps: tuple[int, ...] = option((5, 10, 25, 50, 100), help="DDIM steps of Table 6 / Figure 12 (--steps itself reuses the bmm row: --table6-steps 10 costs nothing)")
    mm_conditions: int = option(100, help="multimodality: conditions C (the paper: 100)")
    mm_samples: int = option(20, help="multimodality: samples per condition S_m (the paper: 20)")
    diversity_pairs: int = option(1000, help="diversity: pairs S_d (the paper: 1000; capped at half the windows)")
    seed: int = option(1234, help="key of the windows, handles and OOD noise, and of the training windows FID compares against")
    sample_seed: int = option(7, help="key of every sampler (folded with each window's row)")
    chunk: int = option(100, help="windows per compiled sampling / learned-IK call")
    exact_chunk: int = option(10, help="windows per compiled exact-IK call (large chunks of the exact IK have hung XLA)")
    no_progress: bool = False

    def __post_init__(self):
        for name in ("data", "bmm", "ik_model", "minus_b", "minus_ik_b", "condmdi_g"):
            per_corpus(self, name)  # raises on a malformed or unknown CORPUS=PATH
        if self.windows < 0 or self.steps < 1 or self.chunk < 1 or self.exact_chunk < 1:
            raise ValueError("--windows must be ≥ 0, --steps, --chunk and --exact-chunk ≥ 1")
        exact_settings(self.exact, "--exact")  # raises on a malformed or unknown setting
        if any(s < 1 for s in self.table6_steps):
            raise ValueError(f"--table6-steps must be ≥ 1, got {list(self.table6_steps)}")
        if self.mm_conditions < 1 or self.mm_samples < 2 or self.diversity_pairs < 1:
            raise ValueError("--mm-conditions and --diversity-pairs must be ≥ 1, --mm-samples ≥ 2")


def per_corpus(args: Options, name: str) -> dict[str, str]:
    """``--NAME CORPUS=PATH`` items as ``{corpus: path}``."""
    out = {}
    for item in getattr(args, name):
        corpus, sep, path = item.partition("=")
        if not sep or corpus not in CORPORA or not path:
            raise ValueError(f"--{name.replace('_', '-')} {item}: expected CORPUS=PATH with CORPUS one of {CORPORA}")
        out[corpus] = path
    return out


def model_dir(args: Options, what: str, corpus: str) -> Path:
    """Where ``what`` (bmm, ik_model, minus_b, minus_ik_b, condmdi_g) of ``corpus`` is read from."""
    given = per_corpus(args, what)
    if corpus in given:
        return Path(given[corpus]).expanduser()
    if corpus == "bandai_namco" and what in ("bmm", "ik_model"):
        return BUNDLED_BMM if what == "bmm" else BUNDLED_IK
    default = {"bmm": f"bmm_{corpus}_cpu", "ik_model": f"ik_{corpus}", "minus_b": f"ablation_minus_b_{corpus}_cpu",
               "minus_ik_b": f"ablation_minus_ik_b_{corpus}_cpu", "condmdi_g": f"ablation_condmdi_g_{corpus}_cpu"}[what]  # fmt: skip
    return runs_dir(default, "model")


def hip_height(corpus: str) -> float:
    """The corpus skeleton's standing hip height (cm): what the feature extractor scales by."""
    return CharacterProfile.load(PROFILES_DIR / f"{corpus}.json").height


def missing_row(reason: str) -> dict:
    return {**dict.fromkeys(METRICS), "missing": reason}


def not_there(path: Path, what: str, command: str) -> str:
    return f"no {what} at {path}; train it with: {command}"


# ------------------------------------------------------------------------------ naturalness


class Naturalness:
    """FID against a corpus's training windows, diversity and multimodality of six-joint windows."""

    def __init__(self, args: Options, extractor, train_set: CurveDataset, height: float, n: int):
        self.args, self.extractor, self.height = args, extractor, height
        key = jax.random.key(args.seed)
        order = np.asarray(jax.random.permutation(jax.random.fold_in(key, 1), len(train_set)))[:n]
        self.key = jax.random.fold_in(key, 3)
        features = self.embed(train_set.dense_pos[order])
        self.truth = gaussian_fit(features, name="training windows")
        self.ground_truth = {"windows": int(len(order)), "diversity": self.diversity(features)}

    def embed(self, pos) -> np.ndarray:
        return motion_features(self.extractor, np.asarray(pos), self.height)

    def diversity(self, features: np.ndarray) -> float:
        return diversity(features, min(self.args.diversity_pairs, len(features) // 2), key=self.key)

    def fid_and_diversity(self, pos, name: str) -> dict[str, float]:
        features = self.embed(pos)
        return {"fid": frechet_distance(self.truth, gaussian_fit(features, name=name)), "diversity": self.diversity(features)}

    def multimodality(self, pos) -> float:
        """``pos`` ``(conditions, samples, frames, 6, 3)``."""
        c, s = pos.shape[:2]
        features = self.embed(np.asarray(pos).reshape(c * s, *pos.shape[2:])).reshape(c, s, -1)
        return multimodality(features, s // 2, key=self.key)


# ------------------------------------------------------------------------------ one corpus


class Setting:
    """What every row of one corpus shares: windows, handles, mocap poses, metrics settings."""

    def __init__(self, args: Options, name: str):
        progress = not args.no_progress
        source = per_corpus(args, "data").get(name)
        if source is not None and Path(source).is_dir() and not (Path(source) / "lafan1").exists() and any(Path(source).glob("*.bvh")):
            self.corpus = load_corpus(source, characteristic=name, validation_every=2, progress=progress)
        else:
            self.corpus = load_corpus(name, source=source or default_source(name), progress=progress)
        self.name = name
        self.validation = curve_dataset(self.corpus, "validation", progress=progress)
        self.train = curve_dataset(self.corpus, "train", progress=progress)
        self.eval_set: EvalSet = make_eval_set(self.validation, key=jax.random.key(args.seed), num_windows=args.windows or None, per_window=True)
        self.n = len(self.eval_set.rows)
        self.handles = {"id": self.eval_set.handles, "ood": self.eval_set.handles_ood}
        self.config = PipelineMetricsConfig(self.validation.layout.stride, self.validation.fps, floor_height_from(self.validation))
        self.keys = window_keys(jax.random.key(args.sample_seed), self.eval_set.rows)
        self.mm = min(args.mm_conditions, self.n)
        # Conditions of the multimodality: the first windows, each repeated S_m times, its own keys.
        self.mm_index = np.repeat(np.arange(self.mm), args.mm_samples)
        self.mm_keys = jax.vmap(lambda k, s: jax.random.fold_in(jax.random.fold_in(k, MM_KEY), s))(
            self.keys[self.mm_index], np.tile(np.arange(args.mm_samples), self.mm)
        )

    def mm_shape(self, pos) -> np.ndarray:
        return np.asarray(pos).reshape(self.mm, -1, *pos.shape[1:])

    def take(self, tree, index):
        return jax.tree.map(lambda a: a[index], tree)


def curve_row(setting: Setting, positions: dict, nat: Naturalness | None, name: str) -> dict:
    """Metrics of six-joint positions per condition (``{"id": (windows, frames, 6, 3), "ood": …}``)."""
    row = {}
    for cond, pos in positions.items():
        m = summarize_windows(window_curve_metrics(setting.config, pos, setting.handles[cond], setting.eval_set.dense_pos))
        row["handles_error_cm" if cond == "id" else "ood_handles_error_cm"] = m["handles_error_cm"]
        if cond == "id":
            row["foot_skating_ratio"] = m["foot_skating_ratio"]
            row["dense_error_cm"] = m["dense_error_cm"]
    if nat is not None:
        row.update(nat.fid_and_diversity(positions["id"], name))
    return row


def pose_row(setting: Setting, character, poses: dict[str, Pose], truth: Pose, nat: Naturalness | None, name: str) -> dict:
    """Metrics of IK'd poses per condition: handles error on the full skeleton, skating of its feet."""
    row = {}
    for cond, pose in poses.items():
        m = summarize_windows(window_pose_metrics(setting.config, character, pose, truth, setting.handles[cond]))
        row["handles_error_cm" if cond == "id" else "ood_handles_error_cm"] = m["handles_error_cm"]
        if cond == "id":
            row["foot_skating_ratio"] = m["foot_skating_ratio"]
            row["mpjpe_cm"] = m["mpjpe_cm"]
    if nat is not None:
        row.update(nat.fid_and_diversity(targets_from_pose(character, poses["id"]).position, name))
    return row


def ik_solve(args: Options, ik, curves: WindowCurves, truth: Pose, exact: bool = False, handles=None) -> Pose:
    """IK'd windows; ``handles``: the curves' own, pinned for an IK that weighs its targets (the exact one)."""
    fn, params = ik
    return solve_window_curves(fn, params, curves, truth, handles=handles, chunk=args.exact_chunk if exact else args.chunk)[0]


def bmm_rows(args: Options, s: Setting, nat, character, iks, truth: Pose, bmm) -> tuple[dict, dict]:
    """Rows ``bmm`` / ``bmm_exact`` and Table 6."""
    curves = {
        cond: sample_window_curves(bmm, character, truth, s.handles[cond], s.keys, steps=args.steps, chunk=args.chunk)
        for cond in ("id", "ood")
    }  # fmt: skip
    rows = {}
    for ik_name, row_name in (("learned", "bmm"), ("exact", "bmm_exact")):
        if ik_name not in iks:
            rows[row_name] = missing_row(f"--ik {ik_name} not requested")
            continue
        poses = {cond: ik_solve(args, iks[ik_name], c, truth, exact=ik_name == "exact", handles=s.handles[cond]) for cond, c in curves.items()}
        rows[row_name] = pose_row(s, character, poses, truth, nat, row_name)
        rows[row_name]["multimodality"] = None
        print(f"{s.name} {row_name}: {rows[row_name]}", flush=True)
    if nat is not None and "learned" in iks:
        mm_truth = s.take(truth, s.mm_index)
        mm_curves = sample_window_curves(bmm, character, mm_truth, s.take(s.handles["id"], s.mm_index), s.mm_keys, steps=args.steps, chunk=args.chunk)
        pose = ik_solve(args, iks["learned"], mm_curves, mm_truth)
        rows["bmm"]["multimodality"] = nat.multimodality(s.mm_shape(targets_from_pose(character, pose).position))
    if "exact" in iks:
        rows["bmm_exact"]["multimodality_note"] = "measured after the learned IK only (row bmm): the exact stage's cost on C·S_m windows"
    table6 = {}
    if "learned" in iks:
        for steps in args.table6_steps:
            t0 = time.perf_counter()
            if steps == args.steps and "bmm" in rows:  # the row itself
                table6[str(steps)] = {k: rows["bmm"].get(k) for k in ("handles_error_cm", "foot_skating_ratio", "fid")} | {"seconds": 0.0}
                continue
            c = sample_window_curves(bmm, character, truth, s.handles["id"], s.keys, steps=steps, chunk=args.chunk)
            r = pose_row(s, character, {"id": ik_solve(args, iks["learned"], c, truth)}, truth, nat, f"bmm {steps} steps")
            table6[str(steps)] = {k: r.get(k) for k in ("handles_error_cm", "foot_skating_ratio", "fid")} | {"seconds": time.perf_counter() - t0}
            print(f"{s.name} table 6, {steps} steps: {table6[str(steps)]}", flush=True)
    return rows, table6


@functools.cache
def _dense_sampler(steps: int):
    one = lambda model, start, end, handles, key: sample_dense(model, start, end, handles, key=key, steps=steps, overwrite="keys")  # noqa: E731
    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0, 0, 0)))


def dense_sample(args: Options, model, start, end, handles: Handles, keys) -> DenseMotion:
    """An ablation's motion of every window, ``--chunk`` windows per call, one key per window."""
    run = _dense_sampler(args.steps)
    n = start.shape[0]
    chunk = min(args.chunk, n)
    parts = []
    for lo in range(0, n, chunk):
        idx = np.arange(lo, lo + chunk) % n
        out = run(model, start[idx], end[idx], jax.tree.map(lambda a: a[idx], handles), keys[idx])
        parts.append(jax.tree.map(lambda a: np.asarray(a)[: min(chunk, n - lo)], out))
    return jax.tree.map(lambda *xs: jnp.asarray(np.concatenate(xs)), *parts)


def minus_b_row(args: Options, s: Setting, nat, character, iks, truth, model) -> dict:
    """BMM⁻ᴮ's dense six-joint trajectories after the learned IK (without an IK: the trajectories)."""
    es = s.eval_set
    motions = {cond: dense_sample(args, model, es.start, es.end, s.handles[cond], s.keys) for cond in ("id", "ood")}
    if not model.config.orientation or "learned" not in iks or character is None:
        row = curve_row(s, {cond: m.pos for cond, m in motions.items()}, nat, "bmm_minus_b")
        row["note"] = "before IK (no learned IK, or a positions-only model): the six joints' trajectories"
        mm = lambda m: m.pos  # noqa: E731
    else:
        to_curves = lambda m: WindowCurves(None, m.pos, m.rot6d)  # noqa: E731
        poses = {cond: ik_solve(args, iks["learned"], to_curves(m), truth) for cond, m in motions.items()}
        row = pose_row(s, character, poses, truth, nat, "bmm_minus_b")
        mm = lambda m: targets_from_pose(character, ik_solve(args, iks["learned"], to_curves(m), s.take(truth, s.mm_index))).position  # noqa: E731
    row["multimodality"] = None
    if nat is not None:
        m = dense_sample(args, model, es.start[s.mm_index], es.end[s.mm_index], s.take(s.handles["id"], s.mm_index), s.mm_keys)
        row["multimodality"] = nat.multimodality(s.mm_shape(mm(m)))
    return row


def minus_ik_b_row(args: Options, s: Setting, nat, model, name: str = "bmm_minus_ik_b") -> dict:
    """A dense full skeleton, no IK (BMM⁻ᴵᴷ⁻ᴮ, CondMDIᴳ at its own default guidance): its
    characteristic joints are the final motion."""
    es, cfg = s.eval_set, model.config
    positions = {
        cond: dense_sample(args, model, es.start, es.end, s.handles[cond], s.keys).characteristic_positions(cfg) for cond in ("id", "ood")
    }  # fmt: skip
    row = curve_row(s, positions, nat, name)
    row["multimodality"] = None
    row["guidance"] = cfg.default_guidance
    if nat is not None:
        m = dense_sample(args, model, es.start[s.mm_index], es.end[s.mm_index], s.take(s.handles["id"], s.mm_index), s.mm_keys)
        row["multimodality"] = nat.multimodality(s.mm_shape(m.characteristic_positions(cfg)))
    return row


def build_iks(args: Options, ik_path: Path, ik_model) -> dict:
    iks = {}
    if "learned" in args.ik:
        iks["learned"] = (protores_ik_fn, ik_model)
    if "exact" in args.ik:
        limits = ik_model_joint_limits(ik_path, ik_model.character)
        iks["exact"] = exact_ik(protores_ik_fn, ik_model, ik_model.character, limits=limits, **exact_settings(args.exact))
    return iks


def merged_rows(args: Options, name: str) -> tuple[dict, dict]:
    """Rows and Table 6 of ``name`` in ``--merge``, after checking it measured the same thing."""
    if args.merge is None:
        return {}, {}
    earlier = json.loads(Path(args.merge).read_text())
    same = ("windows", "steps", "seed", "sample_seed", "mm_conditions", "mm_samples", "diversity_pairs", "features")
    settings = earlier.get("settings", {})
    differ = [k for k in same if settings.get(k) != getattr(args, k)]
    if differ:
        raise ValueError(f"--merge {args.merge}: measured with other {differ}: {[settings.get(k) for k in differ]}")
    return earlier.get(name, {}), earlier.get("table6", {}).get(name, {})


def evaluate_corpus(args: Options, name: str, extractor, extractor_missing: str | None) -> dict:
    started = time.perf_counter()
    s = Setting(args, name)
    es = s.eval_set
    nat = None if extractor is None else Naturalness(args, extractor, s.train, hip_height(name), s.n)
    print(f"{name}: {s.n} validation windows, {len(s.train)} training windows", flush=True)
    wanted = set(args.rows)
    rows: dict[str, dict] = {}

    if "mocap" in wanted:
        mocap = summarize_windows(window_curve_metrics(s.config, es.dense_pos, s.handles["id"], es.dense_pos))
        rows["mocap"] = {"handles_error_cm": None, "ood_handles_error_cm": None, "foot_skating_ratio": mocap["foot_skating_ratio"],
                         **(nat.fid_and_diversity(es.dense_pos, "mocap") if nat else {}), "multimodality": None,
                         "note": "handles are drawn from the mocap's curves (the paper's –); one motion per condition"}  # fmt: skip
    if "reference" in wanted:
        layout = s.validation.layout
        ref = {cond: dense_positions(layout, *reference_curves(es, h, layout)[:2]) for cond, h in s.handles.items()}
        rows["reference"] = {**curve_row(s, ref, nat, "reference"), "multimodality": 0.0 if nat else None,
                             "note": "the curves themselves (no orientations to IK): through every handle by construction; deterministic"}  # fmt: skip

    ik_path = model_dir(args, "ik_model", name)
    ik_model = load_ik_model(ik_path) if (ik_path / "config.json").exists() else None
    character = truth = None
    iks: dict = {}
    if ik_model is not None:
        character = ik_model.character
        if character.skeleton.names != s.corpus.skeleton.names:
            raise ValueError(f"--ik-model {ik_path}: a {character.name} IK, not for the {name} skeleton")
        truth = window_poses(character, motion_clips(s.corpus, "validation"), s.validation, es.rows)
        iks = build_iks(args, ik_path, ik_model)
    no_ik = not_there(ik_path, "learned IK", TRAIN_COMMANDS["ik"].format(corpus=name))

    bmm_path = model_dir(args, "bmm", name)
    # What the bmm rows lack, if anything: the BMM, the learned IK, or both (every command named).
    bmm_missing = [not_there(bmm_path, "BMM", TRAIN_COMMANDS["bmm"].format(corpus=name))] if not (bmm_path / "config.json").exists() else []
    bmm_missing += [no_ik] if ik_model is None else []
    bmm_missing_reason = "; and ".join(bmm_missing) or None
    table6: dict = {}
    if wanted & {"bmm", "bmm_exact"}:
        if bmm_missing_reason:
            rows["bmm"], rows["bmm_exact"] = missing_row(bmm_missing_reason), missing_row(bmm_missing_reason)
        else:
            rows_bmm, table6 = bmm_rows(args, s, nat, character, {k: v for k, v in iks.items() if k != "exact" or "bmm_exact" in wanted}, truth, load_model(bmm_path))
            rows.update(rows_bmm)

    for row, what in DENSE_ROWS.items():
        if row not in wanted:
            continue
        path = model_dir(args, what, name)
        if not (path / "config.json").exists():
            rows[row] = missing_row(not_there(path, DENSE_LABELS[what], TRAIN_COMMANDS[row].format(corpus=name)))
            continue
        model = load_dense_model(path)
        if model.config.variant != what:
            raise ValueError(f"--{what.replace('_', '-')} {path}: a saved {model.config.variant}, not {what}")
        rows[row] = minus_b_row(args, s, nat, character, iks, truth, model) if what == "minus_b" else minus_ik_b_row(args, s, nat, model, row)
        rows[row]["model"] = str(path)
        print(f"{name} {row}: {rows[row]}", flush=True)
    for r in rows.values():
        for metric in METRICS:
            r.setdefault(metric, None)
        if extractor_missing:
            r["naturalness_missing"] = extractor_missing
    rows = {k: v for k, v in rows.items() if k in wanted}
    earlier, earlier_table6 = merged_rows(args, name)
    for row in ROWS:
        if row in rows:
            continue
        if row in earlier:
            rows[row] = {**earlier[row], "merged_from": args.merge}
        else:  # not evaluated here: still say when its model is missing
            reason = "not evaluated (--rows)"
            if row in ("bmm", "bmm_exact") and bmm_missing_reason:
                reason = bmm_missing_reason
            elif row in DENSE_ROWS and not (model_dir(args, DENSE_ROWS[row], name) / "config.json").exists():
                reason = not_there(model_dir(args, DENSE_ROWS[row], name), row, TRAIN_COMMANDS[row].format(corpus=name))
            rows[row] = missing_row(reason)
    if not table6 and earlier_table6:
        table6 = earlier_table6
    info = {
        "windows": s.n, "train_windows_for_fid": nat.ground_truth["windows"] if nat else None,
        "ground_truth_diversity": nat.ground_truth["diversity"] if nat else None,
        "floor_height_cm": s.config.floor_height, "fps": s.config.fps, "mm_conditions": s.mm, "mm_samples": args.mm_samples,
        "bmm": str(bmm_path), "ik_model": str(ik_path), "seconds": time.perf_counter() - started,
    }  # fmt: skip
    return {"rows": {row: rows[row] for row in ROWS}, "table6": table6, "info": info}


# ------------------------------------------------------------------------------ reports


def fmt(x, digits: int = 4) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def format_report(args: Options, table: dict, results: dict) -> str:
    lines = [
        f"Table 1 analogue: {args.steps} DDIM steps, handles on control frames (key {args.seed}), FID against as many training "
        f"windows with our motion feature extractor ({results['features']}), diversity over ≤ {args.diversity_pairs} pairs, "
        f"multimodality over C × {args.mm_samples} samples.",
        "",
    ]
    for corpus, rows in table.items():
        info = results["info"][corpus]
        lines += [
            f"**{corpus}** ({info['windows']} validation windows; training windows' diversity: {fmt(info['ground_truth_diversity'], 3)}):",
            "",
            "| row | handles error (cm) ↓ | OOD handles error (cm) ↓ | foot skating ↓ | FID ↓ | diversity → | multimodality ↑ |",
            "|---|---|---|---|---|---|---|",
        ]
        for row, r in rows.items():
            lines.append(
                f"| {row} | {fmt(r['handles_error_cm'])} | {fmt(r['ood_handles_error_cm'])} | {fmt(r['foot_skating_ratio'])} | "
                f"{fmt(r['fid'])} | {fmt(r['diversity'], 3)} | {fmt(r['multimodality'], 3)} |"
            )
        missing = [f"- {row}: {r['missing']}" for row, r in rows.items() if r.get("missing")]
        lines += ["", *(["Missing rows:", "", *missing, ""] if missing else [])]
        t6 = results["table6"].get(corpus)
        if t6:
            lines += [
                f"Table 6 analogue ({corpus}, BMM after the learned IK, in distribution):",
                "",
                "| DDIM steps | handles error (cm) | foot skating | FID |",
                "|---|---|---|---|",
                *(f"| {st} | {fmt(r['handles_error_cm'])} | {fmt(r['foot_skating_ratio'])} | {fmt(r['fid'])} |" for st, r in t6.items()),
                "",
            ]
    return "\n".join(lines)


def plot_table6(results: dict, path: Path) -> bool:
    """Figure 12: FID against DDIM steps, one line per corpus; False when there is nothing to plot."""
    series = {c: t for c, t in results["table6"].items() if t and any(r["fid"] is not None for r in t.values())}
    if not series:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for corpus, t in series.items():
        steps = [int(st) for st in t]
        ax.plot(steps, [t[str(st)]["fid"] for st in steps], marker="o", label=f"BMM ({corpus})")
    ax.set_xscale("log")
    ticks = sorted({int(st) for t in series.values() for st in t})
    ax.set_xticks(ticks, [str(t) for t in ticks])
    ax.minorticks_off()
    ax.set_xlabel("DDIM steps")
    ax.set_ylabel("FID (our extractor) ↓")
    ax.set_title("FID against inference steps (Figure 12 analogue)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    started = time.perf_counter()
    features = Path(args.features).expanduser() if args.features else runs_dir("motion_features_lafan1_bandai_namco", "model")
    extractor, extractor_missing = None, None
    if (features / "config.json").exists():
        extractor = load_motion_features(features)
    else:
        extractor_missing = not_there(features, "motion feature extractor", TRAIN_COMMANDS["features"])
    table: dict = {}
    extra: dict = {"table6": {}, "info": {}, "features": str(features)}
    for name in args.corpora:
        r = evaluate_corpus(args, name, extractor, extractor_missing)
        table[name], extra["table6"][name], extra["info"][name] = r["rows"], r["table6"], r["info"]
    extra["settings"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(args).items()}
    extra["seconds"] = time.perf_counter() - started
    # The results' layout: {corpus: {row: {metric: value}}}, what else beside it.
    results = {**table, **extra}
    png = Path(args.out).with_suffix(".png")
    report = format_report(args, table, extra)
    if plot_table6(results, png):
        report += f"\nFigure 12 analogue: {png.name}"
    write_results(args.out, results, report)
    return results


if __name__ == "__main__":
    main()
