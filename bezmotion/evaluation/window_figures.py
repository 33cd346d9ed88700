"""Per-window figures of in-betweened motion, and their summaries over windows.

Every function takes windows ``(windows, frames, …)`` (or chains of them) and returns one
figure per window, so a run can be summarised over all windows or any subset (one action
label) with its standard error, and two IKs on the same curves can be compared window by
window (:func:`paired_differences`):

- after IK (:func:`window_pose_metrics`): each handle's distance from the IK'd joint and
  whether it was within reach, MPJPE, foot skating, key pop, per-frame joint turns, how far
  the six joints lie from the curves they were given and how far planted feet rise above or
  sink below theirs;
- the curves before IK (:func:`window_curve_metrics`): handles, dense and orientation error
  against the mocap, foot skating;
- the mocap itself (:func:`window_mocap_metrics`): the yardsticks for skating and turns.

:mod:`bezmotion.evaluation.pipeline` runs the pipeline over a corpus's windows and hands
its poses and curves here; ``experiments/pipeline_eval.py`` reports them.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bezmotion.bmm.sampling import Handles
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, FEET
from bezmotion.data.windows import split_windows
from bezmotion.geometry.rotations import quat_angle, quat_from_rot6d
from bezmotion.ik.protocol import Character, Pose, pose_fk
from bezmotion.ik.rig import Rig
from bezmotion.ik.temporal import planted_feet
from bezmotion.evaluation.metrics import foot_skating_ratio, key_pop_deg, rotation_change_deg


@dataclasses.dataclass(frozen=True)
class PipelineMetricsConfig:
    """Settings of the after-IK metrics: the curves' stride, frame rate and the character's
    ankle height with the foot flat (cm; :func:`~bezmotion.evaluation.curves.floor_height_from`)."""

    stride: int
    fps: float
    floor_height: float


# ------------------------------------------------------------------------------ handles after IK


HANDLE_MISS_CM = 1.0
"""A handle farther than this (cm) from its joint after IK counts as missed (``handles_missed_fraction``)."""


class ReachChains(NamedTuple):
    """How far each characteristic joint can be from the root of its chain, and from each other.

    Attributes:
      root: ``(6,)`` the chain root of each characteristic joint (upper arm for the hands,
        upper leg for the feet, the hips for the head); ``-1`` for the hips (the root moves
        freely: never beyond a chain's reach).
      length: ``(6,)`` the chain's length fully stretched, cm (sum of its bones' offsets).
      apart: ``(6, 6)`` the farthest two characteristic joints can lie from each other, cm:
        the bones on the skeleton's path between them. Two handles on one frame farther
        apart than this cannot both be met (:func:`conflicting_handles`).
    """

    root: np.ndarray
    length: np.ndarray
    apart: np.ndarray


def reach_chains(rig: Rig) -> ReachChains:
    """The chains of ``rig``: its limbs (root, middle, end) and its spine (hips → head)."""
    bone = np.linalg.norm(np.asarray(rig.skeleton.offsets, np.float64), axis=-1)
    parents = rig.skeleton.parents
    root = np.full(len(CHARACTERISTIC_JOINTS), -1, np.int64)
    length = np.zeros(len(CHARACTERISTIC_JOINTS))
    chains = {CHARACTERISTIC_JOINTS.index("head"): rig.spine}
    for role, (root_joint, middle, end), (before, after) in zip(("left_hand", "right_hand", "left_foot", "right_foot"), rig.limbs, rig.limb_between):
        chains[CHARACTERISTIC_JOINTS.index(role)] = (root_joint, *before, middle, *after, end)  # twist joints' bones too
    for role, chain in chains.items():
        root[role], length[role] = chain[0], bone[list(chain[1:])].sum()
    ends = [rig.spine[0]] + [chains[role][-1] for role in range(1, len(CHARACTERISTIC_JOINTS))]

    def up(joint: int) -> dict[int, float]:  # each ancestor (and the joint): the bones down to the joint
        out, total = {}, 0.0
        while joint >= 0:
            out[joint], total, joint = total, total + bone[joint], parents[joint]
        return out

    ancestry = [up(j) for j in ends]
    apart = np.asarray([[min(a[j] + b[j] for j in a.keys() & b.keys()) for b in ancestry] for a in ancestry])
    return ReachChains(root, length, apart)


def handle_distances(positions: Float[Array, "*batch frames joints 3"], handles: Handles) -> Float[Array, "*batch handles"]:
    """Distance (cm) of each handle slot from ``positions`` of its joint at its frame (padding
    slots too: mask with ``handles.valid``)."""
    f, j = positions.shape[-3:-1]
    flat = positions.reshape(*positions.shape[:-3], f * j, 3)
    slot = jnp.clip(handles.frame, 0, f - 1) * j + jnp.clip(handles.joint, 0, j - 1)
    picked = jnp.take_along_axis(flat, slot[..., None], axis=-2)
    return jnp.linalg.norm(picked - handles.position, axis=-1)


def _per_window(fn, *x: Array) -> Array:
    return jax.vmap(fn)(*x)


def _skating(config: PipelineMetricsConfig, feet: Array, heights_from: Array | None = None) -> Array:
    """Per window: :func:`~bezmotion.evaluation.metrics.foot_skating_ratio` of ``feet`` ``(windows, frames, 2, 3)``,
    on the floor where ``heights_from``'s feet are (default: their own)."""
    ratio = lambda f, h: foot_skating_ratio(f, config.fps, floor_height=config.floor_height, heights_from=h)  # noqa: E731
    return _per_window(ratio, feet, feet if heights_from is None else heights_from)


