"""Training the Bézier Motion Model: explicit state, one jitted step, several seeds at once.

``train_step(state, data) -> (state, metrics)`` is pure: it draws its batch (window
indices, timesteps, noise, conditions, dropout) from ``state.key``, so a run is fully
determined by its seed and resumes bit-identically from any checkpoint. Several seeds
train together by ``jax.vmap`` over a stacked state; with more than one local device
the batch is sharded over them (``jax.sharding``) and XLA all-reduces the gradients.

Paper settings (Table 4, §5.2): AdamW with AMSGrad, lr 1e-4, weight decay 1e-2, batch 64,
cosine schedule with T = 1000, conditions = both end control points of all joints plus
0–4 intermediate handles, Min-SNR-γ weighting (γ = 5), condition dropout 0.1 for
classifier-free guidance.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import threading
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxtyping import Array, Bool, Float, Int
from tqdm.auto import tqdm

from bezmotion.bezier import BezierLayout
from bezmotion.checkpoint import CheckpointStore
from bezmotion.data.curves import CurveDataset
from bezmotion.diffusion.schedule import DiffusionSchedule, cosine_schedule
from bezmotion.losses import LossWeights, bmm_loss_terms, min_snr_weight
from bezmotion.models.bmm import BMMConfig, init_denoiser
from bezmotion.models.bmm_data import (
    MAX_INTERMEDIATE_HANDLES,
    FeatureStats,
    control_features,
    from_tokens,
    draw_intermediate_slots,
    inbetween_conditions,
    normalize_conditions,
    predict_x0,
    split_features,
    to_tokens,
)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (defaults: the paper's)."""

    batch_size: int = 64
    learning_rate: float = 1e-4
    weight_decay: float = 1e-2
    ema_decay: float = 0.999
    condition_dropout: float = 0.1
    min_snr_gamma: float | None = 5.0
    max_intermediate_handles: int = MAX_INTERMEDIATE_HANDLES
    weights: LossWeights = LossWeights()

    def __post_init__(self):
        if self.batch_size < 1 or self.learning_rate <= 0 or self.weight_decay < 0:
            raise ValueError(f"invalid TrainConfig: {self}")
        if not 0.0 <= self.condition_dropout < 1.0 or not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"condition_dropout and ema_decay must be in [0, 1), got {self}")


class CurveArrays(NamedTuple):
    """A curve dataset as device arrays, the ``data`` argument of the step."""

    ctrl_pos: Float[Array, "windows controls joints 3"]
    ctrl_tangent: Float[Array, "windows controls joints 3"]
    ctrl_rot6d: Float[Array, "windows controls joints 6"]
    ctrl_contacts: Bool[Array, "windows controls 2"]
    dense_pos: Float[Array, "windows frames joints 3"]

    @classmethod
    def from_dataset(cls, dataset: CurveDataset) -> CurveArrays:
        return cls(*(jnp.asarray(getattr(dataset, f)) for f in cls._fields))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class TrainState:
    """Everything that changes during training (one seed; stacked on axis 0 for several).

    Attributes:
      params, ema: model parameters and their exponential moving average.
      opt_state: optimiser state.
      step: number of steps taken.
      key: PRNG key for the next step.
    """

    params: Any
    opt_state: Any
    ema: Any
    step: Int[Array, "*seeds"]
    key: Array


class AmsgradState(NamedTuple):
    count: Int[Array, ""]
    mu: Any
    nu: Any
    nu_max: Any


def scale_by_amsgrad_torch(b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8) -> optax.GradientTransformation:
    """Adam with AMSGrad exactly as PyTorch computes it (the paper trained with PyTorch).

    PyTorch keeps the running maximum of the *raw* second moment and bias-corrects it
    afterwards: ``m̂ / (√(max_s ν_s / (1 − β₂ᵗ)) + ε)``. ``optax.scale_by_amsgrad`` takes the
    maximum of the already corrected moment instead, so one large early gradient — when
    the correction multiplies ν by up to 1/(1 − β₂) — damps that parameter for good.
    """

    def init(params):
        zeros = lambda: jax.tree.map(jnp.zeros_like, params)  # noqa: E731
        return AmsgradState(jnp.zeros((), jnp.int32), zeros(), zeros(), zeros())

    def update(grads, state, params=None):
        del params
        count = state.count + 1
        mu = jax.tree.map(lambda m, g: b1 * m + (1.0 - b1) * g, state.mu, grads)
        nu = jax.tree.map(lambda v, g: b2 * v + (1.0 - b2) * g * g, state.nu, grads)
        nu_max = jax.tree.map(jnp.maximum, state.nu_max, nu)
        c1 = 1.0 - b1 ** count.astype(jnp.float32)
        c2 = 1.0 - b2 ** count.astype(jnp.float32)
        updates = jax.tree.map(lambda m, v: (m / c1) / (jnp.sqrt(v / c2) + eps), mu, nu_max)
        return updates, AmsgradState(count, mu, nu, nu_max)

    return optax.GradientTransformation(init, update)


