"""``bezmotion inbetween`` on the bundled clip with the bundled BMM: the written BVH's own
forward kinematics hits the handles; samples differ; the glTF file and the preview carry
the same motion; other skeletons work through a mapping file and the analytic rig; and
every bad argument exits with status 2, one line naming the argument and its value, and
writes nothing.

The analytic rig (``--ik rig``) is used throughout: it reaches hands and feet exactly, so a
handle missed by more than float32 rounding is a bug here, not the IK's approximation.
Two DDIM steps; handles are padded to a fixed count, so most runs share one compilation.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import re
import shutil

import jax.numpy as jnp
import numpy as np
import pytest

from helpers import np_forward_kinematics, turned_about_z

from bezmotion._src.output_sets import OUTPUTS_RECORD
from bezmotion.assets import DEMO_CLIP
from bezmotion.cli import main
from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.data.clip_frame import ClipFrame
from bezmotion.data.resample import resample_motion
from bezmotion.cli.handles import HandleRequest, parse_handle, read_handles_file
from bezmotion.cli.plan import InbetweenCommand, bvh_frame_rate, plan
from bezmotion.ik.protocol import targets_from_pose
from bezmotion._src.options import parse_options
from bezmotion.pipeline.authoring import RigSpec, derive_rig_spec, read_mapping, recognise_character

FAST = ["--ik", "rig", "--steps", "2", "--no-progress"]
HAND, FOOT = "Hand_R", "Foot_L"  # the clip's right hand and left ankle


@pytest.fixture(autouse=True)
def in_a_folder_of_its_own(tmp_path, monkeypatch):
    """Each test in its own working folder: a run's default ``--out`` (results/inbetween) is
    then the test's, not whatever an earlier run left in the repository's."""
    monkeypatch.chdir(tmp_path)


def fk_positions(motion) -> np.ndarray:
    """``(frames, joints, 3)`` global positions (cm) of a motion, by a plain NumPy loop."""
    return np_forward_kinematics(motion.skeleton.parents, motion.quat_local, motion.pos_local)[1]


def straight_line(joint: str, frame: int, first: int = 0, last: int = 30) -> np.ndarray:
    """Where ``joint`` is at ``frame`` on the straight line between clip frames ``first`` and ``last``."""
    clip = read_bvh(DEMO_CLIP)
    pos = fk_positions(clip)[:, clip.skeleton.names.index(joint)]
    t = frame / 30
    return (1 - t) * pos[first] + t * pos[last]


def run_cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(["inbetween", *map(str, argv)])
        except SystemExit as exit_:  # argparse's own errors
            code = exit_.code
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Frames 0 and 30 of the clip, a right-hand handle 25 cm above the straight line at frame
    12 and an absolute left-foot handle at frame 18, two samples, into a folder (progress shown)."""
    out = tmp_path_factory.mktemp("inbetween") / "take"
    foot = straight_line(FOOT, 18) + np.array([0.0, 8.0, 5.0])
    code, stdout, stderr = run_cli(
        DEMO_CLIP, "--frames", "0", "30", "--handle", "right_hand@12=+0,25,0", "--handle", f"{FOOT}@18={','.join(map(str, foot))}",
        "--ik", "rig", "--steps", "2", "--samples", "2", "--no-preview", "--out", out,
    )  # fmt: skip
    assert code == 0, stderr
    return out, json.loads((out / "summary.json").read_text()), foot, stdout, stderr


def test_the_bvh_hits_the_handles_in_its_own_fk(run):
    out, summary, foot, _, _ = run
    for k in range(2):
        motion = read_bvh(out / f"inbetween_{k}.bvh")
        pos = fk_positions(motion)
        names = motion.skeleton.names
        # The relative handle: 25 cm above the straight line between the keys' hands.
        np.testing.assert_allclose(pos[12, names.index(HAND)], straight_line(HAND, 12) + [0, 25, 0], atol=1e-3)
        np.testing.assert_allclose(pos[18, names.index(FOOT)], foot, atol=1e-3)
        assert max(summary["samples"][k]["handle_errors_cm"]) < 1e-3
        assert summary["samples"][k]["bvh_fk_error_cm"] < 1e-3


def test_the_bvh_starts_and_ends_on_the_keys_and_rigs_like_the_clip(run):
    out, _, _, _, _ = run
    clip = read_bvh(DEMO_CLIP)
    motion = read_bvh(out / "inbetween_0.bvh")
    assert motion.num_frames == 31 and abs(motion.fps - 30.0) < 1e-9
    np.testing.assert_allclose(motion.skeleton.offsets, clip.skeleton.offsets, atol=1e-6)
    assert motion.end_sites == clip.end_sites
    np.testing.assert_allclose(fk_positions(motion)[[0, 30]], fk_positions(clip)[[0, 30]], atol=1e-3)


def test_two_samples_are_two_different_motions(run):
    out, summary, _, _, _ = run
    a, b = (fk_positions(read_bvh(out / f"inbetween_{k}.bvh")) for k in range(2))
    # Another seed, another in-between: float rounding moves joints by < 1e-3 cm. How far the
    # two samples part is the model's (the bundled BMM, held by both keys' poses and
    # orientations and two handles, 2 DDIM steps); the bar sits a hundred times above rounding.
    assert np.abs(a - b).max() > 0.1  # cm
    assert [s["sample"] for s in summary["samples"]] == [0, 1]
    assert summary["foot_lock"] is True and summary["exact"] == {}  # the defaults
    for sample in summary["samples"]:  # where the body jumps or leaves its curves
        assert set(sample["largest_turn_deg"]) == {"deg", "joint", "frames"} and sample["largest_turn_deg"]["deg"] > 0.0
        assert sample["curve_error_max_cm"]["cm"] >= 0.0 and 0 <= sample["curve_error_max_cm"]["frame"] <= 30
    assert sorted(p.name for p in out.iterdir()) == [
        OUTPUTS_RECORD, "inbetween_0.bvh", "inbetween_0.glb", "inbetween_1.bvh", "inbetween_1.glb", "summary.json"
    ]  # fmt: skip


