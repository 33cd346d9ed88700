"""glTF 2.0 (``.glb``) export of an in-between: the skeleton and the six Bézier curves.

One binary glTF file holds

- the skeleton as a node hierarchy (one node per joint, named as in the BVH, plus a leaf
  node per End Site, ``<parent>_End``; all joints listed in a skin so that importers such
  as Blender's build an armature from them), animated per frame: the translation of the
  joints that carry position channels (the root and the hips with the default layout),
  the rotation of every joint, with ``LINEAR`` (slerp) or ``STEP`` samplers whose keys are
  the frames ``f / fps`` seconds;
- the six characteristic-joint curves as controller nodes ``ctrl_<joint>`` (children of
  the scene, i.e. in the character's world frame) whose translation is animated by
  ``CUBICSPLINE`` samplers with one key per control point and our control points and
  tangents exactly (below);
- optional handles as static marker nodes ``handle_<joint>@<frame>``;
- in ``asset.extras["bezmotion"]`` what a reader needs to undo the conversion exactly
  (frame time, stride, control frames, curve joint names, handles in cm).

**Units and axes.** We work in centimetres, glTF in metres: every position, offset and
tangent is multiplied by :data:`METRES_PER_CM` (0.01) on writing and divided by it on
reading. Our world frame is Y-up like glTF's, so axes are copied as they are.
Quaternions are stored ``(x, y, z, w)`` (glTF's order; ours is ``(w, x, y, z)``), made
sign-continuous over time so that ``LINEAR`` slerps the short way.

**Curves as CUBICSPLINE samplers.** Our segment ``k`` (frames ``f_k … f_{k+1}``,
``d_k = f_{k+1} − f_k`` frames, stride ``s``) is the cubic Bézier
``P_k, P_k + a_k·T_k, P_{k+1} − a_k·T_{k+1}, P_{k+1}`` with ``a_k = d_k / s``
(:mod:`bezmotion.bezier`). glTF's cubic Hermite segment over ``t_d = d_k / fps`` seconds
takes per-second tangents: out-tangent ``b_k = 3(P1 − P0)/t_d`` and in-tangent
``a_{k+1} = 3(P3 − P2)/t_d`` (spec Appendix C). Substituting, the key interval cancels:

    in-tangent = out-tangent = 3 · fps · T_k / s        (units per second)

at every interior control point, also across a shorter last segment; the first key's
in-tangent and the last key's out-tangent are zero (the spec ignores them). The key
value is ``P_k``. Reading inverts it, ``T_k = s · tangent / (3 · fps)``. The file's
curves are therefore ours exactly, to float32 precision.

:func:`write_glb` writes, :func:`read_glb` reads back (:class:`GlbContents`), and
:func:`validate_glb` runs the Khronos glTF validator (the ``gltf-validator`` npm package)
when it is installed. Blender drops CUBICSPLINE tangents on import; ``bezmotion/
blender_curves.py`` reads the curves from this file's samplers into Blender instead.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from jaxtyping import ArrayLike

from bezmotion.bezier import DEFAULT_STRIDE, BezierLayout, JoinedLayout, checked_controls
from bezmotion.data.bvh import POSITION_CHANNELS, BvhMotion
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.geometry.skeleton import Skeleton
from bezmotion._src.io import atomic_write_bytes

METRES_PER_CM = 0.01  # glTF's unit is the metre; ours the centimetre
INTERPOLATIONS = ("LINEAR", "STEP")
EXTRAS_KEY = "bezmotion"
FORMAT_VERSION = 1
_FLOAT = 5126  # GL_FLOAT: every accessor here is float32


class GlbContents(NamedTuple):
    """What :func:`read_glb` gets back from a file written by :func:`write_glb` (cm, float64).

    Attributes:
      motion: the skeleton (OFFSETs and End Sites, cm) and its per-frame local rotations
        ``(w, x, y, z)`` and translations (cm); joints whose translation the file animates
        get position channels, all get ZYX rotation channels; ``frame_time`` is exact.
      ctrl_pos, ctrl_tangent: ``(controls, 6, 3)`` the curves (cm), ``joints`` order; empty
        ``(0, 6, 3)`` when the file has none.
      layout: the curves' :class:`~bezmotion.bezier.BezierLayout` (``None`` without curves).
      joints: the curve joints' names (:data:`CHARACTERISTIC_JOINTS`).
      handles: ``[{"joint", "frame", "position" (cm)}]`` as given to :func:`write_glb`.
      key_frames: the frames that are key poses (the first and last; a chain's inner keys too).
    """

    motion: BvhMotion
    ctrl_pos: np.ndarray
    ctrl_tangent: np.ndarray
    layout: BezierLayout | None
    joints: tuple[str, ...]
    handles: list[dict[str, Any]]
    key_frames: list[int]


def curve_tangents_to_gltf(ctrl_tangent: np.ndarray, *, fps: float, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """glTF CUBICSPLINE ``(in_tangent, out_tangent)`` (per second) of our tangents ``T``.

    ``3·fps·T/s`` on both sides of each key; zero before the first and after the last.

    Args:
      ctrl_tangent: ``(controls, ..., dim)`` our tangents (any unit; the result has the same unit per second).
      fps: frames per second; stride: frames between control points.
    """
    velocity = np.asarray(ctrl_tangent, np.float64) * (3.0 * fps / stride)
    in_tangent, out_tangent = velocity.copy(), velocity.copy()
    in_tangent[0] = 0.0
    out_tangent[-1] = 0.0
    return in_tangent, out_tangent


def curve_tangents_from_gltf(in_tangent: np.ndarray, out_tangent: np.ndarray, *, fps: float, stride: int) -> np.ndarray:
    """Our tangents from glTF CUBICSPLINE per-second tangents (inverse of :func:`curve_tangents_to_gltf`).

    The first key takes its out-tangent, the last its in-tangent, interior keys the mean
    of both (equal in files we write; another tool's asymmetric edit is averaged, as
    :func:`bezmotion.bezier.from_segments` does).
    """
    in_tangent, out_tangent = np.asarray(in_tangent, np.float64), np.asarray(out_tangent, np.float64)
    velocity = 0.5 * (in_tangent + out_tangent)
    velocity[0], velocity[-1] = out_tangent[0], in_tangent[-1]
    return velocity * (stride / (3.0 * fps))


def _quat_xyzw_continuous(quat_wxyz: np.ndarray) -> np.ndarray:
    """``(frames, joints, 4)`` unit quaternions (x, y, z, w) with no sign flips between frames."""
    q = np.asarray(quat_wxyz, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = q.copy()
    for f in range(1, q.shape[0]):
        flip = np.sum(q[f] * q[f - 1], axis=-1) < 0
        q[f, flip] *= -1.0
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _handle_records(handles: Sequence[Mapping[str, Any]] | None, num_frames: int) -> list[dict[str, Any]]:
    records = []
    for i, h in enumerate(handles or ()):
        if not isinstance(h, Mapping) or set(h) < {"joint", "frame", "position"}:
            raise ValueError(f"handle {i} must be a mapping with 'joint', 'frame' and 'position', got {h!r}")
        joint, frame, position = h["joint"], h["frame"], np.asarray(h["position"], np.float64)
        if joint not in CHARACTERISTIC_JOINTS:
            raise ValueError(f"handle {i}: joint must be one of {list(CHARACTERISTIC_JOINTS)}, got {joint!r}")
        if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < num_frames:
            raise ValueError(f"handle {i}: frame must be an integer in 0…{num_frames - 1}, got {frame!r}")
        if position.shape != (3,) or not np.isfinite(position).all():
            raise ValueError(f"handle {i}: position must be 3 finite numbers (cm), got {h['position']!r}")
        records.append({"joint": joint, "frame": int(frame), "position": position.tolist()})
    return records


class _Blob:
    """Accessors packed one after another into the GLB's binary chunk (4-byte aligned)."""

    def __init__(self, gltf):
        self.gltf, self.chunks, self.offset = gltf, [], 0

    def add(self, data: np.ndarray, kind: str, *, with_bounds: bool = False) -> int:
        import pygltflib as g

        data = np.ascontiguousarray(data, np.float32)
        raw = data.tobytes()
        self.gltf.bufferViews.append(g.BufferView(buffer=0, byteOffset=self.offset, byteLength=len(raw)))
        count = data.shape[0]
        bounds = {}
        if with_bounds:  # required on animation inputs
            flat = data.reshape(count, -1)
            bounds = dict(min=flat.min(axis=0).tolist(), max=flat.max(axis=0).tolist())
        self.gltf.accessors.append(
            g.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=_FLOAT, count=count, type=kind, **bounds)
        )
        self.chunks.append(raw)
        self.offset += len(raw)  # float32 data: every view starts 4-byte aligned
        return len(self.gltf.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.chunks)


