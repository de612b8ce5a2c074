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
the DQN's per-episode metrics (:mod:`drqn_jax.learners.episodes`; ``mean_loss`` is
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
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.learners.episodes import budget_met, init_counters, init_metrics, record_episodes
from drqn_jax.learners.hyperparams import Hyperparams, TrainConfig, annealed, step_share
from drqn_jax.learners.optim import apply_updates, clip_by_global_norm, optimizer
from drqn_jax.learners.task import Task, make_task
from drqn_jax.learners.trainer import Trainer, make_trainer
from drqn_jax.networks import Network, make_network
from drqn_jax.programs import cached_program
from drqn_jax.pytree import pytree_dataclass, tree_where

__all__ = [
    "PPOState",
    "Transition",
    "actor_critic",
    "gae",
    "make_ppo",
    "minibatch_epochs",
    "on_policy_init",
    "policy_network",
    "ppo_loss",
    "restarted",
    "run_updates",
]


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


@pytree_dataclass
class PPOState:
    """Everything a PPO run carries between updates (and checkpoints).

    Per-env leaves have a leading N axis. ``online`` holds the network's
    parameters (the name the DQN's state gives the parameters it trains, so
    the host loop and agent selection read both alike); ``done`` (N,) says
    which envs ended an episode at the last step; the episode counters and
    ``metrics`` are :func:`~drqn_jax.learners.episodes.record_episodes`'.
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
    snapshots: Any = None  # always None: snapshot selection is the DQN's (snapshots = 0)
    validation: Any = None

    @property
    def finished(self) -> jax.Array:
        return budget_met(self)


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

    init = on_policy_init(config, task, network)

    def act(state: PPOState, key: jax.Array) -> tuple[jax.Array, Any]:
        """Actions (N,) sampled from the policy and the advanced carry."""
        out, carry = network.step(state.online, state.obs, restarted(network, state))
        return jax.random.categorical(key, out[..., :n_act]).astype(jnp.int32), carry

    def update(state: PPOState) -> PPOState:
        carry0 = state.carry
        state, traj = _rollout(config, task, network, state)
        return _learn(config, network, n_act, state, traj, carry0)

    return make_trainer(config, task, policy, init, act, run_updates(update))


def run_updates(update: Callable[[PPOState], PPOState]) -> Callable[[PPOState, int], PPOState]:
    """The ``run`` of an on-policy learner (PPO's, PQN's) whose iteration is
    ``update``: ``run(state, num_iterations)`` scans that many updates; those
    after the run finished change nothing."""

    def run(state: PPOState, num_iterations: int) -> PPOState:
        def body(state, _):
            return jax.lax.cond(state.finished, lambda s: s, update, state), None

        return jax.lax.scan(body, state, None, length=num_iterations)[0]

    return run


def on_policy_init(
    config: TrainConfig, task: Task, network: Network, extra_metrics: tuple[str, ...] = ()
) -> Callable[..., PPOState]:
    """The ``init(key, hparams=None, env_params=None)`` of an on-policy learner
    (PPO's, PQN's): :func:`_init_state` with the config's hyperparameters and
    the task's env params as defaults."""

    def init(key: jax.Array, hparams: Hyperparams | None = None, env_params: Any = None):
        hp = config.hyperparams if hparams is None else hparams
        env_params = task.env_params if env_params is None else env_params
        return _init_state(config, task, network, key, hp, env_params, extra_metrics)

    return init


def _init_state(
    config: TrainConfig,
    task: Task,
    network: Network,
    key: jax.Array,
    hp: Hyperparams,
    env_params: Any,
    extra_metrics: tuple[str, ...] = (),
) -> PPOState:
    """The state before the first update (PPO's and PQN's): N envs reset, a fresh
    network and Adam, empty metrics (with the learner's ``extra_metrics``)."""
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
        metrics=init_metrics(task, config.num_episodes, extra_metrics),
        **init_counters(n_env, config.num_env_steps),
    )


def restarted(network: Network, state: PPOState) -> Any:
    """The carry (leaves (N, …)) the next step starts from: zeros where the last
    step ended an episode."""
    return tree_where(state.done, network.initial_carry(state.done.shape), state.carry)


