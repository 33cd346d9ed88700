"""Our BVH files, imported by Blender: BVH files an animator can rig with.

A pose sequence written the way ``bezmotion demo`` and ``bezmotion inbetween`` write it
(:func:`~bezmotion.pipeline.export.pose_to_bvh` with the IK model's character and the
user's clip as template) is imported by Blender's own BVH importer, headless. Blender
must show it at 30 fps, with bones no looser than the clip's own import (location keys on
the hips and the root only, a root bone no longer than the clip's), and joints where our
FK puts them, to 1e-3 cm. Skipped without Blender (see ``tests/blender.py``).
"""

from __future__ import annotations

import json
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

from blender import find_blender, run_in_blender

from bezmotion.assets import BUNDLED_IK, DEMO_CLIP
from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.geometry.skeleton import forward_kinematics
from bezmotion.ik.protocol import pose_from_motion
from bezmotion.ik.protores import load_ik_model
from bezmotion.pipeline.export import pose_to_bvh

FRAMES = 31


def blender_import(blender: list[str], path, tmp_path) -> dict:
    """What Blender's BVH importer makes of ``path`` (scale 1: Blender units are our cm)."""
    code = textwrap.dedent(
        f"""
        import json, bpy
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.import_anim.bvh(filepath={str(path)!r}, global_scale=1.0, update_scene_fps=True,
                                 update_scene_duration=True, axis_forward="-Z", axis_up="Y")
        scene = bpy.context.scene
        arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
        bones = arm.data.bones
        located = sorted({{fc.data_path.split('"')[1] for fc in arm.animation_data.action.fcurves if fc.data_path.endswith("location")}})
        heads = []
        for f in range({FRAMES}):
            scene.frame_set(int(arm.animation_data.action.frame_range[0]) + f)
            heads.append({{b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones}})
        print("RESULT" + json.dumps({{
            "fps": scene.render.fps / scene.render.fps_base, "frames": list(arm.animation_data.action.frame_range),
            "lengths": {{b.name: b.length for b in bones}}, "parents": {{b.name: b.parent.name if b.parent else None for b in bones}},
            "located": located, "heads": heads,
        }}))
        """
    )
    stdout = run_in_blender(blender, code, tmp_path)
    return json.loads(stdout.split("RESULT", 1)[1].splitlines()[0])


def test_blender_imports_our_bvh_like_the_clip(tmp_path):
    blender = find_blender()
    if blender is None:
        pytest.skip("no Blender: neither `blender`, $BEZMOTION_BLENDER, nor a bpy venv in ~/.cache/bezmotion/bpy-venv")
    clip = read_bvh(DEMO_CLIP)
    character = load_ik_model(BUNDLED_IK).character  # the demo writes the IK model's character
    pose = pose_from_motion(character, clip.quat_local[:FRAMES], clip.pos_local[:FRAMES])
    ours = tmp_path / "ours.bvh"
    write_bvh(ours, pose_to_bvh(character, pose, template=clip))
    written = read_bvh(ours)
    _, fk = forward_kinematics(written.skeleton.parents, jnp.asarray(written.quat_local), jnp.asarray(written.pos_local))
    fk = np.asarray(fk)

    got = blender_import(blender, ours, tmp_path)
    original = blender_import(blender, DEMO_CLIP, tmp_path)
    names = written.skeleton.names
    root, hips = names[0], names[character.hips]
    assert got["fps"] == pytest.approx(30.0, rel=1e-9)  # the clip itself shows 30.00003 (its 0.0333333 s)
    assert got["frames"][1] - got["frames"][0] == FRAMES - 1
    assert original["located"] == sorted(names)  # the clip itself: a location key on every bone
    assert got["located"] == sorted({root, hips})  # ours: the root and the hips alone
    assert got["parents"] == original["parents"]
    assert got["lengths"][root] <= original["lengths"][root] + 1e-4
    np.testing.assert_allclose([got["lengths"][n] for n in names], [original["lengths"][n] for n in names], atol=1e-4)
    # Blender is Z-up: our (x, y, z) is its (x, −z, y).
    heads = np.asarray([[frame[n] for n in names] for frame in got["heads"]])
    ours_in_blender = np.stack([fk[..., 0], -fk[..., 2], fk[..., 1]], axis=-1)
    np.testing.assert_allclose(heads, ours_in_blender, atol=1e-3)