def test_the_glb_carries_the_same_motion_curves_and_handles(run):
    """Read back by our reader; valid for the Khronos validator when it is installed."""
    from bezmotion.pipeline.gltf import find_gltf_validator, read_glb, validate_glb

    out, summary, _, _, _ = run
    glb, bvh = read_glb(out / "inbetween_0.glb"), read_bvh(out / "inbetween_0.bvh")
    np.testing.assert_allclose(fk_positions(glb.motion), fk_positions(bvh), atol=1e-2)
    assert glb.handles == summary["handles"]
    hand = summary["handles"][0]
    np.testing.assert_allclose(glb.ctrl_pos[hand["frame"] // 6, glb.joints.index("right_hand")], hand["position"], atol=1e-4)
    if find_gltf_validator() is not None:
        assert validate_glb(out / "inbetween_0.glb")["issues"]["numErrors"] == 0


def test_progress_goes_to_stderr_and_results_to_stdout(run):
    _, _, _, stdout, stderr = run
    assert "sample 1/2" in stderr and "sample 2/2" in stderr and "compiling" in stderr
    assert stdout.count("handles hit within") == 2


def test_handles_out_of_reach_are_reported_with_why(tmp_path):
    """On frame 15 a hips handle and a left-foot handle 120 cm below the foot's straight line,
    farther apart than the leg is long: a warning before sampling that no pose meets both. A
    right-hand handle 200 cm above its straight line: reported after the run as missed, beyond
    the arm's reach. A handle that is hit gets no line. Both reports reach stderr under
    --no-progress too (they are results, not progress), and stdout counts the misses."""
    out = tmp_path / "far"
    code, stdout, stderr = run_cli(
        DEMO_CLIP, "--frames", "0", "30", "--handle", "hips@15=+0,0,0", "--handle", "left_foot@15=+0,-120,0",
        "--handle", "right_hand@20=+0,200,0", "--handle", "left_hand@12=+0,5,0", "--no-preview", "--out", out, *FAST,
    )  # fmt: skip
    assert code == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    (warning,) = summary["handle_warnings"]
    apart, reach = map(float, re.match(r"handles hips@15 and left_foot@15 lie ([\d.]+) cm apart, .* \(([\d.]+) cm\): no pose meets both", warning).groups())
    assert apart > 150.0 and 80.0 < reach < 100.0  # the foot's straight line lies ~80 cm below the hips'; the leg ~87 cm
    misses = summary["samples"][0]["handle_misses"]
    errors = dict(zip((f"{h['joint']}@{h['frame']}" for h in summary["handles"]), summary["samples"][0]["handle_errors_cm"]))
    assert errors["right_hand@20"] > 100.0 and errors["left_foot@15"] > 20.0 and errors["left_hand@12"] < 1e-3
    assert f"handle right_hand@20 missed by {errors['right_hand@20']:.1f} cm: beyond the limb's reach from where the IK put its root" in misses
    assert any(m.startswith("handle left_foot@15 missed by") for m in misses)
    assert not any("left_hand" in m or "hips" in m for m in misses)
    assert stderr.splitlines() == [f"bezmotion inbetween: {line}" for line in [f"warning: {warning}", *misses]]
    assert f"{len(misses)} of 4 handle(s) missed, by up to {max(errors.values()):.1f} cm" in stdout and "hit within" not in stdout


def test_two_files_and_a_gif(tmp_path):
    """``--start``/``--end`` put any two poses 30 frames apart (here clip frames 0 and 12);
    ``--out x.gif`` writes the preview alone, one GIF frame per motion frame."""
    from PIL import Image

    clip = tmp_path / "walk copy.bvh"
    shutil.copy(DEMO_CLIP, clip)
    code, _, err = run_cli("--start", f"{DEMO_CLIP}@0", "--end", f"{clip}@12", "--handle", "right_hand@12=+0,25,0", *FAST, "--out", tmp_path / "x.gif")
    assert code == 0, err
    with Image.open(tmp_path / "x.gif") as gif:
        assert gif.n_frames == 31
    code, _, err = run_cli("--start", f"{DEMO_CLIP}@0", "--end", f"{clip}@12", "--handle", "right_hand@12=+0,25,0", *FAST, "--out", tmp_path / "x.bvh")
    assert code == 0, err
    motion = read_bvh(tmp_path / "x.bvh")
    hand = motion.skeleton.names.index(HAND)
    np.testing.assert_allclose(fk_positions(motion)[12, hand], straight_line(HAND, 12, 0, 12) + [0, 25, 0], atol=1e-3)
    assert sorted(p.name for p in tmp_path.iterdir()) == [OUTPUTS_RECORD, "walk copy.bvh", "x.bvh", "x.gif"]


# ------------------------------------------------------------------- other skeletons


def renamed_clip(tmp_path):
    """The bundled clip with every joint renamed ``my_*``: a skeleton no preset knows."""
    text = DEMO_CLIP.read_text()
    for name in read_bvh(DEMO_CLIP).skeleton.names:
        text = text.replace(f"ROOT {name}", f"ROOT my_{name}").replace(f"JOINT {name}", f"JOINT my_{name}")
    path = tmp_path / "custom.bvh"
    path.write_text(text)
    return path


def numbered_clip(tmp_path):
    """The bundled clip with its joints named ``j0``, ``j1``, …: names that say nothing."""
    text = DEMO_CLIP.read_text()
    for i, name in enumerate(read_bvh(DEMO_CLIP).skeleton.names):
        text = text.replace(f"ROOT {name}\n", f"ROOT j{i}\n").replace(f"JOINT {name}\n", f"JOINT j{i}\n")
    path = tmp_path / "numbered.bvh"
    path.write_text(text)
    return path


def test_a_skeleton_no_preset_knows_has_its_joints_read_off_their_names(tmp_path):
    """Without ``--mapping``, the ``my_*`` clip's six joints are read off their names: the
    character and rig of the mapping file naming them, and a warning that lists them."""
    clip = renamed_clip(tmp_path)
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({role: f"my_{name}" for role, name in ROLES.items()}))
    read_off = plan(parse_options(InbetweenCommand, [str(clip), "--frames", "0", "30", *FAST]))
    mapped = plan(parse_options(InbetweenCommand, [str(clip), "--frames", "0", "30", "--mapping", str(mapping), *FAST]))
    assert read_off.recognised.read_off_names == {role: f"my_{name}" for role, name in ROLES.items()}
    assert mapped.recognised.read_off_names is None
    assert read_off.recognised.character.characteristic == mapped.recognised.character.characteristic
    assert read_off.recognised.rig_spec == mapped.recognised.rig_spec
    assert [w for w in read_off.warnings if "read off their names" in w] == [
        f"{clip}: no known skeleton; its six joints read off their names: hips my_Hips, head my_Head, left_hand my_Hand_L, "
        "right_hand my_Hand_R, left_foot my_Foot_L, right_foot my_Foot_R (--mapping MAP.json names others)"
    ]


def test_a_clip_in_metres_with_z_up_gives_the_same_in_between_written_in_its_own_units(tmp_path):
    """The bundled clip written in metres with Z up (as Blender exports BVH): its units and up
    axis are told from it, the in-between is the cm clip's (handles in cm, Y up), and the
    written BVH is in metres with Z up; --units/--up given skip the telling, same result."""
    theirs = ClipFrame("m", "z")
    clip = tmp_path / "blender.bvh"
    write_bvh(clip, theirs.from_ours(read_bvh(DEMO_CLIP)), precision=10)
    handle = ["--handle", "right_hand@12=+0,25,0", "left_foot@18=+0,8,5"]
    runs = {}
    for name, argv in {"cm": [DEMO_CLIP], "told": [clip], "given": [clip, "--units", "m", "--up", "z"]}.items():
        out = tmp_path / name
        code, _, stderr = run_cli(*argv, "--frames", "0", "30", *handle, "--no-preview", "--out", out, *FAST)
        assert code == 0, stderr
        runs[name] = json.loads((out / "summary.json").read_text()), read_bvh(out / "inbetween.bvh")
    assert runs["cm"][0]["clip_units"] == {"units": "cm", "up": "y"}
    ours = fk_positions(runs["cm"][1])
    for name in ("told", "given"):
        summary, written = runs[name]
        assert summary["clip_units"] == {"units": "m", "up": "z"}
        np.testing.assert_allclose(written.skeleton.offsets, np.asarray(read_bvh(DEMO_CLIP).skeleton.offsets) / 100, rtol=0, atol=1e-8)  # 8 decimals
        np.testing.assert_allclose(fk_positions(theirs.to_ours(written)), ours, atol=1e-3)
        assert summary["handles"] == runs["cm"][0]["handles"] and max(summary["samples"][0]["handle_errors_cm"]) < 1e-3
        assert summary["samples"][0]["bvh_fk_error_cm"] < 1e-3


def test_a_clip_at_120_fps_is_in_betweened_at_the_models_30_over_one_second(tmp_path):
    """The bundled 30 fps clip upsampled to 120 fps: its keys one second apart are frames 0 and
    120, the clip is resampled to the BMM's 30 fps (a warning says so), and the in-between is
    the 30 fps clip's, its BVH written at the clip's 120 fps (every 4th frame the 30 fps
    in-between's, keys and handle included, those between slerped) or with ``--bvh-fps 30`` at
    30. At 120 fps, frames 0 and 30 are a quarter of a second apart: refused, naming the
    frames that make one second; at 29.97 fps no whole number of frames is one second."""
    fast, _ = resample_motion(read_bvh(DEMO_CLIP), 120.0)
    clip = tmp_path / "fast.bvh"
    write_bvh(clip, fast, precision=10)
    handle = ["--handle", "right_hand@12=+0,25,0"]
    runs = {}
    cases = {
        "30": [DEMO_CLIP, "--frames", "0", "30"], "120": [clip, "--frames", "0", "120"],
        "120 to 30": [clip, "--frames", "0", "120", "--bvh-fps", "30"],
    }  # fmt: skip
    for name, argv in cases.items():
        out = tmp_path / name.replace(" ", "_")
        code, _, stderr = run_cli(*argv, *handle, "--no-preview", "--out", out, *FAST)
        assert code == 0, stderr
        runs[name] = json.loads((out / "summary.json").read_text()), read_bvh(out / "inbetween.bvh"), stderr
    at_30 = fk_positions(runs["30"][1])
    summary, written, stderr = runs["120"]
    assert summary["fps"] == 30.0 and summary["clip_fps"] == 120.0 and summary["bvh_fps"] == 120.0
    assert written.nominal_fps == 120.0 and written.num_frames == 121
    (warning,) = summary["input_warnings"]
    assert warning == (
        f"{clip}: 120 fps, resampled to the BMM's 30 fps; the in-between is made at 30 fps and its BVH file written at 120 (--bvh-fps)"
    ) and f"warning: {warning}" in stderr
    at_120 = fk_positions(written)
    np.testing.assert_allclose(at_120[::4], at_30, atol=1e-3)  # the in-between's own frames, keys and handle too
    assert summary["samples"][0]["bvh_fk_error_cm"] < 1e-3 and max(summary["samples"][0]["handle_errors_cm"]) < 1e-3
    # Between them a quarter of a 30 fps frame's step at a time, not a hold and a jump.
    step = lambda pos: np.linalg.norm(np.diff(pos, axis=0), axis=-1).max()  # noqa: E731
    assert step(at_120) < 0.35 * step(at_30)
    summary, written, stderr = runs["120 to 30"]
    assert summary["bvh_fps"] == 30.0 and written.nominal_fps == 30.0 and written.num_frames == 31
    assert summary["input_warnings"] == [f"{clip}: 120 fps, resampled to the BMM's 30 fps; the in-between is written at 30 fps"]
    np.testing.assert_allclose(fk_positions(written), at_30, atol=1e-3)
    assert runs["30"][0]["clip_fps"] == 30.0 and runs["30"][0]["bvh_fps"] == 30.0 and not runs["30"][0]["input_warnings"]
    code, _, stderr = run_cli(clip, "--frames", "0", "30", *FAST)
    assert code == 2 and (
        "--frames 0 30: 30 frames at the clip's 120 fps are 7.5 frames at 30 fps, not a whole number; space the keys a multiple of 4 frames apart"
    ) in stderr, stderr
    ntsc = tmp_path / "ntsc.bvh"
    write_bvh(ntsc, dataclasses.replace(read_bvh(DEMO_CLIP), frame_time=1.0 / 29.97))
    code, _, stderr = run_cli(ntsc, "--frames", "0", "30", *FAST)
    assert code == 2 and "--frames 0 30: 30 frames at the clip's 29.97 fps are 30.03 frames at 30 fps, not a whole number; resample the clip to 30 fps" in stderr, stderr


def test_keys_any_distance_apart_keep_the_clips_timing(tmp_path):
    """CLIP ``--frames 5 25``: keys 20 frames apart in-between 21 frames, not retimed to 30;
    ``--start/--end --gap 45``: two poses put 45 frames apart; CLIP ``--frames 0 8 25 39``: a
    chain of unequal windows. Keys, handles and the glTF file's curves (each window's last
    segment shorter) hold as at 30 frames."""
    from bezmotion.bezier import BezierLayout, JoinedLayout, evaluate
    from bezmotion.pipeline.gltf import read_glb

    clip = read_bvh(DEMO_CLIP)
    cases = {
        "clip": ([DEMO_CLIP, "--frames", "5", "25", "--handle", "right_hand@8=+0,20,0"], (0, 20), (5, 25)),
        "gap": (["--start", f"{DEMO_CLIP}@0", "--end", f"{DEMO_CLIP}@39", "--gap", "45", "--handle", "left_hand@31=+0,10,0"], (0, 45), (0, 39)),
        "unequal": ([DEMO_CLIP, "--frames", "0", "8", "25", "39", "--handle", "left_hand@32=+0,10,0"], (0, 8, 25, 39), (0, 8, 25, 39)),
    }
    for name, (argv, key_frames, keys) in cases.items():
        out = tmp_path / name
        code, _, stderr = run_cli(*argv, "--out", out, *FAST)
        assert code == 0, stderr
        summary = json.loads((out / "summary.json").read_text())
        gaps = set(np.diff(key_frames).tolist())
        assert summary["key_frames"] == list(key_frames) and summary["frames"] == key_frames[-1] + 1
        assert summary["gap"] == (gaps.pop() if len(gaps) == 1 else None)
        written = read_bvh(out / "inbetween.bvh")
        assert written.num_frames == key_frames[-1] + 1
        pos, given = fk_positions(written), fk_positions(clip)
        np.testing.assert_allclose(pos[list(key_frames)], given[list(keys)], atol=1e-3)
        assert max(summary["samples"][0]["handle_errors_cm"]) < 1e-3 and summary["samples"][0]["bvh_fk_error_cm"] < 1e-3
        glb = read_glb(out / "inbetween.glb")
        expected = BezierLayout(key_frames[-1] + 1) if len(key_frames) == 2 else JoinedLayout.of(np.diff(key_frames).tolist())
        assert glb.layout == expected and glb.key_frames == list(key_frames)
        (handle,) = summary["handles"]
        dense = np.asarray(evaluate(glb.layout, *(jnp.asarray(a.swapaxes(0, 1), jnp.float32) for a in (glb.ctrl_pos, glb.ctrl_tangent))))  # (6, frames, 3)
        np.testing.assert_allclose(dense[glb.joints.index(handle["joint"]), handle["frame"]], handle["position"], atol=1e-3)
    assert (tmp_path / "unequal" / "preview.gif").stat().st_size > 0


def test_key_poses_of_any_files_take_a_gap_each(tmp_path):
    """``--key`` poses with ``--gap G`` are G apart; with one gap per pair, each its own."""
    keys = ["--key", f"{DEMO_CLIP}@0", "--key", f"{DEMO_CLIP}@9", "--key", f"{DEMO_CLIP}@20"]
    for gaps, times in (([], (0, 30, 60)), (["20"], (0, 20, 40)), (["20", "45"], (0, 20, 65))):
        argv = [*keys, *(["--gap", *gaps] if gaps else []), *FAST, "--out", str(tmp_path / "x.bvh")]
        assert plan(parse_options(InbetweenCommand, argv)).key_times == times


def test_a_clip_in_no_named_unit_is_taken_for_a_typical_adult_and_said(tmp_path):
    """A skeleton a person's size in none of cm, m and mm (raw CMU's ~5.6 cm unit; here the
    demo's actor 1000× smaller) is scaled to a typical adult, with a warning; the BVH is
    written back in the clip's own unit. A bad --units is refused in one line."""
    clip = read_bvh(DEMO_CLIP)
    tiny = tmp_path / "tiny.bvh"
    write_bvh(tiny, dataclasses.replace(clip, skeleton=dataclasses.replace(clip.skeleton, offsets=np.asarray(clip.skeleton.offsets) * 1e-3), pos_local=clip.pos_local * 1e-3), precision=10)
    out = tmp_path / "out"
    code, _, stderr = run_cli(tiny, "--frames", "0", "30", "--no-preview", "--out", out, *FAST)
    assert code == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    units = float(summary["clip_units"]["units"])
    assert 800.0 < units < 1400.0  # the demo's actor is 134 cm head to hips to foot, a typical adult 150
    assert f"1 unit = {units:.4g} cm" in stderr and "a person's size in none of cm, m or mm" in summary["input_warnings"][0]
    written = read_bvh(out / "inbetween.bvh")
    np.testing.assert_allclose(np.asarray(written.skeleton.offsets)[1:], np.asarray(clip.skeleton.offsets)[1:] * 1e-3, rtol=1e-4, atol=1e-9)
    for bad in ("km", "0", "-1"):
        code, _, stderr = run_cli(tiny, "--frames", "0", "30", "--units", bad, *FAST)
        assert code == 2 and f"--units {bad}: units must be one of cm, m, mm, in or centimetres per unit (a number), got '{bad}'" in stderr, stderr
        assert len(stderr.strip().splitlines()) == 1
    code, _, stderr = run_cli(tiny, "--frames", "0", "30", "--units", "mm", "--up", "x", *FAST)
    assert code == 2 and "argument --up: invalid choice: 'x'" in stderr


def test_an_up_axis_no_frame_tells_is_taken_as_y_with_a_warning(tmp_path):
    """A clip lying along X in every frame: Y up is taken (the BVH custom), and said."""
    lying = tmp_path / "lying.bvh"
    write_bvh(lying, turned_about_z(read_bvh(DEMO_CLIP), 90.0))
    out = tmp_path / "out"
    code, _, stderr = run_cli(lying, "--frames", "0", "30", "--no-preview", "--out", out, *FAST)
    assert code == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["clip_units"] == {"units": "cm", "up": "y"}
    (warning,) = summary["input_warnings"]
    assert warning.startswith("cannot tell the clip's up axis: of 40 frames, the head stands above the feet along +X in 0, −X in 40")
    assert warning.endswith("taking Y up, the BVH custom (--up says it)") and f"warning: {warning}" in stderr


ROLES = {"hips": "Hips", "head": "Head", "left_hand": "Hand_L", "right_hand": "Hand_R", "left_foot": "Foot_L", "right_foot": "Foot_R"}


def test_another_skeleton_through_a_mapping_file_and_the_rig(tmp_path):
    clip = renamed_clip(tmp_path)
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({role: f"my_{name}" for role, name in ROLES.items()}))
    code, _, err = run_cli(clip, "--frames", "0", "30", "--mapping", mapping, "--handle", "my_Hand_R@12=+0,25,0", *FAST, "--out", tmp_path / "o.bvh")
    assert code == 0, err
    motion = read_bvh(tmp_path / "o.bvh")
    hand = motion.skeleton.names.index("my_Hand_R")
    np.testing.assert_allclose(fk_positions(motion)[12, hand], straight_line(HAND, 12) + [0, 25, 0], atol=1e-3)


