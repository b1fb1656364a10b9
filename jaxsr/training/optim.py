"""Adam over pytrees and learning-rate schedules, hand-written (no optax).

An optimiser state is a small pytree (`AdamState`); a schedule is a plain function `step -> lr` of the
0-based index of the update being made (the first update has step 0).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["AdamState", "adam_init", "adam_update", "lr_schedule", "step_decay"]


class AdamState(NamedTuple):
    """Adam's moments: `count` (int32 scalar, updates made so far), `mu` and `nu` (first and second moment
    estimates, pytrees shaped like the params)."""

    count: jax.Array
    mu: dict
    nu: dict


def adam_init(params) -> AdamState:
    """Adam state for `params` (any pytree of float arrays).

    Returns `AdamState(count=0, mu=zeros like params, nu=zeros like params)`.
    """
    zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
    return AdamState(jnp.zeros((), jnp.int32), zeros, jax.tree_util.tree_map(jnp.zeros_like, params))


def adam_update(grads, opt_state: AdamState, params, *, lr, b1=0.9, b2=0.999, eps=1e-7):
    """One Adam step in Keras's form (what the paper used), returning (new_params, new_opt_state).

    With t = count + 1: mu = b1 mu + (1 - b1) g; nu = b2 nu + (1 - b2) g^2;
    p -= lr * sqrt(1 - b2^t) / (1 - b1^t) * mu / (sqrt(nu) + eps).
    That is Kingma & Ba's update with their epsilon replaced by eps / sqrt(1 - b2^t) (Keras's placement);
    Keras's default eps = 1e-7. `lr` may be a traced scalar (a schedule's value).
    """
    t = opt_state.count + 1
    mu = jax.tree_util.tree_map(lambda m, g: b1 * m + (1 - b1) * g, opt_state.mu, grads)
    nu = jax.tree_util.tree_map(lambda v, g: b2 * v + (1 - b2) * jnp.square(g), opt_state.nu, grads)
    tf = t.astype(jnp.float32)
    alpha = lr * jnp.sqrt(1 - b2**tf) / (1 - b1**tf)
    new_params = jax.tree_util.tree_map(
        lambda p, m, v: (p - alpha * m / (jnp.sqrt(v) + eps)).astype(p.dtype), params, mu, nu
    )
    return new_params, AdamState(t, mu, nu)


def step_decay(lr0: float, *, factor: float, every: int):
    """Schedule lr(step) = lr0 * factor ** (step // every), `step` the 0-based update index.

    With every = decay_epochs * steps_per_epoch the rate changes exactly at the first update of epoch
    decay_epochs, 2 * decay_epochs, ... (not one step late, as `jax.example_libraries`'s
    `piecewise_constant` does). Returns the schedule, a function step -> lr (scalar).
    """
    if every < 1:
        raise ValueError(f"step_decay: every must be >= 1, got {every}")

    def schedule(step):
        return lr0 * factor ** (jnp.asarray(step) // every).astype(jnp.float32)

    return schedule


def lr_schedule(train_cfg):
    """The learning rate of a `TrainConfig`'s run (our networks' and the baselines'): step -> lr (a scalar), step
    the 0-based update index.

    `lr0 * lr_decay ** (step // (decay_epochs * steps_per_epoch))`: constant within an epoch, cut exactly at
    the first step of epochs decay_epochs + 1, 2 decay_epochs + 1, ... (1-based).
    """
    return step_decay(train_cfg.lr, factor=train_cfg.lr_decay, every=train_cfg.decay_epochs * train_cfg.steps_per_epoch)
