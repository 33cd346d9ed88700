"""Metrics of the full pipeline, after IK, on a corpus's validation windows (BMM Table 1).

The evaluation windows are those of :func:`bezmotion.evaluation.curves.make_eval_set` (same
handles, same OOD noise); here each window also carries the ground-truth full-body poses
of the target character, so the start and end poses are real and MPJPE can be measured.
Everything is in the windows' aligned frame (hips start at the origin in XZ).

Two ways to run it: :func:`evaluate_pipeline` in-betweens each window end to end per IK
(:func:`run_pipeline`); :func:`sample_window_curves` samples each window's curves once and
:func:`solve_window_curves` runs any number of IKs on those same curves (timed), whose
per-window figures :mod:`bezmotion.evaluation.window_figures` measures and summarises over
all windows or any subset (e.g. one action label) — ``experiments/pipeline_eval.py``. Chained segments
the same way: :func:`chain_rows` finds runs of windows 30 frames apart,
:func:`sample_chain_curves` samples each chain's windows together (coupled C¹ at the shared
keys, or independent) and :func:`solve_chain_curves` runs an IK over each chain's joined
frames; the ``window_*_metrics`` then take the chains' frames (``windows=`` for the key pop).
"""

from __future__ import annotations

import functools
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bezmotion.evaluation.curves import EvalSet, map_in_chunks
from bezmotion.bmm.sampling import BezierMotionModel, Handles
from bezmotion.data.characteristic import HIPS
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import CurveDataset
from bezmotion.ik.protocol import Character, IKFn, Pose, pose_fk, pose_from_motion, targets_from_pose
from bezmotion.ik.rig import with_rest_pose
from bezmotion.evaluation.metrics import foot_skating_ratio, handles_error, key_pop_deg, mean_position_error, rotation_change_deg
from bezmotion.pipeline.inbetweening import (
    KEY_BLEND_FRAMES,
    InbetweenOptions,
    WindowCurves,
    chain_key_velocities,
    curves_traced,
    pose_from_curves,
)
from bezmotion.pipeline.transfer import Transfer
from bezmotion.evaluation.window_figures import PipelineMetricsConfig


def full_body_handles_error(
    character: Character, pose: Pose, handles: Handles, stride: int
) -> Float[Array, ""]:
    """Mean distance (cm) between each valid handle and the IK'd skeleton's joint at its
    frame (BMM Table 1, measured after IK). ``pose`` is ``(*batch, frames, …)``, handles
    ``(*batch, handles)`` at any frame (``stride`` is no longer needed; kept for callers)."""
    _, pos = pose_fk(character, pose)
    characteristic = pos[..., np.asarray(character.characteristic), :]  # (*batch, frames, 6, 3)
    return handles_error(characteristic, handles)


def mpjpe(character: Character, pose: Pose, true: Pose) -> Float[Array, ""]:
    """Mean per-joint position error (cm) over every joint and frame."""
    return mean_position_error(pose_fk(character, pose)[1], pose_fk(character, true)[1])


def window_poses(
    character: Character, clips: MotionClips, dataset: CurveDataset, rows: np.ndarray, frames: int | None = None
) -> Pose:
    """Ground-truth poses ``(windows, frames, …)`` of dataset windows ``rows``, aligned like
    the dataset (the start hips at the origin in XZ).

    Args:
      clips: the clips ``dataset`` was built from (e.g. :func:`~bezmotion.data.corpus.motion_clips`).
      frames: frames from each window's start (default the window's own; a chain starting
        there, :func:`chain_rows`, ``windows·30 + 1``); they must lie in the window's clip.
    """
    frames = dataset.layout.num_frames if frames is None else frames
    clip = dataset.clip_index[rows]
    first = clips.starts[clip] + dataset.start_frame[rows]
    past = first + frames > clips.starts[clip + 1]
    if past.any():
        r = int(np.asarray(rows)[past][0])
        raise ValueError(
            f"window {r} (clip {dataset.clip_index[r]}, frame {dataset.start_frame[r]}): {frames} frames from its start "
            f"run past its clip's {clips.starts[dataset.clip_index[r] + 1] - clips.starts[dataset.clip_index[r]]} frames"
        )
    index = first[:, None] + np.arange(frames)
    pose = pose_from_motion(
        character, jnp.asarray(clips.quat_local[index], jnp.float32), jnp.asarray(clips.pos_local[index], jnp.float32)
    )
    shift = pose.root_pos[:, :1] * jnp.asarray([1.0, 0.0, 1.0], jnp.float32)
    return pose._replace(root_pos=pose.root_pos - shift)