def _to_numpy(figures: Mapping[str, Array]) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in figures.items()}


def _key_pop(quat_local: Array, windows: int) -> Array:
    """Key pop of each item ``(items, frames, joints, 4)``; a chain of ``windows`` windows pops
    at each of its windows' first and last frame pairs (both sides of every shared key)."""
    if windows == 1:
        return _per_window(key_pop_deg, quat_local)
    return _per_window(lambda q: key_pop_deg(split_windows(q, windows)), quat_local)


def window_pose_metrics(
    config: PipelineMetricsConfig,
    character: Character,
    pose: Pose,
    truth: Pose,
    handles: Handles,
    chains: ReachChains | None = None,
    windows: int = 1,
    curves: Float[Array, "windows frames 6 3"] | None = None,
) -> dict[str, np.ndarray]:
    """Per-window figures of poses ``(windows, frames, …)`` after IK, for :func:`summarize_windows`:
    each handle's distance from the IK'd skeleton's joint (``handle_error``, ``handle_valid``),
    MPJPE (and ``mpjpe_per_joint``, ``(windows, joints)``: where it comes from), foot
    skating, key pop, per-frame joint turns (:func:`_turn_figures`), and (given
    ``chains``) ``handle_unreachable``: the handle is farther from its chain's root *in the
    IK'd pose at that frame* than the chain's length plus :data:`HANDLE_MISS_CM` (a hand
    beyond the arm's reach from the shoulder the IK chose, :func:`beyond_reach`), or a
    handle missed by more than :data:`HANDLE_MISS_CM` on a frame whose other handle no pose
    meets together with it (:func:`conflicting_handles`: a hips handle 16 cm up and a foot
    handle 16 cm down may lie farther apart than the leg is long). Such a handle is
    necessarily missed by more than :data:`HANDLE_MISS_CM`, so unreachable handles are a
    subset of the missed ones: the rest are misses that some pose would have avoided. (The
    tolerance keeps handles at full extension, an arm hanging straight, from counting: the
    mocap's own come within a few millimetres of the chain's length.)

    Chained segments: ``pose`` and ``truth`` ``(chains, frames, …)`` over the chains' joined
    frames, ``handles`` ``(chains, handles)`` at chain frames (:func:`~bezmotion.evaluation.pipeline.chain_frame_handles`)
    and ``windows`` the windows per chain, whose key pop is the largest over every window's
    first and last frame pair (every key, from both sides).

    Given the ``curves`` the IK was given (the six joints' dense positions, cm), also how far
    the IK'd six joints lie from them on every frame (``curve_error``: mean over frames and
    joints; ``curve_error_max``): whether the whole body follows the curves, not only at the
    handles. An IK that holds the frames next to a key near the key's pose misses the curves
    there, and the body catches up with them in a jump a few frames later. With the curves,
    also the planted feet's largest rise above and sink below their curves (``foot_rise``,
    ``foot_sink``, cm: :func:`_planted_feet_height`) and ``sliding``: the skating test with
    the curves' feet deciding which frames are on the floor (``heights_from`` of
    :func:`~bezmotion.evaluation.metrics.foot_skating_ratio`), so IKs on the same curves are judged on the
    same frames and a sliding foot lifted off its curve is still counted."""
    return _to_numpy(_pose_figures(config, character, pose, truth, handles, chains, windows, curves))


