"""Constants and helpers shared by the BMM test modules (``from bmm.common import …``):
the tiny denoiser configuration every test model uses, and the condition and constraint
helpers of the denoiser and sampling tests.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np

from bezmotion.bmm.denoiser import BMMConfig
from bezmotion.handles import Handles
from bezmotion.bmm.features import inbetween_conditions
from bezmotion.bmm.sampling import SampledCurves

K, J = 6, 6  # control points per 31-frame window at stride 6; characteristic joints
F = J * 12  # frame-token features
TINY = BMMConfig.cpu(width=32, ff_width=64, num_heads=2, num_layers=1, dropout=0.0)
RESIDUAL = dataclasses.replace(TINY, prediction="residual")


def some_conditions(rng: np.random.Generator, handles: int = 4, valid_handles: int = 2) -> Handles:
    """Start/end of all joints plus ``handles`` slots of which the first ``valid_handles`` are valid."""
    return inbetween_conditions(
        TINY.num_frames,
        jnp.asarray(rng.normal(size=(J, 3)), jnp.float32),
        jnp.asarray(rng.normal(size=(J, 3)), jnp.float32),
        Handles(
            frame=jnp.asarray(rng.integers(1, K - 1, handles) * TINY.stride, jnp.int32),
            joint=jnp.asarray(rng.integers(0, J, handles), jnp.int32),
            position=jnp.asarray(rng.normal(size=(handles, 3)), jnp.float32),
            valid=jnp.arange(handles) < valid_handles,
        ),
    )


def grid_errors(curves: SampledCurves, m: SimpleNamespace) -> np.ndarray:
    """All constraint residuals (start, end, valid handles) as one array."""
    pos = np.asarray(curves.ctrl_pos)
    res = [pos[:, 0] - np.asarray(m.start), pos[:, -1] - np.asarray(m.end)]
    h = m.handles
    for b in range(pos.shape[0]):
        for s in range(h.valid.shape[1]):
            if bool(h.valid[b, s]):
                res.append(pos[b, int(h.frame[b, s]) // TINY.stride, int(h.joint[b, s])] - np.asarray(h.position[b, s]))
    return np.concatenate([np.ravel(r) for r in res])
