"""Per-episode bookkeeping of a training run, shared by the learners (SPEC §7).

Both learners (:mod:`drqn_jax.learners.dqn.train`'s Double-DQN and :mod:`drqn_jax.learners.ppo`)
step N environments at once, so episodes end out of order. Each env keeps
the index of its current training episode and running sums; when an episode
ends its metrics are written at its index of (num_episodes,) buffers, and
the env's next episode takes the next free index. ``recorded`` counts the
training episodes written: the run's budget is ``num_episodes`` of them (an
episode beyond it is played but not written), or, with ``num_env_steps`` > 0,
that many env steps if they come first (:func:`budget_met`).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.learners.task import Step, Task

__all__ = ["BASE_METRICS", "budget_met", "init_counters", "init_metrics", "record_episodes"]

#: Per-episode metrics of every learner and task; a learner adds its own (the
#: DQN: ε), a task its own (the paper's env: collision, goal, distance, speed).
BASE_METRICS = ("episode_return", "length", "mean_loss")


def budget_met(state: Any) -> jax.Array:
    """() bool: every one of the ``num_episodes`` training episodes is recorded, or
    the state's ``step_budget`` (``TrainConfig.num_env_steps``; 0 = none) of env
    steps is taken."""
    by_steps = (state.step_budget > 0) & (state.env_steps >= state.step_budget)
    return (state.recorded >= state.metrics["length"].shape[-1]) | by_steps


def init_counters(num_envs: int, num_env_steps: int) -> dict[str, jax.Array]:
    """The counters a state starts with: env i in training episode i, running sums
    (N,) at zero, none recorded, no step or gradient step taken, and the step
    budget (0: none)."""
    zeros_f, zeros_i = jnp.zeros((num_envs,), jnp.float32), jnp.zeros((num_envs,), jnp.int32)
    return {
        "episode": jnp.arange(num_envs, dtype=jnp.int32),
        "ep_return": zeros_f,
        "ep_length": zeros_i,
        "ep_loss_sum": zeros_f,
        "ep_loss_count": zeros_i,
        "episodes_started": jnp.asarray(num_envs, jnp.int32),
        "recorded": jnp.zeros((), jnp.int32),
        "grad_steps": jnp.zeros((), jnp.int32),
        "env_steps": jnp.zeros((), jnp.int32),
        "step_budget": jnp.asarray(num_env_steps, jnp.int32),
    }


def init_metrics(task: Task, num_episodes: int, extra: tuple[str, ...] = ()) -> dict:
    """Empty metric buffers, (num_episodes,) each: ``BASE_METRICS``, the learner's
    float32 ``extra`` ones and the task's."""
    dtypes = {**dict.fromkeys((*BASE_METRICS, *extra), jnp.float32), "length": jnp.int32}
    dtypes.update(dict(task.metrics))
    return {name: jnp.zeros((num_episodes,), dtype) for name, dtype in dtypes.items()}


def record_episodes(
    task: Task,
    num_episodes: int,
    state: Any,
    step: Step,
    done: jax.Array,
    loss_sum: jax.Array,
    n_updates: jax.Array,
    extra: dict[str, jax.Array] | None = None,
) -> tuple[Any, dict[str, jax.Array]]:
    """The bookkeeping of one vector env step (leaves (N,)).

    ``state`` holds the env and observation, the per-env counters (``episode``,
    ``ep_return``, ``ep_length``, ``ep_loss_sum``, ``ep_loss_count``) and the
    run's (``episodes_started``, ``recorded``, ``env_steps``, ``metrics``);
    ``done`` (N,) says which episodes ended at ``step``; ``loss_sum`` and
    ``n_updates`` are the losses summed over and the number of gradient
    updates made at this step; ``extra`` the learner's own per-env values
    written with an ended episode (the DQN's ε). Returns the state moved on
    (counters of ended episodes reset, their envs' next episode indices) and
    the metrics with each ended training episode's values written.
    """
    ep_return = state.ep_return + step.reward
    ep_length = state.ep_length + 1
    ep_loss_sum = state.ep_loss_sum + loss_sum
    ep_loss_count = state.ep_loss_count + n_updates
    record = done & (state.episode < num_episodes)
    index = jnp.where(record, state.episode, num_episodes)  # out of range: dropped
    values = {
        "episode_return": ep_return,
        "length": ep_length,
        **task.episode_metrics(step, ep_length, state.env_params),
        **(extra or {}),
        "mean_loss": ep_loss_sum / jnp.maximum(ep_loss_count, 1).astype(jnp.float32),
    }
    metrics = {
        name: state.metrics[name].at[index].set(values[name].astype(buf.dtype), mode="drop")
        for name, buf in state.metrics.items()
    }
    new_episode = state.episodes_started + jnp.cumsum(done.astype(jnp.int32)) - 1
    zero_f, zero_i = jnp.zeros_like(ep_return), jnp.zeros_like(ep_length)
    moved = state.replace(
        env_state=step.state,
        obs=step.obs,
        episode=jnp.where(done, new_episode, state.episode),
        ep_return=jnp.where(done, zero_f, ep_return),
        ep_length=jnp.where(done, zero_i, ep_length),
        ep_loss_sum=jnp.where(done, zero_f, ep_loss_sum),
        ep_loss_count=jnp.where(done, zero_i, ep_loss_count),
        episodes_started=state.episodes_started + jnp.sum(done, dtype=jnp.int32),
        recorded=state.recorded + jnp.sum(record, dtype=jnp.int32),
        env_steps=state.env_steps + done.shape[0],
    )
    return moved, metrics
