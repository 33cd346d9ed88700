"""The Blender round trip (``bezmotion/integrations/blender_curves.py``).

Without Blender: the script imports with the standard library alone; its GLB parser reads
what :func:`bezmotion.pipeline.gltf.read_glb` reads; the Blender keyframes it makes draw our
Bézier curves (Blender's cubic with handles a third of the way in time) and give our
tangents back; moved keys become handles in the ``bezmotion inbetween --handles`` format.

With Blender (a ``blender`` binary, ``$BEZMOTION_BLENDER``, or a Python with the ``bpy``
wheel in ``~/.cache/bezmotion/bpy-venv``; skipped otherwise): import a ``.glb``, check the
F-curves Blender evaluates, move a key, export the handles.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from blender import find_blender, run_in_blender
from helpers import np_forward_kinematics

from bezmotion.assets import DEMO_CLIP
from bezmotion.bezier import BezierLayout, JoinedLayout, evaluate
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, characteristic_indices
from bezmotion.pipeline.gltf import read_glb, write_glb

SCRIPT = Path(__file__).resolve().parents[1] / "bezmotion" / "integrations" / "blender_curves.py"


def load_script():
    """The script as a plain module, by path (as Blender runs it: no bezmotion package)."""
    spec = importlib.util.spec_from_file_location("blender_curves_under_test", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


bc = load_script()


def clip_curves(frames: int, stride: int = 6, spans: tuple[int, ...] | None = None):
    """The demo clip's first ``frames`` frames and its six joints' curves (fitted by finite
    differences) on ``BezierLayout(frames, stride)``, or with ``spans`` on keys that far apart."""
    clip = read_bvh(DEMO_CLIP)
    motion = dataclasses.replace(
        clip, quat_local=clip.quat_local[:frames], pos_local=clip.pos_local[:frames], frame_time=1.0 / clip.nominal_fps
    )  # 30 fps exactly, as the pipeline writes (not the file's truncated 0.0333333 s)
    _, pos = np_forward_kinematics(motion.skeleton.parents, motion.quat_local, motion.pos_local)
    points = pos[:, characteristic_indices(motion.skeleton.names, "bandai_namco")]
    layout = BezierLayout(frames, stride) if spans is None else JoinedLayout.of(spans, stride)
    tangent = np.gradient(points, axis=0)[layout.control_frames] * (stride / 3.0)
    return motion, layout, points[layout.control_frames], tangent


def our_curve(layout, ctrl_pos, ctrl_tangent, query):
    """``(frames, 6, 3)`` our curves at fractional frames (float64)."""
    with jax.enable_x64(True):
        curves = (jnp.asarray(np.moveaxis(a, 1, 0)) for a in (ctrl_pos, ctrl_tangent))
        return np.moveaxis(np.asarray(evaluate(layout, *curves, query)), 0, 1)


def test_script_imports_neither_jax_nor_bezmotion():
    code = f"import runpy, sys; runpy.run_path({str(SCRIPT)!r}); assert not any(m == 'jax' or m.startswith(('jax.', 'bezmotion')) for m in sys.modules)"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_parse_glb_reads_what_read_glb_reads(tmp_path):
    motion, layout, ctrl_pos, ctrl_tangent = clip_curves(29)
    handles = [{"joint": "left_foot", "frame": 6, "position": [1.0, 2.0, 3.0]}]
    path = tmp_path / "out.glb"
    write_glb(path, motion, ctrl_pos, ctrl_tangent, handles=handles)
    parsed, back = bc.parse_glb(path.read_bytes()), read_glb(path)
    assert parsed["control_frames"] == layout.control_frames.tolist() == [0, 6, 12, 18, 24, 28]
    assert parsed["num_frames"] == 29 and parsed["stride"] == 6 and parsed["frame_time"] == motion.frame_time
    assert list(parsed["curves"]) == list(CHARACTERISTIC_JOINTS) and parsed["handles"] == handles
    assert parsed["key_frames"] == back.key_frames == [0, 28]  # one window's: its first and last frame
    write_glb(path, motion, ctrl_pos, ctrl_tangent, key_frames=[0, 14, 28])  # a chain's, say
    assert bc.parse_glb(path.read_bytes())["key_frames"] == read_glb(path).key_frames == [0, 14, 28]
    with pytest.raises(ValueError, match="key frames must be frames of the motion"):
        write_glb(path, motion, ctrl_pos, ctrl_tangent, key_frames=[0, 29])
    for j, joint in enumerate(CHARACTERISTIC_JOINTS):
        np.testing.assert_allclose(parsed["curves"][joint]["position"], back.ctrl_pos[:, j], rtol=0, atol=1e-9)
        np.testing.assert_allclose(parsed["curves"][joint]["tangent"], back.ctrl_tangent[:, j], rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="not a binary glTF file"):
        bc.parse_glb(b"{}")


def _bezier_fcurve(keys, frame):
    """Blender's Bézier F-curve at ``frame`` from (co, handle_left, handle_right) keys,
    solving the 2-D cubic's time for ``frame`` by bisection, as Blender does (no assumption
    that the handles sit at thirds)."""
    k = max(i for i, (co, _, _) in enumerate(keys[:-1]) if co[0] <= frame) if frame >= keys[0][0][0] else 0
    (p0, _, p1), (p3, p2, _) = keys[k], keys[k + 1]
    cubic = lambda t, a: (1 - t) ** 3 * p0[a] + 3 * (1 - t) ** 2 * t * p1[a] + 3 * (1 - t) * t * t * p2[a] + t**3 * p3[a]  # noqa: E731
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cubic(mid, 0) < frame else (lo, mid)
    return cubic(0.5 * (lo + hi), 1)


@pytest.mark.parametrize("frames", [31, 29, (8, 17, 14)])
def test_blender_keyframes_draw_our_curves_and_give_the_tangents_back(frames):
    """One window of 31 or 29 frames, or keys at unequal distances (each window's own grid)."""
    spans = frames if isinstance(frames, tuple) else None
    frames = frames if spans is None else sum(spans) + 1
    _, layout, ctrl_pos, ctrl_tangent = clip_curves(frames, spans=spans)
    query = np.linspace(0.0, frames - 1, 3 * frames)
    ours = our_curve(layout, ctrl_pos, ctrl_tangent, query)
    for j in range(6):
        axes = bc.blender_keyframes(layout.control_frames.tolist(), 6, ctrl_pos[:, j].tolist(), ctrl_tangent[:, j].tolist())
        assert [co[0] for co, _, _ in axes[0]] == layout.control_frames.tolist()
        drawn = np.asarray([[_bezier_fcurve(axes[a], f) for a in range(3)] for f in query])  # Blender metres, Z-up
        expected = np.asarray([bc.to_blender(p) for p in ours[:, j]])
        np.testing.assert_allclose(drawn, expected, atol=1e-9)
        frames_back, pos_back, tan_back = bc.curve_from_keyframes(axes, 6)
        assert frames_back == layout.control_frames.tolist()
        np.testing.assert_allclose(pos_back, ctrl_pos[:, j], atol=1e-9)
        np.testing.assert_allclose(tan_back, ctrl_tangent[:, j], atol=1e-9)


def test_axes_and_units():
    assert bc.to_blender((100.0, 200.0, 300.0)) == (1.0, -3.0, 2.0)
    np.testing.assert_allclose(bc.from_blender(bc.to_blender((1.5, -2.0, 7.25))), (1.5, -2.0, 7.25))


def test_edited_handles_are_the_moved_interior_keys():
    original = {"control_frames": [0, 6, 12, 18], "position": [[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]], "tangent": [[1, 0, 0]] * 4}
    keys = [
        (0.0, [0, 5, 0], [1, 0, 0]),  # first frame moved: the start pose, not a handle
        (6.0, [1, 1, 1.0000001], [1, 0, 0]),  # within tolerance
        (9.0, [1.5, 1.5, 1.5], [1, 0, 0]),  # a new key
        (12.0, [2, 27, 2], [1, 0, 0]),  # moved
        (18.0, [3, 3, 3], [4, 0, 0]),  # last frame (window of 19): only its tangent changed
    ]
    handles, notes = bc.edited_handles("right_hand", original, keys, num_frames=19)
    assert handles == [
        {"joint": "right_hand", "frame": 9, "position": [1.5, 1.5, 1.5]},
        {"joint": "right_hand", "frame": 12, "position": [2.0, 27.0, 2.0]},
    ]
    assert any("frame 0 moved" in n for n in notes)
    everything, _ = bc.edited_handles("right_hand", original, keys, num_frames=19, everything=True)
    assert [h["frame"] for h in everything] == [6, 9, 12]
    kept, _ = bc.edited_handles("right_hand", original, keys, num_frames=19, keep={6})
    assert [h["frame"] for h in kept] == [6, 9, 12]  # the in-between's own handle stays in the file
    keys[1] = (6.0, [1, 1, 1], [9, 0, 0])
    _, notes = bc.edited_handles("right_hand", original, keys, num_frames=31)
    assert any("tangent at frame 6 changed" in n for n in notes)
    # A chain's inner key (frame 12 of keys at 0, 12, 18) is a key pose, not a handle.
    chained, notes = bc.edited_handles("right_hand", original, keys, num_frames=19, key_frames=[0, 12, 18])
    assert [h["frame"] for h in chained] == [9] and any("frame 12 is a key pose (keys at [0, 12, 18])" in n for n in notes)


def test_round_trip_through_blender(tmp_path):
    blender = find_blender()
    if blender is None:
        pytest.skip("no Blender: neither `blender`, $BEZMOTION_BLENDER, nor a bpy venv in ~/.cache/bezmotion/bpy-venv")
    motion, layout, ctrl_pos, ctrl_tangent = clip_curves(31)
    glb = tmp_path / "out.glb"
    given = [{"joint": "left_foot", "frame": 18, "position": ctrl_pos[3, 4].tolist()}]  # the in-between's own handle
    write_glb(glb, motion, ctrl_pos, ctrl_tangent, handles=given)
    back = read_glb(glb)  # what the file holds (float32)
    query = [0.0, 1.5, 4.25, 12.0, 17.0, 29.5, 30.0]
    # Import, read what Blender evaluates, move the right hand's key at frame 12 up 25 cm
    # (Blender Z, metres), save; then export through the script's command line.
    code = textwrap.dedent(
        f"""
        import json, runpy, sys, bpy
        bc = runpy.run_path({str(SCRIPT)!r}, run_name="blender_curves")
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bc["import_glb"]({str(glb)!r})
        scene = bpy.context.scene
        out = {{"fps": scene.render.fps / scene.render.fps_base, "range": [scene.frame_start, scene.frame_end],
               "armatures": [len(o.data.bones) for o in bpy.data.objects if o.type == "ARMATURE"],
               "names": sorted(o.name for o in bpy.data.objects), "values": {{}}, "types": set()}}
        for obj in bpy.data.objects:
            if obj.name.startswith("ctrl_"):
                curves = sorted(bc["_existing_fcurves"](obj), key=lambda fc: fc.array_index)
                out["values"][obj.name] = [[fc.evaluate(f) for fc in curves] for f in {query!r}]
                for fc in curves:
                    out["types"] |= {{(k.interpolation, k.handle_left_type, k.handle_right_type) for k in fc.keyframe_points}}
                    if obj.name == "ctrl_right_hand" and fc.array_index == 2:
                        key = fc.keyframe_points[2]
                        for attr in ("co", "handle_left", "handle_right"):
                            getattr(key, attr)[1] += 0.25
        out["types"] = sorted(out["types"])
        bpy.ops.wm.save_as_mainfile(filepath={str(tmp_path / "edited.blend")!r})
        print("RESULT" + json.dumps(out))
        """
    )
    stdout = run_in_blender(blender, code, tmp_path)
    result = json.loads(stdout.split("RESULT", 1)[1].splitlines()[0])
    assert result["fps"] == pytest.approx(30.0, rel=1e-9) and result["range"] == [0, 30]
    assert result["armatures"] == [motion.skeleton.num_joints + len(motion.end_sites)]
    assert "handle_left_foot@18" in result["names"]
    assert result["types"] == [["BEZIER", "FREE", "FREE"]]
    expected = our_curve(layout, back.ctrl_pos, back.ctrl_tangent, np.asarray(query))
    for j, joint in enumerate(CHARACTERISTIC_JOINTS):
        blender_m = np.asarray(result["values"][f"ctrl_{joint}"])
        ours_cm = np.asarray([bc.from_blender(p) for p in blender_m])
        np.testing.assert_allclose(ours_cm, expected[:, j], atol=1e-4)  # cm: Blender keeps float32 metres
    # Export through the command line, as an animator would.
    handles_file = tmp_path / "handles.json"
    args = ["export", str(handles_file), "--blend", str(tmp_path / "edited.blend")]
    if blender[-1] == "--python-expr":
        command = [*blender[:-1], "--python", str(SCRIPT), "--", *args]
    else:
        command = [*blender, str(SCRIPT), *args]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    handles = json.loads(handles_file.read_text())
    # The moved key, and the handle the in-between was made with (unmoved), in cm, Y-up.
    assert [(h["joint"], h["frame"]) for h in handles] == [("right_hand", 12), ("left_foot", 18)]
    moved = back.ctrl_pos[2, CHARACTERISTIC_JOINTS.index("right_hand")] + [0.0, 25.0, 0.0]
    np.testing.assert_allclose(handles[0]["position"], moved, atol=1e-4)
    np.testing.assert_allclose(handles[1]["position"], given[0]["position"], atol=1e-4)


def test_run_from_blenders_ui_adds_the_menu_operators(tmp_path):
    blender = find_blender()
    if blender is None:
        pytest.skip("no Blender: neither `blender`, $BEZMOTION_BLENDER, nor a bpy venv in ~/.cache/bezmotion/bpy-venv")
    code = textwrap.dedent(
        f"""
        import runpy, bpy
        runpy.run_path({str(SCRIPT)!r}, run_name="__main__")  # as the Text Editor's Run Script does
        props = bpy.ops.bezmotion.export_handles.get_rna_type().properties.keys()
        assert "everything" in props and "filepath" in props, list(props)
        assert "filepath" in bpy.ops.bezmotion.import_curves.get_rna_type().properties.keys()
        print("UI-OK")
        """
    )
    assert "UI-OK" in run_in_blender(blender, code, tmp_path)