def write_glb(
    path: str | os.PathLike,
    motion: BvhMotion,
    ctrl_pos: ArrayLike | None = None,
    ctrl_tangent: ArrayLike | None = None,
    *,
    stride: int = DEFAULT_STRIDE,
    interpolation: str = "LINEAR",
    handles: Sequence[Mapping[str, Any]] | None = None,
    key_frames: Sequence[int] | None = None,
    name: str = "inbetween",
    layout: BezierLayout | None = None,
) -> None:
    """Write ``motion`` and the six characteristic-joint curves as a binary glTF 2.0 file (atomically).

    See the module docstring for the layout, the cm → m conversion (× 0.01) and the
    tangent conversion (``3·fps·T/s`` per second on both sides of a key).

    Args:
      path: the ``.glb`` to write.
      motion: the skeleton and its frames, as for BVH export: typically
        ``pose_to_bvh(character, result.pose, fps=..., template=clip)``
        (:func:`bezmotion.pipeline.export.pose_to_bvh`), so that the file rigs like the BVH.
        Joints with position channels get animated translations; its frame time sets the
        key times.
      ctrl_pos, ctrl_tangent: ``(controls, 6, 3)`` the curves in the character's world
        frame (cm), :data:`CHARACTERISTIC_JOINTS` order (``InbetweenResult.curves``); both or
        neither.
      stride: frames between control points (the BMM's ``config.stride``); the curves must
        have ``BezierLayout(frames, stride).num_controls`` control points.
      interpolation: ``"LINEAR"`` (slerp between frames) or ``"STEP"`` for the skeleton.
      handles: ``[{"joint": "right_hand", "frame": 12, "position": [x, y, z]}]`` (cm, world
        frame), written as marker nodes and kept in the file's extras.
      key_frames: the frames that are key poses, kept in the extras (default the first and
        last; a chain's inner keys too), so that an editor does not offer them as handles.
      name: the animation's name.
      layout: where the curves' control points sit (default ``BezierLayout(frames, stride)``;
        keys at unequal distances: :attr:`~bezmotion.pipeline.key_times.TimedInbetween.layout`).

    Raises:
      ValueError: curves of the wrong shape or with non-finite values, an unknown
        interpolation, bad handles.
    """
    import pygltflib as g

    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    frames, num_joints = motion.quat_local.shape[:2]
    if frames < 2:
        raise ValueError(f"need at least 2 frames to animate, got {frames}")
    fps = 1.0 / motion.frame_time
    layout = BezierLayout(frames, stride) if layout is None else layout
    if layout.num_frames != frames or layout.stride != stride:
        raise ValueError(f"the curves' layout has {layout.num_frames} frames at stride {layout.stride}, the motion {frames} at stride {stride}")
    ctrl_pos, ctrl_tangent = checked_controls(ctrl_pos, ctrl_tangent, layout, len(CHARACTERISTIC_JOINTS))
    if not (np.isfinite(motion.quat_local).all() and np.isfinite(motion.pos_local).all()):
        raise ValueError("motion contains non-finite values")
    records = _handle_records(handles, frames)
    key_frames = [0, frames - 1] if key_frames is None else sorted({int(f) for f in key_frames})
    if not all(0 <= f < frames for f in key_frames):
        raise ValueError(f"key frames must be frames of the motion, 0…{frames - 1}; got {key_frames}")

    skeleton = motion.skeleton
    offsets = np.asarray(skeleton.offsets, np.float64)
    translated = [j for j, chans in enumerate(motion.channels) if set(POSITION_CHANNELS) <= set(chans)]
    quat_xyzw = _quat_xyzw_continuous(motion.quat_local)
    gltf = g.GLTF2(asset=g.Asset(generator="bezmotion", version="2.0"), scene=0)
    blob = _Blob(gltf)

    # Nodes: joints first (their index is the joint index), then End Sites, controllers, handles.
    for j, joint in enumerate(skeleton.names):
        gltf.nodes.append(
            g.Node(name=joint, translation=(offsets[j] * METRES_PER_CM).tolist(), rotation=quat_xyzw[0, j].tolist())
        )
    for j in range(num_joints):
        if skeleton.parents[j] >= 0:
            gltf.nodes[skeleton.parents[j]].children.append(j)
    for parent, offset in motion.end_sites:
        gltf.nodes.append(g.Node(name=f"{skeleton.names[parent]}_End", translation=(np.asarray(offset) * METRES_PER_CM).tolist()))
        gltf.nodes[parent].children.append(len(gltf.nodes) - 1)
    skin_joints = list(range(len(gltf.nodes)))
    roots = [j for j in range(num_joints) if skeleton.parents[j] < 0]
    gltf.skins.append(g.Skin(name=f"{name}_skeleton", joints=skin_joints, skeleton=roots[0]))

    samplers, channels = [], []

    def animate(node: int, path_: str, times: int, values: np.ndarray, kind: str, mode: str) -> None:
        samplers.append(g.AnimationSampler(input=times, output=blob.add(values, kind), interpolation=mode))
        channels.append(g.AnimationChannel(sampler=len(samplers) - 1, target=g.AnimationChannelTarget(node=node, path=path_)))

    frame_times = blob.add(np.arange(frames) * motion.frame_time, "SCALAR", with_bounds=True)
    for j in translated:
        animate(j, "translation", frame_times, motion.pos_local[:, j] * METRES_PER_CM, "VEC3", interpolation)
    for j in range(num_joints):
        animate(j, "rotation", frame_times, quat_xyzw[:, j], "VEC4", interpolation)

    controllers = []
    if ctrl_pos is not None:
        key_times = blob.add(layout.control_frames * motion.frame_time, "SCALAR", with_bounds=True)
        in_tangent, out_tangent = curve_tangents_to_gltf(ctrl_tangent * METRES_PER_CM, fps=fps, stride=stride)
        for c, joint in enumerate(CHARACTERISTIC_JOINTS):
            gltf.nodes.append(g.Node(name=f"ctrl_{joint}", translation=(ctrl_pos[0, c] * METRES_PER_CM).tolist()))
            node = len(gltf.nodes) - 1
            controllers.append(node)
            # CUBICSPLINE output: per key, in-tangent, value, out-tangent.
            keys = np.stack([in_tangent[:, c], ctrl_pos[:, c] * METRES_PER_CM, out_tangent[:, c]], axis=1).reshape(-1, 3)
            animate(node, "translation", key_times, keys, "VEC3", "CUBICSPLINE")
    markers = []
    for h in records:
        gltf.nodes.append(
            g.Node(name=f"handle_{h['joint']}@{h['frame']}", translation=(np.asarray(h["position"]) * METRES_PER_CM).tolist())
        )
        markers.append(len(gltf.nodes) - 1)

    gltf.animations.append(g.Animation(name=name, samplers=samplers, channels=channels))
    gltf.scenes.append(g.Scene(name=name, nodes=roots + controllers + markers))
    gltf.asset.extras = {
        EXTRAS_KEY: {
            "version": FORMAT_VERSION,
            "units": "m (bezmotion's cm x 0.01)",
            "frame_time": float(motion.frame_time),
            "num_frames": int(frames),
            "joints": list(skeleton.names),
            "rotation_order": "ZYX",
            "stride": int(stride),
            "control_frames": layout.control_frames.tolist() if ctrl_pos is not None else [],
            "curve_joints": list(CHARACTERISTIC_JOINTS) if ctrl_pos is not None else [],
            "curve_nodes": controllers,
            "handles": records,
            "key_frames": key_frames,
        }
    }
    data = blob.bytes()
    gltf.buffers.append(g.Buffer(byteLength=len(data)))
    gltf.set_binary_blob(data)
    atomic_write_bytes(path, b"".join(gltf.save_to_bytes()))