def test_another_skeleton_gets_the_exact_solve_from_the_rig_by_default(tmp_path):
    """``--ik auto`` on a skeleton no learned IK knows: the rig's poses, then the exact solve
    (``exact_rig``). A foot handle 12 cm below the straight line lies beyond the leg's reach
    from where the rig keeps the hips (on their curve: it misses by ~9 cm); the exact solve
    lowers the hips (unpinned, they give way to the handle) and meets it."""
    clip = renamed_clip(tmp_path)
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({role: f"my_{name}" for role, name in ROLES.items()}))
    argv = [clip, "--frames", "0", "30", "--mapping", mapping, "--handle", "left_foot@12=+0,-12,0", "--handle", "my_Hand_R@18=+0,25,0", "--steps", "2", "--no-progress"]
    misses = {}
    for ik in ("auto", "rig"):
        code, _, err = run_cli(*argv, "--ik", ik, "--out", tmp_path / f"{ik}.bvh")
        assert code == 0, err
        motion = read_bvh(tmp_path / f"{ik}.bvh")
        foot, hand = (motion.skeleton.names.index(f"my_{j}") for j in (FOOT, HAND))
        positions = fk_positions(motion)
        misses[ik] = float(np.linalg.norm(positions[12, foot] - straight_line(FOOT, 12) - [0, -12, 0]))
        np.testing.assert_allclose(positions[18, hand], straight_line(HAND, 18) + [0, 25, 0], atol=1e-2)
    # Under a millimetre (the foot's curve comes straight down into the
    # handle, so the frames next to it count as planted and their foot may stay above its curve,
    # plant_height_scale; the solve's start at the handle frame is smoothed with theirs).
    assert misses["auto"] < 0.1 and misses["rig"] > 5.0, misses