def pose_metrics(
    config: PipelineMetricsConfig, character: Character, pose: Pose, truth: Pose, handles: Handles
) -> dict[str, float]:
    """Handles error (full skeleton), foot-skating ratio, MPJPE and key pop (largest per-frame
    joint rotation change at the first and last frame pair, degrees) of ``pose`` ``(windows, frames, …)``."""
    _, pos = pose_fk(character, pose)
    _, true_pos = pose_fk(character, truth)
    feet = np.asarray(character.characteristic[4:6])
    return {
        "handles_error_cm": float(full_body_handles_error(character, pose, handles, config.stride)),
        "foot_skating_ratio": float(foot_skating_ratio(pos[..., feet, :], config.fps, floor_height=config.floor_height)),
        "mpjpe_cm": float(mean_position_error(pos, true_pos)),
        "key_pop_deg": float(key_pop_deg(pose.quat_local)),
    }


def ground_truth_pose_metrics(
    config: PipelineMetricsConfig, character: Character, truth: Pose, ik_fn: IKFn | None = None, ik_params: Any = None
) -> dict[str, float]:
    """The mocap's own foot skating; with an IK, also the IK's floor: MPJPE of IK applied to
    the true six-joint trajectories (positions and orientations) of every frame."""
    _, pos = pose_fk(character, truth)
    feet = np.asarray(character.characteristic[4:6])
    out = {
        "foot_skating_ratio": float(foot_skating_ratio(pos[..., feet, :], config.fps, floor_height=config.floor_height)),
        "key_pop_deg": float(key_pop_deg(truth.quat_local)),
        "max_rotation_change_deg": float(jnp.max(rotation_change_deg(truth.quat_local))),
    }
    if ik_fn is not None:
        ik = jax.jit(jax.vmap(jax.vmap(ik_fn, in_axes=(None, 0)), in_axes=(None, 0)))
        recon = map_in_chunks(lambda t, _: ik(ik_params, t), targets_from_pose(character, truth), key=jax.random.key(0))
        _, rpos = pose_fk(character, recon)
        out["ik_of_mocap_mpjpe_cm"] = float(mean_position_error(rpos, pos))
        out["ik_of_mocap_foot_skating_ratio"] = float(
            foot_skating_ratio(rpos[..., feet, :], config.fps, floor_height=config.floor_height)
        )
    return out


@functools.partial(jax.jit, static_argnames=("ik_fn", "options"))
def _run_chunk(bmm, ik_params, character, transfer, inputs, key, *, ik_fn, options) -> Pose:
    """The in-between of a chunk of windows (each a chain of two keys); one compilation per
    IK, options and shapes, shared by every call (evaluate_pipeline's in-distribution and OOD runs)."""
    start, end, handles = inputs

    def run(s, e, h, k):
        keys = jax.tree.map(lambda a, b: jnp.stack([a, b]), s, e)
        h = jax.tree.map(lambda a: a[None], h)  # one window
        windows = curves_traced(bmm, character, keys, h, transfer, k, options)
        return pose_from_curves(
            ik_fn, ik_params, windows, keys, keep_keyframes=True, key_blend_frames=options.key_blend_frames, handles=h
        )

    return jax.vmap(run)(start, end, handles, jax.random.split(key, start.root_pos.shape[0]))


def run_pipeline(
    bmm: BezierMotionModel,
    ik_fn: IKFn,
    ik_params: Any,
    character: Character,
    truth: Pose,
    handles: Handles,
    *,
    key: jax.Array,
    transfer: Transfer | None = None,
    steps: int = 10,
    foot_lock: bool = False,
    chunk: int = 128,
    key_blend_frames: int = KEY_BLEND_FRAMES,
    key_orientations: bool = True,
) -> Pose:
    """In-between every window (start and end from ``truth``) through ``handles``; poses ``(windows, frames, …)``."""
    transfer = Transfer.identity() if transfer is None else transfer
    options = InbetweenOptions(steps=steps, foot_lock=bool(foot_lock), key_blend_frames=key_blend_frames, key_orientations=key_orientations)
    batch = functools.partial(_run_chunk, bmm, ik_params, character, transfer, ik_fn=ik_fn, options=options)
    first = jax.tree.map(lambda x: x[:, 0], truth)
    last = jax.tree.map(lambda x: x[:, -1], truth)
    return map_in_chunks(batch, (first, last, handles), key=key, chunk=chunk)


