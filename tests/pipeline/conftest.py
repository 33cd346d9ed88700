"""Fixtures shared by the pipeline test modules.

The BMM is tiny and untrained (width 32, one layer): these tests check plumbing, not motion
quality. Compiling dominates the time, so one compiled in-betweening serves most tests; the
fixtures are session-scoped (computed once for every module) and read-only.
"""

from __future__ import annotations

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ik.demo_poses import clip, fk, frame  # noqa: F401  (clip: a fixture, shared with tests/ik)
from pipeline.common import FRAMES, LEFT_HAND, STEPS, STRIDE, TINY, hips_only_ik, identity_quats, model_of, two_keys

from bezmotion.bmm.denoiser import init_denoiser
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, Handles
from bezmotion.data.characteristic import HIPS
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import build_curve_dataset
from bezmotion.pipeline import InbetweenOptions, inbetween


@pytest.fixture(scope="session")
def curves(clip) -> SimpleNamespace:
    """The clip as a curve dataset: 31-frame windows at offset 5 (2 windows)."""
    clips = MotionClips.from_bvh([clip.motion])
    dataset = build_curve_dataset(clips, "bandai_namco", window=FRAMES, stride=STRIDE, offset=5, progress=False)
    return SimpleNamespace(clips=clips, dataset=dataset)


@pytest.fixture(scope="session")
def bmm(curves) -> BezierMotionModel:
    """Untrained tiny BMM; feature statistics computed here in NumPy from the clip's curves."""
    ds = curves.dataset
    feats = np.concatenate([ds.ctrl_pos, ds.ctrl_tangent, ds.ctrl_rot6d], axis=-1).astype(np.float64).reshape(-1, 6, 12)
    stats = FeatureStats(jnp.asarray(feats.mean(0), jnp.float32), jnp.asarray(np.maximum(feats.std(0), 1e-3), jnp.float32))
    graphdef, params = init_denoiser(TINY, key=jax.random.key(3))
    return BezierMotionModel(params, stats, graphdef, TINY)


@pytest.fixture(scope="session")
def run(clip, bmm) -> SimpleNamespace:
    """One in-betweening of frames 0–30 with the hips-only IK (all other joints at identity):
    a hips handle 11 cm off the mocap at frame 12, a left-hand handle at frame 18, and a
    padding slot sitting on the hips handle's place with a NaN position."""
    character = clip.character
    ik = hips_only_ik(character)
    rest = identity_quats(character.num_joints)
    start, end = frame(clip.pose, 0), frame(clip.pose, FRAMES - 1)
    _, pos = fk(character, clip.pose)
    idx = np.asarray(character.characteristic)
    hips_target = np.asarray(pos[12, idx[HIPS]]) + np.array([6.0, 5.0, -8.0])
    hand_target = np.asarray(pos[18, idx[LEFT_HAND]]) + np.array([0.0, 20.0, 0.0])
    handles = Handles(
        joint=jnp.asarray([HIPS, LEFT_HAND, HIPS], jnp.int32),
        frame=jnp.asarray([12, 18, 12], jnp.int32),
        position=jnp.asarray(np.stack([hips_target, hand_target, np.full(3, np.nan)]), jnp.float32),
        valid=jnp.asarray([True, True, False]),
    )
    key = jax.random.key(7)
    model = model_of(bmm, ik, rest, character)
    keys = two_keys(start, end)
    result = inbetween(model, keys, handles, key=key, options=InbetweenOptions(steps=STEPS, key_blend_frames=0))  # the IK's own frames
    return SimpleNamespace(
        character=character, ik=ik, rest=rest, start=start, end=end, keys=keys, model=model, handles=handles, result=result, key=key
    )