def _rollout(
    config: TrainConfig, task: Task, network: Network, state: PPOState
) -> tuple[PPOState, Transition]:
    """``rollout_steps`` steps of the N envs with actions sampled from the policy:
    the moved state (its ended episodes recorded) and the trajectory (leaves
    (T, N, …))."""
    n_act = task.num_actions
    zero_f, zero_i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)

    def step(state, _):
        key, k_act, k_env = jax.random.split(state.key, 3)
        out, carry = network.step(state.online, state.obs, restarted(network, state))
        logits, value = out[..., :n_act], out[..., n_act]
        action = jax.random.categorical(k_act, logits).astype(jnp.int32)
        log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], axis=-1)[:, 0]
        env = jax.vmap(task.step, (0, 0, 0, None))(
            jax.random.split(k_env, config.num_envs), state.env_state, action, state.env_params
        )
        done = env.terminated | env.truncated
        traj = Transition(state.obs, action, env.reward, done, value, log_prob, state.done)
        moved, metrics = record_episodes(
            task, config.num_episodes, state, env, done, zero_f, zero_i
        )
        return moved.replace(key=key, carry=carry, done=done, metrics=metrics), traj

    return jax.lax.scan(step, state, None, config.rollout_steps)


def _learn(
    config: TrainConfig,
    network: Network,
    n_act: int,
    state: PPOState,
    traj: Transition,
    carry0: Any,
) -> PPOState:
    """The update of one rollout: GAE, then epochs of minibatch gradient steps
    (global-norm clip, Adam at the annealed rate); the update's mean loss joins
    every running episode's."""
    hp = state.hparams
    out, _ = network.step(state.online, state.obs, restarted(network, state))
    advantage, target = gae(traj.value, traj.reward, traj.done, out[..., n_act], hp)
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


def minibatch_epochs(
    config: TrainConfig,
    state: Any,
    learning_rate: jax.Array,
    grads_of: Callable[[Any, jax.Array], tuple[Any, jax.Array]],
) -> Any:
    """``update_epochs`` passes over the N envs in ``num_minibatches`` random
    minibatches of whole env sequences: ``grads_of(params, envs (N / M,))`` gives a
    minibatch's gradients and loss; each step clips them to ``max_grad_norm`` and
    takes a step of ``config.optimizer`` (Adam, or PQN's RAdam). The state with
    the new parameters and optimiser, its key advanced, the gradient steps
    counted and the mean loss added to every running episode's (PPO's and PQN's
    update)."""
    hp = state.hparams
    opt = optimizer(config.optimizer, learning_rate, hp.adam_b1, hp.adam_b2, hp.adam_eps)
    per_mb = config.num_envs // config.num_minibatches

    def minibatch(learner, envs):
        params, opt_state = learner
        grads, loss = grads_of(params, envs)
        grads, _ = clip_by_global_norm(hp.max_grad_norm).update(grads, ())
        updates, opt_state = opt.update(grads, opt_state, params)
        return (apply_updates(params, updates), opt_state), loss

    def epoch(loop, _):
        learner, key = loop
        key, k_perm = jax.random.split(key)
        envs = jax.random.permutation(k_perm, config.num_envs)
        learner, losses = jax.lax.scan(minibatch, learner, envs.reshape(-1, per_mb))
        return (learner, key), losses

    key, k_epochs = jax.random.split(state.key)
    ((params, opt_state), _), losses = jax.lax.scan(
        epoch, ((state.online, state.opt_state), k_epochs), None, config.update_epochs
    )
    return state.replace(
        key=key,
        online=params,
        opt_state=opt_state,
        ep_loss_sum=state.ep_loss_sum + jnp.mean(losses),
        ep_loss_count=state.ep_loss_count + 1,
        grad_steps=state.grad_steps + config.update_epochs * config.num_minibatches,
    )


def _total_loss(*args: Any) -> tuple[jax.Array, jax.Array]:
    """:func:`ppo_loss` with the total as its auxiliary output too."""
    total, _ = ppo_loss(*args)
    return total, total