def make_optimizer(config: TrainConfig) -> optax.GradientTransformation:
    """AdamW with AMSGrad as PyTorch's ``AdamW(amsgrad=True)``: decoupled weight decay
    ``lr·wd·θ`` added to the AMSGrad direction, then scaled by the learning rate."""
    return optax.chain(
        scale_by_amsgrad_torch(),
        optax.add_decayed_weights(config.weight_decay),
        optax.scale_by_learning_rate(config.learning_rate),
    )


def fresh_train_state(
    init_model: Callable[[Array], tuple[nnx.GraphDef, nnx.State]],
    optimizer: optax.GradientTransformation,
    *,
    key: Array,
    ema: bool,
) -> tuple[nnx.GraphDef, TrainState]:
    """Fresh parameters (``init_model(key)``), optimiser state and step 0 for one seed;
    ``ema`` starts as a copy of the parameters, or is ``None`` for models that keep none."""
    init_key, state_key = jax.random.split(key)
    graphdef, params = init_model(init_key)
    return graphdef, TrainState(params, optimizer.init(params), params if ema else None, jnp.zeros((), jnp.int32), state_key)


def init_train_state(
    model_config: BMMConfig, train_config: TrainConfig, *, key: Array
) -> tuple[nnx.GraphDef, TrainState]:
    """Fresh parameters and optimiser state for one seed."""
    init = lambda k: init_denoiser(model_config, key=k)  # noqa: E731
    return fresh_train_state(init, make_optimizer(train_config), key=key, ema=True)


def init_train_states(
    model_config: BMMConfig, train_config: TrainConfig, seeds: list[int] | tuple[int, ...]
) -> tuple[nnx.GraphDef, TrainState]:
    """States for several seeds, stacked on a leading axis (for the vmapped step)."""
    return stack_seeds(lambda key: init_train_state(model_config, train_config, key=key), seeds)


def stack_seeds(
    init_one: Callable[[Array], tuple[nnx.GraphDef, TrainState]], seeds: list[int] | tuple[int, ...]
) -> tuple[nnx.GraphDef, TrainState]:
    """``init_one(key)`` for every seed, states stacked on a leading axis (any model)."""
    if not seeds:
        raise ValueError("need at least one seed")
    states = [init_one(jax.random.key(s)) for s in seeds]
    return states[0][0], jax.tree.map(lambda *xs: jnp.stack(xs), *(s for _, s in states))


def _sharded(x: Array, mesh: Mesh | None) -> Array:
    """Split the batch axis over the mesh's devices (no-op on one device)."""
    if mesh is None:
        return x
    return jax.lax.with_sharding_constraint(x, NamedSharding(mesh, PartitionSpec("data")))


def make_train_step(
    graphdef: nnx.GraphDef,
    model_config: BMMConfig,
    train_config: TrainConfig,
    stats: FeatureStats,
    *,
    schedule: DiffusionSchedule | None = None,
    mesh: Mesh | None = None,
) -> Callable[[TrainState, CurveArrays], tuple[TrainState, dict[str, Array]]]:
    """The (un-jitted) single-seed training step; see :func:`compile_train_step`."""
    schedule = cosine_schedule(model_config.num_timesteps) if schedule is None else schedule
    layout = BezierLayout.from_controls(model_config.num_controls, model_config.stride)
    optimizer = make_optimizer(train_config)
    weights = train_config.weights
    k_ctrl, k_joints = model_config.num_controls, model_config.num_joints

    def example_loss(params, batch_item, rng):
        pos, tangent, rot6d, contacts, dense = batch_item
        t_key, noise_key, cond_key, drop_key, dropout_key = jax.random.split(rng, 5)
        t = jax.random.randint(t_key, (), 0, schedule.num_timesteps)
        x0 = to_tokens(stats.normalize(control_features(pos, tangent, rot6d)))
        x_t = schedule.add_noise(x0, t, jax.random.normal(noise_key, x0.shape, x0.dtype))
        control, joint, valid = draw_intermediate_slots(cond_key, k_ctrl, k_joints, train_config.max_intermediate_handles)
        conditions = inbetween_conditions(k_ctrl, pos[0], pos[-1], control, joint, pos[control, joint], valid)
        # Classifier-free guidance: drop every condition of this example at once.
        conditions = conditions._replace(valid=conditions.valid & ~jax.random.bernoulli(drop_key, train_config.condition_dropout))
        mask, _ = conditions.to_grid(k_ctrl, k_joints)
        conditions = normalize_conditions(stats, conditions)
        pred_tokens, contact_logits = predict_x0(nnx.merge(graphdef, params), stats, x_t, t, conditions, key=dropout_key)
        pred_pos, pred_tangent, pred_rot6d = split_features(stats.denormalize(from_tokens(pred_tokens)))
        terms = bmm_loss_terms(
            layout, pred_pos, pred_tangent, pred_rot6d, contact_logits, pos, tangent, rot6d, contacts, dense, mask
        )
        weight = min_snr_weight(schedule.snr(t), train_config.min_snr_gamma)
        return weight * weights.total(terms), terms

    def loss_fn(params, batch, rngs):
        losses, terms = jax.vmap(example_loss, in_axes=(None, 0, 0))(params, batch, rngs)
        return jnp.mean(losses), jax.tree.map(jnp.mean, terms)

    def step(state: TrainState, data: CurveArrays) -> tuple[TrainState, dict[str, Array]]:
        key, index_key, example_key = jax.random.split(state.key, 3)
        index = jax.random.randint(index_key, (train_config.batch_size,), 0, data.ctrl_pos.shape[0])
        batch = jax.tree.map(lambda a: _sharded(a[index], mesh), tuple(data))
        rngs = jax.random.split(example_key, train_config.batch_size)
        (loss, terms), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params, batch, rngs)
        updates, opt_state = optimizer.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        decay = train_config.ema_decay
        ema = jax.tree.map(lambda e, p: decay * e + (1.0 - decay) * p, state.ema, params)
        metrics = {"loss": loss, "grad_norm": optax.global_norm(grads), **terms}
        return TrainState(params, opt_state, ema, state.step + 1, key), metrics

    return step