def test_the_rig_chains_come_from_the_hierarchy_or_the_mapping_file(tmp_path):
    motion = read_bvh(renamed_clip(tmp_path))
    toml = tmp_path / "map.toml"
    preset = RigSpec.preset("bandai_namco")
    rig = {f: [f"my_{n}" for n in getattr(preset, f)] for f in ("spine", "left_arm", "right_arm", "left_leg", "right_leg")}
    lines = ["[characteristic]", *(f'{r} = "my_{n}"' for r, n in ROLES.items()), "[rig]", *(f"{f} = {json.dumps(v)}" for f, v in rig.items())]
    toml.write_text("\n".join(lines) + "\n")
    roles, spec = read_mapping(toml)
    assert roles == {r: f"my_{n}" for r, n in ROLES.items()} and spec == RigSpec.from_dict(rig)
    recognised = recognise_character(motion, toml)
    assert recognised.preset is None and recognised.rig_spec == spec
    assert derive_rig_spec(recognised.character) == spec  # the hierarchy gives the same chains
    assert recognise_character(read_bvh(DEMO_CLIP)).preset == "bandai_namco"


def test_a_lafan1_skeleton_is_recognised_and_gets_the_bundled_transfer(rng):
    from bezmotion.data import lafan1
    from bezmotion.data.bvh import BvhMotion
    from bezmotion.geometry import Skeleton
    from bezmotion.ik.rig import RIG_PRESETS
    from bezmotion.pipeline.authoring import load_profile, make_transfer, target_profile

    skeleton = Skeleton(lafan1.PARENTS, lafan1.JOINT_NAMES, rng.normal(scale=10.0, size=(22, 3)))
    quat = np.zeros((2, 22, 4))
    quat[..., 0] = 1.0
    motion = BvhMotion.from_skeleton(skeleton, quat, np.zeros((2, 3)), rotation_order="zyx")
    recognised = recognise_character(motion)
    assert recognised.preset == "lafan1" and recognised.rig_spec == RIG_PRESETS["lafan1"]
    assert derive_rig_spec(recognised.character) == RIG_PRESETS["lafan1"]
    profile = target_profile(recognised, [motion])
    bundled = load_profile("lafan1")  # the bundled profile, not one measured on two frames
    assert profile.height == bundled.height and np.array_equal(profile.mean_orientation, bundled.mean_orientation)
    transfer = make_transfer(load_profile("bandai_namco"), profile)
    assert float(transfer.scale) == pytest.approx(profile.height / load_profile("bandai_namco").height, rel=1e-6)


