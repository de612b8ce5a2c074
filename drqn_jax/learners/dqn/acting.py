"""Acting while learning: ε-greedy exploration (paper §V-B; SPEC §7).

Random actions follow the task's biased distribution for the first
``explore_bias_fraction`` of episodes, then uniform; with ``explore_guide`` = g > 0
(not the paper's) they are the rule-based agent's (SPEC §6) with probability g.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.learners.dqn.state import TrainState
from drqn_jax.learners.task import Task
from drqn_jax.networks import Network

__all__ = ["GUIDE_STREAM", "explore"]

#: ``fold_in`` index of the guided-action draw: its own stream, so that
#: ``explore_guide = 0`` leaves every other draw as it was.
GUIDE_STREAM = 1


def explore(
    task: Task, network: Network, num_episodes: int, state: TrainState, key: jax.Array
) -> tuple[jax.Array, Any]:
    """ε-greedy actions (N,) int32 of the run's N envs and the advanced network carry."""
    hp = state.hparams
    n_env = state.episode.shape[0]
    k_explore, k_random = jax.random.split(key)
    q, carry = network.step(state.online, state.obs, state.carry)
    greedy = jnp.argmax(q, axis=-1).astype(jnp.int32)
    biased = state.episode < hp.explore_bias_fraction * num_episodes
    probs = jnp.where(biased[:, None], task.explore_bias(hp), 1.0 / task.num_actions)
    random_action = jax.random.categorical(k_random, jnp.log(probs)).astype(jnp.int32)
    if task.teacher is not None:
        guided = jax.random.uniform(jax.random.fold_in(k_random, GUIDE_STREAM), (n_env,))
        guide_action = jax.vmap(task.teacher.act, (0, None))(state.env_state, state.env_params)
        random_action = jnp.where(guided < hp.explore_guide, guide_action, random_action)
    explore_now = jax.random.uniform(k_explore, (n_env,)) < state.epsilon
    return jnp.where(explore_now, random_action, greedy), carry
