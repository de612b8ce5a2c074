"""The learner's gradient update (paper §II-E, §V-B; SPEC §7): sample windows, the
sequence loss and its gradient (clamped with ``clip = "grad"``), Adam, and a hard
target copy every ``target_period`` steps; imitation labels (not the paper's) are
recomputed from the replayed records.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.env.state import BRAKE
from drqn_jax.learners.common import optimizer_of, per_decision
from drqn_jax.learners.dqn.loss import CLIP_GRAD, sequence_loss
from drqn_jax.learners.dqn.replay import EpisodeReplay, sample_windows
from drqn_jax.learners.hyperparams import IMITATION_ALL, Hyperparams, TrainConfig
from drqn_jax.learners.optim import apply_updates, clip
from drqn_jax.learners.task import Task
from drqn_jax.networks import Network

__all__ = ["Learner", "gradient_update", "learn"]


class Learner(NamedTuple):
    """What a gradient step changes: both networks, Adam's state and the step count."""

    online: Any
    target: Any
    opt_state: Any
    grad_steps: jax.Array


def _imitation(task: Task, windows: Any, hp: Hyperparams, env_params: Any) -> tuple:
    """Expert actions and imitation weights (W, B), or (None, None) without a teacher."""
    if task.teacher is None:
        return None, None
    states = jax.tree.map(lambda x: x[:-1], windows.records)  # s_t of each transition
    expert = task.teacher.labels(states, env_params, hp)
    imitate = (hp.imitation_states == IMITATION_ALL) | (expert == BRAKE)
    return expert, hp.imitation_weight * imitate.astype(jnp.float32)


def gradient_update(
    config: TrainConfig,
    task: Task,
    network: Network,
    learner: Learner,
    key: jax.Array,
    replay: EpisodeReplay,
    hp: Hyperparams,
    env_params: Any,
) -> tuple[Learner, jax.Array]:
    """One Double-DQN gradient step on ``learner``; the new learner and the () loss."""
    opt = optimizer_of(config, hp)
    windows = sample_windows(
        replay,
        key,
        config.batch_size,
        config.window,
        lambda records, last: task.observe(records, last, env_params),
        hp.window_start,
        config.burn_in,
    )
    expert, weight = _imitation(task, windows, hp, env_params)
    (loss, _), grads = jax.value_and_grad(sequence_loss, has_aux=True)(
        learner.online,
        learner.target,
        windows,
        network,
        per_decision(hp, task).gamma,
        hp.clip,
        config.n_step,
        expert,
        weight,
        hp.imitation_margin,
        hp.value_rescale,
        config.burn_in,
    )
    clamped, _ = clip(1.0).update(grads, ())
    grads = jax.tree.map(lambda c, g: jnp.where(hp.clip == CLIP_GRAD, c, g), clamped, grads)
    updates, opt_state = opt.update(grads, learner.opt_state, learner.online)
    online = apply_updates(learner.online, updates)
    grad_steps = learner.grad_steps + 1
    copy = grad_steps % hp.target_period == 0
    target = jax.tree.map(lambda o, t: jnp.where(copy, o, t), online, learner.target)
    return Learner(online, target, opt_state, grad_steps), loss


def learn(
    config: TrainConfig,
    task: Task,
    network: Network,
    learner: Learner,
    replay: EpisodeReplay,
    hp: Hyperparams,
    env_params: Any,
    key: jax.Array,
) -> tuple[Learner, jax.Array]:
    """``updates_per_step`` gradient steps: the new learner and the summed loss.

    The replay is a read-only operand of the gating ``lax.cond`` (carrying it would
    make XLA copy it every step).
    """

    def update(learner, k):
        return gradient_update(config, task, network, learner, k, replay, hp, env_params)

    keys = jax.random.split(key, config.updates_per_step)
    learner, losses = jax.lax.scan(update, learner, keys)
    return learner, jnp.sum(losses)
