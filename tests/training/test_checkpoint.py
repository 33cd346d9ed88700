"""Loading a saved model reads and never writes: a wrong path leaves no folder behind,
and the bundled models' folders are not touched (they may sit in a read-only install)."""

from __future__ import annotations

import os

import jax.numpy as jnp
import pytest

from bezmotion.assets import BUNDLED_BMM, BUNDLED_IK
from bezmotion.bmm.sampling import load_model
from bezmotion.ik.protores import load_ik_model
from bezmotion.training.checkpoint import CheckpointStore


def _snapshot(folder):
    """Every path under ``folder`` with its size and modification time."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            path = os.path.join(root, name)
            st = os.stat(path)
            out[os.path.relpath(path, folder)] = (st.st_size, st.st_mtime_ns)
    return out


@pytest.mark.parametrize(("load", "what"), [(load_model, "BMM"), (load_ik_model, "learned IK")])
def test_loading_from_a_missing_path_creates_nothing(tmp_path, load, what):
    missing = tmp_path / "no" / "model"
    with pytest.raises(FileNotFoundError, match=rf"{missing}: not a saved {what} \(no such folder\)"):
        load(missing)
    assert list(tmp_path.iterdir()) == []


def test_a_read_only_store_needs_an_existing_folder_and_refuses_to_save(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such folder"):
        CheckpointStore(tmp_path / "absent", read_only=True)
    assert not (tmp_path / "absent").exists()
    store = CheckpointStore(tmp_path / "run")  # a writable store still creates its folder
    store.save(0, {"x": jnp.arange(3.0)}, {"a": 1})
    store.close()
    reader = CheckpointStore(tmp_path / "run", read_only=True)
    assert reader.latest_step() == 0 and reader.config() == {"a": 1}
    with pytest.raises(ValueError, match="opened read-only"):
        reader.save(1, {"x": jnp.arange(3.0)})
    reader.close()


def test_loading_the_bundled_models_leaves_their_folders_as_they_were():
    before = {p: _snapshot(p) for p in (BUNDLED_BMM, BUNDLED_IK)}
    load_model(BUNDLED_BMM)
    load_ik_model(BUNDLED_IK)
    assert {p: _snapshot(p) for p in (BUNDLED_BMM, BUNDLED_IK)} == before
