"""What ``bezmotion inbetween`` writes where: ``--out`` told a file or a folder by its name; a
run's files written as one set that replaces the earlier one whole, the user's other files
kept; files bezmotion did not write replaced only with ``--force``.

The sets are written by the command's own :func:`~bezmotion.cli.inbetween.write_outputs`
from a plan, with the clip's frames 0…30 standing in for the in-between: no sampling, so
nothing here waits for the sampler to compile.
"""

from __future__ import annotations

import json
import os

import pytest

from bezmotion._src.output_sets import OUTPUTS_RECORD, STAGING_PREFIX
from bezmotion._src.options import parse_options
from bezmotion.assets import DEMO_CLIP
from bezmotion.cli.inbetween import write_outputs
from bezmotion.cli.plan import InbetweenCommand, plan
from bezmotion.data.bvh import read_bvh
from bezmotion.pipeline import authoring
from bezmotion.pipeline.authoring import ResultFiles, motion_poses, motion_window, output_format

FAST = ["--ik", "rig", "--steps", "2", "--no-progress", "--no-preview"]


@pytest.mark.parametrize(
    "out, kind",
    [
        ("take", None), ("take/", None), ("take.v2", None), ("run.001", None), ("a.b/take", None),
        ("take.bvh", ".bvh"), ("TAKE.GLB", ".glb"), ("x.gif", ".gif"), ("take.bvh/", None),
        ("take.fbx", "unknown output format '.fbx'; bezmotion writes .bvh, .glb, .gif files, and into a folder named with a trailing / (take.fbx/)"),
        ("take.json", "unknown output format '.json'"), ("take.mp4", "unknown output format '.mp4'"),
    ],
)  # fmt: skip
def test_out_is_a_file_by_its_format_and_any_other_name_a_folder(out, kind, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    if kind is None or kind.startswith("."):
        assert output_format(out) == kind
    else:
        with pytest.raises(ValueError) as error:
            output_format(out)
        assert str(error.value).startswith(kind)


def test_an_existing_folder_is_a_folder_and_one_named_like_a_file_is_refused(tmp_path):
    (tmp_path / "take.final").mkdir()
    (tmp_path / "take.bvh").mkdir()
    assert output_format(tmp_path / "take.final") is None
    assert output_format(f"{tmp_path}/take.bvh/") is None
    with pytest.raises(ValueError, match=f"^is a folder; {tmp_path}/take.bvh/ writes into it$"):
        output_format(tmp_path / "take.bvh")


def _plan(out, *argv):
    return plan(parse_options(InbetweenCommand, [str(DEMO_CLIP), "--frames", "0", "30", *FAST, "--out", str(out), *argv]))


def _write(p) -> dict:
    """Write ``p``'s set with the clip's frames 0…30 as every sample; returns the summary."""
    clip = read_bvh(DEMO_CLIP)
    character = p.recognised.character
    files = ResultFiles(character, motion_window(clip, 0, 31), None, p.bmm.config.stride)
    summary = {"samples": [{"sample": k, "files": {}} for k in range(len(p.outputs))]}
    write_outputs(p, [(files, motion_poses(clip, character, slice(0, 31)))] * len(p.outputs), summary, started=0.0, say=lambda _: None)
    return summary


def _listing(folder) -> list[str]:
    return sorted(os.listdir(folder))


def test_a_second_run_replaces_the_whole_set_and_keeps_the_users_files(tmp_path, monkeypatch):
    """Two samples, then one: the second set replaces the first at once (the folder holds the
    first, untouched, while the second is written), the first's numbered files are removed,
    the user's notes stay, and no staging folder is left."""
    out = tmp_path / "take"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    first = _write(_plan(out, "--samples", "2"))
    assert first["samples"][1]["files"] == {"bvh": f"{out}/inbetween_1.bvh", "glb": f"{out}/inbetween_1.glb"}
    earlier = ["inbetween_0.bvh", "inbetween_0.glb", "inbetween_1.bvh", "inbetween_1.glb", "summary.json"]
    assert _listing(out) == sorted([OUTPUTS_RECORD, *earlier, "notes.txt"])
    contents = {name: (out / name).read_bytes() for name in _listing(out)}

    p = _plan(out)
    assert (p.existing.ours, p.existing.theirs) == (("summary.json",), ())
    assert p.existing.stale == tuple(earlier[:-1])
    seen = []
    write_glb = authoring.WRITERS[".glb"]

    def glb_while_the_folder_holds_the_earlier_set(path, result):
        seen.append({name: (out / name).read_bytes() for name in _listing(out) if not name.startswith(STAGING_PREFIX)})
        write_glb(path, result)

    monkeypatch.setitem(authoring.WRITERS, ".glb", glb_while_the_folder_holds_the_earlier_set)
    summary = _write(p)
    assert seen == [contents]  # the BVH written already, yet nothing of it in the folder
    assert _listing(out) == sorted([OUTPUTS_RECORD, "inbetween.bvh", "inbetween.glb", "notes.txt", "summary.json"])
    assert (out / "notes.txt").read_text() == "mine\n"
    assert json.loads((out / "summary.json").read_text()) == summary
    assert summary["samples"][0]["files"] == {"bvh": f"{out}/inbetween.bvh", "glb": f"{out}/inbetween.glb"}
    assert summary["samples"][0]["bvh_fk_error_cm"] < 1e-3  # checked in the staging folder, before the move
    assert p.existing.note(p.out_dir) == (
        f"replaced summary.json and removed inbetween_0.bvh, inbetween_0.glb, inbetween_1.bvh, inbetween_1.glb (of the earlier set) in {out}"
    )


def test_a_run_that_fails_while_writing_leaves_the_earlier_set(tmp_path, monkeypatch):
    out = tmp_path / "take"
    _write(_plan(out))
    before = {name: (out / name).read_bytes() for name in _listing(out)}

    def glb_that_fails(path, result):
        raise OSError("no space left on device")

    monkeypatch.setitem(authoring.WRITERS, ".glb", glb_that_fails)
    with pytest.raises(OSError, match="no space left"):
        _write(_plan(out, "--seed", "1"))
    assert {name: (out / name).read_bytes() for name in _listing(out)} == before


def test_files_bezmotion_did_not_write_are_replaced_only_with_force(tmp_path):
    out = tmp_path / "take"
    out.mkdir()
    (out / "inbetween.bvh").write_text("the user's own\n")
    with pytest.raises(ValueError, match=rf"^--out {out}: would replace inbetween.bvh, which is not bezmotion's own output \(unrecorded, or changed since\); --force replaces it$"):
        _plan(out)
    assert (out / "inbetween.bvh").read_text() == "the user's own\n"
    p = _plan(out, "--force")
    assert p.existing.theirs == ("inbetween.bvh",)
    _write(p)
    assert read_bvh(out / "inbetween.bvh").num_frames == 31
    # Written by bezmotion now: the next run replaces it without --force, and a file output
    # written twice is replaced the second time too.
    assert _plan(out).existing.ours == ("inbetween.bvh", "inbetween.glb", "summary.json")
    _write(_plan(tmp_path / "x.bvh"))
    assert _plan(tmp_path / "x.bvh").existing.ours == ("x.bvh",)


def test_an_input_given_as_out_is_refused_without_force(tmp_path):
    clip = tmp_path / "walk.bvh"
    clip.write_bytes(DEMO_CLIP.read_bytes())
    argv = ["--start", f"{clip}@0", "--end", f"{clip}@30", *FAST, "--out", str(clip)]
    with pytest.raises(ValueError, match=rf"^--out {clip}: would replace walk.bvh, the --start file, an input of this run; --force replaces it$"):
        plan(parse_options(InbetweenCommand, argv))
    assert clip.read_bytes() == DEMO_CLIP.read_bytes()
    assert plan(parse_options(InbetweenCommand, [*argv, "--force"])).existing.theirs == ("walk.bvh",)