@functools.partial(jax.jit, static_argnames=("config", "windows"))
def _pose_figures(config, character, pose, truth, handles, chains, windows, curves=None) -> dict[str, Array]:
    _, pos = pose_fk(character, pose)
    _, true_pos = pose_fk(character, truth)
    six = pos[..., np.asarray(character.characteristic), :]
    feet = six[..., list(FEET), :]
    per_joint = jnp.mean(jnp.linalg.norm(pos - true_pos, axis=-1), axis=-2)  # (windows, joints)
    out = {
        "handle_error": handle_distances(six, handles),
        "handle_valid": handles.valid,
        "mpjpe": jnp.mean(per_joint, axis=-1),
        "mpjpe_per_joint": per_joint,
        "skating": _skating(config, feet),
        "key_pop": _key_pop(pose.quat_local, windows),
        **_turn_figures(pose.quat_local),
    }
    if curves is not None:
        off = jnp.linalg.norm(six - curves, axis=-1)  # (windows, frames, 6)
        out["curve_error"] = jnp.mean(off, axis=(-2, -1))
        out["curve_error_max"] = jnp.max(off, axis=(-2, -1))
        out["foot_rise"], out["foot_sink"] = _planted_feet_height(feet, curves, config.fps)
        # The skating test with the curves' feet deciding which frames are on the floor: two IKs
        # given the same curves judged on the same frames (a foot lifted off its curve while it
        # slides escapes the paper's test).
        out["sliding"] = _skating(config, feet, heights_from=curves[..., list(FEET), :])
    if chains is not None:
        paired = jnp.any(conflicting_handles(handles, chains), axis=-1)
        out["handle_unreachable"] = beyond_reach(pos, handles, chains) | (paired & (out["handle_error"] > HANDLE_MISS_CM))
    return out


def _planted_feet_height(feet: Array, curves: Array, fps: float) -> tuple[Array, Array]:
    """Per window: how far (cm) the IK'd feet ``(windows, frames, 2, 3)`` rise above and sink
    below their curves (the six joints', ``(windows, frames, 6, 3)``) at most, on the frames
    where a curve's foot stands still horizontally (:func:`~bezmotion.ik.temporal.planted_feet`
    at the skating metric's 7.5 cm/s); 0 where none does. An IK that lets a planted foot give
    way upwards (``plant_height_scale``) rises; one that sinks puts the foot through the floor."""
    planted = planted_feet(curves, _PLANTED_SPEED / fps)[..., list(FEET)]  # (windows, frames, 2)
    height = feet[..., 1] - curves[..., list(FEET), 1]  # +Y up
    rise = jnp.max(jnp.where(planted, height, 0.0), axis=(-2, -1))
    sink = jnp.max(jnp.where(planted, -height, 0.0), axis=(-2, -1))
    return jnp.maximum(rise, 0.0), jnp.maximum(sink, 0.0)


