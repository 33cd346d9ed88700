"""Blender round trip for bezmotion's Bézier curves: import a ``.glb``, edit, export handles.

Runs inside Blender's Python (stdlib + ``bpy`` only: it never imports jax or bezmotion,
so Blender runs this file by path). Three ways to use it:

- headless, with a Blender build::

      blender --background --python-exit-code 1 --python bezmotion/integrations/blender_curves.py -- import out.glb --blend out.blend
      blender --background --python-exit-code 1 --python bezmotion/integrations/blender_curves.py -- export handles.json --blend edited.blend

  (``--python-exit-code 1``: a failure exits non-zero instead of leaving Blender running on.)

- headless, with the ``bpy`` wheel (``pip install bpy``; CPython 3.11 for Blender 4.2–5.0)::

      python bezmotion/integrations/blender_curves.py import out.glb --blend out.blend

- from Blender's UI: open this file in the Text Editor and press *Run Script*; it adds
  *File › Import › bezmotion curves (.glb)* and *File › Export › bezmotion handles (.json)*.
  (``python -c "import bezmotion.integrations.blender_curves as m; print(m.__file__)"`` prints its path.)

**import** reads a ``.glb`` written by :func:`bezmotion.pipeline.gltf.write_glb`. The
skeleton comes in through Blender's own glTF importer (an armature, animated per frame),
with the scene's frame rate set to the file's first so that frame ``f`` lands on Blender
frame ``f``. The importer drops CUBICSPLINE tangents, so the six controllers are made
here instead: empties ``ctrl_<joint>`` whose location F-curves hold one Bézier keyframe
per control point with FREE handles equal to our tangents. In Blender's Z-up metres a
point ``(x, y, z)`` of ours (cm, Y-up) is ``(x, −z, y) · 0.01`` (what the glTF importer
does). Our segment ``k`` from frame ``f_k`` to ``f_{k+1}`` (``d_k`` frames, stride ``s``)
is the cubic Bézier ``P_k, P_k + a_k T_k, P_{k+1} − a_k T_{k+1}, P_{k+1}`` with
``a_k = d_k / s``; Blender draws the same cubic when its handles are those inner points
placed at a third of the interval in time, so keyframe ``k`` gets

    handle_right = (f_k + d_k / 3,      P_k + a_k T_k)
    handle_left  = (f_k − d_{k−1} / 3,  P_k − a_{k−1} T_k)

(the first key's left and the last key's right handles mirror their other side).
Handles drawn from the ``.glb``'s markers become empties ``handle_<joint>@<frame>``.

**export** reads the controllers back — the keys of the handles the in-between was made
with (where they are now), every key (a control point, or one the animator added) whose
position moved from the imported curve by more than ``--tolerance`` cm, or every interior
key with ``--all`` — into the handles file that ``bezmotion inbetween
--handles FILE`` takes: ``[{"joint": "right_hand", "frame": 12, "position": [x, y, z]}]``,
cm, in the character's world frame. The key poses (the first and last frames, and a
chain's inner keys: the file's ``key_frames``) are not handles: moving them is reported,
not exported. Edits of a handle's tangent
alone have no place in that format and are reported too.

The conversion functions (``parse_glb``, ``blender_keyframes``, ``curve_from_keyframes``,
``edited_handles``) are plain Python and tested without Blender.
"""

# No `from __future__ import annotations`: Blender reads operator properties from real class annotations.

import argparse
import json
import math
import os
import struct
import sys

CM_PER_METRE = 100.0
EXTRAS_KEY = "bezmotion"
PROP = "bezmotion"  # custom property (JSON text) on each controller: its imported curve
JOINT_PROP = "bezmotion_joint"
DEFAULT_TOLERANCE_CM = 1e-3


# ---------------------------------------------------------------- pure conversion logic


def to_blender(p_cm):
    """Our point (cm, Y-up) in Blender's world (m, Z-up): ``(x, −z, y) · 0.01``."""
    x, y, z = p_cm
    return (x / CM_PER_METRE, -z / CM_PER_METRE, y / CM_PER_METRE)


