"""Recurrent PPO (Schulman et al. 2017; not the paper's), as PureJaxRL's ``ppo_rnn.py``: a
rollout of ``rollout_steps`` on ``num_envs`` envs, GAE, ``update_epochs`` of clipped-surrogate
steps over minibatches of whole env sequences. A + 1 outputs (logits, value); a time limit
ends the advantage's sum as a termination does (PureJaxRL)."""

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.learners.common import (
    Trainer,
    make_on_policy,
    minibatch_epochs,
    per_decision,
    restarted,
)
from drqn_jax.learners.hyperparams import Hyperparams, TrainConfig
from drqn_jax.learners.task import Task, make_task
from drqn_jax.networks import Network, make_network
from drqn_jax.programs import cached_program


class Transition(NamedTuple):
    """One rollout step of N envs (leaves (N, …)); ``reset``: the carry was zeroed
    before it (an episode starts)."""

    obs: Any
    action: jax.Array
    reward: jax.Array
    done: jax.Array
    value: jax.Array
    log_prob: jax.Array
    reset: jax.Array


def actor_critic(config: TrainConfig, task: Task) -> Network:
    """The task's network with A + 1 outputs: A logits, then the value."""
    net_config = task.network(config.network)
    return make_network(dataclasses.replace(net_config, num_actions=task.num_actions + 1))


def policy_network(network: Network, num_actions: int) -> Network:
    """``network`` giving the logits (…, A) alone (the greedy agent's argmax)."""

    def step(params, obs, carry):
        out, carry = network.step(params, obs, carry)
        return out[..., :num_actions], carry

    def unroll(params, obs, carry, resets):
        out, carry = network.unroll(params, obs, carry, resets)
        return out[..., :num_actions], carry

    return network._replace(step=step, unroll=unroll)


def gae(
    value: jax.Array, reward: jax.Array, done: jax.Array, last_value: jax.Array, hp: Hyperparams
) -> tuple[jax.Array, jax.Array]:
    """GAE advantages and value targets (T, N) from values, rewards, dones (T, N)
    and the next state's value (N,)."""

    def back(carry, step):
        advantage, next_value = carry
        v, r, d = step
        delta = r + hp.gamma * next_value * (1.0 - d) - v
        advantage = delta + hp.gamma * hp.gae_lambda * (1.0 - d) * advantage
        return (advantage, v), advantage

    init = (jnp.zeros_like(last_value), last_value)
    _, advantages = jax.lax.scan(
        back, init, (value, reward, done.astype(jnp.float32)), reverse=True
    )
    return advantages, advantages + value


def ppo_loss(
    params: Any,
    network: Network,
    num_actions: int,
    carry: Any,
    batch: Transition,
    advantage: jax.Array,
    target: jax.Array,
    hp: Hyperparams,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Clipped-surrogate loss of sequences (T, B, …) from ``carry`` (B, …): actor +
    vf_coef · clipped value loss − ent_coef · entropy, and its parts."""
    out, _ = network.unroll(params, batch.obs, carry, batch.reset)
    logits, value = out[..., :num_actions], out[..., num_actions]
    log_probs = jax.nn.log_softmax(logits)
    log_prob = jnp.take_along_axis(log_probs, batch.action[..., None], axis=-1)[..., 0]
    ratio = jnp.exp(log_prob - batch.log_prob)
    adv = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
    clipped = jnp.clip(ratio, 1.0 - hp.clip_eps, 1.0 + hp.clip_eps)
    actor = -jnp.mean(jnp.minimum(ratio * adv, clipped * adv))
    value_clipped = batch.value + jnp.clip(value - batch.value, -hp.clip_eps, hp.clip_eps)
    critic = 0.5 * jnp.mean(jnp.maximum((value - target) ** 2, (value_clipped - target) ** 2))
    entropy = jnp.mean(-jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1))
    total = actor + hp.vf_coef * critic - hp.ent_coef * entropy
    return total, {"actor": actor, "critic": critic, "entropy": entropy}


@cached_program
def make_ppo(config: TrainConfig) -> Trainer:
    """The :class:`~drqn_jax.learners.common.Trainer` of an ``algorithm = "ppo"`` config."""
    task = make_task(config.env_id, config.env_overrides)
    network = actor_critic(config, task)
    return make_on_policy(
        config,
        task,
        network,
        policy_network(network, task.num_actions),
        functools.partial(_sample, task, network),
        Transition,
        functools.partial(_learn, config, task, network),
    )


def _sample(
    task: Task, network: Network, state: Any, key: jax.Array
) -> tuple[jax.Array, Any, dict[str, jax.Array], None]:
    """The sampling policy: actions (N,) int32, the carry, value and log-prob (N,)."""
    n_act = task.num_actions
    out, carry = network.step(state.online, state.obs, restarted(network, state))
    logits, value = out[..., :n_act], out[..., n_act]
    action = jax.random.categorical(key, logits).astype(jnp.int32)
    log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], axis=-1)[:, 0]
    return action, carry, {"value": value, "log_prob": log_prob}, None


def _learn(
    config: TrainConfig, task: Task, network: Network, state: Any, traj: Transition, carry0: Any
) -> Any:
    """One rollout's update: GAE, then minibatch epochs of :func:`ppo_loss`."""
    hp, n_act = state.hparams, task.num_actions
    out, _ = network.step(state.online, state.obs, restarted(network, state))
    last_value = out[..., n_act]
    advantage, target = gae(traj.value, traj.reward, traj.done, last_value, per_decision(hp, task))

    def loss_of(params, sequences, carry):
        total, _ = ppo_loss(params, network, n_act, carry, *sequences, hp)
        return total, total

    return minibatch_epochs(config, state, loss_of, (traj, advantage, target), carry0)