# cm/s: a curve's foot slower than this stands still (foot_skating_ratio's speed threshold).
_PLANTED_SPEED = 7.5


def beyond_reach(positions: Float[Array, "*batch frames joints 3"], handles: Handles, chains: ReachChains) -> Bool[Array, "*batch handles"]:
    """Handles farther from their chain's root in ``positions`` (every joint of a posed
    skeleton, cm: where the IK put the shoulder or hip) than the chain's length stretched out
    plus :data:`HANDLE_MISS_CM`: out of the limb's reach. Hips handles never are."""
    root = jnp.asarray(chains.root)[handles.joint]
    at_root = handles._replace(joint=jnp.maximum(root, 0))
    beyond = handle_distances(positions, at_root) > jnp.asarray(chains.length, positions.dtype)[handles.joint] + HANDLE_MISS_CM
    return beyond & (root >= 0)


def conflicting_handles(handles: Handles, chains: ReachChains) -> Bool[Array, "*batch handles handles"]:
    """Pairs of valid handles on one frame that no pose can meet together: farther apart than
    the skeleton allows between their joints (``chains.apart``) plus :data:`HANDLE_MISS_CM`."""
    same_frame = (handles.frame[..., :, None] == handles.frame[..., None, :]) & handles.valid[..., :, None] & handles.valid[..., None, :]
    distance = jnp.linalg.norm(handles.position[..., :, None, :] - handles.position[..., None, :, :], axis=-1)
    allowed = jnp.asarray(chains.apart, distance.dtype)[handles.joint[..., :, None], handles.joint[..., None, :]]
    return same_frame & (distance > allowed + HANDLE_MISS_CM)


def largest_turn(character: Character, quat_local: Float[Array | np.ndarray, "frames joints 4"]) -> dict[str, Any]:
    """``{"deg", "joint", "frames"}`` for a summary: the largest per-frame turn of any joint's
    local rotation in one motion ``(frames, joints, 4)``, that joint's name and the frame pair.
    A pop at a key, or a jump where the body catches up with its curves, shows here."""
    change = np.asarray(rotation_change_deg(jnp.asarray(quat_local)))  # (frames - 1, joints)
    frame, joint = np.unravel_index(int(change.argmax()), change.shape)
    return {"deg": round(float(change[frame, joint]), 2), "joint": character.skeleton.names[joint], "frames": [int(frame), int(frame) + 1]}


def curve_miss(
    joints: Float[Array | np.ndarray, "frames 6 3"], curves: Float[Array | np.ndarray, "frames 6 3"]
) -> dict[str, Any]:
    """``{"cm", "frame"}`` for a summary: how far one motion's six characteristic joints
    (``joints``, cm, e.g. FK of the IK'd pose) lie from the curves they were given at worst,
    and on which frame (the per-window figures are :func:`window_pose_metrics`' ``curve_error``)."""
    off = np.linalg.norm(np.asarray(joints) - np.asarray(curves), axis=-1)  # (frames, 6)
    return {"cm": round(float(off.max()), 4), "frame": int(off.max(axis=-1).argmax())}


def _angle_deg(rot6d_a: Array, rot6d_b: Array) -> Array:
    return jnp.degrees(quat_angle(quat_from_rot6d(rot6d_a), quat_from_rot6d(rot6d_b)))


def window_curve_metrics(
    config: PipelineMetricsConfig,
    positions: Float[Array, "windows frames 6 3"],
    handles: Handles,
    true_positions: Float[Array, "windows frames 6 3"],
    rot6d: Float[Array, "windows frames 6 6"] | None = None,
    true_rot6d: Float[Array, "windows frames 6 6"] | None = None,
) -> dict[str, np.ndarray]:
    """Per-window figures of the six joints' dense curves before IK, for :func:`summarize_windows`:
    handle distances, position error per joint (``dense``, ``(windows, 6)``), foot skating, and
    with orientations, the angle (degrees) between the curves' and the mocap's global
    orientation per joint (``orientation``, ``(windows, 6)``)."""
    orientations = (rot6d, true_rot6d) if rot6d is not None and true_rot6d is not None else None
    return _to_numpy(_curve_figures(config, positions, handles, true_positions, orientations))