def from_blender(p_m):
    """Inverse of :func:`to_blender`: ``(x, z, −y) · 100`` cm."""
    x, y, z = p_m
    return (x * CM_PER_METRE, z * CM_PER_METRE, -y * CM_PER_METRE)


def parse_glb(data: bytes) -> dict:
    """The curves, timing and handles of a ``.glb`` from ``write_glb`` (stdlib only).

    Returns:
      ``{"frame_time", "fps", "num_frames", "stride", "control_frames": [f_k],
      "curves": {joint: {"position": [[x, y, z]] cm, "tangent": [[x, y, z]] cm}},
      "handles": [{"joint", "frame", "position"}]}``.
    Raises:
      ValueError: not a GLB, or not one of ours.
    """
    if len(data) < 20 or data[:4] != b"glTF":
        raise ValueError(f"not a binary glTF file (starts with {data[:4]!r}, expected b'glTF')")
    offset, doc, blob = 12, None, b""
    while offset + 8 <= len(data):
        length, kind = struct.unpack_from("<I4s", data, offset)
        chunk = data[offset + 8 : offset + 8 + length]
        if kind == b"JSON":
            doc = json.loads(chunk.decode("utf-8"))
        elif kind == b"BIN\x00":
            blob = chunk
        offset += 8 + length
    meta = ((doc or {}).get("asset", {}).get("extras") or {}).get(EXTRAS_KEY)
    if not isinstance(meta, dict):
        raise ValueError(f"no bezmotion metadata (asset.extras[{EXTRAS_KEY!r}]): not written by bezmotion's write_glb")

    def accessor(index):
        acc = doc["accessors"][index]
        view = doc["bufferViews"][acc["bufferView"]]
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc["type"]]
        if acc["componentType"] != 5126:
            raise ValueError(f"accessor {index}: expected float32 data, got componentType {acc['componentType']}")
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        flat = struct.unpack_from(f"<{acc['count'] * width}f", blob, start)
        return [list(flat[i : i + width]) for i in range(0, len(flat), width)]

    frame_time, stride = float(meta["frame_time"]), int(meta.get("stride", 6))
    fps = 1.0 / frame_time
    curve_nodes, curve_joints = meta.get("curve_nodes", []), meta.get("curve_joints", [])
    curves = {}
    for animation in doc.get("animations", []):
        for channel in animation["channels"]:
            node = channel["target"].get("node")
            if node not in curve_nodes or channel["target"]["path"] != "translation":
                continue
            sampler = animation["samplers"][channel["sampler"]]
            if sampler.get("interpolation") != "CUBICSPLINE":
                raise ValueError(f"curve node {node} is not animated by a CUBICSPLINE sampler")
            out = accessor(sampler["output"])
            keys = [out[i : i + 3] for i in range(0, len(out), 3)]  # in-tangent, value, out-tangent
            scale = CM_PER_METRE * stride / (3.0 * fps)
            tangents = []
            for k, (a, _, b) in enumerate(keys):
                if k == 0:
                    v = b
                elif k == len(keys) - 1:
                    v = a
                else:
                    v = [0.5 * (ai + bi) for ai, bi in zip(a, b)]
                tangents.append([c * scale for c in v])
            curves[curve_joints[curve_nodes.index(node)]] = {
                "position": [[c * CM_PER_METRE for c in value] for _, value, _ in keys],
                "tangent": tangents,
            }
    missing = [j for j in curve_joints if j not in curves]
    if missing:
        raise ValueError(f"curves {missing} have no CUBICSPLINE translation channel")
    return {
        "frame_time": frame_time,
        "fps": fps,
        "num_frames": int(meta["num_frames"]),
        "stride": stride,
        "control_frames": [int(f) for f in meta.get("control_frames", [])],
        "key_frames": [int(f) for f in meta.get("key_frames", [0, int(meta["num_frames"]) - 1])],
        "curves": curves,
        "handles": list(meta.get("handles", [])),
    }