def _accessor_array(gltf, blob: bytes, index: int) -> np.ndarray:
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[accessor.type]
    if accessor.componentType != _FLOAT:
        raise ValueError(f"accessor {index}: expected float32 data (componentType {_FLOAT}), got {accessor.componentType}")
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    data = np.frombuffer(blob, np.float32, count=accessor.count * width, offset=start)
    return data.reshape(accessor.count, width).astype(np.float64)


def read_glb(path: str | os.PathLike) -> GlbContents:
    """Read back a ``.glb`` written by :func:`write_glb` (positions converted back to cm).

    Raises:
      ValueError: the file is not a GLB, or was not written by :func:`write_glb` (no
        ``asset.extras["bezmotion"]``), or its animation does not match its skeleton.
    """
    import pygltflib as g

    path = Path(path)
    data = path.read_bytes()
    if data[:4] != b"glTF":
        raise ValueError(f"{path}: not a binary glTF file (starts with {data[:4]!r}, expected b'glTF')")
    gltf = g.GLTF2.load_from_bytes(data)
    meta = (gltf.asset.extras or {}).get(EXTRAS_KEY)
    if not isinstance(meta, dict) or meta.get("version") != FORMAT_VERSION:
        raise ValueError(f"{path}: no bezmotion metadata (asset.extras[{EXTRAS_KEY!r}] version {FORMAT_VERSION}); not written by write_glb")
    blob = gltf.binary_blob()
    # pygltflib drops empty lists when writing: absent means none.
    curve_nodes, curve_joints = list(meta.get("curve_nodes", [])), tuple(meta.get("curve_joints", []))
    names = tuple(meta["joints"])
    frames, frame_time = int(meta["num_frames"]), float(meta["frame_time"])
    index = {n.name: i for i, n in enumerate(gltf.nodes)}
    missing = [n for n in names if n not in index]
    if missing:
        raise ValueError(f"{path}: joints {missing} have no node")
    joint_node = [index[n] for n in names]
    node_joint = {node: j for j, node in enumerate(joint_node)}
    parents = [-1] * len(names)
    end_sites = []
    for j, node in enumerate(joint_node):
        for child in gltf.nodes[node].children or ():
            if child in node_joint:
                parents[node_joint[child]] = j
            else:
                end_sites.append((j, tuple(float(v) / METRES_PER_CM for v in gltf.nodes[child].translation)))
    offsets = np.asarray([gltf.nodes[n].translation or [0.0, 0.0, 0.0] for n in joint_node], np.float64) / METRES_PER_CM
    quat = np.broadcast_to(np.asarray([1.0, 0.0, 0.0, 0.0]), (frames, len(names), 4)).copy()
    pos = np.broadcast_to(offsets, (frames, len(names), 3)).copy()
    translated = set()
    curves = {}
    animation = gltf.animations[0]
    for channel in animation.channels:
        sampler = animation.samplers[channel.sampler]
        node, target = channel.target.node, channel.target.path
        values = _accessor_array(gltf, blob, sampler.output)
        if node in node_joint:
            j = node_joint[node]
            if values.shape[0] != frames:
                raise ValueError(f"{path}: joint {names[j]!r} {target} has {values.shape[0]} keys, expected {frames}")
            if target == "rotation":
                quat[:, j] = np.concatenate([values[:, 3:], values[:, :3]], axis=-1)
            elif target == "translation":
                pos[:, j] = values / METRES_PER_CM
                translated.add(j)
        elif node in curve_nodes and target == "translation":
            curves[curve_nodes.index(node)] = values.reshape(-1, 3, 3) / METRES_PER_CM  # (keys, in/value/out, 3)
    rotation = ("Zrotation", "Yrotation", "Xrotation")
    channels = tuple((POSITION_CHANNELS + rotation) if j in translated else rotation for j in range(len(names)))
    skeleton = Skeleton(tuple(parents), names, offsets)
    motion = BvhMotion(skeleton, quat, pos, channels, frame_time, tuple(end_sites))
    if curve_joints:
        stride = int(meta["stride"])
        layout = _curve_layout(path, frames, stride, meta)
        if len(curves) != len(curve_joints) or any(c.shape[0] != layout.num_controls for c in curves.values()):
            raise ValueError(f"{path}: expected {len(curve_joints)} curves of {layout.num_controls} keys")
        keys = np.stack([curves[c] for c in range(len(curve_joints))], axis=1)  # (controls, 6, 3, 3)
        ctrl_pos = keys[:, :, 1]
        ctrl_tangent = curve_tangents_from_gltf(keys[:, :, 0], keys[:, :, 2], fps=1.0 / frame_time, stride=stride)
    else:
        layout, ctrl_pos, ctrl_tangent = None, np.zeros((0, 6, 3)), np.zeros((0, 6, 3))
    key_frames = [int(f) for f in meta.get("key_frames", [0, frames - 1])]  # files before key_frames: a window's two
    return GlbContents(motion, ctrl_pos, ctrl_tangent, layout, curve_joints, list(meta.get("handles", [])), key_frames)


