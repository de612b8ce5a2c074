"""Acting while learning: ε-greedy exploration (paper §V-B; SPEC §7).

ε (:func:`~drqn_jax.learners.common.epsilon_of`) falls linearly from
``epsilon_start`` to ``epsilon_end`` over the training episodes (an episode
keeps the ε it started with), or over their first ``epsilon_fraction`` (the
project's option; 1 = the paper). During the first
``explore_bias_fraction`` of episodes a random action is drawn from the
task's biased distribution (the paper's env: accelerate 0.4, slow_down 0.1,
brake 0.1, steer 0.4), uniformly afterwards. With ``explore_guide`` = g > 0
(the project's, not the paper's) an exploratory action is, with probability
g, the teacher's (the rule-based agent, SPEC §6) instead: the replay then
holds episodes of braking and waiting for pedestrians, which uniform random
actions rarely produce; learning stays off-policy Q-learning and the agent
acts greedily on its own at evaluation.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.learners.dqn.state import TrainState
from drqn_jax.learners.task import Task
from drqn_jax.networks import Network

__all__ = ["GUIDE_STREAM", "explore"]

#: ``fold_in`` index of the draw that picks a guided exploratory action: a
#: stream of its own, so that ``explore_guide = 0`` leaves every other draw,
#: and hence every run, as it was.
GUIDE_STREAM = 1


def explore(
    task: Task, network: Network, num_episodes: int, state: TrainState, key: jax.Array
) -> tuple[jax.Array, Any]:
    """ε-greedy actions (N,) int32 of the run's N envs and the advanced network carry.

    Reads ``state``'s online parameters, observations, carry and true env
    states (leading N axes) and each env's training episode and ε, (N,).
    """
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