def blender_keyframes(control_frames, stride, position_cm, tangent_cm):
    """Blender Bézier keyframes of one curve, per Blender axis (see the module docstring).

    Args:
      control_frames: ``[f_k]`` integer frames of the control points.
      stride: frames between control points (``a_k = d_k / stride``).
      position_cm, tangent_cm: ``[[x, y, z]]`` our control points and tangents (cm, Y-up).
    Returns:
      three lists (Blender x, y, z) of ``(co, handle_left, handle_right)``, each a
      ``(frame, value)`` pair in metres.
    """
    n = len(control_frames)
    if n < 2 or len(position_cm) != n or len(tangent_cm) != n:
        raise ValueError(f"need ≥ 2 control frames and as many positions and tangents, got {n}, {len(position_cm)}, {len(tangent_cm)}")
    pos = [to_blender(p) for p in position_cm]
    tan = [to_blender(t) for t in tangent_cm]
    lengths = [control_frames[k + 1] - control_frames[k] for k in range(n - 1)]
    axes = ([], [], [])
    for k, frame in enumerate(control_frames):
        before = lengths[k - 1] if k > 0 else lengths[0]
        after = lengths[k] if k < n - 1 else lengths[-1]
        for axis in range(3):
            p, t = pos[k][axis], tan[k][axis]
            axes[axis].append(
                (
                    (float(frame), p),
                    (frame - before / 3.0, p - before / stride * t),
                    (frame + after / 3.0, p + after / stride * t),
                )
            )
    return axes


def curve_from_keyframes(axes, stride):
    """Control frames, points and tangents (cm, Y-up) from Blender keyframes (inverse of
    :func:`blender_keyframes`; an asymmetric handle pair is averaged).

    Args:
      axes: three lists (Blender x, y, z) of ``(co, handle_left, handle_right)`` on the same frames.
    Returns:
      ``(frames, position_cm, tangent_cm)``.
    """
    frames = [co[0] for co, _, _ in axes[0]]
    n = len(frames)
    position, tangent = [], []
    for k in range(n):
        p_b, t_b = [], []
        for axis in range(3):
            (f, p), (fl, pl), (fr, pr) = axes[axis][k]
            slopes = []
            if f - fl > 0:
                slopes.append((p - pl) / (f - fl))
            if fr - f > 0:
                slopes.append((pr - p) / (fr - f))
            # a handle at a third of the segment holds T·d/s over d/3 frames: slope 3T/s.
            t_b.append(sum(slopes) / len(slopes) * stride / 3.0 if slopes else 0.0)
            p_b.append(p)
        position.append(list(from_blender(p_b)))
        tangent.append(list(from_blender(t_b)))
    return frames, position, tangent


def bezier_value(segment_keys, frame):
    """Value of a Blender Bézier F-curve segment at ``frame`` (handles at a third: time is linear)."""
    (f0, p0), _, (f1h, p1) = segment_keys[0]
    (f3, p3), (f2h, p2), _ = segment_keys[1]
    t = (frame - f0) / (f3 - f0)
    u = 1.0 - t
    return u * u * u * p0 + 3 * u * u * t * p1 + 3 * u * t * t * p2 + t * t * t * p3


