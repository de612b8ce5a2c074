"""Recurrent PPO (Schulman et al. 2017; not the paper's), laid out like PureJaxRL's
``ppo_rnn.py`` behind the same :class:`~drqn_jax.learners.trainer.Trainer` as the DQN.

One update: a rollout of ``rollout_steps`` on ``num_envs`` envs, GAE, then
``update_epochs`` of clipped-surrogate steps over minibatches of whole env sequences.
The network has A + 1 outputs (logits, value); the carry is zeroed at every episode
start, and a time limit ends the advantage's sum as a termination does (PureJaxRL).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.learners.common import (
    budget_met,
    init_counters,
    init_metrics,
    minibatch_epochs,
    per_decision,
    restarted,
    rollout,
    run_updates,
)
from drqn_jax.learners.hyperparams import Hyperparams, TrainConfig, annealed, step_share
from drqn_jax.learners.optim import optimizer
from drqn_jax.learners.task import Task, make_task
from drqn_jax.learners.trainer import Trainer, make_trainer
from drqn_jax.networks import Network, make_network
from drqn_jax.programs import cached_program
from drqn_jax.pytree import pytree_dataclass

__all__ = [
    "PPOState",
    "Transition",
    "actor_critic",
    "gae",
    "make_ppo",
    "policy_network",
    "ppo_loss",
]


@pytree_dataclass
class PPOState:
    """Everything a PPO run carries between updates (and checkpoints); per-env leaves
    (N, …), ``online`` the actor-critic's parameters, ``done`` (N,) restarts the carry."""

    key: jax.Array
    hparams: Hyperparams
    env_params: Any
    env_state: Any
    obs: Any
    carry: Any
    done: jax.Array
    online: Any
    opt_state: Any
    episode: jax.Array
    ep_return: jax.Array
    ep_length: jax.Array
    ep_loss_sum: jax.Array
    ep_loss_count: jax.Array
    episodes_started: jax.Array
    recorded: jax.Array
    grad_steps: jax.Array
    env_steps: jax.Array
    step_budget: jax.Array  # () int32 TrainConfig.num_env_steps (0: none)
    metrics: dict[str, jax.Array]
    #: The protocol's candidates' validation metrics: none, PPO selects no snapshot.
    validation: ClassVar[None] = None

    @property
    def finished(self) -> jax.Array:
        return budget_met(self)


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


def make_ppo(config: TrainConfig) -> Trainer:
    """The :class:`~drqn_jax.learners.trainer.Trainer` of an ``algorithm = "ppo"`` config."""
    if config.algorithm != "ppo":
        raise ValueError(f"make_ppo: TrainConfig.algorithm = {config.algorithm!r}; use 'ppo'")
    return _make_ppo(config)


@cached_program
def _make_ppo(config: TrainConfig) -> Trainer:
    task = make_task(config.env_id, config.env_overrides)
    n_act = task.num_actions
    network = actor_critic(config, task)
    policy = policy_network(network, n_act)

    def init(key: jax.Array, hparams: Hyperparams | None = None, env_params: Any = None):
        """The state before the first update."""
        hp = config.hyperparams if hparams is None else hparams
        env_params = task.env_params if env_params is None else env_params
        return _init_state(config, task, network, key, hp, env_params)

    def act(state: PPOState, key: jax.Array) -> tuple[jax.Array, Any]:
        """Actions (N,) sampled from the policy and the advanced carry."""
        out, carry = network.step(state.online, state.obs, restarted(network, state))
        return jax.random.categorical(key, out[..., :n_act]).astype(jnp.int32), carry

    def update(state: PPOState) -> PPOState:
        """One update: a rollout, GAE, then epochs of clipped-surrogate steps."""
        carry0 = state.carry
        state, traj = _rollout(config, task, network, state)
        return _learn(config, task, network, n_act, state, traj, carry0)

    return make_trainer(config, task, policy, init, act, run_updates(update))


def _init_state(
    config: TrainConfig,
    task: Task,
    network: Network,
    key: jax.Array,
    hp: Hyperparams,
    env_params: Any,
) -> PPOState:
    """N envs reset, a fresh actor-critic and Adam, empty metrics."""
    n_env = config.num_envs
    key, k_net, k_env = jax.random.split(key, 3)
    params = network.init(k_net)
    obs, env_state = jax.vmap(task.reset, (0, None))(jax.random.split(k_env, n_env), env_params)
    return PPOState(
        key=key,
        hparams=hp,
        env_params=env_params,
        env_state=env_state,
        obs=obs,
        carry=network.initial_carry((n_env,)),
        done=jnp.zeros((n_env,), bool),
        online=params,
        opt_state=optimizer(
            config.optimizer, hp.learning_rate, hp.adam_b1, hp.adam_b2, hp.adam_eps
        ).init(params),
        metrics=init_metrics(task, config.num_episodes),
        **init_counters(n_env, config.num_env_steps),
    )


def _sample(
    task: Task, network: Network, state: PPOState, key: jax.Array
) -> tuple[jax.Array, Any, dict[str, jax.Array], None]:
    """The sampling policy: actions (N,) int32, the carry, value and log-prob (N,)."""
    n_act = task.num_actions
    out, carry = network.step(state.online, state.obs, restarted(network, state))
    logits, value = out[..., :n_act], out[..., n_act]
    action = jax.random.categorical(key, logits).astype(jnp.int32)
    log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], axis=-1)[:, 0]
    return action, carry, {"value": value, "log_prob": log_prob}, None


def _rollout(
    config: TrainConfig, task: Task, network: Network, state: PPOState
) -> tuple[PPOState, Transition]:
    """``rollout_steps`` sampled steps: the moved state and the trajectory (T, N, …)."""
    return rollout(config, task, functools.partial(_sample, task, network), Transition, state)


def _learn(
    config: TrainConfig,
    task: Task,
    network: Network,
    n_act: int,
    state: PPOState,
    traj: Transition,
    carry0: Any,
) -> PPOState:
    """One rollout's update: GAE, then minibatch epochs at the annealed rate."""
    hp = state.hparams
    out, _ = network.step(state.online, state.obs, restarted(network, state))
    last_value = out[..., n_act]
    advantage, target = gae(traj.value, traj.reward, traj.done, last_value, per_decision(hp, task))
    lr = annealed(
        hp, state.recorded, config.num_episodes, step_share(config, state.env_steps)
    ).learning_rate

    def grads_of(params, envs):
        take = functools.partial(jnp.take, indices=envs, axis=1)
        batch = jax.tree.map(take, traj)
        mb_carry = jax.tree.map(functools.partial(jnp.take, indices=envs, axis=0), carry0)
        return jax.grad(_total_loss, has_aux=True)(
            params, network, n_act, mb_carry, batch, take(advantage), take(target), hp
        )

    return minibatch_epochs(config, state, lr, grads_of)


def _total_loss(*args: Any) -> tuple[jax.Array, jax.Array]:
    """:func:`ppo_loss` with the total as its auxiliary output too."""
    total, _ = ppo_loss(*args)
    return total, total
