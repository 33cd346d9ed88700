"""Naturalness metrics (FID, diversity, multimodality) on hand-built sets with known
answers, and our motion feature extractor on the bundled real clip (no ../shared).

The clip is ``DEMO_CLIP``: 40 Bandai-Namco frames → 10 windows of 31 frames at offset 1.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from bezmotion.assets import DEMO_CLIP, PROFILES_DIR
from bezmotion.data.bvh import read_bvh
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import characteristic_windows
from bezmotion.evaluation.motion_features import (
    MotionFeatureConfig,
    MotionFeatureExtractor,
    MotionFeatureTrainConfig,
    WindowStats,
    canonical_windows,
    embed_canonical,
    init_motion_autoencoder,
    init_motion_feature_train_state,
    load_motion_features,
    make_motion_feature_train_step,
    motion_features,
    reconstruction_terms,
    save_motion_features,
)
from bezmotion.evaluation.naturalness import diversity, fid, frechet_distance, gaussian_fit, multimodality
from bezmotion.pipeline.transfer import CharacterProfile
from bezmotion.training import compile_train_step, run_training


def whitened(rng: np.random.Generator, n: int, dim: int) -> np.ndarray:
    """``(n, dim)`` samples with sample mean exactly 0 and sample covariance exactly I."""
    x = rng.normal(size=(n, dim))
    x -= x.mean(0)
    return x @ np.linalg.inv(np.linalg.cholesky(np.cov(x, rowvar=False))).T


# ----------------------------------------------------------------------------------- FID


def test_fid_of_identical_sets_is_zero(rng):
    x = rng.normal(size=(300, 12)) @ rng.normal(size=(12, 12))
    assert fid(x, x) == pytest.approx(0.0, abs=1e-8)
    assert fid(x, x[::-1].copy()) == pytest.approx(0.0, abs=1e-8)  # order does not matter


def test_fid_of_diagonal_gaussians_is_the_closed_form(rng):
    """Diagonal covariances: ‖μa − μb‖² + Σ (σa − σb)²."""
    mu_a, mu_b = rng.normal(size=6), rng.normal(size=6)
    sigma_a, sigma_b = rng.uniform(0.2, 3.0, 6), rng.uniform(0.2, 3.0, 6)
    a = mu_a + whitened(rng, 500, 6) * sigma_a
    b = mu_b + whitened(rng, 700, 6) * sigma_b
    expected = np.sum((mu_a - mu_b) ** 2) + np.sum((sigma_a - sigma_b) ** 2)
    assert fid(a, b) == pytest.approx(expected, rel=1e-9)
    # A pure shift of the mean: exactly the squared distance of the means.
    assert fid(a, a + 2.0) == pytest.approx(4.0 * 6, rel=1e-9)


def test_fid_is_symmetric_and_matches_scipy_sqrtm(rng):
    a = rng.normal(size=(400, 8)) @ rng.normal(size=(8, 8))
    b = rng.normal(size=(350, 8)) @ rng.normal(size=(8, 8)) + 0.5
    assert fid(a, b) == pytest.approx(fid(b, a), rel=1e-10)
    linalg = pytest.importorskip("scipy.linalg")
    fa, fb = gaussian_fit(a), gaussian_fit(b)
    covmean = np.real(linalg.sqrtm(fa.cov @ fb.cov))
    reference = np.sum((fa.mean - fb.mean) ** 2) + np.trace(fa.cov + fb.cov - 2 * covmean)
    assert fid(a, b) == pytest.approx(reference, rel=1e-8)


def test_fid_with_singular_covariances_is_finite_and_non_negative(rng):
    """Fewer samples than dimensions: rank-deficient fits, where sqrtm needs an ε offset."""
    a, b = rng.normal(size=(5, 20)), rng.normal(size=(6, 20))
    value = fid(a, b)
    assert np.isfinite(value) and value > 0
    assert frechet_distance(gaussian_fit(a), gaussian_fit(a)) == pytest.approx(0.0, abs=1e-8)


def test_fid_rejects_bad_input_naming_it(rng):
    a = rng.normal(size=(10, 4))
    bad = a.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"features_b holds a non-finite value \(nan\) at index \(3, 1\)"):
        fid(a, bad)
    with pytest.raises(ValueError, match=r"features_a must be \(samples, dim\), got shape \(10,\)"):
        fid(a[:, 0], a)
    with pytest.raises(ValueError, match=r"features_a needs at least 2 samples"):
        fid(a[:1], a)
    with pytest.raises(ValueError, match=r"same dim, got \(10, 4\) and \(10, 3\)"):
        fid(a, a[:, :3])


# ----------------------------------------------------------------- diversity, multimodality


def test_diversity_of_a_simplex_is_its_edge():
    """Every two distinct vertices of s·I are s√2 apart: any pairing gives s√2."""
    features = 3.0 * np.eye(10)
    for seed in range(3):
        assert diversity(features, 5, key=jax.random.key(seed)) == pytest.approx(3.0 * np.sqrt(2.0), rel=1e-12)


def test_diversity_pairs_are_distinct_samples():
    """Two points: the only pair of distinct samples is the pair itself (never a self-pair)."""
    assert diversity(np.asarray([[0.0, 0.0], [3.0, 4.0]]), 1, key=jax.random.key(0)) == pytest.approx(5.0)


def test_multimodality_is_the_mean_of_each_conditions_spread():
    scales = np.asarray([1.0, 2.0, 5.0])
    features = scales[:, None, None] * np.eye(8)[None]  # (3 conditions, 8 samples, 8)
    assert multimodality(features, 4, key=jax.random.key(1)) == pytest.approx(np.sqrt(2.0) * scales.mean(), rel=1e-12)
    # A deterministic method (one output per condition, whatever the noise) scores 0.
    same = np.repeat(np.arange(12.0).reshape(3, 1, 4), 6, axis=1)
    assert multimodality(same, 3, key=jax.random.key(2)) == 0.0


def test_diversity_and_multimodality_reject_bad_input():
    key = jax.random.key(0)
    with pytest.raises(ValueError, match=r"num_pairs=3 needs at least 6 samples, got 5"):
        diversity(np.eye(5), 3, key=key)
    with pytest.raises(ValueError, match=r"num_pairs must be a positive integer, got 0"):
        diversity(np.eye(5), 0, key=key)
    with pytest.raises(ValueError, match=r"features_per_condition must be \(conditions, samples, dim\), got shape \(5, 5\)"):
        multimodality(np.eye(5), 2, key=key)
    with pytest.raises(ValueError, match=r"needs at least 4 samples per condition, got 3"):
        multimodality(np.zeros((2, 3, 4)), 2, key=key)
    bad = np.zeros((2, 4, 3))
    bad[1, 2, 0] = np.inf
    with pytest.raises(ValueError, match=r"features_per_condition holds a non-finite value \(inf\) at index \(1, 2, 0\)"):
        multimodality(bad, 2, key=key)


# ------------------------------------------------------------------- the feature extractor

HEIGHT = CharacterProfile.load(PROFILES_DIR / "bandai_namco.json").height


@pytest.fixture(scope="module")
def demo_windows() -> np.ndarray:
    """``(10, 31, 6, 3)`` aligned six-joint windows of the bundled clip (cm)."""
    clips = MotionClips.from_bvh([read_bvh(DEMO_CLIP)])
    return characteristic_windows(clips, "bandai_namco", window=31, offset=1)[0]


@pytest.fixture(scope="module")
def tiny_extractor(demo_windows) -> MotionFeatureExtractor:
    config = MotionFeatureConfig.tiny()
    graphdef, params = init_motion_autoencoder(config, key=jax.random.key(3))
    stats = WindowStats.from_windows(canonical_windows(jnp.asarray(demo_windows), HEIGHT))
    return MotionFeatureExtractor(params, stats, graphdef, config)


def yaw_and_move(pos: np.ndarray, angle: float, shift: np.ndarray) -> np.ndarray:
    """Rotate windows about +Y by ``angle`` (radians) through the origin, then translate."""
    c, s = np.cos(angle), np.sin(angle)
    rot = np.asarray([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], np.float32)
    return (pos @ rot.T + shift).astype(np.float32)


def test_canonical_windows_start_at_the_hips_facing_plus_z(demo_windows):
    canonical = np.asarray(canonical_windows(jnp.asarray(demo_windows), HEIGHT))
    assert canonical.shape == demo_windows.shape
    np.testing.assert_allclose(canonical[:, 0, 0], 0.0, atol=1e-6)  # the hips' own start
    # The clip walks forward: the hips advance along +Z, a few tenths of a hip height a second.
    assert (canonical[:, -1, 0, 2] > 0.2).all() and (np.abs(canonical[:, -1, 0, 0]) < 0.2).all()
    # Left hand and foot on +X (forward = left × up).
    assert (canonical[:, 0, 2, 0] > canonical[:, 0, 3, 0]).all() and (canonical[:, 0, 4, 0] > canonical[:, 0, 5, 0]).all()
    # The head is above the hips by about 0.6 hip heights: lengths are in hip heights.
    assert np.all((canonical[:, :, 1, 1] > 0.4) & (canonical[:, :, 1, 1] < 0.8))


@pytest.mark.parametrize("angle", [0.7, -2.4, np.pi])
def test_features_are_yaw_translation_and_scale_invariant(demo_windows, tiny_extractor, angle):
    moved = yaw_and_move(demo_windows, angle, np.asarray([130.0, 4.0, -75.0], np.float32))
    reference = canonical_windows(jnp.asarray(demo_windows), HEIGHT)
    np.testing.assert_allclose(canonical_windows(jnp.asarray(moved), HEIGHT), reference, atol=2e-5)
    # A character 1.5 times as tall doing the same: same canonical window.
    np.testing.assert_allclose(canonical_windows(jnp.asarray(1.5 * demo_windows), 1.5 * HEIGHT), reference, atol=2e-5)
    original = motion_features(tiny_extractor, demo_windows, HEIGHT, chunk=4)
    np.testing.assert_allclose(motion_features(tiny_extractor, moved, HEIGHT, chunk=4), original, atol=1e-4)


def test_motion_features_shape_and_chunking(demo_windows, tiny_extractor):
    features = motion_features(tiny_extractor, demo_windows, HEIGHT, chunk=4)  # 10 windows: chunks of 4, 4, 2 (padded)
    assert features.shape == (10, tiny_extractor.config.embed_dim) and features.dtype == np.float32
    whole = embed_canonical(tiny_extractor, canonical_windows(jnp.asarray(demo_windows), HEIGHT))
    np.testing.assert_allclose(features, whole, atol=1e-5)
    # Batch-polymorphic: any leading axes.
    canonical = canonical_windows(jnp.asarray(demo_windows.reshape(2, 5, 31, 6, 3)), HEIGHT)
    np.testing.assert_allclose(embed_canonical(tiny_extractor, canonical).reshape(10, -1), whole, atol=1e-5)


def test_motion_features_rejects_bad_input(demo_windows, tiny_extractor):
    with pytest.raises(ValueError, match=r"pos_cm must be \(windows, 31, 6, 3\), got shape \(10, 30, 6, 3\)"):
        motion_features(tiny_extractor, demo_windows[:, :30], HEIGHT)
    bad = demo_windows.copy()
    bad[2, 5, 1, 0] = np.nan
    with pytest.raises(ValueError, match=r"pos_cm holds a non-finite value \(nan\) at index \(2, 5, 1, 0\)"):
        motion_features(tiny_extractor, bad, HEIGHT)
    with pytest.raises(ValueError, match=r"hip_height_cm must be positive, got 0.0"):
        motion_features(tiny_extractor, demo_windows, 0.0)
    with pytest.raises(ValueError, match=r"MotionFeatureConfig.embed_dim must be a positive integer, got 0"):
        MotionFeatureConfig(embed_dim=0)


def test_a_few_training_steps_lower_the_loss_and_the_model_round_trips(demo_windows, tmp_path):
    canonical = canonical_windows(jnp.asarray(demo_windows), HEIGHT)
    stats = WindowStats.from_windows(canonical)
    model_config = MotionFeatureConfig.tiny()
    train_config = MotionFeatureTrainConfig(num_steps=40, batch_size=10, learning_rate=5e-3, warmup_steps=5)
    graphdef, state = init_motion_feature_train_state(model_config, train_config, key=jax.random.key(0))

    def loss(params) -> float:  # the whole (10-window) set, deterministic
        recon = jax.vmap(nnx.merge(graphdef, params))(stats.to_vector(canonical))
        terms = reconstruction_terms(stats, recon, canonical)
        return float(terms["pos"] + terms["vel"])

    before = loss(state.params)
    step = compile_train_step(make_motion_feature_train_step(graphdef, stats, train_config), num_seeds=None)
    state, history = run_training(step, state, canonical, num_steps=40, progress=False, log_every=10)
    after = loss(state.params)
    assert after < 0.5 * before, (before, after, history)

    extractor = MotionFeatureExtractor(state.params, stats, graphdef, model_config)
    save_motion_features(tmp_path / "features", extractor, corpora=["demo"])
    loaded = load_motion_features(tmp_path / "features")
    assert loaded.config == model_config
    np.testing.assert_array_equal(
        motion_features(loaded, demo_windows, HEIGHT), motion_features(extractor, demo_windows, HEIGHT)
    )
    with pytest.raises(FileNotFoundError, match="not a saved motion feature extractor"):
        load_motion_features(tmp_path / "missing")
