"""Recurrent PPO, a learner of another family (Schulman et al. 2017; the project's).

Laid out like PureJaxRL's ``ppo_rnn.py`` and served through the same
:class:`~drqn_jax.learners.trainer.Trainer` as the DQN (``TrainConfig.algorithm =
"ppo"``; :func:`drqn_jax.learners.make_train` builds it), so the host loop,
checkpoints, sweeps, evaluation and the study treat both alike. An
iteration is one update: a rollout of ``rollout_steps`` steps on
``num_envs`` envs, generalised advantage estimation, then ``update_epochs``
epochs of clipped-surrogate gradient steps over ``num_minibatches``
minibatches of whole env sequences (global-norm clip, Adam). The run's
budget is the project's: ``num_episodes`` training episodes, written with
the DQN's per-episode metrics (:mod:`drqn_jax.learners.common`; ``mean_loss`` is
the mean loss of the updates made while the episode ran); updates after
the budget is met change nothing, so a run split into chunks ends
bit-identical to a one-shot run. The learning rate falls as the DQN's does,
in recorded episodes (``learning_rate_end``; PureJaxRL's annealing to 0 is
``learning_rate_end = 0``).

It shares the DRQN's environment interface (:class:`~drqn_jax.learners.task.Task`,
any env of the gymnax contract), torso and recurrent core
(:mod:`drqn_jax.networks`: the network has one output more than there are
actions — the logits, then the value) and its Adam. The trainer's
``network`` is :func:`policy_network`, the logits alone, whose argmax is the
greedy agent that evaluation plays (:func:`~drqn_jax.agents.drqn.drqn_agent`).

The recurrent state is zeroed before the first step of every episode, in
acting and in the update's unroll (the ``resets`` of each step are the
``done`` flags of the step before), and each minibatch unrolls from the
state its envs had at the rollout's start. Like PureJaxRL, a time limit ends
the advantage's sum as a termination does.

Read top to bottom: the state and a rollout step (:class:`PPOState`,
:class:`Transition`), the network, the advantages and the loss
(:func:`actor_critic`, :func:`gae`, :func:`ppo_loss`), then :func:`make_ppo`,
which wires the init, the sampling policy, the rollout and the update into the
trainer; the rollout scan and the minibatch epochs are the on-policy learners'
(:mod:`drqn_jax.learners.common`).
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
    """Everything a PPO run carries between updates (and checkpoints).

    Per-env leaves have a leading N axis. ``online`` holds the actor-critic's
    parameters, trained and acting (the name the :class:`Trainer` protocol
    reads); ``carry`` is the acting network's recurrent state and ``done`` (N,)
    says which envs ended an episode at the last step (their carry restarts);
    the episode counters and ``metrics`` are
    :func:`~drqn_jax.learners.common.record_episodes`'.
    """

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
    """The network PPO trains: the task's torso (``config.network`` completed from
    the observation) and recurrent core, with A + 1 outputs — A logits, then the
    value."""
    net_config = task.network(config.network)
    return make_network(dataclasses.replace(net_config, num_actions=task.num_actions + 1))


def policy_network(network: Network, num_actions: int) -> Network:
    """``network`` with its value output dropped: ``step`` and ``unroll`` give the
    logits (…, A), whose argmax is the greedy action."""

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
    """Generalised advantage estimates and value targets, (T, N) each, of a
    rollout's values, rewards and end-of-episode flags (T, N) and the value of
    the state after it (N,)."""

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
    """The clipped-surrogate loss of a minibatch of whole sequences (T, B, …)
    unrolled from ``carry`` (B, …): actor + vf_coef · clipped value loss −
    ent_coef · entropy, and its parts."""
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
    """The :class:`~drqn_jax.learners.trainer.Trainer` of a ``config`` with ``algorithm =
    "ppo"`` (equal configs: the same functions). ``make_train`` calls it."""
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
        """The state before the first update (the config's hyperparameters and the
        task's env params by default)."""
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
    """The sampling policy (:data:`~drqn_jax.learners.common.Policy`): actions (N,)
    int32 drawn from the logits, the advanced carry, and the value (N,) and
    log-probability (N,) of the action taken."""
    n_act = task.num_actions
    out, carry = network.step(state.online, state.obs, restarted(network, state))
    logits, value = out[..., :n_act], out[..., n_act]
    action = jax.random.categorical(key, logits).astype(jnp.int32)
    log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], axis=-1)[:, 0]
    return action, carry, {"value": value, "log_prob": log_prob}, None


def _rollout(
    config: TrainConfig, task: Task, network: Network, state: PPOState
) -> tuple[PPOState, Transition]:
    """``rollout_steps`` steps of the N envs with actions sampled from the policy:
    the moved state (its ended episodes recorded) and the trajectory (leaves
    (T, N, …))."""
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
    """The update of one rollout: GAE, then epochs of minibatch gradient steps
    (global-norm clip, Adam at the annealed rate,
    :func:`~drqn_jax.learners.common.minibatch_epochs`); the update's mean loss
    joins every running episode's."""
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
