"""The embedded default: ``bezmotion demo`` on the bundled clip with the bundled models."""

from __future__ import annotations

import json
import os
import shutil
import stat

import numpy as np
import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.cli import main
from bezmotion.data.bvh import read_bvh
from bezmotion.cli.demo import DEMO_FILES, demo
from bezmotion._src.messages import MESSAGE_CHARS, listed
from bezmotion.geometry.rotations import quat_from_axis_angle
from bezmotion.ik.protocol import Character
from bezmotion._src.io import _umask
from bezmotion._src.output_sets import OUTPUTS_RECORD
from bezmotion.evaluation.window_figures import largest_turn


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """One demo run in a small setting (2 DDIM steps), shared by the checks below."""
    out = tmp_path_factory.mktemp("demo")
    code = main(["demo", "--out", str(out), "--steps", "2"])
    return code, out, json.loads((out / "summary.json").read_text()) if code == 0 else None


def test_demo_runs_and_its_curves_pass_through_the_handle(demo_run):
    code, out, summary = demo_run
    assert code == 0
    assert summary["frames"] == 31 and summary["joints"] == 22 and summary["steps"] == 2
    assert summary["curve_handle_error_cm"] == 0.0  # overwrite: the handle, bit for bit
    # The handle moves the right hand 25 cm above the mocap; the default IK (learned, then
    # the exact whole-body solve) puts the hand on it.
    assert summary["ik"] == "exact" and summary["foot_lock"] is True and summary["exact"] == {}  # the defaults
    assert summary["joint_moved_cm"] > 20.0
    assert summary["full_body_handle_error_cm"] < 1e-2
    slide = summary["ground_slide_cm"]
    assert set(slide) == {"inbetween", "mocap"} and all(set(v) == {"left_foot", "right_foot"} for v in slide.values())
    turns = summary["largest_turn_deg"]
    assert set(turns) == {"inbetween", "mocap"} and all(0.0 < t["deg"] < 180.0 and 0 <= t["frames"][0] < 30 for t in turns.values())
    off = summary["curve_error_max_cm"]
    assert 0.0 <= off["cm"] < 50.0 and 0 <= off["frame"] <= 30


