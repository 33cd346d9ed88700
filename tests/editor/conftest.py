"""Fixtures of the editor's tests: the bundled clip and models, few DDIM steps.

Sessions are made per test (each test edits its own); the models once per module, so what
they compile serves every test of the module.
"""

from __future__ import annotations

import dataclasses

import pytest
from editor.common import counting, options

import bezmotion as bm
from bezmotion.editor import EditSession


@pytest.fixture(scope="module")
def clip():
    return bm.read_bvh(bm.DEMO_CLIP)  # 40 frames of Bandai-Namco at 30 fps


@pytest.fixture(scope="module")
def rig_model():
    """The bundled BMM with the analytic rig (cheap to compile), its IK counting its traces."""
    model = bm.pretrained("bandai_namco", ik="rig")
    return dataclasses.replace(model, ik_fn=counting(model.ik_fn))


@pytest.fixture
def session(clip, rig_model, tmp_path) -> EditSession:
    """A fresh session of the clip, keys at its frames 0 and 30, exports to ``tmp_path/out``."""
    return EditSession(clip, {"rig": rig_model}, tmp_path / "out", options=options())
