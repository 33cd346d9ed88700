"""Fixtures shared by the BMM test modules.

Runs without ../shared: the real data is the bundled ``DEMO_CLIP`` (40 Bandai-Namco
frames → 10 windows of 31 frames at offset 1). The expensive objects — the curve dataset
and the compiled sampler — are session-scoped, computed once for every module that uses
them; treat them as read-only.
"""

from __future__ import annotations

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bmm.common import J, TINY

from bezmotion.assets import DEMO_CLIP
from bezmotion.bmm.denoiser import init_denoiser
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, Handles, SampledCurves, sample_curves
from bezmotion.data.bvh import read_bvh
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import build_curve_dataset


@pytest.fixture(scope="session")
def demo_dataset():
    """The real fixture: DEMO_CLIP cut into the 10 windows of 31 frames at offset 1."""
    clips = MotionClips.from_bvh([read_bvh(DEMO_CLIP)])
    return build_curve_dataset(clips, "bandai_namco", window=31, offset=1, progress=False)


@pytest.fixture(scope="session")
def stats(demo_dataset) -> FeatureStats:
    """Per-(joint, feature) mean and floored std computed here in NumPy (float64)."""
    feats = np.concatenate([demo_dataset.ctrl_pos, demo_dataset.ctrl_tangent, demo_dataset.ctrl_rot6d], axis=-1)
    flat = feats.astype(np.float64).reshape(-1, J, 12)
    return FeatureStats(jnp.asarray(flat.mean(0), jnp.float32), jnp.asarray(np.maximum(flat.std(0), 1e-3), jnp.float32))


@pytest.fixture(scope="session")
def model(stats) -> BezierMotionModel:
    graphdef, params = init_denoiser(TINY, key=jax.random.key(11))
    return BezierMotionModel(params, stats, graphdef, TINY)


@pytest.fixture(scope="session")
def motions(demo_dataset) -> SimpleNamespace:
    """Two motions from the demo windows, moved away from the origin in XZ, with handles
    (the second motion has one padding slot)."""
    offset = np.array([150.0, 3.0, -230.0], np.float32)
    rows = [0, 7]
    pos = demo_dataset.ctrl_pos[rows] + offset
    handles = Handles(
        joint=jnp.asarray([[2, 4, 0], [1, 5, 3]], jnp.int32),
        frame=jnp.asarray([[6, 12, 24], [18, 12, 6]], jnp.int32),
        position=jnp.asarray(np.stack([pos[0, [1, 2, 4], [2, 4, 0]] + 5.0, pos[1, [3, 2, 1], [1, 5, 3]] - 7.0]), jnp.float32),
        valid=jnp.asarray([[True, True, True], [True, True, False]]),
    )
    return SimpleNamespace(start=jnp.asarray(pos[:, 0]), end=jnp.asarray(pos[:, -1]), handles=handles)


@pytest.fixture(scope="session")
def sampled(model, motions) -> SampledCurves:
    return sample_curves(model, motions.start, motions.end, motions.handles, key=jax.random.key(21), steps=5)