def evaluate_pipeline(
    config: PipelineMetricsConfig,
    bmm: BezierMotionModel,
    ik_fn: IKFn,
    ik_params: Any,
    character: Character,
    truth: Pose,
    eval_set: EvalSet,
    *,
    key: jax.Array,
    transfer: Transfer | None = None,
    foot_lock: bool = False,
    key_blend_frames: int = KEY_BLEND_FRAMES,
    key_orientations: bool = True,
    chunk: int = 128,
) -> dict[str, dict[str, float]]:
    """After-IK metrics in distribution and OOD (handles with ±16 cm noise), 10 DDIM steps."""
    out = {}
    for name, handles in (("id", eval_set.handles), ("ood", eval_set.handles_ood)):
        pose = run_pipeline(
            bmm, ik_fn, ik_params, character, truth, handles, key=key, transfer=transfer, foot_lock=foot_lock,
            key_blend_frames=key_blend_frames, key_orientations=key_orientations, chunk=chunk,
        )  # fmt: skip
        out[name] = pose_metrics(config, character, pose, truth, handles)
    return out


# ------------------------------------------------------- curves once, every IK on the same curves


def window_keys(key: jax.Array, rows: np.ndarray) -> jax.Array:
    """One sampling key per window, ``fold_in(key, dataset row)``: a window's curves depend
    on the window alone, not on how many windows are evaluated or how they are chunked."""
    return jax.vmap(lambda r: jax.random.fold_in(key, r))(jnp.asarray(rows))


def _chunked(fn, inputs: Any, chunk: int) -> tuple[Any, list[float], int]:
    """``fn(inputs_chunk)`` over the leading axis ``chunk`` rows at a time (the last chunk
    padded by wrapping around, so one compilation serves all); ``(outputs, seconds per
    call, rows run including padding)``. ``fn`` must return arrays ready on return."""
    n = jax.tree.leaves(inputs)[0].shape[0]
    chunk = min(chunk, n)
    parts, seconds = [], []
    for lo in range(0, n, chunk):
        idx = np.arange(lo, lo + chunk) % n
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(jax.tree.map(lambda a: a[idx], inputs)))
        seconds.append(time.perf_counter() - t0)
        parts.append(jax.tree.map(lambda a: np.asarray(a)[: min(chunk, n - lo)], out))
    return jax.tree.map(lambda *xs: jnp.asarray(np.concatenate(xs)), *parts), seconds, chunk * len(seconds)


def window_key_velocities(character: Character, truth: Pose) -> Float[Array, "windows 2 6 3"]:
    """The six joints' velocities at each window's start and end key (cm/frame) from the
    motion itself (a window is a chain of one:
    :func:`~bezmotion.pipeline.inbetweening.chain_key_velocities`, frames 0→1 and 29→30):
    one-sided differences into the window, where a user would take them from the frames
    around the keys. An evaluation that gives them to the curves knows one frame past each
    key: an upper bound on what such context buys."""
    return chain_key_velocities(character, truth, truth.root_pos.shape[-2] - 1)


def sample_window_curves(bmm: BezierMotionModel, character: Character, truth: Pose, handles: Handles, keys: jax.Array, **options) -> WindowCurves:
    """:func:`sample_chain_curves` of single windows, each a chain of one (start and end from
    ``truth`` ``(windows, frames, …)``, handles ``(windows, slots)``, one key per window, e.g.
    :func:`window_keys`; the same ``options``): batched
    :class:`~bezmotion.pipeline.inbetweening.WindowCurves` ``(windows, …)``, which
    :func:`solve_window_curves` hands to any number of IKs."""
    curves = sample_chain_curves(bmm, character, truth, _one_window(handles), keys, coupled=False, **options)
    return jax.tree.map(lambda a: a[:, 0], curves)


def _one_window(handles: Handles | None) -> Handles | None:
    """Each window's handles ``(windows, slots)`` as chains of one window ``(windows, 1, slots)``."""
    return None if handles is None else jax.tree.map(lambda a: a[:, None], handles)


class IKTiming(NamedTuple):
    """How long an IK took on a set of windows.

    Attributes:
      compile_s: the warm-up call before the timed ones: compiling the chunked IK and one call.
      run_s: the compiled calls, each waited for (``block_until_ready``).
      windows_run: windows those calls solved, the last chunk's padding included.
    """

    compile_s: float
    run_s: float
    windows_run: int

    @property
    def ms_per_window(self) -> float:
        """Steady-state IK time per window (ms): compiled calls only, padding counted as work."""
        return 1e3 * self.run_s / max(self.windows_run, 1)


