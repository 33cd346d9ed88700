"""Models by name (:mod:`bezmotion.assets.registry`): ``bm.pretrained``, the checksum
manifest and ``bezmotion models``."""

from __future__ import annotations

import json
import shutil

import jax
import numpy as np
import pytest

import bezmotion as bm
from bezmotion.assets import MODELS_DIR, PROFILES_DIR
from bezmotion.assets.registry import (
    MANIFEST,
    REGISTRY,
    ChecksumError,
    folder_digest,
    load_pretrained,
    model_folder,
    read_manifest,
    write_manifest,
)
from bezmotion.cli import main
from bezmotion.ik.protocol import pose_fk
from bezmotion.pipeline.authoring import resolve_bmm, resolve_ik_model
from bezmotion.pipeline.transfer import CharacterProfile


def test_the_manifest_matches_the_bundled_files():
    """Every bundled folder, and nothing else, is in the committed manifest with its files'
    digest: changing a model without ``python -m bezmotion.assets.registry --write-manifest``
    fails here."""
    manifest = read_manifest()
    bundled = {getattr(e, part) for e in REGISTRY.values() if e.bundled for part in ("bmm", "ik")}
    on_disk = {p.name for p in MODELS_DIR.iterdir() if p.is_dir()}
    assert set(manifest) == bundled == on_disk
    for name, record in manifest.items():
        files = [p for p in (MODELS_DIR / name).rglob("*") if p.is_file()]
        assert record == {"sha256": folder_digest(MODELS_DIR / name), "files": len(files), "bytes": sum(p.stat().st_size for p in files)}, name


def test_write_manifest_reproduces_the_committed_one(tmp_path):
    shutil.copytree(MODELS_DIR, tmp_path / "models")
    (tmp_path / "models" / MANIFEST).unlink()
    write_manifest(tmp_path / "models")
    assert json.loads((tmp_path / "models" / MANIFEST).read_text()) == json.loads((MODELS_DIR / MANIFEST).read_text())


def test_load_pretrained_loads_working_parts():
    parts = load_pretrained("bandai_namco")
    assert parts.character is parts.ik.character and parts.character.name == "bandai_namco" and parts.character.num_joints == 22
    assert parts.joint_limits is not None and parts.entry.bundled and "CC BY-NC 4.0" in parts.entry.licence
    profile = CharacterProfile.load(PROFILES_DIR / "bandai_namco.json")
    assert parts.profile.height == profile.height and np.array_equal(parts.profile.mean_orientation, profile.mean_orientation)


def test_pretrained_is_a_model_that_hits_a_handle():
    """``bm.pretrained`` gives the model object: its curves pass through the handle exactly
    and its exact IK puts the hand there."""
    model = bm.pretrained("bandai_namco")
    assert isinstance(model, bm.Inbetweener) and model.character.name == "bandai_namco"
    clip = bm.read_bvh(bm.DEMO_CLIP)
    keys = model.poses(clip, [0, 30])
    handles = model.handles({"right_hand": (12, (0.0, 20.0, 0.0))}, relative_to=keys)
    result = model.inbetween(keys, handles, key=jax.random.key(0), options=bm.InbetweenOptions(steps=2))
    np.testing.assert_array_equal(result.joined_curves().ctrl_pos[2, 3], handles.position[0])  # the handle, exactly
    _, positions = pose_fk(model.character, result.pose)
    assert float(np.linalg.norm(np.asarray(positions)[12, model.character.characteristic[3]] - np.asarray(handles.position[0]))) < 0.05


def test_a_corrupted_copy_fails_its_checksum(tmp_path):
    root = tmp_path / "models"
    shutil.copytree(MODELS_DIR, root)
    assert model_folder("bandai_namco", "bmm", root=root) == root / "bmm_bandai_namco"  # the copy passes
    expected = read_manifest(root)["bmm_bandai_namco"]["sha256"]
    victim = max((p for p in (root / "bmm_bandai_namco").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0xFF
    victim.write_bytes(bytes(data))
    with pytest.raises(ChecksumError) as error:
        load_pretrained("bandai_namco", root=root)
    message = str(error.value)
    assert str(root / "bmm_bandai_namco") in message and expected in message
    assert folder_digest(root / "bmm_bandai_namco") in message and "checksum mismatch" in message
    # A missing file too, in the IK's folder.
    (root / "ik_bandai_namco" / "joint_limits.json").unlink()
    with pytest.raises(ChecksumError, match=r"ik_bandai_namco: checksum mismatch.*18 files .* expected, 17 of"):
        model_folder("bandai_namco", "ik", root=root)


def test_an_unknown_name_lists_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown pretrained model 'amass'; known: bandai_namco \(bundled\), lafan1"):
        bm.pretrained("amass")


def test_a_model_not_trained_here_names_its_command(tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    with pytest.raises(FileNotFoundError) as error:
        load_pretrained("lafan1")
    message = str(error.value)
    assert "not bundled" in message and "CC BY-NC-ND 4.0" in message and str(tmp_path / "cache" / "runs") in message
    assert "retrain with: python experiments/bmm_lafan1.py" in message and "python experiments/train_ik.py --corpus lafan1" in message


def test_the_commands_resolve_names_through_the_registry(tmp_path):
    assert resolve_bmm("bandai_namco") == (MODELS_DIR / "bmm_bandai_namco", "bandai_namco")
    assert resolve_ik_model("bandai_namco") == MODELS_DIR / "ik_bandai_namco"
    assert resolve_bmm(tmp_path) == (tmp_path, None)  # a folder stays a folder
    assert resolve_ik_model(str(tmp_path)) == tmp_path


def test_models_command_lists_the_bundled_entry_with_its_licence(capsys):
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("bandai_namco "))
    assert "bundled, checksum ok" in row and "MB" in row and "2.28 M" in row and "CC BY-NC 4.0" in row
    lafan1 = next(line for line in out.splitlines() if line.startswith("lafan1 "))
    assert "not bundled" in lafan1 and "CC BY-NC-ND 4.0" in lafan1
    assert "Bandai Namco Research Inc." in out and "python experiments/train_ik.py --corpus bandai_namco" in out
    assert main(["models", "--check"]) == 0
    assert "every bundled model matches" in capsys.readouterr().out


def test_inbetween_with_an_untrained_named_model_fails_with_the_command(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    code = main(["inbetween", str(bm.DEMO_CLIP), "--frames", "0", "30", "--model", "lafan1", "--out", str(tmp_path / "out.bvh")])
    assert code == 2
    err = capsys.readouterr().err
    assert err == (
        "bezmotion: error: --model lafan1: pretrained model 'lafan1' is not bundled (its data is CC BY-NC-ND 4.0) and its BMM "
        "is not trained here; bezmotion models lists the commands that train it\n"
    )
    assert not (tmp_path / "out.bvh").exists()
