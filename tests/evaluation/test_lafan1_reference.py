"""The library's LaFAN1 benchmark against an independent plain-NumPy reference.

``reference_lafan1`` re-implements the official protocol (REFERENCE.md §1) from the
written specification, sharing no code with ``bezmotion``; both must give the same
zero-velocity / interpolation baseline numbers on the LaFAN1 subset in
``../shared/data/lafan1`` (skipped when absent). The acceptance criterion is 1e-4; we
check 1e-6. LaFAN1: Ubisoft La Forge, CC BY-NC-ND 4.0 (Harvey et al., SIGGRAPH 2020);
subset numbers are not comparable to the published full-set numbers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import reference_lafan1 as ref
from helpers import SHARED_DATA

ZIP_PATH = SHARED_DATA / "lafan1" / "lafan1-subset.zip"
VARIANTS = ("official", "delta")
METHODS = ("zerov", "interp")
METRICS = ("l2q", "l2p", "npss")
LENGTHS = ("5", "15", "30", "45")
ATOL = 1e-6

requires_lafan1 = pytest.mark.skipif(not ZIP_PATH.exists(), reason=f"LaFAN1 subset not found at {ZIP_PATH}")


# ------------------------------------------------- self-checks of the reference (no data)


def _matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_reference_euler_is_rz_ry_rx():
    a, b, c = np.radians([30.0, -50.0, 70.0])
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rx = np.array([[1, 0, 0], [0, np.cos(c), -np.sin(c)], [0, np.sin(c), np.cos(c)]])
    text = (
        "HIERARCHY\r\nROOT Hips\r\n{\r\n\tOFFSET 0 0 0\r\n"
        "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation\r\n"
        "\tEnd Site\r\n\t{\r\n\t\tOFFSET 0 1 0\r\n\t}\r\n}\r\n"
        "MOTION\r\nFrames: 1\r\nFrame Time: 0.033333\r\n1 2 3 30 -50 70\r\n"
    )
    bvh = ref.read_bvh_text(text)
    assert bvh["names"] == ["Hips"]
    np.testing.assert_allclose(bvh["positions"][0, 0], [1, 2, 3])
    np.testing.assert_allclose(_matrix(bvh["rotations"][0, 0]), rz @ ry @ rx, atol=1e-14)


def test_reference_slerp_and_delta_fix():
    rng = np.random.default_rng(0)
    a = ref.q_normalize(rng.normal(size=(200, 4)))
    b = ref.q_normalize(rng.normal(size=(200, 4)))
    dot = np.sum(a * b, axis=-1)
    far = 1.0 - np.abs(dot) >= 0.01
    b_short = np.where((dot < 0)[:, None], -b, b)
    d = ref.q_mul(ref.q_inv(a), b_short)
    angle = 2 * np.arccos(np.clip(d[:, 0], -1, 1))
    axis = d[:, 1:] / np.linalg.norm(d[:, 1:], axis=-1, keepdims=True)
    expected = ref.q_mul(a, ref.q_axis_angle(axis, 0.3 * angle))
    np.testing.assert_allclose(ref.q_slerp(a, b, 0.3)[far], expected[far], atol=1e-12)
    # Δ variant: only signs change, and the sequence is continuous from the prepended frame.
    gq = ref.q_normalize(rng.normal(size=(3, 6, 2, 4)))
    last = ref.q_normalize(rng.normal(size=(3, 2, 4)))
    fixed = ref._delta_fix(gq, last)
    np.testing.assert_array_equal(np.abs(fixed), np.abs(gq))
    seq = np.concatenate([last[:, None], fixed], axis=1)
    assert (np.sum(seq[:, 1:] * seq[:, :-1], axis=-1) >= 0).all()


# ------------------------------------------------------ library vs reference (real data)


@pytest.fixture(scope="module")
def reference() -> dict:
    return {v: ref.reference_baselines(ZIP_PATH, variant=v) for v in VARIANTS}


@pytest.fixture(scope="module")
def library_bench():
    from bezmotion.evaluation.lafan1 import lafan1_benchmark

    return lafan1_benchmark(ZIP_PATH)


@pytest.mark.shared
@requires_lafan1
@pytest.mark.parametrize("variant", VARIANTS)
def test_library_baselines_match_reference(variant, reference, library_bench):
    from bezmotion.evaluation.lafan1 import evaluate_baselines

    got = evaluate_baselines(library_bench, variant=variant)
    want = reference[variant]
    assert want["n_windows"] == 376
    assert int(got["n_windows"]) == 376
    assert set(got) == set(want)
    mismatches = []
    for method in METHODS:
        assert set(got[method]) == set(METRICS)
        for metric in METRICS:
            assert set(got[method][metric]) == set(LENGTHS)
            for n in LENGTHS:
                g, w = float(got[method][metric][n]), want[method][metric][n]
                if not abs(g - w) <= ATOL:
                    mismatches.append(f"{method}.{metric}[{n}]: library {g!r} reference {w!r} diff {g - w:+.3e}")
    assert not mismatches, f"{variant}: " + "; ".join(mismatches)