def test_models_default_to_those_of_the_clips_skeleton_trained_here(tmp_path, monkeypatch):
    """Without ``--model`` / ``--ik-model``, a clip of a skeleton with registered models that are
    here (LaFAN1's, once trained locally) gets them: no transfer, and the exact IK on its own
    learned IK under ``--ik auto``; before they are trained, or when named, the bundled ones."""
    import jax

    from conftest import synthetic_clip
    from bezmotion.assets import BUNDLED_BMM
    from bezmotion.assets.registry import trained_for
    from bezmotion.data.bvh import BvhMotion
    from bezmotion.ik.protocol import Character
    from bezmotion.ik.protores import ProtoResConfig, ProtoResModel, init_protores, save_ik_model
    from bezmotion.cli.plan import default_models

    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    skeleton, quat, root = synthetic_clip(40, seed=3)
    clip = tmp_path / "walk1_subject1.bvh"
    write_bvh(clip, BvhMotion.from_skeleton(skeleton, quat, root, rotation_order="zyx"))
    argv = [str(clip), "--frames", "0", "30", "--steps", "2", "--no-progress"]
    assert trained_for("lafan1", "bmm") is None and trained_for("bandai_namco", "ik") == "bandai_namco" and trained_for(None, "ik") is None
    before = plan(parse_options(InbetweenCommand, argv))  # nothing trained on LaFAN1 here: the bundled models
    assert before.models == {"bmm": "bandai_namco", "ik": None} and before.ik == "exact_rig" and before.transferred

    # "Train" lafan1_cpu here: the bundled BMM's files, and a small untrained IK of the LaFAN1 skeleton.
    runs = tmp_path / "cache" / "runs"
    shutil.copytree(BUNDLED_BMM, runs / "bmm_lafan1_cpu_residual" / "model")
    character = Character.from_bvh(read_bvh(clip), "lafan1")
    config = ProtoResConfig(22, encoder_width=16, stage_blocks=1, decoder_width=16, decoder_blocks=1, embedding_dim=8)
    graphdef, params = init_protores(config, key=jax.random.key(0))
    save_ik_model(runs / "ik_lafan1" / "model", ProtoResModel(params, character, graphdef, config))
    assert trained_for("lafan1", "bmm") == trained_for("lafan1", "ik") == "lafan1_cpu"
    own = plan(parse_options(InbetweenCommand, argv))
    assert own.models == {"bmm": "lafan1_cpu", "ik": "lafan1_cpu"} and own.ik == "exact" and not own.transferred
    assert own.transfer.facing is not None and float(own.transfer.scale) == 1.0  # the training facing alone
    named = plan(parse_options(InbetweenCommand, [*argv, "--model", "bandai_namco", "--ik-model", "bandai_namco"]))
    assert named.models == {"bmm": "bandai_namco", "ik": None} and named.ik == "exact_rig" and named.transferred
    assert default_models("lafan1", "my_bmm/", None) == ("my_bmm/", "lafan1_cpu")
    assert default_models(None, None, None) == ("bandai_namco", "bandai_namco")


# ----------------------------------------------------------------------------- handles


def test_handle_syntax():
    assert parse_handle("right_hand@12=40,150,80") == HandleRequest("right_hand", 12, (40.0, 150.0, 80.0), False, "--handle right_hand@12=40,150,80")
    assert parse_handle("right_hand@12=+0,25,-1.5").value == (0.0, 25.0, -1.5)
    assert parse_handle("right_hand@12=+0,25,-1.5").relative
    assert not parse_handle("Hand_R@6=-3,4,5").relative
    for bad in ("right_hand@12=1,2", "right_hand=1,2,3", "right_hand@x=1,2,3", "right_hand@=1,2,3", "right_hand@12=a,b,c"):
        with pytest.raises(ValueError, match=rf"--handle {bad}: expected JOINT@FRAME=X,Y,Z"):
            parse_handle(bad)
    for bad, frame in (("right_hand@12.5=1,2,3", "12.5"), ("right_hand@1e1=1,2,3", "1e1")):
        with pytest.raises(ValueError, match=rf"--handle {bad}: the frame must be a whole number, got {frame}$"):
            parse_handle(bad)
    for bad in ("right_hand@12=1,2,nan", "right_hand@12=+inf,0,0"):
        with pytest.raises(ValueError, match=rf"--handle {re.escape(bad)}: the position must be finite, got {re.escape(bad.split('=')[1])}$"):
            parse_handle(bad)


def test_handles_files_json_as_blender_exports_them_and_toml(tmp_path):
    blender = tmp_path / "handles.json"
    blender.write_text(json.dumps([{"joint": "right_hand", "frame": 12, "position": [1, 2, 3]}]))
    assert read_handles_file(blender) == [HandleRequest("right_hand", 12, (1.0, 2.0, 3.0), False, f"--handles {blender}: handle 0 (right_hand@12)")]
    wrapped = tmp_path / "wrapped.json"
    wrapped.write_text(json.dumps({"handles": [{"joint": "head", "frame": 6, "offset": [0, 5, 0]}]}))
    assert read_handles_file(wrapped)[0].relative
    toml = tmp_path / "handles.toml"
    toml.write_text('[[handles]]\njoint = "left_foot"\nframe = 18\noffset = [0, 10, 0]\n\n[[handles]]\njoint = "hips"\nframe = 12\nposition = [0.5, 90, 3]\n')
    got = read_handles_file(toml)
    assert [(h.joint, h.frame, h.value, h.relative) for h in got] == [("left_foot", 18, (0.0, 10.0, 0.0), True), ("hips", 12, (0.5, 90.0, 3.0), False)]
    bad = tmp_path / "bad.json"
    for entry in ({"joint": "head", "frame": 6}, {"joint": "head", "frame": 6.5, "position": [0, 0, 0]},
                  {"joint": "head", "frame": 6, "position": [0, 0]}, {"joint": "head", "frame": 6, "position": [0, 0, 0], "offset": [0, 0, 0]}):  # fmt: skip
        bad.write_text(json.dumps([entry]))
        with pytest.raises(ValueError, match=rf"--handles {bad}: handle 0: expected"):
            read_handles_file(bad)
    bad.write_text("[{")
    with pytest.raises(ValueError, match=rf"--handles {bad}: not valid JSON"):
        read_handles_file(bad)


