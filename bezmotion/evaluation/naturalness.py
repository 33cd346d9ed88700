"""Naturalness metrics on motion embeddings: FID, diversity and multimodality (BMM appendix B).

The three statistics the BMM paper's Table 1 reports beside the handles error, defined
as MDM (Tevet et al. 2022) computes them on HumanML3D features, here on the embeddings
of any feature extractor (ours: :mod:`bezmotion.evaluation.motion_features`):

- :func:`fid` — the Fréchet distance between Gaussian fits of two feature sets (eq. 5);
- :func:`diversity` — the mean distance between random pairs of one set's features (eq. 6);
- :func:`multimodality` — the mean distance between random pairs of samples generated
  for the same condition, averaged over conditions (eq. 7).

These are statistics of whole evaluation sets, computed once per table row, so they run
in NumPy float64 outside any ``jit``. Random pairs are drawn from a JAX ``key`` (no
global RNG). One difference from MDM's code, which draws the two subsets independently
(so a sample is sometimes paired with itself, distance 0): here both subsets come from
one permutation, so the pairs are always of distinct samples, as the paper's "the output
is split into two subsets" describes; the estimate is then unbiased for the mean
distance between distinct samples, and needs ``2 · num_pairs`` samples.

Inputs are annotated ``ArrayLike`` rather than with their shapes: any array a user hands
in is checked here, and a wrong shape or a NaN is a ``ValueError`` naming the argument.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np
from jaxtyping import Array, ArrayLike, Float


class GaussianFit(NamedTuple):
    """Mean and covariance of a feature set (float64).

    Attributes:
      mean: ``(dim,)``.
      cov: ``(dim, dim)`` the unbiased sample covariance (``ddof = 1``, as ``np.cov``).
      count: how many feature vectors were fitted.
    """

    mean: Float[np.ndarray, "dim"]
    cov: Float[np.ndarray, "dim dim"]
    count: int


def _checked(name: str, features: ArrayLike, ndim: int, layout: str) -> np.ndarray:
    """``features`` as float64 with ``ndim`` axes, all finite, or a ValueError naming it."""
    x = np.asarray(features, np.float64)
    if x.ndim != ndim:
        raise ValueError(f"{name} must be {layout}, got shape {x.shape}")
    if not np.isfinite(x).all():
        bad = np.argwhere(~np.isfinite(x))[0]
        raise ValueError(f"{name} holds a non-finite value ({x[tuple(bad)]}) at index {tuple(int(i) for i in bad)}")
    return x


def gaussian_fit(features: ArrayLike, *, name: str = "features") -> GaussianFit:
    """Mean and covariance of ``features`` (fit a reference set once, compare many against it).

    Args:
      features: ``(samples, dim)`` embeddings, ``samples ≥ 2``.
      name: how error messages call ``features``.
    Raises:
      ValueError: not 2-D, fewer than two samples, or a non-finite value (named).
    """
    x = _checked(name, features, 2, "(samples, dim)")
    if x.shape[0] < 2:
        raise ValueError(f"{name} needs at least 2 samples for a covariance, got shape {x.shape}")
    return GaussianFit(x.mean(axis=0), np.atleast_2d(np.cov(x, rowvar=False)), int(x.shape[0]))


def _psd_sqrt(cov: np.ndarray) -> np.ndarray:
    """Symmetric square root of a symmetric positive semi-definite matrix (eigenvalues
    rounded below zero by float error are taken as zero)."""
    values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    return (vectors * np.sqrt(np.clip(values, 0.0, None))) @ vectors.T


def frechet_distance(a: GaussianFit, b: GaussianFit) -> float:
    """The Fréchet distance of two Gaussian fits (BMM eq. 5):
    ``‖μa − μb‖² + tr(Σa + Σb − 2 (Σa Σb)^½)``.

    ``tr (Σa Σb)^½`` is computed without a general (complex, unstable) matrix square root:
    ``Σa Σb`` is similar to the symmetric PSD ``Σa^½ Σb Σa^½``, so the trace is the sum of
    the square roots of that matrix's eigenvalues. Exact for singular covariances (fewer
    samples than dimensions) too, where ``scipy.linalg.sqrtm`` needs an ε offset.

    Raises:
      ValueError: the fits' dimensions differ.
    """
    if a.mean.shape != b.mean.shape:
        raise ValueError(f"feature dimensions differ: {a.mean.shape[0]} vs {b.mean.shape[0]}")
    root_a = _psd_sqrt(a.cov)
    middle = root_a @ b.cov @ root_a
    eigen = np.linalg.eigvalsh(0.5 * (middle + middle.T))
    trace_sqrt = float(np.sum(np.sqrt(np.clip(eigen, 0.0, None))))
    diff = a.mean - b.mean
    value = float(diff @ diff + np.trace(a.cov) + np.trace(b.cov) - 2.0 * trace_sqrt)
    return max(value, 0.0)  # float error can leave −1e−12 for identical sets; a distance is ≥ 0


def fid(features_a: ArrayLike, features_b: ArrayLike) -> float:
    """Fréchet (Inception) distance between two sets of motion embeddings (BMM eq. 5).

    Symmetric in its arguments; 0 for identical sets. Pass the ground truth as either.

    Args:
      features_a, features_b: ``(samples, dim)`` embeddings of the same extractor, at
        least 2 samples each (for a stable estimate, many more samples than ``dim``).
    Returns:
      The distance, in squared embedding units.
    Raises:
      ValueError: a set not ``(samples, dim)`` with ``samples ≥ 2``, non-finite values
        (named with their index), or different ``dim``.
    """
    a = gaussian_fit(features_a, name="features_a")
    b = gaussian_fit(features_b, name="features_b")
    if a.mean.shape != b.mean.shape:
        raise ValueError(
            f"features_a and features_b must have the same dim, got {np.shape(features_a)} and {np.shape(features_b)}"
        )
    return frechet_distance(a, b)


def _check_pairs(num_pairs: int, available: int, what: str) -> None:
    if not isinstance(num_pairs, int | np.integer) or isinstance(num_pairs, bool) or num_pairs < 1:
        raise ValueError(f"num_pairs must be a positive integer, got {num_pairs!r}")
    if 2 * num_pairs > available:
        raise ValueError(f"num_pairs={num_pairs} needs at least {2 * num_pairs} {what}, got {available}")


def diversity(features: ArrayLike, num_pairs: int, *, key: Array) -> float:
    """Mean distance between ``num_pairs`` random pairs of distinct samples (BMM eq. 6).

    Two disjoint subsets ``{v_i}``, ``{v'_i}`` of ``num_pairs`` samples each (the paper:
    ``S_d = 1000``) are drawn from one permutation; the result is
    ``(1/S_d) Σ_i ‖v_i − v'_i‖₂``. Compare a model's value with the ground truth's (→).

    Args:
      features: ``(samples, dim)`` embeddings, ``samples ≥ 2 · num_pairs``.
      num_pairs: ``S_d``.
      key: PRNG key for the permutation.
    Returns:
      The mean distance, in embedding units.
    Raises:
      ValueError: bad shape, non-finite values (named) or too few samples.
    """
    x = _checked("features", features, 2, "(samples, dim)")
    _check_pairs(num_pairs, x.shape[0], "samples")
    order = np.asarray(jax.random.permutation(key, x.shape[0]))
    first, second = order[:num_pairs], order[num_pairs : 2 * num_pairs]
    return float(np.mean(np.linalg.norm(x[first] - x[second], axis=-1)))


def multimodality(features_per_condition: ArrayLike, num_pairs: int, *, key: Array) -> float:
    """Mean distance between random pairs of samples of the same condition (BMM eq. 7).

    For each condition ``c`` its samples are split at random into two disjoint subsets of
    ``num_pairs`` each (the paper: ``S_m = 20`` samples per condition, ``C = 100``
    conditions, two subsets of 10), and the result is the mean over conditions and pairs
    of ``‖v_{c,i} − v'_{c,i}‖₂``. Larger is better (↑): the model varies its output under
    fixed constraints. A deterministic method scores 0.

    Args:
      features_per_condition: ``(conditions, samples, dim)`` embeddings, ``samples`` of
        each condition, ``samples ≥ 2 · num_pairs``.
      num_pairs: pairs per condition (``S_m / 2``).
      key: PRNG key; each condition gets its own random permutation from it.
    Returns:
      The mean distance, in embedding units.
    Raises:
      ValueError: bad shape, non-finite values (named), no condition or too few samples.
    """
    x = _checked("features_per_condition", features_per_condition, 3, "(conditions, samples, dim)")
    if x.shape[0] < 1:
        raise ValueError(f"features_per_condition has no condition, shape {x.shape}")
    _check_pairs(num_pairs, x.shape[1], "samples per condition")
    order = np.argsort(np.asarray(jax.random.uniform(key, x.shape[:2])), axis=1)  # a random permutation per condition
    first = np.take_along_axis(x, order[:, :num_pairs, None], axis=1)
    second = np.take_along_axis(x, order[:, num_pairs : 2 * num_pairs, None], axis=1)
    return float(np.mean(np.linalg.norm(first - second, axis=-1)))


__all__ = ["GaussianFit", "diversity", "fid", "frechet_distance", "gaussian_fit", "multimodality"]