def solve_window_curves(ik_fn: IKFn, ik_params: Any, curves: WindowCurves, truth: Pose, **options) -> tuple[Pose, IKTiming]:
    """:func:`solve_chain_curves` of single windows (curves ``(windows, …)`` of
    :func:`sample_window_curves`, ``handles`` ``(windows, slots)``; the same ``options``):
    ``(poses (windows, frames, …), timing)``."""
    chains = WindowCurves(None, curves.positions[:, None], curves.rot6d[:, None])
    handles = _one_window(options.pop("handles", None))
    return solve_chain_curves(ik_fn, ik_params, chains, truth, handles=handles, **options)


def _timed(run, inputs: Any, chunk: int) -> tuple[Pose, IKTiming]:
    """``run`` over ``inputs`` in chunks (:func:`_chunked`) after one untimed warm-up call."""
    n = jax.tree.leaves(inputs)[0].shape[0]
    chunk = min(chunk, n)
    example = jax.tree.map(lambda a: a[np.arange(chunk)], inputs)
    t0 = time.perf_counter()
    jax.block_until_ready(run(example))  # warm-up: compiles (unless compiled before) and runs once, untimed below
    compile_s = time.perf_counter() - t0
    pose, seconds, windows_run = _chunked(run, inputs, chunk)
    return pose, IKTiming(compile_s, float(sum(seconds)), windows_run)


# ------------------------------------------------------------------------------ chained segments


def chain_rows(dataset: CurveDataset, windows: int) -> np.ndarray:
    """Every chain of ``windows`` dataset windows: runs of windows of one clip, each
    starting ``num_frames − 1`` (30) frames after the previous, so window ``i``'s last frame
    is window ``i + 1``'s first (a shared key) and the chain covers ``windows·30 + 1``
    frames. Chains overlap like the windows do (one per window start).

    Returns:
      ``(chains, windows)`` dataset rows, in the order of their first windows.
    Raises:
      ValueError: ``windows < 1``, or no clip long enough for one chain (names the longest).
    """
    if windows < 1:
        raise ValueError(f"a chain has at least 1 window, got {windows}")
    gap = dataset.layout.num_frames - 1
    row_of = {(int(c), int(f)): r for r, (c, f) in enumerate(zip(dataset.clip_index, dataset.start_frame))}
    chains = [
        [row_of.get((int(c), int(f) + i * gap), -1) for i in range(windows)]
        for c, f in zip(dataset.clip_index, dataset.start_frame)
    ]  # fmt: skip
    chains = np.asarray([c for c in chains if min(c) >= 0], np.int64).reshape(-1, windows)
    if len(chains) == 0:
        covered = int((dataset.start_frame + dataset.layout.num_frames).max(initial=0))
        raise ValueError(
            f"no chain of {windows} windows: it needs {windows * gap + 1} frames of one clip, and the longest "
            f"clip's windows cover {covered}"
        )
    return chains


