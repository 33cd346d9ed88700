"""The optimiser (``bezmotion.training.optim``): AdamW with AMSGrad and decoupled weight
decay, against a NumPy transcription of ``torch.optim.AdamW(amsgrad=True)``.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import optax

from bezmotion.bmm.train import BMMTrainConfig
from bezmotion.training.optim import adamw_amsgrad_torch


def test_optimizer_is_adamw_with_amsgrad_and_decoupled_decay():
    config = BMMTrainConfig(learning_rate=0.1, weight_decay=0.5)
    opt = adamw_amsgrad_torch(config.learning_rate, config.weight_decay)
    params = {"w": jnp.asarray([1.0, -2.0, 3.0])}
    grads = {"w": jnp.asarray([0.5, -0.1, 0.0])}
    updates, _ = opt.update(grads, opt.init(params), params)
    # First Adam step: m̂/√v̂ = sign(g); the decay is added unscaled, then everything × −lr.
    np.testing.assert_allclose(updates["w"], -0.1 * (np.sign([0.5, -0.1, 0.0]) + 0.5 * np.array([1.0, -2.0, 3.0])), rtol=1e-5)
    # Many steps against a NumPy transcription of torch.optim.AdamW(amsgrad=True): decay
    # p ← p(1 − lr·wd), then the step with the max of the *raw* second moment, corrected after.
    lr, wd = 0.1, 0.5
    rng = np.random.default_rng(3)
    p = np.array([1.0, -2.0, 3.0])
    m, v, v_max = np.zeros(3), np.zeros(3), np.zeros(3)
    params, state = {"w": jnp.asarray(p, jnp.float32)}, opt.init(params)
    for t in range(1, 41):
        g = rng.normal(size=3) * (30.0 if t == 1 else 1.0)  # one large early gradient
        updates, state = opt.update({"w": jnp.asarray(g, jnp.float32)}, state, params)
        params = optax.apply_updates(params, updates)
        p = p * (1.0 - lr * wd)
        m, v = 0.9 * m + 0.1 * g, 0.999 * v + 0.001 * g * g
        v_max = np.maximum(v_max, v)
        p = p - lr * (m / (1 - 0.9**t)) / (np.sqrt(v_max / (1 - 0.999**t)) + 1e-8)
    np.testing.assert_allclose(np.asarray(params["w"]), p, rtol=1e-5, atol=1e-6)