# ------------------------------------------------------------------------------ chains


@pytest.fixture(scope="module")
def long_clip(tmp_path_factory):
    """The bundled clip played forward then back: 79 frames, room for keys at 0, 30 and 60."""
    motion = read_bvh(DEMO_CLIP)
    there_and_back = np.r_[np.arange(40), np.arange(38, -1, -1)]
    path = tmp_path_factory.mktemp("long") / "there_and_back.bvh"
    write_bvh(path, dataclasses.replace(motion, quat_local=motion.quat_local[there_and_back], pos_local=motion.pos_local[there_and_back]))
    return path


def test_a_chain_through_three_keys_keeps_them_and_hits_handles_in_both_windows(long_clip, tmp_path):
    """``--frames 0 30 60``: one 61-frame motion through the three key poses, handles in
    either window (frames counted from the first key), one joined curve in the glTF file."""
    from bezmotion.pipeline.gltf import read_glb

    out = tmp_path / "chain"
    code, _, err = run_cli(
        long_clip, "--frames", "0", "30", "60", "--handle", "right_hand@45=+0,25,0", "--handle", "left_foot@13=+0,5,0",
        *FAST, "--no-preview", "--out", out,
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["frames"], summary["windows"]) == (61, 2)
    clip, motion = read_bvh(long_clip), read_bvh(out / "inbetween.bvh")
    pos, truth = fk_positions(motion), fk_positions(clip)
    assert motion.num_frames == 61
    np.testing.assert_allclose(pos[[0, 30, 60]], truth[[0, 30, 60]], atol=1e-3)  # every key, the inner one too
    names = clip.skeleton.names
    hand = names.index(HAND)
    # Relative to the straight line between the keys around the handle: frames 30 and 60.
    np.testing.assert_allclose(pos[45, hand], 0.5 * (truth[30, hand] + truth[60, hand]) + [0, 25, 0], atol=1e-3)
    assert [h["frame"] for h in summary["handles"]] == [45, 13]
    assert max(summary["samples"][0]["handle_errors_cm"]) < 1e-3
    glb = read_glb(out / "inbetween.glb")
    assert glb.ctrl_pos.shape == (11, 6, 3)  # two windows' 6 control points, the shared key once
    assert glb.key_frames == [0, 30, 60]  # so that Blender's handle export leaves the inner key alone
    np.testing.assert_allclose(glb.ctrl_pos[5, glb.joints.index("right_hand")], truth[30, hand], atol=1e-3)
    np.testing.assert_allclose(fk_positions(glb.motion), pos, atol=1e-2)


def test_a_chain_refuses_a_handle_on_its_inner_key_and_takes_every_keys_velocity(long_clip):
    argv = [str(long_clip), "--frames", "1", "31", "61", *FAST]
    with pytest.raises(ValueError, match=r"--handle head@30=\+0,1,0: frame 30 is a key of the chain \(keys at 0, 30, 60\)"):
        plan(parse_options(InbetweenCommand, [*argv, "--handle", "head@30=+0,1,0"]))
    p = plan(parse_options(InbetweenCommand, [*argv, "--key-velocities", "--handle", "head@59=+0,1,0"]))
    assert len(p.keys) == 3 and p.handles.position.shape == (4, 3)  # (slots, xyz), frames of the whole in-between
    assert np.asarray(p.handles.valid).tolist() == [True, False, False, False]
    assert int(p.handles.frame[0]) == 59
    pos = fk_positions(read_bvh(long_clip))[:, list(p.recognised.character.characteristic)]
    # Outwards at the ends (the frames before and after), the central difference inside.
    np.testing.assert_allclose(np.asarray(p.key_velocity), np.stack([pos[1] - pos[0], (pos[32] - pos[30]) / 2, pos[62] - pos[61]]), atol=1e-3)


def test_a_handle_one_frame_after_a_shared_key_moves_the_chain_no_faster_than_it_asks(long_clip):
    """A handle 20 cm off the line one frame after the inner key of ``--frames 0 30 60`` asks
    the hand to move 20 cm in that frame; the joined chain's curve does that and no more.
    Window by window, with the shared tangent held, the next control point alone would make
    it up, and the hand's curve would run faster than asked for several frames."""
    import jax
    import jax.numpy as jnp

    from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
    from bezmotion.pipeline import InbetweenOptions, Inbetweener, inbetween

    p = plan(parse_options(InbetweenCommand, [str(long_clip), "--frames", "0", "30", "60", "--handle", "right_hand@31=+0,20,0", *FAST]))
    keys = jax.tree.map(lambda *x: jnp.stack(x), *p.keys)
    model = Inbetweener(p.bmm, p.ik_fn, p.ik_params, p.recognised.character, p.transfer)
    r = inbetween(model, keys, p.handles, key=jax.random.key(0), options=InbetweenOptions(steps=2))
    hand = np.asarray(r.positions)[:, CHARACTERISTIC_JOINTS.index("right_hand")]  # (61, 3)
    np.testing.assert_allclose(hand[31], p.handle_records[0]["position"], atol=1e-3)
    speed = np.linalg.norm(np.diff(hand, axis=0), axis=-1)
    assert speed.max() < 22.0 and np.sort(speed)[-2] < 18.0, np.sort(speed)[-3:]


def test_keys_from_any_frames_of_any_files_make_a_chain_in_their_order(long_clip):
    """``--key FILE@FRAME`` (repeated): each pose put 30 frames after the one before."""
    clip = str(DEMO_CLIP)
    argv = ["--key", f"{clip}@5", "--key", f"{long_clip}@60", "--key", f"{clip}@12", *FAST]
    p = plan(parse_options(InbetweenCommand, argv))
    assert p.label == f"{clip}@5 → {long_clip}@60 → {clip}@12" and p.reference is None
    six = list(p.recognised.character.characteristic)
    truth = fk_positions(read_bvh(DEMO_CLIP))[:, six]
    # The long clip's frame 60 is the bundled clip's frame 18 (played forward, then back).
    for pose, frame in zip(p.keys, (5, 18, 12)):
        np.testing.assert_allclose(np.asarray(targets_from_pose(p.recognised.character, pose).position), truth[frame], atol=1e-3)
    p = plan(parse_options(InbetweenCommand, [*argv, "--key-velocities"]))
    np.testing.assert_allclose(np.asarray(p.key_velocity)[1], (truth[17] - truth[19]) / 2, atol=1e-3)  # backwards there
    with pytest.raises(ValueError, match=f"--key-velocities: the key {clip}@0 is the first frame of its file; its velocity needs the frames on both sides"):
        plan(parse_options(InbetweenCommand, ["--key", f"{clip}@5", "--key", f"{clip}@0", "--key", f"{clip}@12", "--key-velocities", *FAST]))