def edited_handles(joint, original, keys, *, num_frames, key_frames=None, tolerance_cm=DEFAULT_TOLERANCE_CM, everything=False, keep=()):
    """Handles (cm) for the keys of one controller that moved, and notes on what cannot be said.

    Args:
      joint: the characteristic joint's name.
      original: ``{"control_frames", "position", "tangent"}`` as imported (cm).
      keys: ``[(frame, position_cm, tangent_cm)]`` the controller's keys now.
      num_frames: the motion's length.
      key_frames: the frames that are key poses, never handles (default the first and last;
        a chain's inner keys too).
      tolerance_cm: a key counts as moved beyond this distance.
      everything: every interior key, moved or not.
      keep: frames whose keys are handles whether they moved or not (the handles the
        in-between was made with, so that the file describes the whole edit).
    Returns:
      ``(handles, notes)``: ``[{"joint", "frame", "position"}]`` and a list of messages.
    """
    before = {int(f): (p, t) for f, p, t in zip(original["control_frames"], original["position"], original["tangent"])}
    key_frames = {0, num_frames - 1} if key_frames is None else set(key_frames)
    handles, notes = [], []
    for frame, position, tangent in keys:
        whole = round(frame)
        if abs(frame - whole) > 1e-3:
            notes.append(f"{joint}: key at frame {frame:.3f} is not on a whole frame; skipped")
            continue
        old = before.get(whole)
        moved = old is None or math.dist(position, old[0]) > tolerance_cm
        if whole in key_frames:
            if moved:
                notes.append(f"{joint}: the key at frame {whole} moved, but frame {whole} is a key pose (keys at {sorted(key_frames)}); not a handle")
            continue
        if not 0 < whole < num_frames - 1:
            notes.append(f"{joint}: key at frame {whole} is outside the window 0…{num_frames - 1}; skipped")
            continue
        if moved or everything or whole in keep:
            handles.append({"joint": joint, "frame": whole, "position": [float(c) for c in position]})
        elif math.dist(tangent, old[1]) > tolerance_cm:
            notes.append(f"{joint}: the tangent at frame {whole} changed; the handles format carries positions only")
    return handles, notes


# ---------------------------------------------------------------- Blender side


def _fcurves(obj, action_name):
    """An empty F-curve collection for ``obj`` (slotted actions from Blender 4.4, ``action.fcurves`` before)."""
    import bpy

    obj.animation_data_create()
    action = bpy.data.actions.new(action_name)
    obj.animation_data.action = action
    if hasattr(action, "slots"):  # Blender ≥ 4.4
        from bpy_extras import anim_utils

        slot = action.slots.new(id_type="OBJECT", name=obj.name)
        obj.animation_data.action_slot = slot
        return anim_utils.action_ensure_channelbag_for_slot(action, slot).fcurves
    return action.fcurves


def _existing_fcurves(obj):
    ad = obj.animation_data
    if ad is None or ad.action is None:
        return []
    action = ad.action
    if hasattr(action, "slots"):
        from bpy_extras import anim_utils

        bag = anim_utils.action_get_channelbag_for_slot(action, ad.action_slot)
        return list(bag.fcurves) if bag is not None else []
    return list(action.fcurves)


def import_glb(path, *, armature=True):
    """Import ``path`` into the current scene: armature (glTF importer) and six exact controllers."""
    import bpy

    with open(path, "rb") as f:
        data = parse_glb(f.read())
    scene = bpy.context.scene
    fps = data["fps"]
    scene.render.fps = max(1, round(fps))
    scene.render.fps_base = scene.render.fps / fps
    scene.frame_start, scene.frame_end = 0, data["num_frames"] - 1
    if armature:
        before = set(bpy.data.objects)
        bpy.ops.import_scene.gltf(filepath=os.fspath(path))
        # The importer also made the controllers and markers, with AUTO handles: ours replace them.
        for obj in set(bpy.data.objects) - before:
            if obj.name.startswith(("ctrl_", "handle_")):
                bpy.data.objects.remove(obj, do_unlink=True)
    collection = bpy.data.collections.new("bezmotion curves")
    scene.collection.children.link(collection)
    made = []
    for joint, curve in data["curves"].items():
        obj = bpy.data.objects.new(f"ctrl_{joint}", None)
        obj.empty_display_type = "SPHERE"
        obj.empty_display_size = 0.03
        collection.objects.link(obj)
        obj[JOINT_PROP] = joint
        obj[PROP] = json.dumps(
            {"control_frames": data["control_frames"], "stride": data["stride"], "num_frames": data["num_frames"], "key_frames": data["key_frames"], **curve}
        )
        fcurves = _fcurves(obj, f"ctrl_{joint}")
        for axis, keys in enumerate(blender_keyframes(data["control_frames"], data["stride"], curve["position"], curve["tangent"])):
            fc = fcurves.new("location", index=axis)
            fc.keyframe_points.add(len(keys))
            fc.keyframe_points.foreach_set("co", [c for co, _, _ in keys for c in co])
            for point, (_, left, right) in zip(fc.keyframe_points, keys):
                point.interpolation = "BEZIER"
                point.handle_left_type = point.handle_right_type = "FREE"
                point.handle_left, point.handle_right = left, right
            fc.update()
        obj.location = to_blender(curve["position"][0])
        made.append(obj)
    for h in data["handles"]:
        marker = bpy.data.objects.new(f"handle_{h['joint']}@{h['frame']}", None)
        marker.empty_display_type = "PLAIN_AXES"
        marker.empty_display_size = 0.05
        marker.location = to_blender(h["position"])
        collection.objects.link(marker)
    scene[PROP] = json.dumps(
        {"source": os.fspath(path), "frame_time": data["frame_time"], "num_frames": data["num_frames"], "handles": data["handles"]}
    )
    scene.frame_set(0)
    return made


