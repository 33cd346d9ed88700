"""glTF export (``bezmotion.pipeline.gltf``): the file reads back to float32 precision, its
CUBICSPLINE samplers evaluated by the glTF spec's own formula are our Bézier curves, the
Khronos validator accepts it (when installed), and bad input is refused.

Real data in NumPy only (no JAX compile): the bundled clip's first frames, curves through
its six characteristic joints with finite-difference tangents.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from helpers import np_forward_kinematics

from bezmotion.assets import DEMO_CLIP
from bezmotion.bezier import BezierLayout, evaluate
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS, characteristic_indices
from bezmotion.pipeline.gltf import METRES_PER_CM, find_gltf_validator, read_glb, validate_glb, write_glb

EPS32 = float(np.finfo(np.float32).eps)
HANDLES = [{"joint": "right_hand", "frame": 12, "position": [10.5, 120.25, -3.0]}]


def window(frames: int, stride: int = 6):
    """The clip's first ``frames`` frames and curves ``(controls, 6, 3)`` through its six joints."""
    clip = read_bvh(DEMO_CLIP)
    motion = dataclasses.replace(clip, quat_local=clip.quat_local[:frames], pos_local=clip.pos_local[:frames])
    _, pos = np_forward_kinematics(motion.skeleton.parents, motion.quat_local, motion.pos_local)
    points = pos[:, characteristic_indices(motion.skeleton.names, "bandai_namco")]  # (frames, 6, 3)
    layout = BezierLayout(frames, stride)
    velocity = np.gradient(points, axis=0)  # cm per frame; T = velocity · s / 3
    return motion, layout, points[layout.control_frames], velocity[layout.control_frames] * (stride / 3.0)


def f32_close(actual, expected, what: str) -> None:
    """Equal to what float32 metres can hold: a few ulps of the largest magnitude."""
    expected = np.asarray(expected, np.float64)
    tol = 4 * EPS32 * max(np.abs(expected).max(), 1.0)
    err = np.abs(np.asarray(actual) - expected).max()
    assert err <= tol, f"{what}: max error {err:.3g} > {tol:.3g}"


@pytest.mark.parametrize("frames", [31, 29])  # 29: a 4-frame last segment
def test_glb_round_trip_to_float32(tmp_path, frames):
    motion, layout, ctrl_pos, ctrl_tangent = window(frames)
    path = tmp_path / "out.glb"
    write_glb(path, motion, ctrl_pos, ctrl_tangent, stride=6, handles=HANDLES)
    back = read_glb(path)
    assert back.motion.skeleton.names == motion.skeleton.names
    assert back.motion.skeleton.parents == motion.skeleton.parents
    f32_close(back.motion.skeleton.offsets, motion.skeleton.offsets, "offsets")
    assert [j for j, _ in back.motion.end_sites] == [j for j, _ in motion.end_sites]
    f32_close([o for _, o in back.motion.end_sites], [o for _, o in motion.end_sites], "end sites")
    assert back.motion.frame_time == motion.frame_time
    # Translations are animated where the clip has position channels (all joints here), rotations everywhere.
    f32_close(back.motion.pos_local, motion.pos_local, "translations")
    sign = np.sign(np.sum(back.motion.quat_local * motion.quat_local, axis=-1, keepdims=True))
    f32_close(back.motion.quat_local * sign, motion.quat_local, "rotations")
    assert back.layout == layout and back.joints == CHARACTERISTIC_JOINTS
    f32_close(back.ctrl_pos, ctrl_pos, "control points")
    f32_close(back.ctrl_tangent, ctrl_tangent, "tangents")
    assert back.handles == HANDLES


def _hermite(times, keys, t):
    """glTF 2.0 Appendix C: CUBICSPLINE at time ``t`` from (keys, in/value/out, 3) outputs."""
    k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
    td = times[k + 1] - times[k]
    s = (t - times[k]) / td
    v0, b0 = keys[k, 1], keys[k, 2]
    v1, a1 = keys[k + 1, 1], keys[k + 1, 0]
    return (
        (2 * s**3 - 3 * s**2 + 1) * v0 + td * (s**3 - 2 * s**2 + s) * b0 + (-2 * s**3 + 3 * s**2) * v1 + td * (s**3 - s**2) * a1
    )


