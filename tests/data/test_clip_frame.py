"""A clip's units and up axis: told from the bundled clip in every convention we convert
to, the conversion exact both ways, and clear errors where neither can be told."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from helpers import np_forward_kinematics, turned_about_z

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh
from bezmotion.data.clip_frame import CM_PER_UNIT, TYPICAL_PERSON_CM, ClipFrame, detect_clip_frame, detect_units, detect_up, skeleton_size
from bezmotion.ik.protocol import Character

CLIP = read_bvh(DEMO_CLIP)  # Bandai-Namco: cm, Y up
HIPS, HEAD, _, _, LEFT_FOOT, RIGHT_FOOT = Character.from_bvh(CLIP, "bandai_namco").characteristic
FEET = (LEFT_FOOT, RIGHT_FOOT)
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) → (x, z, −y)


def positions(motion) -> np.ndarray:
    return np_forward_kinematics(motion.skeleton.parents, motion.quat_local, motion.pos_local)[1]


FRAMES = [ClipFrame(units, up) for units in CM_PER_UNIT for up in ("y", "z")]


@pytest.mark.parametrize("frame", FRAMES, ids=str)
def test_a_motion_of_ours_in_any_frame_and_back(frame):
    """``from_ours`` scales every length (offsets, translations, End Sites) and turns Z up
    about X; ``to_ours`` undoes it to float64 rounding."""
    theirs = frame.from_ours(CLIP)
    scale, turn = CM_PER_UNIT[frame.units], (Z_UP_TO_Y_UP if frame.up == "z" else np.eye(3))
    np.testing.assert_allclose(positions(theirs) * scale @ turn.T, positions(CLIP), atol=1e-9)
    np.testing.assert_allclose([np.asarray(o) * scale for _, o in theirs.end_sites], [o for _, o in CLIP.end_sites], atol=1e-9)
    back = frame.to_ours(theirs)
    np.testing.assert_allclose(back.pos_local, CLIP.pos_local, atol=1e-9)
    np.testing.assert_allclose(back.skeleton.offsets, CLIP.skeleton.offsets, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(back.quat_local * CLIP.quat_local, axis=-1)), 1.0, atol=1e-12)


@pytest.mark.parametrize("frame", [f for f in FRAMES if f.units != "in"], ids=str)
def test_units_and_up_are_told_from_the_clip(frame):
    assert detect_clip_frame(frame.from_ours(CLIP), HIPS, HEAD, FEET) == frame


def test_inches_read_as_a_typical_adults_unit():
    """A person is ~55–65 in head to hips to foot: no person's size in cm, m or mm, so the unit is
    the one that makes a typical adult, within a person's build of the inch."""
    units = detect_units(ClipFrame("in").from_ours(CLIP), HIPS, HEAD, FEET)
    assert units not in CM_PER_UNIT and 0.8 < float(units) / 2.54 < 1.25


def test_a_size_no_named_unit_makes_a_person_is_taken_for_a_typical_adults():
    """Raw CMU files are in a unit of about 5.6 cm: a person's size in none of cm, m and mm.
    The unit is then the one that makes the skeleton a typical adult's size, within a
    person's build of the truth; a skeleton of no size at all raises."""
    cmu = ClipFrame(f"{5.6:.6g}")
    units = detect_units(cmu.from_ours(CLIP), HIPS, HEAD, FEET)
    assert units not in CM_PER_UNIT
    size = skeleton_size(ClipFrame(units).to_ours(cmu.from_ours(CLIP)), HIPS, HEAD, FEET)
    assert size == pytest.approx(TYPICAL_PERSON_CM, rel=1e-5)
    assert 0.7 < float(units) / 5.6 < 1.4  # the demo's actor is 134 cm head to hips to foot
    flat = dataclasses.replace(CLIP, skeleton=dataclasses.replace(CLIP.skeleton, offsets=np.zeros_like(CLIP.skeleton.offsets)))
    with pytest.raises(ValueError, match=r"cannot tell the clip's units: its head-to-hips-to-foot bones are 0 units long"):
        detect_units(flat, HIPS, HEAD, FEET)


def test_a_unit_may_be_any_number_of_centimetres():
    frame = ClipFrame("5.6", "z")
    assert frame.cm_per_unit == 5.6 and not frame.is_ours
    back = frame.to_ours(frame.from_ours(CLIP))
    np.testing.assert_allclose(positions(back), positions(CLIP), atol=1e-9)


def lying(motion, frames: int, about_z: float):
    """``frames`` copies of the motion's first frame turned ``about_z`` degrees about Z (lying along ∓X)."""
    first = dataclasses.replace(motion, quat_local=motion.quat_local[:1], pos_local=motion.pos_local[:1])
    turned = turned_about_z(first, about_z)
    return dataclasses.replace(turned, quat_local=np.repeat(turned.quat_local, frames, axis=0), pos_local=np.repeat(turned.pos_local, frames, axis=0))


def concatenated(*motions):
    return dataclasses.replace(
        motions[0], quat_local=np.concatenate([m.quat_local for m in motions]), pos_local=np.concatenate([m.pos_local for m in motions])
    )


def test_up_is_told_where_lying_frames_outnumber_standing_ones():
    """100 frames lying along −X and 20 along +X beside the clip's 40 standing frames: the
    head's mean over frames points along −X, but up is the direction voted for whose
    opposite never is."""
    clip = concatenated(CLIP, lying(CLIP, 100, 90.0), lying(CLIP, 20, -90.0))
    above = positions(clip)[:, HEAD] - positions(clip)[:, list(FEET)].mean(axis=1)
    assert np.argmax(np.abs(above.mean(axis=0))) == 0  # the mean alone would say X
    assert detect_up(clip, HEAD, FEET) == "y"
    assert detect_up(ClipFrame("m", "z").from_ours(clip), HEAD, FEET) == "z"


def test_a_clip_standing_along_x_raises_with_the_counts():
    with pytest.raises(ValueError, match=r"cannot tell the clip's up axis: of 30 frames, the head stands above the feet along \+X in 0, −X in 30"):
        detect_up(lying(CLIP, 30, 90.0), HEAD, FEET)


def test_an_unknown_unit_or_axis_raises():
    with pytest.raises(ValueError, match=r"units must be one of cm, m, mm, in or centimetres per unit \(a number\), got 'km'"):
        ClipFrame("km")
    for bad in ("0", "-2", "nan", "inf", "1e300"):
        with pytest.raises(ValueError, match=f"got '{bad}'"):
            ClipFrame(bad)
    with pytest.raises(ValueError, match="up must be one of y, z, got 'x'"):
        ClipFrame("cm", "x")
