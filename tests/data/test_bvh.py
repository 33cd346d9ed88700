"""BVH reading and writing: a real fixture, round trips, hand-checked FK, real corpora, bad input."""

from __future__ import annotations

import dataclasses
import re
import tarfile
import zipfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SHARED_DATA, assert_same_rotation, np_forward_kinematics, np_matrix_from_euler, np_matrix_from_quat

from bezmotion.assets import DEMO_CLIP
from bezmotion._src.messages import MESSAGE_CHARS
from bezmotion.data.bvh import MAX_DEPTH, MAX_JOINT_FRAMES, MAX_JOINTS, BvhMotion, format_bvh, parse_bvh, read_bvh, write_bvh
from bezmotion.geometry.skeleton import Skeleton, forward_kinematics

FIXTURE = DEMO_CLIP  # the bundled real clip (attribution: bezmotion/assets/README.md)
FIXTURE_ORIGINAL = "dataset-2_walk_normal_001.bvh"
LAFAN1_ZIP = SHARED_DATA / "lafan1" / "lafan1-subset.zip"
BANDAI_ARCHIVE = SHARED_DATA / "bandai-namco" / "bandai-namco-2.tar.xz"
LAFAN1_JOINTS = (
    "Hips", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToe", "RightUpLeg", "RightLeg", "RightFoot",
    "RightToe", "Spine", "Spine1", "Spine2", "Neck", "Head", "LeftShoulder", "LeftArm",
    "LeftForeArm", "LeftHand", "RightShoulder", "RightArm", "RightForeArm", "RightHand",
)  # fmt: skip
BANDAI_JOINTS = (
    "joint_Root", "Hips", "Spine", "Chest", "Neck", "Head", "Shoulder_L", "UpperArm_L", "LowerArm_L",
    "Hand_L", "Shoulder_R", "UpperArm_R", "LowerArm_R", "Hand_R", "UpperLeg_L", "LowerLeg_L", "Foot_L",
    "Toes_L", "UpperLeg_R", "LowerLeg_R", "Foot_R", "Toes_R",
)  # fmt: skip

requires_lafan1 = pytest.mark.skipif(not LAFAN1_ZIP.exists(), reason=f"{LAFAN1_ZIP} not found")
requires_bandai = pytest.mark.skipif(not BANDAI_ARCHIVE.exists(), reason=f"{BANDAI_ARCHIVE} not found")


@pytest.fixture(scope="module")
def fixture_motion() -> BvhMotion:
    return read_bvh(FIXTURE)