def test_demo_bvh_reads_back_and_matches_the_pipeline(demo_run):
    _, out, summary = demo_run
    assert summary["bvh_fk_error_cm"] < 1e-3  # FK of the re-read file vs the pipeline's poses
    for name in ("inbetween.bvh", "ground_truth.bvh"):
        motion = read_bvh(out / name)
        assert motion.num_frames == 31 and motion.skeleton.num_joints == 22
        assert np.isfinite(motion.quat_local).all()
    assert (out / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_writes_the_glb_and_the_preview(demo_run):
    """The glTF file reads back with the BVH's skeleton and frames and the curves through
    the handle; the preview has one GIF frame per motion frame."""
    from PIL import Image

    from bezmotion.pipeline.gltf import read_glb

    _, out, summary = demo_run
    glb, bvh = read_glb(out / "inbetween.glb"), read_bvh(out / "inbetween.bvh")
    assert glb.motion.skeleton.names == bvh.skeleton.names and glb.motion.channels == bvh.channels
    assert glb.layout.num_frames == 31 and glb.layout.stride == 6
    np.testing.assert_allclose(glb.motion.pos_local, bvh.pos_local, atol=1e-3)  # BVH: 6 decimals
    sign = np.sign(np.sum(glb.motion.quat_local * bvh.quat_local, axis=-1, keepdims=True))
    np.testing.assert_allclose(glb.motion.quat_local * sign, bvh.quat_local, atol=1e-5)
    handle = summary["handle"]
    assert glb.handles == [{"joint": handle["joint"], "frame": handle["frame"], "position": handle["position_cm"]}]
    at_handle = glb.ctrl_pos[handle["frame"] // 6, glb.joints.index(handle["joint"])]
    np.testing.assert_allclose(at_handle, handle["position_cm"], rtol=2e-7)  # float32 metres
    with Image.open(out / "preview.gif") as gif:
        assert gif.format == "GIF" and gif.n_frames == 31
    assert set(summary["files"]) >= {"inbetween", "ground_truth", "png", "glb", "gif"}


def _hierarchy(text: str) -> tuple[list[str], list[str], list[tuple[str, int]], str]:
    """OFFSET lines of joints, those of End Sites, (joint, channel count) and the Frame Time, read independently of the reader."""
    lines = [line.strip() for line in text.splitlines()]
    joints = [i for i, line in enumerate(lines) if line.startswith(("ROOT ", "JOINT "))]
    sites = [i for i, line in enumerate(lines) if line == "End Site"]
    joint_offsets = [lines[i + 2] for i in joints]
    site_offsets = [lines[i + 2] for i in sites]
    channels = [(lines[i].split()[1], int(lines[i + 3].split()[1]) if lines[i + 3].startswith("CHANNELS") else 0) for i in joints]
    frame_time = next(line for line in lines if line.startswith("Frame Time:"))
    return joint_offsets, site_offsets, channels, frame_time


def test_demo_bvh_rigs_like_the_clip(demo_run):
    """The files carry the clip's own OFFSETs (the Hips' −2 cm along Z, not the IK model's
    −427 cm) and End Sites, positions on the root and the hips only, exactly 30 fps, and
    the permissions an ordinary file gets."""
    _, out, summary = demo_run
    assert summary["channels"] == "default"
    clip = read_bvh(DEMO_CLIP)
    clip_offsets, clip_sites, _, _ = _hierarchy(DEMO_CLIP.read_text())
    for name in ("inbetween.bvh", "ground_truth.bvh"):
        offsets, sites, channels, frame_time = _hierarchy((out / name).read_text())
        hips = [float(v) for v in offsets[1].split()[1:]]
        np.testing.assert_allclose(hips, [float(v) for v in clip_offsets[1].split()[1:]], atol=1e-6)
        assert hips[2] == pytest.approx(-2.00062, abs=1e-6)
        np.testing.assert_allclose(
            [[float(v) for v in line.split()[1:]] for line in offsets], [[float(v) for v in line.split()[1:]] for line in clip_offsets], atol=1e-6
        )
        assert len(sites) == len(clip_sites) == 5
        assert [[float(v) for v in line.split()[1:]] for line in sites] == [[float(v) for v in line.split()[1:]] for line in clip_sites]
        assert channels == [("joint_Root", 6), ("Hips", 6)] + [(n, 3) for n in clip.skeleton.names[2:]]
        back = read_bvh(out / name)
        assert back.end_sites == clip.end_sites
        assert abs(back.fps - 30.0) < 1e-9, frame_time
        assert stat.S_IMODE(os.stat(out / name).st_mode) == 0o666 & ~_umask()


def test_demo_prints_the_data_attribution(demo_run, capsys):
    _, out, summary = demo_run
    assert "Bandai Namco Research" in summary["attribution"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--frame", "0"], "--frame 0 --offset 0 25 0: handles sit on integer frames strictly between 0 and 30"),
        (["--frame", "30"], "strictly between 0 and 30"),
        (["--offset", "0", "nan", "0"], "--frame 12 --offset 0 nan 0: handle positions must be finite"),
        (["--exact", "smoothing=2"], "--exact smoothing=2: must lie in [0.0, 0.5]"),
        (["--steps", "0"], "--steps must be at least 1, got 0"),
        (["--bmm-corpus", "amass"], "--bmm-corpus must be one of"),
        (["--exact", "nope=1"], "--exact nope=1: expected NAME=VALUE with NAME one of"),
        (["--ik", "rig", "--exact", "plant_weight=10"], "--exact plant_weight=10.0: the settings of the exact IK, not of --ik rig"),
    ],
)
def test_demo_rejects_bad_arguments_with_a_clear_message(tmp_path, capsys, args, message):
    assert main(["demo", "--out", str(tmp_path), *args]) == 2
    assert message in capsys.readouterr().err


def test_demo_refuses_an_output_folder_under_a_file_before_it_works(tmp_path, capsys):
    (tmp_path / "notes").write_text("mine\n")
    assert main(["demo", "--out", str(tmp_path / "notes" / "demo")]) == 2
    assert f"--out {tmp_path}/notes/demo: {tmp_path}/notes is a file, not a folder" in capsys.readouterr().err
    assert (tmp_path / "notes").read_text() == "mine\n"


def test_demo_rejects_an_unknown_channel_layout(tmp_path):
    with pytest.raises(ValueError, match=r"--channels must be one of \('default', 'clip'\), got 'all'"):
        demo(tmp_path / "out", channels="all")
    assert not (tmp_path / "out").exists()


def test_ground_slide_counts_only_travel_near_the_ground():
    from bezmotion.cli.demo import ground_slide_cm

    # Left foot: 1 cm per frame along X on the ground, then lifted 10 cm and moved on;
    # right foot: still on the ground, then 2 cm along Z at 4 cm height (within 5 cm).
    feet = np.zeros((6, 2, 3))
    feet[:, 0, 0] = np.arange(6.0)
    feet[3:, 0, 1] = 10.0
    feet[4:, 1, 2] = 2.0
    feet[:, 1, 1] = 4.0
    np.testing.assert_allclose(ground_slide_cm(feet, np.zeros(2)), [2.0, 2.0])


def test_largest_turn_names_the_joint_and_the_frames():
    character = Character.from_bvh(read_bvh(DEMO_CLIP), "bandai_namco")
    quat = np.zeros((5, character.num_joints, 4), np.float32)
    quat[..., 0] = 1.0
    quat[3:, 7] = np.asarray(quat_from_axis_angle(np.asarray([0.0, 1.0, 0.0]), np.radians(30.0)))  # joint 7 turns 30° at 2 → 3
    turn = largest_turn(character, quat)
    assert turn["joint"] == character.skeleton.names[7] and turn["frames"] == [2, 3]
    assert turn["deg"] == pytest.approx(30.0, abs=1e-3)


def test_demo_again_in_its_folder_replaces_its_own_files_with_a_note(demo_run, tmp_path, capsys):
    """A second demo in the first one's folder (copied) replaces its set, says so on stderr,
    and leaves the user's file there alone."""
    _, first, _ = demo_run
    out = shutil.copytree(first, tmp_path / "demo")
    (out / "notes.txt").write_text("mine\n")
    capsys.readouterr()
    assert main(["demo", "--out", str(out), "--steps", "2", "--seed", "1"]) == 0
    err = capsys.readouterr().err
    assert f"bezmotion demo: note: replaced {listed(DEMO_FILES)} in {out}" in err
    assert sorted(os.listdir(out)) == sorted([*DEMO_FILES, OUTPUTS_RECORD, "notes.txt"])
    assert (out / "notes.txt").read_text() == "mine\n"
    assert (out / "inbetween.bvh").read_bytes() != (first / "inbetween.bvh").read_bytes()  # another seed


def test_demo_refuses_files_it_did_not_write_without_force(tmp_path, capsys):
    (tmp_path / "inbetween.bvh").write_text("the user's own\n")
    assert main(["demo", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"bezmotion: error: --out {tmp_path}: would replace inbetween.bvh, which is not bezmotion's own output (unrecorded, or changed since); "
        "--force replaces it\n"
    )
    assert sorted(os.listdir(tmp_path)) == ["inbetween.bvh"]


def test_an_error_is_one_line_of_about_300_characters(monkeypatch, capsys):
    """The last guard in ``main``: a message of 5,000 characters is cut in its middle, keeping
    what failed (its start) and why (its end); argparse's own errors too."""
    import bezmotion.cli as cli

    def long_error(args):
        raise ValueError(f"--handle {'x' * 5000}: the end says why")

    monkeypatch.setattr(cli, "run_inbetween", long_error)
    assert main(["inbetween", str(DEMO_CLIP), "--frames", "0", "30"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bezmotion: error: --handle xxx") and err.endswith(": the end says why\n") and err.count("\n") == 1
    assert len(err) <= len("bezmotion: error: \n") + MESSAGE_CHARS
    with pytest.raises(SystemExit) as exit_:
        main(["inbetween", "--ik", "x" * 5000])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith("bezmotion: error: argument --ik: invalid choice") and err.count("\n") == 1
    assert len(err) <= len("bezmotion: error:  (see bezmotion inbetween --help)\n") + MESSAGE_CHARS