def _curve_layout(path: Path, frames: int, stride: int, meta: Mapping[str, Any]) -> BezierLayout:
    """The layout of a file's curves: its control frames on the stride's grid, or each window
    between its keys on its own grid (keys at unequal distances, :class:`~bezmotion.bezier.JoinedLayout`)."""
    layout = BezierLayout(frames, stride)
    control_frames = [int(f) for f in meta.get("control_frames", layout.control_frames.tolist())]
    if control_frames == layout.control_frames.tolist():
        return layout
    key_frames = [int(f) for f in meta.get("key_frames", [0, frames - 1])]
    joined = JoinedLayout.of(np.diff(key_frames).tolist(), stride)
    if joined.num_frames != frames or joined.control_frames.tolist() != control_frames:
        raise ValueError(f"{path}: control frames {control_frames} are neither every {stride} frames nor each window's between the keys {key_frames}")
    return joined


def find_gltf_validator() -> Path | None:
    """The installed ``gltf-validator`` npm package's folder, or ``None`` (nothing is downloaded).

    Looked for in ``$BEZMOTION_GLTF_VALIDATOR`` (the package folder or a prefix holding
    ``node_modules/gltf-validator``), then ``~/.cache/bezmotion/gltf-validator`` (where
    ``npm install --prefix ~/.cache/bezmotion/gltf-validator gltf-validator`` puts it), then
    node's own resolution from the working directory. Needs ``node`` on the PATH.
    """
    if shutil.which("node") is None:
        return None
    candidates = []
    if os.environ.get("BEZMOTION_GLTF_VALIDATOR"):
        candidates.append(Path(os.environ["BEZMOTION_GLTF_VALIDATOR"]))
    candidates.append(Path.home() / ".cache" / "bezmotion" / "gltf-validator")
    for base in candidates:
        for folder in (base, base / "node_modules" / "gltf-validator"):
            if (folder / "package.json").is_file() and (folder / "gltf_validator.dart.js").is_file():
                return folder
    try:
        found = subprocess.run(
            ["node", "-e", "console.log(require.resolve('gltf-validator/package.json'))"],
            capture_output=True, text=True, timeout=30, check=False,
        )  # fmt: skip
    except (OSError, subprocess.TimeoutExpired):
        return None
    return Path(found.stdout.strip()).parent if found.returncode == 0 and found.stdout.strip() else None


