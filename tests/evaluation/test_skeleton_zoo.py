"""One motion written many ways (``bezmotion.evaluation.skeleton_zoo``, ``experiments/skeleton_zoo.py``):
each re-expression moves every joint as the original does, and ``bezmotion inbetween`` gives
the same in-between whatever the file's conventions."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import load_experiment

from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import read_bvh, write_bvh
from bezmotion.evaluation import skeleton_zoo as zoo
from bezmotion.pipeline.authoring import recognise_character


@pytest.fixture(scope="module")
def experiment():
    return load_experiment("skeleton_zoo")


@pytest.fixture(scope="module")
def reference(experiment):
    return zoo.renamed(read_bvh(DEMO_CLIP), lambda n: experiment.PREFIX + n)


def test_every_variant_moves_every_joint_as_the_reference_does(experiment, reference):
    truth = zoo.world_positions(reference)
    for name, variant in experiment.variants(reference).items():
        motion = variant.make(reference)
        if variant.fps in (24.0, 25.0):  # one second is 24 or 25 frames: its first and last frame are the reference's 0 and 30
            pos = experiment.in_reference_frame(variant, motion, reference.skeleton.names)
            np.testing.assert_allclose(pos[[0, round(variant.fps)]], truth[[0, 30]], atol=1e-6, err_msg=name)
            continue
        pos = experiment.in_reference_frame(variant, motion, reference.skeleton.names)
        gone = np.isnan(pos).any(axis=(0, 2))
        assert gone.sum() == (0 if variant.same_skeleton else 1), name
        np.testing.assert_allclose(pos[:, ~gone], truth[: pos.shape[0], ~gone], atol=1e-6, err_msg=name)
        assert recognise_character(motion).preset is None, name  # each goes the way a user's own character goes


def test_a_variant_survives_its_bvh_file(experiment, reference, tmp_path):
    variant = experiment.variants(reference)["daz_everything"]
    write_bvh(tmp_path / "v.bvh", variant.make(reference), precision=9)
    pos = experiment.in_reference_frame(variant, read_bvh(tmp_path / "v.bvh"), reference.skeleton.names)
    np.testing.assert_allclose(pos, zoo.world_positions(reference), atol=1e-4)


@pytest.fixture(scope="module")
def reference_in_between(experiment, reference, tmp_path_factory):
    folder = tmp_path_factory.mktemp("reference")
    write_bvh(folder / "reference.bvh", reference)
    return zoo.world_positions(experiment.run(folder / "reference.bvh", [0, 30], 0, folder / "reference_out.bvh"))


@pytest.mark.parametrize("name", ["daz_everything", "yaw_90", "z_up"])
def test_the_in_between_is_the_same_whatever_the_files_conventions(experiment, reference, reference_in_between, tmp_path, name):
    """Daz lower-case names, random bone axes, fingers, a jaw, twist joints and CMU's 5.6 cm unit
    all at once; the clip turned a quarter about the vertical; Z up: the in-between, brought back,
    is the reference's to within 0.5 cm."""
    ours = reference_in_between
    variant = experiment.variants(reference)[name]
    write_bvh(tmp_path / "variant.bvh", variant.make(reference), precision=9)
    theirs = experiment.in_reference_frame(variant, experiment.run(tmp_path / "variant.bvh", [0, 30], 0, tmp_path / "variant_out.bvh"), reference.skeleton.names)
    assert np.nanmax(np.linalg.norm(theirs - ours, axis=-1)) < 0.5  # measured 0.145 / 0.003 / 0.006 cm


def test_a_spine_joint_fewer_keeps_every_other_joint(reference):
    fewer = zoo.without_joint(reference, reference.skeleton.names[2])
    keep = [n for n in reference.skeleton.names if n != reference.skeleton.names[2]]
    pos = zoo.world_positions(fewer)[:, [fewer.skeleton.names.index(n) for n in keep]]
    np.testing.assert_allclose(pos, zoo.world_positions(reference)[:, [reference.skeleton.names.index(n) for n in keep]], atol=1e-9)
    with pytest.raises(ValueError, match="is the root"):
        zoo.without_joint(reference, reference.skeleton.names[0])
