"""Training on windows of many lengths (``BMMTrainConfig(spans=…)``): one compiled step whose
examples each draw their own length, padded to the longest. What a padded window computes on
its own frames and control points must be what the same window computes unpadded — the
layout, the fit, the reference curves, the denoiser and the losses — so the model learns on
exactly what sampling at that length will ask of it."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bmm.common import J, RESIDUAL

from bezmotion.assets import DEMO_CLIP
from bezmotion.bezier import BezierLayout, PaddedLayout, evaluate, fit_curves, fit_operator
from bezmotion.bmm.denoiser import init_denoiser
from bezmotion.bmm.features import draw_intermediate_slots, inbetween_conditions, normalize_conditions, predict_x0
from bezmotion.bmm.losses import bmm_loss_terms
from bezmotion.bmm.train import (
    BMMTrainConfig,
    DenseWindows,
    init_bmm_train_state,
    make_bmm_example_loss,
    make_bmm_train_step,
    make_training_window,
    span_fit_operators,
)
from bezmotion.data.bvh import read_bvh
from bezmotion.data.corpus import MotionClips
from bezmotion.handles import Handles, grid_conditions
from bezmotion.training import compile_train_step

MAX_SPAN = 24
SPANS = (6, 7, 12, 13, 17, 24)  # whole strides and shorter last segments, down to one segment


@pytest.fixture(scope="module")
def windows() -> DenseWindows:
    """The real fixture: DEMO_CLIP cut into windows of MAX_SPAN + 1 frames."""
    clips = MotionClips.from_bvh([read_bvh(DEMO_CLIP)])
    return DenseWindows.from_clips(clips, "bandai_namco", frames=MAX_SPAN + 1, offset=3)


def padded(span: int) -> PaddedLayout:
    return PaddedLayout(jnp.asarray(span + 1, jnp.int32), 6, MAX_SPAN + 1)


@pytest.mark.parametrize("span", SPANS)
def test_a_padded_layout_evaluates_its_window_as_the_window_own_layout(span):
    own, pad = BezierLayout(span + 1), padded(span)
    k = own.num_controls
    np.testing.assert_array_equal(np.asarray(pad.control_frames)[:k], own.control_frames)
    assert int(pad.last_control) == k - 1 and int(np.sum(pad.control_valid)) == k and int(np.sum(pad.frame_valid)) == span + 1
    assert (np.diff(np.asarray(pad.control_frames)) > 0).all()  # the padding continues the grid
    rng = np.random.default_rng(span)
    pos, tangent = (jnp.asarray(rng.normal(size=(pad.num_controls, 3)) * 50, jnp.float32) for _ in range(2))
    want = evaluate(own, pos[:k], tangent[:k])
    got = jax.jit(lambda n: evaluate(PaddedLayout(n, 6, MAX_SPAN + 1), pos, tangent))(jnp.asarray(span + 1))
    np.testing.assert_allclose(np.asarray(got)[: span + 1], np.asarray(want), atol=1e-4)


@pytest.mark.parametrize("frames", (7, 8, 14, 25, 31))
def test_the_fit_operator_is_the_fit_on_real_motion(windows, frames):
    points = windows.dense_pos[:4, :frames] if frames <= MAX_SPAN + 1 else None
    if points is None:
        clips = MotionClips.from_bvh([read_bvh(DEMO_CLIP)])
        points = DenseWindows.from_clips(clips, "bandai_namco", frames=frames, offset=5).dense_pos[:4]
    layout = BezierLayout(frames)
    fit = fit_curves(layout, jnp.moveaxis(points, 2, 1))  # (windows, joints, frames, 3)
    tangent = np.einsum("kf,wfjd->wjkd", fit_operator(layout), np.asarray(points, np.float64))
    assert np.abs(tangent - np.asarray(fit.ctrl_tangent)).max() < 1e-3  # cm


def test_slots_are_drawn_inside_the_window_only():
    for seed in range(20):
        for last in (1, 2, 3):
            control, _, valid = draw_intermediate_slots(jax.random.key(seed), 5, J, 4, last_control=jnp.asarray(last))
            assert (np.asarray(control)[np.asarray(valid)] < last).all()
            assert int(np.sum(valid)) <= (last - 1) * J  # one segment: no intermediate control point


@pytest.mark.parametrize("span", (7, 13, 24))
def test_padding_changes_nothing_the_window_predicts_or_is_scored_on(windows, stats, span):
    """The residual model's x̂₀ (reference curves through keys and off-grid handles, masked
    attention) and every loss term: padded as in training, and as the window alone."""
    own, pad = BezierLayout(span + 1), padded(span)
    k = own.num_controls
    graphdef, params = init_denoiser(RESIDUAL, key=jax.random.key(1))
    denoiser = __import__("flax").nnx.merge(graphdef, params)
    dense = windows.dense_pos[2]
    ops = span_fit_operators(6, 6, MAX_SPAN)[span - 6]
    tangent = jnp.einsum("kf,fjd->kjd", ops, dense)
    pos = dense[jnp.minimum(pad.control_frames, MAX_SPAN)]
    handles = Handles(jnp.asarray([1, 4], jnp.int32), jnp.asarray([3, span - 2], jnp.int32), dense[jnp.asarray([3, span - 2]), jnp.asarray([1, 4])] + 2.0, jnp.ones(2, bool))
    rng = np.random.default_rng(0)
    x_t = jnp.asarray(rng.normal(size=(pad.num_controls, RESIDUAL.frame_features)), jnp.float32)

    def run(layout, controls, frames):
        conditions = normalize_conditions(stats, inbetween_conditions(layout.num_frames, dense[0], dense[span], handles))
        x0, logits = predict_x0(denoiser, stats, x_t[:controls], jnp.asarray(500), conditions, layout=layout)
        mask, _ = grid_conditions(layout, conditions, J)
        feats = x0.reshape(controls, J, 12) * stats.std + stats.mean
        terms = bmm_loss_terms(
            layout, feats[..., :3], feats[..., 3:6], feats[..., 6:], logits, pos[:controls], tangent[:controls],
            jnp.zeros((controls, J, 6)) + 0.1, jnp.zeros((controls, 2), bool), dense[:frames], mask,
        )  # fmt: skip
        return x0, logits, terms

    x0_own, logits_own, terms_own = run(own, k, span + 1)
    x0_pad, logits_pad, terms_pad = jax.jit(lambda n: run(PaddedLayout(n, 6, MAX_SPAN + 1), pad.num_controls, MAX_SPAN + 1))(jnp.asarray(span + 1))
    np.testing.assert_allclose(np.asarray(x0_pad)[:k], np.asarray(x0_own), atol=2e-4)
    np.testing.assert_allclose(np.asarray(logits_pad)[:k], np.asarray(logits_own), atol=2e-4)
    for name in terms_own:
        np.testing.assert_allclose(float(terms_pad[name]), float(terms_own[name]), rtol=2e-4, err_msg=name)


def test_frames_past_the_drawn_window_change_nothing(windows, stats):
    """An example is the first ``span + 1`` frames of its window: whatever the frames after
    them hold (here moved 3 m, turned and with their contacts flipped), its loss is the same,
    end key condition and all."""
    train = BMMTrainConfig(spans=(6, MAX_SPAN), off_grid_handles=0.5)
    graphdef, params = init_denoiser(RESIDUAL, key=jax.random.key(2))
    example_loss = jax.jit(make_bmm_example_loss(graphdef, RESIDUAL, train, stats))
    window = make_training_window(RESIDUAL, train)
    item = tuple(a[1] for a in windows)
    spans = set()
    for seed in range(12):
        rng = jax.random.key(seed)
        span = int(window(item, rng)[1].num_frames) - 1
        spans.add(span)
        after = (jnp.arange(MAX_SPAN + 1) > span)[:, None, None]
        moved = (item[0] + jnp.where(after, 300.0, 0.0), jnp.where(after, item[1][..., ::-1], item[1]), jnp.where(after[..., 0], ~item[2], item[2]))
        (loss, terms), (loss_moved, terms_moved) = example_loss(params, item, rng), example_loss(params, moved, rng)
        np.testing.assert_allclose(float(loss_moved), float(loss), rtol=1e-5, err_msg=f"span {span}")
    assert len(spans) > 4  # the lengths drawn vary


def test_a_step_on_many_lengths_trains(windows, stats):
    train = BMMTrainConfig(batch_size=8, learning_rate=1e-3, spans=(6, MAX_SPAN), off_grid_handles=0.5, still_augmentation=0.2)
    graphdef, state = init_bmm_train_state(RESIDUAL, train, key=jax.random.key(0))
    step = compile_train_step(make_bmm_train_step(graphdef, RESIDUAL, train, stats), num_seeds=None)
    losses = []
    for _ in range(12):
        state, metrics = step(state, windows)
        losses.append(float(metrics["loss"]))
    assert np.isfinite(losses).all() and np.mean(losses[-4:]) < np.mean(losses[:4])
    short = dataclasses.replace(train, spans=(6, MAX_SPAN - 1))
    with pytest.raises(ValueError, match=f"{MAX_SPAN} frames"):
        make_bmm_train_step(graphdef, RESIDUAL, short, stats)(state, windows)


@pytest.mark.parametrize("spans", [(1, 10), (10, 9), (6, 901)])
def test_spans_are_checked(spans):
    with pytest.raises(ValueError, match="spans"):
        BMMTrainConfig(spans=spans)


def test_the_native_span_fraction_draws_the_models_own_window(windows):
    """``native_span_fraction``: that share of examples has the model's own window (the tiny
    config's 30 frames: 31 > MAX_SPAN, so a config of 19 frames here); 0 draws as before."""
    config = dataclasses.replace(RESIDUAL, num_controls=4)  # 19 frames
    item = tuple(a[1] for a in windows)

    def drawn(fraction):
        window = make_training_window(config, BMMTrainConfig(spans=(6, MAX_SPAN), native_span_fraction=fraction))
        return [int(window(item, jax.random.key(seed))[1].num_frames) - 1 for seed in range(40)]

    plain, always, half = drawn(0.0), drawn(1.0), drawn(0.5)
    assert always == [18] * 40 and 5 < half.count(18) < 35 and plain.count(18) < 8
    assert [s for s, h in zip(plain, half) if h != 18] == [h for h in half if h != 18]  # the other draws unchanged
    with pytest.raises(ValueError, match="draws the model's own span, 18 frames, outside spans"):
        make_training_window(config, BMMTrainConfig(spans=(20, MAX_SPAN), native_span_fraction=0.5))
    with pytest.raises(ValueError, match="give spans too"):
        BMMTrainConfig(native_span_fraction=0.5)