_VALIDATE_JS = """
const validator = require(process.argv[1]);
const fs = require('fs');
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator.validateBytes(data, {maxIssues: 0})
  .then((report) => { console.log(JSON.stringify(report)); })
  .catch((error) => { console.error(String(error)); process.exit(2); });
"""


def validate_glb(path: str | os.PathLike, validator: str | os.PathLike | None = None) -> dict:
    """The Khronos glTF validator's report on ``path`` (its JSON, as a dict).

    ``report["issues"]["numErrors"]`` is 0 for a valid file; ``report["issues"]["messages"]``
    lists errors, warnings, infos and hints with their codes.

    Args:
      validator: the ``gltf-validator`` package folder; default :func:`find_gltf_validator`.
    Raises:
      FileNotFoundError: the validator (or node) is not installed.
      RuntimeError: the validator failed to run.
    """
    folder = Path(validator) if validator is not None else find_gltf_validator()
    if folder is None or shutil.which("node") is None:
        raise FileNotFoundError(
            "the Khronos glTF validator is not installed: needs node and the gltf-validator npm package "
            "(npm install --prefix ~/.cache/bezmotion/gltf-validator gltf-validator)"
        )
    run = subprocess.run(
        ["node", "-e", _VALIDATE_JS, str(folder.resolve()), str(Path(path).resolve())],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    if run.returncode != 0:
        raise RuntimeError(f"gltf-validator failed on {path}: {run.stderr.strip() or run.stdout.strip()}")
    return json.loads(run.stdout)