# ------------------------------------------------------------------------ bad arguments


def _cases(tmp):
    clip = str(DEMO_CLIP)
    keys = [clip, "--frames", "0", "30"]
    return {
        "unknown joint": ([*keys, "--handle", "right_hnd@12=+0,25,0"], "--handle right_hnd@12=+0,25,0: unknown joint 'right_hnd'"),
        "frame out of the clip": ([clip, "--frames", "0", "45"], "--frames 0 45: frame 45 is out of range; the file has frames 0…39"),
        "a clip without frames": ([f"{tmp}/frameless.bvh", "--frames", "0", "30"], "--frames 0 30: frame 0 is out of range; the file has no frames"),
        "end frame out of the clip": (["--start", f"{clip}@0", "--end", f"{clip}@40"], f"--end {clip}@40: frame 40 is out of range"),
        "handle frame out of the in-between": ([*keys, "--handle", "head@31=+0,1,0"], "--handle head@31=+0,1,0: frame 31 is outside the in-between, frames 0…30"),
        "keys on one frame": ([clip, "--frames", "4", "4"], "--frames 4 4: keys are 2 … 900 frames apart at 30 fps, got 0"),
        "keys one frame apart": (["--start", f"{clip}@0", "--end", f"{clip}@9", "--gap", "1"], "--gap 1: keys are 2 … 900 frames apart at 30 fps, got 1"),
        "gaps not one per pair of keys": (
            ["--key", f"{clip}@0", "--key", f"{clip}@9", "--key", f"{clip}@20", "--gap", "20", "45", "25"],
            "--gap 20 45 25: one gap for every pair of keys, or one per pair (2 through 3 keys), got 3",
        ),
        "a gap beside the clip's frames": ([*keys, "--gap", "45"], "--gap 45: goes with --start/--end or --key; CLIP --frames 0 30 keeps the clip's own spacing"),
        "not a BVH file": ([f"{tmp}/notes.bvh", "--frames", "0", "30"], f"CLIP {tmp}/notes.bvh: "),
        "missing clip": ([f"{tmp}/missing.bvh", "--frames", "0", "30"], f"CLIP {tmp}/missing.bvh: no such file"),
        "missing end file": (["--start", f"{clip}@0", "--end", f"{tmp}/nope.bvh@30"], f"--end {tmp}/nope.bvh@30: no such file"),
        "unknown skeleton": (
            [f"{tmp}/numbered.bvh", "--frames", "0", "30"],
            f"CLIP {tmp}/numbered.bvh: unknown skeleton of 22 joints (j0, j1, j2, j3, … (22 in all)): not lafan1 or bandai_namco, "
            "and its names do not tell its six joints (no joint's name reads as the head); name them in a mapping file",
        ),
        "missing mapping": ([f"{tmp}/custom.bvh", "--frames", "0", "30", "--mapping", f"{tmp}/map.json"], f"--mapping {tmp}/map.json: no such file"),
        "missing model": ([*keys, "--model", f"{tmp}/models/bmm"], f"--model {tmp}/models/bmm: not a saved BMM (no such folder)"),
        "missing learned IK": ([*keys, "--ik", "refined", "--ik-model", f"{tmp}/models/ik"], f"--ik-model {tmp}/models/ik: not a saved learned IK"),
        "missing handles file": ([*keys, "--handles", f"{tmp}/h.json"], f"--handles {tmp}/h.json: no such file"),
        "bad handle": ([*keys, "--handle", "right_hand@12=1,2"], "--handle right_hand@12=1,2: expected JOINT@FRAME=X,Y,Z"),
        "handle 100 m away": (
            [*keys, "--handle", "head@12=+0,20000,0"],
            "--handle head@12=+0,20000,0: head at frame 12 lies 200 m from the straight line between the keys' head positions, farther than 100 m",
        ),
        "unknown output format": (
            [*keys, "--out", f"{tmp}/x.fbx"],
            f"--out {tmp}/x.fbx: unknown output format '.fbx'; bezmotion writes .bvh, .glb, .gif files, and into a folder named with a trailing /",
        ),
        "a file bezmotion did not write": (
            [*keys, "--out", f"{tmp}/notes.bvh"],
            f"--out {tmp}/notes.bvh: would replace notes.bvh, which is not bezmotion's own output (unrecorded, or changed since); --force replaces it",
        ),
        "the clip as the output": (
            [f"{tmp}/custom.bvh", "--frames", "0", "30", "--out", f"{tmp}/custom.bvh"],
            f"--out {tmp}/custom.bvh: would replace custom.bvh, the CLIP file, an input of this run; --force replaces it",
        ),
        "output under a file": ([*keys, "--out", f"{tmp}/notes.bvh/x.bvh"], f"--out {tmp}/notes.bvh/x.bvh: {tmp}/notes.bvh is a file, not a folder"),
        "output folder under a file": ([*keys, "--out", f"{tmp}/notes.bvh/a/b"], f"--out {tmp}/notes.bvh/a/b: {tmp}/notes.bvh is a file, not a folder"),
        "no samples": ([*keys, "--samples", "0"], "--samples 0: must be at least 1"),
        "not a number": ([*keys, "--samples", "x"], "argument --samples: invalid int value: 'x'"),
        "unknown profile": ([*keys, "--trained-on", "amass"], "--trained-on amass: not a bundled profile"),
        "no keys": (["--handle", "head@12=+0,1,0"], "give the key poses"),
        "unknown exact setting": ([*keys, "--ik", "exact", "--exact", "speed=3"], "--exact speed=3: expected NAME=VALUE with NAME one of"),
        "exact setting not a number": ([*keys, "--ik", "exact", "--exact", "iterations=x"], "--exact iterations=x: 'x' is not a number"),
        "exact setting out of its range": ([*keys, "--ik", "exact", "--exact", "smoothing=0.9"], "--exact smoothing=0.9: must lie in [0.0, 0.5]"),
        "exact step count not whole": ([*keys, "--ik", "exact", "--exact", "iterations=2.5"], "--exact iterations=2.5: iterations is a count, a whole number"),
        "two handles on one joint and frame": (
            [*keys, "--handle", "head@12=+0,1,0", "head@12=+0,2,0"],
            "--handle head@12=+0,2,0: head at frame 12 has another handle, --handle head@12=+0,1,0, at a different position: (",
        ),
        "exact settings for another IK": ([*keys, "--exact", "plant_weight=10"], "--exact plant_weight=10: the settings of the exact IK, not of --ik rig"),
        "one key frame": ([clip, "--frames", "5"], "--frames 5: needs at least two key frames"),
        "one --key": (["--key", f"{clip}@3"], f"--key {clip}@3: needs at least two --key poses"),
        "keys given two ways": ([*keys, "--key", f"{clip}@3", "--key", f"{clip}@9"], f"CLIP {clip}: give the keys one way"),
        "a --key frame out of its file": (["--key", f"{clip}@3", "--key", f"{clip}@40"], f"--key {clip}@40: frame 40 is out of range"),
        "chain keys not increasing": ([clip, "--frames", "0", "30", "29"], "--frames 0 30 29: keys are 2 … 900 frames apart at 30 fps, got -1"),
        "chain keys one frame apart": ([clip, "--frames", "0", "1", "30"], "--frames 0 1 30: keys are 2 … 900 frames apart at 30 fps, got 1"),
        "key velocity before the clip": ([*keys, "--key-velocities"], f"--key-velocities: the start key {clip} is the first frame of its file; its velocity needs the frame before it"),
        "key velocity after the clip": (
            ["--start", f"{clip}@5", "--end", f"{clip}@39", "--key-velocities"], f"--key-velocities: the end key {clip}@39 is the last frame (39) of its file; its velocity needs the frame after it"
        ),
    }  # fmt: skip