@functools.partial(jax.jit, static_argnames=("config",))
def _curve_figures(config, positions, handles, true_positions, orientations) -> dict[str, Array]:
    out = {
        "handle_error": handle_distances(positions, handles),
        "handle_valid": handles.valid,
        "dense": jnp.mean(jnp.linalg.norm(positions - true_positions, axis=-1), axis=-2),
        "skating": _skating(config, positions[..., list(FEET), :]),
    }
    if orientations is not None:
        out["orientation"] = jnp.mean(_angle_deg(*orientations), axis=-2)
    return out


def window_mocap_metrics(
    config: PipelineMetricsConfig, character: Character, truth: Pose, windows: int = 1
) -> dict[str, np.ndarray]:
    """Per-window figures of the mocap itself: foot skating, key pop and largest per-frame
    rotation change (the yardsticks of :func:`~bezmotion.evaluation.pipeline.ground_truth_pose_metrics`). For chains,
    ``truth`` ``(chains, frames, …)`` and ``windows`` per chain (key pop at every key, as in
    :func:`window_pose_metrics`)."""
    return _to_numpy(_mocap_figures(config, character, truth, windows))


@functools.partial(jax.jit, static_argnames=("config", "windows"))
def _mocap_figures(config, character, truth, windows) -> dict[str, Array]:
    _, pos = pose_fk(character, truth)
    feet = pos[..., np.asarray(character.characteristic[4:6]), :]
    return {
        "skating": _skating(config, feet),
        "key_pop": _key_pop(truth.quat_local, windows),
        **_turn_figures(truth.quat_local),
    }


def _turn_figures(quat_local: Array) -> dict[str, Array]:
    """Per item ``(items, frames, joints, 4)``: the largest per-frame joint rotation change
    anywhere (``max_rotation_change``, degrees) and its mean over the frame pairs
    (``rotation_change``: how much the most-turning joint turns per frame on average, where
    a pose that jitters from frame to frame stands out against the mocap's)."""
    change = jnp.max(rotation_change_deg(quat_local), axis=-1)  # (items, frames - 1)
    return {"max_rotation_change": jnp.max(change, axis=-1), "rotation_change": jnp.mean(change, axis=-1)}


def standard_error(values: np.ndarray) -> float | None:
    """The standard error of the mean of per-window ``values`` ``(windows, …)`` (each window's
    mean over the other axes is one sample): ``std / √n``, None for fewer than 2 windows.
    Two runs whose means differ by less than about twice their standard errors are not told
    apart by the windows drawn."""
    per_window = np.asarray(values, np.float64).reshape(len(values), -1).mean(axis=-1)
    if per_window.size < 2:
        return None
    return float(per_window.std(ddof=1) / np.sqrt(per_window.size))