def window_shifts(character: Character, truth: Pose, windows: int) -> Float[Array, "chains windows 3"]:
    """Where each window of a chain starts, as the dataset aligns it: the chain's hips (X, Z)
    at each window's first frame (cm; height 0), ``truth`` ``(chains, frames, …)`` aligned
    like :func:`window_poses`. Add it to a window's aligned positions (its handles, curves)
    to put them in the chain's frame."""
    hips = targets_from_pose(character, truth).position[..., :-1, HIPS, :]  # (chains, frames − 1, 3)
    starts = hips[:, :: (hips.shape[1] // windows)]
    return starts * jnp.asarray([1.0, 0.0, 1.0], starts.dtype)


def chain_frame_handles(handles: Handles, window_frames: int) -> Handles:
    """Handles of each window, ``(*batch, windows, handles)`` at window frames, → the chain's
    ``(*batch, windows·handles)`` at chain frames (window ``i``'s frame ``f`` is
    ``i·(window_frames − 1) + f``); positions as given."""
    *batch, windows, slots = handles.frame.shape
    frame = handles.frame + (window_frames - 1) * jnp.arange(windows, dtype=handles.frame.dtype)[:, None]
    flat = lambda a: a.reshape(*batch, windows * slots, *a.shape[len(batch) + 2 :])  # noqa: E731
    return Handles(flat(handles.joint), flat(frame), flat(handles.position), flat(handles.valid))


@functools.partial(jax.jit, static_argnames=("options",))
def _chain_curves_chunk(bmm, character, transfer, inputs, *, options) -> WindowCurves:
    keys, handles, rng, velocity = inputs
    return jax.vmap(lambda k, h, r, v: curves_traced(bmm, character, k, h, transfer, r, options, v))(keys, handles, rng, velocity)


def chain_keys(truth: Pose, windows: int) -> Pose:
    """The key poses of chains ``(chains, frames, …)``: ``(chains, windows + 1, …)``, every
    ``(frames − 1) / windows`` frames from the first to the last."""
    step = (truth.root_pos.shape[1] - 1) // windows
    return jax.tree.map(lambda a: a[:, ::step], truth)


def sample_chain_curves(
    bmm: BezierMotionModel,
    character: Character,
    truth: Pose,
    handles: Handles,
    keys: jax.Array,
    *,
    coupled: bool = True,
    transfer: Transfer | None = None,
    steps: int = 10,
    foot_lock: bool = False,
    key_orientations: bool = True,
    chunk: int = 128,
    with_key_velocities: bool = False,
) -> WindowCurves:
    """:func:`sample_window_curves` for chains: the curves stage of every chain
    (:func:`~bezmotion.pipeline.inbetweening.curves_traced`, its windows sampled in
    one :func:`~bezmotion.bmm.sampling.sample_chained_curves` call), ``chunk`` chains per
    compiled call. ``with_key_velocities``: the curves are also given the keys' velocities,
    from the chain's own motion (:func:`~bezmotion.pipeline.inbetweening.chain_key_velocities`).

    Args:
      truth: ``(chains, windows·30 + 1, …)`` poses; the keys are every 30th frame.
      handles: ``(chains, windows, handles)`` at window frames (1 … 29), positions in the
        chain's frame (:func:`window_shifts`).
      keys: one sampling key per chain (e.g. :func:`window_keys` of the first windows).
      coupled: join the windows C¹ at the shared keys, or sample them independently (BMM
        Appendix D.1); with the same ``keys`` both start from the same noise.
    Returns:
      :class:`~bezmotion.pipeline.inbetweening.WindowCurves` batched ``(chains, windows, …)``
      (per window; :func:`~bezmotion.data.windows.join_windows` joins a chain).
    """
    transfer = Transfer.identity() if transfer is None else transfer
    options = InbetweenOptions(steps=steps, foot_lock=bool(foot_lock), key_orientations=key_orientations, coupled=coupled)
    run = functools.partial(_chain_curves_chunk, bmm, character, transfer, options=options)
    windows = handles.frame.shape[1]
    velocity = chain_key_velocities(character, truth, (truth.root_pos.shape[1] - 1) // windows) if with_key_velocities else None
    return _chunked(run, (chain_keys(truth, windows), handles, keys, velocity), chunk)[0]


@functools.partial(jax.jit, static_argnames=("ik_fn", "key_blend_frames", "rest_from_keys"))
def _chain_ik_chunk(ik_params, inputs, *, ik_fn, key_blend_frames, rest_from_keys) -> Pose:
    positions, rot6d, keys, handles = inputs

    def one(p, r, k, h):
        windows = WindowCurves(None, p, r)  # pose_from_curves reads the dense trajectories only
        params = with_rest_pose(ik_params, k.quat_local[0]) if rest_from_keys else ik_params
        return pose_from_curves(ik_fn, params, windows, k, keep_keyframes=True, key_blend_frames=key_blend_frames, handles=h)

    return jax.vmap(one)(positions, rot6d, keys, handles)


def solve_chain_curves(
    ik_fn: IKFn,
    ik_params: Any,
    curves: WindowCurves,
    truth: Pose,
    *,
    handles: Handles | None = None,
    key_blend_frames: int = KEY_BLEND_FRAMES,
    chunk: int = 128,
    rest_from_keys: bool = False,
) -> tuple[Pose, IKTiming]:
    """One IK over each chain's joined frames (curves ``(chains, windows, …)`` of
    :func:`sample_chain_curves`), each window blended to its two keys from ``truth``;
    ``(poses (chains, frames, …), timing)``, the timing per chain (``windows_run`` counts
    chains). ``handles`` ``(chains, windows, handles)`` at window frames, pinned for the IK;
    ``None``: none. ``rest_from_keys``: every :class:`~bezmotion.ik.rig.Rig` in
    ``ik_params`` takes each chain's first key as its rest pose, as ``bezmotion inbetween``
    gives the rig the take's start key; otherwise the rig's own.

    A warm-up call on the first chunk compiles the chunked IK (``compile_s``: compiling and
    one call), so ``run_s`` is its steady-state time."""
    inputs = (curves.positions, curves.rot6d, chain_keys(truth, curves.positions.shape[1]), handles)
    run = functools.partial(_chain_ik_chunk, ik_params, ik_fn=ik_fn, key_blend_frames=key_blend_frames, rest_from_keys=rest_from_keys)
    return _timed(run, inputs, chunk)