def controller_keys(obj):
    """``(joint, original, [(frame, position_cm, tangent_cm)])`` of a controller made by :func:`import_glb`."""
    original = json.loads(obj[PROP])
    curves = {fc.array_index: fc for fc in _existing_fcurves(obj) if fc.data_path == "location"}
    if sorted(curves) != [0, 1, 2]:
        raise ValueError(f"{obj.name}: expected location F-curves x, y, z, found indices {sorted(curves)}")
    frames = sorted({round(k.co[0], 4) for fc in curves.values() for k in fc.keyframe_points})
    keys = []
    for frame in frames:
        axes = []
        for axis in range(3):
            fc = curves[axis]
            point = next((k for k in fc.keyframe_points if abs(k.co[0] - frame) < 1e-4), None)
            if point is None:  # a key on some axes only: the others as the curve is there
                value = fc.evaluate(frame)
                axes.append([((frame, value), (frame, value), (frame, value))])
            else:
                axes.append([(tuple(point.co), tuple(point.handle_left), tuple(point.handle_right))])
        _, position, tangent = curve_from_keyframes(axes, original["stride"])
        keys.append((frame, position[0], tangent[0]))
    return obj[JOINT_PROP], original, keys


def export_handles(path, *, tolerance_cm=DEFAULT_TOLERANCE_CM, everything=False):
    """Write the handles file for the controllers in the current scene; returns ``(handles, notes)``."""
    import bpy

    controllers = [obj for obj in bpy.context.scene.objects if JOINT_PROP in obj and PROP in obj]
    if not controllers:
        raise ValueError("no bezmotion controllers in this scene (import a .glb first)")
    given = json.loads(bpy.context.scene.get(PROP, "{}")).get("handles", [])
    handles, notes = [], []
    for obj in controllers:
        joint, original, keys = controller_keys(obj)
        keep = {h["frame"] for h in given if h["joint"] == joint}
        h, n = edited_handles(
            joint, original, keys, num_frames=original["num_frames"], key_frames=original.get("key_frames"),
            tolerance_cm=tolerance_cm, everything=everything, keep=keep,
        )
        handles += h
        notes += n
    handles.sort(key=lambda h: (h["frame"], h["joint"]))
    text = json.dumps(handles, indent=2) + "\n"
    tmp = f"{path}.tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
    os.replace(tmp, path)  # never a half-written file
    return handles, notes