CASES = list(_cases("TMP"))


@pytest.mark.parametrize("case", CASES)
def test_a_bad_argument_exits_2_with_one_line_and_writes_nothing(case, tmp_path):
    renamed_clip(tmp_path), numbered_clip(tmp_path)
    before = sorted(os.listdir(tmp_path))
    argv, message = _cases(str(tmp_path))[case]
    (tmp_path / "notes.bvh").write_text("not a BVH file\n")
    hierarchy = DEMO_CLIP.read_text().split("MOTION")[0]
    (tmp_path / "frameless.bvh").write_text(f"{hierarchy}MOTION\nFrames: 0\nFrame Time: 0.0333333\n")
    before = sorted(os.listdir(tmp_path))
    code, stdout, stderr = run_cli("--ik", "rig", "--steps", "2", "--out", tmp_path / "out", *argv)  # argv's own flags win
    assert code == 2
    assert stderr.startswith("bezmotion: error: ") and stderr.count("\n") == 1, stderr
    assert message in stderr, stderr
    assert stdout == ""
    assert sorted(os.listdir(tmp_path)) == before  # no folder, no file, no model folder


@pytest.mark.parametrize("part, shown", [("resolve_bmm", "the default BMM bandai_namco"), ("resolve_ik_model", "the default learned IK bandai_namco")])
def test_a_default_models_error_names_no_option_the_user_did_not_give(part, shown, tmp_path, monkeypatch):
    import bezmotion.cli.plan as plan_module

    def not_here(name, **options):
        raise FileNotFoundError("not trained here")

    monkeypatch.setattr(plan_module, part, not_here)
    code, _, err = run_cli(DEMO_CLIP, "--frames", "0", "30", "--steps", "2", "--out", tmp_path / "x.bvh")  # --ik auto: the learned IK first
    assert code == 2 and f"{shown}: not trained here" in err, err
    assert "--model" not in err and "--ik" not in err


def test_the_learned_ik_refuses_another_skeleton(tmp_path):
    clip = renamed_clip(tmp_path)
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({role: f"my_{name}" for role, name in ROLES.items()}))
    code, _, err = run_cli(clip, "--frames", "0", "30", "--mapping", mapping, "--ik", "learned", "--out", tmp_path / "o.bvh")
    assert code == 2 and "--ik learned: the learned IK bandai_namco does not fit this skeleton" in err and "the rig and exact_rig IKs need no training" in err
    assert "--ik exact_rig" not in err  # an option the user did not pass
    assert not (tmp_path / "o.bvh").exists()


def test_key_velocities_come_from_the_frames_around_the_keys(tmp_path):
    """``--key-velocities``: the six joints' velocities at the keys from the frame before the
    start and the one after the end (the motion kept around the in-between)."""
    args = parse_options(InbetweenCommand, [str(DEMO_CLIP), "--frames", "5", "35", "--key-velocities", *FAST, "--out", str(tmp_path / "x.bvh")])
    p = plan(args)
    six = list(p.recognised.character.characteristic)
    pos = fk_positions(read_bvh(DEMO_CLIP))[:, six]
    np.testing.assert_allclose(np.asarray(p.key_velocity), np.stack([pos[5] - pos[4], pos[36] - pos[35]]), atol=1e-3)
    assert plan(parse_options(InbetweenCommand, [str(DEMO_CLIP), "--frames", "5", "35", *FAST])).key_velocity is None


@pytest.mark.parametrize("flag, locked", [([], True), (["--no-foot-lock"], False), (["--foot-lock"], True)])
def test_foot_lock_reaches_the_pipeline(flag, locked, tmp_path, monkeypatch):
    """``--foot-lock`` (the default) and ``--no-foot-lock`` (the paper's curves) reach :func:`inbetween_at`."""
    import bezmotion.cli.inbetween as command

    class Called(Exception):
        pass

    def inbetween(*args, **kwargs):
        raise Called(kwargs["options"].foot_lock)

    monkeypatch.setattr(command, "inbetween_at", inbetween)
    args = parse_options(InbetweenCommand, [str(DEMO_CLIP), "--frames", "0", "30", *FAST, *flag, "--out", str(tmp_path / "x.bvh")])
    with pytest.raises(Called) as called:
        command.run_inbetween(args)
    assert called.value.args == (locked,)


def test_exact_settings_reach_the_exact_ik(tmp_path):
    """``--exact NAME=VALUE`` (repeatable) sets the exact IK's :class:`ExactIKParams`."""
    argv = [str(DEMO_CLIP), "--frames", "0", "30", *FAST, "--ik", "exact", "--out", str(tmp_path / "x.bvh")]
    p = plan(parse_options(InbetweenCommand, [*argv, "--exact", "plant_weight=10", "--exact", "iterations=3"]))
    assert p.ik == "exact" and p.ik_params.plant_weight == 10.0 and p.ik_params.iterations == 3
    default = plan(parse_options(InbetweenCommand, argv)).ik_params
    assert default.plant_weight == 4.0 and default.iterations == 6


def test_the_bvh_rate_is_the_clips_where_every_in_between_frame_is_one_of_its_frames():
    assert [bvh_frame_rate("clip", fps) for fps in (30.0, 60.0, 120.0, 90.0, 24.0, 25.0, 29.97, 50.0)] == [30.0, 60.0, 120.0, 90.0, 30.0, 30.0, 30.0, 30.0]
    assert bvh_frame_rate("30", 120.0) == 30.0
    with pytest.raises(ValueError, match="--bvh-fps must be clip or 30, got '60'"):
        bvh_frame_rate("60", 60.0)


def test_a_model_without_checksums_needs_no_verify(tmp_path):
    """A saved model folder without its checksums is refused in the command's words; with
    ``--no-verify`` it is loaded (with a warning) and planned as any other."""
    from bezmotion.assets import BUNDLED_BMM

    model = tmp_path / "old_bmm"
    shutil.copytree(BUNDLED_BMM, model)
    (model / "checksums.json").unlink()
    argv = [str(DEMO_CLIP), "--frames", "0", "30", "--model", str(model), *FAST]
    code, _, err = run_cli(*argv)
    assert code == 2
    assert err.strip() == f"bezmotion: error: --model {model}: no checksums.json (saved before models carried checksums); --no-verify loads it if you trust its files"
    with pytest.warns(UserWarning, match="unverified"):
        p = plan(parse_options(InbetweenCommand, [*argv, "--no-verify"]))
    assert p.models["bmm"] == str(model)