def compile_train_step(step_fn: Callable, *, num_seeds: int | None) -> Callable:
    """``jax.jit`` the step, vmapped over stacked seeds when ``num_seeds`` is given.

    The state is not donated: if Ctrl-C lands mid-step, the previous state must still be
    intact so it can be checkpointed."""
    fn = jax.vmap(step_fn, in_axes=(0, None)) if num_seeds is not None else step_fn
    return jax.jit(fn)


def data_mesh() -> Mesh | None:
    """A 1-D mesh over all local devices named ``"data"``, or ``None`` with one device."""
    devices = jax.local_devices()
    return Mesh(np.asarray(devices), ("data",)) if len(devices) > 1 else None


@contextlib.contextmanager
def _terminate_requests():
    """Record SIGTERM (``kill``, a scheduler's pre-emption) instead of dying, so the loop
    can stop at a step boundary and checkpoint as on Ctrl-C. Background jobs of a
    non-interactive shell ignore SIGINT, so for them SIGTERM is the polite way to stop.
    Yields a list that gets the signal number; a no-op outside the main thread."""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: received.append(signum))
    try:
        yield received
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_training(
    step_fn: Callable[[TrainState, Any], tuple[TrainState, dict[str, Array]]],
    state: TrainState,
    data: Any,
    *,
    num_steps: int,
    store: CheckpointStore | None = None,
    checkpoint_every: int = 1000,
    config: dict[str, Any] | None = None,
    progress: bool = True,
    log_every: int = 25,
) -> tuple[TrainState, list[dict[str, float | int]]]:
    """Run a compiled step until ``state.step`` reaches ``num_steps``, resuming from ``store``.

    Model-agnostic: ``data`` is whatever the step takes (BMM's :class:`CurveArrays`, the
    Δ-interpolator's windows).

    Checkpoints every ``checkpoint_every`` steps, at the end and on Ctrl-C or SIGTERM
    (then raises ``KeyboardInterrupt``). Returns the final state and the logged metrics (every ``log_every``
    steps, averaged over seeds).
    """
    if store is not None and store.latest_step() is not None:
        state = store.restore(state)
    done = int(np.max(np.asarray(state.step)))
    history: list[dict[str, float]] = []
    bar = tqdm(total=num_steps, initial=done, desc="training", unit="step", disable=not progress)
    started, started_step = time.perf_counter(), done
    with _terminate_requests() as terminate:
        try:
            while done < num_steps:
                if terminate:  # a SIGTERM arrived during the last step: stop here, cleanly
                    raise KeyboardInterrupt(f"signal {terminate[0]}")
                state, metrics = step_fn(state, data)
                done += 1
                if done % log_every == 0 or done == num_steps:
                    logged = {k: float(np.mean(np.asarray(v))) for k, v in metrics.items()}
                    rate = (done - started_step) / max(time.perf_counter() - started, 1e-9)
                    history.append({"step": done, "steps_per_s": rate, **logged})
                    bar.set_postfix(loss=f"{logged['loss']:.4g}", steps_per_s=f"{rate:.2f}")
                bar.update(1)
                if store is not None and done % checkpoint_every == 0:
                    store.save(done, state, config)
        except KeyboardInterrupt:
            if store is not None:
                done = int(np.max(np.asarray(state.step)))  # the state actually held, whatever was interrupted
                store.save(done, state, config)
                bar.write(f"interrupted: saved step {done} to {store.directory}")
            raise
        finally:
            bar.close()
    if store is not None:
        store.save(done, state, config)
    return state, history


__all__ = [
    "CurveArrays",
    "TrainConfig",
    "TrainState",
    "compile_train_step",
    "data_mesh",
    "init_train_state",
    "init_train_states",
    "make_optimizer",
    "make_train_step",
    "run_training",
    "stack_seeds",
]
