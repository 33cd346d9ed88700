"""The whole pipeline on one corpus, every IK on the same curves.

    python experiments/pipeline_eval.py --corpus bandai_namco --windows 100 --out results/pipeline_eval_bn.json
    python experiments/pipeline_eval.py --corpus bandai_namco --bvh-dir my_clips/ --ik exact --out mine.json
    python experiments/pipeline_eval.py --corpus lafan1 --out lafan1.json   # LaFAN1's registered models, trained here
    python experiments/pipeline_eval.py --corpus lafan1 --bmm runs/bmm/model --ik-model runs/ik/model --out lafan1.json
    python experiments/pipeline_eval.py --corpus bandai_namco --windows 20 --segments 3 --ik exact --out chains.json
    python experiments/pipeline_eval.py --corpus bandai_namco --ik refined exact --foot-lock --out locked.json   # feet locked first
    python experiments/pipeline_eval.py --corpus lafan1 --bmm bandai_namco --out transferred.json   # another skeleton's BMM

**Windows.** The validation split of the corpus (Bandai-Namco: every 10th take; LaFAN1:
subject 5), or with ``--bvh-dir`` every ``*.bvh`` of a folder of the corpus's skeleton (a
user's own clips; all of them are evaluated). Windows and handles are
:func:`~bezmotion.evaluation.curves.make_eval_set`'s draws with ``per_window=True`` (key
``--seed``): the windows are a prefix of one fixed permutation and each window's 1–4
handles and OOD noise (±16 cm per axis) come from ``fold_in(key, window row)``, so a
window's handles depend on the window alone and the first ``n`` windows of a larger run
are an ``n``-window run. ``--handle-frames`` puts handles on control frames (``grid``,
the paper), between them (``off_grid``) or on any intermediate frame (``any``).

**Another skeleton's BMM.** The six joints' curves do not name a skeleton, so a BMM trained
on one drives any other: ``--bmm`` of another skeleton than ``--corpus`` (a registered
model's own, or ``--trained-on NAME|PROFILE.json`` for a saved folder) has its curves moved
to the corpus's skeleton by :class:`~bezmotion.pipeline.transfer.Transfer` (the ratio of
the bundled profiles' heights, the six joints' mean orientation offsets), conditioned in its
own space and hit exactly in the corpus's, as ``bezmotion inbetween`` does for a clip of
another skeleton. The settings record ``bmm_trained_on`` and the ``transfer``.

**Curves once.** Each window's BMM curves are sampled once (``--steps`` DDIM steps, key
``fold_in(--sample-seed, window row)``, in distribution and OOD) and every IK of ``--ik``
runs on those same dense trajectories, the start and end poses blended in over
``--key-blend`` frames. ``learned``: the bundled / given learned IK; ``refined``: it plus
the rig's exact two-bone limbs; ``rig``: the analytic rig alone, resting in each window's
start key (its bind pose: the joints it does not solve, where its spine and twists start,
which way the knees bend), as ``bezmotion inbetween`` gives it the take's; ``exact``: the learned
IK then the exact damped least-squares stage (:mod:`bezmotion.ik.exact`) with the joint
limits stored beside the IK model, told the keys (it starts from poses joined to them
and holds the frames next to them) and the handles (pinned: hit first where the targets
conflict); ``exact_refined``: the same on top of ``refined``; ``exact_rig``: the same on
top of the rig (``bezmotion inbetween``'s choice for a skeleton no learned IK knows;
``--no-limits`` measures it as it runs there).
``--exact NAME=VALUE`` (repeatable) sets an :class:`~bezmotion.ik.exact.ExactIKParams`
field of every exact IK, e.g. ``--exact iterations=20 --exact hips_position_scale=0.3``.

**Chained segments.** ``--segments K`` (K > 1) evaluates chains instead of windows: K
windows of one clip, each starting 30 frames after the previous, so consecutive windows
share a key and a chain covers ``30·K + 1`` frames
(:func:`~bezmotion.evaluation.pipeline.chain_rows`; ``--windows`` then counts chains, a
prefix of one permutation of every chain, key ``--seed``). Each window keeps the handles
and OOD noise it has in a single-window run (``make_eval_set(rows=…)``), moved into the
chain's frame; the keys are the mocap's poses at frames 0, 30, …, 30·K. The curves are
sampled once per chain (:func:`~bezmotion.evaluation.pipeline.sample_chain_curves`, one
``sample_chained_curves`` call, key ``fold_in(--sample-seed, first window's row)``),
coupled C¹ at the shared keys, and every IK runs once over the chain's joined frames, each
window blended to its two keys (:func:`~bezmotion.pipeline.inbetweening.pose_from_curves`,
as :func:`~bezmotion.pipeline.inbetweening.inbetween` does); ``--chunk`` windows per
call become ``--chunk // K`` chains (at least one). The same curves are also sampled
independently (BMM Appendix D.1, same noise) for the velocity jump at the shared keys
(:func:`~bezmotion.evaluation.metrics.chain_velocity_jumps`, six joints, cm/frame), beside the mocap's
own frame-to-frame change over the same chains (as ``experiments/chained_segments.py``)
and the jump of the mocap's own per-window curve fits there, joined as they are and coupled
as the sampler couples (``mocap_fits``: what a model that drew each window's training
curve exactly would give).
Every metric below is then taken over the chains' frames (see ``segments.metrics`` in the
JSON); ``--segments 1`` (the default) is the single-window evaluation. ``--key-velocities``
gives the curves the mocap's velocities at the keys (windows: frames 0→1 and 29→30; chains:
:func:`~bezmotion.pipeline.inbetweening.chain_key_velocities`, the central difference at a
shared key, which both its windows take).

**Metrics.** Per IK, in distribution (``id``) and OOD (``ood``):

- ``handles_error_cm`` / ``handles_error_max_cm``: mean / largest distance between a
  handle and the IK'd skeleton's joint at its frame;
- ``handles_missed_fraction``: handles farther than 1 cm from their joint after IK;
- ``unreachable_fraction``: handles out of the limb's reach: farther from the root of
  their chain in the IK'd pose at that frame (the upper arm for a hand, the upper leg
  for a foot, the hips for the head) than the chain's length stretched out (sum of its
  bones) plus 1 cm; and handles missed by more than 1 cm on a frame whose other handle
  lies farther from them than the skeleton reaches between the two joints (the bones on
  its path between them, plus 1 cm: no pose meets both). Such handles are missed
  by more than 1 cm whatever the limb does, so they are a subset of the missed ones; the rest
  (``handles_missed_fraction − unreachable_fraction``) are misses the limb could have
  avoided. (The 1 cm keeps handles at full extension, an arm hanging straight, from
  counting: the mocap's own lie within millimetres of the chain's length.)
- ``curve_error_cm`` / ``curve_error_max_cm``: how far the IK'd six joints lie from the
  curves they were given, on every frame (mean over frames, joints and windows; largest):
  an IK may hit the handles and still leave the curves elsewhere (e.g. next to the keys);
- ``planted_foot_rise_cm`` / ``planted_foot_sink_cm`` (each with ``…_max_cm``): per window,
  how far the IK'd feet rise above / sink below their curves at most where a curve's foot
  stands still (slower than 7.5 cm/s horizontally), mean over windows and largest: a foot
  the body pulls out of reach either rises (a heel lifting) or slides, and one that sinks
  goes through the floor;
- ``mpjpe_cm`` (every joint and frame against the mocap window), ``foot_skating_ratio``;
- ``foot_sliding_ratio``: the same skating test with the *curves'* feet deciding which frames
  are on the floor (the speeds the IK'd feet's), so every IK on the same curves is judged on
  the same frames: a foot that slides while lifted off its curve above the test's 5 cm counts
  here and escapes ``foot_skating_ratio`` (the paper's);
- ``key_pop_deg``: the largest per-frame joint rotation change at frames 0→1 and 29→30
  (chains: of every window, so both sides of every key);
- ``rotation_change_deg``: per frame pair, the largest joint rotation change, averaged over
  frames and windows (jitter: the mocap's own is beside it), and ``max_rotation_change_deg``
  the largest anywhere;
- ``ik_ms_per_window``: steady-state IK time per window (the compiled IK, every call
  waited for, ``--chunk`` windows per call, padding of the last chunk counted), beside
  ``compile_s`` once per IK (the warm-up call that compiles it, in distribution; the OOD
  run reuses the compilation). Chains: ``ik_ms_per_chain`` instead (one IK per chain).

``curves``: the curves before IK, ``bmm`` (the sampled curves given to every IK) and
``reference`` (interpolation through the same start, end and handles,
:func:`~bezmotion.evaluation.curves.reference_curves`), each ``id`` / ``ood`` with
``handles_error_cm`` (≈ 0: the curves pass through every handle), ``dense_error_cm`` and
per joint, ``foot_skating_ratio``, and for the BMM the orientation error (degrees between
the curves' and the mocap's global orientation of each joint, mean and per joint).
Every mean over windows (``dense_error_cm``, ``curve_error_cm``, ``mpjpe_cm``,
``foot_skating_ratio``) has its standard error over the windows beside it (``…_se``;
:func:`~bezmotion.evaluation.window_figures.standard_error`), so two runs can be told apart from
the windows' own spread: the report prints them as ``mean ± se``.
``mocap``: the mocap's own foot skating, key pop and largest per-frame rotation change.
``labels``: the same figures per content / action label (Bandai-Namco ``content``; LaFAN1
the file's sequence without its number, ``walk4`` → ``walk``; a folder, the file stem
without trailing digits).

**JSON**::

    {"windows": n, "corpus": …, "settings": {…}, "seconds": …,
     "ik": {"<ik>": {"compile_s": …, "id": {<after-IK metrics>}, "ood": {…}}, …},
     "curves": {"bmm": {"id": {…}, "ood": {…}}, "reference": {"id": {…}, "ood": {…}}},
     "mocap": {…},
     "paired": {"<b> minus <a>": {"id": {<figure>: {mean, se, median, better_fraction, windows}}, "ood": {…}}, …},
     "labels": {"<label>": {"windows": k, "ik": {"<ik>": {"id", "ood"}}, "curves": {…}, "mocap": {…}, "paired": {…}}}}

``paired``: for every two IKs ``a`` before ``b`` in ``--ik``, b minus a window by window on
the same curves (:func:`~bezmotion.evaluation.window_figures.paired_differences`: ``mpjpe_cm``,
``foot_skating_ratio``, ``foot_sliding_ratio``, ``curve_error_cm``). The windows' figures move together between two
IKs, so the difference's standard error is much smaller than either mean's: this, not two
means ± their own se, tells whether one IK beats another. Every per-window figure the
summaries come from is also saved beside the JSON, ``FILE.windows.npz`` (``np.load``:
``ik/<ik>/<id|ood>/<figure>``, ``curves/<kind>/<id|ood>/<figure>``, ``mocap/<figure>``,
``labels``, ``rows``).

With ``--segments K`` (K > 1) ``windows`` is chains × K, ``curves`` also holds
``bmm_independent``, each label also ``chains``, and beside them::

    "segments": {"k": K, "chains": n, "frames_per_chain": 30·K + 1, "key_frames": […],
      "boundary_velocity_jump_cm_per_frame": {"coupled": {mean, p95, max, count, minus_mocap: {mean, se, chains}}, "independent": {…},
        "coupled_other_frames": {…}, "coupled_inner_control_frames": {…}, "mocap": {…}, "mocap_at_shared_keys": {…},
        "mocap_fits": {"independent": {…}, "coupled": {…}},
        "ood": {"coupled", "coupled_other_frames", "coupled_inner_control_frames", "independent"},
        "after_ik": {"<ik>": {"id", "ood"}}, "where": …},
      (``minus_mocap``: the jump at the shared keys minus the mocap's at the same keys and
      joints, its mean and standard error over the chains),
      "metrics": {<how each figure is taken over a chain>}, "not_computed": {<figure>: why}}

With a single ``--ik`` its ``id`` and ``ood`` also sit at the top level
(``{"windows": n, "id": {…}, "ood": {…}, "curves": …}``). A Markdown report is written
beside the JSON.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bezmotion.assets.registry import REGISTRY, resolve_folder
from bezmotion.bezier import BezierLayout
from bezmotion.evaluation.curves import EvalSet, dense_positions, floor_height_from, make_eval_set, reference_curves
from bezmotion.bmm.features import HANDLE_FRAMES
from bezmotion.evaluation.baselines import OFF_GRID_REFERENCES
from bezmotion.bmm.sampling import Handles, load_model, share_boundaries, with_off_grid_prior
from bezmotion.data.corpus import Corpus, motion_clips
from bezmotion.data.curves import CurveDataset, curve_dataset
from bezmotion.data.resample import TRAINED_FPS
from bezmotion.data.sources import load_corpus
from bezmotion.ik.exact import exact_ik, exact_settings
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protocol import Character, Pose, targets_from_pose
from bezmotion.ik.protores import load_ik_model, protores_ik_fn, protores_refined_ik_fn
from bezmotion.ik.rig import make_rig, rig_ik
from bezmotion._src.io import atomic_path, write_results
from bezmotion.evaluation.metrics import chain_velocity_jumps, distribution_summary
from bezmotion._src.options import option, options, parse_options
from bezmotion.evaluation.pipeline import (
    chain_frame_handles,
    chain_rows,
    sample_chain_curves,
    sample_window_curves,
    solve_chain_curves,
    solve_window_curves,
    window_keys,
    window_poses,
    window_shifts,
)
from bezmotion.evaluation.window_figures import (
    PipelineMetricsConfig,
    paired_differences,
    reach_chains,
    standard_error,
    summarize_windows,
    window_curve_metrics,
    window_mocap_metrics,
    window_pose_metrics,
)
from bezmotion.data.windows import join_windows
from bezmotion.pipeline.inbetweening import KEY_BLEND_FRAMES, WindowCurves
from bezmotion.pipeline.authoring import FACING_CHOICES, load_profile, make_transfer
from bezmotion.pipeline.transfer import ORIENTATION_CHOICES, Transfer
from _common import window_labels

CORPORA = ("bandai_namco", "lafan1")
IKS = ("learned", "refined", "rig", "exact", "exact_refined", "exact_rig")
CONDITIONS = ("id", "ood")


@options
class Options:
    out: str = option(help="output JSON (a .md report is written beside it)")
    corpus: str = option("bandai_namco", choices=CORPORA, help="the skeleton (and, without --bvh-dir, the validation split)")
    bvh_dir: str | None = option(None, help="evaluate every .bvh in this folder (the corpus's skeleton) instead of the validation split")
    bmm: str = option(
        "bundled", help="a saved BMM folder or a registered model's name (`bezmotion models`); 'bundled' (default): the corpus's own (LaFAN1's once trained here)"
    )
    facing: str = option(
        "trained", choices=FACING_CHOICES,
        help="trained (default, as bezmotion inbetween): each window turned to start facing the way the BMM's training motions do; keys: as the keys face (the paper's)",
    )  # fmt: skip
    orientation: str = option(
        "anatomical", choices=ORIENTATION_CHOICES,
        help="how a transfer aligns the joints' orientations: anatomical (each joint against its bones) or facing (its mean against the facing)",
    )  # fmt: skip
    trained_on: str | None = option(
        None, metavar="NAME|PROFILE.json",
        help="the skeleton --bmm was trained on: a profile name (bandai_namco, lafan1) or a profile JSON; default: a "
        "registered model's own, a saved folder's the corpus's; another skeleton's curves are transferred to the corpus's",
    )  # fmt: skip
    ik_model: str = option(
        "bundled", help="a saved learned IK folder or a registered model's name; 'bundled' (default): the corpus's own; 'none': the curves alone, no IK"
    )
    joint_limits: str | None = option(None, help="the exact IK's joint limits JSON (default: joint_limits.json beside the IK model, if any)")
    no_limits: bool = False
    exact: tuple[str, ...] = option(
        (), repeat=True, metavar="NAME=VALUE",
        help="an ExactIKParams setting of the exact IKs (e.g. iterations=12, rotation_weight=5); may repeat",
    )  # fmt: skip
    ik: tuple[str, ...] = option(("learned", "refined", "rig", "exact"), choices=IKS, help="IKs to run on the same curves")
    windows: int = option(100, help="windows, or with --segments K > 1 chains (0 = all)")
    handle_frames: str = option("grid", choices=HANDLE_FRAMES, help="handles on control frames, between them, or any frame")
    off_grid_prior: str | None = option(
        None, choices=OFF_GRID_REFERENCES,
        help="sample a residual BMM over this reference between control frames (default: the model's own; models saved without off_grid_prior learned over projection)",
    )  # fmt: skip
    segments: int = option(1, help="windows per evaluated chain, keys 30 frames apart (1: single windows)")
    steps: int = option(10, help="DDIM steps")
    key_velocities: bool = option(
        False,
        help="give the curves the keys' velocities too, from the clip (windows: frames 0→1 and 29→30; chains: "
        "the central difference at a shared key)",
    )
    foot_lock: bool = option(
        False, help="lock the curves' feet on their predicted contacts before any IK (sample_curves(foot_lock=True))"
    )
    key_blend: int = option(KEY_BLEND_FRAMES, help="frames over which the start / end poses are blended in (0: replace the two frames)")
    chunk: int = option(10, help="windows per compiled call, chains: chunk // K (large chunks of the exact IK have hung XLA)")
    seed: int = option(1234, help="key of the windows, handles and OOD noise")
    sample_seed: int = option(7, help="key of the BMM sampler (folded with each window's row)")

    def __post_init__(self):
        for what in ("bmm", "ik_model") if self.ik_model != "none" else ("bmm",):
            model_path(self, what)  # raises naming the folder (and the command that trains a registered model)
        if self.bvh_dir is not None and not Path(self.bvh_dir).is_dir():
            raise ValueError(f"--bvh-dir {self.bvh_dir}: not a folder")
        if self.windows < 0 or self.chunk < 1 or self.steps < 1:
            raise ValueError("--windows must be ≥ 0, --chunk and --steps ≥ 1")
        if self.segments < 1:
            raise ValueError(f"--segments {self.segments}: must be ≥ 1 (windows per chain; 1 = single windows)")
        exact_settings(self.exact, "--exact")  # raises on a malformed or unknown setting
        if self.trained_on is not None:
            try:
                load_profile(self.trained_on)
            except ValueError as error:
                raise ValueError(f"--trained-on {self.trained_on}: {error}") from None


def model_path(args: Options, what: str) -> Path:
    """The folder of ``--bmm`` or ``--ik-model``: a saved model's, or a registered model's
    (``bundled``: the one registered under the corpus's name, bundled or trained here)."""
    value, flag, part = getattr(args, what), "--" + what.replace("_", "-"), "bmm" if what == "bmm" else "ik"
    if value == "bundled" and args.corpus not in REGISTRY:
        raise ValueError(f"no registered model for the corpus {args.corpus}: pass {flag} PATH")
    try:
        folder, _ = resolve_folder(args.corpus if value == "bundled" else value, part)
    except FileNotFoundError as error:
        raise ValueError(f"{flag} {value}: {error}") from None
    if not folder.is_dir():
        raise ValueError(f"{flag} {value}: no saved model folder there")
    return folder


def bmm_transfer(args: Options) -> tuple[str, Transfer | None]:
    """``(skeleton, transfer)``: the skeleton ``--bmm`` was trained on (``--trained-on``, else a
    registered model's own, else the corpus's) and the transfer of its curves to the corpus's
    skeleton (:meth:`~bezmotion.pipeline.transfer.Transfer.between` their bundled profiles,
    as ``bezmotion inbetween`` moves a model to a clip of a known skeleton); None for the same."""
    trained_on = args.trained_on
    if trained_on is None:
        entry = REGISTRY.get(args.corpus if args.bmm == "bundled" else args.bmm)  # None: a saved folder
        trained_on = args.corpus if entry is None else entry.skeleton
    source = load_profile(trained_on)
    if trained_on == args.corpus:
        return trained_on, make_transfer(source, None, facing=args.facing)
    return trained_on, make_transfer(source, load_profile(args.corpus), orientation=args.orientation, facing=args.facing)


def open_windows(args: Options, character: Character | None = None) -> tuple[Corpus, CurveDataset]:
    """The corpus (validation split, or a whole BVH folder validating) and its curve dataset;
    ``character``: the IK model's, whose skeleton the corpus must have (None: not checked).

    Raises:
      SystemExit: one line naming ``--bvh-dir`` (or the corpus) for a folder that cannot be
        read (a malformed BVH: its file and line), whose skeleton is not ``character``'s, or
        that holds no whole window.
    """
    source = f"--bvh-dir {args.bvh_dir}" if args.bvh_dir else args.corpus
    try:
        if args.bvh_dir is None:
            corpus = load_corpus(args.corpus, progress=False)
        else:  # every file validates
            # At the models' rate, as bezmotion inbetween takes a clip (a 120 fps window of 31 frames is a quarter second).
            corpus = load_corpus(args.bvh_dir, characteristic=args.corpus, validation_every=1, fps=TRAINED_FPS, progress=False)
        if character is not None and (corpus.skeleton.names, corpus.skeleton.parents) != (character.skeleton.names, character.skeleton.parents):
            raise ValueError(f"its skeleton is not the IK model's ({character.name}); use clips of the {args.corpus} skeleton")
        dataset = curve_dataset(corpus, "validation", progress=False)
        if len(dataset.ctrl_pos) == 0:
            raise ValueError(f"no {dataset.layout.num_frames}-frame window in its clips")
    except (OSError, ValueError) as error:
        raise SystemExit(f"pipeline_eval.py: error: {source}: {' '.join(str(error).split())}") from None
    return corpus, dataset


def build_iks(args: Options, ik_model, rig) -> tuple[dict[str, tuple], bool]:
    """The IKs of ``--ik`` as ``{name: (ik_fn, params)}``, and whether the exact IK has joint limits."""
    character = ik_model.character
    limits = None
    if not args.no_limits:
        path = Path(args.joint_limits) if args.joint_limits else model_path(args, "ik_model") / "joint_limits.json"
        if path.exists():
            limits = JointLimits.load(path, character)
        elif args.joint_limits:
            raise FileNotFoundError(f"--joint-limits {path}: no such file")
    settings = exact_settings(args.exact)
    makers = {
        "learned": lambda: (protores_ik_fn, ik_model),
        "refined": lambda: (protores_refined_ik_fn, (ik_model, rig)),
        "rig": lambda: (rig_ik, rig),
        "exact": lambda: exact_ik(protores_ik_fn, ik_model, character, limits=limits, **settings),
        "exact_refined": lambda: exact_ik(protores_refined_ik_fn, (ik_model, rig), character, limits=limits, **settings),
        "exact_rig": lambda: exact_ik(rig_ik, rig, character, limits=limits, **settings),
    }
    return {name: makers[name]() for name in dict.fromkeys(args.ik)}, limits is not None


def by_label(per_window: dict, labels: np.ndarray) -> dict[str, dict]:
    return {label: summarize_windows(per_window, labels == label) for label in sorted(set(labels))}


class Items(NamedTuple):
    """What is evaluated: single windows (``--segments 1``) or chains of ``--segments`` K windows.

    Attributes:
      rows: ``(items,)`` the windows' dataset rows, or ``(items, K)`` each chain's windows'.
      eval_set: handles and OOD noise of every window (chains: ``items·K`` windows, chain by
        chain), at window frames, in each window's own aligned frame.
      truth: ``(items, frames, …)`` the mocap (31 frames, or a chain's ``30·K + 1``),
        aligned like the item's first window.
      handles: per condition, the handles the curves are sampled through: ``(items,
        handles)``, or ``(items, K, handles)`` moved into the chain's frame.
      metric_handles: per condition, the same handles at the item's frames: ``(items,
        handles)``, or ``(items, K·handles)`` at chain frames.
      shifts: chains only, ``(items, K, 3)`` cm: where each window starts in its chain's frame.
    """

    rows: np.ndarray
    eval_set: EvalSet
    truth: Pose
    handles: dict[str, Handles]
    metric_handles: dict[str, Handles]
    shifts: jax.Array | None


def draw_items(args: Options, dataset: CurveDataset, clips, character) -> Items:
    """The windows, or the chains, and their handles (key ``--seed``)."""
    key = jax.random.key(args.seed)
    if args.segments == 1:
        eval_set = make_eval_set(
            dataset, key=key, num_windows=args.windows or None, handle_frames=args.handle_frames, per_window=True
        )
        handles = {"id": eval_set.handles, "ood": eval_set.handles_ood}
        return Items(eval_set.rows, eval_set, window_poses(character, clips, dataset, eval_set.rows), handles, handles, None)
    k, frames = args.segments, dataset.layout.num_frames
    candidates = chain_rows(dataset, k)  # raises when no clip holds a chain
    order = np.asarray(jax.random.permutation(jax.random.fold_in(key, k), len(candidates)))[: args.windows or None]
    rows = candidates[order]
    # Each window's own handles and noise (those of a single-window run), then in its chain's frame.
    eval_set = make_eval_set(dataset, key=key, handle_frames=args.handle_frames, per_window=True, rows=rows.ravel())
    truth = window_poses(character, clips, dataset, rows[:, 0], frames=k * (frames - 1) + 1)
    shifts = window_shifts(character, truth, k)

    def moved(h: Handles) -> Handles:  # (items·K, handles) → (items, K, handles), chain frame
        h = jax.tree.map(lambda a: a.reshape(len(rows), k, *a.shape[1:]), h)
        return h._replace(position=h.position + shifts[:, :, None, :])

    handles = {"id": moved(eval_set.handles), "ood": moved(eval_set.handles_ood)}
    at_frames = {cond: chain_frame_handles(h, frames) for cond, h in handles.items()}
    return Items(rows, eval_set, truth, handles, at_frames, shifts)


def chain_chunk(args: Options) -> int:
    """Chains per compiled call: about ``--chunk`` windows' worth, at least one chain."""
    return max(1, args.chunk // args.segments)


def sample_items(
    args: Options, bmm, character, items: Items, cond: str, keys: jax.Array, transfer: Transfer | None, coupled: bool = True
) -> WindowCurves:
    """The curves of every item, sampled once (chains: ``(items, K, …)`` per window), moved
    to the corpus's skeleton by ``transfer`` (:func:`bmm_transfer`) where the BMM's is another."""
    if args.segments == 1:
        return sample_window_curves(
            bmm, character, items.truth, items.handles[cond], keys, transfer=transfer,
            steps=args.steps, with_key_velocities=args.key_velocities, chunk=args.chunk, foot_lock=sampler_foot_lock(args),
        )  # fmt: skip
    return sample_chain_curves(
        bmm, character, items.truth, items.handles[cond], keys, transfer=transfer,
        coupled=coupled, steps=args.steps, chunk=chain_chunk(args), foot_lock=sampler_foot_lock(args),
        with_key_velocities=args.key_velocities,
    )  # fmt: skip


def sampler_foot_lock(args: Options) -> bool:
    """The samplers' ``foot_lock``."""
    return args.foot_lock


def joined(args: Options, curves: WindowCurves) -> WindowCurves:
    """Dense trajectories at the items' frames: a chain's windows joined, each shared key once."""
    if args.segments == 1:
        return curves
    return curves._replace(positions=jax.vmap(join_windows)(curves.positions), rot6d=jax.vmap(join_windows)(curves.rot6d))


def solve_items(args: Options, fn, params, curves: WindowCurves, truth: Pose, handles: Handles):
    """Every IK'd item ``(items, frames, …)`` and its timing (chains: one IK per chain);
    ``handles``: the curves' (``Items.handles``), pinned for the IK; a rig (``rig``,
    ``exact_rig``) rests in each item's start key."""
    if args.segments == 1:
        solve, chunk = solve_window_curves, args.chunk
    else:
        solve, chunk = solve_chain_curves, chain_chunk(args)
    return solve(fn, params, curves, truth, handles=handles, key_blend_frames=args.key_blend, chunk=chunk, rest_from_keys=True)


def reference_positions(items: Items, cond: str, layout) -> jax.Array:
    """The reference's dense positions ``(items, frames, 6, 3)`` (chains: its windows joined)."""
    handles = items.eval_set.handles if cond == "id" else items.eval_set.handles_ood
    ref = reference_curves(items.eval_set, handles, layout)
    positions = dense_positions(layout, ref.ctrl_pos, ref.ctrl_tangent)
    if items.shifts is None:
        return positions
    n, k = items.shifts.shape[:2]
    per_window = positions.reshape(n, k, *positions.shape[1:]) + items.shifts[:, :, None, None, :]
    return jax.vmap(join_windows)(per_window)


def jumps_at_keys(positions: jax.Array, k: int, mocap_at_keys: np.ndarray) -> dict:
    """Velocity jump summary (cm/frame) of ``(chains, frames, 6, 3)`` at the shared keys,
    with its excess over the mocap's jumps there (``mocap_at_keys``:
    ``chain_velocity_jumps(mocap, k).at_shared_keys``; :func:`summarize_jumps_at_keys`)."""
    return summarize_jumps_at_keys(chain_velocity_jumps(positions, k).at_shared_keys, mocap_at_keys)


def summarize_jumps_at_keys(at_keys: jax.Array, mocap_at_keys: np.ndarray) -> dict:
    """:func:`~bezmotion.evaluation.metrics.distribution_summary` of the jumps at the shared keys
    ``(chains, keys − 1, 6)`` (cm/frame), and ``minus_mocap``: the jumps minus the mocap's at
    the same keys and joints, its mean and the mean's standard error over the chains (each
    chain's mean one sample). A pairwise difference: the chains' own spread (some motions
    jerk more than others) cancels, which the two means' separate spreads do not."""
    diff = np.asarray(at_keys, np.float64) - np.asarray(mocap_at_keys, np.float64)
    excess = {"mean": float(diff.mean()), "se": standard_error(diff), "chains": int(diff.shape[0])}
    return {**distribution_summary(at_keys), "minus_mocap": excess}


def coupled_jumps(positions: jax.Array, k: int, layout: BezierLayout, mocap_at_keys: np.ndarray) -> dict:
    """Velocity jump summaries (cm/frame) of coupled chains ``(chains, frames, 6, 3)``: at the
    shared keys (with the excess over the mocap's there, ``mocap_at_keys``), at every other inner frame, and
    at the control frames inside each of the ``k`` windows (``layout``'s, keys excluded: C¹
    joins like the keys)."""
    jumps = chain_velocity_jumps(positions, k)
    step = layout.num_frames - 1
    inner = np.concatenate([w * step + layout.control_frames[1:-1] for w in range(k)])
    return {
        "coupled": summarize_jumps_at_keys(jumps.at_shared_keys, mocap_at_keys),
        "coupled_other_frames": distribution_summary(jumps.other_frames),
        "coupled_inner_control_frames": distribution_summary(jumps.all_frames[..., inner - 1, :]),
    }


def mocap_fit_jumps(ctrl_pos: jax.Array, ctrl_tangent: jax.Array, layout: BezierLayout, mocap_at_keys: np.ndarray) -> dict:
    """Velocity jump summaries (cm/frame) at the shared keys of the mocap's own curves: each
    chain window's training curve (the dataset's fit, ``(chains, k, controls, 6, 3)``, in the
    chain's frame), joined as they are (``independent``: each window's own tangent at a key,
    fitted from its side only) and with each shared key's tangent the mean of its two windows'
    (``coupled``: the sampler's coupling, :func:`~bezmotion.bmm.sampling.share_boundaries`).
    ``coupled`` is what a BMM that drew every window's training curve exactly would give
    (smoother curves give less)."""

    def at_keys(tangent: jax.Array) -> dict:
        positions = jax.vmap(join_windows)(dense_positions(layout, ctrl_pos, tangent))
        return jumps_at_keys(positions, ctrl_pos.shape[1], mocap_at_keys)

    return {"independent": at_keys(ctrl_tangent), "coupled": at_keys(jax.vmap(share_boundaries)(ctrl_tangent))}


CHAIN_METRICS = {
    "handles_error_cm": "every window's handles, at their chain frames, against the IK'd chain",
    "mpjpe_cm": "every joint and frame of the chain (each shared key once) against the mocap",
    "foot_skating_ratio": "over each chain's frames",
    "foot_sliding_ratio": "over each chain's frames, on the joined curves' floor contacts",
    "key_pop_deg": "largest per-frame rotation change at each window's first and last frame pair: both sides of every key",
    "max_rotation_change_deg": "over each chain's frames",
    "rotation_change_deg": "each frame pair's largest joint turn, averaged over each chain's frames",
    "dense_error_cm": "the curves' windows joined, every chain frame",
    "ik_ms_per_chain": "steady-state IK time per chain (one IK over its joined frames), --chunk // K chains per call",
}
CHAIN_NOT_COMPUTED = {
    "ik_ms_per_window": "the IK runs once over each chain's joined frames, not per window: see ik_ms_per_chain",
    "independent_after_ik": "the independent windows (curves.bmm_independent) are sampled for the velocity jump only, not IK'd",
}


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    started = time.perf_counter()
    bmm = load_model(model_path(args, "bmm"))
    if args.off_grid_prior is not None:
        bmm = with_off_grid_prior(bmm, args.off_grid_prior)
    trained_on, transfer = bmm_transfer(args)
    if args.ik_model == "none":  # the curves alone: no learned IK needed, the corpus's own skeleton
        ik_model = None
        corpus, dataset = open_windows(args)
        character = Character.from_skeleton(corpus.skeleton, args.corpus)
    else:
        ik_model = load_ik_model(model_path(args, "ik_model"))
        character = ik_model.character
        corpus, dataset = open_windows(args, character)
    clips = motion_clips(corpus, "validation")
    items = draw_items(args, dataset, clips, character)
    k, truth = args.segments, items.truth
    first_rows = items.rows if k == 1 else items.rows[:, 0]
    labels = window_labels(corpus, dataset, "validation", first_rows)
    n = int(truth.root_pos.shape[0])
    config = PipelineMetricsConfig(dataset.layout.stride, dataset.fps, floor_height_from(dataset))
    # The rig's rest pose (the rotations of the joints it does not solve, clavicles and toes, and
    # where its spine and twists start) is each window's start key (solve_items), as `bezmotion
    # inbetween` gives it the take's; this one only checks the rig and measures its chains.
    rig = make_rig(character, args.corpus, rest_quat_local=np.asarray(truth.quat_local[0, 0]))
    chains = reach_chains(rig)
    iks, limited = build_iks(args, ik_model, rig) if ik_model is not None else ({}, False)
    true_targets = targets_from_pose(character, truth)
    mocap_jumps = chain_velocity_jumps(true_targets.position, k) if k > 1 else None  # every curve's jumps are set beside these
    keys = window_keys(jax.random.key(args.sample_seed), first_rows)
    timing_name = "ik_ms_per_window" if k == 1 else "ik_ms_per_chain"
    what = "windows" if k == 1 else f"chains of {k} windows"

    mocap = window_mocap_metrics(config, character, truth, windows=k)
    curve_windows: dict[str, dict[str, dict]] = {"bmm": {}, "reference": {}}
    ik_windows: dict[str, dict[str, dict]] = {name: {} for name in iks}
    ik_results: dict[str, dict] = {name: {} for name in iks}
    jumps: dict[str, dict] = {cond: {} for cond in CONDITIONS}
    after_ik: dict[str, dict] = {name: {} for name in iks}
    for cond in CONDITIONS:
        t0 = time.perf_counter()
        curves = sample_items(args, bmm, character, items, cond, keys, transfer)
        print(f"{cond}: curves of {n} {what} sampled once ({time.perf_counter() - t0:.0f} s)", flush=True)
        dense = joined(args, curves)
        curve_windows["bmm"][cond] = window_curve_metrics(
            config, dense.positions, items.metric_handles[cond], true_targets.position, dense.rot6d, true_targets.rot6d
        )
        ref_positions = reference_positions(items, cond, dataset.layout)
        curve_windows["reference"][cond] = window_curve_metrics(config, ref_positions, items.metric_handles[cond], true_targets.position)
        if k > 1:  # the same windows sampled independently (same noise), for the jump at the shared keys
            independent = joined(args, sample_items(args, bmm, character, items, cond, keys, transfer, coupled=False))
            curve_windows.setdefault("bmm_independent", {})[cond] = window_curve_metrics(
                config, independent.positions, items.metric_handles[cond], true_targets.position, independent.rot6d, true_targets.rot6d
            )
            # The coupled curves between the keys too: is a shared key rougher than the rest of
            # the motion, and than the joins inside a window?
            jumps[cond] = {
                **coupled_jumps(dense.positions, k, dataset.layout, mocap_jumps.at_shared_keys),
                "independent": jumps_at_keys(independent.positions, k, mocap_jumps.at_shared_keys),
            }
            print(f"{cond}: velocity jump at the shared keys {jumps[cond]}", flush=True)
        for name, (fn, params) in iks.items():
            pose, timing = solve_items(args, fn, params, curves, truth, items.handles[cond])
            ik_windows[name][cond] = window_pose_metrics(
                config, character, pose, truth, items.metric_handles[cond], chains, windows=k, curves=dense.positions
            )
            summary = summarize_windows(ik_windows[name][cond])
            ik_results[name][cond] = {**summary, timing_name: timing.ms_per_window}
            ik_results[name].setdefault("compile_s", timing.compile_s)  # the OOD run reuses the compilation
            if k > 1:
                after_ik[name][cond] = jumps_at_keys(targets_from_pose(character, pose).position, k, mocap_jumps.at_shared_keys)
            print(f"{cond} {name}: {ik_results[name][cond]} (compile {timing.compile_s:.1f} s)", flush=True)

    results = {
        "windows": n * k,
        "corpus": args.corpus,
        "source": args.bvh_dir or f"{args.corpus} validation",
        "settings": {
            "bmm": str(model_path(args, "bmm")), "ik_model": None if ik_model is None else str(model_path(args, "ik_model")), "joint_limits": limited,
            "bmm_trained_on": trained_on,
            "transfer": None if trained_on == args.corpus else {"scale": float(transfer.scale), "rot_offset": np.asarray(transfer.rot_offset).tolist()},
            "facing": args.facing, "orientation": args.orientation,
            "handle_frames": args.handle_frames, "off_grid_prior": bmm.config.off_grid_prior, "steps": args.steps, "key_blend_frames": args.key_blend,
            "key_velocities": args.key_velocities, "foot_lock": args.foot_lock,
            "chunk": args.chunk, "seed": args.seed, "sample_seed": args.sample_seed, "segments": k,
            "exact": exact_settings(args.exact),
            "rows": np.asarray(items.rows).tolist(),
        },  # fmt: skip
        "ik": {name: {"compile_s": r.pop("compile_s"), **r} for name, r in ik_results.items()},
        "curves": {kind: {cond: summarize_windows(w) for cond, w in conds.items()} for kind, conds in curve_windows.items()},
        "mocap": summarize_windows(mocap),
    }
    if k > 1:
        results["segments"] = {
            "k": k, "chains": n, "frames_per_chain": int(truth.root_pos.shape[1]),
            "key_frames": list(range(0, int(truth.root_pos.shape[1]), dataset.layout.num_frames - 1)),
            "boundary_velocity_jump_cm_per_frame": {
                "where": "‖(p[b+1] − p[b]) − (p[b] − p[b−1])‖ of the six joints: the curves before IK (in distribution) "
                "and the IK'd chains at the K − 1 shared keys; mocap: every inner frame of the same chains",
                "coupled": jumps["id"]["coupled"], "independent": jumps["id"]["independent"],
                "coupled_other_frames": jumps["id"]["coupled_other_frames"],
                "coupled_inner_control_frames": jumps["id"]["coupled_inner_control_frames"],
                "mocap": distribution_summary(mocap_jumps.all_frames),
                "mocap_at_shared_keys": distribution_summary(mocap_jumps.at_shared_keys),
                "mocap_fits": mocap_fit_jumps(
                    jnp.asarray(dataset.ctrl_pos[items.rows]) + items.shifts[:, :, None, None, :],
                    jnp.asarray(dataset.ctrl_tangent[items.rows]), dataset.layout, mocap_jumps.at_shared_keys,
                ),
                "ood": jumps["ood"], "after_ik": after_ik,
            },
            "metrics": CHAIN_METRICS, "not_computed": CHAIN_NOT_COMPUTED,
        }  # fmt: skip
    results["paired"] = {f"{b} minus {a}": {cond: paired_differences(ik_windows[a][cond], ik_windows[b][cond]) for cond in CONDITIONS}
                         for a, b in ik_pairs(iks)}  # fmt: skip
    results["labels"] = {}
    if len(iks) == 1:
        only = next(iter(results["ik"].values()))
        results["id"], results["ood"] = only["id"], only["ood"]
    for label in sorted(set(labels)):
        mask = labels == label
        results["labels"][label] = {
            "windows": int(mask.sum()) * k,
            **({"chains": int(mask.sum())} if k > 1 else {}),
            "ik": {name: {cond: summarize_windows(ik_windows[name][cond], mask) for cond in CONDITIONS} for name in iks},
            "curves": {kind: {cond: summarize_windows(w, mask) for cond, w in conds.items()} for kind, conds in curve_windows.items()},
            "mocap": summarize_windows(mocap, mask),
            "paired": {
                f"{b} minus {a}": {cond: paired_differences(ik_windows[a][cond], ik_windows[b][cond], mask) for cond in CONDITIONS}
                for a, b in ik_pairs(iks)
            },
        }
    results["seconds"] = time.perf_counter() - started
    write_results(args.out, results, format_report(results))
    save_per_window(per_window_path(args.out), labels, items.rows, ik_windows, curve_windows, mocap)
    return results


def ik_pairs(iks) -> list[tuple[str, str]]:
    """Every pair of the evaluated IKs, in ``--ik`` order: ``(a, b)`` is reported as b minus a."""
    names = list(iks)
    return [(a, b) for i, a in enumerate(names) for b in names[i + 1 :]]


def per_window_path(out: str | Path) -> Path:
    """Where the per-window figures of ``--out FILE.json`` go: ``FILE.windows.npz``."""
    return Path(out).with_suffix(".windows.npz")


def save_per_window(path: Path, labels, rows, ik_windows: dict, curve_windows: dict, mocap: dict) -> None:
    """Every per-window figure the summaries were taken from, for analyses of their own
    (``np.load``): ``ik/<ik>/<cond>/<figure>``, ``curves/<kind>/<cond>/<figure>``,
    ``mocap/<figure>``, each ``(windows, …)`` in the order of ``labels`` and ``rows``."""
    arrays = {"labels": np.asarray(labels).astype(str), "rows": np.asarray(rows)}
    for group, tree in (("ik", ik_windows), ("curves", curve_windows)):
        for name, conds in tree.items():
            for cond, figures in conds.items():
                arrays.update({f"{group}/{name}/{cond}/{k}": np.asarray(v) for k, v in figures.items()})
    arrays.update({f"mocap/{k}": np.asarray(v) for k, v in mocap.items()})
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    print(f"wrote {path}")


def transferred(settings: dict) -> str:
    """The report's words for a BMM of another skeleton (``settings["transfer"]``), or none."""
    if not settings.get("transfer"):
        return ""
    return f"the BMM trained on {settings['bmm_trained_on']}, its curves transferred (× {settings['transfer']['scale']:.3f}), "


def format_report(r: dict) -> str:
    s = r["settings"]
    m = r["mocap"]
    seg = r.get("segments")

    def pm(x: dict, key: str, digits: int) -> str:
        """``x[key]`` ± its standard error over the windows (where the summary has one)."""
        se = x.get(f"{key}_se")
        return f"{x[key]:.{digits}f}" + ("" if se is None else f" ± {se:.{digits}f}")

    per, items = ("window", f"{r['windows']} windows") if seg is None else ("chain", f"{seg['chains']} chains of {seg['k']} windows")
    lines = [
        f"Pipeline on {r['source']}: {items}, handles on {s['handle_frames']} frames, {s['steps']} DDIM steps, "
        f"{transferred(s)}"
        f"key blend {s['key_blend_frames']} frames{'; the keys’ velocities given to the curves' if s.get('key_velocities') else ''}"
        f"{'; feet locked on their predicted contacts' if s.get('foot_lock') else ''}"
        f"; the curves sampled once, every IK on the same curves ({r['seconds']:.0f} s).",
        f"Mocap: foot skating {m['foot_skating_ratio']:.4f}, key pop {m['key_pop_deg']:.2f}°, "
        f"largest per-frame change {m['max_rotation_change_deg']:.2f}° (mean of each frame's largest {m['rotation_change_deg']:.2f}°).",
    ]
    if seg is not None:
        jump = seg["boundary_velocity_jump_cm_per_frame"]
        def row(label: str, x: dict) -> str:
            excess = x.get("minus_mocap")
            paired = "" if excess is None else f"{excess['mean']:+.3f}" + ("" if excess["se"] is None else f" ± {excess['se']:.3f}")
            return f"| {label} | {x['mean']:.3f} | {x['p95']:.3f} | {x['max']:.3f} | {x['count']} | {paired} |"

        lines += [
            "",
            f"Chains of {seg['k']} windows ({seg['frames_per_chain']} frames, keys at {seg['key_frames']}); every figure below "
            "over the chains' frames. Velocity jump of the six joints (cm/frame), in distribution:",
            "",
            "| where | mean | p95 | max | values | minus the mocap's at the same keys, mean ± se over chains |",
            "|---|---|---|---|---|---|",
            row("coupled curves, at shared keys", jump["coupled"]),
            row("independent curves (D.1), at shared keys", jump["independent"]),
            *([row("coupled curves, every other frame", jump["coupled_other_frames"])] if "coupled_other_frames" in jump else []),
            *([row("coupled curves, control frames inside the windows", jump["coupled_inner_control_frames"])]
              if "coupled_inner_control_frames" in jump else []),
            *(row(f"after IK ({name}), at shared keys", x["id"]) for name, x in jump["after_ik"].items()),
            row("mocap, all frames", jump["mocap"]),
            row("mocap, at the shared keys", jump["mocap_at_shared_keys"]),
            *([row("mocap's per-window fits (the training curves), at shared keys", jump["mocap_fits"]["independent"]),
               row("the same fits, shared tangents averaged (the sampler's coupling)", jump["mocap_fits"]["coupled"])]
              if "mocap_fits" in jump else []),
        ]
    lines += [
        "",
        f"| IK | handles ID (cm) | OOD (cm) | max ID / OOD (cm) | unreachable ID / OOD | off the curves ID, mean / max (cm) | planted feet OOD, rise / sink (cm) | MPJPE ID (cm) | skating ID | key pop ID / OOD (°) | turn per frame ID, mean / max (°) | IK ms/{per} | compile (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, x in r["ik"].items():
        i, o = x["id"], x["ood"]
        lines.append(
            f"| {name} | {i['handles_error_cm']:.4f} | {o['handles_error_cm']:.4f} | {i['handles_error_max_cm']:.2f} / {o['handles_error_max_cm']:.2f} | "
            f"{i['unreachable_fraction']:.3f} / {o['unreachable_fraction']:.3f} | {i['curve_error_cm']:.3f} / {i['curve_error_max_cm']:.2f} | "
            f"{o['planted_foot_rise_cm']:.2f} / {o['planted_foot_sink_cm']:.2f} | {pm(i, 'mpjpe_cm', 3)} | {pm(i, 'foot_skating_ratio', 4)} | "
            f"{i['key_pop_deg']:.2f} / {o['key_pop_deg']:.2f} | {i['rotation_change_deg']:.2f} / {i['max_rotation_change_deg']:.1f} | "
            f"{i[f'ik_ms_per_{per}']:.1f} | {x['compile_s']:.1f} |"
        )
    lines += [
        "",
        "Curves before IK (six joints):",
        "",
        "| curves | handles ID / OOD (cm) | dense error ID / OOD (cm) | skating ID / OOD | orientation ID / OOD (°) |",
        "|---|---|---|---|---|",
    ]
    for kind, c in r["curves"].items():
        i, o = c["id"], c["ood"]
        orientation = f"{i['orientation_error_deg']:.2f} / {o['orientation_error_deg']:.2f}" if "orientation_error_deg" in i else "–"
        lines.append(
            f"| {kind} | {i['handles_error_cm']:.4f} / {o['handles_error_cm']:.4f} | {pm(i, 'dense_error_cm', 3)} / {pm(o, 'dense_error_cm', 3)} | "
            f"{pm(i, 'foot_skating_ratio', 4)} / {pm(o, 'foot_skating_ratio', 4)} | {orientation} |"
        )
    if r["paired"]:
        def diff(x: dict, digits: int) -> str:
            se = "" if x["se"] is None else f" ± {x['se']:.{digits}f}"
            return f"{x['mean']:+.{digits}f}{se} ({x['better_fraction']:.0%})"

        lines += [
            "",
            f"Paired on the same curves: the second IK minus the first, mean ± se of the per-{per} difference "
            "(in brackets: the share of windows where the second is lower):",
            "",
            "| IKs | MPJPE ID (cm) | OOD (cm) | skating ID | OOD | sliding on the curves' floor contacts ID | OOD | off the curves ID (cm) |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for pair, x in r["paired"].items():
            i, o = x["id"], x["ood"]
            lines.append(
                f"| {pair} | {diff(i['mpjpe_cm'], 3)} | {diff(o['mpjpe_cm'], 3)} | {diff(i['foot_skating_ratio'], 4)} | "
                f"{diff(o['foot_skating_ratio'], 4)} | {diff(i['foot_sliding_ratio'], 4)} | {diff(o['foot_sliding_ratio'], 4)} | "
                f"{diff(i['curve_error_cm'], 3)} |"
            )
    first_ik = next(iter(r["ik"]), None)  # None: the curves alone (--ik-model none)
    lines += [
        "",
        f"Per label (in distribution; after IK: {first_ik}):" if first_ik else "Per label (in distribution; the curves alone):",
        "",
        "| label | windows | BMM dense (cm) | reference dense (cm) | BMM orientation (°) | handles (cm) | MPJPE (cm) | skating | mocap skating |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, x in r["labels"].items():
        b, ref = x["curves"]["bmm"]["id"], x["curves"]["reference"]["id"]
        ik = x["ik"][first_ik]["id"] if first_ik else {"handles_error_cm": b["handles_error_cm"], "mpjpe_cm": float("nan"), "foot_skating_ratio": b["foot_skating_ratio"]}
        lines.append(
            f"| {label} | {x['windows']} | {b['dense_error_cm']:.3f} | {ref['dense_error_cm']:.3f} | {b['orientation_error_deg']:.2f} | "
            f"{ik['handles_error_cm']:.4f} | {ik['mpjpe_cm']:.3f} | {ik['foot_skating_ratio']:.4f} | {x['mocap']['foot_skating_ratio']:.4f} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