def summarize_windows(per_window: Mapping[str, np.ndarray], select: np.ndarray | None = None) -> dict[str, Any]:
    """Aggregate per-window figures (of ``window_*_metrics``) over all windows or the ``select``
    ones (a boolean mask or indices). Means over valid handles / windows; maxima for the
    largest handle error, key pop and rotation change; per joint by role name. The means over
    windows (dense error, curve error, MPJPE, skating) come with their standard error over the
    windows (``…_se``: :func:`standard_error`)."""
    pick = (lambda a: a) if select is None else (lambda a: np.asarray(a)[select])  # noqa: E731
    w = {k: pick(v) for k, v in per_window.items()}
    out: dict[str, Any] = {}
    if "handle_error" in w:
        valid = w["handle_valid"].astype(bool)
        error = w["handle_error"][valid]
        out["handles_error_cm"] = float(error.mean()) if error.size else 0.0
        out["handles_error_max_cm"] = float(error.max()) if error.size else 0.0
        out["handles_missed_fraction"] = float(np.mean(error > HANDLE_MISS_CM)) if error.size else 0.0
        if "handle_unreachable" in w:
            out["unreachable_fraction"] = float(w["handle_unreachable"][valid].mean()) if error.size else 0.0
    if "dense" in w:
        out["dense_error_cm"] = float(w["dense"].mean())
        out["dense_error_cm_se"] = standard_error(w["dense"])
        out["dense_error_per_joint_cm"] = dict(zip(CHARACTERISTIC_JOINTS, map(float, w["dense"].mean(axis=0))))
    if "orientation" in w:
        out["orientation_error_deg"] = float(w["orientation"].mean())
        out["orientation_error_per_joint_deg"] = dict(zip(CHARACTERISTIC_JOINTS, map(float, w["orientation"].mean(axis=0))))
    if "curve_error" in w:
        out["curve_error_cm"] = float(w["curve_error"].mean())
        out["curve_error_cm_se"] = standard_error(w["curve_error"])
        out["curve_error_max_cm"] = float(w["curve_error_max"].max())
    for key in ("foot_rise", "foot_sink"):  # planted feet off their curves, up and down
        if key in w:
            out[f"planted_{key}_cm"] = float(w[key].mean())
            out[f"planted_{key}_max_cm"] = float(w[key].max())
    for key, name in (("mpjpe", "mpjpe_cm"), ("skating", "foot_skating_ratio"), ("sliding", "foot_sliding_ratio")):
        if key in w:
            out[name] = float(w[key].mean())
            out[f"{name}_se"] = standard_error(w[key])
    for key, name in (("key_pop", "key_pop_deg"), ("max_rotation_change", "max_rotation_change_deg")):
        if key in w:
            out[name] = float(w[key].max())
    if "rotation_change" in w:
        out["rotation_change_deg"] = float(w["rotation_change"].mean())
    return out


# The per-window figures :func:`paired_differences` compares, by their summary name.
PAIRED_FIGURES = {"mpjpe": "mpjpe_cm", "skating": "foot_skating_ratio", "sliding": "foot_sliding_ratio", "curve_error": "curve_error_cm"}


def paired_differences(
    base: Mapping[str, np.ndarray], other: Mapping[str, np.ndarray], select: np.ndarray | None = None
) -> dict[str, dict[str, float | int | None]]:
    """``other`` minus ``base``, window by window, for two sets of per-window figures of the
    same windows (two IKs on the same curves: :func:`window_pose_metrics`).

    Each window's figures are correlated between the two (the same curves, the same
    motion), so the standard error of the per-window difference is far smaller than either
    mean's: two IKs whose means lie within their own standard errors can still be told
    apart. Per figure of :data:`PAIRED_FIGURES` both have: ``{"mean", "se", "median",
    "better_fraction"}`` (``better_fraction``: windows where ``other`` is lower; ties count
    half) and ``"windows"``; ``select`` as in :func:`summarize_windows`.
    """
    pick = (lambda a: np.asarray(a)) if select is None else (lambda a: np.asarray(a)[select])  # noqa: E731
    out: dict[str, dict[str, float | int | None]] = {}
    for key, name in PAIRED_FIGURES.items():
        if key not in base or key not in other:
            continue
        a, b = pick(base[key]), pick(other[key])
        if a.shape != b.shape:
            raise ValueError(f"paired figures need the same windows: {key} has shapes {a.shape} and {b.shape}")
        diff = (b.astype(np.float64) - a).reshape(len(a), -1).mean(axis=-1)
        if diff.size == 0:
            continue
        out[name] = {
            "mean": float(diff.mean()),
            "se": standard_error(diff),
            "median": float(np.median(diff)),
            "better_fraction": float(np.mean(diff < 0) + 0.5 * np.mean(diff == 0)),
            "windows": int(diff.size),
        }
    return out
