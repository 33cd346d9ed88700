"""The BMM's losses (``bezmotion.bmm.losses``), checked against values worked out by hand.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from bmm.common import J, K

from bezmotion.bezier import BezierLayout, evaluate
from bezmotion.bmm.losses import LossWeights, bmm_loss_terms, dense_velocity, min_snr_weight
from bezmotion.data.characteristic import FEET, HIPS
from bezmotion.diffusion.schedule import cosine_schedule


def perfect_prediction(rng) -> dict:
    """Targets whose feet stand still exactly where they are in contact, and a prediction
    equal to them (contact logits ±1000, so the probabilities are exactly 0 or 1)."""
    layout = BezierLayout.from_controls(K, 6)
    pos = rng.normal(scale=30.0, size=(K, J, 3))
    tan = rng.normal(scale=5.0, size=(K, J, 3))
    left, right = FEET
    # Left foot planted over segments 0 and 1 (controls 0, 1), then moving.
    pos[:3, left] = pos[0, left]
    tan[:3, left] = 0.0
    # Right foot moving, then planted over segments 3 and 4 (controls 3, 4, and 5 which looks back).
    pos[3:, right] = pos[3, right]
    tan[3:, right] = 0.0
    contacts = np.zeros((K, 2), bool)
    contacts[:2, 0] = True
    contacts[3:, 1] = True
    rot = rng.normal(size=(K, J, 6))
    pos, tan, rot = (jnp.asarray(a, jnp.float32) for a in (pos, tan, rot))
    dense = jnp.moveaxis(evaluate(layout, jnp.moveaxis(pos, 1, 0), jnp.moveaxis(tan, 1, 0)), 0, 1)
    mask = jnp.zeros((K, J), bool).at[0].set(True).at[-1].set(True).at[2, 1].set(True).at[3, 4].set(True)
    contacts = jnp.asarray(contacts)
    return {
        "layout": layout, "pred_pos": pos, "pred_tangent": tan, "pred_rot6d": rot,
        "contact_logits": jnp.where(contacts, 1000.0, -1000.0), "target_pos": pos, "target_tangent": tan,
        "target_rot6d": rot, "target_contacts": contacts, "dense_target": dense, "condition_mask": mask,
    }  # fmt: skip


def terms_of(case: dict) -> dict[str, float]:
    return {k: float(v) for k, v in bmm_loss_terms(**case).items()}


def test_loss_terms_vanish_for_a_perfect_prediction(rng):
    case = perfect_prediction(rng)
    terms = terms_of(case)
    assert set(terms) == {"position", "tangent", "orientation", "velocity", "dense_position", "condition", "contact", "skate"}
    for name, value in terms.items():
        assert value < 1e-12, f"{name} = {value} for a perfect prediction"


def test_each_loss_term_responds_to_its_own_perturbation(rng):
    case = perfect_prediction(rng)
    num_cond = int(case["condition_mask"].sum())
    zero = lambda terms, names: all(terms[n] < 1e-12 for n in names)  # noqa: E731

    # Position of an unconditioned control point (hips, control 2): 10 cm = 0.1 m.
    t = terms_of({**case, "pred_pos": case["pred_pos"].at[2, HIPS, 0].add(10.0)})
    assert t["position"] == pytest.approx(0.01 / (K * J * 3), rel=1e-4)
    assert t["dense_position"] > 0 and t["velocity"] > 0
    assert zero(t, ["tangent", "orientation", "condition", "contact", "skate"])

    # Position of a conditioned one (joint 1 at control 2).
    t = terms_of({**case, "pred_pos": case["pred_pos"].at[2, 1, 0].add(10.0)})
    assert t["condition"] == pytest.approx(0.01 / (3 * num_cond), rel=1e-4)
    assert t["position"] == pytest.approx(0.01 / (K * J * 3), rel=1e-4)

    # Tangent.
    t = terms_of({**case, "pred_tangent": case["pred_tangent"].at[1, 2, 2].add(10.0)})
    assert t["tangent"] == pytest.approx(0.01 / (K * J * 3), rel=1e-4)
    assert t["dense_position"] > 0 and t["velocity"] > 0
    assert zero(t, ["position", "orientation", "condition", "contact"])

    # Orientation (unitless).
    t = terms_of({**case, "pred_rot6d": case["pred_rot6d"].at[4, 3, 5].add(0.5)})
    assert t["orientation"] == pytest.approx(0.25 / (K * J * 6), rel=1e-4)
    assert zero(t, ["position", "tangent", "velocity", "dense_position", "condition", "contact", "skate"])

    # Dense target: a jump at one frame.
    t = terms_of({**case, "dense_target": case["dense_target"].at[14, 0, 1].add(10.0)})
    assert t["dense_position"] == pytest.approx(0.01 / (31 * J * 3), rel=1e-4)
    assert t["velocity"] == pytest.approx(2 * 0.01 / (30 * J * 3), rel=1e-4)  # two velocities change
    assert zero(t, ["position", "tangent", "orientation", "condition", "contact", "skate"])

    # Contact where the foot is planted but predicted off: contact only, no skating.
    t = terms_of({**case, "contact_logits": case["contact_logits"].at[0, 0].set(-1000.0)})
    assert t["contact"] == pytest.approx(1.0 / (K * 2))
    assert zero(t, ["skate", "position", "velocity"])

    # Contact predicted where the left foot moves (control 3, frame 18 → 19): skating.
    t = terms_of({**case, "contact_logits": case["contact_logits"].at[3, 0].set(1000.0)})
    assert t["contact"] == pytest.approx(1.0 / (K * 2))
    p3, p4 = np.asarray(case["pred_pos"][3:5, FEET[0]], np.float64)
    t3, t4 = np.asarray(case["pred_tangent"][3:5, FEET[0]], np.float64)
    u = 1.0 / 6.0
    bez = (1 - u) ** 3 * p3 + 3 * (1 - u) ** 2 * u * (p3 + t3) + 3 * (1 - u) * u**2 * (p4 - t4) + u**3 * p4
    v = (bez - p3) / 100.0
    assert t["skate"] == pytest.approx(np.sum(v**2) / (K * 2 * 3), rel=1e-3)
    assert t["skate"] > 1e-6


def test_loss_weights_are_the_papers_table_5():
    w = LossWeights()
    assert dataclasses.asdict(w) == {
        "position": 1.0, "tangent": 5.0, "orientation": 1.0, "velocity": 10.0,
        "dense_position": 1.0, "condition": 5.0, "contact": 0.01, "skate": 10.0,
    }  # fmt: skip
    terms = {name: jnp.float32(i + 1) for i, name in enumerate(dataclasses.asdict(w))}
    expected = sum(getattr(w, name) * (i + 1) for i, name in enumerate(dataclasses.asdict(w)))
    assert float(w.total(terms)) == pytest.approx(expected)


def test_min_snr_weight_and_dense_velocity(rng):
    snr = jnp.asarray([0.01, 1.0, 5.0, 7.0, 1e6])
    np.testing.assert_allclose(min_snr_weight(snr, 5.0), [0.01, 1.0, 5.0, 5.0, 5.0])
    np.testing.assert_array_equal(min_snr_weight(snr, None), np.ones(5))
    schedule = cosine_schedule(1000)
    assert float(min_snr_weight(schedule.snr(jnp.int32(0)), 5.0)) == 5.0
    assert float(min_snr_weight(schedule.snr(jnp.int32(999)), 5.0)) < 1e-6
    pos = jnp.asarray(rng.normal(size=(2, 7, J, 3)), jnp.float32)
    vel = dense_velocity(pos)
    assert vel.shape == (2, 6, J, 3)
    np.testing.assert_allclose(vel[1, 3], pos[1, 4] - pos[1, 3], rtol=1e-6)