def _register_ui():
    import bpy
    from bpy_extras.io_utils import ExportHelper, ImportHelper

    class ImportCurves(bpy.types.Operator, ImportHelper):
        """Import a bezmotion .glb: armature plus six Bézier controllers with exact handles"""

        bl_idname = "bezmotion.import_curves"
        bl_label = "Import bezmotion curves"
        filename_ext = ".glb"
        filter_glob: bpy.props.StringProperty(default="*.glb", options={"HIDDEN"})

        def execute(self, context):
            try:
                import_glb(self.filepath)
            except (OSError, ValueError) as error:
                self.report({"ERROR"}, str(error))
                return {"CANCELLED"}
            return {"FINISHED"}

    class ExportHandles(bpy.types.Operator, ExportHelper):
        """Write the edited controllers' keys as a handles file for `bezmotion inbetween --handles`"""

        bl_idname = "bezmotion.export_handles"
        bl_label = "Export bezmotion handles"
        filename_ext = ".json"
        filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})
        everything: bpy.props.BoolProperty(name="All keys", description="every interior key, moved or not", default=False)

        def execute(self, context):
            try:
                handles, notes = export_handles(self.filepath, everything=self.everything)
            except (OSError, ValueError) as error:
                self.report({"ERROR"}, str(error))
                return {"CANCELLED"}
            for note in notes:
                self.report({"WARNING"}, note)
            self.report({"INFO"}, f"wrote {len(handles)} handles to {self.filepath}")
            return {"FINISHED"}

    for cls in (ImportCurves, ExportHandles):
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(lambda menu, _: menu.layout.operator(ImportCurves.bl_idname, text="bezmotion curves (.glb)"))
    bpy.types.TOPBAR_MT_file_export.append(lambda menu, _: menu.layout.operator(ExportHandles.bl_idname, text="bezmotion handles (.json)"))


def main(argv):
    parser = argparse.ArgumentParser(prog="blender_curves.py", description="bezmotion curves in and out of Blender")
    commands = parser.add_subparsers(dest="command", required=True)
    imp = commands.add_parser("import", help="import a .glb written by bezmotion (armature + six Bézier controllers)")
    imp.add_argument("glb")
    imp.add_argument("--blend", help="save the scene to this .blend afterwards")
    imp.add_argument("--no-armature", action="store_true", help="controllers only (skip Blender's glTF importer)")
    exp = commands.add_parser("export", help="write the edited controllers' keys as a handles JSON file")
    exp.add_argument("handles")
    exp.add_argument("--blend", help="open this .blend first")
    exp.add_argument("--all", action="store_true", help="every interior key, not only the moved ones")
    exp.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_CM, help="cm a key must move to count (default %(default)s)")
    args = parser.parse_args(argv)

    import bpy

    if args.command == "import":
        if not os.path.isfile(args.glb):
            parser.error(f"glb: no such file: {args.glb!r}")
        if bpy.app.background and not args.blend:
            print("note: headless without --blend: nothing will be saved", file=sys.stderr)
        if bpy.app.background and not bpy.data.filepath:  # a fresh headless session: an empty scene, not the default cube
            bpy.ops.wm.read_factory_settings(use_empty=True)
        try:
            made = import_glb(args.glb, armature=not args.no_armature)
        except ValueError as error:
            parser.error(f"{args.glb}: {error}")
        print(f"imported {len(made)} controllers from {args.glb}")
        if args.blend:
            bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(args.blend))
            print(f"saved {args.blend}")
    else:
        if args.blend:
            if not os.path.isfile(args.blend):
                parser.error(f"--blend: no such file: {args.blend!r}")
            bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.blend))
        try:
            handles, notes = export_handles(args.handles, tolerance_cm=args.tolerance, everything=args.all)
        except ValueError as error:
            parser.error(str(error))
        for note in notes:
            print(f"note: {note}", file=sys.stderr)
        print(f"wrote {len(handles)} handles to {args.handles}")


if __name__ == "__main__":
    if "--" in sys.argv:  # blender --background --python this.py -- import out.glb
        main(sys.argv[sys.argv.index("--") + 1 :])
    elif len(sys.argv) > 1 and sys.argv[1] in ("import", "export", "-h", "--help"):  # python this.py import … (bpy wheel)
        main(sys.argv[1:])
    else:  # Blender's Text Editor: Run Script
        _register_ui()