def _motion_rows(text: str) -> list[list[float]]:
    """The motion table of a BVH text, parsed independently of the reader."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip().lower().startswith("frame time")) + 1
    return [[float(v) for v in line.split()] for line in lines[start:] if line.strip()]


def assert_same_motion(a: BvhMotion, b: BvhMotion, *, quat_atol: float, pos_atol: float) -> None:
    """Same hierarchy, channels, End Sites and frame time; rotations and translations within tolerance."""
    assert a.skeleton.names == b.skeleton.names
    assert a.skeleton.parents == b.skeleton.parents
    assert a.channels == b.channels
    assert a.frame_time == b.frame_time
    assert [p for p, _ in a.end_sites] == [p for p, _ in b.end_sites]
    np.testing.assert_allclose([o for _, o in a.end_sites], [o for _, o in b.end_sites], atol=pos_atol, rtol=0)
    np.testing.assert_allclose(np.asarray(a.skeleton.offsets), np.asarray(b.skeleton.offsets), atol=pos_atol, rtol=0)
    assert_same_rotation(a.quat_local, b.quat_local, atol=quat_atol)
    np.testing.assert_allclose(a.pos_local, b.pos_local, atol=pos_atol, rtol=0)


def assert_round_trips(motion: BvhMotion, tmp_path: Path, precision: int = 6) -> None:
    """read → write → read is exact to the written precision, and writing again gives the same text."""
    path = tmp_path / "round_trip.bvh"
    write_bvh(path, motion, precision=precision)
    again = read_bvh(path)
    # Rounding each angle by ≤ 0.5·10^-p degrees moves the quaternion by ≤ ~1.3e-2·10^-p.
    assert_same_motion(motion, again, quat_atol=2e-2 * 10.0**-precision, pos_atol=0.5 * 10.0**-precision + 1e-12)
    assert format_bvh(again, precision=precision) == path.read_text()


# ------------------------------------------------------------------------------ real fixture


def test_fixture_hierarchy_and_values(fixture_motion: BvhMotion):
    m = fixture_motion
    assert m.skeleton.names == BANDAI_JOINTS
    assert m.num_frames == 40 and m.quat_local.shape == (40, 22, 4) and m.pos_local.shape == (40, 22, 3)
    assert m.quat_local.dtype == np.float64 and m.pos_local.dtype == np.float64
    assert m.frame_time == 0.0333333
    assert all(c == ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation") for c in m.channels)
    assert [p for p, _ in m.end_sites] == list(m.skeleton.indices(("Head", "Hand_L", "Hand_R", "Toes_L", "Toes_R")))
    np.testing.assert_allclose(np.linalg.norm(m.quat_local, axis=-1), 1.0, atol=1e-12)
    # Each joint's 6 values: position then Z, X, Y rotation in degrees, R = Rz·Rx·Ry.
    rows = np.asarray(_motion_rows(FIXTURE.read_text())).reshape(40, 22, 6)
    np.testing.assert_array_equal(m.pos_local, rows[..., :3])
    expected = np_matrix_from_euler(np.deg2rad(rows[..., 3:]), "zxy")
    np.testing.assert_allclose(np_matrix_from_quat(m.quat_local), expected, atol=1e-12)
    assert np.asarray(m.skeleton.offsets)[8, 1] == 1.87007e-05  # scientific notation in the original file


def test_fixture_round_trip(fixture_motion: BvhMotion, tmp_path: Path):
    assert_round_trips(fixture_motion, tmp_path)


@pytest.mark.parametrize("precision", [3, 6, 9])
def test_round_trip_of_unrounded_motion(precision: int, rng: np.random.Generator, tmp_path: Path):
    """A motion with full-precision values survives write → read to the written precision."""
    offsets = [[1.0, 2.0, 3.0], [0.0, 10.123456789, 0.0], [3.3, 0.0, 0.0], [0.0, 0.0, -4.25]]
    skeleton = Skeleton((-1, 0, 1, 1), ("root", "a", "b", "c"), np.asarray(offsets))
    q = rng.normal(size=(7, 4, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    motion = BvhMotion.from_skeleton(
        skeleton,
        q,
        rng.normal(scale=50.0, size=(7, 3)),
        frame_time=1 / 30,
        rotation_order="yxz",
        end_sites=[(2, (0.5, 0.0, 0.0))],
    )
    assert_round_trips(motion, tmp_path, precision)


@pytest.mark.parametrize("fps", [24.0, 30.0, 60.0, 120.0])
def test_frame_time_is_written_exactly(fps: float, tmp_path: Path):
    """1/fps reads back as fps to float precision (Blender shows 0.0333333 as 30.00003 fps)."""
    skeleton = Skeleton((-1, 0), ("root", "a"), np.asarray([[0.0, 0.0, 0.0], [0.0, 10.0, 0.0]]))
    motion = BvhMotion.from_skeleton(skeleton, np.tile([1.0, 0, 0, 0], (3, 2, 1)), np.zeros((3, 3)), frame_time=1 / fps)
    write_bvh(tmp_path / "a.bvh", motion, precision=3)
    line = next(x for x in (tmp_path / "a.bvh").read_text().splitlines() if x.startswith("Frame Time:"))
    assert len(line.split(":")[1].strip().lstrip("0.")) >= 10  # significant digits, whatever the precision
    back = read_bvh(tmp_path / "a.bvh")
    assert abs(back.fps - fps) < 1e-9 and back.nominal_fps == fps


def test_nominal_fps_of_a_rounded_frame_time(fixture_motion: BvhMotion):
    """A frame time written to 6 or 7 decimals stands for a whole rate; 29.97 fps stays."""
    assert fixture_motion.frame_time == 0.0333333 and fixture_motion.fps != 30.0
    assert fixture_motion.nominal_fps == 30.0
    for frame_time, fps in ((0.033333, 30.0), (0.008333, 120.0), (0.004167, 240.0), (0.04, 25.0), (1 / 29.97, 1 / (1 / 29.97))):
        assert dataclasses.replace(fixture_motion, frame_time=frame_time).nominal_fps == fps, frame_time


@pytest.mark.parametrize(
    "written, fps",
    [
        ("0.03333", 30.0),  # cut off at 5 decimals: 30.003 fps as written
        ("3.333e-02", 30.0),  # the same in scientific notation
        ("0.0333", 30.0),  # 4 decimals: 30.03
        ("0.0167", 60.0),  # 4 decimals, rounded: 59.88
        ("0.0083", 120.0),  # 120.48
        ("0.033367", 1 / 0.033367),  # 29.97 written to 6 decimals stays 29.97
        ("0.0334", 30.0),  # 29.94 at 4 decimals cannot be told from 30
        ("0.017", 1 / 0.017),  # 3 decimals fit 59 and 60 fps alike: taken as written
    ],
)
def test_nominal_fps_reads_the_decimals_the_frame_time_was_written_to(written: str, fps: float):
    """A frame time is 1/fps rounded or cut off to the decimals written, so a short one
    (0.03333) still stands for 30 fps; a frame time written too short to tell stays as it is."""
    text = "\n".join(_replace(18, f"Frame Time: {written}")(TEMPLATE)) + "\n"
    motion = parse_bvh(text, "rate.bvh")
    assert motion.nominal_fps == fps


def test_crlf_reads_like_lf(fixture_motion: BvhMotion, tmp_path: Path):
    crlf = tmp_path / "crlf.bvh"
    crlf.write_bytes(FIXTURE.read_bytes().replace(b"\n", b"\r\n"))
    m = read_bvh(crlf)
    np.testing.assert_array_equal(m.quat_local, fixture_motion.quat_local)
    np.testing.assert_array_equal(m.pos_local, fixture_motion.pos_local)
    np.testing.assert_array_equal(np.asarray(m.skeleton.offsets), np.asarray(fixture_motion.skeleton.offsets))
    assert (m.skeleton.names, m.channels, m.frame_time, m.end_sites) == (
        fixture_motion.skeleton.names, fixture_motion.channels, fixture_motion.frame_time, fixture_motion.end_sites
    )  # fmt: skip


# ------------------------------------------------------------------------ hand-written files

MIXED = """\
HIERARCHY
ROOT root
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
\tJOINT arm
\t{
\t\tOFFSET 1.0E+01 0 0
\t\tCHANNELS 3 Xrotation Yrotation Zrotation
\t\tJOINT hand
\t\t{
\t\t\tOFFSET 0 5 0
\t\t\tCHANNELS 6 Yrotation Xposition Yposition Zposition Xrotation Zrotation
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0 0 2.5e0
\t\t\t}
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 4e-2
1 2 3 0 0 0   0 0 0   0 0 5 0 0 0
0 0 0 90 0 0  0 0 0   0 0 5 0 0 0
0 0 0 0 0 0   0 9.0e1 0   0 0 0 3 0 0
"""


def test_mixed_channel_orders_and_scientific_notation():
    m = parse_bvh(MIXED, "mixed.bvh")
    assert m.skeleton.names == ("root", "arm", "hand") and m.skeleton.parents == (-1, 0, 1)
    assert m.channels[1] == ("Xrotation", "Yrotation", "Zrotation")
    assert m.channels[2] == ("Yrotation", "Xposition", "Yposition", "Zposition", "Xrotation", "Zrotation")
    assert m.frame_time == 0.04
    assert m.end_sites == ((2, (0.0, 0.0, 2.5)),)
    np.testing.assert_array_equal(np.asarray(m.skeleton.offsets), [[0, 0, 0], [10, 0, 0], [0, 5, 0]])
    # The hand's position channels replace its OFFSET; the arm keeps its OFFSET.
    np.testing.assert_array_equal(m.pos_local[:, 2], [[0, 5, 0], [0, 5, 0], [0, 0, 3]])
    np.testing.assert_array_equal(m.pos_local[:, 1], np.broadcast_to([10.0, 0, 0], (3, 3)))


def test_mixed_channels_forward_kinematics_by_hand():
    m = parse_bvh(MIXED, "mixed.bvh")
    expected = np.array(
        [
            [[1, 2, 3], [11, 2, 3], [11, 7, 3]],  # frame 0: pure translation
            [[0, 0, 0], [0, 10, 0], [-5, 10, 0]],  # frame 1: root Rz(90°) turns +X to +Y and +Y to -X
            [[0, 0, 0], [10, 0, 0], [13, 0, 0]],  # frame 2: arm Ry(90°) turns the hand's (0, 0, 3) to +X
        ],
        float,
    )
    with jax.enable_x64(True):
        _, pos = forward_kinematics(m.skeleton.parents, jnp.asarray(m.quat_local), jnp.asarray(m.pos_local))
    np.testing.assert_allclose(np.asarray(pos), expected, atol=1e-12)
    _, pos_reference = np_forward_kinematics(m.skeleton.parents, m.quat_local, m.pos_local)
    np.testing.assert_allclose(pos_reference, expected, atol=1e-12)


def test_rotation_order_follows_the_channel_order():
    """``Yrotation … Xrotation Zrotation`` means R = Ry·Rx·Rz, whatever channels sit between."""
    text = MIXED.replace("0 0 0 0 0 0   0 9.0e1 0   0 0 0 3 0 0", "0 0 0 0 0 0   0 0 0   30 0 0 0 -45 60")
    m = parse_bvh(text, "mixed.bvh")
    expected = np_matrix_from_euler(np.deg2rad([30.0, -45.0, 60.0]), "yxz")
    np.testing.assert_allclose(np_matrix_from_quat(m.quat_local[2, 2]), expected, atol=1e-12)


# ------------------------------------------------------------------------------ real corpora


def _read_tar_member(archive: Path, name: str) -> bytes:
    with tarfile.open(archive, "r|xz") as tar:
        for member in tar:
            if Path(member.name).name == name:
                return tar.extractfile(member).read()
    raise FileNotFoundError(f"{name} not in {archive}")


@requires_lafan1
def test_lafan1_file_reads_in_reference_order_and_round_trips(tmp_path: Path):
    with zipfile.ZipFile(LAFAN1_ZIP) as zf:
        raw = zf.read("walk4_subject1.bvh")
    assert b"\r\n" in raw  # LaFAN1 ships CRLF files
    m = parse_bvh(raw.decode("utf-8"), "walk4_subject1.bvh")
    assert m.skeleton.names == LAFAN1_JOINTS
    assert m.skeleton.parents == (-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 12, 11, 14, 15, 16, 11, 18, 19, 20)
    assert m.num_frames == 4918 and len(m.end_sites) == 5
    assert m.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    assert all(c == ("Zrotation", "Yrotation", "Xrotation") for c in m.channels[1:])
    # Continuity fixed over time: consecutive frames of a joint lie in the same hemisphere.
    assert (np.sum(m.quat_local[1:] * m.quat_local[:-1], axis=-1) >= 0).all()
    assert_round_trips(m, tmp_path)


@requires_bandai
def test_bandai_namco_full_clip_and_the_fixture_cut_from_it(tmp_path: Path):
    raw = _read_tar_member(BANDAI_ARCHIVE, FIXTURE_ORIGINAL)
    full = parse_bvh(raw.decode("utf-8"), FIXTURE_ORIGINAL)
    assert full.num_frames == 273 and full.skeleton.names == BANDAI_JOINTS
    # The fixture is the original text with frames cut and the frame count fixed.
    original, fixture = raw.decode().split("\n"), FIXTURE.read_text().split("\n")
    frames_line = original.index("Frames:\t273")
    assert fixture[:frames_line] == original[:frames_line] and fixture[frames_line] == "Frames:\t40"
    assert fixture[frames_line + 1 : -1] == original[frames_line + 1 : frames_line + 42]
    np.testing.assert_array_equal(read_bvh(FIXTURE).pos_local, full.pos_local[:40])
    assert_round_trips(full, tmp_path)


# ------------------------------------------------------------------------------- bad input

TEMPLATE = [
    "HIERARCHY",  # 1
    "ROOT Hips",  # 2
    "{",  # 3
    "\tOFFSET 0 0 0",  # 4
    "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation",  # 5
    "\tJOINT Chest",  # 6
    "\t{",  # 7
    "\t\tOFFSET 0 10 0",  # 8
    "\t\tCHANNELS 3 Zrotation Xrotation Yrotation",  # 9
    "\t\tEnd Site",  # 10
    "\t\t{",  # 11
    "\t\t\tOFFSET 0 5 0",  # 12
    "\t\t}",  # 13
    "\t}",  # 14
    "}",  # 15
    "MOTION",  # 16
    "Frames: 2",  # 17
    "Frame Time: 0.0333333",  # 18
    "0 90 0 0 0 0 0 0 0",  # 19
    "1 90 0 10 0 0 0 0 0",  # 20
]


def _replace(line: int, text: str):
    return lambda lines: lines[: line - 1] + [text] + lines[line:]


def _delete(line: int):
    return lambda lines: lines[: line - 1] + lines[line:]


def _insert(after: int, text: str):
    return lambda lines: lines[:after] + [text] + lines[after:]


MALFORMED = {
    "missing brace": (_delete(7), 7, r"expected '\{' after the declaration on line 6"),
    "bad offset number": (_replace(8, "\t\tOFFSET 0 1O 0"), 8, r"OFFSET: expected numbers, got '0 1O 0'"),
    "short offset": (_replace(8, "\t\tOFFSET 0 10"), 8, r"OFFSET needs 3 numbers, got 2"),
    "unknown channel": (_replace(9, "\t\tCHANNELS 3 Zrotation Xrotation Wrotation"), 9, r"unknown channel 'Wrotation'"),
    "channel count": (_replace(9, "\t\tCHANNELS 4 Zrotation Xrotation"), 9, r"announces 4 channels but lists 2"),
    "repeated axis": (_replace(9, "\t\tCHANNELS 3 Zrotation Xrotation Xrotation"), 9, r"three distinct axes"),
    "too few values": (_replace(20, "1 90 0 10 0 0 0 0"), 20, r"frame 1 has 8 values, the hierarchy declares 9"),
    "non-numeric": (_replace(19, "0 90 0 abc 0 0 0 0 0"), 19, r"frame 0: 'abc' is not a number"),
    "nan value": (_replace(20, "1 90 0 10 nan 0 0 0 0"), 20, r"frame 1: non-finite value"),
    "fewer frames": (_replace(17, "Frames: 3"), 20, r"'Frames:' announces 3 frames but the file has 2"),
    "more frames": (_insert(20, "2 90 0 10 0 0 0 0 0"), 21, r"more motion rows than the 2 announced"),
    "end site channels": (_insert(12, "\t\t\tCHANNELS 1 Xrotation"), 13, r"an End Site cannot have CHANNELS"),
    "missing MOTION": (_delete(16), 16, r"expected 'MOTION' after the hierarchy, got 'Frames: 2'"),
    "truncated hierarchy": (lambda lines: lines[:12], 12, r"unexpected end of file"),
    "negative frame time": (_replace(18, "Frame Time: -0.04"), 18, r"Frame Time must be positive, got -0.04"),
    "zero frame time": (_replace(18, "Frame Time: 0"), 18, r"Frame Time must be positive, got 0.0"),
    "denormal frame time": (_replace(18, "Frame Time: 1e-320"), 18, r"Frame Time must lie in 1e-05 … 60 s, got 9.99989e-321"),
    "hour-long frame": (_replace(18, "Frame Time: 3600"), 18, r"Frame Time must lie in 1e-05 … 60 s, got 3600"),
    "duplicate joint": (_replace(6, "\tJOINT Hips"), 6, r"joint name 'Hips' is used twice"),
    "bad frame count": (_replace(17, "Frames: many"), 17, r"expected 'Frames: <count>'"),
    "huge offset": (_replace(8, "\t\tOFFSET 0 1e300 0"), 8, r"OFFSET: 1e300 is out of range, beyond ±1e\+06$"),
    "hips offset -1e308": (_replace(4, "\tOFFSET -1e308 0 0"), 4, r"OFFSET: -1e308 is out of range"),
    "infinite offset": (_replace(12, "\t\t\tOFFSET 0 inf 0"), 12, r"OFFSET: non-finite value 'inf' in '0 inf 0'"),
    "huge position": (_replace(19, "0 1e9 0 0 0 0 0 0 0"), 19, r"frame 0: Hips Yposition 1e9 is out of range, beyond ±1e\+08$"),
    "huge angle": (_replace(20, "1 90 0 10 0 0 0 0 -2e6"), 20, r"frame 1: Chest Yrotation -2e6 is out of range, beyond ±1e\+06 degrees"),
    "infinite angle": (_replace(20, "1 90 0 10 0 0 -inf 0 0"), 20, r"frame 1: non-finite value '-inf' in Chest Zrotation"),
    "5,000-digit frame count": (_replace(17, "Frames: " + "9" * 5000), 17, r"expected 'Frames: <count>', got 'Frames: 9+ … 9+'$"),
}


def test_template_is_valid(tmp_path: Path):
    path = tmp_path / "good.bvh"
    path.write_text("\n".join(TEMPLATE) + "\n")
    m = read_bvh(path)
    assert m.skeleton.names == ("Hips", "Chest") and m.num_frames == 2


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_file_names_file_line_and_problem(case: str, tmp_path: Path):
    edit, line, phrase = MALFORMED[case]
    path = tmp_path / f"{case.replace(' ', '_')}.bvh"
    path.write_text("\n".join(edit(list(TEMPLATE))) + "\n")
    with pytest.raises(ValueError) as info:
        read_bvh(path)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}: "), message
    assert re.search(phrase, message), message
    assert "\n" not in message and len(message) <= MESSAGE_CHARS, message


@pytest.mark.parametrize(
    "content, problem",
    [(b"", "the file is empty"), (b"\r", "the file has only blank lines"), (b"\r\r\r", "the file has only blank lines"), (b" \r\n\t\n", "the file has only blank lines")],
)
def test_an_empty_file_is_reported_at_line_1(content: bytes, problem: str, tmp_path: Path):
    path = tmp_path / "empty.bvh"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}:1: {problem}$"):
        read_bvh(path)


def _nested(depth: int, siblings: int = 0) -> str:
    """A BVH text: a root, ``depth`` joints nested one in another below it (no channels), and
    ``siblings`` more side by side under the root."""
    chain = [f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0" for i in range(depth)]
    side = [f"JOINT s{i}\n{{\nOFFSET 1 0 0\n}}" for i in range(siblings)]
    hierarchy = "\n".join(["HIERARCHY", "ROOT root", "{", "OFFSET 0 0 0", "CHANNELS 3 Xposition Yposition Zposition", *side, *chain])
    return hierarchy + "\n" + "}\n" * (depth + 1) + "MOTION\nFrames: 1\nFrame Time: 0.0333333\n0 0 0\n"


def test_nesting_deeper_than_max_depth_is_refused_at_its_line_not_by_recursion(tmp_path: Path):
    """Thousands of nested joints (Python's recursion limit is about 1,000) give one line at
    the first joint too deep; ``MAX_DEPTH`` nested joints read and write back."""
    deep = tmp_path / "deep.bvh"
    deep.write_text(_nested(5_000))
    first_too_deep = 6 + 4 * (MAX_DEPTH - 1)  # "JOINT j255": the root is depth 1
    with pytest.raises(ValueError, match=rf"^{re.escape(str(deep))}:{first_too_deep}: joints nested more than {MAX_DEPTH} deep$"):
        read_bvh(deep)
    deepest = parse_bvh(_nested(MAX_DEPTH - 1), "deepest.bvh")
    assert deepest.skeleton.num_joints == MAX_DEPTH
    assert parse_bvh(format_bvh(deepest), "again.bvh").skeleton.parents == deepest.skeleton.parents


def test_more_joints_than_max_joints_are_refused(tmp_path: Path):
    path = tmp_path / "wide.bvh"
    path.write_text(_nested(0, siblings=MAX_JOINTS))
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}:{6 + 4 * (MAX_JOINTS - 1)}: more than {MAX_JOINTS} joints$"):
        read_bvh(path)


def test_a_long_line_is_cut_in_the_middle_of_its_message(tmp_path: Path):
    """A 5,000-character line is quoted in part: the message keeps the file, the line and
    what is wrong on one line."""
    path = tmp_path / "long.bvh"
    path.write_text("\n".join(_replace(9, "\t\t" + "y" * 5000 + " CHANNELS")(TEMPLATE)) + "\n")
    with pytest.raises(ValueError) as info:
        read_bvh(path)
    message = str(info.value)
    assert message.startswith(f"{path}:9: unexpected 'yyy") and message.endswith("yyy CHANNELS' inside 'Chest'"), message
    assert len(message) <= MESSAGE_CHARS and " … " in message


# ------------------------------------------------------------------------------- writing


def test_failed_write_leaves_the_old_file_and_no_temp_file(fixture_motion: BvhMotion, tmp_path: Path):
    path = tmp_path / "out.bvh"
    write_bvh(path, fixture_motion)
    before = path.read_bytes()
    quat = fixture_motion.quat_local.copy()
    quat[3, 5, 0] = np.nan
    broken = dataclasses.replace(fixture_motion, quat_local=quat)
    with pytest.raises(ValueError, match=r"cannot write non-finite quat_local at frame 3, joint 5 \('Head'\)"):
        write_bvh(path, broken)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["out.bvh"]


def _with(array, index, value) -> np.ndarray:
    """A copy of ``array`` with ``array[index] = value``."""
    changed = np.array(array, np.float64)
    changed[index] = value
    return changed


@pytest.mark.parametrize(
    "change, problem",
    [
        (lambda m: dataclasses.replace(m, pos_local=m.pos_local + np.where(np.arange(22) == 1, 2e8, 0.0)[:, None]),
         r"cannot write pos_local 2(\.\d+)?e\+08 at frame 0, joint 1 \('Hips'\): a position channel is at most 1e\+08 in size"),
        (lambda m: dataclasses.replace(m, skeleton=dataclasses.replace(m.skeleton, offsets=_with(m.skeleton.offsets, (1, 1), -1e308))),
         r"cannot write the OFFSET -1e\+308 of joint 1 \('Hips'\): an OFFSET is finite and at most 1e\+06 in size"),
        (lambda m: dataclasses.replace(m, end_sites=m.end_sites[:1] + ((m.end_sites[1][0], (0.0, np.inf, 0.0)),)),
         r"cannot write the End Site OFFSET inf under joint 9 \('Hand_L'\): an OFFSET is finite"),
        (lambda m: dataclasses.replace(m, skeleton=dataclasses.replace(m.skeleton, names=("Hips", "Left\nUpLeg", *m.skeleton.names[2:]))),
         r"cannot write joint 1 \('Left\\nUpLeg'\): a joint's name is words joined by single spaces"),
        (lambda m: dataclasses.replace(m, skeleton=dataclasses.replace(m.skeleton, names=("Hips", "Spine {", *m.skeleton.names[2:]))),
         r"cannot write joint 1 \('Spine \{'\): a joint's name is words joined by single spaces, not ending in '\{'"),
    ],
)
def test_writing_refuses_what_reading_would(fixture_motion: BvhMotion, change, problem: str, tmp_path: Path):
    with pytest.raises(ValueError, match=problem):
        write_bvh(tmp_path / "out.bvh", change(fixture_motion))
    assert not list(tmp_path.iterdir())


def test_write_interrupted_mid_file_leaves_the_old_file(fixture_motion: BvhMotion, tmp_path: Path, monkeypatch):
    import bezmotion._src.io

    path = tmp_path / "out.bvh"
    path.write_text("old contents\n")

    def disk_full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(bezmotion._src.io.os, "fsync", disk_full)
    with pytest.raises(OSError, match="No space left"):
        write_bvh(path, fixture_motion)
    assert path.read_text() == "old contents\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.bvh"]


def test_more_joint_frames_than_the_bound_are_refused_before_any_row_is_read(tmp_path: Path):
    """A frame count that would need tens of gigabytes is refused at its line, before the rows."""
    hierarchy = DEMO_CLIP.read_text().split("MOTION")[0]
    joints = hierarchy.count("ROOT") + hierarchy.count("JOINT")
    frames = MAX_JOINT_FRAMES // joints + 1
    path = tmp_path / "long.bvh"
    path.write_text(f"{hierarchy}MOTION\nFrames: {frames}\nFrame Time: 0.0333333\n0 0 0\n")
    line = hierarchy.count("\n") + 2
    with pytest.raises(ValueError, match=rf"^{path}:{line}: {frames} frames of {joints} joints: more than 50,000,000 joint-frames; split the file$"):
        read_bvh(path)