@pytest.mark.parametrize("frames", [31, 29])
def test_cubicspline_samplers_are_our_curves(tmp_path, frames):
    """Evaluated by the spec's formula from the raw file (pygltflib, not our reader), the
    controllers follow :func:`bezmotion.bezier.evaluate` at fractional frames, also across
    a shorter last segment: the key-interval scaling of the tangents is right."""
    import pygltflib

    motion, layout, ctrl_pos, ctrl_tangent = window(frames)
    path = tmp_path / "out.glb"
    write_glb(path, motion, ctrl_pos, ctrl_tangent, stride=6)
    gltf = pygltflib.GLTF2.load(str(path))
    blob = gltf.binary_blob()

    def array(index, width):
        acc = gltf.accessors[index]
        view = gltf.bufferViews[acc.bufferView]
        return np.frombuffer(blob, np.float32, acc.count * width, view.byteOffset or 0).reshape(acc.count, width).astype(np.float64)

    query = np.linspace(0.0, frames - 1, 4 * frames)
    with jax.enable_x64(True):
        curves = (jnp.asarray(np.moveaxis(a, 1, 0)) for a in (ctrl_pos, ctrl_tangent))
        expected = np.moveaxis(np.asarray(evaluate(layout, *curves, query)), 0, 1)  # (frames, 6, 3)
    animation = gltf.animations[0]
    seen = 0
    for channel in animation.channels:
        node = gltf.nodes[channel.target.node]
        if not node.name.startswith("ctrl_"):
            continue
        sampler = animation.samplers[channel.sampler]
        assert sampler.interpolation == "CUBICSPLINE" and channel.target.path == "translation"
        times = array(sampler.input, 1)[:, 0]
        np.testing.assert_allclose(times * 30.0, layout.control_frames, atol=1e-4)
        keys = array(sampler.output, 3).reshape(-1, 3, 3)
        assert not keys[0, 0].any() and not keys[-1, 2].any()  # first in-, last out-tangent zero
        j = CHARACTERISTIC_JOINTS.index(node.name.removeprefix("ctrl_"))
        got = np.stack([_hermite(times, keys, f * motion.frame_time) for f in query]) / METRES_PER_CM
        np.testing.assert_allclose(got, expected[:, j], atol=2e-3)  # cm; float32 metres and times
        seen += 1
    assert seen == 6


def test_glb_without_curves_and_step_interpolation(tmp_path):
    motion, *_ = window(7)
    path = tmp_path / "skeleton.glb"
    write_glb(path, motion, interpolation="STEP")
    back = read_glb(path)
    assert back.layout is None and back.ctrl_pos.shape == (0, 6, 3) and back.joints == ()
    f32_close(back.motion.pos_local, motion.pos_local, "translations")
    import pygltflib

    gltf = pygltflib.GLTF2.load(str(path))
    assert {s.interpolation for s in gltf.animations[0].samplers} == {"STEP"}


def test_glb_passes_the_khronos_validator(tmp_path):
    validator = find_gltf_validator()
    if validator is None:
        pytest.skip("gltf-validator (npm) or node not installed; see bezmotion.pipeline.gltf.find_gltf_validator")
    motion, _, ctrl_pos, ctrl_tangent = window(31)
    path = tmp_path / "out.glb"
    write_glb(path, motion, ctrl_pos, ctrl_tangent, handles=HANDLES)
    report = validate_glb(path, validator)
    issues = report["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    # What remains is information: animated empties and a skin no mesh uses.
    assert {m["code"] for m in issues["messages"]} <= {"NODE_EMPTY", "UNUSED_OBJECT"}


def test_glb_bad_input_is_refused(tmp_path):
    motion, layout, ctrl_pos, ctrl_tangent = window(31)
    path = tmp_path / "bad.glb"
    with pytest.raises(ValueError, match="interpolation must be one of .* got 'CUBIC'"):
        write_glb(path, motion, interpolation="CUBIC")
    with pytest.raises(ValueError, match=r"ctrl_pos must be \(6, 6, 3\) for 31 frames at stride 6, got \(5, 6, 3\)"):
        write_glb(path, motion, ctrl_pos[:5], ctrl_tangent[:5])
    with pytest.raises(ValueError, match="both ctrl_pos and ctrl_tangent"):
        write_glb(path, motion, ctrl_pos)
    bad = ctrl_tangent.copy()
    bad[2, 1, 0] = np.nan
    with pytest.raises(ValueError, match="ctrl_tangent contains non-finite values"):
        write_glb(path, motion, ctrl_pos, bad)
    with pytest.raises(ValueError, match="handle 0: joint must be one of .* got 'tail'"):
        write_glb(path, motion, handles=[{"joint": "tail", "frame": 3, "position": [0, 0, 0]}])
    with pytest.raises(ValueError, match=r"handle 0: frame must be an integer in 0…30, got 31"):
        write_glb(path, motion, handles=[{"joint": "head", "frame": 31, "position": [0, 0, 0]}])
    assert not path.exists()
    text = tmp_path / "not.glb"
    text.write_text("hello")
    with pytest.raises(ValueError, match="not a binary glTF file"):
        read_glb(text)
