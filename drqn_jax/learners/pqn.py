"""Recurrent PQN (Gallici et al. 2024; purejaxql's ``pqn_rnn_gymnax.py``): the paper's
recurrent Q-network (Table I; paper §V-B) without replay or target network. One update: an
ε-greedy rollout (the DQN's ε schedule), Q(λ) targets from the trained network (no gradient),
then minibatch epochs of the squared TD error. Targets also bootstrap from the observation
after the rollout (purejaxql drops the last step). With ``memory_window`` = W > 0 the previous
rollout's last W steps come first in every sequence, unrolled from the state they were acted
from, and are trained again (purejaxql's ``MEMORY_WINDOW``; padding, weighted 0, at first)."""

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.learners.common import (
    Trainer,
    epsilon_of,
    make_on_policy,
    minibatch_epochs,
    per_decision,
    restarted,
)
from drqn_jax.learners.hyperparams import Hyperparams, TrainConfig, step_share
from drqn_jax.learners.task import Task, make_task
from drqn_jax.networks import Network, make_network
from drqn_jax.programs import cached_program


class QTransition(NamedTuple):
    """One rollout step of N envs (leaves (N, …)); ``q`` (N, A): the Q-values acted
    on; ``reset``: the carry was zeroed before it (an episode starts); ``carry``: the
    state acted from (with a memory window only)."""

    obs: Any
    q: jax.Array
    action: jax.Array
    reward: jax.Array
    done: jax.Array
    reset: jax.Array
    carry: Any = None


def q_lambda_targets(
    q_next: jax.Array, reward: jax.Array, done: jax.Array, gamma: jax.Array, lam: jax.Array
) -> jax.Array:
    """Peng's Q(λ) targets (T, N) from ``q_next`` = max_a Q after each step, ``reward``,
    ``done`` (T, N): G_t = r + γ(1 − d)((1 − λ) q_next + λ G_{t+1}) (purejaxql's)."""
    not_done = 1.0 - done.astype(jnp.float32)

    def back(g_next, step):
        q, r, nd = step
        g = r + gamma * nd * ((1.0 - lam) * q + lam * g_next)
        return g, g

    last = q_next[-1]  # G_T: the bootstrap itself, so that G_{T-1} = r + γ(1 − d) q_next
    _, targets = jax.lax.scan(back, last, (q_next, reward, not_done), reverse=True)
    return targets


def pqn_loss(
    params: Any,
    network: Network,
    carry: Any,
    batch: QTransition,
    last: QTransition,
    hp: Hyperparams,
    weight: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Half the mean squared TD error of sequences (T, B, …) plus ``last`` (B, …),
    unrolled from ``carry``, against fixed :func:`q_lambda_targets`, the steps weighted
    by ``weight`` (T,) if given: (loss, loss)."""
    obs = jax.tree.map(lambda xs, x: jnp.concatenate([xs, x[None]]), batch.obs, last.obs)
    resets = jnp.concatenate([batch.reset, last.reset[None]])
    q, _ = network.unroll(params, obs, carry, resets)  # (T + 1, B, A)
    q_max = jax.lax.stop_gradient(jnp.max(q[1:], axis=-1))
    reward = batch.reward * hp.reward_scale
    targets = q_lambda_targets(q_max, reward, batch.done, hp.gamma, hp.q_lambda)
    chosen = jnp.take_along_axis(q[:-1], batch.action[..., None], axis=-1)[..., 0]
    squared = jnp.square(chosen - targets)
    if weight is None:
        loss = 0.5 * jnp.mean(squared)
    else:
        loss = 0.5 * jnp.sum(weight[:, None] * squared) / (jnp.sum(weight) * squared.shape[1])
    return loss, loss


@cached_program
def make_pqn(config: TrainConfig) -> Trainer:
    """The :class:`~drqn_jax.learners.common.Trainer` of an ``algorithm = "pqn"`` config;
    its episodes also record the ε they ran with."""
    task = make_task(config.env_id, config.env_overrides)
    network = make_network(task.network(config.network))
    policy = functools.partial(_explore, config, task, network)
    learn = functools.partial(_learn, config, task, network)
    memory = functools.partial(_empty_memory, config, task) if config.memory_window else None
    return make_on_policy(
        config, task, network, network, policy, QTransition, learn, ("epsilon",), memory
    )


def _empty_memory(config: TrainConfig, task: Task, fields: dict[str, Any]) -> QTransition:
    """The memory before the first rollout: W zero steps (W, N, …), weighted 0."""
    n = config.num_envs
    step = QTransition(
        obs=fields["obs"],
        q=jnp.zeros((n, task.num_actions), jnp.float32),
        action=jnp.zeros((n,), jnp.int32),
        reward=jnp.zeros((n,), jnp.float32),
        done=jnp.zeros((n,), bool),
        reset=jnp.ones((n,), bool),
        carry=fields["carry"],
    )
    return jax.tree.map(lambda x: jnp.zeros((config.memory_window, *x.shape), x.dtype), step)


def _explore(
    config: TrainConfig, task: Task, network: Network, state: Any, key: jax.Array
) -> tuple[jax.Array, Any, dict[str, jax.Array], dict[str, jax.Array]]:
    """The ε-greedy policy: actions (N,) int32, the carry, Q-values (N, A) and ε (N,)."""
    hp = state.hparams
    k_explore, k_random = jax.random.split(key)
    start = restarted(network, state)
    q, carry = network.step(state.online, state.obs, start)
    eps = epsilon_of(state.episode, hp, config.num_episodes, step_share(config, state.env_steps))
    shape = state.episode.shape
    random_action = jax.random.randint(k_random, shape, 0, task.num_actions, jnp.int32)
    greedy = jnp.argmax(q, axis=-1).astype(jnp.int32)
    action = jnp.where(jax.random.uniform(k_explore, shape) < eps, random_action, greedy)
    acted = {"q": q, "carry": start} if config.memory_window else {"q": q}
    return action, carry, acted, {"epsilon": eps}


def _learn(
    config: TrainConfig, task: Task, network: Network, state: Any, traj: QTransition, carry0: Any
) -> Any:
    """One rollout's update: minibatch epochs of :func:`pqn_loss`, over the memory
    window and the rollout (W + T, N, …) if ``memory_window`` = W > 0."""
    td_hp = per_decision(state.hparams, task)
    last = jax.tree.map(lambda x: x[0], traj)._replace(obs=state.obs, reset=state.done)
    weight = None
    if config.memory_window:
        window = config.memory_window
        first = state.grad_steps == 0  # the memory is padding: the rollout restarts
        traj, state = (
            jax.tree.map(lambda m, x: jnp.concatenate([m, x]), state.memory, traj),
            state.replace(memory=jax.tree.map(lambda x: x[-window:], traj)),
        )
        traj = traj._replace(reset=traj.reset.at[window].set(traj.reset[window] | first))
        carry0 = jax.tree.map(lambda x: x[0], traj.carry)
        weight = (jnp.arange(traj.reward.shape[0]) >= window) | ~first
        weight = weight.astype(jnp.float32)

    def loss_of(params, batch, per_env):
        carry, mb_last = per_env
        return pqn_loss(params, network, carry, batch, mb_last, td_hp, weight)

    return minibatch_epochs(config, state, loss_of, traj, (carry0, last))
